//! The canonical binary BVH.

use bytemuck::{Pod, Zeroable};
use oxray_core::Aabb;

/// A 32-byte binary BVH node.
///
/// An inner node (`count == 0`) has its two children at `left_first` and `left_first + 1`; a leaf
/// holds the primitive slots `left_first .. left_first + count`.
#[repr(C, align(32))]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Bvh2Node {
    /// Smallest corner of the node's box.
    pub min: [f32; 3],
    /// First child (inner node) or first primitive slot (leaf).
    pub left_first: u32,
    /// Largest corner of the node's box.
    pub max: [f32; 3],
    /// Number of primitives; 0 for an inner node.
    pub count: u32,
}

impl Bvh2Node {
    /// The node's box.
    #[must_use]
    pub fn bounds(&self) -> Aabb {
        Aabb::new(self.min.into(), self.max.into())
    }

    /// Whether the node is a leaf.
    #[must_use]
    pub fn is_leaf(&self) -> bool {
        self.count > 0
    }
}

/// A binary BVH over primitives: `nodes[0]` is the root (no nodes: no primitives); `prim_order[slot]` is the index (into the
/// builder's input) of the primitive at leaf slot `slot`.
#[derive(Clone, Debug, Default)]
pub struct Bvh2 {
    /// Nodes, root first; children pairs are adjacent. Slots that no node references (under
    /// leaves) may be left unused.
    pub nodes: Vec<Bvh2Node>,
    /// Leaf slot to input primitive.
    pub prim_order: Vec<u32>,
}
