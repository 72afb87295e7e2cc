//! A GAS on the device, and batches of rays and results on the device.

use crate::context::CudaContext;
use crate::device_build::GasBuilder;
use crate::error::{driver, CudaError};
use crate::layout::{bvh2_words, DeviceLayout, NodeLayout, SlotInfo, MAX_SLOTS};
use crate::node_buffer::NodeBuffer;
use bytemuck::{Pod, Zeroable};
use cudarc::driver::{CudaSlice, CudaView, DevicePtr, LaunchConfig, PushKernelArg};
use oxray_bvh::{Bvh2, GasData, GasInfo, GasKind};
use oxray_core::{
    Aabb, BackendKind, CurveType, Hit, HitKind, MotionOptions, Ray, RayRecord, Traversable,
    TraversableKind,
};
use rayon::prelude::*;
use std::sync::Mutex;

/// Threads per block of the trace kernels (their `__launch_bounds__`).
const BLOCK: u32 = 128;

/// One closest-hit result as the kernel writes it: `t`, the leaf slot with the back-face flag in
/// bit 31, and the barycentrics. A miss has `t = +inf` and slot `0xFFFF_FFFF`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct HitRecord {
    /// Distance along the ray; `+inf` for a miss.
    pub t: f32,
    /// Leaf slot, with bit 31 set for a back-face hit; `0xFFFF_FFFF` for a miss.
    pub slot: u32,
    /// First barycentric (weight of the second vertex).
    pub u: f32,
    /// Second barycentric (weight of the third vertex).
    pub v: f32,
}

impl HitRecord {
    /// The slot value of a miss.
    pub const MISS: u32 = u32::MAX;

    /// Whether the ray hit something.
    #[must_use]
    pub fn is_hit(&self) -> bool {
        self.slot != Self::MISS
    }

    /// The leaf slot hit (meaningless for a miss).
    #[must_use]
    pub fn slot_index(&self) -> u32 {
        self.slot & 0x7FFF_FFFF
    }

    /// Whether the hit is on a triangle's front face.
    #[must_use]
    pub fn is_front_face(&self) -> bool {
        self.slot & 0x8000_0000 == 0
    }
}

/// A batch of rays in device memory.
#[derive(Debug)]
pub struct DeviceRays {
    pub(crate) words: CudaSlice<u32>,
    len: usize,
}

impl DeviceRays {
    /// Copies rays to the device.
    pub fn upload(ctx: &CudaContext, rays: &[Ray]) -> Result<DeviceRays, CudaError> {
        check_batch(rays.len())?;
        let records = records(rays);
        let words: &[u32] = bytemuck::cast_slice(&records);
        let words = if words.is_empty() {
            ctx.stream.alloc_zeros::<u32>(8)
        } else {
            ctx.stream.clone_htod(words)
        }
        .map_err(driver("copying rays to the device"))?;
        Ok(DeviceRays {
            words,
            len: rays.len(),
        })
    }

    /// Replaces the rays with as many new ones.
    pub fn write(&mut self, ctx: &CudaContext, rays: &[Ray]) -> Result<(), CudaError> {
        if rays.len() != self.len {
            return Err(CudaError::LengthMismatch {
                rays: rays.len(),
                outputs: self.len,
            });
        }
        if rays.is_empty() {
            return Ok(());
        }
        ctx.stream
            .memcpy_htod(
                bytemuck::cast_slice::<RayRecord, u32>(&records(rays)),
                &mut self.words,
            )
            .map_err(driver("copying rays to the device"))
    }

    /// Rays in the batch.
    #[must_use]
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the batch is empty.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

/// Closest-hit results in device memory, one [`HitRecord`] per ray.
#[derive(Debug)]
pub struct DeviceHits {
    pub(crate) words: CudaSlice<u32>,
    len: usize,
}

impl DeviceHits {
    /// Room for `len` results.
    pub fn new(ctx: &CudaContext, len: usize) -> Result<DeviceHits, CudaError> {
        check_batch(len)?;
        let words = ctx
            .stream
            .alloc_zeros::<u32>(4 * len.max(1))
            .map_err(driver("allocating hit records"))?;
        Ok(DeviceHits { words, len })
    }

    /// Copies the results to the host.
    pub fn download(&self, ctx: &CudaContext) -> Result<Vec<HitRecord>, CudaError> {
        let mut out = vec![HitRecord::zeroed(); self.len];
        self.download_into(ctx, &mut out)?;
        Ok(out)
    }

    /// Copies the results into `out`, which must hold exactly [`len`](Self::len) records.
    pub fn download_into(&self, ctx: &CudaContext, out: &mut [HitRecord]) -> Result<(), CudaError> {
        if out.len() != self.len {
            return Err(CudaError::LengthMismatch {
                rays: self.len,
                outputs: out.len(),
            });
        }
        if out.is_empty() {
            return Ok(());
        }
        let view = self.words.slice(..4 * self.len);
        ctx.stream
            .memcpy_dtoh(&view, bytemuck::cast_slice_mut::<HitRecord, u32>(out))
            .map_err(driver("copying hit records to the host"))?;
        ctx.synchronize()
    }

    /// Results held.
    #[must_use]
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether it holds no results.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

/// Occlusion results in device memory, one byte per ray (1: occluded).
#[derive(Debug)]
pub struct DeviceOcclusion {
    pub(crate) bytes: CudaSlice<u8>,
    len: usize,
}

impl DeviceOcclusion {
    /// Room for `len` results.
    pub fn new(ctx: &CudaContext, len: usize) -> Result<DeviceOcclusion, CudaError> {
        check_batch(len)?;
        let bytes = ctx
            .stream
            .alloc_zeros::<u8>(len.max(1))
            .map_err(driver("allocating occlusion results"))?;
        Ok(DeviceOcclusion { bytes, len })
    }

    /// Copies the results to the host.
    pub fn download(&self, ctx: &CudaContext) -> Result<Vec<bool>, CudaError> {
        if self.len == 0 {
            return Ok(Vec::new());
        }
        let mut raw = vec![0u8; self.len];
        let view = self.bytes.slice(..self.len);
        ctx.stream
            .memcpy_dtoh(&view, &mut raw[..])
            .map_err(driver("copying occlusion results to the host"))?;
        ctx.synchronize()?;
        Ok(raw.into_iter().map(|b| b != 0).collect())
    }

