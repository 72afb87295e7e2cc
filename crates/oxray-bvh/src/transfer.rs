//! Structures moved between layouts and devices: what another backend keeps of a structure
//! besides its arrays ([`GasData::skeleton`]), a structure assembled back from a binary tree
//! over another layout's leaf slots ([`GasData::assemble`]), a binary tree made from a wide
//! layout ([`Bvh2::from_wide`]) and binary trees refit in place ([`Bvh2::refit`]).
//!
//! A GPU keeps its own node and primitive arrays; saving its structure (guide §5.7, and
//! beyond: loading it on another backend) reads them back and assembles the CPU's layout from
//! them, and loading a saved structure on a GPU derives the GPU's binary tree from the saved
//! 4-wide one. Neither is the tree a fresh build would make, but every box holds its
//! primitives, so the hits are the same (which of two primitives at exactly the same distance
//! is reported may differ, as between any two layouts).

use crate::bvh2::{Bvh2, Bvh2Node};
use crate::bvh4::Bvh4;
use crate::curve::CurveSegment;
use crate::gas::{pack_triangles, GasData, GasKind, NO_PRIMITIVE};
use crate::sphere::Sphere;
use crate::triangle::is_degenerate;
use crate::wide::WideNode;
use bytemuck::Zeroable;
use glam::Vec3;
use oxray_core::{Aabb, BuildInput, LoadError};

/// The primitives of every leaf slot of another layout, by kind.
#[derive(Clone, Debug)]
pub enum SlotPrimitives {
    /// Triangles: three vertices per slot.
    Triangles(Vec<[[f32; 3]; 3]>),
    /// Custom primitives' boxes ([`Aabb::EMPTY`] where inactive).
    Aabbs(Vec<Aabb>),
    /// Spheres.
    Spheres(Vec<Sphere>),
    /// Curve segments.
    Curves(Vec<CurveSegment>),
}

impl SlotPrimitives {
    fn len(&self) -> usize {
        match self {
            SlotPrimitives::Triangles(v) => v.len(),
            SlotPrimitives::Aabbs(v) => v.len(),
            SlotPrimitives::Spheres(v) => v.len(),
            SlotPrimitives::Curves(v) => v.len(),
        }
    }

    fn kind(&self) -> GasKind {
        match self {
            SlotPrimitives::Triangles(_) => GasKind::Triangles,
            SlotPrimitives::Aabbs(_) => GasKind::CustomPrimitives,
            SlotPrimitives::Spheres(_) => GasKind::Spheres,
            SlotPrimitives::Curves(_) => GasKind::Curves,
        }
    }
}

fn invalid(what: &'static str, index: usize) -> LoadError {
    LoadError::Invalid {
        what,
        index: index as u64,
    }
}

impl GasData {
    /// Everything of the structure but its tree and primitives: the inputs' records and
    /// shapes, the SBT records' flags and per-primitive offsets, the counts, bounds, flags and
    /// lineage. What a backend that keeps the tree and primitives elsewhere (a GPU) needs to
    /// check an update (guide §5.6), resolve hits and save the structure. Motion keys are not
    /// kept (a structure with motion has no other layout yet).
    ///
    /// ```
    /// use oxray_bvh::GasData;
    /// use oxray_core::{BuildOptions, TriangleInput, VertexBuffer};
    /// let v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    /// let gas = GasData::build(&BuildOptions::default(), &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
    /// let s = gas.skeleton();
    /// assert_eq!((s.num_primitives, s.triangles.len(), s.bounds), (1, 0, gas.bounds));
    /// # Ok::<(), oxray_core::BuildError>(())
    /// ```
    #[must_use]
    pub fn skeleton(&self) -> GasData {
        GasData {
            kind: self.kind,
            build_flags: self.build_flags,
            bvh: Bvh4 { nodes: Vec::new() },
            bvh8: None,
            triangles: Vec::new(),
            aabbs: Vec::new(),
            spheres: Vec::new(),
            curves: Vec::new(),
            slot_prim: Vec::new(),
            sbt_offsets: self.sbt_offsets.clone(),
            inputs: self.inputs.clone(),
            record_flags: self.record_flags.clone(),
            bounds: self.bounds,
            num_primitives: self.num_primitives,
            shapes: self.shapes.clone(),
            lineage: self.lineage,
            motion: None,
        }
    }

