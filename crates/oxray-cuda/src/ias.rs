//! An instance acceleration structure on the device. The batched query kernels trace one level
//! of instances over triangle GASes (the graph of OptiX's `ALLOW_SINGLE_LEVEL_INSTANCING`);
//! pipelines trace any graph: instances of IASes, static transforms and custom-primitive GASes.

use crate::context::CudaContext;
use crate::device_build::GasBuilder;
use crate::error::{driver, CudaError};
use crate::gas::CudaGas;
use crate::gas::{check_batch, grid, hit_of, DescriptorHome, HitRecord, ProgramView, Scratch};
use crate::gas::{DESCRIPTOR_IAS, DESCRIPTOR_INSTANCE};
use crate::layout::{ChildRef, IasLayout};
use crate::transform::{resolve_child, CudaChild};
use cudarc::driver::{CudaSlice, DevicePtr, PushKernelArg};
use oxray_bvh::{Bvh2, IasData};
use oxray_core::{
    Aabb, BackendKind, BuildError, Hit, InstanceFlags, Ray, Traversable, TraversableKind,
};
use rayon::prelude::*;
use std::sync::Arc;
use std::sync::Mutex;

/// An IAS in device memory: its top-level binary tree and an instance table holding the
/// world-to-object transform, world box and device addresses of each child GAS. Queries give
/// the CPU backend's hits: distances, barycentrics and facing bit for bit, with the instance's
/// id and index; which of two hits at exactly the same distance is reported may differ (the
/// top-level layouts differ, as for [`crate::NodeLayout::Bvh2`]).
#[derive(Debug)]
pub struct CudaIas {
    ctx: CudaContext,
    nodes: CudaSlice<u32>,
    instances: CudaSlice<u32>,
    /// The instances, boxes and flags, in slot order (it keeps the children alive too).
    data: IasData,
    /// The top-level binary tree the device nodes were made from (refit by updates).
    tree: Bvh2,
    /// The child of every slot (`None`: null), for resolving hits and making handles.
    children: Vec<Option<CudaChild>>,
    /// Whether every child is a triangle GAS (or null): what the batched query kernels trace.
    queryable: bool,
    device_bytes: usize,
    scratch: Mutex<Scratch>,
    /// What a pipeline's traversal reads, made on first use ([`CudaIas::optix_handle`]).
    program_view: Mutex<Option<ProgramView>>,
    /// The `__oxray_Motion` header of an IAS built with motion options (guide §5.10.3), whose
    /// vanish flags hide its instances outside its time range.
    motion: Option<CudaSlice<u32>>,
    /// Where its top-level tree was built.
    builder: GasBuilder,
}