    /// Results held.
    #[must_use]
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether it holds no results.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

/// The kernels' ray records (8 words a ray; motion comes with the motion-blur work, so the
/// time is not sent).
fn records(rays: &[Ray]) -> Vec<RayRecord> {
    rays.par_iter().map(|&r| RayRecord::from(r)).collect()
}

pub(crate) fn check_batch(len: usize) -> Result<(), CudaError> {
    if len > u32::MAX as usize {
        return Err(CudaError::TooLarge(format!(
            "a batch of {len} rays; at most {} per launch",
            u32::MAX
        )));
    }
    Ok(())
}

/// A triangle GAS uploaded to the device: its BVH in a chosen [`NodeLayout`] and its triangles
/// in leaf-slot order. Queries return the hits of the CPU backend's batched queries: distances,
/// barycentrics and facing bit for bit; with [`NodeLayout::Bvh4`] the primitive too where two
/// hits tie at the same distance.
///
/// ```no_run
/// use oxray_bvh::GasData;
/// use oxray_core::{BuildOptions, Ray, TriangleInput, VertexBuffer};
/// use oxray_cuda::{CudaContext, CudaGas};
/// let v = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
/// let (gas, tree) = GasData::build_with_tree(&BuildOptions::default(), &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
/// let ctx = CudaContext::new()?;
/// let gpu = CudaGas::upload(&ctx, &gas, &tree)?;
/// let rays = vec![Ray::new([0.0, 0.0, 1.0].into(), [0.0, 0.0, -1.0].into()); 1000];
/// let hits = gpu.intersect_batch(&rays)?;
/// assert_eq!(hits[0].unwrap().t, 1.0);
/// assert!(gpu.occluded_batch(&rays)?.iter().all(|&o| o));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
///
/// A GAS of custom primitives is uploaded too (its boxes in leaf-slot order, in the binary
/// layout): pipelines trace it, running the hit groups' intersection programs; the batched
/// queries refuse it ([`CudaError::CustomPrimitives`]).
#[derive(Debug)]
pub struct CudaGas {
    pub(crate) ctx: CudaContext,
    pub(crate) kind: GasKind,
    pub(crate) layout: NodeLayout,
    pub(crate) nodes: NodeBuffer,
    pub(crate) triangles: CudaSlice<u32>,
    pub(crate) slots: Vec<SlotInfo>,
    pub(crate) info: GasInfo,
    pub(crate) num_nodes: usize,
    pub(crate) device_bytes: usize,
    /// Which builder made the tree.
    pub(crate) builder: GasBuilder,
    /// Buffers of the one-call queries, kept between calls (grown as batches grow) so that a
    /// call allocates and page-faults nothing once warm.
    pub(crate) scratch: Mutex<Scratch>,
    /// Geometry flags of each SBT record (by SBT-GAS index).
    pub(crate) record_flags: Vec<u32>,
    /// What a pipeline's traversal reads, made on first use ([`CudaGas::optix_handle`]).
    pub(crate) program_view: Mutex<Option<ProgramView>>,
    /// The curve type of each leaf slot of a curve GAS (empty otherwise): a hit's kind.
    pub(crate) curve_types: Vec<CurveType>,
    /// The structure's tables without its tree and primitives ([`GasData::skeleton`]): the
    /// inputs' records and shapes, SBT offsets, counts and lineage, for updates and saving.
    pub(crate) meta: GasData,
    /// What a device update needs (structures built with `ALLOW_UPDATE`).
    pub(crate) refit: Option<crate::refit::RefitPlan>,
    /// Each primitive's first leaf slot, for random vertex access (made on first use).
    pub(crate) random_slots: std::sync::OnceLock<Vec<u32>>,
    /// What the simulation queries read besides the tree (made on first use).
    pub(crate) simulation: Mutex<Option<std::sync::Arc<crate::simulation::SimulationTables>>>,
    /// A GAS built with motion (guide §5.10.2): its `__oxray_Motion` table on the device (the
    /// options, then the primitives at keys 1, 2, … in the layout of `triangles`).
    pub(crate) motion: Option<DeviceMotion>,
}

/// The motion of a GAS on the device.
#[derive(Debug)]
pub(crate) struct DeviceMotion {
    pub(crate) options: MotionOptions,
    pub(crate) words: CudaSlice<u32>,
    /// The box of the primitives at each key (the emitted `AABBS`, guide §5.10.2).
    pub(crate) key_bounds: Vec<Aabb>,
}

impl DeviceMotion {
    /// Uploads the motion table of `gas`, if it has motion keys.
    pub(crate) fn upload(ctx: &CudaContext, gas: &GasData) -> Result<Option<Self>, CudaError> {
        let Some(host) = motion_words(gas) else {
            return Ok(None);
        };
        let words = ctx
            .stream
            .clone_htod(&host[..])
            .map_err(driver("copying motion keys to the device"))?;
        Ok(Some(DeviceMotion {
            options: gas.motion_options(),
            words,
            key_bounds: gas.key_bounds(),
        }))
    }

    /// A copy in new device memory.
    pub(crate) fn duplicate(&self, ctx: &CudaContext) -> Result<Self, CudaError> {
        Ok(DeviceMotion {
            options: self.options,
            words: ctx
                .stream
                .clone_dtod(&self.words)
                .map_err(driver("copying motion keys on the device"))?,
            key_bounds: self.key_bounds.clone(),
        })
    }

