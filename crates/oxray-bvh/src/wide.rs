//! What the wide layouts ([`crate::Bvh4`], [`crate::Bvh8`]) share: a node of `WIDTH` lanes with
//! structure-of-arrays child boxes, and the collapse of the canonical [`Bvh2`] into such nodes.

use crate::bvh2::Bvh2;
use oxray_core::Aabb;
use rayon::prelude::*;

/// A node of a wide BVH: `WIDTH` lanes, each an empty box (unused), an inner child (count 0, a
/// node index) or a leaf (count > 0, a primitive slot range).
pub trait WideNode: Copy + Send + Sync + PartialEq + std::fmt::Debug + 'static {
    /// Lanes per node.
    const WIDTH: usize;
    /// A node with every lane unused: empty boxes (`+inf .. -inf`), child `u32::MAX`, count 0.
    const EMPTY: Self;
    /// Child node index or first primitive slot of lane `lane`.
    fn child(&self, lane: usize) -> u32;
    /// Primitive count of lane `lane` (0: an inner child or an unused lane).
    fn count(&self, lane: usize) -> u32;
    /// Sets the child index or first slot of lane `lane`.
    fn set_child(&mut self, lane: usize, child: u32);
    /// Bound `row` (lower x, y, z, then upper x, y, z) of lane `lane`.
    fn bound(&self, row: usize, lane: usize) -> f32;
    /// Sets bound `row` of lane `lane`.
    fn set_bound(&mut self, row: usize, lane: usize, value: f32);

    /// The box of child `lane`.
    fn child_bounds(&self, lane: usize) -> Aabb {
        Aabb::new(
            [
                self.bound(0, lane),
                self.bound(1, lane),
                self.bound(2, lane),
            ]
            .into(),
            [
                self.bound(3, lane),
                self.bound(4, lane),
                self.bound(5, lane),
            ]
            .into(),
        )
    }

    /// Whether lane `lane` holds a child.
    fn is_used(&self, lane: usize) -> bool {
        self.child_bounds(lane).is_valid()
    }

    /// Sets the box of child `lane`.
    fn set_bounds(&mut self, lane: usize, b: &Aabb) {
        for axis in 0..3 {
            self.set_bound(axis, lane, b.min[axis]);
            self.set_bound(3 + axis, lane, b.max[axis]);
        }
    }

    /// Sets lane `lane` to a child: box, node index or first slot, and count.
    fn set(&mut self, lane: usize, b: &Aabb, child: u32, count: u32) {
        self.set_bounds(lane, b);
        self.set_child(lane, child);
        self.set_count(lane, count);
    }

    /// Sets the primitive count of lane `lane`.
    fn set_count(&mut self, lane: usize, count: u32);

    /// The union of every lane's box.
    fn bounds(&self) -> Aabb {
        (0..Self::WIDTH).fold(Aabb::EMPTY, |a, l| a.union(&self.child_bounds(l)))
    }
}

/// Implements [`WideNode`] for a node struct with `bounds: [[f32; W]; 6]`, `child: [u32; W]`
/// and `count: [u32; W]`.
macro_rules! wide_node {
    ($node:ty, $width:expr) => {
        impl $crate::wide::WideNode for $node {
            const WIDTH: usize = $width;
            const EMPTY: Self = Self {
                bounds: [
                    [f32::INFINITY; $width],
                    [f32::INFINITY; $width],
                    [f32::INFINITY; $width],
                    [f32::NEG_INFINITY; $width],
                    [f32::NEG_INFINITY; $width],
                    [f32::NEG_INFINITY; $width],
                ],
                child: [u32::MAX; $width],
                count: [0; $width],
            };
            #[inline]
            fn child(&self, lane: usize) -> u32 {
                self.child[lane]
            }
            #[inline]
            fn count(&self, lane: usize) -> u32 {
                self.count[lane]
            }
            #[inline]
            fn set_child(&mut self, lane: usize, child: u32) {
                self.child[lane] = child;
            }
            #[inline]
            fn set_count(&mut self, lane: usize, count: u32) {
                self.count[lane] = count;
            }
            #[inline]
            fn bound(&self, row: usize, lane: usize) -> f32 {
                self.bounds[row][lane]
            }
            #[inline]
            fn set_bound(&mut self, row: usize, lane: usize, value: f32) {
                self.bounds[row][lane] = value;
            }
        }
    };
}
pub(crate) use wide_node;