    /// Takes the SBT index offsets of an update's inputs (guide §5.6: their contents may
    /// change); the inputs must have passed [`check_update`](Self::check_update).
    pub fn update_sbt_offsets(&mut self, inputs: &[BuildInput<'_>]) {
        if self.sbt_offsets.is_empty() {
            return;
        }
        let mut at = 0;
        for input in inputs {
            let n = input.num_primitives() as usize;
            let offsets = input.sbt_index_offsets();
            if let Some(out) = self.sbt_offsets.get_mut(at..at + n) {
                for (p, o) in out.iter_mut().enumerate() {
                    *o = offsets.map_or(0, |o| o.get(p));
                }
            }
            at += n;
        }
    }

    /// The primitives of an update's inputs by leaf slot, as the CPU's update reads them
    /// (guide §5.6): slot `s` holds primitive `slot_prim[s]`, inactive where the CPU's update
    /// makes it so (a degenerate triangle is NaN, an invalid box [`Aabb::EMPTY`], a sphere
    /// [`Sphere::INACTIVE`], a segment [`CurveSegment::deactivated`]); a slot without a
    /// primitive gets an inactive one. For a backend that keeps slots elsewhere (a GPU). The
    /// inputs must have passed [`check_update`](Self::check_update) and be of this structure's
    /// kind.
    #[must_use]
    pub fn update_slot_primitives(
        &self,
        slot_prim: &[u32],
        inputs: &[BuildInput<'_>],
    ) -> SlotPrimitives {
        use crate::gas::{decode_curve, decode_sphere, decode_triangle};
        use rayon::prelude::*;
        let starts: Vec<u32> = self.inputs.iter().map(|r| r.first).collect();
        let locate = |g: u32| -> Option<(&BuildInput<'_>, usize)> {
            if g == NO_PRIMITIVE || starts.is_empty() {
                return None;
            }
            let i = starts.partition_point(|&f| f <= g).saturating_sub(1);
            let k = (g - starts[i]) as usize;
            inputs
                .get(i)
                .filter(|input| k < input.num_primitives() as usize)
                .map(|input| (input, k))
        };
        match self.kind {
            GasKind::Triangles => SlotPrimitives::Triangles(
                slot_prim
                    .par_iter()
                    .map(|&g| match locate(g) {
                        Some((BuildInput::Triangles(t), k)) => {
                            let p = decode_triangle(t, k);
                            if is_degenerate(p[0], p[1], p[2]) {
                                [[f32::NAN; 3]; 3]
                            } else {
                                p.map(|v| v.to_array())
                            }
                        }
                        _ => [[f32::NAN; 3]; 3],
                    })
                    .collect(),
            ),
            GasKind::CustomPrimitives => SlotPrimitives::Aabbs(
                slot_prim
                    .par_iter()
                    .map(|&g| match locate(g) {
                        Some((BuildInput::CustomPrimitives(c), k)) => {
                            let b = crate::refit::read_aabb(c, k);
                            if b.is_finite_valid() {
                                b
                            } else {
                                Aabb::EMPTY
                            }
                        }
                        _ => Aabb::EMPTY,
                    })
                    .collect(),
            ),
            GasKind::Spheres => SlotPrimitives::Spheres(
                slot_prim
                    .par_iter()
                    .map(|&g| match locate(g) {
                        Some((BuildInput::Spheres(input), k)) => {
                            let s = decode_sphere(input, k);
                            if s.is_active() {
                                s
                            } else {
                                Sphere::INACTIVE
                            }
                        }
                        _ => Sphere::INACTIVE,
                    })
                    .collect(),
            ),
            GasKind::Curves => SlotPrimitives::Curves(
                slot_prim
                    .par_iter()
                    .map(|&g| match locate(g) {
                        Some((BuildInput::Curves(input), k)) => {
                            let s = decode_curve(input, k);
                            if s.is_active() {
                                s
                            } else {
                                s.deactivated()
                            }
                        }
                        _ => CurveSegment::zeroed().deactivated(),
                    })
                    .collect(),
            ),
        }
    }

    /// Assembles a structure from a binary `tree` whose leaves are ranges of another layout's
    /// leaf slots, the global primitive of each slot (`slot_prim`, [`NO_PRIMITIVE`] for slots no
    /// leaf holds) and each slot's primitive, over the tables of `skeleton`: the 4-wide layout
    /// is collapsed from the tree, triangles are packed into blocks as a build packs them, and
    /// every box is refit to the primitives. Inactive primitives (degenerate triangles, empty
    /// boxes, spheres and segments without a positive radius) stay in their slots, never hit.
    ///
    /// The arrays come from another device's memory, so they are checked as a loader checks
    /// bytes: every leaf inside the slots, every slot a leaf holds naming a primitive of the
    /// structure; otherwise [`LoadError::Invalid`].
    pub fn assemble(
        skeleton: &GasData,
        tree: &Bvh2,
        slot_prim: &[u32],
        prims: SlotPrimitives,
    ) -> Result<GasData, LoadError> {
        if prims.kind() != skeleton.kind {
            return Err(invalid("primitive kind", 0));
        }
        if prims.len() != slot_prim.len() {
            return Err(invalid("slot count", prims.len()));
        }
        check_tree(tree, slot_prim, skeleton.num_primitives)?;
        let mut gas = skeleton.skeleton();
        if !gas
            .build_flags
            .contains(oxray_core::BuildFlags::ALLOW_UPDATE)
        {
            // Only an update reads the inputs' shapes; a saved structure keeps them only then.
            gas.shapes = Vec::new();
        }
        gas.bvh = Bvh4::from(tree);
        match prims {
            SlotPrimitives::Triangles(tris) => {
                let nan = [Vec3::splat(f32::NAN); 3];
                let mut by_prim = vec![nan; skeleton.num_primitives as usize];
                for (&g, t) in slot_prim.iter().zip(&tris) {
                    if g == NO_PRIMITIVE {
                        continue;
                    }
                    let p = t.map(Vec3::from);
                    by_prim[g as usize] = if is_degenerate(p[0], p[1], p[2]) {
                        nan
                    } else {
                        p
                    };
                }
                (gas.triangles, gas.slot_prim) = pack_triangles(&mut gas.bvh, slot_prim, &by_prim);
                gas.bounds = crate::refit::refit_triangle_boxes(&mut gas);
            }
            SlotPrimitives::Aabbs(boxes) => {
                gas.slot_prim = slot_prim.to_vec();
                gas.aabbs = boxes
                    .into_iter()
                    .map(|b| if b.is_finite_valid() { b } else { Aabb::EMPTY })
                    .collect();
                gas.bounds = crate::refit::refit_aabb_boxes(&mut gas);
            }
            SlotPrimitives::Spheres(spheres) => {
                gas.slot_prim = slot_prim.to_vec();
                gas.spheres = spheres
                    .into_iter()
                    .map(|s| if s.is_active() { s } else { Sphere::INACTIVE })
                    .collect();
                gas.bounds = crate::refit::refit_sphere_boxes(&mut gas);
            }
            SlotPrimitives::Curves(curves) => {
                gas.slot_prim = slot_prim.to_vec();
                gas.curves = curves;
                gas.bounds = crate::refit::refit_curve_boxes(&mut gas);
            }
        }
        Ok(gas)
    }
}

/// Checks a tree from another device, walking it from the root: every child pair inside the
/// node array, no node reached twice (so that no walk loops or repeats),
/// leaves inside the slots, every slot a leaf holds naming one of the structure's primitives.
fn check_tree(tree: &Bvh2, slot_prim: &[u32], num_primitives: u32) -> Result<(), LoadError> {
    if tree.nodes.is_empty() {
        return Ok(());
    }
    let mut seen = vec![false; tree.nodes.len()];
    let mut stack = vec![0usize];
    while let Some(i) = stack.pop() {
        if std::mem::replace(&mut seen[i], true) {
            return Err(invalid("node reached twice", i));
        }
        let n = tree.nodes[i];
        if n.is_leaf() {
            let end = n.left_first as u64 + n.count as u64;
            if end > slot_prim.len() as u64 {
                return Err(invalid("leaf slot range", i));
            }
            let slots = &slot_prim[n.left_first as usize..end as usize];
            if slots
                .iter()
                .any(|&g| g == NO_PRIMITIVE || g >= num_primitives)
            {
                return Err(invalid("slot primitive", i));
            }
        } else {
            let c = n.left_first as usize;
            if c + 1 >= tree.nodes.len() {
                return Err(invalid("child node", i));
            }
            stack.push(c + 1);
            stack.push(c);
        }
    }
    Ok(())
}

/// A part of a wide node being split into binary nodes: a leaf lane or an inner child.
#[derive(Clone, Copy)]
enum Part {
    Leaf {
        bounds: Aabb,
        first: u32,
        count: u32,
    },
    Inner {
        bounds: Aabb,
        node: u32,
    },
}

impl Part {
    fn bounds(&self) -> Aabb {
        match self {
            Part::Leaf { bounds, .. } | Part::Inner { bounds, .. } => *bounds,
        }
    }
}

fn lanes<N: WideNode>(node: &N) -> Vec<Part> {
    (0..N::WIDTH)
        .filter(|&l| node.is_used(l))
        .map(|l| {
            let bounds = node.child_bounds(l);
            if node.count(l) > 0 {
                Part::Leaf {
                    bounds,
                    first: node.child(l),
                    count: node.count(l),
                }
            } else {
                Part::Inner {
                    bounds,
                    node: node.child(l),
                }
            }
        })
        .collect()
}

impl Bvh2 {
    /// A binary tree with the leaves of a wide layout (4- or 8-wide nodes, root first): each
    /// wide node becomes a small balanced binary subtree over its lanes, inner boxes the union
    /// of their children's. `prim_order` is the identity over the slots the leaves reach, so
    /// leaves point at the same slots as the wide layout's. The wide nodes must form a tree
    /// (as a loader has checked); children indices past the array end the walk there.
    ///
    /// ```
    /// use oxray_bvh::{Bvh2, GasData};
    /// use oxray_core::{BuildOptions, TriangleInput, VertexBuffer};
    /// let v: Vec<[f32; 3]> = (0..300).map(|i| [i as f32, (i % 7) as f32, (i % 3) as f32]).collect();
    /// let gas = GasData::build(&BuildOptions::default(), &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
    /// let tree = Bvh2::from_wide(&gas.bvh.nodes);
    /// assert_eq!(tree.nodes[0].bounds(), gas.bounds);
    /// # Ok::<(), oxray_core::BuildError>(())
    /// ```
    pub fn from_wide<N: WideNode>(wide: &[N]) -> Bvh2 {
        let Some(root) = wide.first() else {
            return Bvh2::default();
        };
        let root_parts = lanes(root);
        if root_parts.is_empty() {
            return Bvh2::default();
        }
        let mut nodes = vec![Bvh2Node::zeroed()];
        let mut slots = 0u32;
        let mut work = vec![(0usize, root_parts)];
        while let Some((at, mut parts)) = work.pop() {
            // A lone inner child is that node's lanes (a bounded number of times: a malformed
            // layout could chain lone children into a loop).
            let mut hops = 0;
            while let [Part::Inner { node, .. }] = parts[..] {
                hops += 1;
                parts = match wide.get(node as usize) {
                    Some(n) if hops <= wide.len() => lanes(n),
                    _ => Vec::new(),
                };
            }
            let bounds = parts.iter().fold(Aabb::EMPTY, |a, p| a.union(&p.bounds()));
            match parts[..] {
                [] => {
                    // Only in a malformed layout: a leaf that no ray enters.
                    nodes[at] = leaf_node(Aabb::EMPTY, 0, 1);
                }
                [Part::Leaf {
                    bounds,
                    first,
                    count,
                }] => {
                    nodes[at] = leaf_node(bounds, first, count);
                    slots = slots.max(first.saturating_add(count));
                }
                _ => {
                    let first = nodes.len();
                    nodes.push(Bvh2Node::zeroed());
                    nodes.push(Bvh2Node::zeroed());
                    nodes[at] = Bvh2Node {
                        min: bounds.min.to_array(),
                        left_first: first as u32,
                        max: bounds.max.to_array(),
                        count: 0,
                    };
                    let right = parts.split_off(parts.len().div_ceil(2));
                    work.push((first + 1, right));
                    work.push((first, parts));
                }
            }
        }
        Bvh2 {
            nodes,
            prim_order: (0..slots).collect(),
        }
    }

    /// Recomputes every box bottom-up: leaves from `leaf(first_slot, count)`, inner nodes as the
    /// union of their children. Returns the root's box ([`Aabb::EMPTY`] for an empty tree).
    pub fn refit(&mut self, leaf: impl Fn(u32, u32) -> Aabb) -> Aabb {
        if self.nodes.is_empty() {
            return Aabb::EMPTY;
        }
        // Post-order with an explicit stack: (node, children done).
        let mut stack = vec![(0usize, false)];
        while let Some((i, done)) = stack.pop() {
            let n = self.nodes[i];
            if n.is_leaf() {
                let b = leaf(n.left_first, n.count);
                self.nodes[i].min = b.min.to_array();
                self.nodes[i].max = b.max.to_array();
            } else if done {
                let c = n.left_first as usize;
                let b = self.nodes[c].bounds().union(&self.nodes[c + 1].bounds());
                self.nodes[i].min = b.min.to_array();
                self.nodes[i].max = b.max.to_array();
            } else {
                let c = n.left_first as usize;
                if c + 1 >= self.nodes.len() {
                    continue;
                }
                stack.push((i, true));
                stack.push((c, false));
                stack.push((c + 1, false));
            }
        }
        self.nodes[0].bounds()
    }
}

fn leaf_node(bounds: Aabb, first: u32, count: u32) -> Bvh2Node {
    Bvh2Node {
        min: bounds.min.to_array(),
        left_first: first,
        max: bounds.max.to_array(),
        count,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gas::tests::{layout_leaves, tree_leaves};
    use crate::gas::GasData;
    use oxray_core::{BuildFlags, BuildOptions, TriangleInput, VertexBuffer};

    fn mesh(n: usize) -> Vec<[f32; 3]> {
        (0..3 * n)
            .map(|i| {
                let f = i as f32;
                [
                    f * 0.37 % 11.0,
                    (f * 0.71) % 5.0,
                    (f * 0.13) % 7.0 + (i % 3) as f32,
                ]
            })
            .collect()
    }

    #[test]
    fn a_binary_tree_from_the_wide_layout_has_its_leaves_and_boxes() {
        let v = mesh(2000);
        let gas = GasData::build(
            &BuildOptions::default(),
            &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()],
        )
        .unwrap();
        let tree = Bvh2::from_wide(&gas.bvh.nodes);
        assert_eq!(tree_leaves(&tree), layout_leaves(&gas));
        assert_eq!(tree.nodes[0].bounds(), gas.bounds);
        // Every inner box is the union of its children's.
        for n in tree.nodes.iter().filter(|n| !n.is_leaf()) {
            let c = n.left_first as usize;
            let u = tree.nodes[c].bounds().union(&tree.nodes[c + 1].bounds());
            assert_eq!(n.bounds(), u);
        }
    }

    #[test]
    fn a_structure_assembled_from_its_own_tree_and_slots_equals_the_build() {
        let v = mesh(1500);
        let (gas, tree) = GasData::build_with_tree(
            &BuildOptions::new(BuildFlags::ALLOW_UPDATE),
            &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()],
        )
        .unwrap();
        let slots: Vec<[[f32; 3]; 3]> = (0..gas.slot_prim.len())
            .map(|s| gas.triangles[s / 4].get(s % 4))
            .collect();
        let back = GasData::assemble(
            &gas.skeleton(),
            &tree,
            &gas.slot_prim,
            SlotPrimitives::Triangles(slots),
        )
        .unwrap();
        assert_eq!(back.slot_prim, gas.slot_prim);
        assert_eq!(back.bounds, gas.bounds);
        assert_eq!(back.to_bytes().len(), gas.to_bytes().len());
        for (a, b) in back.triangles.iter().zip(&gas.triangles) {
            for l in 0..4 {
                let (x, y) = (a.get(l), b.get(l));
                let same = x
                    .iter()
                    .flatten()
                    .zip(y.iter().flatten())
                    .all(|(p, q)| p.to_bits() == q.to_bits() || (p.is_nan() && q.is_nan()));
                assert!(same, "lane {l}: {x:?} vs {y:?}");
            }
        }
    }

    #[test]
    fn trees_and_slots_that_do_not_fit_are_refused() {
        let v = mesh(100);
        let (gas, tree) = GasData::build_with_tree(
            &BuildOptions::default(),
            &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()],
        )
        .unwrap();
        let slots = |n: usize| SlotPrimitives::Triangles(vec![[[0.0; 3]; 3]; n]);
        let n = gas.slot_prim.len();
        // Too few slots for the leaves.
        let short = &gas.slot_prim[..n / 2];
        assert!(GasData::assemble(&gas.skeleton(), &tree, short, slots(n / 2)).is_err());
        // A slot naming a primitive the structure does not have.
        let mut bad = gas.slot_prim.clone();
        let first_leaf = tree.nodes.iter().find(|n| n.is_leaf()).unwrap().left_first;
        bad[first_leaf as usize] = 10_000;
        assert!(GasData::assemble(&gas.skeleton(), &tree, &bad, slots(n)).is_err());
        // A child pointing back at the root.
        let mut looped = tree.clone();
        let c = looped.nodes[0].left_first as usize;
        let inner = if looped.nodes[c].is_leaf() { c + 1 } else { c };
        assert!(!looped.nodes[inner].is_leaf());
        looped.nodes[inner].left_first = 0;
        assert!(GasData::assemble(&gas.skeleton(), &looped, &gas.slot_prim, slots(n)).is_err());
        // Another kind.
        let boxes = SlotPrimitives::Aabbs(vec![Aabb::EMPTY; n]);
        assert!(GasData::assemble(&gas.skeleton(), &tree, &gas.slot_prim, boxes).is_err());
    }

    #[test]
    fn refit_makes_every_box_hold_its_leaves() {
        let v = mesh(500);
        let (gas, mut tree) = GasData::build_with_tree(
            &BuildOptions::default(),
            &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()],
        )
        .unwrap();
        let root = tree.refit(|first, _| {
            let f = first as f32;
            Aabb::new(Vec3::splat(f), Vec3::splat(f + 1.0))
        });
        for n in tree.nodes.iter().filter(|n| n.is_leaf()) {
            assert_eq!(n.min[0], n.left_first as f32);
        }
        let last = gas.slot_prim.len() as f32;
        assert!(root.min.x == 0.0 && root.max.x <= last + 1.0);
    }
}
