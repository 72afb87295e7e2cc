//! Updates (refits) of GASes on the device (guide §5.6): the same tree and leaf slots, new
//! primitives, boxes recomputed bottom-up by the kernels at the end of `kernels/build.cu`.
//!
//! A GAS built with `ALLOW_UPDATE` keeps a slot for every primitive, inactive ones included, so
//! that an update can make them active. Triangles and custom primitives are built so by the
//! device's builder (`device_build.rs`, which places inactive primitives, with empty boxes,
//! after the active ones); spheres, curves, the BVH4 layout and a host-builder backend build on
//! the host and upload in the binary layout. Either keeps a [`RefitPlan`]: the global primitive
//! of every leaf slot (host and device), and the device nodes in an order that puts every node
//! after its inner children (by depth for an upload, by height for a device build). An update
//! then
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

/// What an update of a GAS needs: the global primitive of each leaf slot, on the host and the
/// device, and the device nodes in groups, each group's inner children in earlier groups.
#[derive(Debug)]
pub(crate) struct RefitPlan {
    /// Global primitive of each leaf slot ([`NO_PRIMITIVE`] for padding).
    pub(crate) slot_prim: Vec<u32>,
    d_slot_prim: CudaSlice<u32>,
    /// Device node indices, children's groups first.
    order: CudaSlice<u32>,
    /// `(first, count)` of each group in `order`, in launch order.
    levels: Vec<(u32, u32)>,
    /// The node layout the plan's indices and the refit kernel are for.
    layout: NodeLayout,
}

/// Words of one binary node (`layout.rs`).
const NODE_WORDS: usize = 16;
/// Words of one BVH4-layout node (`oxray_bvh::Bvh4Node`).
const NODE4_WORDS: usize = 32;

/// Where a layout's node keeps child `k`'s link and count, and how many children it has.
struct Links {
    words: usize,
    children: usize,
    child: usize,
    count: usize,
}

impl Links {
    fn of(layout: NodeLayout) -> Links {
        match layout {
            NodeLayout::Bvh2 => Links {
                words: NODE_WORDS,
                children: 2,
                child: 12,
                count: 14,
            },
            NodeLayout::Bvh4 => Links {
                words: NODE4_WORDS,
                children: 4,
                child: 24,
                count: 28,
            },
        }
    }
}

impl RefitPlan {
    /// The plan of a GAS uploaded with `nodes` (words of `layout`): `None` unless it was built
    /// with `ALLOW_UPDATE` (in the binary layout, or in the BVH4 layout, which holds only
    /// triangles).
    pub(crate) fn for_upload(
        ctx: &CudaContext,
        gas: &GasData,
        nodes: &[u32],
        layout: NodeLayout,
    ) -> Result<Option<RefitPlan>, CudaError> {
        if !gas.build_flags.contains(BuildFlags::ALLOW_UPDATE)
            || (layout == NodeLayout::Bvh4 && gas.kind != GasKind::Triangles)
        {
            return Ok(None);
        }
        let (order, levels) = levels(nodes, layout);
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
            layout,
        }))
    }

    /// The plan of a GAS the device built with `ALLOW_UPDATE`: `slot_prim` the global primitive
    /// of every leaf slot (the sorted ids, inactive primitives included) and `heights` the
    /// height of every device node, by which the refit's launches go (lowest first: a node's
    /// inner children are lower than it).
    pub(crate) fn from_heights(
        ctx: &CudaContext,
        slot_prim: Vec<u32>,
        heights: &[u32],
    ) -> Result<RefitPlan, CudaError> {
        let (order, levels) = by_height(heights);
        let upload = |w: &[u32]| {
            let w: &[u32] = if w.is_empty() { &[0] } else { w };
            ctx.stream
                .clone_htod(w)
                .map_err(driver("copying refit tables to the device"))
        };
        Ok(RefitPlan {
            d_slot_prim: upload(&slot_prim)?,
            order: upload(&order)?,
            slot_prim,
            levels,
            layout: NodeLayout::Bvh2,
        })
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
            layout: self.layout,
        })
    }
}

