//! A CPU port of the trace kernels' traversal over the device layout, for tests: it reads the very
//! words that are uploaded, walks them as `kernels/trace.cu` does, and must find the CPU
//! backend's hits. That proves the layout and the traversal order without a GPU; the GPU test
//! then checks the CUDA code itself.

use crate::context::{ROBUST_FAR, TMAX_SLACK};
use crate::gas::HitRecord;
use crate::layout::{DeviceLayout, NodeLayout};
use oxray_bvh::triangle::WatertightRay;
use oxray_core::Ray;

#[derive(Clone, Copy)]
struct Entry {
    child: u32,
    count: u32,
    dist: f32,
}

struct Prepared {
    org: [f32; 3],
    inv: [f32; 3],
    neg: [bool; 3],
    tri: WatertightRay,
}

fn max_keep(x: f32, acc: f32) -> f32 {
    if x > acc {
        x
    } else {
        acc
    }
}

fn min_keep(x: f32, acc: f32) -> f32 {
    if x < acc {
        x
    } else {
        acc
    }
}

/// The kernel's slab test: near and far planes per axis.
fn slab(r: &Prepared, near: [f32; 3], far: [f32; 3], tmin: f32, box_tmax: f32) -> (bool, f32) {
    let mut tn = tmin;
    let mut tf = box_tmax;
    for a in 0..3 {
        tn = max_keep((near[a] - r.org[a]) * r.inv[a], tn);
        tf = min_keep(((far[a] - r.org[a]) * r.inv[a]) * ROBUST_FAR, tf);
    }
    (tn <= tf, tn)
}

/// Traces one ray through the device layout as the kernel does.
pub(crate) fn trace(l: &DeviceLayout, ray: &Ray, any: bool) -> HitRecord {
    let miss = HitRecord {
        t: f32::INFINITY,
        slot: HitRecord::MISS,
        u: 0.0,
        v: 0.0,
    };
    if ray.validate().is_err() {
        return miss;
    }
    let d = ray.direction.to_array();
    let inv = d.map(|x| if x == 0.0 { f32::INFINITY } else { 1.0 / x });
    let r = Prepared {
        org: ray.origin.to_array(),
        inv,
        // `inv` is never NaN (a zero component gives +inf).
        neg: inv.map(|x| x < 0.0),
        tri: WatertightRay::new(ray.origin, ray.direction),
    };
    let f = |w: u32| f32::from_bits(w);
    let tmin = ray.tmin;
    let mut tmax = ray.tmax;
    let mut box_tmax = tmax * TMAX_SLACK;
    let mut best = miss;
    let mut stack: Vec<Entry> = Vec::new();
    let mut cur = Entry {
        child: 0,
        count: 0,
        dist: tmin,
    };
    loop {
        if cur.count == 0 {
            let mut hit: Vec<Entry> = Vec::with_capacity(4);
            match l.layout {
                NodeLayout::Bvh4 => {
                    let n = &l.nodes[32 * cur.child as usize..][..32];
                    for lane in 0..4 {
                        let row = |k: usize| f(n[4 * k + lane]);
                        let pick = |a: usize, near: bool| {
                            if r.neg[a] == near {
                                row(a + 3)
                            } else {
                                row(a)
                            }
                        };
                        let near = [pick(0, true), pick(1, true), pick(2, true)];
                        let far = [pick(0, false), pick(1, false), pick(2, false)];
                        let (h, dist) = slab(&r, near, far, tmin, box_tmax);
                        if h {
                            hit.push(Entry {
                                child: n[24 + lane],
                                count: n[28 + lane],
                                dist,
                            });
                        }
                    }
                }
                NodeLayout::Bvh2 => {
                    let n = &l.nodes[16 * cur.child as usize..][..16];
                    // Child c: x in row c (words 4c, 4c+1), y (4c+2, 4c+3), z in row 2.
                    for c in 0..2 {
                        let lo = [f(n[4 * c]), f(n[4 * c + 2]), f(n[8 + 2 * c])];
                        let hi = [f(n[4 * c + 1]), f(n[4 * c + 3]), f(n[9 + 2 * c])];
                        let near = std::array::from_fn(|a| if r.neg[a] { hi[a] } else { lo[a] });
                        let far = std::array::from_fn(|a| if r.neg[a] { lo[a] } else { hi[a] });
                        let (h, dist) = slab(&r, near, far, tmin, box_tmax);
                        if h {
                            hit.push(Entry {
                                child: n[12 + c],
                                count: n[14 + c],
                                dist,
                            });
                        }
                    }
                }
            }
            match hit.len() {
                0 => {}
                1 => {
                    cur = hit[0];
                    continue;
                }
                2 => {
                    let (a, b) = (hit[0], hit[1]);
                    if b.dist < a.dist {
                        stack.push(a);
                        cur = b;
                    } else {
                        stack.push(b);
                        cur = a;
                    }
                    continue;
                }
                _ => {
                    // Insertion sort, farthest first; equal distances keep lane order.
                    let base = stack.len();
                    for e in hit {
                        stack.push(e);
                        let mut j = stack.len() - 1;
                        while j > base && stack[j - 1].dist < e.dist {
                            stack[j] = stack[j - 1];
                            j -= 1;
                        }
                        stack[j] = e;
                    }
                    cur = stack.pop().expect("pushed three or more");
                    continue;
                }
            }
        } else {
            for s in cur.child..cur.child + cur.count {
                let t = &l.triangles[12 * s as usize..][..12];
                let p = |k: usize| [t[4 * k], t[4 * k + 1], t[4 * k + 2]];
                if let Some(h) = r.tri.intersect(&p(0), &p(1), &p(2), tmin, tmax) {
                    best = HitRecord {
                        t: h.t,
                        slot: s | if h.front_face { 0 } else { 0x8000_0000 },
                        u: h.u,
                        v: h.v,
                    };
                    if any {
                        return best;
                    }
                    tmax = h.t;
                    box_tmax = tmax * TMAX_SLACK;
                }
            }
        }
        loop {
            let Some(e) = stack.pop() else {
                return best;
            };
            cur = e;
            if cur.dist <= box_tmax {
                break;
            }
        }
    }
}
