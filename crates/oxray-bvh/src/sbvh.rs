//! Spatial splits for triangle BVHs (SBVH: Stich, Friedrich and Dietrich, "Spatial Splits in
//! Bounding Volume Hierarchies", HPG 2009).
//!
//! At every node the builder compares the best binned object split (as [`build_bvh2`](crate::build_bvh2)) with
//! the best *spatial* split: the node's box is cut into slabs along an axis, each triangle is
//! chopped at the slab planes and each piece's box (the triangle clipped to the slab, within
//! the reference's box) goes into its slab. A triangle that straddles the chosen plane is then
//! referenced from both sides, each time with the box of its part on that side, so that
//! children overlap less. Spatial splits are only tried where the object split's children
//! overlap by more than [`SpatialSplits::alpha`] of the root's area, and only while the node's
//! share of the split budget lasts: at most [`SpatialSplits::budget`] more references than
//! triangles over the whole tree, the rest of a node's share going to its children in
//! proportion to their references. Where a node's share is spent, its subtree is built by
//! [`build_bvh2`](crate::build_bvh2)'s binned builder over the references' boxes.
//!
//! A leaf may thus hold a triangle that another leaf holds too: a ray can meet the same
//! triangle twice. Hits are the same (the same triangle test on the same vertices), but an
//! any-hit program may run twice for one primitive, which guide §5.1 allows by default and
//! `REQUIRE_SINGLE_ANYHIT_CALL` forbids (the primitives of such records are never split, see
//! [`GasData::build`](crate::GasData::build)).
//!
//! Deterministic: every decision depends only on the node's references (binning reduces with
//! min, max and integer sums; budgets are split by integer arithmetic), and the tree is laid
//! out after it is built, depth first; so it is bit-identical whatever the number of threads.

use crate::build::{
    best_binned_split, best_sweep_split, build_bvh2_at, normalized, partition, reduce, small_split,
    widest_axis, Box4, BuildConfig, PrimRef, Split, PARALLEL_BINNING, PARALLEL_SUBTREE, SMALL_NODE,
};
use crate::bvh2::{Bvh2, Bvh2Node};
use crate::FORCE_MEDIAN_DEPTH;
use glam::Vec3;
use oxray_core::Aabb;
use rayon::prelude::*;

/// How much a build may split (see the module's documentation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpatialSplits {
    /// More references than triangles the whole tree may hold, as a fraction of the triangles
    /// (0.3: at most 30 % more).
    pub budget: f32,
    /// Spatial splits are tried at a node only where its object split's children overlap by
    /// more than this fraction of the root's surface area (Stich et al.'s α).
    pub alpha: f32,
}

impl SpatialSplits {
    /// The setting of `PREFER_FAST_TRACE` triangle builds.
    pub const FAST_TRACE: SpatialSplits = SpatialSplits {
        budget: 0.3,
        alpha: 1e-5,
    };

    /// The most references a build over `n` triangles makes.
    #[must_use]
    pub fn max_references(&self, n: usize) -> usize {
        n + self.extra(n)
    }

    fn extra(&self, n: usize) -> usize {
        (n as f64 * self.budget.clamp(0.0, 1.0) as f64) as usize
    }
}

/// Slabs per axis of the spatial-split search.
const SPATIAL_BINS: usize = 32;

/// Builds a binary BVH over triangles with spatial splits. `bounds[k]` is the (finite, valid)
/// box of triangle `tris[k]`; triangles with `splittable[k] == false` are never split (all are
/// splittable when `splittable` is `None`). The tree's `prim_order` may name a triangle more
/// than once (never more than `splits.max_references(n)` slots in all).
#[must_use]
pub fn build_sbvh2(
    tris: &[[Vec3; 3]],
    bounds: &[Aabb],
    splittable: Option<&[bool]>,
    config: &BuildConfig,
    splits: &SpatialSplits,
) -> Bvh2 {
    assert_eq!(tris.len(), bounds.len(), "one box per triangle");
    let config = normalized(config);
    let refs: Vec<PrimRef> = bounds
        .par_iter()
        .enumerate()
        .map(|(i, b)| PrimRef::new(b, i as u32))
        .collect();
    if refs.is_empty() {
        return Bvh2::default();
    }
    let (root_box, _) = reduce(&refs);
    let ctx = Ctx {
        tris,
        splittable,
        config,
        min_overlap: splits.alpha.max(0.0) * root_box.half_area(),
    };
    let spare = splits.extra(refs.len());
    let tree = ctx.node(refs, root_box, 0, spare);
    let mut out = Bvh2 {
        nodes: vec![Bvh2Node {
            min: [0.0; 3],
            left_first: 0,
            max: [0.0; 3],
            count: 0,
        }],
        prim_order: Vec::new(),
    };
    emit(&tree, 0, &mut out);
    out
}

