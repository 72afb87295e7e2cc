//! Node layouts: how the children of one node are tested against a ray. A layout is one axis
//! of the traversal kernel ([`super::kernel::traverse`]); a new layout (quantised, say) is a
//! new implementation of [`NodeLayout`], and every primitive kind and visitor runs on it.
//!
//! - [`Bvh4`]: 4-wide nodes, SSE on x86-64, portable code elsewhere;
//! - [`Bvh8Scalar`]: 8-wide nodes, portable code (the reference of the SIMD 8-wide layouts);
//! - `Bvh8Avx2`, `Bvh8Avx512` (x86-64): 8-wide nodes with AVX2, or AVX-512's mask compares.
//!   Their tests are `#[target_feature]` functions: only the kernels of
//!   [`super::kernel`] compiled with those features traverse them, and only once the processor
//!   was found to have them ([`crate::Isa`]);
//! - `QBvh8Avx2`, `QBvh8Avx512` (x86-64): the quantised 8-wide nodes ([`QBvh8Node`]), decoded
//!   to boxes that contain the exact ones, then tested as the 8-wide layouts test theirs.
//!
//! Every layout computes the same slab distances with the same `f32` operations in the same
//! order (no fused multiply-add: Rust never contracts), so a box is entered by one layout iff
//! it is by another, and the conservative far-plane scaling (`ROBUST_FAR`, `TMAX_SLACK`) is
//! the same everywhere. The quantised layouts test larger boxes with those operations, so they
//! enter every box the others enter, and some more.

