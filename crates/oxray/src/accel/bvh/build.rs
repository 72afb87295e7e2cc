//! Binned SAH builder (Wald 2007), parallel over subtrees and, at the top, over primitives.
//!
//! Every reduction is a min, a max or an integer sum, and work is split at fixed sizes, so the
//! tree is bit-identical whatever the number of threads.

use super::bvh2::{Bvh2, Bvh2Node};
use super::FORCE_MEDIAN_DEPTH;
use crate::geometry::Aabb;
use glam::Vec3;
use rayon::prelude::*;

/// Tuning of the SAH builder; the build flags choose one of the presets.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BuildConfig {
    /// Bins per axis.
    pub bins: usize,
    /// Largest leaf the SAH may choose; more primitives than this are always split.
    pub max_leaf_size: usize,
    /// Cost of visiting a node relative to intersecting one primitive.
    pub traversal_cost: f32,
    /// Nodes with at most this many primitives are split by a full SAH sweep (exact SAH over
    /// sorted centroids) instead of bins; 0 disables the sweep.
    pub sweep_threshold: usize,
}

impl BuildConfig {
    /// `PREFER_FAST_BUILD`: few bins, larger leaves.
    pub const FAST_BUILD: BuildConfig = BuildConfig {
        bins: 8,
        max_leaf_size: 8,
        traversal_cost: 1.0,
        sweep_threshold: 0,
    };
    /// The default trade-off.
    pub const BALANCED: BuildConfig = BuildConfig {
        bins: 16,
        max_leaf_size: 8,
        traversal_cost: 1.0,
        sweep_threshold: 0,
    };
    /// `PREFER_FAST_TRACE`: more bins, and an exact SAH sweep near the leaves.
    pub const FAST_TRACE: BuildConfig = BuildConfig {
        bins: 32,
        max_leaf_size: 8,
        traversal_cost: 1.0,
        sweep_threshold: 256,
    };
}

const MAX_BINS: usize = 64;
/// Subtrees smaller than this are built on the current thread.
const PARALLEL_SUBTREE: usize = 4096;
/// Nodes larger than this bin their primitives in parallel chunks of this size.
const PARALLEL_BINNING: usize = 1 << 15;

/// The builder's view of one primitive.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub(crate) struct PrimRef {
    min: [f32; 3],
    id: u32,
    max: [f32; 3],
    _pad: u32,
}

impl PrimRef {
    #[inline]
    fn centroid(&self, axis: usize) -> f32 {
        self.min[axis] * 0.5 + self.max[axis] * 0.5
    }
    #[inline]
    fn bounds(&self) -> Aabb {
        Aabb::new(self.min.into(), self.max.into())
    }
}

enum Node {
    Leaf { bounds: Aabb, start: u32, count: u32 },
    Inner { bounds: Aabb, children: Box<[Node; 2]> },
}

impl Node {
    fn bounds(&self) -> Aabb {
        match self {
            Node::Leaf { bounds, .. } | Node::Inner { bounds, .. } => *bounds,
        }
    }
}

/// Bytes of working memory [`build_bvh2`] allocates for `n` primitives, at most.
pub(crate) fn temp_bytes(n: usize) -> usize {
    let nodes = 2 * n.max(1);
    n * std::mem::size_of::<PrimRef>()
        + nodes * (std::mem::size_of::<Node>() + std::mem::size_of::<Bvh2Node>())
        + n * std::mem::size_of::<u32>()
}

/// Builds a binary BVH over `bounds` (every box must be finite and valid).
pub(crate) fn build_bvh2(bounds: &[Aabb], config: &BuildConfig) -> Bvh2 {
    let config = BuildConfig {
        bins: config.bins.clamp(2, MAX_BINS),
        max_leaf_size: config.max_leaf_size.max(1),
        ..*config
    };
    let mut refs: Vec<PrimRef> = bounds
        .par_iter()
        .enumerate()
        .map(|(i, b)| PrimRef {
            min: b.min.to_array(),
            id: i as u32,
            max: b.max.to_array(),
            _pad: 0,
        })
        .collect();
    if refs.is_empty() {
        return Bvh2::default();
    }
    let mut nodes = Vec::with_capacity(2 * refs.len());
    let root_bounds = reduce_bounds(&refs);
    let root = build_node(&mut refs, 0, root_bounds, 0, &config);
    nodes.push(placeholder());
    flatten(root, 0, &mut nodes);
    Bvh2 {
        nodes,
        prim_order: refs.iter().map(|r| r.id).collect(),
    }
}

fn placeholder() -> Bvh2Node {
    Bvh2Node {
        min: [0.0; 3],
        left_first: 0,
        max: [0.0; 3],
        count: 0,
    }
}

