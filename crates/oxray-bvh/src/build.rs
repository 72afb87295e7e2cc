//! Binned SAH builder (Wald 2007), parallel over subtrees and, at the top, over primitives.
//!
//! Every reduction is a min, a max or an integer sum, and work is split at fixed sizes, so the
//! tree is bit-identical whatever the number of threads.

use crate::bvh2::{Bvh2, Bvh2Node};
use crate::FORCE_MEDIAN_DEPTH;
use oxray_core::Aabb;
use rayon::prelude::*;

/// Tuning of the SAH builder; the build flags choose one of the presets.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BuildConfig {
    /// Bins per axis: 8, 16 or 32 (other values round up to one of these, at most 32).
    pub bins: usize,
    /// Largest leaf the SAH may choose; more primitives than this are always split.
    pub max_leaf_size: usize,
    /// Cost of visiting a node relative to intersecting one block of primitives.
    pub traversal_cost: f32,
    /// Nodes with at most this many primitives (at most 256) are split by a full SAH sweep
    /// (exact SAH over sorted centroids) instead of bins; 0 disables the sweep.
    pub sweep_threshold: usize,
    /// Primitives the traversal tests at once (4 for triangles, which leaves store in blocks of
    /// four): the SAH counts a leaf's cost in blocks, and a node with at most one block of
    /// primitives becomes a leaf.
    pub block_size: usize,
    /// Nodes with fewer primitives than this search splits along the widest axis of their
    /// centroids only (a third of the binning work); larger nodes search all three axes.
    pub widest_axis_below: usize,
}

impl BuildConfig {
    /// `PREFER_FAST_BUILD`: few bins.
    pub const FAST_BUILD: BuildConfig = BuildConfig {
        bins: 8,
        max_leaf_size: 8,
        traversal_cost: 1.0,
        sweep_threshold: 0,
        block_size: 4,
        widest_axis_below: usize::MAX,
    };
    /// The default trade-off.
    pub const BALANCED: BuildConfig = BuildConfig {
        bins: 16,
        max_leaf_size: 8,
        traversal_cost: 1.0,
        sweep_threshold: 0,
        block_size: 4,
        widest_axis_below: 1024,
    };
    /// `PREFER_FAST_TRACE`: more bins, and an exact SAH sweep near the leaves.
    pub const FAST_TRACE: BuildConfig = BuildConfig {
        bins: 32,
        max_leaf_size: 8,
        traversal_cost: 1.0,
        sweep_threshold: 32,
        block_size: 4,
        widest_axis_below: 0,
    };
}

/// Nodes with fewer primitives than this use 8 bins whatever the configuration.
pub(crate) const SMALL_NODE: usize = 64;
/// Largest node the exact sweep handles (its scratch lives on the stack).
const MAX_SWEEP: usize = 256;
/// Subtrees smaller than this are built on the current thread.
pub(crate) const PARALLEL_SUBTREE: usize = 1024;
/// Nodes larger than this bin their primitives in parallel chunks of this size.
pub(crate) const PARALLEL_BINNING: usize = 1 << 13;

/// A box with a fourth, unused lane, so that unions compile to `minps`/`maxps`.
#[repr(C, align(16))]
#[derive(Clone, Copy, Debug)]
pub(crate) struct Box4 {
    pub(crate) lo: [f32; 4],
    pub(crate) hi: [f32; 4],
}

impl Box4 {
    pub(crate) const EMPTY: Box4 = Box4 {
        lo: [f32::INFINITY; 4],
        hi: [f32::NEG_INFINITY; 4],
    };

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    pub(crate) fn grow(&mut self, o: &Box4) {
        use std::arch::x86_64::*;
        // SAFETY: SSE is part of the x86_64 baseline; `Box4` is `align(16)` and its rows are
        // `[f32; 4]`, so the loads and stores are aligned and in bounds. `minps(a, b)` returns `b`
        // when either is NaN, so NaN in `o` keeps `self`, as the portable form does.
        unsafe {
            let lo = _mm_min_ps(_mm_load_ps(o.lo.as_ptr()), _mm_load_ps(self.lo.as_ptr()));
            let hi = _mm_max_ps(_mm_load_ps(o.hi.as_ptr()), _mm_load_ps(self.hi.as_ptr()));
            _mm_store_ps(self.lo.as_mut_ptr(), lo);
            _mm_store_ps(self.hi.as_mut_ptr(), hi);
        }
    }

    #[cfg(not(target_arch = "x86_64"))]
    #[inline(always)]
    pub(crate) fn grow(&mut self, o: &Box4) {
        for i in 0..4 {
            self.lo[i] = if o.lo[i] < self.lo[i] {
                o.lo[i]
            } else {
                self.lo[i]
            };
            self.hi[i] = if o.hi[i] > self.hi[i] {
                o.hi[i]
            } else {
                self.hi[i]
            };
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    pub(crate) fn grow_point(&mut self, p: &[f32; 4]) {
        use std::arch::x86_64::*;
        // SAFETY: SSE is part of the x86_64 baseline; `Box4` is `align(16)`, `p` is loaded
        // unaligned. As in `grow`, a NaN in `p` keeps `self` (as the portable form does).
        unsafe {
            let q = _mm_loadu_ps(p.as_ptr());
            _mm_store_ps(
                self.lo.as_mut_ptr(),
                _mm_min_ps(q, _mm_load_ps(self.lo.as_ptr())),
            );
            _mm_store_ps(
                self.hi.as_mut_ptr(),
                _mm_max_ps(q, _mm_load_ps(self.hi.as_ptr())),
            );
        }
    }

    #[cfg(not(target_arch = "x86_64"))]
    #[inline(always)]
    pub(crate) fn grow_point(&mut self, p: &[f32; 4]) {
        for i in 0..4 {
            self.lo[i] = if p[i] < self.lo[i] { p[i] } else { self.lo[i] };
            self.hi[i] = if p[i] > self.hi[i] { p[i] } else { self.hi[i] };
        }
    }

    pub(crate) fn aabb(&self) -> Aabb {
        Aabb::new(
            [self.lo[0], self.lo[1], self.lo[2]].into(),
            [self.hi[0], self.hi[1], self.hi[2]].into(),
        )
    }

    /// [`Aabb::half_area`] of the box (0 for an empty one), computed as that does.
    pub(crate) fn half_area(&self) -> f32 {
        if (0..3).any(|i| self.hi[i] - self.lo[i] < 0.0) {
            return 0.0;
        }
        self.half_area_nonempty()
    }

    /// [`half_area`](Self::half_area) of a box known not to be empty, without the emptiness
    /// test or the conversion: the same operations in the same order, so the same bits. (Of an
    /// empty box it returns a meaningless value: callers only use it where a count says the
    /// box holds something.)
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn half_area_nonempty(&self) -> f32 {
        use std::arch::x86_64::*;
        // SAFETY: SSE is part of the x86_64 baseline; `Box4` is `align(16)`. The fourth lanes
        // (a bin's box carries the largest id's subnormal bits there) are masked off before
        // the subtraction: the compiler widened the portable form's three subtractions to four
        // lanes, and the subnormal operand's microcode assist made the SAH sweeps a third of
        // the build time.
        unsafe {
            let xyz = _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1));
            let e = _mm_sub_ps(
                _mm_and_ps(_mm_load_ps(self.hi.as_ptr()), xyz),
                _mm_and_ps(_mm_load_ps(self.lo.as_ptr()), xyz),
            );
            // (x y, y z, z x, 0), summed in the portable form's order.
            let p = _mm_mul_ps(e, _mm_shuffle_ps::<0b11_00_10_01>(e, e));
            let mut q = [0.0f32; 4];
            _mm_storeu_ps(q.as_mut_ptr(), p);
            q[0] + q[1] + q[2]
        }
    }

