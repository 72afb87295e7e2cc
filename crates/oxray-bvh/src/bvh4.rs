//! The 4-wide BVH that CPU traversal runs on, collapsed from a [`Bvh2`].

use crate::bvh2::Bvh2;
use crate::wide::WideNode;
use bytemuck::{Pod, Zeroable};
use oxray_core::Aabb;

/// A 128-byte, 64-byte-aligned node with four children, boxes stored structure-of-arrays so that
/// one ray is tested against all four boxes with 4-wide arithmetic.
///
/// `bounds[axis][lane]` is the lower bound and `bounds[3 + axis][lane]` the upper bound of child
/// `lane`. A child with `count == 0` is an inner node at index `child`; with `count > 0` it is a
/// leaf holding primitive slots `child .. child + count`. Unused lanes have an empty box
/// (`+inf .. -inf`) that no ray can enter.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Bvh4Node {
    /// Child boxes: lower x, y, z then upper x, y, z, each for the four lanes.
    pub bounds: [[f32; 4]; 6],
    /// Child node index or first primitive slot.
    pub child: [u32; 4],
    /// Primitive count of a leaf child; 0 for an inner child or an unused lane.
    pub count: [u32; 4],
}

crate::wide::wide_node!(Bvh4Node, 4);

impl Bvh4Node {
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

/// A 4-wide BVH; `nodes[0]` is the root. Primitive slots are those of the [`Bvh2`] it came from.
#[derive(Clone, Debug)]
pub struct Bvh4 {
    /// Nodes, root first.
    pub nodes: Vec<Bvh4Node>,
}

impl From<&Bvh2> for Bvh4 {
    /// Collapses a binary BVH: each 4-wide node takes the binary node's children and keeps
    /// opening the inner child with the largest surface area until it has four. The subtrees
    /// under the root are collapsed in parallel and laid out one after the other, in lane
    /// order, so the result does not depend on the number of threads.
    fn from(b: &Bvh2) -> Self {
        Bvh4 {
            nodes: crate::wide::collapse(b),
        }
    }
}
