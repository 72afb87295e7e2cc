//! The quantised 8-wide layout: a [`Bvh8`] whose child boxes are stored as 8-bit offsets on a
//! per-node grid, so that a node takes two cache lines instead of four.
//!
//! Traversal is bound by the latency of loading nodes (see docs/BENCHMARKS.md, "Prefetching,
//! unordered occlusion and packets"); halving a node's size halves the lines each visit waits
//! for. The boxes grow a little (each side moves out to the grid), so a ray may enter a few more
//! children, but never fewer: every decoded box contains the box it stands for, checked with
//! the very `f32` operations the kernels decode with. The leaves are the [`Bvh8`]'s, so the
//! hits are the same.

use crate::bvh8::{Bvh8, Bvh8Node};
use bytemuck::{Pod, Zeroable};
use oxray_core::Aabb;
use rayon::prelude::*;

/// A 128-byte, 64-byte-aligned node with eight children whose boxes are quantised.
///
/// Bound `row` (lower x, y, z, then upper x, y, z) of lane `lane` is
/// `q[row][lane] as f32 * scale[axis] + origin[axis]` with `axis = row % 3`, computed as one
/// multiplication then one addition (no fused multiply-add), which is how every kernel decodes
/// it. `scale` is a power of two, so the product is exact. Lanes not in `valid` hold no child.
#[repr(C, align(64))]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct QBvh8Node {
    /// The grid's origin: the smallest lower bound of the node's children, per axis.
    pub origin: [f32; 3],
    /// The grid's step per axis (a power of two).
    pub scale: [f32; 3],
    /// Quantised bounds: lower x, y, z then upper x, y, z, each for the eight lanes.
    pub q: [[u8; 8]; 6],
    /// Child node index or first primitive slot (as [`Bvh8Node::child`]).
    pub child: [u32; 8],
    /// Primitive count of a leaf child; 0 for an inner child or an unused lane.
    pub count: [u16; 8],
    /// Bit `lane` set: the lane holds a child.
    pub valid: u8,
    /// Padding to 128 bytes.
    pub pad: [u8; 7],
}

const _: () = assert!(std::mem::size_of::<QBvh8Node>() == 128);

impl QBvh8Node {
    /// Bound `row` of lane `lane`, decoded as the kernels decode it.
    #[inline(always)]
    #[must_use]
    pub fn bound(&self, row: usize, lane: usize) -> f32 {
        decode(self.q[row][lane], self.scale[row % 3], self.origin[row % 3])
    }

    /// The decoded box of child `lane` (empty for an unused lane).
    #[must_use]
    pub fn child_bounds(&self, lane: usize) -> Aabb {
        if self.valid & (1 << lane) == 0 {
            return Aabb::EMPTY;
        }
        let row = |r: usize| self.bound(r, lane);
        Aabb::new(
            [row(0), row(1), row(2)].into(),
            [row(3), row(4), row(5)].into(),
        )
    }

    /// Quantises `node`, or `None` where a child's box is not finite or a count does not fit
    /// 16 bits.
    fn quantize(node: &Bvh8Node) -> Option<QBvh8Node> {
        let mut out = QBvh8Node::zeroed();
        out.child = [u32::MAX; 8];
        for l in (0..8).filter(|&l| node.is_used(l)) {
            out.valid |= 1 << l;
            out.child[l] = node.child[l];
            out.count[l] = u16::try_from(node.count[l]).ok()?;
        }
        if out.valid == 0 {
            // No child: any grid; `valid` keeps every lane out.
            return Some(out);
        }
        let used = |l: &usize| out.valid & (1 << *l) != 0;
        for axis in 0..3 {
            let origin = (0..8)
                .filter(used)
                .map(|l| node.bounds[axis][l])
                .fold(f32::INFINITY, f32::min);
            let top = (0..8)
                .filter(used)
                .map(|l| node.bounds[3 + axis][l])
                .fold(f32::NEG_INFINITY, f32::max);
            if !origin.is_finite() || !top.is_finite() {
                return None;
            }
            let scale = grid_step(origin, top)?;
            out.origin[axis] = origin;
            out.scale[axis] = scale;
            for l in (0..8).filter(used) {
                out.q[axis][l] = quantize_down(node.bounds[axis][l], scale, origin);
                out.q[3 + axis][l] = quantize_up(node.bounds[3 + axis][l], scale, origin);
            }
        }
        Some(out)
    }
}

