//! Updates (refits) of built structures (guide §5.6): the same tree, new primitive data. Leaf
//! boxes are recomputed from the new primitives, then node boxes bottom-up over the existing
//! wide layouts (the 4-wide one, and the 8-wide one where the structure has it); the topology (which primitive is in which leaf, which node is where) never
//! changes, so the traversal code and every table that resolves a hit stay as they are.
//!
//! A refit keeps the hits exact (every box still holds its primitives) but not the tree's
//! quality: primitives that move apart stretch the boxes of the leaves and nodes that hold
//! them, and traversal visits more nodes. The SAH cost ([`crate::BvhStats::sah_cost`]) of the
//! refit tree against a rebuild measures that; rebuild when it has grown too much.

use crate::gas::{
    check_indices, decode_curve, decode_sphere, decode_triangle, GasData, GasKind, InputShape,
    NO_PRIMITIVE,
};
use crate::sphere::Sphere;
use crate::triangle::is_degenerate;
use crate::triangle4::Triangle4;
use crate::wide::WideNode;
use glam::Vec3;
use oxray_core::validate::{validate_sbt_offsets, validate_structure};
use oxray_core::{
    Aabb, BuildError, BuildFlags, BuildInput, BuildOperation, BuildOptions, CustomPrimitiveInput,
    InputLocation, UpdateRule,
};
use rayon::prelude::*;

/// Recomputes every box of a wide BVH: leaf lanes from `leaf(first_slot, count)`, inner lanes
/// as the union of their child node's lanes, bottom-up. Relies on every child node being
/// stored after its parent (as the collapse lays them out, and as the loader checks). Returns
/// the box of the root's lanes.
pub(crate) fn refit_nodes<N: WideNode>(
    nodes: &mut [N],
    leaf: impl Fn(u32, u32) -> Aabb + Sync + Send,
) -> Aabb {
    nodes.par_iter_mut().for_each(|n| {
        for lane in 0..N::WIDTH {
            if n.count(lane) > 0 {
                let b = leaf(n.child(lane), n.count(lane));
                n.set_bounds(lane, &b);
            }
        }
    });
    for i in (0..nodes.len()).rev() {
        for lane in 0..N::WIDTH {
            let (child, count) = (nodes[i].child(lane), nodes[i].count(lane));
            if count == 0 && child != u32::MAX {
                let b = nodes[child as usize].bounds();
                nodes[i].set_bounds(lane, &b);
            }
        }
    }
    nodes.first().map_or(Aabb::EMPTY, |root| root.bounds())
}

/// The lane value of an inactive triangle: NaN everywhere, which the watertight test never
/// hits (its determinant is not finite) on any backend.
fn set_inactive(block: &mut Triangle4, lane: usize) {
    block.set(lane, &[[f32::NAN; 3]; 3]);
}

/// Marks the lanes of inactive primitives (`active[global] == false`) with NaN.
pub(crate) fn deactivate_lanes(blocks: &mut [Triangle4], slot_prim: &[u32], active: &[bool]) {
    blocks.par_iter_mut().enumerate().for_each(|(b, block)| {
        for lane in 0..4 {
            let g = slot_prim[b * 4 + lane];
            if g != NO_PRIMITIVE && !active[g as usize] {
                set_inactive(block, lane);
            }
        }
    });
}

/// Refits the node boxes of a triangle GAS from its blocks; returns the new bounds.
pub(crate) fn refit_triangle_boxes(gas: &mut GasData) -> Aabb {
    let blocks = &gas.triangles;
    let leaf = |first: u32, count: u32| {
        let mut b = Aabb::EMPTY;
        for slot in first as usize..(first + count) as usize {
            let (block, lane) = (&blocks[slot / 4], slot % 4);
            if block.v[0][0][lane].is_nan() {
                continue;
            }
            for v in &block.v {
                b.grow(Vec3::new(v[0][lane], v[1][lane], v[2][lane]));
            }
        }
        b
    };
    if let Some(b8) = &mut gas.bvh8 {
        refit_nodes(&mut b8.nodes, leaf);
    }
    refit_nodes(&mut gas.bvh.nodes, leaf)
}

/// Refits the node boxes of a custom-primitive GAS from its boxes; returns the new bounds.
pub(crate) fn refit_aabb_boxes(gas: &mut GasData) -> Aabb {
    let boxes = &gas.aabbs;
    let leaf = |first: u32, count: u32| {
        boxes[first as usize..(first + count) as usize]
            .iter()
            .filter(|b| b.is_finite_valid())
            .fold(Aabb::EMPTY, |a, b| a.union(b))
    };
    if let Some(b8) = &mut gas.bvh8 {
        refit_nodes(&mut b8.nodes, leaf);
    }
    refit_nodes(&mut gas.bvh.nodes, leaf)
}