    /// Its device address (the descriptor's `motion`).
    pub(crate) fn address(&self, ctx: &CudaContext) -> u64 {
        let (p, _g) = self.words.device_ptr(&ctx.stream);
        p
    }
}

/// Words of the header of a `__oxray_Motion` table.
const MOTION_HEADER_WORDS: usize = 8;

/// The header of a `__oxray_Motion` table: keys, flags, the two times and the stride (in
/// `float4`) of one key's primitive table.
pub(crate) fn motion_header(m: &MotionOptions, stride_words: usize) -> [u32; MOTION_HEADER_WORDS] {
    [
        m.num_keys as u32,
        m.flags.bits() as u32,
        m.time_begin.to_bits(),
        m.time_end.to_bits(),
        (stride_words / 4) as u32,
        0,
        0,
        0,
    ]
}

/// The `__oxray_Motion` table of a GAS with motion keys: its options, then its primitives at
/// keys 1, 2, … each in the layout of the key-0 table (`triangle_key_words`, `box_words`,
/// `sphere_key_words`, the curve records); `None` for a GAS without motion.
pub(crate) fn motion_words(gas: &GasData) -> Option<Vec<u32>> {
    use oxray_bvh::GasMotion;
    let m = gas.motion.as_ref()?;
    let keys = m.options.key_count();
    let key_words = |k: usize| -> Vec<u32> {
        match gas.kind {
            GasKind::Triangles => {
                triangle_key_words(gas, GasMotion::key(&gas.triangles, &m.triangles, k))
            }
            GasKind::CustomPrimitives => box_words(GasMotion::key(&gas.aabbs, &m.aabbs, k)),
            GasKind::Spheres => sphere_key_words(GasMotion::key(&gas.spheres, &m.spheres, k)),
            GasKind::Curves => {
                bytemuck::cast_slice(GasMotion::key(&gas.curves, &m.curves, k)).to_vec()
            }
        }
    };
    let later: Vec<Vec<u32>> = (1..keys).map(key_words).collect();
    let stride = later.first().map_or(0, Vec::len);
    let mut words = motion_header(&m.options, stride).to_vec();
    words.reserve(stride * later.len());
    for k in later {
        words.extend_from_slice(&k);
    }
    Some(words)
}

/// One key's triangles as uploaded (12 words per leaf slot: the three vertices as `float4`),
/// NaN in the slots that are not active.
fn triangle_key_words(gas: &GasData, blocks: &[oxray_bvh::Triangle4]) -> Vec<u32> {
    let n = gas.slot_prim.len();
    let mut words = Vec::with_capacity(12 * n);
    for slot in 0..n {
        if gas.slot_is_active(slot) {
            for p in blocks[slot / 4].get(slot % 4) {
                words.extend_from_slice(&[p[0], p[1], p[2], 0.0].map(f32::to_bits));
            }
        } else {
            words.extend_from_slice(&[f32::NAN.to_bits(); 12]);
        }
    }
    words
}

/// The device tables a pipeline's traversal reads beyond the query kernels' (slot
/// resolution, geometry flags) and the traversable descriptor that an `OptixTraversableHandle`
/// points at (64 bytes: see `__oxray_Traversable` in `oxray_device.h`).
#[derive(Debug)]
pub(crate) struct ProgramView {
    _tables: Vec<CudaSlice<u32>>,
    /// The descriptor, when it has a buffer of its own (an IAS's); a GAS's is the header of
    /// its node buffer.
    _descriptor: Option<CudaSlice<u32>>,
    pub(crate) address: u64,
}

/// Where a [`ProgramView`]'s descriptor goes, and the nodes it describes.
pub(crate) enum DescriptorHome<'a> {
    /// A buffer of its own, over the nodes at this address.
    Own(u64),
    /// The header of a GAS's node buffer, right before its nodes.
    Header(&'a NodeBuffer),
}

impl ProgramView {
    /// Uploads `tables` and a descriptor of `kind` over the nodes of `home`, `prims`, the
    /// tables' addresses and `motion` (a `__oxray_Motion` table's address, 0 for none); `types`
    /// is a curve GAS's `OptixPrimitiveTypeFlags` (0 otherwise).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn upload(
        ctx: &CudaContext,
        kind: u32,
        types: u32,
        depth: u32,
        count: u32,
        home: DescriptorHome<'_>,
        prims: u64,
        tables: Vec<Vec<u32>>,
        motion: u64,
    ) -> Result<ProgramView, CudaError> {
        let nodes = match &home {
            DescriptorHome::Own(nodes) => *nodes,
            DescriptorHome::Header(buffer) => buffer.nodes_address(ctx),
        };
        let tables: Vec<CudaSlice<u32>> = tables
            .into_iter()
            .map(|t| {
                let t = if t.is_empty() { vec![0; 4] } else { t };
                ctx.stream
                    .clone_htod(&t[..])
                    .map_err(driver("copying traversal tables to the device"))
            })
            .collect::<Result<_, _>>()?;
        let addr = |i: usize| {
            tables.get(i).map_or(0, |t| {
                let (p, _g) = t.device_ptr(&ctx.stream);
                p
            })
        };
        let mut words = descriptor_words(kind, depth, count, nodes, prims, addr(0), addr(1));
        words[11] = types;
        // A GAS's random vertex access table (`random` in `__oxray_Traversable`), if any.
        let random = addr(2);
        words[12] = random as u32;
        words[13] = (random >> 32) as u32;
        words[14] = motion as u32;
        words[15] = (motion >> 32) as u32;
        let (descriptor, address) = match home {
            DescriptorHome::Own(_) => {
                let descriptor = ctx
                    .stream
                    .clone_htod(&words[..])
                    .map_err(driver("copying a traversable descriptor"))?;
                let address = {
                    let (p, _g) = descriptor.device_ptr(&ctx.stream);
                    p
                };
                (Some(descriptor), address)
            }
            DescriptorHome::Header(buffer) => (None, buffer.write_header(ctx, &words)?),
        };
        ctx.synchronize()?;
        Ok(ProgramView {
            _tables: tables,
            _descriptor: descriptor,
            address,
        })
    }
}

impl ProgramView {
    /// Writes `words` over table `index` in place (the same length as it was uploaded with),
    /// so that handles given out stay valid after an update.
    pub(crate) fn rewrite_table(
        &mut self,
        ctx: &CudaContext,
        index: usize,
        words: &[u32],
    ) -> Result<(), CudaError> {
        let Some(t) = self._tables.get_mut(index) else {
            return Ok(());
        };
        if words.is_empty() || words.len() > t.len() {
            return Ok(());
        }
        ctx.stream
            .memcpy_htod(words, &mut t.slice_mut(..words.len()))
            .map_err(driver("updating a traversal table"))?;
        ctx.synchronize()
    }
}

/// What the batched query kernels do not trace: their rays carry no time.
pub(crate) const MOTION_QUERIES: &str =
    "batched queries over structures with motion on the CUDA backend (their rays carry no time; pipelines trace them at each ray's time)";

/// Descriptor kinds (`__OXRAY_GAS`… in `oxray_device.h`).
pub(crate) const DESCRIPTOR_GAS: u32 = 1;
pub(crate) const DESCRIPTOR_IAS: u32 = 2;
pub(crate) const DESCRIPTOR_STATIC: u32 = 3;
pub(crate) const DESCRIPTOR_INSTANCE: u32 = 4;
pub(crate) const DESCRIPTOR_CUSTOM_GAS: u32 = 5;
pub(crate) const DESCRIPTOR_SPHERE_GAS: u32 = 6;
pub(crate) const DESCRIPTOR_CURVE_GAS: u32 = 7;
pub(crate) const DESCRIPTOR_MATRIX_MOTION: u32 = 8;
pub(crate) const DESCRIPTOR_SRT_MOTION: u32 = 9;

/// The 16 words of a traversable descriptor (`__oxray_Traversable`): kind, count, four
/// addresses, the graph depth.
pub(crate) fn descriptor_words(
    kind: u32,
    depth: u32,
    count: u32,
    nodes: u64,
    prims: u64,
    info: u64,
    flags: u64,
) -> [u32; 16] {
    let mut w = [0u32; 16];
    w[0] = kind;
    w[1] = count;
    for (i, a) in [nodes, prims, info, flags].into_iter().enumerate() {
        w[2 + 2 * i] = a as u32;
        w[3 + 2 * i] = (a >> 32) as u32;
    }
    w[10] = depth;
    w
}

/// The boxes of a custom-primitive GAS as uploaded (8 words per leaf slot: lower corner, 0,
/// upper corner, 0) and what a hit on each slot reports. Inactive slots keep their empty box,
/// which no ray enters.
pub(crate) fn custom_words(gas: &GasData) -> (Vec<u32>, Vec<SlotInfo>) {
    let mut words = box_words(&gas.aabbs);
    if words.is_empty() {
        words.resize(8, 0);
    }
    (words, slot_infos(gas, gas.aabbs.len()))
}

/// Boxes as uploaded: 8 words each (lower corner, 0, upper corner, 0).
fn box_words(boxes: &[Aabb]) -> Vec<u32> {
    boxes
        .iter()
        .flat_map(|b| {
            [
                b.min.x, b.min.y, b.min.z, 0.0, b.max.x, b.max.y, b.max.z, 0.0,
            ]
        })
        .map(f32::to_bits)
        .collect()
}

/// Spheres as uploaded: 4 words each (centre, radius).
fn sphere_key_words(spheres: &[oxray_bvh::Sphere]) -> Vec<u32> {
    spheres
        .iter()
        .flat_map(|s| s.to_array().map(f32::to_bits))
        .collect()
}

/// The spheres of a sphere GAS as uploaded (4 words per leaf slot: the centre and the radius,
/// `optixGetSphereData`'s `float4`) and what a hit on each slot reports. Inactive slots keep
/// their NaN record, which no ray hits.
pub(crate) fn sphere_words(gas: &GasData) -> (Vec<u32>, Vec<SlotInfo>) {
    let mut words = sphere_key_words(&gas.spheres);
    if words.is_empty() {
        words.resize(4, 0);
    }
    (words, slot_infos(gas, gas.spheres.len()))
}

/// The curve segments of a curve GAS as uploaded (24 words per leaf slot: the
/// [`CurveSegment`](oxray_bvh::CurveSegment) record, which `curve.cu` reads as its
/// `CurveRecord`) and what a hit on each slot reports. Inactive slots keep their NaN control
/// points, which no ray hits.
pub(crate) fn curve_words(gas: &GasData) -> (Vec<u32>, Vec<SlotInfo>) {
    let mut words: Vec<u32> = bytemuck::cast_slice(&gas.curves).to_vec();
    if words.is_empty() {
        words.resize(24, 0);
    }
    (words, slot_infos(gas, gas.curves.len()))
}

/// What a hit on each of the first `n` leaf slots reports (an inactive slot: no primitive).
fn slot_infos(gas: &GasData, n: usize) -> Vec<SlotInfo> {
    (0..n)
        .map(|s| {
            if gas.slot_is_active(s) {
                let (primitive_index, sbt_gas_index, build_input) = gas.resolve(s as u32);
                SlotInfo {
                    primitive_index,
                    sbt_gas_index,
                    build_input,
                }
            } else {
                SlotInfo {
                    primitive_index: u32::MAX,
                    sbt_gas_index: 0,
                    build_input: 0,
                }
            }
        })
        .collect()
}

/// Device and host buffers reused by the one-call queries.
#[derive(Debug, Default)]
pub(crate) struct Scratch {
    /// Rays the device buffers hold room for.
    capacity: usize,
    pub(crate) rays: Option<CudaSlice<u32>>,
    pub(crate) hits: Option<CudaSlice<u32>>,
    pub(crate) occluded: Option<CudaSlice<u8>>,
    /// Instance slot of each hit (IAS queries).
    pub(crate) insts: Option<CudaSlice<u32>>,
    pub(crate) records: Vec<HitRecord>,
    pub(crate) inst_records: Vec<u32>,
    pub(crate) flags: Vec<u8>,
    /// Host staging of the rays' kernel records.
    staged: Vec<RayRecord>,
}

/// Queues a closest-hit kernel over `n` rays: (rays, hit records, instance slots, n).
pub(crate) type ClosestLaunch<'a> = &'a dyn Fn(
    &CudaSlice<u32>,
    &mut CudaSlice<u32>,
    &mut CudaSlice<u32>,
    u32,
) -> Result<(), CudaError>;
/// Queues an occlusion kernel over `n` rays: (rays, flags, n).
pub(crate) type AnyLaunch<'a> =
    &'a dyn Fn(&CudaSlice<u32>, &mut CudaSlice<u8>, u32) -> Result<(), CudaError>;

fn missing() -> CudaError {
    CudaError::Driver {
        during: "tracing",
        message: "scratch buffers missing".into(),
    }
}

impl Scratch {
    /// One closest-hit query: rays up, `launch`, hit records (and, with `instances`, the
    /// instance slot of each hit) down. The records are left in `self.records` and
    /// `self.inst_records`.
    pub(crate) fn closest(
        &mut self,
        ctx: &CudaContext,
        rays: &[Ray],
        instances: bool,
        launch: ClosestLaunch<'_>,
    ) -> Result<(), CudaError> {
        let n = rays.len();
        self.records.clear();
        self.inst_records.clear();
        if n == 0 {
            return Ok(());
        }
        self.load(ctx, rays)?;
        let (Some(d_rays), Some(d_hits), Some(d_insts)) =
            (self.rays.as_ref(), self.hits.as_mut(), self.insts.as_mut())
        else {
            return Err(missing());
        };
        launch(d_rays, d_hits, d_insts, n as u32)?;
        self.records.resize(n, HitRecord::zeroed());
        ctx.stream
            .memcpy_dtoh(
                &d_hits.slice(..4 * n),
                bytemuck::cast_slice_mut::<HitRecord, u32>(&mut self.records[..n]),
            )
            .map_err(driver("copying hit records to the host"))?;
        if instances {
            self.inst_records.resize(n, 0);
            ctx.stream
                .memcpy_dtoh(&d_insts.slice(..n), &mut self.inst_records[..n])
                .map_err(driver("copying instance records to the host"))?;
        }
        ctx.synchronize()
    }