    #[cfg(not(target_arch = "x86_64"))]
    #[inline(always)]
    fn half_area_nonempty(&self) -> f32 {
        let e: [f32; 3] = std::array::from_fn(|i| self.hi[i] - self.lo[i]);
        e[0] * e[1] + e[1] * e[2] + e[2] * e[0]
    }
}

/// The builder's view of one primitive: its box, with the primitive's id in the bits of the
/// unused fourth lane of `hi` (ids are below 2^29, so those bits are a small finite float).
///
/// Below 2^23 those bits are a subnormal float, and x86 processors take a microcode assist of
/// a hundred cycles or more for every add or multiply with a subnormal operand: no arithmetic
/// may ever read the fourth lanes (min and max may, they take no assist). Reading them made
/// every binning and partition step ten times slower than it is.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PrimRef(pub(crate) Box4);

impl PrimRef {
    pub(crate) fn new(b: &Aabb, id: u32) -> Self {
        PrimRef(Box4 {
            lo: [b.min.x, b.min.y, b.min.z, 0.0],
            hi: [b.max.x, b.max.y, b.max.z, f32::from_bits(id)],
        })
    }

    #[inline(always)]
    pub(crate) fn id(&self) -> u32 {
        self.0.hi[3].to_bits()
    }

    /// Coordinate `axis` of [`centroid`](Self::centroid), alone (for sorts).
    #[inline(always)]
    pub(crate) fn centroid_on(&self, axis: usize) -> f32 {
        self.0.lo[axis] * 0.5 + self.0.hi[axis] * 0.5
    }

    /// The centroid; binning and partitioning both use this, so they agree bit for bit. The
    /// fourth lane is 0 (never the id's subnormal arithmetic, see the type's note).
    #[inline(always)]
    pub(crate) fn centroid(&self) -> [f32; 4] {
        let b = &self.0;
        std::array::from_fn(|i| {
            if i < 3 {
                b.lo[i] * 0.5 + b.hi[i] * 0.5
            } else {
                0.0
            }
        })
    }
}

/// Bytes of working memory [`build_bvh2`] allocates for `n` primitives, at most.
#[must_use]
pub fn temp_bytes(n: usize) -> usize {
    // Two reference arrays: binned splits partition from one into the other.
    2 * n * std::mem::size_of::<PrimRef>()
        + 2 * n.max(1) * std::mem::size_of::<Bvh2Node>()
        + n * std::mem::size_of::<u32>()
}

/// Builds a binary BVH over `bounds` (every box must be finite and valid).
#[must_use]
pub fn build_bvh2(bounds: &[Aabb], config: &BuildConfig) -> Bvh2 {
    build_bvh2_at(bounds, config, 0)
}

/// The configuration the builder works with: bins a power of two in 8..=32, sizes in range.
pub(crate) fn normalized(config: &BuildConfig) -> BuildConfig {
    BuildConfig {
        bins: config.bins.clamp(8, 32).next_power_of_two(),
        max_leaf_size: config.max_leaf_size.max(1),
        sweep_threshold: config.sweep_threshold.min(MAX_SWEEP),
        ..*config
    }
}

/// [`build_bvh2`] for a subtree whose root is at `depth` of a larger tree (the spatial-split
/// builder's subtrees), so that the depth bound holds for the whole tree.
pub(crate) fn build_bvh2_at(bounds: &[Aabb], config: &BuildConfig, depth: usize) -> Bvh2 {
    let config = normalized(config);
    let mut refs: Vec<PrimRef> = bounds
        .par_iter()
        .enumerate()
        .map(|(i, b)| PrimRef::new(b, i as u32))
        .collect();
    if refs.is_empty() {
        return Bvh2::default();
    }
    let (root_bounds, root_centroids) = reduce(&refs);
    // Node slots: the root, then the interior of its subtree (see `build_node`).
    // Zeroed memory from the allocator: pages under leaves are never even touched.
    let mut nodes: Vec<Bvh2Node> = bytemuck::allocation::zeroed_vec(2 * refs.len() - 1);
    // The other half of the ping-pong buffer of binned partitions; only its slots under
    // interior nodes are written before they are read.
    let mut scratch: Vec<PrimRef> = vec![PrimRef(Box4::EMPTY); refs.len()];
    let (root, interior) = nodes.split_at_mut(1);
    root[0] = build_node(
        Refs {
            cur: &mut refs,
            other: &mut scratch,
            flipped: false,
        },
        0,
        interior,
        1,
        root_bounds,
        root_centroids,
        depth,
        &config,
    );
    Bvh2 {
        nodes,
        prim_order: refs.iter().map(PrimRef::id).collect(),
    }
}