use super::kernel::Entry;
use super::ray::PreparedRay;
use oxray_bvh::{Bvh4Node, Bvh8Node, QBvh8Node};
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
    /// Asks for node `index` of `nodes` to be loaded (a hint; any index is allowed).
    #[inline(always)]
    fn prefetch(nodes: &[Self::Node], index: u32) {
        let lines = super::prefetch::lines_of::<Self::Node>();
        super::prefetch::prefetch(nodes.as_ptr().wrapping_add(index as usize), lines);
    }
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
/// `tmax` is the interval's end with [`TMAX_SLACK`](oxray_core::ray::TMAX_SLACK) applied.
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
    // aligned load of 4 floats; `dist` is 4 writable floats (unaligned store).
    unsafe {
        let load = |row: &[f32; 4]| _mm_load_ps(row.as_ptr());
        let mut tn = _mm_set1_ps(tmin);
        let mut tf = _mm_set1_ps(tmax);
        let robust = _mm_set1_ps(ROBUST_FAR);
        for a in 0..3 {
            let o = _mm_set1_ps(r.org[a]);
            let inv = _mm_set1_ps(r.inv[a]);
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
    intersect_portable(&node.bounds, r, tmin, tmax)
}

/// The box test lane by lane, for any width: the operations of the SIMD forms, with their
/// NaN rule (`maxps`/`minps` return their second operand when either is NaN).
#[inline(always)]
fn intersect_portable<const W: usize>(
    b: &[[f32; W]; 6],
    r: &PreparedRay,
    tmin: f32,
    tmax: f32,
) -> ([f32; W], u32) {
    // `x > y ? x : y` with the NaN rule of `maxps(x, y)`, and likewise for min.
    #[inline(always)]
    fn max_ps(x: f32, y: f32) -> f32 {
        if x > y {
            x
        } else {
            y
        }
    }
    #[inline(always)]
    fn min_ps(x: f32, y: f32) -> f32 {
        if x < y {
            x
        } else {
            y
        }
    }
    let mut tn = [tmin; W];
    let mut tf = [tmax; W];
    for a in 0..3 {
        let nb = &b[r.near[a]];
        let fb = &b[r.far[a]];
        let (o, inv) = (r.org[a], r.inv[a]);
        for l in 0..W {
            tn[l] = max_ps((nb[l] - o) * inv, tn[l]);
            tf[l] = min_ps((fb[l] - o) * inv * ROBUST_FAR, tf[l]);
        }
    }
    let mut mask = 0;
    for l in 0..W {
        mask |= ((tn[l] <= tf[l]) as u32) << l;
    }
    (tn, mask)
}

/// The 8-wide layout ([`Bvh8Node`]) tested lane by lane with portable code.
pub(crate) struct Bvh8Scalar;

impl NodeLayout for Bvh8Scalar {
    type Node = Bvh8Node;
    type Dists = [f32; 8];

    #[inline(always)]
    fn intersect(node: &Bvh8Node, ray: &PreparedRay, tmin: f32, tmax: f32) -> ([f32; 8], u32) {
        intersect_portable(&node.bounds, ray, tmin, tmax)
    }

    #[inline(always)]
    fn entry(node: &Bvh8Node, lane: usize, dist: f32) -> Entry {
        entry8(node, lane, dist)
    }
}

#[inline(always)]
fn entry8(node: &Bvh8Node, lane: usize, dist: f32) -> Entry {
    Entry {
        child: node.child[lane],
        count: node.count[lane],
        dist,
    }
}

/// The 8-wide layout tested with AVX2. Traversed only by
/// [`traverse_avx2`](super::kernel::traverse_avx2) and the batch path's `rays_avx2`.
#[cfg(target_arch = "x86_64")]
pub(crate) struct Bvh8Avx2;

#[cfg(target_arch = "x86_64")]
impl NodeLayout for Bvh8Avx2 {
    type Node = Bvh8Node;
    type Dists = [f32; 8];

    #[inline(always)]
    fn intersect(node: &Bvh8Node, ray: &PreparedRay, tmin: f32, tmax: f32) -> ([f32; 8], u32) {
        // SAFETY: this layout is traversed only by `kernel::traverse_avx2` and
        // `batch::rays_avx2`, which are called only for a structure whose kernel is
        // `Isa::Avx2` or `Isa::Avx512`, and a structure gets those kernels only after
        // `Isa::is_available` detected AVX2 (and the features `intersect8_avx2` is compiled
        // with) on this processor.
        unsafe { intersect8_avx2(node, ray, tmin, tmax) }
    }

    #[inline(always)]
    fn entry(node: &Bvh8Node, lane: usize, dist: f32) -> Entry {
        entry8(node, lane, dist)
    }
}

/// The 8-wide layout tested with AVX-512 (VL): the compare writes a mask register. Traversed
/// only by [`traverse_avx512`](super::kernel::traverse_avx512) and the batch path's
/// `rays_avx512`.
#[cfg(target_arch = "x86_64")]
pub(crate) struct Bvh8Avx512;

#[cfg(target_arch = "x86_64")]
impl NodeLayout for Bvh8Avx512 {
    type Node = Bvh8Node;
    type Dists = [f32; 8];

    #[inline(always)]
    fn intersect(node: &Bvh8Node, ray: &PreparedRay, tmin: f32, tmax: f32) -> ([f32; 8], u32) {
        // SAFETY: traversed only by `kernel::traverse_avx512` and `batch::rays_avx512`, called
        // only for a structure whose kernel is `Isa::Avx512`, which `Isa::is_available` gives
        // only after detecting AVX2, AVX-512F and AVX-512VL on this processor.
        unsafe { intersect8_avx512(node, ray, tmin, tmax) }
    }

    #[inline(always)]
    fn entry(node: &Bvh8Node, lane: usize, dist: f32) -> Entry {
        entry8(node, lane, dist)
    }
}

/// The slab distances of the eight lanes with AVX: the operations of [`intersect4`], eight
/// lanes at a time.
///
/// # Safety
///
/// The processor must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn slabs8(
    node: &Bvh8Node,
    r: &PreparedRay,
    tmin: f32,
    tmax: f32,
) -> (std::arch::x86_64::__m256, std::arch::x86_64::__m256) {
    use std::arch::x86_64::*;
    let b = &node.bounds;
    // SAFETY: `Bvh8Node` is `repr(C, align(64))` with `bounds` (rows of `[f32; 8]`) first, so
    // each row is a 32-byte aligned, in-bounds load of 8 floats.
    unsafe {
        let load = |row: &[f32; 8]| _mm256_load_ps(row.as_ptr());
        let mut tn = _mm256_set1_ps(tmin);
        let mut tf = _mm256_set1_ps(tmax);
        let robust = _mm256_set1_ps(ROBUST_FAR);
        for a in 0..3 {
            let o = _mm256_set1_ps(r.org[a]);
            let inv = _mm256_set1_ps(r.inv[a]);
            let n = _mm256_mul_ps(_mm256_sub_ps(load(&b[r.near[a]]), o), inv);
            let f = _mm256_mul_ps(
                _mm256_mul_ps(_mm256_sub_ps(load(&b[r.far[a]]), o), inv),
                robust,
            );
            // vmaxps/vminps return their second operand when either is NaN.
            tn = _mm256_max_ps(n, tn);
            tf = _mm256_min_ps(f, tf);
        }
        (tn, tf)
    }
}