/// Refits the node boxes of a sphere GAS from its spheres; returns the new bounds.
pub(crate) fn refit_sphere_boxes(gas: &mut GasData) -> Aabb {
    let spheres = &gas.spheres;
    let leaf = |first: u32, count: u32| {
        spheres[first as usize..(first + count) as usize]
            .iter()
            .filter(|s| s.is_active())
            .fold(Aabb::EMPTY, |a, s| a.union(&s.bounds()))
    };
    if let Some(b8) = &mut gas.bvh8 {
        refit_nodes(&mut b8.nodes, leaf);
    }
    refit_nodes(&mut gas.bvh.nodes, leaf)
}

/// Refits the node boxes of a curve GAS from its segments; returns the new bounds.
pub(crate) fn refit_curve_boxes(gas: &mut GasData) -> Aabb {
    let curves = &gas.curves;
    let leaf = |first: u32, count: u32| {
        curves[first as usize..(first + count) as usize]
            .iter()
            .filter(|s| s.is_active())
            .fold(Aabb::EMPTY, |a, s| a.union(&s.bounds()))
    };
    if let Some(b8) = &mut gas.bvh8 {
        refit_nodes(&mut b8.nodes, leaf);
    }
    refit_nodes(&mut gas.bvh.nodes, leaf)
}

/// Box `i` of a validated custom-primitive input.
pub(crate) fn read_aabb(c: &CustomPrimitiveInput<'_>, i: usize) -> Aabb {
    let a = c.aabbs;
    let stride = a.effective_stride();
    let f: [f32; 6] = std::array::from_fn(|k| {
        let at = i * stride + 4 * k;
        f32::from_le_bytes(a.data[at..at + 4].try_into().unwrap_or([0; 4]))
    });
    Aabb::new(Vec3::new(f[0], f[1], f[2]), Vec3::new(f[3], f[4], f[5]))
}

fn rule(r: UpdateRule) -> BuildError {
    BuildError::InvalidUpdate(r)
}