/// The box of the primitives and the box of their centroids.
pub(crate) fn reduce(refs: &[PrimRef]) -> (Box4, Box4) {
    let fold = |(mut b, mut c): (Box4, Box4), r: &PrimRef| {
        b.grow(&r.0);
        c.grow_point(&r.centroid());
        (b, c)
    };
    let empty = (Box4::EMPTY, Box4::EMPTY);
    if refs.len() > PARALLEL_BINNING {
        refs.par_chunks(PARALLEL_BINNING)
            .map(|c| c.iter().fold(empty, fold))
            .reduce(
                || empty,
                |(mut a, mut b), (c, d)| {
                    a.grow(&c);
                    b.grow(&d);
                    (a, b)
                },
            )
    } else {
        refs.iter().fold(empty, fold)
    }
}

/// A chosen split.
#[derive(Clone, Copy)]
pub(crate) enum Split {
    /// Left iff the bin of the centroid along `axis` is below `bin`.
    Binned {
        axis: usize,
        bin: usize,
        cmin: f32,
        scale: f32,
    },
    /// Sorted by centroid along `axis`, the first `count` go left.
    Sorted { axis: usize, count: usize },
    /// Object median along `axis` (or, with `axis == 3`, by position in the array).
    Median { axis: usize },
    /// The references are in order already: the first `count` go left.
    Ordered { count: usize },
}

#[inline(always)]
fn bin_of<const B: usize>(c: f32, cmin: f32, scale: f32) -> usize {
    // `as usize` saturates (and maps NaN to 0), so every centroid lands in a valid bin.
    (((c - cmin) * scale) as usize).min(B - 1)
}

/// The bins of a primitive's centroid on the three axes; equal, axis by axis, to [`bin_of`]
/// applied to [`PrimRef::centroid`] (same operations, and clamping before or after the
/// truncation gives the same integer).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn bin_indices<const B: usize>(r: &PrimRef, cmin: &[f32; 4], scale: &[f32; 4]) -> [usize; 4] {
    use std::arch::x86_64::*;
    // SAFETY: SSE2 is part of the x86_64 baseline; all pointers come from `[f32; 4]`/`[i32; 4]`
    // arrays (the `Box4` rows are 16-byte aligned; the others are loaded unaligned).
    unsafe {
        // Lane 3 of `half` is 0 and of `xyz` all ones: the fourth lanes (the id's subnormal
        // bits) are masked off before any arithmetic, which would otherwise take a microcode
        // assist (see `PrimRef`).
        let half = _mm_set_ps(0.0, 0.5, 0.5, 0.5);
        let xyz = _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1));
        let c = _mm_add_ps(
            _mm_mul_ps(_mm_and_ps(_mm_load_ps(r.0.lo.as_ptr()), xyz), half),
            _mm_mul_ps(_mm_and_ps(_mm_load_ps(r.0.hi.as_ptr()), xyz), half),
        );
        let f = _mm_mul_ps(
            _mm_sub_ps(c, _mm_loadu_ps(cmin.as_ptr())),
            _mm_loadu_ps(scale.as_ptr()),
        );
        // maxps returns the second operand (0) for NaN, as `as usize` maps NaN to 0.
        let f = _mm_min_ps(_mm_max_ps(f, _mm_setzero_ps()), _mm_set1_ps((B - 1) as f32));
        let mut out = [0i32; 4];
        _mm_storeu_si128(out.as_mut_ptr().cast(), _mm_cvttps_epi32(f));
        [out[0] as usize, out[1] as usize, out[2] as usize, 0]
    }
}

#[cfg(not(target_arch = "x86_64"))]
#[inline(always)]
fn bin_indices<const B: usize>(r: &PrimRef, cmin: &[f32; 4], scale: &[f32; 4]) -> [usize; 4] {
    let c = r.centroid();
    std::array::from_fn(|a| {
        if a < 3 {
            bin_of::<B>(c[a], cmin[a], scale[a])
        } else {
            0
        }
    })
}

/// Per axis and bin: the primitives' box and their count.
#[derive(Clone, Copy)]
struct Bins<const B: usize> {
    boxes: [[Box4; B]; 3],
    counts: [[u32; B]; 3],
}

impl<const B: usize> Bins<B> {
    fn new() -> Self {
        Bins {
            boxes: [[Box4::EMPTY; B]; 3],
            counts: [[0; B]; 3],
        }
    }

    fn merge(mut self, o: &Self) -> Self {
        for a in 0..3 {
            for b in 0..B {
                self.boxes[a][b].grow(&o.boxes[a][b]);
                self.counts[a][b] += o.counts[a][b];
            }
        }
        self
    }

    /// Bins every primitive on the searched axes at once. In large nodes, even and odd
    /// primitives go to separate bin sets, merged at the end, so that consecutive primitives
    /// falling in the same bin do not wait on each other's stores; small nodes are not worth
    /// a second set. (Boxes merge by min and max and counts by integer sums, so the bins are
    /// the same either way.)
    fn fill(refs: &[PrimRef], cmin: &[f32; 4], scale: &[f32; 4]) -> Self {
        let active: [bool; 3] = std::array::from_fn(|a| scale[a] != 0.0);
        let add = |bins: &mut Self, r: &PrimRef| {
            let idx = bin_indices::<B>(r, cmin, scale);
            for axis in 0..3 {
                // Axes without extent (or not searched) take no part.
                if active[axis] {
                    let i = idx[axis];
                    bins.boxes[axis][i].grow(&r.0);
                    bins.counts[axis][i] += 1;
                }
            }
        };
        let mut even = Self::new();
        if refs.len() < TWO_BIN_SETS {
            for r in refs {
                add(&mut even, r);
            }
            return even;
        }
        let mut odd = Self::new();
        let mut pairs = refs.chunks_exact(2);
        for pair in &mut pairs {
            add(&mut even, &pair[0]);
            add(&mut odd, &pair[1]);
        }
        if let [last] = pairs.remainder() {
            add(&mut even, last);
        }
        even.merge(&odd)
    }
}

/// Nodes with at least this many primitives bin into two sets of bins (see [`Bins::fill`]).
const TWO_BIN_SETS: usize = 256;

/// The boxes of the two sides of a split.
#[derive(Clone, Copy)]
struct Sides {
    bounds: [Box4; 2],
    centroids: [Box4; 2],
}

/// Returns the best binned split, its SAH cost (area-weighted primitive count, not yet divided
/// by the parent's area) and the boxes of its sides (the centroid boxes are filled in by the
/// partition).
pub(crate) fn best_binned_split<const B: usize>(
    refs: &[PrimRef],
    cb: &Box4,
    block: usize,
    widest_axis_only: bool,
) -> Option<(Split, f32, [Box4; 2])> {
    best_binned_split_counted::<B>(refs, cb, block, widest_axis_only)
        .map(|(split, cost, sides, _)| (split, cost, sides))
}

