//! The 8-wide BVH of the CPU backend's AVX2 and AVX-512 kernels, collapsed from a [`Bvh2`].

use crate::bvh2::Bvh2;
use crate::wide::WideNode;
use bytemuck::{Pod, Zeroable};
use oxray_core::Aabb;

/// A 256-byte, 64-byte-aligned node with eight children, boxes stored structure-of-arrays so
/// that one ray is tested against all eight boxes with 8-wide arithmetic (one AVX register per
/// row).
///
/// `bounds[axis][lane]` is the lower bound and `bounds[3 + axis][lane]` the upper bound of child
/// `lane`. A child with `count == 0` is an inner node at index `child`; with `count > 0` it is a
/// leaf holding primitive slots `child .. child + count`. Unused lanes have an empty box
/// (`+inf .. -inf`) that no ray can enter, child `u32::MAX` and count 0.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Bvh8Node {
    /// Child boxes: lower x, y, z then upper x, y, z, each for the eight lanes.
    pub bounds: [[f32; 8]; 6],
    /// Child node index or first primitive slot.
    pub child: [u32; 8],
    /// Primitive count of a leaf child; 0 for an inner child or an unused lane.
    pub count: [u32; 8],
}

crate::wide::wide_node!(Bvh8Node, 8);

impl Bvh8Node {
    /// The box of child `lane`.
    #[must_use]
    pub fn child_bounds(&self, lane: usize) -> Aabb {
        WideNode::child_bounds(self, lane)
    }

    /// Whether lane `lane` holds a child.
    #[must_use]
    pub fn is_used(&self, lane: usize) -> bool {
        WideNode::is_used(self, lane)
    }
}

/// An 8-wide BVH; `nodes[0]` is the root. Primitive slots are those of the [`Bvh2`] it came
/// from (for a triangle GAS, remapped to the triangle blocks; see
/// [`GasData::bvh8`](crate::GasData::bvh8)).
#[derive(Clone, Debug)]
pub struct Bvh8 {
    /// Nodes, root first; children are stored after their parents.
    pub nodes: Vec<Bvh8Node>,
}

impl From<&Bvh2> for Bvh8 {
    /// Collapses a binary BVH as Embree and Wald et al. do: each 8-wide node takes the binary
    /// node's children and keeps opening the inner child with the largest surface area (ties:
    /// the earlier lane) until it has eight. Deterministic, whatever the number of threads.
    /// The leaves are the binary tree's leaves.
    ///
    /// ```
    /// use oxray_bvh::{build_bvh2, BuildConfig, Bvh4, Bvh8};
    /// use oxray_core::Aabb;
    /// use glam::Vec3;
    /// let boxes: Vec<Aabb> = (0..1000)
    ///     .map(|i| Aabb::new(Vec3::splat(i as f32), Vec3::splat(i as f32 + 0.5)))
    ///     .collect();
    /// let bvh2 = build_bvh2(&boxes, &BuildConfig::BALANCED);
    /// let (b4, b8) = (Bvh4::from(&bvh2), Bvh8::from(&bvh2));
    /// assert_eq!(b4.stats().leaves, b8.stats().leaves);
    /// assert!(b8.nodes.len() < b4.nodes.len());
    /// ```
    fn from(b: &Bvh2) -> Self {
        Bvh8 {
            nodes: crate::wide::collapse(b),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{build_bvh2, BuildConfig, Bvh4};

    fn leaves<N: WideNode>(nodes: &[N]) -> Vec<(u32, u32, [u32; 6])> {
        let mut out: Vec<_> = nodes
            .iter()
            .flat_map(|n| {
                (0..N::WIDTH).filter(|&l| n.count(l) > 0).map(move |l| {
                    let b = n.child_bounds(l);
                    let bits = [b.min, b.max].map(|v| v.to_array().map(f32::to_bits));
                    let bits = [
                        bits[0][0], bits[0][1], bits[0][2], bits[1][0], bits[1][1], bits[1][2],
                    ];
                    (n.child(l), n.count(l), bits)
                })
            })
            .collect();
        out.sort_unstable();
        out
    }

    fn boxes(n: usize, seed: u64) -> Vec<Aabb> {
        crate::test_boxes::random_boxes(n, seed, 0.0, 100.0)
    }

    #[test]
    fn the_8_wide_collapse_keeps_the_binary_leaves_and_orders_children_after_parents() {
        for (n, seed) in [(1, 1), (2, 2), (9, 3), (100, 4), (5000, 5)] {
            let bvh2 = build_bvh2(&boxes(n, seed), &BuildConfig::BALANCED);
            let (b4, b8) = (Bvh4::from(&bvh2), Bvh8::from(&bvh2));
            assert_eq!(leaves(&b4.nodes), leaves(&b8.nodes), "n = {n}");
            let mut referenced = vec![false; b8.nodes.len()];
            for (i, node) in b8.nodes.iter().enumerate() {
                let used = (0..8).filter(|&l| node.is_used(l)).count();
                assert!(used >= 1);
                for l in 0..8 {
                    if node.is_used(l) && node.count[l] == 0 {
                        let c = node.child[l] as usize;
                        assert!(c > i && !referenced[c]);
                        referenced[c] = true;
                        // The child's box is its lanes' union.
                        assert_eq!(b8.nodes[c].bounds(), node.child_bounds(l));
                    } else if !node.is_used(l) {
                        assert_eq!((node.child[l], node.count[l]), (u32::MAX, 0));
                    }
                }
                // Lanes are filled from the first.
                assert!((0..used).all(|l| node.is_used(l)));
            }
            assert!(referenced.iter().skip(1).all(|&r| r));
            if n >= 100 {
                assert!(b8.nodes.len() < b4.nodes.len(), "{n}");
                assert!(b8.stats().sah_cost < b4.stats().sah_cost);
            }
            // Deterministic whatever the thread count.
            let one = rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .build()
                .unwrap()
                .install(|| Bvh8::from(&bvh2));
            assert_eq!(one.nodes, b8.nodes);
        }
    }
}