    /// One occlusion query into `occluded`: rays up, `launch`, flags down.
    pub(crate) fn any(
        &mut self,
        ctx: &CudaContext,
        rays: &[Ray],
        occluded: &mut [bool],
        launch: AnyLaunch<'_>,
    ) -> Result<(), CudaError> {
        if rays.len() != occluded.len() {
            return Err(CudaError::LengthMismatch {
                rays: rays.len(),
                outputs: occluded.len(),
            });
        }
        let n = rays.len();
        if n == 0 {
            return Ok(());
        }
        self.load(ctx, rays)?;
        let (Some(d_rays), Some(d_occ)) = (self.rays.as_ref(), self.occluded.as_mut()) else {
            return Err(missing());
        };
        launch(d_rays, d_occ, n as u32)?;
        self.flags.resize(n, 0);
        ctx.stream
            .memcpy_dtoh(&d_occ.slice(..n), &mut self.flags[..n])
            .map_err(driver("copying occlusion results to the host"))?;
        ctx.synchronize()?;
        const CHUNK: usize = 1 << 16;
        occluded
            .par_chunks_mut(CHUNK)
            .zip(self.flags[..n].par_chunks(CHUNK))
            .for_each(|(o, f)| {
                for (o, &f) in o.iter_mut().zip(f) {
                    *o = f != 0;
                }
            });
        Ok(())
    }