/// [`best_binned_split`], also returning how many primitives go left (always some, never all).
fn best_binned_split_counted<const B: usize>(
    refs: &[PrimRef],
    cb: &Box4,
    block: usize,
    widest_axis_only: bool,
) -> Option<(Split, f32, [Box4; 2], usize)> {
    let mut scale = [0.0f32; 4];
    let widest = widest_axis(cb);
    for axis in 0..3 {
        let e = cb.hi[axis] - cb.lo[axis];
        let s = B as f32 * (1.0 - 1e-6) / e;
        let searched = !widest_axis_only || axis == widest;
        scale[axis] = if searched && e > 0.0 && s.is_finite() {
            s
        } else {
            0.0
        };
    }
    if scale == [0.0; 4] {
        return None;
    }
    let bins = if refs.len() > PARALLEL_BINNING {
        refs.par_chunks(PARALLEL_BINNING)
            .map(|c| Bins::<B>::fill(c, &cb.lo, &scale))
            .reduce(Bins::new, |a, b| a.merge(&b))
    } else {
        Bins::<B>::fill(refs, &cb.lo, &scale)
    };
    let mut best: Option<(usize, usize, f32)> = None;
    for axis in 0..3 {
        if scale[axis] == 0.0 {
            continue;
        }
        // Sweep from the right for right-side areas and counts, then from the left.
        // Areas are taken only of sides that hold primitives (`half_area_nonempty`).
        let mut right_area = [0.0f32; B];
        let mut right_count = [0u32; B];
        let mut acc = Box4::EMPTY;
        let mut n = 0u32;
        for i in (1..B).rev() {
            acc.grow(&bins.boxes[axis][i]);
            n += bins.counts[axis][i];
            right_area[i] = acc.half_area_nonempty();
            right_count[i] = n;
        }
        let mut acc = Box4::EMPTY;
        let mut n = 0u32;
        for i in 1..B {
            acc.grow(&bins.boxes[axis][i - 1]);
            n += bins.counts[axis][i - 1];
            if n == 0 || right_count[i] == 0 {
                continue;
            }
            let cost = acc.half_area_nonempty() * n.div_ceil(block as u32) as f32
                + right_area[i] * right_count[i].div_ceil(block as u32) as f32;
            if cost.is_finite() && best.is_none_or(|(_, _, c)| cost < c) {
                best = Some((axis, i, cost));
            }
        }
    }
    let (axis, bin, cost) = best?;
    let side = |r: std::ops::Range<usize>| {
        bins.boxes[axis][r].iter().fold(Box4::EMPTY, |mut a, b| {
            a.grow(b);
            a
        })
    };
    let split = Split::Binned {
        axis,
        bin,
        cmin: cb.lo[axis],
        scale: scale[axis],
    };
    let left = bins.counts[axis][..bin].iter().sum::<u32>() as usize;
    Some((split, cost, [side(0..bin), side(bin..B)], left))
}

/// The axis along which a box is widest.
pub(crate) fn widest_axis(b: &Box4) -> usize {
    let e = [b.hi[0] - b.lo[0], b.hi[1] - b.lo[1], b.hi[2] - b.lo[2]];
    if e[0] >= e[1] && e[0] >= e[2] {
        0
    } else if e[1] >= e[2] {
        1
    } else {
        2
    }
}

/// The split of a node of at most two blocks: sorted along the widest centroid axis, one full
/// block on the left.
pub(crate) fn small_split(refs: &mut [PrimRef], cb: &Box4, block: usize) -> Option<(Split, f32)> {
    let e = [
        cb.hi[0] - cb.lo[0],
        cb.hi[1] - cb.lo[1],
        cb.hi[2] - cb.lo[2],
    ];
    let axis = if e[0] >= e[1] && e[0] >= e[2] {
        0
    } else if e[1] >= e[2] {
        1
    } else {
        2
    };
    sort_by_centroid(refs, axis);
    let side = |r: &[PrimRef]| {
        r.iter().fold(Box4::EMPTY, |mut a, p| {
            a.grow(&p.0);
            a
        })
    };
    let n = refs.len();
    let cost = side(&refs[..block]).half_area_nonempty()
        + side(&refs[block..]).half_area_nonempty() * (n - block).div_ceil(block) as f32;
    cost.is_finite()
        .then_some((Split::Sorted { axis, count: block }, cost))
}

/// How close to a face of its node's box, relative to the box's extent across the face, a
/// primitive's box must lie for [`face_split`] (modelled rooms are rarely square to a
/// thousandth: the Cornell data's walls lean by about 1 %).
const FACE_SLAB: f32 = 1.0 / 32.0;

/// The split that takes the primitives lying in one face of the node's box (boxes within
/// [`FACE_SLAB`] of the box's extent from that face: a room's wall, floor or ceiling) away
/// from the others, if any: the first such face along x, y, z, low face before high.
///
/// The builders call it where the surface-area heuristic chose a leaf. The heuristic prices a
/// node by its box's area, which is right for rays from outside it; but rays that start
/// inside a room (every bounce of a path in it) enter the room-spanning box of a leaf of
/// several walls whatever its area, and test every wall in it, where walls in leaves of their
/// own have flat boxes that most rays pass by. Peeling the faces' primitives off one face at a
/// time gives each wall its own leaf. Scanned and smooth meshes have no primitives exactly in
/// a face of their leaves' boxes, and keep their trees.
pub(crate) fn face_split(refs: &mut [PrimRef], bounds: &Box4) -> Option<Split> {
    let n = refs.len();
    for axis in 0..3 {
        let (lo, hi) = (bounds.lo[axis], bounds.hi[axis]);
        let slab = (hi - lo) * FACE_SLAB;
        if slab.is_nan() || slab <= 0.0 {
            continue;
        }
        for high in [false, true] {
            let in_face = |r: &PrimRef| match high {
                false => r.0.hi[axis] <= lo + slab,
                true => r.0.lo[axis] >= hi - slab,
            };
            let count = refs.iter().filter(|r| in_face(r)).count();
            if count > 0 && count < n {
                // A stable order (the face's references first), so the tree stays the same
                // whatever the thread count.
                refs.sort_by_key(|r| !in_face(r));
                return Some(Split::Ordered { count });
            }
        }
    }
    None
}