/// A subtree before it is laid out.
enum Tree {
    Leaf {
        bounds: Box4,
        ids: Vec<u32>,
    },
    Inner {
        bounds: Box4,
        children: Box<[Tree; 2]>,
    },
    /// A subtree built by the binned builder over `ids`' references (its `prim_order` indexes
    /// `ids`).
    Binned {
        bvh: Bvh2,
        ids: Vec<u32>,
    },
}

/// Lays `tree` out at node `at` of `out`: children pairs appended after their parent.
fn emit(tree: &Tree, at: usize, out: &mut Bvh2) {
    match tree {
        Tree::Leaf { bounds, ids } => {
            out.nodes[at] = node(bounds, out.prim_order.len() as u32, ids.len() as u32);
            out.prim_order.extend_from_slice(ids);
        }
        Tree::Inner { bounds, children } => {
            let pair = out.nodes.len();
            out.nodes[at] = node(bounds, pair as u32, 0);
            out.nodes.extend([out.nodes[at]; 2]);
            emit(&children[0], pair, out);
            emit(&children[1], pair + 1, out);
        }
        Tree::Binned { bvh, ids } => emit_binned(bvh, 0, ids, at, out),
    }
}

/// Copies node `n` of a binned subtree (and what is under it) to node `at` of `out`.
fn emit_binned(bvh: &Bvh2, n: usize, ids: &[u32], at: usize, out: &mut Bvh2) {
    let src = bvh.nodes[n];
    if src.is_leaf() {
        let first = out.prim_order.len() as u32;
        let slots = src.left_first as usize..(src.left_first + src.count) as usize;
        out.prim_order
            .extend(bvh.prim_order[slots].iter().map(|&k| ids[k as usize]));
        out.nodes[at] = Bvh2Node {
            left_first: first,
            ..src
        };
    } else {
        let pair = out.nodes.len();
        out.nodes[at] = Bvh2Node {
            left_first: pair as u32,
            ..src
        };
        out.nodes.extend([src; 2]);
        let c = src.left_first as usize;
        emit_binned(bvh, c, ids, pair, out);
        emit_binned(bvh, c + 1, ids, pair + 1, out);
    }
}

fn node(b: &Box4, left_first: u32, count: u32) -> Bvh2Node {
    let a = b.aabb();
    Bvh2Node {
        min: a.min.to_array(),
        left_first,
        max: a.max.to_array(),
        count,
    }
}

/// What every node of one build shares.
struct Ctx<'a> {
    tris: &'a [[Vec3; 3]],
    splittable: Option<&'a [bool]>,
    config: BuildConfig,
    /// Smallest overlap (half area) of an object split's children worth a spatial split.
    min_overlap: f32,
}

/// A chosen spatial split: the plane at `pos` along `axis`, slab `bin` being the first on the
/// right; `cost` as the object splits' (area-weighted block counts).
#[derive(Clone, Copy)]
struct SpatialSplit {
    axis: usize,
    bin: usize,
    pos: f32,
    lo: f32,
    scale: f32,
    cost: f32,
    left: usize,
    right: usize,
}