/// Collapses a binary BVH into `N`-wide nodes: each wide node takes the binary node's children
/// and keeps opening the inner child with the largest surface area (ties: the earlier lane)
/// until it has `N::WIDTH`. The subtrees under the root are collapsed in parallel and laid out
/// one after the other, in lane order, so the result does not depend on the number of threads.
/// Children are always stored after their parents. Leaves keep the binary leaves' slot ranges.
pub(crate) fn collapse<N: WideNode>(b: &Bvh2) -> Vec<N> {
    let mut nodes = vec![N::EMPTY];
    let Some(root) = b.nodes.first() else {
        return nodes;
    };
    if root.is_leaf() {
        nodes[0].set(0, &root.bounds(), root.left_first, root.count);
        return nodes;
    }
    let kids = open_children::<N>(b, 0);
    let subtrees: Vec<Vec<N>> = kids
        .par_iter()
        .map(|&kid| {
            if b.nodes[kid].is_leaf() {
                Vec::new()
            } else {
                collapse_subtree::<N>(b, kid)
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
            for l in 0..N::WIDTH {
                if n.count(l) == 0 && n.child(l) != u32::MAX {
                    n.set_child(l, n.child(l) + base);
                }
            }
            n
        }));
    }
    nodes
}

/// The (up to `N::WIDTH`) binary nodes that become the children of the wide node made from
/// `src`.
fn open_children<N: WideNode>(b: &Bvh2, src: usize) -> Kids {
    let first = b.nodes[src].left_first as usize;
    let mut kids = Kids {
        kids: [0; MAX_WIDTH],
        len: 2,
    };
    kids.kids[0] = first;
    kids.kids[1] = first + 1;
    while kids.len < N::WIDTH {
        let k = kids.len;
        let open = (0..k)
            .filter(|&i| !b.nodes[kids.kids[i]].is_leaf())
            .max_by(|&i, &j| {
                let ai = b.nodes[kids.kids[i]].bounds().half_area();
                let aj = b.nodes[kids.kids[j]].bounds().half_area();
                // Ties go to the earlier lane, for a deterministic layout.
                ai.total_cmp(&aj).then(j.cmp(&i))
            });
        let Some(i) = open else { break };
        let c = b.nodes[kids.kids[i]].left_first as usize;
        kids.kids[i] = c;
        kids.kids[k] = c + 1;
        kids.len += 1;
    }
    kids
}

/// Collapses the subtree under binary inner node `top`; its root is node 0 of the result.
fn collapse_subtree<N: WideNode>(b: &Bvh2, top: usize) -> Vec<N> {
    let mut nodes = vec![N::EMPTY];
    // (bvh2 inner node, wide node to fill)
    let mut work = vec![(top, 0usize)];
    while let Some((src, dst)) = work.pop() {
        let kids = open_children::<N>(b, src);
        for (lane, &kid) in kids.iter().enumerate() {
            let kn = &b.nodes[kid];
            if kn.is_leaf() {
                nodes[dst].set(lane, &kn.bounds(), kn.left_first, kn.count);
            } else {
                let idx = nodes.len();
                nodes.push(N::EMPTY);
                nodes[dst].set(lane, &kn.bounds(), idx as u32, 0);
                work.push((kid, idx));
            }
        }
    }
    nodes
}

/// The widest layout.
const MAX_WIDTH: usize = 8;

/// Up to [`MAX_WIDTH`] node indices.
struct Kids {
    kids: [usize; MAX_WIDTH],
    len: usize,
}

impl std::ops::Deref for Kids {
    type Target = [usize];
    fn deref(&self) -> &[usize] {
        &self.kids[..self.len]
    }
}

/// The first slot of every leaf lane, in node and lane order.
pub(crate) fn leaf_starts<N: WideNode>(nodes: &[N]) -> Vec<u32> {
    nodes
        .iter()
        .flat_map(|n| {
            (0..N::WIDTH)
                .filter(|&l| n.count(l) > 0)
                .map(|l| n.child(l))
        })
        .collect()
}