fn flatten(node: Node, at: usize, nodes: &mut Vec<Bvh2Node>) {
    match node {
        Node::Leaf {
            bounds,
            start,
            count,
        } => {
            nodes[at] = Bvh2Node {
                min: bounds.min.to_array(),
                left_first: start,
                max: bounds.max.to_array(),
                count,
            };
        }
        Node::Inner { bounds, children } => {
            let first = nodes.len();
            nodes.push(placeholder());
            nodes.push(placeholder());
            nodes[at] = Bvh2Node {
                min: bounds.min.to_array(),
                left_first: first as u32,
                max: bounds.max.to_array(),
                count: 0,
            };
            let [l, r] = *children;
            flatten(l, first, nodes);
            flatten(r, first + 1, nodes);
        }
    }
}

fn reduce_bounds(refs: &[PrimRef]) -> Aabb {
    let fold = |b: Aabb, r: &PrimRef| b.union(&r.bounds());
    if refs.len() > PARALLEL_BINNING {
        refs.par_chunks(PARALLEL_BINNING)
            .map(|c| c.iter().fold(Aabb::EMPTY, fold))
            .reduce(|| Aabb::EMPTY, |a, b| a.union(&b))
    } else {
        refs.iter().fold(Aabb::EMPTY, fold)
    }
}

fn centroid_bounds(refs: &[PrimRef]) -> Aabb {
    let fold = |mut b: Aabb, r: &PrimRef| {
        b.grow(Vec3::new(r.centroid(0), r.centroid(1), r.centroid(2)));
        b
    };
    if refs.len() > PARALLEL_BINNING {
        refs.par_chunks(PARALLEL_BINNING)
            .map(|c| c.iter().fold(Aabb::EMPTY, fold))
            .reduce(|| Aabb::EMPTY, |a, b| a.union(&b))
    } else {
        refs.iter().fold(Aabb::EMPTY, fold)
    }
}

/// A chosen split: primitives go left when `goes_left` says so.
#[derive(Clone, Copy)]
enum Split {
    /// Bin-based: left iff bin(centroid[axis]) < bin.
    Binned {
        axis: usize,
        bin: usize,
        cmin: f32,
        scale: f32,
        bins: usize,
    },
    /// Sorted by centroid along `axis`, the first `count` go left.
    Sorted { axis: usize, count: usize },
    /// Object median along `axis` (or, with `axis == 3`, by position in the array).
    Median { axis: usize },
}

#[inline]
fn bin_of(c: f32, cmin: f32, scale: f32, bins: usize) -> usize {
    // `as usize` saturates (and maps NaN to 0), so every centroid lands in a valid bin.
    (((c - cmin) * scale) as usize).min(bins - 1)
}

#[derive(Clone, Copy)]
struct Bins {
    bounds: [[Aabb; MAX_BINS]; 3],
    counts: [[u32; MAX_BINS]; 3],
}

impl Bins {
    fn new() -> Self {
        Bins {
            bounds: [[Aabb::EMPTY; MAX_BINS]; 3],
            counts: [[0; MAX_BINS]; 3],
        }
    }
    fn merge(mut self, o: &Bins) -> Bins {
        for a in 0..3 {
            for b in 0..MAX_BINS {
                self.bounds[a][b] = self.bounds[a][b].union(&o.bounds[a][b]);
                self.counts[a][b] += o.counts[a][b];
            }
        }
        self
    }
}

fn fill_bins(refs: &[PrimRef], cmin: [f32; 3], scale: [f32; 3], bins: usize) -> Bins {
    let fill = |chunk: &[PrimRef]| {
        let mut b = Bins::new();
        for r in chunk {
            let rb = r.bounds();
            for axis in 0..3 {
                let i = bin_of(r.centroid(axis), cmin[axis], scale[axis], bins);
                b.bounds[axis][i] = b.bounds[axis][i].union(&rb);
                b.counts[axis][i] += 1;
            }
        }
        b
    };
    if refs.len() > PARALLEL_BINNING {
        refs.par_chunks(PARALLEL_BINNING)
            .map(fill)
            .reduce(Bins::new, |a, b| a.merge(&b))
    } else {
        fill(refs)
    }
}

/// Returns the best binned split and its SAH cost (in units of primitive intersections, relative
/// to the parent's area).
fn best_binned_split(refs: &[PrimRef], cb: &Aabb, config: &BuildConfig) -> Option<(Split, f32)> {
    let bins = config.bins;
    let ext = cb.extent();
    let mut scale = [0.0f32; 3];
    let cmin = cb.min.to_array();
    for axis in 0..3 {
        let e = ext[axis];
        let s = bins as f32 * (1.0 - 1e-6) / e;
        scale[axis] = if e > 0.0 && s.is_finite() { s } else { 0.0 };
    }
    if scale == [0.0; 3] {
        return None;
    }
    let b = fill_bins(refs, cmin, scale, bins);
    let mut best: Option<(Split, f32)> = None;
    for axis in 0..3 {
        if scale[axis] == 0.0 {
            continue;
        }
        // Sweep from the right to get right-side areas and counts, then from the left.
        let mut right_area = [0.0f32; MAX_BINS];
        let mut right_count = [0u32; MAX_BINS];
        let mut acc = Aabb::EMPTY;
        let mut n = 0u32;
        for i in (1..bins).rev() {
            acc = acc.union(&b.bounds[axis][i]);
            n += b.counts[axis][i];
            right_area[i] = acc.half_area();
            right_count[i] = n;
        }
        let mut acc = Aabb::EMPTY;
        let mut n = 0u32;
        for i in 1..bins {
            acc = acc.union(&b.bounds[axis][i - 1]);
            n += b.counts[axis][i - 1];
            if n == 0 || right_count[i] == 0 {
                continue;
            }
            let cost = acc.half_area() * n as f32 + right_area[i] * right_count[i] as f32;
            if cost.is_finite() && best.is_none_or(|(_, c)| cost < c) {
                best = Some((
                    Split::Binned {
                        axis,
                        bin: i,
                        cmin: cmin[axis],
                        scale: scale[axis],
                        bins,
                    },
                    cost,
                ));
            }
        }
    }
    best
}