impl Ctx<'_> {
    fn splittable(&self, r: &PrimRef) -> bool {
        self.splittable.is_none_or(|s| s[r.id() as usize])
    }

    /// Builds the subtree over `refs` (whose box is `bounds`), which may add `spare` references.
    fn node(&self, mut refs: Vec<PrimRef>, bounds: Box4, depth: usize, spare: usize) -> Tree {
        let n = refs.len();
        let block = self.config.block_size.max(1);
        // Past the depth where the binned builder falls back on median splits, with the budget
        // spent, or where a spatial split cannot pay off, the binned builder takes over.
        if spare == 0 || n <= 2 * block || depth >= FORCE_MEDIAN_DEPTH {
            let boxes: Vec<Aabb> = refs.iter().map(|r| r.0.aabb()).collect();
            let bvh = build_bvh2_at(&boxes, &self.config, depth);
            return Tree::Binned {
                bvh,
                ids: refs.iter().map(PrimRef::id).collect(),
            };
        }
        // The object split, with its children's boxes.
        let (_, cb) = reduce(&refs);
        let object = self.object_split(&mut refs, &cb);
        let spatial = object.and_then(|(_, cost, sides)| {
            let overlap = overlap_half_area(&sides[0], &sides[1]);
            if overlap <= self.min_overlap {
                return None;
            }
            self.best_spatial_split(&refs, &bounds, spare)
                .filter(|s| s.cost < cost)
        });
        let leaf_cost = n.div_ceil(block) as f32;
        let best_cost = spatial.map(|s| s.cost).or(object.map(|o| o.1));
        let split_cost = best_cost.map(|c| self.config.traversal_cost + c / bounds.half_area());
        if n <= self.config.max_leaf_size
            && split_cost.is_none_or(|s| leaf_cost <= s || !s.is_finite())
        {
            return Tree::Leaf {
                bounds,
                ids: refs.iter().map(PrimRef::id).collect(),
            };
        }
        let (left, right) = match spatial {
            Some(s) => self.spatial_partition(refs, &s),
            None => object_partition(refs, object.map(|o| o.0), &cb),
        };
        // Degenerate partitions (non-finite arithmetic) fall back on the binned builder.
        if left.is_empty() || right.is_empty() {
            let mut all = left;
            all.extend(right);
            return self.node(all, bounds, depth, 0);
        }
        let added = (left.len() + right.len()).saturating_sub(n);
        let rest = spare.saturating_sub(added);
        // The rest of the budget goes to the children in proportion to their references.
        let spare_left =
            (rest as u128 * left.len() as u128 / (left.len() + right.len()) as u128) as usize;
        let spare_right = rest - spare_left;
        let (lb, _) = reduce(&left);
        let (rb, _) = reduce(&right);
        let (l, r) = if n > PARALLEL_SUBTREE {
            rayon::join(
                || self.node(left, lb, depth + 1, spare_left),
                || self.node(right, rb, depth + 1, spare_right),
            )
        } else {
            (
                self.node(left, lb, depth + 1, spare_left),
                self.node(right, rb, depth + 1, spare_right),
            )
        };
        Tree::Inner {
            bounds,
            children: Box::new([l, r]),
        }
    }

    /// The best object split, its cost and its children's boxes, as the binned builder finds
    /// it (binned, an exact sweep near the leaves, or one block on a side for two blocks).
    /// `refs` may be reordered.
    fn object_split(&self, refs: &mut [PrimRef], cb: &Box4) -> Option<(Split, f32, [Box4; 2])> {
        let n = refs.len();
        let block = self.config.block_size.max(1);
        if n <= self.config.sweep_threshold || n <= 2 * block {
            let (split, cost) = if n <= 2 * block && n > self.config.sweep_threshold {
                small_split(refs, cb, block)?
            } else {
                best_sweep_split(refs, block)?
            };
            // Sorted splits: sort, then measure the sides.
            let (mid, _) = partition::<8>(refs, split);
            let (l, _) = reduce(&refs[..mid]);
            let (r, _) = reduce(&refs[mid..]);
            return Some((split, cost, [l, r]));
        }
        let widest_only = n < self.config.widest_axis_below;
        if n < SMALL_NODE {
            return best_binned_split::<8>(refs, cb, block, widest_only);
        }
        match self.config.bins {
            8 => best_binned_split::<8>(refs, cb, block, widest_only),
            16 => best_binned_split::<16>(refs, cb, block, widest_only),
            _ => best_binned_split::<32>(refs, cb, block, widest_only),
        }
    }

    /// The best spatial split of a node whose references' box is `bounds` that adds at most
    /// `spare` references.
    fn best_spatial_split(
        &self,
        refs: &[PrimRef],
        bounds: &Box4,
        spare: usize,
    ) -> Option<SpatialSplit> {
        let mut lo = [0.0f32; 3];
        let mut scale = [0.0f32; 3];
        for a in 0..3 {
            let e = bounds.hi[a] - bounds.lo[a];
            let s = SPATIAL_BINS as f32 / e;
            lo[a] = bounds.lo[a];
            scale[a] = if e > 0.0 && s.is_finite() { s } else { 0.0 };
        }
        if scale == [0.0; 3] {
            return None;
        }
        let bins = if refs.len() > PARALLEL_BINNING {
            refs.par_chunks(PARALLEL_BINNING)
                .map(|c| self.fill_spatial(c, &lo, &scale))
                .reduce(SpatialBins::new, |a, b| a.merge(&b))
        } else {
            self.fill_spatial(refs, &lo, &scale)
        };
        let block = self.config.block_size.max(1) as u32;
        let n = refs.len();
        let mut best: Option<SpatialSplit> = None;
        for axis in 0..3 {
            if scale[axis] == 0.0 {
                continue;
            }
            let mut right_area = [0.0f32; SPATIAL_BINS];
            let mut right_count = [0u32; SPATIAL_BINS];
            let mut acc = Box4::EMPTY;
            let mut exits = 0u32;
            for i in (1..SPATIAL_BINS).rev() {
                acc.grow(&bins.boxes[axis][i]);
                exits += bins.exits[axis][i];
                right_area[i] = acc.half_area();
                right_count[i] = exits;
            }
            let mut acc = Box4::EMPTY;
            let mut entries = 0u32;
            for i in 1..SPATIAL_BINS {
                acc.grow(&bins.boxes[axis][i - 1]);
                entries += bins.entries[axis][i - 1];
                let (nl, nr) = (entries as usize, right_count[i] as usize);
                if nl == 0 || nr == 0 || nl + nr > n + spare {
                    continue;
                }
                let cost = acc.half_area() * (nl as u32).div_ceil(block) as f32
                    + right_area[i] * (nr as u32).div_ceil(block) as f32;
                if cost.is_finite() && best.is_none_or(|b| cost < b.cost) {
                    best = Some(SpatialSplit {
                        axis,
                        bin: i,
                        pos: plane(lo[axis], scale[axis], i),
                        lo: lo[axis],
                        scale: scale[axis],
                        cost,
                        left: nl,
                        right: nr,
                    });
                }
            }
        }
        best
    }

    /// Chops every reference at the slab planes its box crosses, on the three axes.
    fn fill_spatial(&self, refs: &[PrimRef], lo: &[f32; 3], scale: &[f32; 3]) -> SpatialBins {
        let mut bins = SpatialBins::new();
        for r in refs {
            let split = self.splittable(r);
            for axis in 0..3 {
                if scale[axis] == 0.0 {
                    continue;
                }
                let (first, last) = if split {
                    (
                        slab(r.0.lo[axis], lo[axis], scale[axis]),
                        slab(r.0.hi[axis], lo[axis], scale[axis]),
                    )
                } else {
                    // Never split: the whole reference in the slab of its centroid, as the
                    // partition places it.
                    let c = slab(r.centroid()[axis], lo[axis], scale[axis]);
                    (c, c)
                };
                bins.entries[axis][first] += 1;
                bins.exits[axis][last] += 1;
                if first == last {
                    bins.boxes[axis][first].grow(&r.0);
                    continue;
                }
                let tri = &self.tris[r.id() as usize];
                let mut piece = r.0;
                for b in first..last {
                    let pos = plane(lo[axis], scale[axis], b + 1);
                    let (left, right) = clip(tri, &piece, axis, pos);
                    bins.boxes[axis][b].grow(&left);
                    piece = right;
                }
                bins.boxes[axis][last].grow(&piece);
            }
        }
        bins
    }

    /// Applies a spatial split: references wholly on one side go there; straddling ones are
    /// split in two (or, when never split, go by their centroid's slab).
    fn spatial_partition(
        &self,
        refs: Vec<PrimRef>,
        s: &SpatialSplit,
    ) -> (Vec<PrimRef>, Vec<PrimRef>) {
        let mut left = Vec::with_capacity(s.left);
        let mut right = Vec::with_capacity(s.right);
        let a = s.axis;
        for r in refs {
            let first = slab(r.0.lo[a], s.lo, s.scale);
            let last = slab(r.0.hi[a], s.lo, s.scale);
            if last < s.bin {
                left.push(r);
            } else if first >= s.bin {
                right.push(r);
            } else if !self.splittable(&r) {
                if slab(r.centroid()[a], s.lo, s.scale) < s.bin {
                    left.push(r);
                } else {
                    right.push(r);
                }
            } else {
                let (l, rr) = clip(&self.tris[r.id() as usize], &r.0, a, s.pos);
                let id = r.id();
                // A piece may be empty where the triangle only touches the plane.
                if is_valid(&l) {
                    left.push(PrimRef::new(&l.aabb(), id));
                }
                if is_valid(&rr) {
                    right.push(PrimRef::new(&rr.aabb(), id));
                }
            }
        }
        (left, right)
    }
}