    /// Makes room for `n` rays and copies them to the device.
    pub(crate) fn load(&mut self, ctx: &CudaContext, rays: &[Ray]) -> Result<(), CudaError> {
        let n = rays.len();
        check_batch(n)?;
        if n > self.capacity || self.rays.is_none() {
            let cap = n.max(1).next_power_of_two();
            // Free the old buffers first.
            (self.rays, self.hits, self.occluded, self.insts) = (None, None, None, None);
            let s = &ctx.stream;
            self.rays = Some(
                s.alloc_zeros::<u32>(8 * cap)
                    .map_err(driver("allocating rays"))?,
            );
            self.hits = Some(
                s.alloc_zeros::<u32>(4 * cap)
                    .map_err(driver("allocating hits"))?,
            );
            self.occluded = Some(
                s.alloc_zeros::<u8>(cap)
                    .map_err(driver("allocating occlusion results"))?,
            );
            self.insts = Some(
                s.alloc_zeros::<u32>(cap)
                    .map_err(driver("allocating instance results"))?,
            );
            self.capacity = cap;
        }
        // The kernels read 32-byte records; converting in parallel into a buffer kept between
        // calls costs a fraction of the copy to the device.
        self.staged.resize(n, RayRecord::zeroed());
        self.staged
            .par_iter_mut()
            .zip(rays.par_iter())
            .with_min_len(1 << 14)
            .for_each(|(d, &r)| *d = RayRecord::from(r));
        if let Some(d) = self.rays.as_mut() {
            let mut view = d.slice_mut(..8 * n);
            ctx.stream
                .memcpy_htod(
                    bytemuck::cast_slice::<RayRecord, u32>(&self.staged),
                    &mut view,
                )
                .map_err(driver("copying rays to the device"))?;
        }
        Ok(())
    }
}

impl CudaGas {
    /// Uploads a triangle GAS in the default layout ([`NodeLayout::Bvh2`]); `tree` is the
    /// canonical binary tree of its build ([`GasData::build_with_tree`]), from which the device
    /// nodes are derived.
    pub fn upload(ctx: &CudaContext, gas: &GasData, tree: &Bvh2) -> Result<CudaGas, CudaError> {
        CudaGas::upload_with_layout(ctx, gas, tree, NodeLayout::default())
    }

    /// Uploads a GAS in the given node layout. A GAS of custom primitives or of spheres is
    /// uploaded in the binary layout whatever `layout` says.
    pub fn upload_with_layout(
        ctx: &CudaContext,
        gas: &GasData,
        tree: &Bvh2,
        layout: NodeLayout,
    ) -> Result<CudaGas, CudaError> {
        match gas.kind {
            GasKind::CustomPrimitives => return Self::upload_custom(ctx, gas, tree),
            GasKind::Spheres => return Self::upload_spheres(ctx, gas, tree),
            GasKind::Curves => return Self::upload_curves(ctx, gas, tree),
            GasKind::Triangles => {}
        }
        let export = gas.export_triangles().ok_or(CudaError::CustomPrimitives)?;
        let host = DeviceLayout::new(&export, tree, layout).map_err(CudaError::TooLarge)?;
        let nodes = NodeBuffer::upload(ctx, &host.nodes)?;
        let tri_words: Vec<u32> = if host.triangles.is_empty() {
            vec![0; 12]
        } else {
            host.triangles.iter().map(|f| f.to_bits()).collect()
        };
        let triangles = ctx
            .stream
            .clone_htod(&tri_words[..])
            .map_err(driver("copying triangles to the device"))?;
        let refit = crate::refit::RefitPlan::for_upload(ctx, gas, &host.nodes, host.layout)?;
        let motion = DeviceMotion::upload(ctx, gas)?;
        let device_bytes = host.device_bytes() + motion.as_ref().map_or(0, |m| 4 * m.words.len());
        let slots = crate::refit::updatable_slots(gas, refit.as_ref(), host.slots);
        ctx.synchronize()?;
        Ok(CudaGas {
            ctx: ctx.clone(),
            kind: GasKind::Triangles,
            layout: host.layout,
            num_nodes: host.nodes.len() / (layout.node_bytes() / 4),
            device_bytes,
            builder: GasBuilder::Host,
            nodes,
            triangles,
            slots,
            info: gas.info(),
            scratch: Mutex::new(Scratch::default()),
            record_flags: gas.record_flags.iter().map(|f| f.bits()).collect(),
            program_view: Mutex::new(None),
            curve_types: Vec::new(),
            meta: gas.skeleton(),
            refit,
            random_slots: Default::default(),
            simulation: Default::default(),
            motion,
        })
    }