impl CudaIas {
    /// Uploads a built IAS whose children are structures of `ctx`: GASes in the binary layout
    /// (triangles or custom primitives), IASes, static transforms (core [`StaticTransform`]s are
    /// uploaded here, as [`CudaStaticTransform`](crate::CudaStaticTransform)s), or null.
    /// Children of another device are refused. The batched queries trace only IASes whose
    /// children are triangle GASes; pipelines trace them all. An instance with a zero
    /// visibility mask is uploaded as null: no ray mask shares a bit with it.
    ///
    /// [`StaticTransform`]: oxray_core::StaticTransform
    pub fn upload(ctx: &CudaContext, data: IasData, tree: &Bvh2) -> Result<CudaIas, BuildError> {
        let (children, refs, queryable) = resolve_children(ctx, &data)?;
        let host = IasLayout::new(&data, tree, &refs).map_err(BuildError::Device)?;
        let upload = |words: &[u32], what: &'static str| {
            let words: &[u32] = if words.is_empty() { &[0; 4] } else { words };
            ctx.stream
                .clone_htod(words)
                .map_err(driver(what))
                .map_err(|e| BuildError::Device(e.to_string()))
        };
        let nodes = upload(&host.nodes, "copying IAS nodes to the device")?;
        let instances = upload(&host.instances, "copying instances to the device")?;
        let motion = if data.motion.has_motion() {
            let header = crate::gas::motion_header(&data.motion, 0);
            Some(upload(&header, "copying motion options to the device")?)
        } else {
            None
        };
        // The query kernels' rays carry no time: an IAS that can vanish is traced by pipelines.
        let queryable = queryable && motion.is_none();
        ctx.synchronize()
            .map_err(|e| BuildError::Device(e.to_string()))?;
        Ok(CudaIas {
            ctx: ctx.clone(),
            nodes,
            instances,
            device_bytes: host.device_bytes(),
            data,
            tree: tree.clone(),
            children,
            queryable,
            scratch: Mutex::new(Scratch::default()),
            program_view: Mutex::new(None),
            motion,
            builder: GasBuilder::Host,
        })
    }

    /// Where the top-level tree was built: [`GasBuilder::Device`] for an IAS whose tree the
    /// device's kernels made ([`crate::device_build::build_box_tree`]), [`GasBuilder::Host`]
    /// for one built (or loaded) on the host and uploaded.
    #[must_use]
    pub fn builder(&self) -> GasBuilder {
        self.builder
    }

    /// The same IAS, saying its tree was built by `builder`.
    pub(crate) fn built_by(mut self, builder: GasBuilder) -> Self {
        self.builder = builder;
        self
    }

    /// Updates (refits) the IAS in place (guide §5.6): new transforms, ids, SBT offsets, masks
    /// and flags for the same instances over the same children, where a child may be an update
    /// of the structure the IAS was built over (its new bounds and device arrays are taken).
    /// The rules are those of [`IasData::update`], with its typed errors; on an error nothing
    /// has changed. The instance boxes and the top-level tree's boxes are recomputed on the
    /// host (an IAS is small) and written over the device's copies, so the handle a pipeline
    /// got stays valid.
    pub fn update(
        &mut self,
        options: &oxray_core::BuildOptions,
        inputs: &[oxray_core::BuildInput<'_>],
    ) -> Result<(), BuildError> {
        let mut data = self.data.clone();
        data.update(options, inputs)?;
        let (children, refs, queryable) = resolve_children(&self.ctx, &data)?;
        let mut tree = self.tree.clone();
        tree.refit(|first, count| {
            data.boxes
                .get(first as usize..(first + count) as usize)
                .unwrap_or(&[])
                .iter()
                .fold(Aabb::EMPTY, |a, b| a.union(b))
        });
        let host = IasLayout::new(&data, &tree, &refs).map_err(BuildError::Device)?;
        let dev = |e: CudaError| BuildError::Device(e.to_string());
        if host.nodes.len() > self.nodes.len() || host.instances.len() > self.instances.len() {
            return Err(BuildError::Device(
                "the updated IAS does not fit its device arrays".into(),
            ));
        }
        // The instance records a pipeline reads, before anything changes.
        let records = match self
            .program_view
            .get_mut()
            .unwrap_or_else(|e| e.into_inner())
        {
            Some(_) => Some(instance_records(&data, &children).map_err(dev)?),
            None => None,
        };
        let s = &self.ctx.stream;
        if !host.nodes.is_empty() {
            s.memcpy_htod(
                &host.nodes[..],
                &mut self.nodes.slice_mut(..host.nodes.len()),
            )
            .map_err(driver("copying IAS nodes to the device"))
            .map_err(dev)?;
        }
        if !host.instances.is_empty() {
            s.memcpy_htod(
                &host.instances[..],
                &mut self.instances.slice_mut(..host.instances.len()),
            )
            .map_err(driver("copying instances to the device"))
            .map_err(dev)?;
        }
        self.ctx.synchronize().map_err(dev)?;
        if let (Some(records), Some(view)) = (
            records,
            self.program_view
                .get_mut()
                .unwrap_or_else(|e| e.into_inner())
                .as_mut(),
        ) {
            view.rewrite_table(&self.ctx, 0, &records).map_err(dev)?;
        }
        self.data = data;
        self.tree = tree;
        self.children = children;
        self.queryable = queryable && self.motion.is_none();
        Ok(())
    }

    /// The emitted property `COMPACTED_SIZE` (guide §5.8): the device bytes of the compacted
    /// IAS (its own; the children are their own); `None` unless built with `ALLOW_COMPACTION`.
    pub fn compacted_size(&self) -> Option<usize> {
        self.data
            .build_flags
            .contains(oxray_core::BuildFlags::ALLOW_COMPACTION)
            .then_some(self.device_bytes)
    }

    /// A copy of the IAS in new device memory over the same children: what an update of an IAS
    /// that is shared writes into.
    pub fn duplicate(&self) -> Result<CudaIas, BuildError> {
        Ok(CudaIas::upload(&self.ctx, self.data.clone(), &self.tree)?.built_by(self.builder))
    }

    /// The compacted IAS (guide §5.8): the same instances over the same children, exactly
    /// sized (device IASes are exactly sized from the start). Refused without
    /// `ALLOW_COMPACTION`.
    pub fn compact(&self) -> Result<CudaIas, BuildError> {
        Ok(CudaIas::upload(&self.ctx, self.data.compact()?, &self.tree)?.built_by(self.builder))
    }

    /// An IAS given as host data ([`IasData::from_bytes`], over children that live on this
    /// device) uploaded to the device: its binary tree is made from the data's 4-wide one.
    pub fn from_data(ctx: &CudaContext, data: IasData) -> Result<CudaIas, BuildError> {
        let tree = Bvh2::from_wide(&data.bvh.nodes);
        CudaIas::upload(ctx, data, &tree)
    }

    /// The `OptixTraversableHandle` of this IAS for programs of a [`CudaPipeline`](crate::CudaPipeline):
    /// the device address of a descriptor of its top-level tree, its instance table and, for
    /// each instance, its id, SBT offset, flags, mask, index and child's handle. Made on first
    /// use and kept with the IAS.
    #[doc(alias = "OptixTraversableHandle")]
    pub fn optix_handle(&self) -> Result<u64, CudaError> {
        let mut view = self.program_view.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(v) = view.as_ref() {
            return Ok(v.address);
        }
        let info = instance_records(&self.data, &self.children)?;
        let (nodes, _g1) = self.nodes.device_ptr(&self.ctx.stream);
        let (insts, _g2) = self.instances.device_ptr(&self.ctx.stream);
        // Random instance access (guide §13.12): the slot of every instance index, as the
        // third table (the descriptor's `random`).
        let tables = if self
            .data
            .build_flags
            .contains(oxray_core::BuildFlags::ALLOW_RANDOM_INSTANCE_ACCESS)
        {
            let mut slots = vec![self.data.slot_of.len() as u32];
            slots.extend_from_slice(&self.data.slot_of);
            vec![info, Vec::new(), slots]
        } else {
            vec![info]
        };
        let v = ProgramView::upload(
            &self.ctx,
            DESCRIPTOR_IAS,
            0,
            self.data.depth,
            self.data.instances.len() as u32,
            DescriptorHome::Own(nodes),
            insts,
            tables,
            self.motion.as_ref().map_or(0, |m| {
                let (p, _g) = m.device_ptr(&self.ctx.stream);
                p
            }),
        )?;
        let address = v.address;
        *view = Some(v);
        Ok(address)
    }

    /// Whether the batched queries trace this IAS: every child is a triangle GAS (or null).
    pub fn is_queryable(&self) -> bool {
        self.queryable
    }

    /// Refuses the batched queries on a graph the query kernels do not trace.
    fn check_queryable(&self) -> Result<(), CudaError> {
        if self.queryable {
            Ok(())
        } else {
            Err(CudaError::Unsupported(
                "batched queries over instances of IASes, transforms, custom primitives or structures with motion (CudaPipeline traces them)",
            ))
        }
    }

    /// The top-level nodes and the instance slots the query kernels read.
    pub(crate) fn device_tables(&self) -> (&CudaSlice<u32>, &CudaSlice<u32>) {
        (&self.nodes, &self.instances)
    }

    /// The child of the instance in slot `slot` (`None`: null or masked out).
    pub(crate) fn child(&self, slot: usize) -> Option<&CudaChild> {
        self.children.get(slot)?.as_ref()
    }

    /// The triangle GAS of the instance in slot `slot`, if it has one.
    pub(crate) fn triangle_child(&self, slot: usize) -> Option<&Arc<CudaGas>> {
        self.children
            .get(slot)?
            .as_ref()
            .and_then(CudaChild::triangle_gas)
    }

    /// The triangle GAS of every instance that has one.
    pub(crate) fn triangle_children(&self) -> impl Iterator<Item = &Arc<CudaGas>> + '_ {
        self.children
            .iter()
            .filter_map(|c| c.as_ref().and_then(CudaChild::triangle_gas))
    }

    /// The built data: instances, world boxes, flags, BVH statistics.
    pub fn data(&self) -> &IasData {
        &self.data
    }

    /// Bytes of the top-level nodes and the instance table in device memory (the children's
    /// are their own).
    pub fn device_bytes(&self) -> usize {
        self.device_bytes
    }

    /// The context it lives in.
    pub fn context(&self) -> &CudaContext {
        &self.ctx
    }

    /// Closest hits of a batch into `hits`: rays up, the kernel, hits down and resolved.
    pub fn intersect_batch_into(
        &self,
        rays: &[Ray],
        hits: &mut [Option<Hit>],
    ) -> Result<(), CudaError> {
        if rays.len() != hits.len() {
            return Err(CudaError::LengthMismatch {
                rays: rays.len(),
                outputs: hits.len(),
            });
        }
        self.check_queryable()?;
        let mut guard = self.scratch.lock().unwrap_or_else(|e| e.into_inner());
        guard.closest(&self.ctx, rays, true, &|r, h, i, n| {
            self.launch_closest(r, h, i, n)
        })?;
        self.resolve_into(&guard.records, &guard.inst_records, hits);
        Ok(())
    }

    /// Occlusion of a batch into `occluded`.
    pub fn occluded_batch_into(
        &self,
        rays: &[Ray],
        occluded: &mut [bool],
    ) -> Result<(), CudaError> {
        self.check_queryable()?;
        let mut guard = self.scratch.lock().unwrap_or_else(|e| e.into_inner());
        guard.any(&self.ctx, rays, occluded, &|r, o, n| {
            self.launch_occluded(r, o, n)
        })
    }

    /// Traces rays already on the device (8 words each) into `hits` (4 words each) and `insts`
    /// (one instance slot each); returns when the kernel is done.
    pub(crate) fn intersect_device(
        &self,
        rays: &CudaSlice<u32>,
        hits: &mut CudaSlice<u32>,
        insts: &mut CudaSlice<u32>,
        n: usize,
    ) -> Result<(), CudaError> {
        self.check_queryable()?;
        check_batch(n)?;
        if n == 0 {
            return Ok(());
        }
        self.launch_closest(rays, hits, insts, n as u32)?;
        self.ctx.synchronize()
    }

    /// Traces occlusion of rays already on the device into `out` (a byte each).
    pub(crate) fn occluded_device(
        &self,
        rays: &CudaSlice<u32>,
        out: &mut CudaSlice<u8>,
        n: usize,
    ) -> Result<(), CudaError> {
        self.check_queryable()?;
        check_batch(n)?;
        if n == 0 {
            return Ok(());
        }
        self.launch_occluded(rays, out, n as u32)?;
        self.ctx.synchronize()
    }

    fn launch_closest(
        &self,
        rays: &CudaSlice<u32>,
        hits: &mut CudaSlice<u32>,
        insts: &mut CudaSlice<u32>,
        n: u32,
    ) -> Result<(), CudaError> {
        debug_assert!(
            rays.len() >= 8 * n as usize
                && hits.len() >= 4 * n as usize
                && insts.len() >= n as usize
        );
        let mut launch = self
            .ctx
            .stream
            .launch_builder(&self.ctx.kernels.closest_ias);
        launch
            .arg(&self.nodes)
            .arg(&self.instances)
            .arg(rays)
            .arg(hits)
            .arg(insts)
            .arg(&n);
        // SAFETY: the kernel's parameters are (const float4* top, const float4* insts,
        // const float4* rays, uint4* hits, u32* inst_out, u32 n), matching the arguments: device
        // buffers of 32-bit words holding the `IasLayout` (every child index and slot range in
        // bounds; every non-null child address is the nodes or triangles of a live `CudaGas` in
        // this context, kept alive by `self.children` and never written after its upload), at
        // least 8 words per ray, 4 per hit and 1 per instance result for `n` rays.
        unsafe { launch.launch(grid(n)) }
            .map_err(driver("launching the IAS closest-hit kernel"))?;
        Ok(())
    }

    fn launch_occluded(
        &self,
        rays: &CudaSlice<u32>,
        out: &mut CudaSlice<u8>,
        n: u32,
    ) -> Result<(), CudaError> {
        debug_assert!(rays.len() >= 8 * n as usize && out.len() >= n as usize);
        let mut launch = self
            .ctx
            .stream
            .launch_builder(&self.ctx.kernels.occluded_ias);
        launch
            .arg(&self.nodes)
            .arg(&self.instances)
            .arg(rays)
            .arg(out)
            .arg(&n);
        // SAFETY: as in `launch_closest`, with the output at least a byte per ray for `n` rays.
        unsafe { launch.launch(grid(n)) }.map_err(driver("launching the IAS occlusion kernel"))?;
        Ok(())
    }

    /// Turns hit records and instance slots into [`Hit`]s.
    pub(crate) fn resolve_into(
        &self,
        records: &[HitRecord],
        insts: &[u32],
        out: &mut [Option<Hit>],
    ) {
        const CHUNK: usize = 1 << 14;
        records
            .par_chunks(CHUNK)
            .zip(insts.par_chunks(CHUNK))
            .zip(out.par_chunks_mut(CHUNK))
            .for_each(|((r, i), o)| {
                for ((r, &i), o) in r.iter().zip(i).zip(o) {
                    *o = self.resolve_one(r, i);
                }
            });
    }

    pub(crate) fn resolve_one(&self, r: &HitRecord, slot: u32) -> Option<Hit> {
        if !r.is_hit() {
            return None;
        }
        let inst = self.data.instances.get(slot as usize)?;
        let gas = self.children.get(slot as usize)?.as_ref()?.triangle_gas()?;
        let s = gas.slot_info(r.slot_index())?;
        let flip = inst.flags.contains(InstanceFlags::FLIP_TRIANGLE_FACING);
        Some(hit_of(r, s, flip, inst.instance_id, inst.index))
    }
}