/// Applies an object split (or, without one, the median along the widest centroid axis).
fn object_partition(
    mut refs: Vec<PrimRef>,
    split: Option<Split>,
    cb: &Box4,
) -> (Vec<PrimRef>, Vec<PrimRef>) {
    let split = split.unwrap_or_else(|| {
        let axis = widest_axis(cb);
        Split::Median {
            axis: if cb.hi[axis] - cb.lo[axis] > 0.0 {
                axis
            } else {
                3
            },
        }
    });
    // A binned split partitions with `bin_of::<32>`: for the split's own bin count B <= 32 it
    // gives the same sides, since indices are below B and the clamp only matters for the
    // last bin, which is on the right either way.
    let mid = partition::<32>(&mut refs, split).0;
    let right = refs.split_off(mid);
    (refs, right)
}

/// The box of the overlap of two boxes (half area; 0 when they are disjoint).
fn overlap_half_area(a: &Box4, b: &Box4) -> f32 {
    let mut o = Box4::EMPTY;
    for i in 0..3 {
        o.lo[i] = a.lo[i].max(b.lo[i]);
        o.hi[i] = a.hi[i].min(b.hi[i]);
        if o.lo[i] > o.hi[i] {
            return 0.0;
        }
    }
    o.half_area()
}

fn is_valid(b: &Box4) -> bool {
    (0..3).all(|i| b.lo[i] <= b.hi[i])
}

