//! Node layouts: how the children of one node are tested against a ray. A layout is one axis
//! of the traversal kernel ([`super::kernel::traverse`]); a new layout (8-wide, quantised) is a
//! new implementation of [`NodeLayout`], and every primitive kind and visitor runs on it.

use super::kernel::Entry;
use super::ray::PreparedRay;
use oxray_bvh::Bvh4Node;
use oxray_core::ray::ROBUST_FAR;

/// A node layout of the CPU kernel.
pub(crate) trait NodeLayout {
    /// One node.
    type Node;
    /// The entry distance of every child (an array as wide as the node).
    type Dists: std::ops::Index<usize, Output = f32>;
    /// Tests the children of `node` against the ray over `[tmin, tmax]`: their entry distances
    /// and a mask of those the ray enters. Conservative: a child whose box holds a hit in the
    /// interval is never missed.
    fn intersect(node: &Self::Node, ray: &PreparedRay, tmin: f32, tmax: f32) -> (Self::Dists, u32);
    /// The stack entry of child `lane`: an inner node (count 0) or a leaf's slot range.
    fn entry(node: &Self::Node, lane: usize, dist: f32) -> Entry;
}

/// The 4-wide layout ([`Bvh4Node`]): boxes structure-of-arrays, tested with 4-wide SSE
/// arithmetic on x86-64 and the same arithmetic lane by lane elsewhere.
pub(crate) struct Bvh4;

impl NodeLayout for Bvh4 {
    type Node = Bvh4Node;
    type Dists = [f32; 4];

    #[inline(always)]
    fn intersect(node: &Bvh4Node, ray: &PreparedRay, tmin: f32, tmax: f32) -> ([f32; 4], u32) {
        intersect4(node, ray, tmin, tmax)
    }

    #[inline(always)]
    fn entry(node: &Bvh4Node, lane: usize, dist: f32) -> Entry {
        Entry {
            child: node.child[lane],
            count: node.count[lane],
            dist,
        }
    }
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
