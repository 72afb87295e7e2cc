//! A CPU port of the trace kernels' traversal over the device layout, for tests: it reads the very
//! words that are uploaded, walks them as `kernels/trace.cu` does, and must find the CPU
//! backend's hits. That proves the layout and the traversal order without a GPU; the GPU test
//! then checks the CUDA code itself.

use crate::context::{ROBUST_FAR, TMAX_SLACK};
use crate::gas::HitRecord;
use crate::layout::{DeviceLayout, IasLayout, NodeLayout, INSTANCE_WORDS};
use oxray_bvh::triangle::WatertightRay;
use oxray_core::{Ray, Transform};

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

/// The kernel's `prepare_ray`: `None` for an invalid ray.
fn prepare(ray: &Ray) -> Option<Prepared> {
    ray.validate().ok()?;
    let d = ray.direction.to_array();
    let inv = d.map(|x| if x == 0.0 { f32::INFINITY } else { 1.0 / x });
    Some(Prepared {
        org: ray.origin.to_array(),
        inv,
        // `inv` is never NaN (a zero component gives +inf).
        neg: inv.map(|x| x < 0.0),
        tri: WatertightRay::new(ray.origin, ray.direction),
    })
}

const MISS: HitRecord = HitRecord {
    t: f32::INFINITY,
    slot: HitRecord::MISS,
    u: 0.0,
    v: 0.0,
};

/// Traces one ray through the device layout as the kernel does.
pub(crate) fn trace(l: &DeviceLayout, ray: &Ray, any: bool) -> HitRecord {
    match prepare(ray) {
        Some(r) => trace_prepared(l, &r, ray.tmin, ray.tmax, any),
        None => MISS,
    }
}

fn trace_prepared(l: &DeviceLayout, r: &Prepared, tmin: f32, tmax: f32, any: bool) -> HitRecord {
    let mut best = MISS;
    walk(&l.nodes, l.layout, r, tmin, tmax, |start, count, tmax| {
        for s in start..start + count {
            let t = &l.triangles[12 * s as usize..][..12];
            let p = |k: usize| [t[4 * k], t[4 * k + 1], t[4 * k + 2]];
            if let Some(h) = r.tri.intersect(&p(0), &p(1), &p(2), tmin, *tmax) {
                best = HitRecord {
                    t: h.t,
                    slot: s | if h.front_face { 0 } else { 0x8000_0000 },
                    u: h.u,
                    v: h.v,
                };
                if any {
                    return true;
                }
                *tmax = h.t;
            }
        }
        false
    });
    best
}

/// The kernel's `hits_box` (the CPU's scalar instance-box test).
fn hits_box(r: &Prepared, lo: [f32; 3], hi: [f32; 3], tmin: f32, tmax: f32) -> bool {
    let mut t0 = tmin;
    let mut t1 = f32::INFINITY;
    for a in 0..3 {
        let (n, f) = if r.neg[a] {
            (hi[a], lo[a])
        } else {
            (lo[a], hi[a])
        };
        t0 = max_keep((n - r.org[a]) * r.inv[a], t0);
        t1 = min_keep((f - r.org[a]) * r.inv[a], t1);
    }
    t0 <= min_keep(t1 * ROBUST_FAR, tmax * TMAX_SLACK)
}

/// Traces one ray through an IAS layout as the IAS kernels do; `children[i]` is the layout of
/// the child whose index the instance table names. Returns the hit and its instance slot.
pub(crate) fn trace_ias(
    top: &IasLayout,
    children: &[Option<DeviceLayout>],
    ray: &Ray,
    any: bool,
) -> (HitRecord, u32) {
    let Some(r) = prepare(ray) else {
        return (MISS, u32::MAX);
    };
    let f = |w: u32| f32::from_bits(w);
    let mut best = (MISS, u32::MAX);
    let tmin = ray.tmin;
    walk(
        &top.nodes,
        NodeLayout::Bvh2,
        &r,
        tmin,
        ray.tmax,
        |start, count, tmax| {
            for s in start..start + count {
                let w = &top.instances[INSTANCE_WORDS * s as usize..][..INSTANCE_WORDS];
                let lo = [f(w[12]), f(w[13]), f(w[14])];
                let hi = [f(w[16]), f(w[17]), f(w[18])];
                if !hits_box(&r, lo, hi, tmin, *tmax) {
                    continue;
                }
                let Some(Some(child)) = children.get(w[15] as usize) else {
                    continue;
                };
                let m = Transform(std::array::from_fn(|k| f(w[k])));
                let object = Ray {
                    origin: m.transform_point(ray.origin),
                    direction: m.transform_vector(ray.direction),
                    tmin,
                    tmax: *tmax,
                    time: ray.time,
                };
                let Some(o) = prepare(&object) else {
                    continue;
                };
                let h = trace_prepared(child, &o, tmin, *tmax, any);
                if h.is_hit() {
                    best = (h, s);
                    if any {
                        return true;
                    }
                    *tmax = h.t;
                }
            }
            false
        },
    );
    best
}

/// Walks a BVH of the device layout as the kernels do, handing each leaf's slot range to
/// `leaf` with the interval's end; `leaf` may shrink it and returns whether to stop.
fn walk(
    nodes: &[u32],
    layout: NodeLayout,
    r: &Prepared,
    tmin: f32,
    tmax: f32,
    mut leaf: impl FnMut(u32, u32, &mut f32) -> bool,
) {
    let f = |w: u32| f32::from_bits(w);
    let mut tmax = tmax;
    let mut box_tmax = tmax * TMAX_SLACK;
    let mut stack: Vec<Entry> = Vec::new();
    let mut cur = Entry {
        child: 0,
        count: 0,
        dist: tmin,
    };
    loop {
        if cur.count == 0 {
            let mut hit: Vec<Entry> = Vec::with_capacity(4);
            match layout {
                NodeLayout::Bvh4 => {
                    let n = &nodes[32 * cur.child as usize..][..32];
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
                        let (h, dist) = slab(r, near, far, tmin, box_tmax);
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
                    let n = &nodes[16 * cur.child as usize..][..16];
                    // Child c: x in row c (words 4c, 4c+1), y (4c+2, 4c+3), z in row 2.
                    for c in 0..2 {
                        let lo = [f(n[4 * c]), f(n[4 * c + 2]), f(n[8 + 2 * c])];
                        let hi = [f(n[4 * c + 1]), f(n[4 * c + 3]), f(n[9 + 2 * c])];
                        let near = std::array::from_fn(|a| if r.neg[a] { hi[a] } else { lo[a] });
                        let far = std::array::from_fn(|a| if r.neg[a] { lo[a] } else { hi[a] });
                        let (h, dist) = slab(r, near, far, tmin, box_tmax);
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
            let before = tmax;
            if leaf(cur.child, cur.count, &mut tmax) {
                return;
            }
            if tmax != before {
                box_tmax = tmax * TMAX_SLACK;
            }
        }
        loop {
            let Some(e) = stack.pop() else {
                return;
            };
            cur = e;
            if cur.dist <= box_tmax {
                break;
            }
        }
    }
}