/// The device view of every instance's child: the children (`None`: null or masked out), the
/// query kernels' references to triangle GASes, and whether every child is one (or null).
#[allow(clippy::type_complexity)]
fn resolve_children(
    ctx: &CudaContext,
    data: &IasData,
) -> Result<(Vec<Option<CudaChild>>, Vec<Option<ChildRef>>, bool), BuildError> {
    let mut children = Vec::with_capacity(data.instances.len());
    let mut refs = Vec::with_capacity(data.instances.len());
    let mut addresses: std::collections::HashMap<usize, (u64, u64)> = Default::default();
    let mut queryable = true;
    for (slot, inst) in data.instances.iter().enumerate() {
        let child = resolve_child(ctx, &inst.child, Some(inst.index))?;
        let child = child.filter(|_| inst.mask != 0);
        let gas = child.as_ref().and_then(CudaChild::triangle_gas);
        queryable &= child.is_none() || gas.is_some();
        refs.push(gas.map(|gas| {
            // Many instances share a child: its addresses are looked up once (each lookup
            // records a stream event).
            let key = std::sync::Arc::as_ptr(gas) as usize;
            let addrs = *addresses.entry(key).or_insert_with(|| {
                let (n, t) = gas.device_arrays();
                let (nodes_addr, _n) = n.device_ptr(&ctx.stream);
                let (triangles_addr, _t) = t.device_ptr(&ctx.stream);
                (nodes_addr, triangles_addr)
            });
            ChildRef {
                index: slot as u32,
                nodes_addr: addrs.0,
                triangles_addr: addrs.1,
            }
        }));
        children.push(child);
    }
    Ok((children, refs, queryable))
}