/// The slab of a coordinate (clamped into range; NaN in slab 0).
#[inline]
fn slab(x: f32, lo: f32, scale: f32) -> usize {
    (((x - lo) * scale) as usize).min(SPATIAL_BINS - 1)
}

/// The plane between slabs `i - 1` and `i`.
#[inline]
fn plane(lo: f32, scale: f32, i: usize) -> f32 {
    lo + i as f32 / scale
}

/// The boxes of the parts of triangle `tri` on either side of the plane `x[axis] = pos`, each
/// within `within` (the reference's box): conservative, so that every point of the triangle
/// inside `within` lies in one of them (the points where edges cross the plane are rounded,
/// so the boxes are widened by a few units in the last place across the plane).
fn clip(tri: &[Vec3; 3], within: &Box4, axis: usize, pos: f32) -> (Box4, Box4) {
    let mut left = Box4::EMPTY;
    let mut right = Box4::EMPTY;
    for k in 0..3 {
        let v0 = tri[k].to_array();
        let v1 = tri[(k + 1) % 3].to_array();
        let p0 = [v0[0], v0[1], v0[2], 0.0];
        if v0[axis] <= pos {
            left.grow_point(&p0);
        }
        if v0[axis] >= pos {
            right.grow_point(&p0);
        }
        if (v0[axis] < pos && pos < v1[axis]) || (v1[axis] < pos && pos < v0[axis]) {
            let t = (pos - v0[axis]) / (v1[axis] - v0[axis]);
            let mut lo = [0.0f32; 4];
            let mut hi = [0.0f32; 4];
            for i in 0..3 {
                if i == axis {
                    lo[i] = pos;
                    hi[i] = pos;
                } else {
                    let p = v0[i] + (v1[i] - v0[i]) * t;
                    // The rounding of the interpolation is below a few ulps of the larger
                    // endpoint coordinate.
                    let pad = v0[i].abs().max(v1[i].abs()) * (8.0 * f32::EPSILON);
                    lo[i] = p - pad;
                    hi[i] = p + pad;
                }
            }
            left.grow_point(&lo);
            left.grow_point(&hi);
            right.grow_point(&lo);
            right.grow_point(&hi);
        }
    }
    let within_side = |mut b: Box4, left_side: bool| {
        for i in 0..3 {
            b.lo[i] = b.lo[i].max(within.lo[i]);
            b.hi[i] = b.hi[i].min(within.hi[i]);
        }
        if left_side {
            b.hi[axis] = b.hi[axis].min(pos);
        } else {
            b.lo[axis] = b.lo[axis].max(pos);
        }
        b.lo[3] = 0.0;
        b.hi[3] = 0.0;
        b
    };
    (within_side(left, true), within_side(right, false))
}

/// Per axis and slab: the box of the pieces in it, references starting in it (entries) and
/// ending in it (exits).
#[derive(Clone, Copy)]
struct SpatialBins {
    boxes: [[Box4; SPATIAL_BINS]; 3],
    entries: [[u32; SPATIAL_BINS]; 3],
    exits: [[u32; SPATIAL_BINS]; 3],
}

impl SpatialBins {
    fn new() -> Self {
        SpatialBins {
            boxes: [[Box4::EMPTY; SPATIAL_BINS]; 3],
            entries: [[0; SPATIAL_BINS]; 3],
            exits: [[0; SPATIAL_BINS]; 3],
        }
    }

    fn merge(mut self, o: &Self) -> Self {
        for a in 0..3 {
            for b in 0..SPATIAL_BINS {
                self.boxes[a][b].grow(&o.boxes[a][b]);
                self.entries[a][b] += o.entries[a][b];
                self.exits[a][b] += o.exits[a][b];
            }
        }
        self
    }
}
