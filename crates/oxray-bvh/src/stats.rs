//! Quality statistics of a BVH: node counts, depth and SAH cost.

use crate::bvh4::Bvh4;
use crate::bvh8::Bvh8;
use crate::wide::WideNode;

/// Statistics of a [`Bvh4`] or a [`Bvh8`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BvhStats {
    /// Nodes.
    pub nodes: usize,
    /// Leaves.
    pub leaves: usize,
    /// Deepest leaf (the root's children are at depth 1).
    pub max_depth: usize,
    /// Mean primitives per leaf.
    pub mean_leaf_size: f64,
    /// Primitive references in the leaves: the primitives, plus the repeats that spatial
    /// splits make (a primitive held by several leaves counts once per leaf).
    pub references: usize,
    /// Surface-area-heuristic cost: expected node visits plus primitive tests for a random ray
    /// that hits the root box (node cost 1, primitive cost 1).
    pub sah_cost: f64,
    /// Bytes of the node array.
    pub node_bytes: usize,
}

impl Bvh4 {
    /// Computes the statistics of this BVH.
    #[must_use]
    pub fn stats(&self) -> BvhStats {
        stats_of(&self.nodes)
    }
}

impl Bvh8 {
    /// Computes the statistics of this BVH.
    #[must_use]
    pub fn stats(&self) -> BvhStats {
        stats_of(&self.nodes)
    }
}

/// The statistics of a wide node array.
fn stats_of<N: WideNode>(nodes: &[N]) -> BvhStats {
    let root = &nodes[0];
    let root_area: f64 = (0..N::WIDTH)
        .filter(|&l| root.is_used(l))
        .map(|l| root.child_bounds(l))
        .fold(oxray_core::Aabb::EMPTY, |a, b| a.union(&b))
        .half_area() as f64;
    let mut s = BvhStats {
        nodes: nodes.len(),
        node_bytes: std::mem::size_of_val(nodes),
        sah_cost: 1.0,
        ..BvhStats::default()
    };
    let mut prims = 0usize;
    let mut stack = vec![(0usize, 1usize)];
    while let Some((i, depth)) = stack.pop() {
        let n = &nodes[i];
        for lane in 0..N::WIDTH {
            if !n.is_used(lane) {
                continue;
            }
            let rel = if root_area > 0.0 {
                n.child_bounds(lane).half_area() as f64 / root_area
            } else {
                1.0
            };
            if n.count(lane) > 0 {
                s.leaves += 1;
                prims += n.count(lane) as usize;
                s.max_depth = s.max_depth.max(depth);
                s.sah_cost += rel * n.count(lane) as f64;
            } else {
                s.sah_cost += rel;
                stack.push((n.child(lane) as usize, depth + 1));
            }
        }
    }
    s.references = prims;
    s.mean_leaf_size = if s.leaves > 0 {
        prims as f64 / s.leaves as f64
    } else {
        0.0
    };
    s
}