    /// A GAS of custom primitives: the binary nodes and, per leaf slot, its box as two `float4`
    /// (lower and upper corners; `w` unused).
    fn upload_custom(ctx: &CudaContext, gas: &GasData, tree: &Bvh2) -> Result<CudaGas, CudaError> {
        let (words, slots) = custom_words(gas);
        Self::upload_slots(ctx, gas, tree, GasKind::CustomPrimitives, words, slots)
    }

    /// A GAS of built-in spheres (guide §5.3): the binary nodes and, per leaf slot, its sphere
    /// as one `float4` (centre, radius), which both the pipelines' traversal and the query
    /// kernels test with the CPU's arithmetic.
    fn upload_spheres(ctx: &CudaContext, gas: &GasData, tree: &Bvh2) -> Result<CudaGas, CudaError> {
        let (words, slots) = sphere_words(gas);
        Self::upload_slots(ctx, gas, tree, GasKind::Spheres, words, slots)
    }

    /// A GAS of built-in curves (guide §5.2): the binary nodes and, per leaf slot, its segment
    /// record (control points, ribbon normals, type, caps), which both the pipelines'
    /// traversal and the query kernels intersect with the CPU's double-precision arithmetic.
    fn upload_curves(ctx: &CudaContext, gas: &GasData, tree: &Bvh2) -> Result<CudaGas, CudaError> {
        let (words, slots) = curve_words(gas);
        let mut g = Self::upload_slots(ctx, gas, tree, GasKind::Curves, words, slots)?;
        g.curve_types = gas.curves.iter().map(|c| c.curve_type()).collect();
        Ok(g)
    }

    /// A GAS in the binary layout whose leaf slots are the primitive records `words`.
    fn upload_slots(
        ctx: &CudaContext,
        gas: &GasData,
        tree: &Bvh2,
        kind: GasKind,
        words: Vec<u32>,
        slots: Vec<SlotInfo>,
    ) -> Result<CudaGas, CudaError> {
        if slots.len() > MAX_SLOTS {
            return Err(CudaError::TooLarge(format!(
                "{} leaf slots; at most {MAX_SLOTS}",
                slots.len()
            )));
        }
        let nodes_host = bvh2_words(tree).map_err(CudaError::TooLarge)?;
        let nodes = NodeBuffer::upload(ctx, &nodes_host)?;
        let boxes = ctx
            .stream
            .clone_htod(&words[..])
            .map_err(driver("copying primitives to the device"))?;
        let refit = crate::refit::RefitPlan::for_upload(ctx, gas, &nodes_host, NodeLayout::Bvh2)?;
        let slots = crate::refit::updatable_slots(gas, refit.as_ref(), slots);
        let motion = DeviceMotion::upload(ctx, gas)?;
        let motion_bytes = motion.as_ref().map_or(0, |m| 4 * m.words.len());
        ctx.synchronize()?;
        Ok(CudaGas {
            ctx: ctx.clone(),
            kind,
            layout: NodeLayout::Bvh2,
            num_nodes: nodes_host.len() / 16,
            device_bytes: 4 * (nodes_host.len() + words.len()) + motion_bytes,
            builder: GasBuilder::Host,
            nodes,
            triangles: boxes,
            slots,
            info: gas.info(),
            scratch: Mutex::new(Scratch::default()),
            record_flags: gas.record_flags.iter().map(|f| f.bits()).collect(),
            program_view: Mutex::new(None),
            curve_types: Vec::new(),
            meta: gas.skeleton(),
            refit,
            random_slots: Default::default(),
            simulation: Default::default(),
            motion,
        })
    }

    /// A GAS of triangles or custom primitives (`meta.kind`) the device built in the binary
    /// layout (`device_build`): its nodes and primitives already in device memory, the host's
    /// slot table and summary.
    pub(crate) fn from_device_build(
        ctx: &CudaContext,
        nodes: NodeBuffer,
        num_nodes: usize,
        triangles: CudaSlice<u32>,
        slots: Vec<SlotInfo>,
        info: GasInfo,
        meta: GasData,
    ) -> CudaGas {
        let per_slot = if meta.kind == GasKind::CustomPrimitives {
            32
        } else {
            48
        };
        CudaGas {
            ctx: ctx.clone(),
            kind: meta.kind,
            layout: NodeLayout::Bvh2,
            num_nodes,
            device_bytes: 64 * num_nodes + per_slot * slots.len(),
            builder: GasBuilder::Device,
            nodes,
            triangles,
            slots,
            info,
            scratch: Mutex::new(Scratch::default()),
            record_flags: meta.record_flags.iter().map(|f| f.bits()).collect(),
            program_view: Mutex::new(None),
            curve_types: Vec::new(),
            meta,
            refit: None,
            random_slots: Default::default(),
            simulation: Default::default(),
            motion: None,
        }
    }

    /// Which builder made the tree: [`GasBuilder::Device`] for a GAS built by the device's
    /// kernels, [`GasBuilder::Host`] for one built on the host and uploaded.
    pub fn builder(&self) -> GasBuilder {
        self.builder
    }

    /// Refuses the batched queries on a GAS of custom primitives (which need a pipeline's
    /// intersection programs); triangles and spheres have query kernels.
    fn check_queryable(&self) -> Result<(), CudaError> {
        if self.motion.is_some() {
            return Err(CudaError::Unsupported(MOTION_QUERIES));
        }
        match self.kind {
            GasKind::Triangles | GasKind::Spheres | GasKind::Curves => Ok(()),
            GasKind::CustomPrimitives => Err(CudaError::CustomPrimitives),
        }
    }

