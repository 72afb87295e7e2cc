//! The traversal kernel over one GAS: a 4-wide BVH walked nearest-first with a fixed-size stack,
//! with the decisions about candidate hits delegated to a [`GasVisitor`]. Queries, any-hit filters
//! and (later) the program pipeline are visitors, monomorphised into the loop.

use super::ray::PreparedRay;
use oxray_bvh::{Bvh4Node, Triangle4, TRAVERSAL_STACK_SIZE};
use oxray_core::ray::{min_ignore_nan, ROBUST_FAR, TMAX_SLACK};
use oxray_core::Aabb;

/// What a visitor decides about a candidate hit (guide §13.4, §13.13).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Decision {
    /// Not a hit (an any-hit program ignored it, or it was culled): tmax stays.
    Ignore,
    /// Accepted: tmax shrinks to its t.
    Accept,
    /// Accepted, and traversal ends (terminate-ray, or terminate-on-first-hit).
    AcceptAndTerminate,
    /// Not accepted, and traversal ends (an exception was raised).
    Abort,
}

/// Receives the candidate hits of a traversal.
pub(crate) trait GasVisitor {
    /// A triangle hit within the current interval, at leaf slot `slot`.
    fn triangle(&mut self, slot: u32, hit: &oxray_bvh::triangle::TriangleHit) -> Decision;
    /// A custom primitive whose box the ray enters within `[tmin, tmax]`. Returns the t of the
    /// closest hit it accepted (the new tmax), and whether traversal must end. `spare` is the
    /// unused part of the traversal stack, for a nested traversal (an instance's child).
    fn custom(
        &mut self,
        slot: u32,
        tmin: f32,
        tmax: f32,
        spare: &mut [Entry],
    ) -> (Option<f32>, bool);
}