/// Exact SAH: sorts along each axis and evaluates every split position.
pub(crate) fn best_sweep_split(refs: &mut [PrimRef], block: usize) -> Option<(Split, f32)> {
    let n = refs.len();
    let mut right_area = [0.0f32; MAX_SWEEP];
    let mut best: Option<(Split, f32)> = None;
    for axis in 0..3 {
        sort_by_centroid(refs, axis);
        let mut acc = Box4::EMPTY;
        for i in (1..n).rev() {
            acc.grow(&refs[i].0);
            right_area[i] = acc.half_area_nonempty();
        }
        let mut acc = Box4::EMPTY;
        for i in 1..n {
            acc.grow(&refs[i - 1].0);
            let cost = acc.half_area_nonempty() * i.div_ceil(block) as f32
                + right_area[i] * (n - i).div_ceil(block) as f32;
            if cost.is_finite() && best.is_none_or(|(_, c)| cost < c) {
                best = Some((Split::Sorted { axis, count: i }, cost));
            }
        }
    }
    best
}

fn sort_by_centroid(refs: &mut [PrimRef], axis: usize) {
    // Ties are broken by id so that the order (and the tree) is fully determined.
    refs.sort_unstable_by(|a, b| {
        a.centroid_on(axis)
            .total_cmp(&b.centroid_on(axis))
            .then(a.id().cmp(&b.id()))
    });
}

/// Applies a split; returns how many primitives went left and, for a binned split, the boxes of
/// the sides' centroids.
pub(crate) fn partition<const B: usize>(
    refs: &mut [PrimRef],
    split: Split,
) -> (usize, Option<[Box4; 2]>) {
    match split {
        Split::Binned {
            axis,
            bin,
            cmin,
            scale,
        } => {
            let mut cl = Box4::EMPTY;
            let mut cr = Box4::EMPTY;
            let mut i = 0;
            let mut j = refs.len();
            while i < j {
                let c = refs[i].centroid();
                if bin_of::<B>(c[axis], cmin, scale) < bin {
                    cl.grow_point(&c);
                    i += 1;
                } else {
                    cr.grow_point(&c);
                    j -= 1;
                    refs.swap(i, j);
                }
            }
            (i, Some([cl, cr]))
        }
        Split::Sorted { axis, count } => {
            sort_by_centroid(refs, axis);
            (count, None)
        }
        Split::Ordered { count } => (count, None),
        Split::Median { axis } => {
            let mid = refs.len() / 2;
            if axis < 3 {
                refs.select_nth_unstable_by(mid, |a, b| {
                    a.centroid_on(axis)
                        .total_cmp(&b.centroid_on(axis))
                        .then(a.id().cmp(&b.id()))
                });
            }
            (mid, None)
        }
    }
}

/// Chunks of at most this many primitives are partitioned in parallel (nodes larger than
/// [`PARALLEL_BINNING`]); fixed, so the result does not depend on the thread count.
const PARTITION_CHUNK: usize = PARALLEL_BINNING;

/// Moves `src` into `left` (centroids in bins below `bin` along `axis`) and `right` (the rest),
/// each in `src`'s order, and returns the boxes of the two sides' centroids. The lengths of
/// `left` and `right` must be the two sides' counts.
///
/// Without a branch on the side: a sorted or clustered mesh sends long, irregular runs of
/// primitives to either side, which a branch predictor guesses badly. The side is one float
/// comparison: `bin_of(c) >= bin` holds exactly when `(c - cmin) * scale >= bin` (for `bin` in
/// `1..B`: the truncation of a value is at least an integer iff the value is, and a negative
/// or NaN value bins to 0).
#[cfg(target_arch = "x86_64")]
fn scatter<const B: usize>(
    src: &[PrimRef],
    left: &mut [PrimRef],
    right: &mut [PrimRef],
    axis: usize,
    bin: usize,
    cmin: f32,
    scale: f32,
) -> [Box4; 2] {
    use std::arch::x86_64::*;
    debug_assert!((1..B).contains(&bin) && axis < 3);
    let threshold = bin as f32;
    let (mut at_left, mut at_right) = (0usize, 0usize);
    // SAFETY: SSE2 is part of the x86_64 baseline. `Box4` rows are 16-byte aligned `[f32; 4]`
    // (aligned loads and stores). Every write goes to `left[at_left]` or `right[at_right]`
    // after checking that index against the slice's length.
    unsafe {
        let half = _mm_set_ps(0.0, 0.5, 0.5, 0.5);
        let xyz = _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1));
        let inf = _mm_set1_ps(f32::INFINITY);
        let ninf = _mm_set1_ps(f32::NEG_INFINITY);
        let (mut l_lo, mut l_hi, mut r_lo, mut r_hi) = (inf, ninf, inf, ninf);
        for r in src {
            let lo = _mm_load_ps(r.0.lo.as_ptr());
            let hi = _mm_load_ps(r.0.hi.as_ptr());
            // `PrimRef::centroid`'s operations (the fourth lane masked to 0).
            let c = _mm_add_ps(
                _mm_mul_ps(_mm_and_ps(lo, xyz), half),
                _mm_mul_ps(_mm_and_ps(hi, xyz), half),
            );
            let right_side = (r.centroid_on(axis) - cmin) * scale >= threshold;
            if right_side {
                if at_right >= right.len() {
                    break;
                }
            } else if at_left >= left.len() {
                break;
            }
            let dst = if right_side {
                right.as_mut_ptr().add(at_right)
            } else {
                left.as_mut_ptr().add(at_left)
            };
            *dst = *r;
            at_right += usize::from(right_side);
            at_left += usize::from(!right_side);
            // Each side's centroid box grows by the centroid or by an empty point (`minps` and
            // `maxps` keep the accumulator for a NaN lane, as `Box4::grow_point` does).
            let m = _mm_castsi128_ps(_mm_set1_epi32(-i32::from(right_side)));
            let on_right_lo = _mm_or_ps(_mm_and_ps(m, c), _mm_andnot_ps(m, inf));
            let on_right_hi = _mm_or_ps(_mm_and_ps(m, c), _mm_andnot_ps(m, ninf));
            let on_left_lo = _mm_or_ps(_mm_andnot_ps(m, c), _mm_and_ps(m, inf));
            let on_left_hi = _mm_or_ps(_mm_andnot_ps(m, c), _mm_and_ps(m, ninf));
            r_lo = _mm_min_ps(on_right_lo, r_lo);
            r_hi = _mm_max_ps(on_right_hi, r_hi);
            l_lo = _mm_min_ps(on_left_lo, l_lo);
            l_hi = _mm_max_ps(on_left_hi, l_hi);
        }
        debug_assert_eq!([at_left, at_right], [left.len(), right.len()]);
        let mut cb = [Box4::EMPTY; 2];
        _mm_store_ps(cb[0].lo.as_mut_ptr(), l_lo);
        _mm_store_ps(cb[0].hi.as_mut_ptr(), l_hi);
        _mm_store_ps(cb[1].lo.as_mut_ptr(), r_lo);
        _mm_store_ps(cb[1].hi.as_mut_ptr(), r_hi);
        cb
    }
}