    /// The `OptixTraversableHandle` of this GAS for programs of a [`CudaPipeline`](crate::CudaPipeline):
    /// the device address of a descriptor of its tables, made on first use and kept with the
    /// GAS (which must outlive the launches that trace it). GASes in the BVH4 layout are not
    /// traced by pipelines yet.
    #[doc(alias = "OptixTraversableHandle")]
    pub fn optix_handle(&self) -> Result<u64, CudaError> {
        if self.layout != NodeLayout::Bvh2 {
            return Err(CudaError::Unsupported(
                "pipelines trace GASes in the binary (BVH2) node layout",
            ));
        }
        let mut view = self.program_view.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(v) = view.as_ref() {
            return Ok(v.address);
        }
        let slots: Vec<u32> = self
            .slots
            .iter()
            .flat_map(|s| [s.primitive_index, s.sbt_gas_index])
            .collect();
        let (tris, _g2) = self.triangles.device_ptr(&self.ctx.stream);
        let kind = match self.kind {
            GasKind::Triangles => DESCRIPTOR_GAS,
            GasKind::CustomPrimitives => DESCRIPTOR_CUSTOM_GAS,
            GasKind::Spheres => DESCRIPTOR_SPHERE_GAS,
            GasKind::Curves => DESCRIPTOR_CURVE_GAS,
        };
        let v = ProgramView::upload(
            &self.ctx,
            kind,
            self.curve_types
                .iter()
                .fold(0, |f, t| f | t.type_flag().bits()),
            1,
            self.record_flags.len() as u32,
            DescriptorHome::Header(&self.nodes),
            tris,
            match self.random_access_words() {
                Some(r) => vec![slots, self.record_flags.clone(), r],
                None => vec![slots, self.record_flags.clone()],
            },
            self.motion.as_ref().map_or(0, |m| m.address(&self.ctx)),
        )?;
        let address = v.address;
        *view = Some(v);
        Ok(address)
    }

    /// The box around the primitives at each motion key (guide §5.10.2: the emitted property
    /// `AABBS`); one box, the structure's, without motion.
    pub fn key_bounds(&self) -> Vec<Aabb> {
        match &self.motion {
            Some(m) => m.key_bounds.clone(),
            None => vec![self.bounds()],
        }
    }

    /// The motion options it was built with ([`MotionOptions::NONE`] without motion).
    pub fn motion_options(&self) -> MotionOptions {
        self.motion
            .as_ref()
            .map_or(MotionOptions::NONE, |m| m.options)
    }

    /// The node layout.
    pub fn layout(&self) -> NodeLayout {
        self.layout
    }

    /// The kind of primitives.
    pub fn kind(&self) -> GasKind {
        self.kind
    }

    /// Nodes of the device BVH.
    pub fn num_nodes(&self) -> usize {
        self.num_nodes
    }

    /// Bytes of nodes and triangles in device memory.
    pub fn device_bytes(&self) -> usize {
        self.device_bytes
    }

    /// The device arrays of nodes and triangles (for an IAS over this GAS).
    pub(crate) fn device_arrays(&self) -> (CudaView<'_, u32>, &CudaSlice<u32>) {
        (self.nodes.nodes(), &self.triangles)
    }

    /// What a hit on leaf slot `slot` reports.
    pub(crate) fn slot_info(&self, slot: u32) -> Option<&SlotInfo> {
        self.slots.get(slot as usize)
    }

    /// What the structure was built from: counts, flags, bounds, BVH statistics.
    pub fn info(&self) -> &GasInfo {
        &self.info
    }

    /// The context it lives in.
    pub fn context(&self) -> &CudaContext {
        &self.ctx
    }

    /// Closest hits of a batch: uploads the rays, traces them, downloads and resolves the hits.
    /// An invalid ray (see [`Ray::validate`]) hits nothing, as on the CPU.
    pub fn intersect_batch(&self, rays: &[Ray]) -> Result<Vec<Option<Hit>>, CudaError> {
        let mut hits = vec![None; rays.len()];
        self.intersect_batch_into(rays, &mut hits)?;
        Ok(hits)
    }

    /// [`intersect_batch`](Self::intersect_batch) into a slice.
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
        self.with_records(rays, |records| self.resolve_into(records, hits))
    }

    /// Closest hits of a batch as raw [`HitRecord`]s (resolve them with
    /// [`resolve`](Self::resolve) or [`primitive_index`](Self::primitive_index)).
    pub fn intersect_records(&self, rays: &[Ray]) -> Result<Vec<HitRecord>, CudaError> {
        let mut out = Vec::new();
        self.with_records(rays, |records| out.extend_from_slice(records))?;
        Ok(out)
    }

    /// Traces a batch with the reused buffers and hands the records to `f`.
    fn with_records(&self, rays: &[Ray], f: impl FnOnce(&[HitRecord])) -> Result<(), CudaError> {
        self.check_queryable()?;
        let mut guard = self.scratch.lock().unwrap_or_else(|e| e.into_inner());
        guard.closest(&self.ctx, rays, false, &|r, h, _, n| {
            self.launch_closest(r, h, n)
        })?;
        f(&guard.records);
        Ok(())
    }

    /// Occlusion of a batch: whether anything lies in each ray's `[tmin, tmax]`.
    pub fn occluded_batch(&self, rays: &[Ray]) -> Result<Vec<bool>, CudaError> {
        let mut out = vec![false; rays.len()];
        self.occluded_batch_into(rays, &mut out)?;
        Ok(out)
    }

    /// [`occluded_batch`](Self::occluded_batch) into a slice.
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

    /// Traces rays already on the device into `hits`; returns when the kernel is done.
    pub fn intersect_device(
        &self,
        rays: &DeviceRays,
        hits: &mut DeviceHits,
    ) -> Result<(), CudaError> {
        self.check_queryable()?;
        if rays.len() != hits.len() {
            return Err(CudaError::LengthMismatch {
                rays: rays.len(),
                outputs: hits.len(),
            });
        }
        if rays.is_empty() {
            return Ok(());
        }
        self.launch_closest(&rays.words, &mut hits.words, rays.len() as u32)?;
        self.ctx.synchronize()
    }

    /// Traces occlusion of rays already on the device into `out`; returns when the kernel is
    /// done.
    pub fn occluded_device(
        &self,
        rays: &DeviceRays,
        out: &mut DeviceOcclusion,
    ) -> Result<(), CudaError> {
        self.check_queryable()?;
        if rays.len() != out.len() {
            return Err(CudaError::LengthMismatch {
                rays: rays.len(),
                outputs: out.len(),
            });
        }
        if rays.is_empty() {
            return Ok(());
        }
        self.launch_occluded(&rays.words, &mut out.bytes, rays.len() as u32)?;
        self.ctx.synchronize()
    }

