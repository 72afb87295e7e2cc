//! The 4-wide BVH that CPU traversal runs on, collapsed from a [`Bvh2`].

use crate::bvh2::Bvh2;
use bytemuck::{Pod, Zeroable};
use oxray_core::Aabb;
use rayon::prelude::*;

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

impl Bvh4Node {
    const EMPTY: Bvh4Node = Bvh4Node {
        bounds: [
            [f32::INFINITY; 4],
            [f32::INFINITY; 4],
            [f32::INFINITY; 4],
            [f32::NEG_INFINITY; 4],
            [f32::NEG_INFINITY; 4],
            [f32::NEG_INFINITY; 4],
        ],
        child: [u32::MAX; 4],
        count: [0; 4],
    };

    /// The box of child `lane`.
    pub fn child_bounds(&self, lane: usize) -> Aabb {
        let b = &self.bounds;
        Aabb::new(
            [b[0][lane], b[1][lane], b[2][lane]].into(),
            [b[3][lane], b[4][lane], b[5][lane]].into(),
        )
    }

    /// Whether lane `lane` holds a child.
    pub fn is_used(&self, lane: usize) -> bool {
        self.child_bounds(lane).is_valid()
    }

    /// Sets the box of child `lane`.
    pub(crate) fn set_bounds(&mut self, lane: usize, b: &Aabb) {
        for axis in 0..3 {
            self.bounds[axis][lane] = b.min[axis];
            self.bounds[3 + axis][lane] = b.max[axis];
        }
    }

    fn set(&mut self, lane: usize, b: &Aabb, child: u32, count: u32) {
        self.set_bounds(lane, b);
        self.child[lane] = child;
        self.count[lane] = count;
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
        let mut nodes = vec![Bvh4Node::EMPTY];
        let Some(root) = b.nodes.first() else {
            return Bvh4 { nodes };
        };
        if root.is_leaf() {
            nodes[0].set(0, &root.bounds(), root.left_first, root.count);
            return Bvh4 { nodes };
        }
        let kids = open_children(b, 0);
        let subtrees: Vec<Vec<Bvh4Node>> = kids
            .par_iter()
            .map(|&kid| {
                if b.nodes[kid].is_leaf() {
                    Vec::new()
                } else {
                    collapse(b, kid)
                }
            })
            .collect();
        for (lane, (&kid, sub)) in kids.iter().zip(&subtrees).enumerate() {
            let kn = &b.nodes[kid];
            if kn.is_leaf() {
                nodes[0].set(lane, &kn.bounds(), kn.left_first, kn.count);
                continue;
            }
            let base = nodes.len() as u32;
            nodes[0].set(lane, &kn.bounds(), base, 0);
            nodes.extend(sub.iter().map(|n| {
                let mut n = *n;
                for l in 0..4 {
                    if n.count[l] == 0 && n.child[l] != u32::MAX {
                        n.child[l] += base;
                    }
                }
                n
            }));
        }
        Bvh4 { nodes }
    }
}

/// The (up to four) binary nodes that become the children of the 4-wide node made from `src`.
fn open_children(b: &Bvh2, src: usize) -> Kids {
    let first = b.nodes[src].left_first as usize;
    let mut kids: [usize; 4] = [first, first + 1, 0, 0];
    let mut k = 2;
    while k < 4 {
        let open = (0..k)
            .filter(|&i| !b.nodes[kids[i]].is_leaf())
            .max_by(|&i, &j| {
                let ai = b.nodes[kids[i]].bounds().half_area();
                let aj = b.nodes[kids[j]].bounds().half_area();
                // Ties go to the earlier lane, for a deterministic layout.
                ai.total_cmp(&aj).then(j.cmp(&i))
            });
        let Some(i) = open else { break };
        let c = b.nodes[kids[i]].left_first as usize;
        kids[i] = c;
        kids[k] = c + 1;
        k += 1;
    }
    Kids { kids, len: k }
}

/// Collapses the subtree under binary inner node `top`; its root is node 0 of the result.
fn collapse(b: &Bvh2, top: usize) -> Vec<Bvh4Node> {
    let mut nodes = vec![Bvh4Node::EMPTY];
    // (bvh2 inner node, bvh4 node to fill)
    let mut work = vec![(top, 0usize)];
    while let Some((src, dst)) = work.pop() {
        let kids = open_children(b, src);
        for (lane, &kid) in kids.iter().enumerate() {
            let kn = &b.nodes[kid];
            if kn.is_leaf() {
                nodes[dst].set(lane, &kn.bounds(), kn.left_first, kn.count);
            } else {
                let idx = nodes.len();
                nodes.push(Bvh4Node::EMPTY);
                nodes[dst].set(lane, &kn.bounds(), idx as u32, 0);
                work.push((kid, idx));
            }
        }
    }
    nodes
}

/// Up to four node indices.
struct Kids {
    kids: [usize; 4],
    len: usize,
}

impl std::ops::Deref for Kids {
    type Target = [usize];
    fn deref(&self) -> &[usize] {
        &self.kids[..self.len]
    }
}