/// The instance records of every slot, as pipelines read them.
fn instance_records(data: &IasData, children: &[Option<CudaChild>]) -> Result<Vec<u32>, CudaError> {
    let mut info = Vec::with_capacity(INSTANCE_RECORD_WORDS * data.instances.len());
    for (slot, inst) in data.instances.iter().enumerate() {
        let child = match children.get(slot).and_then(|c| c.as_ref()) {
            Some(c) => c.optix_handle()?,
            None => 0,
        };
        info.extend_from_slice(&instance_record(inst, child));
    }
    Ok(info)
}

/// Words of an instance record as pipelines read it (`__oxray_Instance`: 128 bytes).
pub(crate) const INSTANCE_RECORD_WORDS: usize = 32;

/// The record of one instance: kind, id, SBT offset, flags, mask, index, the child's handle,
/// then the object-to-world and world-to-object rows.
pub(crate) fn instance_record(
    inst: &oxray_bvh::InstanceData,
    child: u64,
) -> [u32; INSTANCE_RECORD_WORDS] {
    let mut w = [0u32; INSTANCE_RECORD_WORDS];
    w[..8].copy_from_slice(&[
        DESCRIPTOR_INSTANCE,
        inst.instance_id,
        inst.sbt_offset,
        inst.flags.bits(),
        inst.mask as u32,
        inst.index,
        child as u32,
        (child >> 32) as u32,
    ]);
    for (k, f) in inst.object_to_world.0.iter().enumerate() {
        w[8 + k] = f.to_bits();
    }
    for (k, f) in inst.world_to_object.0.iter().enumerate() {
        w[20 + k] = f.to_bits();
    }
    w
}

impl Traversable for CudaIas {
    fn traversable_kind(&self) -> TraversableKind {
        TraversableKind::Ias
    }

    fn bounds(&self) -> Aabb {
        self.data.bounds
    }

    fn graph_depth(&self) -> u32 {
        self.data.depth
    }

    fn backend(&self) -> BackendKind {
        BackendKind::Cuda
    }

    fn lineage(&self) -> Option<u64> {
        Some(self.data.lineage)
    }

    fn describe(&self) -> String {
        format!("CUDA IAS of {} instances", self.data.num_instances)
    }
}