/// Exact SAH: sorts along each axis and evaluates every split position.
fn best_sweep_split(refs: &mut [PrimRef]) -> Option<(Split, f32)> {
    let n = refs.len();
    let mut right_area = vec![0.0f32; n];
    let mut best: Option<(Split, f32)> = None;
    for axis in 0..3 {
        sort_by_centroid(refs, axis);
        let mut acc = Aabb::EMPTY;
        for i in (1..n).rev() {
            acc = acc.union(&refs[i].bounds());
            right_area[i] = acc.half_area();
        }
        let mut acc = Aabb::EMPTY;
        for i in 1..n {
            acc = acc.union(&refs[i - 1].bounds());
            let cost = acc.half_area() * i as f32 + right_area[i] * (n - i) as f32;
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
        a.centroid(axis)
            .total_cmp(&b.centroid(axis))
            .then(a.id.cmp(&b.id))
    });
}

/// Applies a split; returns how many primitives went left.
fn partition(refs: &mut [PrimRef], split: Split) -> usize {
    match split {
        Split::Binned {
            axis,
            bin,
            cmin,
            scale,
            bins,
        } => {
            let mut i = 0;
            let mut j = refs.len();
            while i < j {
                if bin_of(refs[i].centroid(axis), cmin, scale, bins) < bin {
                    i += 1;
                } else {
                    j -= 1;
                    refs.swap(i, j);
                }
            }
            i
        }
        Split::Sorted { axis, count } => {
            sort_by_centroid(refs, axis);
            count
        }
        Split::Median { axis } => {
            let mid = refs.len() / 2;
            if axis < 3 {
                refs.select_nth_unstable_by(mid, |a, b| {
                    a.centroid(axis)
                        .total_cmp(&b.centroid(axis))
                        .then(a.id.cmp(&b.id))
                });
            }
            mid
        }
    }
}

fn build_node(
    refs: &mut [PrimRef],
    offset: usize,
    bounds: Aabb,
    depth: usize,
    config: &BuildConfig,
) -> Node {
    let n = refs.len();
    let leaf = Node::Leaf {
        bounds,
        start: offset as u32,
        count: n as u32,
    };
    if n <= 1 {
        return leaf;
    }
    let cb = centroid_bounds(refs);
    let split = if depth >= FORCE_MEDIAN_DEPTH {
        None
    } else if n <= config.sweep_threshold {
        best_sweep_split(refs)
    } else {
        best_binned_split(refs, &cb, config)
    };
    let split = match split {
        Some((split, cost)) => {
            // SAH in units of one primitive test, relative to this node's area.
            let area = bounds.half_area();
            let split_cost = config.traversal_cost + cost / area;
            let leaf_cost = n as f32;
            if n <= config.max_leaf_size && (leaf_cost <= split_cost || !split_cost.is_finite()) {
                return leaf;
            }
            split
        }
        None => {
            if n <= config.max_leaf_size && depth < FORCE_MEDIAN_DEPTH {
                return leaf;
            }
            let ext = cb.extent();
            let axis = cb.largest_axis();
            Split::Median {
                axis: if ext[axis] > 0.0 { axis } else { 3 },
            }
        }
    };
    let mut mid = partition(refs, split);
    if mid == 0 || mid == n {
        // Only reachable with non-finite arithmetic; any split keeps the tree correct.
        mid = n / 2;
    }
    let (l, r) = refs.split_at_mut(mid);
    let (lb, rb) = if n > PARALLEL_SUBTREE {
        rayon::join(|| reduce_bounds(l), || reduce_bounds(r))
    } else {
        (reduce_bounds(l), reduce_bounds(r))
    };
    let (left, right) = if n > PARALLEL_SUBTREE {
        rayon::join(
            || build_node(l, offset, lb, depth + 1, config),
            || build_node(r, offset + mid, rb, depth + 1, config),
        )
    } else {
        (
            build_node(l, offset, lb, depth + 1, config),
            build_node(r, offset + mid, rb, depth + 1, config),
        )
    };
    debug_assert!(bounds.contains_box(&left.bounds().union(&right.bounds())));
    Node::Inner {
        bounds,
        children: Box::new([left, right]),
    }
}