/// The decoding every kernel performs: a multiplication then an addition, each rounded.
#[inline(always)]
fn decode(q: u8, scale: f32, origin: f32) -> f32 {
    f32::from(q) * scale + origin
}

/// The smallest power of two `s` with `decode(255, s, origin) >= top`.
fn grid_step(origin: f32, top: f32) -> Option<f32> {
    let extent = top - origin;
    if !extent.is_finite() {
        return None;
    }
    // A power of two at or above extent / 255 (the smallest normal one for a flat node).
    let mut s = (extent / 255.0).max(f32::MIN_POSITIVE);
    let bits = s.to_bits();
    if bits & 0x007f_ffff != 0 {
        s = f32::from_bits((bits & 0xff80_0000) + 0x0080_0000);
    }
    // Rounding of the addition may leave the top short: take the next step until it is not.
    while decode(255, s, origin) < top {
        s *= 2.0;
        if !s.is_finite() {
            return None;
        }
    }
    Some(s)
}

/// The largest `q` whose decoded value is at or below `v` (`q = 0` decodes to the origin,
/// which is at or below every lower bound of the node).
fn quantize_down(v: f32, scale: f32, origin: f32) -> u8 {
    let mut q = ((v - origin) / scale).floor().clamp(0.0, 255.0) as u8;
    while q > 0 && decode(q, scale, origin) > v {
        q -= 1;
    }
    q
}

/// The smallest `q` whose decoded value is at or above `v` (`q = 255` is, by [`grid_step`]).
fn quantize_up(v: f32, scale: f32, origin: f32) -> u8 {
    let mut q = ((v - origin) / scale).ceil().clamp(0.0, 255.0) as u8;
    while q < 255 && decode(q, scale, origin) < v {
        q += 1;
    }
    q
}

/// A quantised 8-wide BVH: the nodes of a [`Bvh8`], one for one (same indices, same leaves).
#[derive(Clone, Debug)]
pub struct QBvh8 {
    /// Nodes, root first.
    pub nodes: Vec<QBvh8Node>,
}

impl QBvh8 {
    /// Quantises every node of `bvh8`; `None` where a box is not finite or a leaf holds more
    /// than 65,535 slots (the float layout then serves).
    ///
    /// ```
    /// use oxray_bvh::{build_bvh2, BuildConfig, Bvh8, QBvh8};
    /// use oxray_core::Aabb;
    /// use glam::Vec3;
    /// let boxes: Vec<Aabb> = (0..1000)
    ///     .map(|i| Aabb::new(Vec3::splat(i as f32 * 0.37), Vec3::splat(i as f32 * 0.37 + 0.5)))
    ///     .collect();
    /// let b8 = Bvh8::from(&build_bvh2(&boxes, &BuildConfig::BALANCED));
    /// let q = QBvh8::quantize(&b8).unwrap();
    /// // Every decoded box holds the box it stands for.
    /// for (n, qn) in b8.nodes.iter().zip(&q.nodes) {
    ///     for lane in (0..8).filter(|&l| n.is_used(l)) {
    ///         let (exact, wide) = (n.child_bounds(lane), qn.child_bounds(lane));
    ///         assert!(wide.min.cmple(exact.min).all() && wide.max.cmpge(exact.max).all());
    ///     }
    /// }
    /// assert_eq!(std::mem::size_of_val(&q.nodes[0]) * 2, std::mem::size_of_val(&b8.nodes[0]));
    /// ```
    #[must_use]
    pub fn quantize(bvh8: &Bvh8) -> Option<QBvh8> {
        let nodes: Option<Vec<QBvh8Node>> =
            bvh8.nodes.par_iter().map(QBvh8Node::quantize).collect();
        nodes.map(|nodes| QBvh8 { nodes })
    }