/// The device nodes (words of `layout`) grouped by depth below the root (node 0), deepest group
/// first: the order and the `(first, count)` of each group.
fn levels(nodes: &[u32], layout: NodeLayout) -> (Vec<u32>, Vec<(u32, u32)>) {
    let links = Links::of(layout);
    let n = nodes.len() / links.words;
    let mut by_depth: Vec<Vec<u32>> = Vec::new();
    if n > 0 {
        let mut seen = vec![false; n];
        seen[0] = true;
        let mut frontier = vec![0u32];
        while !frontier.is_empty() {
            let mut next = Vec::new();
            for &i in &frontier {
                let w = &nodes[i as usize * links.words..(i as usize + 1) * links.words];
                for k in 0..links.children {
                    let (child, count) = (w[links.child + k], w[links.count + k]);
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

/// The nodes grouped by height, lowest group first (a counting sort): the order and the
/// `(first, count)` of each group.
fn by_height(heights: &[u32]) -> (Vec<u32>, Vec<(u32, u32)>) {
    let top = heights.iter().copied().max().unwrap_or(0) as usize;
    let mut starts = vec![0u32; top + 2];
    for &h in heights {
        starts[h as usize + 1] += 1;
    }
    for k in 1..starts.len() {
        starts[k] += starts[k - 1];
    }
    let levels = (0..=top)
        .map(|h| (starts[h], starts[h + 1] - starts[h]))
        .filter(|&(_, count)| count > 0)
        .collect();
    let mut next = starts;
    let mut order = vec![0u32; heights.len()];
    for (i, &h) in heights.iter().enumerate() {
        order[next[h as usize] as usize] = i as u32;
        next[h as usize] += 1;
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
    /// GASes in either node layout are refit on the device.
    #[doc(alias = "optixAccelBuild")]
    #[doc(alias = "OPTIX_BUILD_OPERATION_UPDATE")]
    pub fn update(
        &mut self,
        options: &BuildOptions,
        inputs: &[BuildInput<'_>],
    ) -> Result<(), BuildError> {
        self.meta.check_update(options, inputs)?;
        let Some(plan) = &self.refit else {
            // Every structure built with ALLOW_UPDATE keeps a plan, which check_update asked.
            return Err(BuildError::Device(
                "the structure kept no refit plan".into(),
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
            let wide = plan.layout == NodeLayout::Bvh4;
            for &(first, count) in &plan.levels {
                let prims_arg = prims.as_ref().unwrap_or(&self.triangles);
                let mut nodes = self.nodes.nodes_mut();
                let launched = if wide {
                    let mut b = self.ctx.stream.launch_builder(&k.refit_nodes4);
                    b.arg(&mut nodes)
                        .arg(&plan.order)
                        .arg(&first)
                        .arg(&count)
                        .arg(prims_arg);
                    // SAFETY: oxray_refit_nodes4(u32* nodes, const u32* order, u32 begin,
                    // u32 count, const float4* prims): order[begin..begin + count] are 32-word
                    // nodes of the array (made from its own words); each node's leaf children
                    // are slot ranges of the upload, whose prims hold 3 float4 per slot (the
                    // BVH4 layout holds triangles only: `for_upload`); inner children are
                    // nodes of a deeper level, written by an earlier launch on the stream.
                    unsafe { b.launch(build_grid(count)) }
                } else {
                    let mut b = self.ctx.stream.launch_builder(&k.refit_nodes);
                    b.arg(&mut nodes)
                        .arg(&plan.order)
                        .arg(&first)
                        .arg(&count)
                        .arg(prims_arg)
                        .arg(&triangles);
                    // SAFETY: oxray_refit_nodes(u32* nodes, const u32* order, u32 begin,
                    // u32 count, const float4* prims, u32 triangles): order[begin..begin +
                    // count] are nodes of the array (made from its own words, or from the
                    // device build's heights); each node's leaf children are slot ranges of
                    // the structure, whose prims hold 3 float4 (triangles) or 2 float4 (boxes)
                    // per slot; inner children are nodes of an earlier group, written by an
                    // earlier launch on the same stream.
                    unsafe { b.launch(build_grid(count)) }
                };
                launched
                    .map_err(driver("launching the node update kernel"))
                    .map_err(device)?;
            }
        }
        let words = Links::of(plan.layout).words;
        let mut root = vec![0u32; words];
        self.ctx
            .stream
            .memcpy_dtoh(&self.nodes.nodes().slice(..words), &mut root[..])
            .map_err(driver("copying the root node"))
            .map_err(device)?;
        self.ctx.synchronize().map_err(device)?;
        if let Some(p) = prims {
            _keep.push(p);
        }
        let bounds = match plan.layout {
            NodeLayout::Bvh2 => root_bounds(&root),
            NodeLayout::Bvh4 => root_bounds4(&root),
        };
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

/// The box of a BVH4-layout node 0's four children (rows of four lanes: lower x, y, z, upper
/// x, y, z; unused lanes are empty).
fn root_bounds4(w: &[u32]) -> Aabb {
    let f = |i: usize| f32::from_bits(w[i]);
    (0..4).fold(Aabb::EMPTY, |b, k| {
        b.union(&Aabb::new(
            [f(k), f(4 + k), f(8 + k)].into(),
            [f(12 + k), f(16 + k), f(20 + k)].into(),
        ))
    })
}

/// The box of node 0's two children.
pub(crate) fn root_bounds(w: &[u32]) -> Aabb {
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
        let (gas, tree): (GasData, Bvh2) = GasData::build_with_tree(
            &BuildOptions::new(BuildFlags::ALLOW_UPDATE),
            &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()],
        )
        .unwrap();
        let binary = crate::layout::bvh2_words(&tree).unwrap();
        let wide: Vec<u32> = bytemuck::cast_slice(&gas.bvh.nodes).to_vec();
        for (words, layout) in [(binary, NodeLayout::Bvh2), (wide, NodeLayout::Bvh4)] {
            let links = Links::of(layout);
            let n = words.len() / links.words;
            assert!(n > 10, "{layout:?}");
            let (order, levels) = levels(&words, layout);
            let mut seen = order.clone();
            seen.sort_unstable();
            assert_eq!(seen, (0..n as u32).collect::<Vec<_>>(), "{layout:?}");
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
            let mut inner = 0;
            for i in 0..n as u32 {
                let w = &words[i as usize * links.words..];
                for k in 0..links.children {
                    let (child, count) = (w[links.child + k], w[links.count + k]);
                    if count == 0 && child != u32::MAX {
                        assert!(level_of(child) < level_of(i), "{layout:?}");
                        inner += 1;
                    }
                }
            }
            assert_eq!(
                inner,
                n - 1,
                "{layout:?}: every node but the root is a child"
            );
        }
        // The root box of the 4-wide layout is the structure's.
        let wide: Vec<u32> = bytemuck::cast_slice(&gas.bvh.nodes[..1]).to_vec();
        assert_eq!(root_bounds4(&wide), gas.bounds);
    }

    #[test]
    fn nodes_by_height_come_lowest_first_each_once() {
        let heights = [3, 1, 2, 1, 1, 2, 4];
        let (order, levels) = by_height(&heights);
        assert_eq!(order, vec![1, 3, 4, 2, 5, 0, 6]);
        assert_eq!(levels, vec![(0, 3), (3, 2), (5, 1), (6, 1)]);
        // A single node (a device build of fewer than two primitives).
        assert_eq!(by_height(&[1]), (vec![0], vec![(0, 1)]));
        assert_eq!(by_height(&[]), (vec![], vec![]));
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