/// Tests a ray against the eight boxes of a node with AVX2; returns the entry distances and
/// a hit mask.
///
/// # Safety
///
/// The processor must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn intersect8_avx2(
    node: &Bvh8Node,
    r: &PreparedRay,
    tmin: f32,
    tmax: f32,
) -> ([f32; 8], u32) {
    use std::arch::x86_64::*;
    // SAFETY: the caller guarantees AVX2.
    let (tn, tf) = unsafe { slabs8(node, r, tmin, tmax) };
    let mask = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(tn, tf)) as u32;
    // SAFETY: the caller guarantees AVX2.
    (unsafe { store8(tn) }, mask)
}

/// [`intersect8_avx2`] with AVX-512VL's compare into a mask register.
///
/// # Safety
///
/// The processor must have AVX2, AVX-512F and AVX-512VL.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512vl")]
#[inline]
unsafe fn intersect8_avx512(
    node: &Bvh8Node,
    r: &PreparedRay,
    tmin: f32,
    tmax: f32,
) -> ([f32; 8], u32) {
    use std::arch::x86_64::*;
    // SAFETY: the caller guarantees AVX2.
    let (tn, tf) = unsafe { slabs8(node, r, tmin, tmax) };
    let mask = _mm256_cmp_ps_mask::<_CMP_LE_OQ>(tn, tf) as u32;
    // SAFETY: the caller guarantees AVX2.
    (unsafe { store8(tn) }, mask)
}

/// The quantised 8-wide layout ([`QBvh8Node`]) tested with AVX2. Traversed only by
/// [`traverse_q_avx2`](super::kernel::traverse_q_avx2).
#[cfg(target_arch = "x86_64")]
pub(crate) struct QBvh8Avx2;

#[cfg(target_arch = "x86_64")]
impl NodeLayout for QBvh8Avx2 {
    type Node = QBvh8Node;
    type Dists = [f32; 8];

    #[inline(always)]
    fn intersect(node: &QBvh8Node, ray: &PreparedRay, tmin: f32, tmax: f32) -> ([f32; 8], u32) {
        // SAFETY: this layout is traversed only by `kernel::traverse_q_avx2`, which is called
        // only for a structure whose kernel is `Isa::Avx2Quantized` or `Isa::Avx512Quantized`,
        // given only after `Isa::is_available` detected AVX2 on this processor.
        unsafe {
            use std::arch::x86_64::*;
            let (tn, tf) = qslabs8(node, ray, tmin, tmax);
            let hit = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(tn, tf)) as u32;
            (store8(tn), hit & u32::from(node.valid))
        }
    }

    #[inline(always)]
    fn entry(node: &QBvh8Node, lane: usize, dist: f32) -> Entry {
        qentry8(node, lane, dist)
    }
}