impl GasData {
    /// Checks an update of this structure against the rules of guide §5.6 without changing
    /// anything: `operation` is `Update`, the structure was built with `ALLOW_UPDATE`, the
    /// flags are the build's, the inputs have the build's types, counts, formats, SBT records
    /// and geometry flags, and every index and SBT index offset is in range.
    pub fn check_update(
        &self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(), BuildError> {
        if options.operation != BuildOperation::Update {
            return Err(rule(UpdateRule::NotAnUpdate));
        }
        if !self.build_flags.contains(BuildFlags::ALLOW_UPDATE) {
            return Err(rule(UpdateRule::NotAllowed));
        }
        if options.flags != self.build_flags {
            return Err(rule(UpdateRule::Flags {
                built: self.build_flags,
                given: options.flags,
            }));
        }
        if options.motion.has_motion() {
            // An updatable structure has no motion (motion builds refuse ALLOW_UPDATE).
            return Err(rule(UpdateRule::Motion {
                built: self.motion_options(),
                given: options.motion,
            }));
        }
        if inputs.len() != self.inputs.len() {
            return Err(rule(UpdateRule::InputCount {
                built: self.inputs.len(),
                given: inputs.len(),
            }));
        }
        validate_structure(options, inputs)?;
        for (i, (input, built)) in inputs.iter().zip(&self.shapes).enumerate() {
            let Some(shape) = InputShape::of(input) else {
                return Err(rule(UpdateRule::InputKind {
                    input: i,
                    built: self.kind(),
                    given: input.kind(),
                }));
            };
            if shape.kind != built.kind {
                return Err(rule(UpdateRule::InputKind {
                    input: i,
                    built: self.kind(),
                    given: input.kind(),
                }));
            }
            let count = |what, b: u32, g: u32| {
                if b == g {
                    Ok(())
                } else {
                    Err(rule(UpdateRule::Count {
                        input: i,
                        what,
                        built: b as u64,
                        given: g as u64,
                    }))
                }
            };
            let vertices = match shape.kind {
                GasKind::Triangles => "vertices",
                GasKind::CustomPrimitives => "AABBs",
                GasKind::Spheres => "spheres",
                GasKind::Curves => "control points",
            };
            count(vertices, built.num_vertices, shape.num_vertices)?;
            count("index triplets", built.num_indices, shape.num_indices)?;
            count("SBT records", built.num_sbt_records, shape.num_sbt_records)?;
            let describe = |what| Err(rule(UpdateRule::Description { input: i, what }));
            if shape.vertex_format != built.vertex_format {
                return describe("the vertex format");
            }
            if (shape.index_format == 0) != (built.index_format == 0) {
                return describe("the presence of an index buffer");
            }
            if shape.index_format != built.index_format {
                return describe("the index format");
            }
            if shape.pre_transform != built.pre_transform {
                return describe("the presence of a pre-transform");
            }
            if shape.single_radius != built.single_radius {
                return describe("singleRadius");
            }
            if shape.sbt_offset_size != built.sbt_offset_size {
                return describe("the SBT index offset buffer (presence or size)");
            }
            let rec = &self.inputs[i];
            if input.primitive_index_offset() != rec.primitive_index_offset {
                return describe("the primitive index offset");
            }
            let base = rec.sbt_base as usize;
            if self.record_flags.get(base..base + input.flags().len()) != Some(input.flags()) {
                return describe("the geometry flags of its SBT records");
            }
            let at = InputLocation { input: i };
            if let Some(o) = input.sbt_index_offsets() {
                validate_sbt_offsets(at, o, input.num_primitives(), input.flags().len() as u32)?;
            }
            if let BuildInput::Triangles(t) = input {
                check_indices(at, t)?;
            }
        }
        Ok(())
    }

    /// Updates (refits) the structure in place with new buffer contents (guide §5.6): the same
    /// inputs as the build up to the contents of their buffers (vertices, indices, boxes, SBT
    /// index offsets, the pre-transform matrix). Every rule is checked first
    /// ([`check_update`](Self::check_update)); on an error nothing has changed.
    ///
    /// Primitives are re-read into their leaf slots, inactive ones (degenerate triangles,
    /// spheres whose radius is not positive) are masked
    /// and ones inactive at the build may become active; then leaf and node boxes are refit
    /// bottom-up. The hits are those of the new data; the tree's quality is that of the old.
    ///
    /// ```
    /// use oxray_bvh::GasData;
    /// use oxray_core::{BuildFlags, BuildOperation, BuildOptions, TriangleInput, VertexBuffer};
    /// let mut v = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    /// let mut options = BuildOptions::new(BuildFlags::ALLOW_UPDATE);
    /// let mut gas = GasData::build(&options, &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
    /// v[2] = [0.0, 3.0, 0.0];
    /// options.operation = BuildOperation::Update;
    /// gas.update(&options, &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
    /// assert_eq!(gas.bounds().max.y, 3.0);
    /// # Ok::<(), oxray_core::BuildError>(())
    /// ```
    pub fn update(
        &mut self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(), BuildError> {
        self.check_update(options, inputs)?;
        self.apply_update(inputs);
        Ok(())
    }

    /// The update after its checks.
    pub(crate) fn apply_update(&mut self, inputs: &[BuildInput<'_>]) {
        let starts: Vec<u32> = self.inputs.iter().map(|r| r.first).collect();
        let locate = |g: u32| {
            let i = starts.partition_point(|&f| f <= g) - 1;
            (i, (g - starts[i]) as usize)
        };
        let slot_prim = &self.slot_prim;
        match self.kind {
            GasKind::Triangles => {
                self.triangles
                    .par_iter_mut()
                    .enumerate()
                    .for_each(|(b, block)| {
                        for lane in 0..4 {
                            let g = slot_prim[b * 4 + lane];
                            if g == NO_PRIMITIVE {
                                continue;
                            }
                            let (i, k) = locate(g);
                            let BuildInput::Triangles(t) = &inputs[i] else {
                                unreachable!("checked: the inputs are triangles")
                            };
                            let tri = decode_triangle(t, k);
                            if is_degenerate(tri[0], tri[1], tri[2]) {
                                set_inactive(block, lane);
                            } else {
                                block.set(lane, &tri.map(|p| p.to_array()));
                            }
                        }
                    });
                self.bounds = refit_triangle_boxes(self);
            }
            GasKind::CustomPrimitives => {
                self.aabbs.par_iter_mut().enumerate().for_each(|(slot, a)| {
                    if slot_prim[slot] == NO_PRIMITIVE {
                        *a = Aabb::EMPTY;
                        return;
                    }
                    let (i, k) = locate(slot_prim[slot]);
                    let BuildInput::CustomPrimitives(c) = &inputs[i] else {
                        unreachable!("checked: the inputs are custom primitives")
                    };
                    let b = read_aabb(c, k);
                    *a = if b.is_finite_valid() { b } else { Aabb::EMPTY };
                });
                self.bounds = refit_aabb_boxes(self);
            }
            GasKind::Spheres => {
                self.spheres
                    .par_iter_mut()
                    .enumerate()
                    .for_each(|(slot, s)| {
                        let (i, k) = locate(slot_prim[slot]);
                        let BuildInput::Spheres(input) = &inputs[i] else {
                            unreachable!("checked: the inputs are spheres")
                        };
                        let new = decode_sphere(input, k);
                        *s = if new.is_active() {
                            new
                        } else {
                            Sphere::INACTIVE
                        };
                    });
                self.bounds = refit_sphere_boxes(self);
            }
            GasKind::Curves => {
                self.curves
                    .par_iter_mut()
                    .enumerate()
                    .for_each(|(slot, s)| {
                        let (i, k) = locate(slot_prim[slot]);
                        let BuildInput::Curves(input) = &inputs[i] else {
                            unreachable!("checked: the inputs are curves")
                        };
                        let new = decode_curve(input, k);
                        *s = if new.is_active() {
                            new
                        } else {
                            new.deactivated()
                        };
                    });
                self.bounds = refit_curve_boxes(self);
            }
        }
        self.update_sbt_offsets(inputs);
    }
}