/// The portable form of the SIMD `scatter` (the reference its test compares with).
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
fn scatter_portable<const B: usize>(
    src: &[PrimRef],
    left: &mut [PrimRef],
    right: &mut [PrimRef],
    axis: usize,
    bin: usize,
    cmin: f32,
    scale: f32,
) -> [Box4; 2] {
    let out = [left, right];
    let mut at = [0usize; 2];
    let mut cb = [Box4::EMPTY; 2];
    for r in src {
        let c = r.centroid();
        let side = (bin_of::<B>(c[axis], cmin, scale) >= bin) as usize;
        out[side][at[side]] = *r;
        at[side] += 1;
        cb[side].grow_point(&c);
    }
    debug_assert_eq!([at[0], at[1]], [out[0].len(), out[1].len()]);
    cb
}

#[cfg(not(target_arch = "x86_64"))]
use self::scatter_portable as scatter;

/// Applies a binned split by moving `src` into `dst`, left side first, `left` primitives on it
/// (as the bins counted); each side keeps `src`'s order, so the result is the same however
/// the work is divided. Returns the boxes of the sides' centroids. Large nodes are partitioned
/// in parallel chunks: each chunk counts its left side, and the counts' prefix sums give each
/// chunk its own ranges of `dst`.
fn partition_into<const B: usize>(
    src: &[PrimRef],
    dst: &mut [PrimRef],
    left: usize,
    split: Split,
) -> [Box4; 2] {
    let Split::Binned {
        axis,
        bin,
        cmin,
        scale,
    } = split
    else {
        unreachable!("only binned splits partition into the other buffer")
    };
    let (dl, dr) = dst.split_at_mut(left);
    if src.len() <= PARALLEL_BINNING {
        return scatter::<B>(src, dl, dr, axis, bin, cmin, scale);
    }
    let lefts: Vec<usize> = src
        .par_chunks(PARTITION_CHUNK)
        .map(|c| {
            c.iter()
                .filter(|r| bin_of::<B>(r.centroid_on(axis), cmin, scale) < bin)
                .count()
        })
        .collect();
    // One (source, left range, right range) per chunk: one small vector per large node.
    let mut jobs = Vec::with_capacity(lefts.len());
    let (mut dl, mut dr) = (dl, dr);
    for (c, &l) in src.chunks(PARTITION_CHUNK).zip(&lefts) {
        let (a, rest_l) = std::mem::take(&mut dl).split_at_mut(l);
        let (b, rest_r) = std::mem::take(&mut dr).split_at_mut(c.len() - l);
        dl = rest_l;
        dr = rest_r;
        jobs.push((c, a, b));
    }
    jobs.into_par_iter()
        .map(|(c, a, b)| scatter::<B>(c, a, b, axis, bin, cmin, scale))
        .collect::<Vec<_>>()
        .iter()
        .fold([Box4::EMPTY; 2], |mut acc, s| {
            acc[0].grow(&s[0]);
            acc[1].grow(&s[1]);
            acc
        })
}

/// A node's primitive references: `cur` holds them, `other` is the same range of the other
/// half of the ping-pong buffer (`flipped`: `cur` is in the scratch half, whose contents the
/// tree's leaves must copy back to the main half).
struct Refs<'a> {
    cur: &'a mut [PrimRef],
    other: &'a mut [PrimRef],
    flipped: bool,
}

impl<'a> Refs<'a> {
    /// The references of the first `mid` and of the remaining primitives.
    fn split_at(self, mid: usize) -> (Refs<'a>, Refs<'a>) {
        let (cl, cr) = self.cur.split_at_mut(mid);
        let (ol, or) = self.other.split_at_mut(mid);
        (
            Refs {
                cur: cl,
                other: ol,
                flipped: self.flipped,
            },
            Refs {
                cur: cr,
                other: or,
                flipped: self.flipped,
            },
        )
    }

    /// The same references after a partition from `cur` into `other`.
    fn swapped(self) -> Refs<'a> {
        Refs {
            cur: self.other,
            other: self.cur,
            flipped: !self.flipped,
        }
    }

    /// Puts the references of a leaf where the tree's primitive order is read from.
    fn settle(self) {
        if self.flipped {
            self.other.copy_from_slice(self.cur);
        }
    }
}

/// Builds the subtree over `refs` (primitive slots `offset..offset + refs.len()`) and returns its
/// root node.
///
/// Node slots are assigned without coordination, so subtrees can be built in parallel and the
/// layout does not depend on scheduling: the subtree over `n` primitives owns the `2n - 2` slots of
/// `interior` (global index `base`); a split after `m` primitives puts the left subtree's interior
/// first (`2m - 2` slots), then the pair of children, then the right subtree's interior. Slots
/// under leaves stay unused.
#[allow(clippy::too_many_arguments)]
fn build_node(
    refs: Refs<'_>,
    offset: usize,
    interior: &mut [Bvh2Node],
    base: usize,
    bounds: Box4,
    cb: Box4,
    depth: usize,
    config: &BuildConfig,
) -> Bvh2Node {
    // Small nodes bin coarsely: their few primitives cannot use many bins, and each bin costs.
    let bins = if refs.cur.len() < SMALL_NODE {
        8
    } else {
        config.bins
    };
    match bins {
        8 => build_node_b::<8>(refs, offset, interior, base, bounds, cb, depth, config),
        16 => build_node_b::<16>(refs, offset, interior, base, bounds, cb, depth, config),
        _ => build_node_b::<32>(refs, offset, interior, base, bounds, cb, depth, config),
    }
}

