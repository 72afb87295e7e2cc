//! Updates (refits) of GASes on the device (guide §5.6): the same tree and leaf slots, new
//! primitives, boxes recomputed bottom-up by the kernels at the end of `kernels/build.cu`.
//!
//! A GAS built with `ALLOW_UPDATE` is built by the host's builder (which keeps a slot for every
//! primitive, inactive ones included, so that an update can make them active) and uploaded in
//! the binary layout; the upload keeps a [`RefitPlan`]: the global primitive of every leaf slot
//! (host and device), and the device nodes ordered by depth. An update then
//!
//! 1. checks the guide's rules against what the build kept ([`GasData::check_update`]), so that
//!    a refused update changes nothing and gives the CPU backend's typed error;
//! 2. writes the slots' new primitives: triangles are fetched from the inputs by the device
//!    (the vertices and indices copied as a device build copies them), with the CPU's
//!    degeneracy rule; boxes, spheres and curve segments are read by the host as the CPU's
//!    update reads them and copied into the slots;
//! 3. refits the node boxes, one launch per depth, deepest first;
//! 4. takes the new SBT index offsets into the slot table (and into a pipeline's copy of it).
//!
//! Every box is recomputed with exact minima and maxima of the same values the CPU's update
//! reads, so an updated GAS traces the hits of the CPU backend's update of the same build.

use crate::context::CudaContext;
use crate::device_build::upload_inputs;
use crate::error::{driver, CudaError};
use crate::gas::CudaGas;
use crate::layout::{NodeLayout, SlotInfo};
use cudarc::driver::{CudaSlice, LaunchConfig, PushKernelArg};
use oxray_bvh::{GasData, GasKind, SlotPrimitives, NO_PRIMITIVE};
use oxray_core::{Aabb, BuildError, BuildFlags, BuildInput, BuildOptions};
use rayon::prelude::*;

/// What an update of an uploaded GAS needs: the global primitive of each leaf slot, on the
/// host and the device, and the device nodes by depth.
#[derive(Debug)]
pub(crate) struct RefitPlan {
    /// Global primitive of each leaf slot ([`NO_PRIMITIVE`] for padding).
    pub(crate) slot_prim: Vec<u32>,
    d_slot_prim: CudaSlice<u32>,
    /// Device node indices, deepest level first.
    order: CudaSlice<u32>,
    /// `(first, count)` of each level in `order`, deepest first.
    levels: Vec<(u32, u32)>,
}

/// Words of one binary node (`layout.rs`).
const NODE_WORDS: usize = 16;

impl RefitPlan {
    /// The plan of a GAS uploaded with `nodes` (binary-layout words): `None` unless it was
    /// built with `ALLOW_UPDATE` in the binary layout (the BVH4 layout is not refit on the
    /// device; its update is refused).
    pub(crate) fn for_upload(
        ctx: &CudaContext,
        gas: &GasData,
        nodes: &[u32],
        layout: NodeLayout,
    ) -> Result<Option<RefitPlan>, CudaError> {
        if !gas.build_flags.contains(BuildFlags::ALLOW_UPDATE) || layout != NodeLayout::Bvh2 {
            return Ok(None);
        }
        let (order, levels) = levels(nodes);
        let upload = |w: &[u32]| {
            let w: &[u32] = if w.is_empty() { &[0] } else { w };
            ctx.stream
                .clone_htod(w)
                .map_err(driver("copying refit tables to the device"))
        };
        Ok(Some(RefitPlan {
            d_slot_prim: upload(&gas.slot_prim)?,
            order: upload(&order)?,
            slot_prim: gas.slot_prim.clone(),
            levels,
        }))
    }

    /// A copy of the plan's device tables (for a copy of the structure).
    pub(crate) fn duplicate(&self, ctx: &CudaContext) -> Result<RefitPlan, CudaError> {
        let copy = |w: &CudaSlice<u32>| {
            ctx.stream
                .clone_dtod(w)
                .map_err(driver("copying refit tables"))
        };
        Ok(RefitPlan {
            slot_prim: self.slot_prim.clone(),
            d_slot_prim: copy(&self.d_slot_prim)?,
            order: copy(&self.order)?,
            levels: self.levels.clone(),
        })
    }
}