/// The primitives of a GAS in leaf-slot order.
#[derive(Clone, Copy)]
pub(crate) enum Primitives<'a> {
    /// Blocks of four; leaf slot `s` is lane `s % 4` of block `s / 4`.
    Triangles(&'a [Triangle4]),
    Aabbs(&'a [Aabb]),
}

/// One entry of the traversal stack.
#[derive(Clone, Copy, Default)]
pub(crate) struct Entry {
    child: u32,
    count: u32,
    dist: f32,
}

/// Entries of the per-thread stack: enough for the deepest graph (31 levels) of the deepest BVHs
/// oxray builds.
pub(crate) const STACK_ENTRIES: usize = 32 * TRAVERSAL_STACK_SIZE;

thread_local! {
    static STACK: std::cell::RefCell<Vec<Entry>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Runs `f` with this thread's traversal stack (allocated once per thread, so traversal
/// allocates nothing per ray). Should work nest on the same thread while the stack is in use
/// (a program running its own thread pool inside a traversal), a fresh stack is used.
pub(crate) fn with_stack<R>(f: impl FnOnce(&mut [Entry]) -> R) -> R {
    STACK.with(|cell| match cell.try_borrow_mut() {
        Ok(mut stack) => {
            if stack.len() < STACK_ENTRIES {
                stack.resize(STACK_ENTRIES, Entry::default());
            }
            f(&mut stack)
        }
        Err(_) => f(&mut vec![Entry::default(); STACK_ENTRIES]),
    })
}

/// Tests a ray against the four boxes of a node; returns the entry distances and a hit mask.
/// `tmax` is the interval's end with [`TMAX_SLACK`] applied.
///
/// The slab distances use NaN-ignoring min/max: a NaN (origin exactly on a slab plane of an axis
/// the ray does not move along) leaves the accumulated interval unchanged, as it should for a
/// closed box.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn intersect4(node: &Bvh4Node, r: &PreparedRay, tmin: f32, tmax: f32) -> ([f32; 4], u32) {
    use std::arch::x86_64::*;
    let b = &node.bounds;
    // SAFETY: SSE is part of the x86_64 baseline, so the intrinsics are available. `Bvh4Node` is
    // `repr(C, align(64))` with `bounds` (rows of `[f32; 4]`) first, so each row is a 16-byte
    // aligned load of 4 floats, as are the `Lanes` of the ray (`align(16)`); `dist` is 4 writable
    // floats (unaligned store).
    unsafe {
        let load = |row: &[f32; 4]| _mm_load_ps(row.as_ptr());
        let mut tn = _mm_set1_ps(tmin);
        let mut tf = _mm_set1_ps(tmax);
        let robust = _mm_set1_ps(ROBUST_FAR);
        for a in 0..3 {
            let o = _mm_load_ps(r.org4[a].0.as_ptr());
            let inv = _mm_load_ps(r.inv4[a].0.as_ptr());
            let n = _mm_mul_ps(_mm_sub_ps(load(&b[r.near[a]]), o), inv);
            let f = _mm_mul_ps(_mm_mul_ps(_mm_sub_ps(load(&b[r.far[a]]), o), inv), robust);
            // maxps/minps return their second operand when either is NaN.
            tn = _mm_max_ps(n, tn);
            tf = _mm_min_ps(f, tf);
        }
        let mask = _mm_movemask_ps(_mm_cmple_ps(tn, tf)) as u32;
        let mut dist = [0.0f32; 4];
        _mm_storeu_ps(dist.as_mut_ptr(), tn);
        (dist, mask)
    }
}

/// Portable form of the 4-wide box test.
#[cfg(not(target_arch = "x86_64"))]
#[inline(always)]
fn intersect4(node: &Bvh4Node, r: &PreparedRay, tmin: f32, tmax: f32) -> ([f32; 4], u32) {
    use oxray_core::ray::{max_ignore_nan, min_ignore_nan};
    let b = &node.bounds;
    let mut tn = [tmin; 4];
    let mut tf = [tmax; 4];
    for a in 0..3 {
        let nb = &b[r.near[a]];
        let fb = &b[r.far[a]];
        let (o, inv) = (r.org[a], r.inv[a]);
        for l in 0..4 {
            tn[l] = max_ignore_nan(tn[l], (nb[l] - o) * inv);
            tf[l] = min_ignore_nan(tf[l], (fb[l] - o) * inv * ROBUST_FAR);
        }
    }
    let mut mask = 0;
    for l in 0..4 {
        mask |= ((tn[l] <= tf[l]) as u32) << l;
    }
    (tn, mask)
}

/// Walks the BVH from the root, nearest child first, calling the visitor for every candidate in
/// the shrinking interval. Returns the final tmax and whether the visitor ended traversal.
#[inline(always)]
pub(crate) fn traverse_gas<V: GasVisitor>(
    nodes: &[Bvh4Node],
    prims: Primitives<'_>,
    ray: &PreparedRay,
    tmin: f32,
    mut tmax: f32,
    visitor: &mut V,
    stack: &mut [Entry],
) -> (f32, bool) {
    let mut sp = 0usize;
    let mut box_tmax = tmax * TMAX_SLACK;
    let mut cur = Entry {
        child: 0,
        count: 0,
        dist: tmin,
    };
    loop {
        if cur.count == 0 {
            let node = &nodes[cur.child as usize];
            let (dist, mut mask) = intersect4(node, ray, tmin, box_tmax);
            if mask != 0 {
                let entry = |l: usize| Entry {
                    child: node.child[l],
                    count: node.count[l],
                    dist: dist[l],
                };
                let a = entry(mask.trailing_zeros() as usize);
                mask &= mask - 1;
                if mask == 0 {
                    // One child hit: descend without touching the stack.
                    cur = a;
                    continue;
                }
                let b = entry(mask.trailing_zeros() as usize);
                mask &= mask - 1;
                if mask == 0 {
                    // Two: push the farther one.
                    let (near, far) = if b.dist < a.dist { (b, a) } else { (a, b) };
                    stack[sp] = far;
                    sp += 1;
                    cur = near;
                    continue;
                }
                // Three or four: push all, sort them farthest first, continue with the nearest.
                let base = sp;
                stack[sp] = a;
                stack[sp + 1] = b;
                sp += 2;
                while mask != 0 {
                    stack[sp] = entry(mask.trailing_zeros() as usize);
                    mask &= mask - 1;
                    sp += 1;
                }
                for i in base + 1..sp {
                    let e = stack[i];
                    let mut j = i;
                    while j > base && stack[j - 1].dist < e.dist {
                        stack[j] = stack[j - 1];
                        j -= 1;
                    }
                    stack[j] = e;
                }
                sp -= 1;
                cur = stack[sp];
                continue;
            }
        } else {
            let start = cur.child as usize;
            let count = cur.count as usize;
            match prims {
                Primitives::Triangles(blocks) => {
                    let mut slot = start;
                    let end = start + count;
                    while slot < end {
                        let valid = (end - slot).min(4);
                        let hits = ray.tri.intersect4(&blocks[slot / 4], valid, tmin, tmax);
                        let mut m = hits.mask;
                        while m != 0 {
                            let l = m.trailing_zeros() as usize;
                            m &= m - 1;
                            // An earlier lane may have shrunk the interval.
                            if hits.t[l] > tmax {
                                continue;
                            }
                            let h = hits.get(l);
                            match visitor.triangle((slot + l) as u32, &h) {
                                Decision::Ignore => {}
                                Decision::Accept => {
                                    tmax = h.t;
                                    box_tmax = tmax * TMAX_SLACK;
                                }
                                Decision::AcceptAndTerminate => return (h.t, true),
                                Decision::Abort => return (tmax, true),
                            }
                        }
                        slot += 4;
                    }
                }
                Primitives::Aabbs(boxes) => {
                    for (slot, b) in boxes[start..start + count].iter().enumerate() {
                        if ray.hits_box(b, tmin, tmax) {
                            let spare = &mut stack[sp..];
                            let (t, stop) =
                                visitor.custom((start + slot) as u32, tmin, tmax, spare);
                            if let Some(t) = t {
                                tmax = min_ignore_nan(tmax, t);
                                box_tmax = tmax * TMAX_SLACK;
                            }
                            if stop {
                                return (tmax, true);
                            }
                        }
                    }
                }
            }
        }
        // Pop the next entry that may still hold a hit.
        loop {
            if sp == 0 {
                return (tmax, false);
            }
            sp -= 1;
            cur = stack[sp];
            if cur.dist <= box_tmax {
                break;
            }
        }
    }
}