    /// Bytes held by the nodes.
    #[must_use]
    pub fn memory(&self) -> usize {
        std::mem::size_of_val(&self.nodes[..])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_boxes::random_boxes;
    use crate::{build_bvh2, BuildConfig};

    #[test]
    fn decoded_boxes_hold_the_exact_ones_and_keep_the_tree() {
        // Far from the origin and tiny, huge, flat: the cases where the addition rounds.
        for (n, seed, offset, size) in [
            (1, 1, 0.0, 1.0),
            (500, 2, 0.0, 1.0),
            (5000, 3, 1.0e6, 0.5),
            (2000, 4, -3.0e4, 1.0e-3),
            (2000, 5, 0.0, 1.0e30),
            (2000, 6, 1.0e-30, 1.0e-35),
        ] {
            let b8 = Bvh8::from(&build_bvh2(
                &random_boxes(n, seed, offset, size),
                &BuildConfig::BALANCED,
            ));
            let q = QBvh8::quantize(&b8).unwrap();
            assert_eq!(q.nodes.len(), b8.nodes.len());
            for (node, qn) in b8.nodes.iter().zip(&q.nodes) {
                for lane in 0..8 {
                    if !node.is_used(lane) {
                        assert_eq!(qn.valid & (1 << lane), 0);
                        assert!(!qn.child_bounds(lane).is_valid());
                        continue;
                    }
                    let (exact, wide) = (node.child_bounds(lane), qn.child_bounds(lane));
                    assert!(
                        wide.min.cmple(exact.min).all() && wide.max.cmpge(exact.max).all(),
                        "{exact:?} not in {wide:?} (n = {n}, offset {offset}, size {size})"
                    );
                    assert_eq!(
                        (qn.child[lane], u32::from(qn.count[lane])),
                        (node.child[lane], node.count[lane])
                    );
                }
            }
        }
    }

    #[test]
    fn the_grid_is_tight_for_ordinary_nodes() {
        // A grid of 255 steps over the node: a child's box grows by at most two steps a side.
        let b8 = Bvh8::from(&build_bvh2(
            &random_boxes(3000, 7, 0.0, 10.0),
            &BuildConfig::BALANCED,
        ));
        let q = QBvh8::quantize(&b8).unwrap();
        for (node, qn) in b8.nodes.iter().zip(&q.nodes) {
            for lane in (0..8).filter(|&l| node.is_used(l)) {
                let (exact, wide) = (node.child_bounds(lane), qn.child_bounds(lane));
                for axis in 0..3 {
                    let step = qn.scale[axis];
                    assert!(exact.min[axis] - wide.min[axis] <= 2.0 * step);
                    assert!(wide.max[axis] - exact.max[axis] <= 2.0 * step);
                }
            }
        }
    }

    #[test]
    fn boxes_that_cannot_be_quantised_give_none() {
        let mut b8 = Bvh8::from(&build_bvh2(
            &random_boxes(100, 8, 0.0, 1.0),
            &BuildConfig::BALANCED,
        ));
        b8.nodes[0].bounds[3][0] = f32::INFINITY;
        assert!(QBvh8::quantize(&b8).is_none());
        let mut b8 = Bvh8::from(&build_bvh2(
            &random_boxes(100, 9, 0.0, 1.0),
            &BuildConfig::BALANCED,
        ));
        let lane = (0..8)
            .find(|&l| b8.nodes[0].count[l] > 0 || b8.nodes[0].is_used(l))
            .unwrap();
        b8.nodes[0].count[lane] = 70_000;
        assert!(QBvh8::quantize(&b8).is_none());
        // Extents beyond f32's range.
        assert!(grid_step(-3.0e38, 3.0e38).is_none());
    }
}