/// The quantised 8-wide layout tested with AVX-512 (VL) compares. Traversed only by
/// [`traverse_q_avx512`](super::kernel::traverse_q_avx512).
#[cfg(target_arch = "x86_64")]
pub(crate) struct QBvh8Avx512;

#[cfg(target_arch = "x86_64")]
impl NodeLayout for QBvh8Avx512 {
    type Node = QBvh8Node;
    type Dists = [f32; 8];

    #[inline(always)]
    fn intersect(node: &QBvh8Node, ray: &PreparedRay, tmin: f32, tmax: f32) -> ([f32; 8], u32) {
        // SAFETY: traversed only by `kernel::traverse_q_avx512`, called only for a structure
        // whose kernel is `Isa::Avx512Quantized`, which `Isa::is_available` gives only after
        // detecting AVX2, AVX-512F and AVX-512VL on this processor.
        unsafe {
            use std::arch::x86_64::*;
            let (tn, tf) = qslabs8(node, ray, tmin, tmax);
            let hit = _mm256_mask_cmp_ps_mask::<_CMP_LE_OQ>(node.valid, tn, tf) as u32;
            (store8(tn), hit)
        }
    }

    #[inline(always)]
    fn entry(node: &QBvh8Node, lane: usize, dist: f32) -> Entry {
        qentry8(node, lane, dist)
    }
}

#[inline(always)]
fn qentry8(node: &QBvh8Node, lane: usize, dist: f32) -> Entry {
    Entry {
        child: node.child[lane],
        count: u32::from(node.count[lane]),
        dist,
    }
}

/// The eight lanes of an AVX register as an array.
///
/// # Safety
///
/// The processor must have AVX.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn store8(v: std::arch::x86_64::__m256) -> [f32; 8] {
    let mut out = [0.0f32; 8];
    // SAFETY: `out` is 8 writable floats (unaligned store); the caller guarantees AVX.
    unsafe { std::arch::x86_64::_mm256_storeu_ps(out.as_mut_ptr(), v) };
    out
}

/// The slab distances of a quantised node's eight lanes: each bound row decoded (bytes to
/// floats, times the axis's step, plus its origin: [`QBvh8Node::bound`]'s operations), then
/// [`slabs8`]'s operations on the decoded boxes.
///
/// # Safety
///
/// The processor must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn qslabs8(
    node: &QBvh8Node,
    r: &PreparedRay,
    tmin: f32,
    tmax: f32,
) -> (std::arch::x86_64::__m256, std::arch::x86_64::__m256) {
    use std::arch::x86_64::*;
    // SAFETY: each row of `node.q` is 8 in-bounds bytes (an unaligned 8-byte load).
    let row = |k: usize, scale: __m256, origin: __m256| unsafe {
        let bytes = _mm_loadl_epi64(node.q[k].as_ptr().cast());
        let q = _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(bytes));
        _mm256_add_ps(_mm256_mul_ps(q, scale), origin)
    };
    let mut tn = _mm256_set1_ps(tmin);
    let mut tf = _mm256_set1_ps(tmax);
    let robust = _mm256_set1_ps(ROBUST_FAR);
    for a in 0..3 {
        let scale = _mm256_set1_ps(node.scale[a]);
        let origin = _mm256_set1_ps(node.origin[a]);
        let o = _mm256_set1_ps(r.org[a]);
        let inv = _mm256_set1_ps(r.inv[a]);
        let n = _mm256_mul_ps(_mm256_sub_ps(row(r.near[a], scale, origin), o), inv);
        let f = _mm256_mul_ps(
            _mm256_mul_ps(_mm256_sub_ps(row(r.far[a], scale, origin), o), inv),
            robust,
        );
        tn = _mm256_max_ps(n, tn);
        tf = _mm256_min_ps(f, tf);
    }
    (tn, tf)
}