    /// Queues the closest-hit kernel over the first `n` rays of `rays` (8 words each), writing
    /// 4 words per ray to `hits`.
    fn launch_closest(
        &self,
        rays: &CudaSlice<u32>,
        hits: &mut CudaSlice<u32>,
        n: u32,
    ) -> Result<(), CudaError> {
        debug_assert!(rays.len() >= 8 * n as usize && hits.len() >= 4 * n as usize);
        let k = &self.ctx.kernels;
        let f = match (self.kind, self.layout) {
            (GasKind::Spheres, _) => &k.closest_spheres,
            (GasKind::Curves, _) => &k.closest_curves,
            (_, NodeLayout::Bvh4) => &k.closest_bvh4,
            (_, NodeLayout::Bvh2) => &k.closest_bvh2,
        };
        let nodes = self.nodes.nodes();
        let mut launch = self.ctx.stream.launch_builder(f);
        launch
            .arg(&nodes)
            .arg(&self.triangles)
            .arg(rays)
            .arg(hits)
            .arg(&n);
        // SAFETY: the kernel's parameters are (const float4* nodes, const float4* triangles or
        // spheres, const float4* rays, uint4* hits, u32 n), matching the arguments pushed:
        // device buffers of 32-bit words, 256-byte aligned by the allocator, holding the nodes
        // and primitives of `DeviceLayout` or `upload_slots` (every child index and slot range
        // in bounds, a sphere GAS always in the binary layout its kernel walks), and at
        // least 8 words per ray and 4 words per hit for `n` rays (checked by every caller).
        // Threads past `n` return at once.
        unsafe { launch.launch(grid(n)) }.map_err(driver("launching the closest-hit kernel"))?;
        Ok(())
    }

    /// Queues the occlusion kernel over the first `n` rays, writing a byte per ray to `out`.
    fn launch_occluded(
        &self,
        rays: &CudaSlice<u32>,
        out: &mut CudaSlice<u8>,
        n: u32,
    ) -> Result<(), CudaError> {
        debug_assert!(rays.len() >= 8 * n as usize && out.len() >= n as usize);
        let k = &self.ctx.kernels;
        let f = match (self.kind, self.layout) {
            (GasKind::Spheres, _) => &k.occluded_spheres,
            (GasKind::Curves, _) => &k.occluded_curves,
            (_, NodeLayout::Bvh4) => &k.occluded_bvh4,
            (_, NodeLayout::Bvh2) => &k.occluded_bvh2,
        };
        let nodes = self.nodes.nodes();
        let mut launch = self.ctx.stream.launch_builder(f);
        launch
            .arg(&nodes)
            .arg(&self.triangles)
            .arg(rays)
            .arg(out)
            .arg(&n);
        // SAFETY: as in `launch_closest`, with the output at least a byte per ray for `n`
        // rays.
        unsafe { launch.launch(grid(n)) }.map_err(driver("launching the occlusion kernel"))?;
        Ok(())
    }

    /// The primitive index (with its input's offset) that a hit record reports, `None` for a
    /// miss.
    pub fn primitive_index(&self, record: &HitRecord) -> Option<u32> {
        if !record.is_hit() {
            return None;
        }
        self.slots
            .get(record.slot_index() as usize)
            .map(|s| s.primitive_index)
    }

    /// Turns hit records into the CPU backend's [`Hit`]s.
    pub fn resolve(&self, records: &[HitRecord]) -> Vec<Option<Hit>> {
        let mut out = vec![None; records.len()];
        self.resolve_into(records, &mut out);
        out
    }

    /// Turns hit records into [`Hit`]s in place; `out` must be as long as `records` (extra
    /// entries on either side are left alone).
    pub fn resolve_into(&self, records: &[HitRecord], out: &mut [Option<Hit>]) {
        const CHUNK: usize = 1 << 14;
        records
            .par_chunks(CHUNK)
            .zip(out.par_chunks_mut(CHUNK))
            .for_each(|(r, o)| {
                for (r, o) in r.iter().zip(o) {
                    *o = self.resolve_one(r);
                }
            });
    }

    pub(crate) fn resolve_one(&self, r: &HitRecord) -> Option<Hit> {
        if !r.is_hit() {
            return None;
        }
        let s = self.slots.get(r.slot_index() as usize)?;
        let mut hit = hit_of(r, s, false, !0, 0);
        match self.kind {
            // Spheres have only a front face and no attributes (guide §9.4, §13.4).
            GasKind::Spheres => hit.hit_kind = HitKind::SPHERE_FRONT_FACE,
            // A curve's kind names its type; only ribbons have back faces (§9.3, §9.6).
            GasKind::Curves => {
                let ty = self.curve_types.get(r.slot_index() as usize)?;
                hit.hit_kind = HitKind::curve(*ty, !r.is_front_face());
            }
            _ => {}
        }
        Some(hit)
    }
}

/// The [`Hit`] a hit record on a slot reports: facing swapped by `flip`
/// (`FLIP_TRIANGLE_FACING`, guide §5.4), with the nearest instance's id and index (`!0` and 0
/// without one, §13.7).
pub(crate) fn hit_of(
    r: &HitRecord,
    s: &SlotInfo,
    flip: bool,
    instance_id: u32,
    instance_index: u32,
) -> Hit {
    Hit {
        t: r.t,
        u: r.u,
        v: r.v,
        primitive_index: s.primitive_index,
        sbt_gas_index: s.sbt_gas_index,
        build_input: s.build_input,
        hit_kind: if r.is_front_face() != flip {
            HitKind::TRIANGLE_FRONT_FACE
        } else {
            HitKind::TRIANGLE_BACK_FACE
        },
        instance_id,
        instance_index,
    }
}

impl Traversable for CudaGas {
    fn traversable_kind(&self) -> TraversableKind {
        TraversableKind::Gas
    }

    fn bounds(&self) -> Aabb {
        self.info.bounds
    }

    fn graph_depth(&self) -> u32 {
        1
    }

    fn backend(&self) -> BackendKind {
        BackendKind::Cuda
    }

    fn lineage(&self) -> Option<u64> {
        Some(self.meta.lineage)
    }

    fn describe(&self) -> String {
        format!(
            "CUDA GAS of {} {} ({:?} layout)",
            self.info.num_primitives,
            match self.kind {
                GasKind::Triangles => "triangles",
                GasKind::CustomPrimitives => "custom primitives",
                GasKind::Spheres => "spheres",
                GasKind::Curves => "curves",
            },
            self.layout
        )
    }
}

pub(crate) fn grid(n: u32) -> LaunchConfig {
    LaunchConfig {
        grid_dim: (n.div_ceil(BLOCK), 1, 1),
        block_dim: (BLOCK, 1, 1),
        shared_mem_bytes: 0,
    }
}