#[allow(clippy::too_many_arguments)]
fn build_node_b<const B: usize>(
    refs: Refs<'_>,
    offset: usize,
    interior: &mut [Bvh2Node],
    base: usize,
    bounds: Box4,
    cb: Box4,
    depth: usize,
    config: &BuildConfig,
) -> Bvh2Node {
    let n = refs.cur.len();
    let aabb = bounds.aabb();
    let leaf = Bvh2Node {
        min: aabb.min.to_array(),
        left_first: offset as u32,
        max: aabb.max.to_array(),
        count: n as u32,
    };
    if n <= 1 {
        refs.settle();
        return leaf;
    }
    let blocks = |k: usize| k.div_ceil(config.block_size.max(1)) as f32;
    let mut side_bounds = None;
    let block = config.block_size.max(1);
    // The split the surface-area heuristic chooses, `None` where it keeps a leaf (a node of at
    // most one block always).
    let chosen = if n <= block && depth < FORCE_MEDIAN_DEPTH {
        None
    } else {
        let found = if depth >= FORCE_MEDIAN_DEPTH {
            None
        } else if n <= 2 * block && n <= config.max_leaf_size && n > config.sweep_threshold {
            // At most two blocks: the only split worth a node puts one full block on one side.
            small_split(refs.cur, &cb, block)
        } else if n <= config.sweep_threshold {
            best_sweep_split(refs.cur, block)
        } else {
            best_binned_split_counted::<B>(refs.cur, &cb, block, n < config.widest_axis_below).map(
                |(split, cost, sides, left)| {
                    side_bounds = Some((sides, left));
                    (split, cost)
                },
            )
        };
        match found {
            Some((split, cost)) => {
                // SAH in units of one block test, relative to this node's area.
                let split_cost = config.traversal_cost + cost / bounds.half_area();
                let leaf_wins = blocks(n) <= split_cost || !split_cost.is_finite();
                (n > config.max_leaf_size || !leaf_wins).then_some(split)
            }
            None if n <= config.max_leaf_size && depth < FORCE_MEDIAN_DEPTH => None,
            None => {
                let axis = widest_axis(&cb);
                Some(Split::Median {
                    axis: if cb.hi[axis] - cb.lo[axis] > 0.0 {
                        axis
                    } else {
                        3
                    },
                })
            }
        }
    };
    let split = match chosen {
        Some(split) => split,
        // Where the heuristic keeps a leaf, a room's walls are still split apart.
        None => match face_split(refs.cur, &bounds) {
            Some(face) => {
                // The references are ordered for it, not moved by a binned split.
                side_bounds = None;
                face
            }
            None => {
                refs.settle();
                return leaf;
            }
        },
    };
    // A binned split moves the references into the other buffer (its bins counted the left
    // side, which is never empty nor everything); the others sort in place.
    let (refs, mut mid, mut sides) = match side_bounds {
        Some((bounds, left)) => {
            let centroids = partition_into::<B>(refs.cur, refs.other, left, split);
            (refs.swapped(), left, Some(Sides { bounds, centroids }))
        }
        None => {
            let mid = partition::<B>(refs.cur, split).0;
            (refs, mid, None)
        }
    };
    if mid == 0 || mid == n {
        // Only reachable with non-finite arithmetic; any split keeps the tree correct.
        mid = n / 2;
        sides = None;
    }
    let (l, r) = refs.split_at(mid);
    let parallel = n > PARALLEL_SUBTREE;
    let sides = sides.unwrap_or_else(|| {
        let ((lb, lc), (rb, rc)) = if parallel {
            rayon::join(|| reduce(l.cur), || reduce(r.cur))
        } else {
            (reduce(l.cur), reduce(r.cur))
        };
        Sides {
            bounds: [lb, rb],
            centroids: [lc, rc],
        }
    });
    let Sides {
        bounds: [lb, rb],
        centroids: [lc, rc],
    } = sides;
    let (left_interior, rest) = interior.split_at_mut(2 * mid - 2);
    let (pair, right_interior) = rest.split_at_mut(2);
    let pair_index = base + 2 * mid - 2;
    let right_base = pair_index + 2;
    let (left, right) = if parallel {
        rayon::join(
            || build_node(l, offset, left_interior, base, lb, lc, depth + 1, config),
            || {
                build_node(
                    r,
                    offset + mid,
                    right_interior,
                    right_base,
                    rb,
                    rc,
                    depth + 1,
                    config,
                )
            },
        )
    } else {
        (
            build_node(l, offset, left_interior, base, lb, lc, depth + 1, config),
            build_node(
                r,
                offset + mid,
                right_interior,
                right_base,
                rb,
                rc,
                depth + 1,
                config,
            ),
        )
    };
    pair[0] = left;
    pair[1] = right;
    Bvh2Node {
        count: 0,
        left_first: pair_index as u32,
        ..leaf
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// Boxes of a clustered scene: dense clumps (many equal bins and long runs to one side
    /// of a split), long slivers and some exact duplicates (ties broken by id).
    fn clustered_boxes(n: usize) -> Vec<Aabb> {
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        (0..n)
            .map(|i| {
                let clump = Vec3::new((i % 7) as f32 * 10.0, (i % 3) as f32 * 10.0, 0.0);
                let p = clump + Vec3::new(next(), next(), next()) * 2.0;
                let size = if i % 11 == 0 {
                    Vec3::new(5.0 * next(), 0.01, 0.01)
                } else {
                    Vec3::splat(0.05 * next())
                };
                if i % 97 == 0 {
                    Aabb::new(Vec3::ONE, Vec3::splat(1.5))
                } else {
                    Aabb::new(p, p + size)
                }
            })
            .collect()
    }

    /// The SIMD partition moves every primitive where the portable one does and gives the
    /// same centroid boxes, bit for bit, for every bin count, axis and split bin.
    type ScatterFn =
        fn(&[PrimRef], &mut [PrimRef], &mut [PrimRef], usize, usize, f32, f32) -> [Box4; 2];

    #[test]
    fn the_simd_scatter_is_the_portable_one() {
        fn check<const B: usize>(refs: &[PrimRef]) {
            let (_, cb) = reduce(refs);
            for axis in 0..3 {
                let e = cb.hi[axis] - cb.lo[axis];
                let scale = B as f32 * (1.0 - 1e-6) / e;
                for bin in 1..B {
                    let left = refs
                        .iter()
                        .filter(|r| bin_of::<B>(r.centroid_on(axis), cb.lo[axis], scale) < bin)
                        .count();
                    let run = |f: ScatterFn| {
                        let mut dst = vec![PrimRef(Box4::EMPTY); refs.len()];
                        let (l, r) = dst.split_at_mut(left);
                        let boxes = f(refs, l, r, axis, bin, cb.lo[axis], scale);
                        let ids: Vec<u32> = dst.iter().map(PrimRef::id).collect();
                        let bits = boxes.map(|b| [b.lo, b.hi].map(|row| row.map(f32::to_bits)));
                        (ids, bits)
                    };
                    assert_eq!(
                        run(scatter::<B>),
                        run(scatter_portable::<B>),
                        "{B} bins, axis {axis}, bin {bin}"
                    );
                }
            }
        }
        let refs: Vec<PrimRef> = clustered_boxes(3000)
            .iter()
            .enumerate()
            .map(|(i, b)| PrimRef::new(b, i as u32))
            .collect();
        check::<8>(&refs);
        check::<16>(&refs);
        check::<32>(&refs);
        // One side empty of centroids on an axis: a flat set.
        let flat: Vec<PrimRef> = (0..100)
            .map(|i| {
                let p = Vec3::new(i as f32, 2.0, 3.0);
                PrimRef::new(&Aabb::new(p, p + Vec3::new(0.5, 0.0, 0.0)), i)
            })
            .collect();
        check::<8>(&flat[..]);
        // Centroids exactly on bin boundaries (a grid of step 1 from 0), where `>=` and `>`
        // part ways.
        let grid: Vec<PrimRef> = (0..64u32)
            .map(|i| {
                let p = Vec3::splat((i % 32) as f32);
                PrimRef::new(&Aabb::new(p, p), i)
            })
            .collect();
        for bin in 1..32 {
            let left = grid
                .iter()
                .filter(|r| r.centroid_on(0) < bin as f32)
                .count();
            let run = |f: ScatterFn| {
                let mut dst = vec![PrimRef(Box4::EMPTY); grid.len()];
                let (l, r) = dst.split_at_mut(left);
                let boxes = f(&grid, l, r, 0, bin, 0.0, 1.0);
                let ids: Vec<u32> = dst.iter().map(PrimRef::id).collect();
                (
                    ids,
                    boxes.map(|b| [b.lo, b.hi].map(|row| row.map(f32::to_bits))),
                )
            };
            assert_eq!(run(scatter::<32>), run(scatter_portable::<32>), "bin {bin}");
        }
    }

    /// Checks that the tree holds every primitive once, that every box holds what is below it
    /// and that the depth is within the bound; returns the depth.
    fn check_tree(t: &Bvh2, bounds: &[Aabb]) -> usize {
        let mut seen = vec![false; bounds.len()];
        for &p in &t.prim_order {
            assert!(!std::mem::replace(&mut seen[p as usize], true), "{p} twice");
        }
        assert!(seen.iter().all(|&s| s), "a primitive is missing");
        let mut deepest = 0;
        let mut stack = vec![(0usize, 0usize)];
        while let Some((i, depth)) = stack.pop() {
            deepest = deepest.max(depth);
            let n = &t.nodes[i];
            let b = n.bounds();
            let inside = |c: &Aabb| b.union(c) == b;
            if n.is_leaf() {
                let slots = n.left_first as usize..(n.left_first + n.count) as usize;
                for s in slots {
                    assert!(inside(&bounds[t.prim_order[s] as usize]), "leaf {i}");
                }
            } else {
                for c in [n.left_first as usize, n.left_first as usize + 1] {
                    // (Children may sit before their parent: see `build_node`'s slots.)
                    assert!(inside(&t.nodes[c].bounds()), "node {i}");
                    stack.push((c, depth + 1));
                }
            }
        }
        assert!(deepest <= crate::MAX_BVH2_DEPTH);
        deepest
    }

    #[test]
    fn binned_builds_are_valid_and_the_same_whatever_the_thread_count() {
        // Over 8,192 primitives: the top nodes bin and partition in parallel chunks, and
        // subtrees over 1,024 are built as parallel tasks.
        let bounds = clustered_boxes(40_000);
        for config in [
            BuildConfig::FAST_BUILD,
            BuildConfig::BALANCED,
            BuildConfig::FAST_TRACE,
        ] {
            let build = |threads: usize| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap()
                    .install(|| build_bvh2(&bounds, &config))
            };
            let one = build(1);
            check_tree(&one, &bounds);
            for threads in [2, 3, 8] {
                let other = build(threads);
                assert!(one.nodes == other.nodes, "{config:?}, {threads} threads");
                assert_eq!(one.prim_order, other.prim_order, "{config:?}, {threads}");
            }
        }
    }

    #[test]
    fn the_parallel_partition_matches_a_sequential_one() {
        // One split of a large node, partitioned in parallel chunks and in one piece: the same
        // order (each side keeps the input order) and the same centroid boxes.
        let bounds = clustered_boxes(3 * PARTITION_CHUNK + 123);
        let refs: Vec<PrimRef> = bounds
            .iter()
            .enumerate()
            .map(|(i, b)| PrimRef::new(b, i as u32))
            .collect();
        let (_, cb) = reduce(&refs);
        let (split, _, _, left) = best_binned_split_counted::<16>(&refs, &cb, 4, false).unwrap();
        let mut parallel = vec![PrimRef(Box4::EMPTY); refs.len()];
        let pc = partition_into::<16>(&refs, &mut parallel, left, split);
        let mut sequential = vec![PrimRef(Box4::EMPTY); refs.len()];
        let Split::Binned {
            axis,
            bin,
            cmin,
            scale,
        } = split
        else {
            panic!("a binned split")
        };
        let (l, r) = sequential.split_at_mut(left);
        let sc = scatter::<16>(&refs, l, r, axis, bin, cmin, scale);
        let ids = |v: &[PrimRef]| v.iter().map(PrimRef::id).collect::<Vec<_>>();
        assert_eq!(ids(&parallel), ids(&sequential));
        let expected: Vec<u32> = {
            let side = |r: &PrimRef| bin_of::<16>(r.centroid()[axis], cmin, scale) >= bin;
            let mut v: Vec<u32> = refs.iter().filter(|r| !side(r)).map(PrimRef::id).collect();
            v.extend(refs.iter().filter(|r| side(r)).map(PrimRef::id));
            v
        };
        assert_eq!(ids(&sequential), expected);
        for k in 0..2 {
            assert_eq!((pc[k].lo, pc[k].hi), (sc[k].lo, sc[k].hi));
        }
    }
}