/// The device nodes grouped by depth below the root (node 0), deepest group first: the order
/// and the `(first, count)` of each group.
fn levels(nodes: &[u32]) -> (Vec<u32>, Vec<(u32, u32)>) {
    let n = nodes.len() / NODE_WORDS;
    let mut by_depth: Vec<Vec<u32>> = Vec::new();
    if n > 0 {
        let mut seen = vec![false; n];
        seen[0] = true;
        let mut frontier = vec![0u32];
        while !frontier.is_empty() {
            let mut next = Vec::new();
            for &i in &frontier {
                let w = &nodes[i as usize * NODE_WORDS..(i as usize + 1) * NODE_WORDS];
                for k in 0..2 {
                    let (child, count) = (w[12 + k], w[14 + k]);
                    // Each node once, so that the walk ends whatever the words say.
                    if count == 0
                        && (child as usize) < n
                        && !std::mem::replace(&mut seen[child as usize], true)
                    {
                        next.push(child);
                    }
                }
            }
            by_depth.push(std::mem::replace(&mut frontier, next));
        }
    }
    let mut order = Vec::with_capacity(n);
    let mut levels = Vec::with_capacity(by_depth.len());
    for level in by_depth.iter().rev() {
        levels.push((order.len() as u32, level.len() as u32));
        order.extend_from_slice(level);
    }
    (order, levels)
}

fn device(e: CudaError) -> BuildError {
    BuildError::Device(e.to_string())
}

impl CudaGas {
    /// Updates (refits) the GAS on the device, in place (`optixAccelBuild` with
    /// `OPTIX_BUILD_OPERATION_UPDATE`, guide §5.6): the same inputs as the build up to the
    /// contents of their buffers (vertices, indices, boxes, spheres, control points, SBT index
    /// offsets, the pre-transform). Every rule is checked first, with the CPU backend's typed
    /// errors ([`BuildError::InvalidUpdate`]); on an error nothing has changed. Primitives are
    /// re-read into their leaf slots (degenerate triangles, invalid boxes and spheres or
    /// segments without a positive radius become inactive, inactive ones may become active)
    /// and the node boxes are refit bottom-up; the hits are those of the CPU backend's update
    /// of the same build. The handle a pipeline got ([`optix_handle`](Self::optix_handle))
    /// stays valid and sees the new primitives.
    ///
    /// GASes in the BVH4 node layout are not updated on the device
    /// ([`BuildError::Unsupported`]).
    #[doc(alias = "optixAccelBuild")]
    #[doc(alias = "OPTIX_BUILD_OPERATION_UPDATE")]
    pub fn update(
        &mut self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(), BuildError> {
        self.meta.check_update(options, inputs)?;
        let Some(plan) = &self.refit else {
            return Err(BuildError::Unsupported(
                "updating a GAS in the BVH4 node layout on the CUDA backend",
            ));
        };
        let n_slots = plan.slot_prim.len();
        // Kept alive until the kernels that read them are done (the synchronisation below).
        let mut _keep: Vec<CudaSlice<u32>> = Vec::new();
        let mut _inputs = None;
        let (prims, triangles): (Option<CudaSlice<u32>>, u32) = match self.kind {
            GasKind::Triangles => {
                let k = self.ctx.build_kernels().map_err(device)?;
                let d = upload_inputs(&self.ctx, &self.meta.inputs, inputs).map_err(device)?;
                if n_slots > 0 {
                    let n = n_slots as u32;
                    let mut b = self.ctx.stream.launch_builder(&k.refit_triangles);
                    b.arg(&d.table)
                        .arg(&d.count)
                        .arg(&plan.d_slot_prim)
                        .arg(&n)
                        .arg(&mut self.triangles);
                    // SAFETY: oxray_refit_triangles(const InputDesc* in, u32 n_in,
                    // const u32* slot_prim, u32 n_slots, float4* out): the table holds n_in
                    // descriptors of inputs whose vertices and indices are on the device and
                    // were checked by `check_update` (every index in range, the counts the
                    // build's); slot_prim holds n_slots global ids below the build's primitive
                    // count or NO_PRIMITIVE; out holds 3 float4 per slot (the upload's array).
                    unsafe { b.launch(build_grid(n)) }
                        .map_err(driver("launching the triangle update kernel"))
                        .map_err(device)?;
                }
                _inputs = Some(d);
                (None, 1)
            }
            _ => {
                let slots = self.meta.update_slot_primitives(&plan.slot_prim, inputs);
                let (words, boxes) = slot_words(&slots);
                if words.len() > self.triangles.len() {
                    return Err(BuildError::Device(
                        "the update's primitives do not fit the structure's slots".into(),
                    ));
                }
                self.ctx
                    .stream
                    .memcpy_htod(&words[..], &mut self.triangles.slice_mut(..words.len()))
                    .map_err(driver("copying updated primitives to the device"))
                    .map_err(device)?;
                let boxes = match boxes {
                    Some(b) => Some(
                        self.ctx
                            .stream
                            .clone_htod(&b[..])
                            .map_err(driver("copying primitive boxes to the device"))
                            .map_err(device)?,
                    ),
                    None => None,
                };
                (boxes, 0)
            }
        };
        {
            let k = self.ctx.build_kernels().map_err(device)?;
            for &(first, count) in &plan.levels {
                let mut b = self.ctx.stream.launch_builder(&k.refit_nodes);
                let prims_arg = prims.as_ref().unwrap_or(&self.triangles);
                b.arg(&mut self.nodes)
                    .arg(&plan.order)
                    .arg(&first)
                    .arg(&count)
                    .arg(prims_arg)
                    .arg(&triangles);
                // SAFETY: oxray_refit_nodes(u32* nodes, const u32* order, u32 begin, u32 count,
                // const float4* prims, u32 triangles): order[begin..begin + count] are nodes of
                // the array (made from its own words); each node's leaf children are slot ranges
                // of the upload, whose prims hold 3 float4 (triangles) or 2 float4 (boxes) per
                // slot; inner children are nodes of a deeper level, written by an earlier launch
                // on the same stream.
                unsafe { b.launch(build_grid(count)) }
                    .map_err(driver("launching the node update kernel"))
                    .map_err(device)?;
            }
        }
        let mut root = [0u32; NODE_WORDS];
        self.ctx
            .stream
            .memcpy_dtoh(&self.nodes.slice(..NODE_WORDS), &mut root[..])
            .map_err(driver("copying the root node"))
            .map_err(device)?;
        self.ctx.synchronize().map_err(device)?;
        if let Some(p) = prims {
            _keep.push(p);
        }
        let bounds = root_bounds(&root);
        self.meta.bounds = bounds;
        self.info.bounds = bounds;
        // The slot table names every slot's primitive from the upload on
        // (`updatable_slots`); only per-primitive SBT index offsets, which an update may
        // change, change it.
        if self.meta.sbt_offsets.is_empty() {
            return Ok(());
        }
        self.meta.update_sbt_offsets(inputs);
        let meta = &self.meta;
        self.slots = plan
            .slot_prim
            .par_iter()
            .with_min_len(1 << 14)
            .map(|&g| slot_info(meta, g))
            .collect();
        // A pipeline's copy of the slot table, in place: its handle stays valid.
        let view = self
            .program_view
            .get_mut()
            .unwrap_or_else(|e| e.into_inner());
        if let Some(v) = view.as_mut() {
            let words: Vec<u32> = self
                .slots
                .iter()
                .flat_map(|s| [s.primitive_index, s.sbt_gas_index])
                .collect();
            v.rewrite_table(&self.ctx, 0, &words).map_err(device)?;
        }
        Ok(())
    }
}

/// The slot table of an uploaded structure: with a refit plan, every slot that holds a
/// primitive names it, inactive ones included, since an update may make them active (the
/// upload's table leaves them out); else `slots` as they are.
pub(crate) fn updatable_slots(
    gas: &GasData,
    plan: Option<&RefitPlan>,
    slots: Vec<SlotInfo>,
) -> Vec<SlotInfo> {
    match plan {
        Some(p) => p
            .slot_prim
            .par_iter()
            .with_min_len(1 << 14)
            .map(|&g| slot_info(gas, g))
            .collect(),
        None => slots,
    }
}

/// What a hit on a slot holding global primitive `g` reports.
pub(crate) fn slot_info(meta: &GasData, g: u32) -> SlotInfo {
    if g == NO_PRIMITIVE || g >= meta.num_primitives {
        SlotInfo {
            primitive_index: u32::MAX,
            sbt_gas_index: 0,
            build_input: 0,
        }
    } else {
        let (primitive_index, sbt_gas_index, build_input) = meta.resolve_global(g);
        SlotInfo {
            primitive_index,
            sbt_gas_index,
            build_input,
        }
    }
}

/// The slots' records as uploaded (`custom_words`, `sphere_words`, `curve_words` in `gas.rs`),
/// and for spheres and curves each slot's box as two `float4` (custom primitives' records are
/// their boxes).
pub(crate) fn slot_words(slots: &SlotPrimitives) -> (Vec<u32>, Option<Vec<u32>>) {
    // Two float4 per box (lower corner, 0, upper corner, 0); an inactive slot's box is empty.
    fn boxes(all: impl Iterator<Item = Aabb>) -> Vec<u32> {
        all.flat_map(|a| {
            [
                a.min.x, a.min.y, a.min.z, 0.0, a.max.x, a.max.y, a.max.z, 0.0,
            ]
        })
        .map(f32::to_bits)
        .collect()
    }
    let or_empty = |active: bool, b: Aabb| if active { b } else { Aabb::EMPTY };
    match slots {
        SlotPrimitives::Triangles(t) => (
            t.iter()
                .flat_map(|t| t.iter().flat_map(|p| [p[0], p[1], p[2], 0.0]))
                .map(f32::to_bits)
                .collect(),
            None,
        ),
        SlotPrimitives::Aabbs(a) => (boxes(a.iter().copied()), None),
        SlotPrimitives::Spheres(s) => (
            s.iter()
                .flat_map(|s| s.to_array().map(f32::to_bits))
                .collect(),
            Some(boxes(s.iter().map(|s| or_empty(s.is_active(), s.bounds())))),
        ),
        SlotPrimitives::Curves(c) => (
            bytemuck::cast_slice(c).to_vec(),
            Some(boxes(c.iter().map(|s| or_empty(s.is_active(), s.bounds())))),
        ),
    }
}

/// The box of node 0's two children.
pub(crate) fn root_bounds(w: &[u32; NODE_WORDS]) -> Aabb {
    let f = |i: usize| f32::from_bits(w[i]);
    let child = |k: usize| {
        Aabb::new(
            [f(4 * k), f(4 * k + 2), f(8 + 2 * k)].into(),
            [f(4 * k + 1), f(4 * k + 3), f(9 + 2 * k)].into(),
        )
    };
    child(0).union(&child(1))
}

/// Launch shape of the build module's kernels (256 threads a block).
fn build_grid(n: u32) -> LaunchConfig {
    LaunchConfig {
        grid_dim: (n.max(1).div_ceil(256), 1, 1),
        block_dim: (256, 1, 1),
        shared_mem_bytes: 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use oxray_bvh::Bvh2;
    use oxray_core::{TriangleInput, VertexBuffer};

    #[test]
    fn levels_list_every_node_once_children_before_parents() {
        let v: Vec<[f32; 3]> = (0..3000)
            .map(|i| [(i % 37) as f32, (i % 11) as f32 * 0.5, (i / 100) as f32])
            .collect();
        let (_, tree): (GasData, Bvh2) = GasData::build_with_tree(
            &BuildOptions::new(BuildFlags::ALLOW_UPDATE),
            &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()],
        )
        .unwrap();
        let words = crate::layout::bvh2_words(&tree).unwrap();
        let n = words.len() / NODE_WORDS;
        let (order, levels) = levels(&words);
        let mut seen = order.clone();
        seen.sort_unstable();
        assert_eq!(seen, (0..n as u32).collect::<Vec<_>>());
        assert_eq!(
            levels.last().unwrap(),
            &(n as u32 - 1, 1),
            "the root comes last"
        );
        // Each node's inner children sit in an earlier level.
        let level_of = |node: u32| {
            let at = order.iter().position(|&x| x == node).unwrap() as u32;
            levels
                .iter()
                .position(|&(f, c)| at >= f && at < f + c)
                .unwrap()
        };
        for i in 0..n as u32 {
            let w = &words[i as usize * NODE_WORDS..];
            for k in 0..2 {
                if w[14 + k] == 0 && w[12 + k] != u32::MAX {
                    assert!(level_of(w[12 + k]) < level_of(i));
                }
            }
        }
    }

    #[test]
    fn updated_slots_are_encoded_as_the_upload_encodes_them() {
        use oxray_bvh::Sphere;
        let b = Aabb::new([1.0, 2.0, 3.0].into(), [4.0, 5.0, 6.0].into());
        let (words, boxes) = slot_words(&SlotPrimitives::Aabbs(vec![b, Aabb::EMPTY]));
        let f: Vec<f32> = words.iter().map(|&w| f32::from_bits(w)).collect();
        assert_eq!(f[..8], [1.0, 2.0, 3.0, 0.0, 4.0, 5.0, 6.0, 0.0]);
        assert_eq!(f[8], f32::INFINITY);
        assert!(boxes.is_none(), "a box is its own record");
        let s = [Sphere::new([1.0, 1.0, 1.0].into(), 0.5), Sphere::INACTIVE];
        let (words, boxes) = slot_words(&SlotPrimitives::Spheres(s.to_vec()));
        assert_eq!(f32::from_bits(words[3]), 0.5);
        let boxes: Vec<f32> = boxes.unwrap().iter().map(|&w| f32::from_bits(w)).collect();
        let (lo, hi) = (s[0].bounds().min, s[0].bounds().max);
        assert_eq!(boxes[..8], [lo.x, lo.y, lo.z, 0.0, hi.x, hi.y, hi.z, 0.0]);
        assert_eq!((boxes[8], boxes[12]), (f32::INFINITY, f32::NEG_INFINITY));
    }

    #[test]
    fn the_root_box_is_the_union_of_its_children() {
        let mut w = [0u32; NODE_WORDS];
        let rows = [
            0.0f32, 1.0, 0.0, 1.0, 2.0, 3.0, -1.0, 0.5, 0.0, 1.0, 4.0, 5.0,
        ];
        for (i, f) in rows.iter().enumerate() {
            w[i] = f.to_bits();
        }
        let b = root_bounds(&w);
        assert_eq!(b.min.to_array(), [0.0, -1.0, 0.0]);
        assert_eq!(b.max.to_array(), [3.0, 1.0, 5.0]);
    }
}
