//! The simulation queries on the device: every primitive along a ray and hit counts (on a GAS
//! of triangles or spheres, or one level of instances over triangle GASes), hit surfaces,
//! closest points (on a triangle GAS, and through one level of instances placed by
//! similarities), signed distances and inside tests (on a triangle GAS), in batches. The results are the CPU
//! backend's (`oxray_cpu::simulation`), in the same types ([`AllHits`], [`ClosestPoint`]) with
//! the same errors ([`SurfaceQueryError`]).
//!
//! - **Along rays** the kernels (`kernels/simulation.cu`) walk with an interval that never
//!   shrinks and record every primitive hit ("offers"), with the CPU's box and triangle tests
//!   bit for bit. A first pass counts each ray's offers; where no primitive has two leaf slots
//!   (every tree the device builds) a count is final. Otherwise, and for the lists, a second
//!   pass writes the offers into exactly sized memory, in parts of at most [`OFFER_BUDGET`]
//!   offers, and the host sorts each ray's list as the CPU does (by `t`, then instance, build
//!   input and primitive), drops repeats and keeps the nearest `max_hits_per_ray`.
//! - **Closest points** walk the tree nearest box first with box distances grown by a rounding
//!   margin, and keep the nearest triangle (the lowest global id among equal distances) with
//!   Ericson's region test, operation for operation the CPU's: the same point, distance,
//!   triangle and barycentrics. The sign of a signed distance is the angle-weighted
//!   pseudo-normal's at the closest point, summed over the triangles there in global-id order
//!   as on the CPU (its angles come from the device's `acosf`, which may differ from the host's
//!   in the last bit: the sign can differ only where the pseudo-normal is perpendicular to the
//!   offset, within rounding).
//!
//! ```no_run
//! use oxray_bvh::GasData;
//! use oxray_core::{AllHits, BuildOptions, Ray, TriangleInput, VertexBuffer};
//! use oxray_cuda::{CudaContext, CudaGas};
//! use glam::Vec3;
//! let v = [[-1.0f32, -1.0, 1.0], [1.0, -1.0, 1.0], [0.0, 1.0, 1.0],
//!          [-1.0, -1.0, 2.0], [1.0, -1.0, 2.0], [0.0, 1.0, 2.0]];
//! let (gas, tree) = GasData::build_with_tree(&BuildOptions::default(), &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
//! let gpu = CudaGas::upload(&CudaContext::new()?, &gas, &tree)?;
//! let rays = [Ray::new(Vec3::ZERO, Vec3::Z)];
//! let mut counts = [0u32];
//! gpu.count_hits_batch(&rays, &mut counts)?;
//! let mut lists = AllHits::new();
//! gpu.all_hits_batch(&rays, 8, &mut lists)?;
//! assert_eq!((counts[0], lists.hits(0)[1].t), (2, 2.0));
//! let mut closest = [None];
//! gpu.closest_point_batch(&[Vec3::new(0.0, 0.0, -1.0)], &mut closest)?;
//! assert_eq!(closest[0].unwrap().distance, 2.0);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use crate::context::{compile_options, guarded, nvrtc_compile, CudaContext};
use crate::error::{driver, CudaError};
use crate::gas::{check_batch, grid, CudaGas, HitRecord};
use crate::ias::CudaIas;
use crate::layout::NodeLayout;
use crate::transform::CudaChild;
use bytemuck::Zeroable;
use cudarc::driver::{CudaFunction, CudaSlice, CudaView, DevicePtr, PushKernelArg};
use glam::Vec3;
use oxray_bvh::triangle::WatertightRay;
use oxray_bvh::{GasKind, NO_PRIMITIVE};
use oxray_core::simulation::hit_order;
use oxray_core::simulation::{sphere_surface_parts, surface_in_world, triangle_surface_parts};
use oxray_core::{
    AllHits, ClosestPoint, Hit, InstanceClosestPoint, NoShadingNormals, PrimitiveType, Ray,
    RayRecord, ShadingNormals, SurfaceHit, SurfaceQueryError, Transform,
};
use rayon::prelude::*;
use std::cmp::Ordering;
use std::sync::Arc;

/// The CUDA C++ source of the simulation kernels: the trace kernels' walks and tests
/// (`trace.cu`, `curve.cu`, without their entry points), then `simulation.cu`.
pub const SIMULATION_SOURCE: &str = concat!(
    include_str!("kernels/trace.cu"),
    "\n",
    include_str!("kernels/curve.cu"),
    "\n",
    include_str!("kernels/simulation.cu")
);

/// Most offers (primitive hits along rays, repeats included) held in device memory at once by
/// the all-hits and repeat-counting passes (20 bytes each): a batch with more is traced in
/// parts of consecutive rays, a ray with more alone. `OXRAY_CUDA_OFFER_BUDGET` sets another
/// (a device with little free memory, or tests of the parts).
pub const OFFER_BUDGET: usize = 1 << 24;

/// [`OFFER_BUDGET`], or the positive number `OXRAY_CUDA_OFFER_BUDGET` gives.
fn offer_budget() -> usize {
    std::env::var("OXRAY_CUDA_OFFER_BUDGET")
        .ok()
        .and_then(|v| v.parse::<usize>().ok())
        .filter(|&b| b > 0)
        .unwrap_or(OFFER_BUDGET)
}

/// The compiled simulation kernels.
#[derive(Debug)]
pub(crate) struct SimulationKernels {
    offers_triangles: CudaFunction,
    offers_spheres: CudaFunction,
    offers_ias: CudaFunction,
    closest_points: CudaFunction,
    signed_distances: CudaFunction,
    gather_records: CudaFunction,
    instance_closest_points: CudaFunction,
}

/// The entry points of [`SIMULATION_SOURCE`].
pub(crate) const SIMULATION_ENTRIES: [&str; 7] = [
    "oxray_offers_triangles",
    "oxray_offers_spheres",
    "oxray_offers_ias",
    "oxray_closest_points",
    "oxray_signed_distances",
    "oxray_gather_records",
    "oxray_instance_closest_points",
];

/// Compiles the simulation kernels to PTX with NVRTC, for compute capability `cc`.
pub(crate) fn compile_simulation(cc: (i32, i32)) -> Result<cudarc::nvrtc::Ptx, CudaError> {
    let mut options = compile_options(cc);
    options.push("-DOXRAY_NO_QUERY_KERNELS".into());
    nvrtc_compile(SIMULATION_SOURCE, options, "oxray_simulation.cu")
}

impl SimulationKernels {
    pub(crate) fn load(ctx: &CudaContext) -> Result<SimulationKernels, CudaError> {
        let ptx = compile_simulation(ctx.device().compute_capability)?;
        let cu = ctx.stream.context().clone();
        let module = guarded("loading the simulation module", || cu.load_module(ptx))?;
        let f = |name: &'static str| guarded("loading a kernel", || module.load_function(name));
        Ok(SimulationKernels {
            offers_triangles: f(SIMULATION_ENTRIES[0])?,
            offers_spheres: f(SIMULATION_ENTRIES[1])?,
            offers_ias: f(SIMULATION_ENTRIES[2])?,
            closest_points: f(SIMULATION_ENTRIES[3])?,
            signed_distances: f(SIMULATION_ENTRIES[4])?,
            gather_records: f(SIMULATION_ENTRIES[5])?,
            instance_closest_points: f(SIMULATION_ENTRIES[6])?,
        })
    }
}

/// What the simulation kernels read of a GAS besides its nodes and primitives, made on first
/// use and kept with it.
#[derive(Debug)]
pub(crate) struct SimulationTables {
    /// The global primitive id of every leaf slot (`NO_PRIMITIVE` for none).
    ids: CudaSlice<u32>,
    /// Whether some primitive has several leaf slots (spatial splits): counts then need the
    /// host's repeat check.
    repeats: bool,
}

/// A device failure as a query error.
fn query_error(e: CudaError) -> SurfaceQueryError {
    match e {
        CudaError::Unsupported(what) => SurfaceQueryError::Unsupported(what),
        CudaError::LengthMismatch { rays, outputs } => SurfaceQueryError::LengthMismatch {
            queries: rays,
            outputs,
        },
        e => SurfaceQueryError::Device(e.to_string()),
    }
}

fn length_check(queries: usize, outputs: usize) -> Result<(), SurfaceQueryError> {
    if queries == outputs {
        Ok(())
    } else {
        Err(SurfaceQueryError::LengthMismatch { queries, outputs })
    }
}

/// The first invalid ray, as the CPU's batches report it.
fn first_invalid(rays: &[Ray]) -> Option<SurfaceQueryError> {
    rays.par_iter()
        .enumerate()
        .find_first(|(_, r)| r.validate().is_err())
        .and_then(|(index, r)| {
            r.validate()
                .err()
                .map(|error| SurfaceQueryError::InvalidRay { index, error })
        })
}

/// The first non-finite point, as the CPU's batches report it.
fn first_non_finite(points: &[Vec3]) -> Option<SurfaceQueryError> {
    points
        .par_iter()
        .position_first(|p| !p.is_finite())
        .map(|index| SurfaceQueryError::NonFinitePoint {
            index,
            point: points[index],
        })
}

/// A null device pointer, as a kernel argument.
const NULL: u64 = 0;

/// What the offer kernels trace.
#[derive(Clone, Copy)]
enum Target<'a> {
    Gas(&'a CudaGas),
    Ias(&'a CudaIas),
}

impl Target<'_> {
    fn ctx(&self) -> &CudaContext {
        match self {
            Target::Gas(g) => &g.ctx,
            Target::Ias(i) => i.context(),
        }
    }

    /// Queues the offer kernel over `n` rays: the count pass into `counts` (`out` `None`), or
    /// the write pass at `offsets` into `out` (4 words an offer) and its instance slots.
    fn launch(
        &self,
        k: &SimulationKernels,
        rays: &CudaView<'_, u32>,
        counts: &mut CudaSlice<u32>,
        out: Option<(&CudaSlice<u64>, &mut CudaSlice<u32>, &mut CudaSlice<u32>)>,
        n: u32,
    ) -> Result<(), CudaError> {
        let ctx = self.ctx();
        let (f, top, prims) = match self {
            Target::Gas(g) => (
                match g.kind {
                    GasKind::Spheres => &k.offers_spheres,
                    _ => &k.offers_triangles,
                },
                g.nodes.nodes(),
                &g.triangles,
            ),
            Target::Ias(i) => {
                let (nodes, instances) = i.device_tables();
                (&k.offers_ias, nodes.slice(..), instances)
            }
        };
        let mut launch = ctx.stream.launch_builder(f);
        launch.arg(&top).arg(prims).arg(rays).arg(counts);
        match out {
            None => {
                launch.arg(&NULL).arg(&NULL);
                if matches!(self, Target::Ias(_)) {
                    launch.arg(&NULL);
                }
            }
            Some((offsets, offers, insts)) => {
                launch.arg(offsets).arg(offers);
                if matches!(self, Target::Ias(_)) {
                    launch.arg(insts);
                }
            }
        }
        launch.arg(&n);
        // SAFETY: the kernels' parameters are (const float4* nodes or top-level nodes, const
        // float4* triangles, spheres or instance slots, const float4* rays, u32* counts,
        // const u64* offsets, uint4* offers[, u32* instance slots], u32 n), matching the
        // arguments: the structure's device tables (as the query kernels read them, every
        // child address of an IAS a live GAS kept by it), `n` rays of 8 words, `n` counts;
        // in the write pass `offsets[i]` plus ray i's count (the count pass's, same rays and
        // structure) is at most the offers' length, checked by the caller; in the count pass
        // the offsets are null and nothing is written but the counts.
        unsafe { launch.launch(grid(n)) }.map_err(driver("launching an offer kernel"))?;
        Ok(())
    }

    /// Turns an offer (and its instance slot) into the hit it reports.
    fn resolve(&self, record: &HitRecord, inst: u32) -> Option<Hit> {
        match self {
            Target::Gas(g) => g.resolve_one(record),
            Target::Ias(i) => i.resolve_one(record, inst),
        }
    }
}

/// Rays as the kernels read them, on the device.
fn upload_rays(ctx: &CudaContext, rays: &[Ray]) -> Result<CudaSlice<u32>, CudaError> {
    let records: Vec<RayRecord> = rays.par_iter().map(|&r| RayRecord::from(r)).collect();
    ctx.stream
        .clone_htod(bytemuck::cast_slice::<RayRecord, u32>(&records))
        .map_err(driver("copying rays to the device"))
}

/// Every ray's offers: the count pass into `counts`; then, unless `lists` is `None`, the
/// offers of consecutive rays in parts of at most [`OFFER_BUDGET`] handed to
/// `lists(first ray, counts of its rays, offers, instance slots)`.
#[allow(clippy::type_complexity)]
fn trace_offers(
    target: Target<'_>,
    rays: &[Ray],
    counts: &mut [u32],
    mut lists: Option<&mut dyn FnMut(usize, &[u32], &[HitRecord], &[u32])>,
) -> Result<(), CudaError> {
    let n = rays.len();
    check_batch(n)?;
    if n == 0 {
        return Ok(());
    }
    let ctx = target.ctx();
    let k = ctx.simulation_kernels()?;
    let d_rays = upload_rays(ctx, rays)?;
    let mut d_counts = ctx
        .stream
        .alloc_zeros::<u32>(n)
        .map_err(driver("allocating offer counts"))?;
    target.launch(k, &d_rays.slice(..), &mut d_counts, None, n as u32)?;
    ctx.stream
        .memcpy_dtoh(&d_counts, counts)
        .map_err(driver("copying offer counts to the host"))?;
    ctx.synchronize()?;
    let Some(lists) = lists.as_mut() else {
        return Ok(());
    };
    let budget = offer_budget();
    let mut start = 0;
    while start < n {
        // The longest run of rays from `start` within the budget (one ray at least).
        let mut end = start;
        let mut total = 0usize;
        while end < n && (end == start || total + counts[end] as usize <= budget) {
            total += counts[end] as usize;
            end += 1;
        }
        let mut offsets = Vec::with_capacity(end - start);
        let mut at = 0u64;
        for &c in &counts[start..end] {
            offsets.push(at);
            at += u64::from(c);
        }
        let s = &ctx.stream;
        let d_offsets = s
            .clone_htod(&offsets)
            .map_err(driver("copying offer offsets to the device"))?;
        let mut d_offers = s
            .alloc_zeros::<u32>(4 * total.max(1))
            .map_err(driver("allocating offers"))?;
        let mut d_insts = s
            .alloc_zeros::<u32>(total.max(1))
            .map_err(driver("allocating offers' instances"))?;
        let mut d_unused = s
            .alloc_zeros::<u32>(end - start)
            .map_err(driver("allocating offer counts"))?;
        target.launch(
            k,
            &d_rays.slice(8 * start..8 * end),
            &mut d_unused,
            Some((&d_offsets, &mut d_offers, &mut d_insts)),
            (end - start) as u32,
        )?;
        let mut offers = vec![HitRecord::zeroed(); total];
        let mut insts = vec![0u32; total];
        if total > 0 {
            s.memcpy_dtoh(
                &d_offers.slice(..4 * total),
                bytemuck::cast_slice_mut::<HitRecord, u32>(&mut offers),
            )
            .map_err(driver("copying offers to the host"))?;
            if matches!(target, Target::Ias(_)) {
                s.memcpy_dtoh(&d_insts.slice(..total), &mut insts)
                    .map_err(driver("copying offers' instances to the host"))?;
            }
        }
        ctx.synchronize()?;
        lists(start, &counts[start..end], &offers, &insts);
        start = end;
    }
    Ok(())
}

/// Sorts a ray's hits in the all-hits order and drops repeats (two offers of one primitive);
/// returns how many distinct hits are left at the front.
fn sort_distinct(hits: &mut [Hit]) -> usize {
    hits.sort_unstable_by(hit_order);
    let mut kept = 0;
    for i in 0..hits.len() {
        if kept == 0 || hit_order(&hits[kept - 1], &hits[i]) != Ordering::Equal {
            hits[kept] = hits[i];
            kept += 1;
        }
    }
    kept
}

/// Rays a thread turns into lists at a time.
const LIST_CHUNK: usize = 1024;

/// The hits of one part's offers, ray by ray, sorted, without repeats and at most
/// `max_hits_per_ray` each, as consecutive results of [`LIST_CHUNK`] rays made in parallel
/// (for [`AllHits::append_parts`]). `resolve` turns an offer and its instance slot into its hit.
pub(crate) fn distinct_lists(
    resolve: impl Fn(&HitRecord, u32) -> Option<Hit> + Sync,
    counts: &[u32],
    offers: &[HitRecord],
    insts: &[u32],
    max_hits_per_ray: usize,
) -> Vec<AllHits> {
    // Where each chunk's offers start.
    let mut starts = Vec::with_capacity(counts.len().div_ceil(LIST_CHUNK));
    let mut at = 0usize;
    for (i, &c) in counts.iter().enumerate() {
        if i % LIST_CHUNK == 0 {
            starts.push(at);
        }
        at += c as usize;
    }
    counts
        .par_chunks(LIST_CHUNK)
        .zip(starts.par_iter())
        .map(|(counts, &first)| {
            let mut part = AllHits::new();
            let mut list = Vec::new();
            let mut at = first;
            for &c in counts {
                let end = at + c as usize;
                list.clear();
                list.extend(
                    offers[at..end]
                        .iter()
                        .zip(&insts[at..end])
                        .filter_map(|(r, &i)| resolve(r, i)),
                );
                let kept = sort_distinct(&mut list);
                part.push_ray(
                    &list[..kept.min(max_hits_per_ray)],
                    kept <= max_hits_per_ray,
                );
                at = end;
            }
            part
        })
        .collect()
}

/// [`all_hits_batch`](CudaGas::all_hits_batch) of either structure.
fn all_hits(
    target: Target<'_>,
    rays: &[Ray],
    max_hits_per_ray: usize,
    out: &mut AllHits,
) -> Result<(), SurfaceQueryError> {
    out.clear();
    if let Some(e) = first_invalid(rays) {
        return Err(e);
    }
    let mut counts = vec![0u32; rays.len()];
    let mut each = |_: usize, counts: &[u32], offers: &[HitRecord], insts: &[u32]| {
        let resolve = |r: &HitRecord, i| target.resolve(r, i);
        out.append_parts(distinct_lists(
            resolve,
            counts,
            offers,
            insts,
            max_hits_per_ray,
        ));
    };
    trace_offers(target, rays, &mut counts, Some(&mut each)).map_err(query_error)
}

/// [`count_hits_batch`](CudaGas::count_hits_batch) of either structure: the count pass alone
/// where no primitive has two leaf slots (`repeats` false), else the lists' distinct hits.
fn count_hits(
    target: Target<'_>,
    repeats: bool,
    rays: &[Ray],
    counts: &mut [u32],
) -> Result<(), SurfaceQueryError> {
    length_check(rays.len(), counts.len())?;
    let mut found = vec![0u32; rays.len()];
    if repeats {
        let mut distinct = Vec::with_capacity(rays.len());
        let mut each = |_: usize, counts: &[u32], offers: &[HitRecord], insts: &[u32]| {
            let resolve = |r: &HitRecord, i| target.resolve(r, i);
            for part in distinct_lists(resolve, counts, offers, insts, usize::MAX) {
                distinct.extend(part.offsets().windows(2).map(|w| (w[1] - w[0]) as u32));
            }
        };
        trace_offers(target, rays, &mut found, Some(&mut each)).map_err(query_error)?;
        found = distinct;
    } else {
        trace_offers(target, rays, &mut found, None).map_err(query_error)?;
    }
    // As the CPU's batch: an invalid ray's count is left as it was, and the first is the error.
    let first = first_invalid(rays);
    for (i, (c, f)) in counts.iter_mut().zip(found).enumerate() {
        if rays[i].validate().is_ok() {
            *c = f;
        }
    }
    first.map_or(Ok(()), Err)
}

impl CudaGas {
    /// Refuses the simulation queries this GAS cannot run on the device.
    fn check_simulation(&self, needs_triangles: bool) -> Result<(), SurfaceQueryError> {
        if needs_triangles && self.kind != GasKind::Triangles {
            return Err(SurfaceQueryError::NotTriangles(self.info.kind));
        }
        if self.motion.is_some() {
            return Err(SurfaceQueryError::Unsupported(
                "a GAS with motion on the CUDA device",
            ));
        }
        if self.layout != NodeLayout::Bvh2 {
            return Err(SurfaceQueryError::Unsupported(
                "a GAS in the BVH4 layout on the CUDA device",
            ));
        }
        if self.kind == GasKind::Curves {
            return Err(SurfaceQueryError::Unsupported(
                "all hits of curves on the CUDA device",
            ));
        }
        Ok(())
    }

    /// Whether the GAS has no leaf slot the kernels could read.
    fn has_no_slots(&self) -> bool {
        self.slots.is_empty() || self.num_nodes == 0
    }

    /// The slot ids on the device and whether a primitive has several slots, made on first use.
    fn simulation_tables(&self) -> Result<Arc<SimulationTables>, CudaError> {
        let mut guard = self.simulation.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(t) = guard.as_ref() {
            return Ok(t.clone());
        }
        let ids = self.slot_globals();
        let mut seen = vec![false; self.meta.num_primitives as usize];
        let mut repeats = false;
        for &g in &ids {
            if g == NO_PRIMITIVE {
                continue;
            }
            match seen.get_mut(g as usize) {
                Some(s) if *s => {
                    repeats = true;
                    break;
                }
                Some(s) => *s = true,
                None => {}
            }
        }
        let ids = self
            .ctx
            .stream
            .clone_htod(&ids)
            .map_err(driver("copying slot ids to the device"))?;
        let t = Arc::new(SimulationTables { ids, repeats });
        *guard = Some(t.clone());
        Ok(t)
    }

    /// Every primitive each ray crosses in its `[tmin, tmax]`, into `out` (cleared first): as
    /// the CPU's `all_hits_batch`, the same lists bit for bit — sorted by `t` (then instance,
    /// build input and primitive), each primitive once, at most `max_hits_per_ray` (the
    /// nearest), with whether each list is complete. Triangles and spheres; custom primitives
    /// are not hit. An invalid ray is an error (the lowest index) and `out` is left empty.
    pub fn all_hits_batch(
        &self,
        rays: &[Ray],
        max_hits_per_ray: usize,
        out: &mut AllHits,
    ) -> Result<(), SurfaceQueryError> {
        if self.kind == GasKind::CustomPrimitives || self.has_no_slots() {
            out.clear();
            if let Some(e) = first_invalid(rays) {
                return Err(e);
            }
            for _ in rays {
                out.push_ray(&[], true);
            }
            return Ok(());
        }
        self.check_simulation(false)?;
        all_hits(Target::Gas(self), rays, max_hits_per_ray, out)
    }

    /// The number of distinct primitives each ray crosses in its `[tmin, tmax]`, as the CPU's
    /// `count_hits_batch`. The first invalid ray (the lowest index) is the error; the counts of
    /// the others are written.
    pub fn count_hits_batch(
        &self,
        rays: &[Ray],
        counts: &mut [u32],
    ) -> Result<(), SurfaceQueryError> {
        length_check(rays.len(), counts.len())?;
        if self.kind == GasKind::CustomPrimitives || self.has_no_slots() {
            let first = first_invalid(rays);
            for (c, r) in counts.iter_mut().zip(rays) {
                if r.validate().is_ok() {
                    *c = 0;
                }
            }
            return first.map_or(Ok(()), Err);
        }
        self.check_simulation(false)?;
        let repeats = self.simulation_tables().map_err(query_error)?.repeats;
        count_hits(Target::Gas(self), repeats, rays, counts)
    }

    /// Queues a point kernel (`closest` or signed distances) over `points`, returning its
    /// output words (`words` per point) on the host.
    fn point_kernel(
        &self,
        points: &[Vec3],
        max_distance: f32,
        signed: bool,
    ) -> Result<Vec<u32>, CudaError> {
        let n = points.len();
        check_batch(n)?;
        let words = if signed { 1 } else { 8 };
        let ctx = &self.ctx;
        let k = ctx.simulation_kernels()?;
        let tables = self.simulation_tables()?;
        // A non-finite point is an error of its own: the kernels see the origin instead.
        let staged: Vec<[f32; 4]> = points
            .par_iter()
            .map(|p| {
                if p.is_finite() {
                    [p.x, p.y, p.z, max_distance]
                } else {
                    [0.0, 0.0, 0.0, max_distance]
                }
            })
            .collect();
        let s = &ctx.stream;
        let d_points = s
            .clone_htod(bytemuck::cast_slice::<[f32; 4], f32>(&staged))
            .map_err(driver("copying points to the device"))?;
        let mut d_out = s
            .alloc_zeros::<u32>(words * n.max(1))
            .map_err(driver("allocating point results"))?;
        let b = self.info.bounds;
        let extent = b.min.abs().max(b.max.abs()).max_element();
        let extent = if extent.is_finite() { extent } else { 0.0 };
        let n32 = n as u32;
        let nodes = self.nodes.nodes();
        let mut launch = s.launch_builder(if signed {
            &k.signed_distances
        } else {
            &k.closest_points
        });
        launch
            .arg(&nodes)
            .arg(&self.triangles)
            .arg(&tables.ids)
            .arg(&d_points)
            .arg(&mut d_out)
            .arg(&extent)
            .arg(&n32);
        // SAFETY: the kernels' parameters are (const float4* nodes, const float4* triangles,
        // const u32* slot ids, const float4* points, uint4* or float* out, float extent, u32 n),
        // matching the arguments: this triangle GAS's binary nodes and triangles (every child
        // index and slot range in bounds), one id per leaf slot, `n` points of 4 words and
        // `words` output words per point.
        unsafe { launch.launch(grid(n32)) }.map_err(driver("launching a point kernel"))?;
        let mut out = vec![0u32; words * n];
        s.memcpy_dtoh(&d_out.slice(..words * n), &mut out)
            .map_err(driver("copying point results to the host"))?;
        ctx.synchronize()?;
        Ok(out)
    }

    /// The closest point of this triangle GAS to every point, as the CPU's
    /// `closest_point_batch`: the same point, distance, triangle and barycentrics (`None` for
    /// an empty GAS). The first non-finite point (the lowest index) is the error; the others'
    /// results are written.
    pub fn closest_point_batch(
        &self,
        points: &[Vec3],
        out: &mut [Option<ClosestPoint>],
    ) -> Result<(), SurfaceQueryError> {
        self.check_simulation(true)?;
        length_check(points.len(), out.len())?;
        let first = first_non_finite(points);
        if self.has_no_slots() {
            for (o, p) in out.iter_mut().zip(points) {
                if p.is_finite() {
                    *o = None;
                }
            }
            return first.map_or(Ok(()), Err);
        }
        let words = self
            .point_kernel(points, f32::INFINITY, false)
            .map_err(query_error)?;
        out.par_iter_mut()
            .zip(points.par_iter())
            .zip(words.par_chunks(8))
            .for_each(|((o, p), w)| {
                if !p.is_finite() {
                    return;
                }
                let slot = w[6];
                *o = self.slots.get(slot as usize).map(|s| ClosestPoint {
                    point: Vec3::new(
                        f32::from_bits(w[0]),
                        f32::from_bits(w[1]),
                        f32::from_bits(w[2]),
                    ),
                    distance: f32::from_bits(w[3]).sqrt(),
                    primitive_index: s.primitive_index,
                    build_input: s.build_input,
                    u: f32::from_bits(w[4]),
                    v: f32::from_bits(w[5]),
                });
            });
        first.map_or(Ok(()), Err)
    }

    /// The signed distance from every point to the surface, as the CPU's
    /// `signed_distance_batch`: negative inside a closed, consistently oriented mesh, `+inf`
    /// for an empty GAS. Errors as [`closest_point_batch`](Self::closest_point_batch).
    pub fn signed_distance_batch(
        &self,
        points: &[Vec3],
        out: &mut [f32],
    ) -> Result<(), SurfaceQueryError> {
        self.check_simulation(true)?;
        length_check(points.len(), out.len())?;
        let first = first_non_finite(points);
        let words = if self.has_no_slots() {
            vec![f32::INFINITY.to_bits(); points.len()]
        } else {
            self.point_kernel(points, f32::INFINITY, true)
                .map_err(query_error)?
        };
        for ((o, p), w) in out.iter_mut().zip(points).zip(words) {
            if p.is_finite() {
                *o = f32::from_bits(w);
            }
        }
        first.map_or(Ok(()), Err)
    }

    /// Whether every point lies strictly inside the closed mesh (a negative signed distance).
    pub fn contains_batch(
        &self,
        points: &[Vec3],
        out: &mut [bool],
    ) -> Result<(), SurfaceQueryError> {
        length_check(points.len(), out.len())?;
        let mut d = vec![0.0f32; points.len()];
        let r = self.signed_distance_batch(points, &mut d);
        for ((o, p), d) in out.iter_mut().zip(points).zip(d) {
            if p.is_finite() {
                *o = d < 0.0;
            }
        }
        r
    }
}

impl CudaIas {
    /// Whether a primitive of some child has several leaf slots.
    fn child_repeats(&self) -> Result<bool, CudaError> {
        for gas in self.triangle_children() {
            if gas.simulation_tables()?.repeats {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// Every primitive each ray crosses under the instances, as the CPU's
    /// `Ias::all_hits_batch` (each primitive of each instance once). Over triangle GASes
    /// ([`is_queryable`](Self::is_queryable)); errors as [`CudaGas::all_hits_batch`].
    pub fn all_hits_batch(
        &self,
        rays: &[Ray],
        max_hits_per_ray: usize,
        out: &mut AllHits,
    ) -> Result<(), SurfaceQueryError> {
        self.check_simulation()?;
        all_hits(Target::Ias(self), rays, max_hits_per_ray, out)
    }

    /// The number of distinct primitives of each instance each ray crosses, as the CPU's
    /// `Ias::count_hits_batch`.
    pub fn count_hits_batch(
        &self,
        rays: &[Ray],
        counts: &mut [u32],
    ) -> Result<(), SurfaceQueryError> {
        self.check_simulation()?;
        let repeats = self.child_repeats().map_err(query_error)?;
        count_hits(Target::Ias(self), repeats, rays, counts)
    }

    fn check_simulation(&self) -> Result<(), SurfaceQueryError> {
        if self.is_queryable() {
            Ok(())
        } else {
            Err(SurfaceQueryError::Unsupported(
                "all hits through instances of IASes, transforms, custom primitives or structures with motion on the CUDA device",
            ))
        }
    }
}

/// A hit's primitive found in device memory: the address of its record, the ray in its
/// object space, and the instance above it.
#[derive(Clone, Copy)]
struct Located {
    address: u64,
    /// Words of the record: [`TRIANGLE_WORDS`] or [`SPHERE_WORDS`].
    words: u32,
    sphere: bool,
    object_ray: Ray,
    /// (object-to-world, world-to-object) of the instance, if any.
    instance: Option<(Transform, Transform)>,
}

/// Record words of a triangle slot (three `float4`) and of a sphere slot (one).
const TRIANGLE_WORDS: usize = 12;
const SPHERE_WORDS: usize = 4;

/// The interval around a hit's `t` in which the CPU's surface query finds the hit again.
fn around(t: f32) -> (f32, f32) {
    let slack = t * 1e-6 + f32::MIN_POSITIVE;
    ((t - slack).max(0.0), t + slack)
}

/// The surfaces of a batch of hits on either structure, as the CPU's `hit_surface_batch`:
/// `locate` finds each hit's primitive (an error, or `None` where it is not in the structure),
/// the primitives' records are read from device memory in one launch, each hit is checked to
/// lie on its ray there, and the surface is finished as on the CPU.
fn surfaces<N: ShadingNormals + Sync + ?Sized>(
    ctx: &CudaContext,
    rays: &[Ray],
    hits: &[Option<Hit>],
    normals: &N,
    out: &mut [Option<SurfaceHit>],
    locate: impl Fn(&Ray, &Hit) -> Result<Option<Located>, SurfaceQueryError> + Sync,
) -> Result<(), SurfaceQueryError> {
    length_check(rays.len(), hits.len())?;
    length_check(rays.len(), out.len())?;
    check_batch(rays.len()).map_err(query_error)?;
    let not_found = |i: usize, h: &Hit| SurfaceQueryError::HitNotFound {
        index: i,
        primitive_index: h.primitive_index,
        build_input: h.build_input,
        instance_index: h.instance_index,
    };
    // Each query: Ok(None) for a miss, else where its primitive lies.
    let found: Vec<Result<Option<Located>, SurfaceQueryError>> = rays
        .par_iter()
        .zip(hits.par_iter())
        .enumerate()
        .map(|(i, (ray, hit))| {
            let Some(h) = hit else { return Ok(None) };
            ray.validate()
                .map_err(|error| SurfaceQueryError::InvalidRay { index: i, error })?;
            match h.hit_kind.primitive_type() {
                PrimitiveType::Triangle | PrimitiveType::Sphere => {}
                PrimitiveType::Custom => {
                    return Err(SurfaceQueryError::Unsupported("a custom primitive"))
                }
                PrimitiveType::Curve(_) => return Err(SurfaceQueryError::Unsupported("a curve")),
            }
            if !(h.t >= 0.0 && h.t.is_finite()) {
                return Err(not_found(i, h));
            }
            match locate(ray, h).map_err(|e| e.at(i))? {
                Some(l) => Ok(Some(l)),
                None => Err(not_found(i, h)),
            }
        })
        .collect();
    // Every record in one launch, in query order.
    let located: Vec<(usize, Located)> = found
        .iter()
        .enumerate()
        .filter_map(|(i, f)| f.as_ref().ok().copied().flatten().map(|l| (i, l)))
        .collect();
    let words = TRIANGLE_WORDS;
    let mut records = vec![0u32; words * located.len()];
    if !located.is_empty() {
        let k = ctx.simulation_kernels().map_err(query_error)?;
        let s = &ctx.stream;
        let addrs: Vec<u64> = located.iter().map(|(_, l)| l.address).collect();
        let lens: Vec<u32> = located.iter().map(|(_, l)| l.words).collect();
        let mut run = || -> Result<(), CudaError> {
            let d_addrs = s
                .clone_htod(&addrs)
                .map_err(driver("copying record addresses to the device"))?;
            let d_lens = s
                .clone_htod(&lens)
                .map_err(driver("copying record sizes to the device"))?;
            let mut d_out = s
                .alloc_zeros::<u32>(records.len())
                .map_err(driver("allocating records"))?;
            let n = located.len() as u32;
            let mut launch = s.launch_builder(&k.gather_records);
            launch.arg(&d_addrs).arg(&d_lens).arg(&mut d_out).arg(&n);
            // SAFETY: oxray_gather_records(const u64* addrs, const u32* words, u32* out,
            // u32 n): `n` addresses, each the start of a slot's record in a live GAS of this
            // context (the caller's structures, borrowed for the whole call), holding the
            // `words[i]` words read from it (12 for a triangle slot, 4 for a sphere's: `locate`
            // sets both from the GAS's kind), and 12 output words per address.
            unsafe { launch.launch(grid(n)) }.map_err(driver("launching the record gather"))?;
            s.memcpy_dtoh(&d_out, &mut records)
                .map_err(driver("copying records to the host"))?;
            ctx.synchronize()
        };
        run().map_err(query_error)?;
    }
    let mut record_of = vec![usize::MAX; rays.len()];
    for (k, (i, _)) in located.iter().enumerate() {
        record_of[*i] = k;
    }
    let results: Vec<Result<Option<SurfaceHit>, SurfaceQueryError>> = found
        .into_par_iter()
        .enumerate()
        .map(|(i, f)| {
            let Some(l) = f? else { return Ok(None) };
            let h = hits[i].as_ref().expect("located hits are hits");
            let w = &records[words * record_of[i]..words * record_of[i] + words];
            let f = |k: usize| f32::from_bits(w[k]);
            let (tmin, tmax) = around(h.t);
            let (o, d) = (l.object_ray.origin, l.object_ray.direction);
            let (point, normal, shading) = if l.sphere {
                let sphere = oxray_bvh::Sphere::new(Vec3::new(f(0), f(1), f(2)), f(3));
                if sphere.intersect(o, d, tmin, tmax).is_none() {
                    return Err(not_found(i, h));
                }
                let (p, n) =
                    sphere_surface_parts(Vec3::new(f(0), f(1), f(2)), f(3), &l.object_ray, h.t);
                (p, n, None)
            } else {
                let v = [0, 4, 8].map(|k| [f(k), f(k + 1), f(k + 2)]);
                let hit = WatertightRay::new(o, d).intersect(&v[0], &v[1], &v[2], tmin, tmax);
                if hit.is_none() {
                    return Err(not_found(i, h));
                }
                triangle_surface_parts(v.map(Vec3::from), h, normals.vertex_normals(h))
            };
            Ok(Some(surface_in_world(
                point,
                normal,
                shading,
                l.instance,
                h.hit_kind.is_front_face(),
            )))
        })
        .collect();
    let mut first = None;
    for (i, (o, r)) in out.iter_mut().zip(results).enumerate() {
        match r {
            Ok(v) => *o = v,
            Err(e) => {
                first.get_or_insert(e.at(i));
            }
        }
    }
    first.map_or(Ok(()), Err)
}

impl CudaGas {
    /// The device address of the slot table (read once per batch: each lookup records a
    /// stream event).
    fn records_address(&self) -> u64 {
        let (base, _guard) = self.triangles.device_ptr(&self.ctx.stream);
        base
    }

    /// Where hit `h` of `ray` (in this GAS's space) lies, the slot table being at `base`:
    /// `None` where it is not one of this GAS's primitives; the instance above it is the
    /// caller's.
    fn locate(
        &self,
        base: u64,
        ray: &Ray,
        h: &Hit,
        instance: Option<(Transform, Transform)>,
    ) -> Option<Located> {
        let global = self
            .meta
            .global_primitive(h.primitive_index, h.sbt_gas_index)?;
        let slot = *self.primitive_slots().get(global as usize)?;
        let info = self.slots.get(slot as usize)?;
        if info.primitive_index != h.primitive_index || info.build_input != h.build_input {
            return None;
        }
        let (sphere, words) = match self.kind {
            GasKind::Spheres => (true, SPHERE_WORDS),
            _ => (false, TRIANGLE_WORDS),
        };
        Some(Located {
            address: base + 4 * (words as u64) * u64::from(slot),
            words: words as u32,
            sphere,
            object_ray: *ray,
            instance,
        })
    }

    /// Refuses the surface queries this GAS cannot answer on the device.
    fn check_surfaces(&self) -> Result<(), SurfaceQueryError> {
        if self.motion.is_some() {
            return Err(SurfaceQueryError::Unsupported(
                "a GAS with motion on the CUDA device",
            ));
        }
        match self.kind {
            GasKind::Triangles | GasKind::Spheres => Ok(()),
            GasKind::CustomPrimitives => Err(SurfaceQueryError::Unsupported("a custom primitive")),
            GasKind::Curves => Err(SurfaceQueryError::Unsupported("a curve")),
        }
    }

    /// The world-space point, unit geometric normal and face of every hit (`hits[i]` of
    /// `rays[i]`, `None` for a miss; `out[i]` `None` then), as the CPU's `hit_surface_batch`:
    /// the same values bit for bit, and the same errors (a hit that is not on its ray in this
    /// structure is [`SurfaceQueryError::HitNotFound`]). The primitives are read from device
    /// memory; the surfaces are finished on the host. The first failing query (the lowest
    /// index) is the error; every other output is written.
    pub fn hit_surface_batch(
        &self,
        rays: &[Ray],
        hits: &[Option<Hit>],
        out: &mut [Option<SurfaceHit>],
    ) -> Result<(), SurfaceQueryError> {
        self.hit_surface_batch_shaded(rays, hits, &NoShadingNormals, out)
    }

    /// [`hit_surface_batch`](Self::hit_surface_batch) with the shading normal interpolated
    /// from vertex normals.
    pub fn hit_surface_batch_shaded<N: ShadingNormals + Sync + ?Sized>(
        &self,
        rays: &[Ray],
        hits: &[Option<Hit>],
        normals: &N,
        out: &mut [Option<SurfaceHit>],
    ) -> Result<(), SurfaceQueryError> {
        self.check_surfaces()?;
        let base = self.records_address();
        surfaces(&self.ctx, rays, hits, normals, out, |ray, h| {
            if (h.instance_id, h.instance_index) != (!0, 0) {
                return Ok(None);
            }
            Ok(self.locate(base, ray, h, None))
        })
    }
}

impl CudaIas {
    /// [`CudaGas::hit_surface_batch`] for hits through this IAS's instances (one level over
    /// triangle GASes: [`is_queryable`](Self::is_queryable)).
    pub fn hit_surface_batch(
        &self,
        rays: &[Ray],
        hits: &[Option<Hit>],
        out: &mut [Option<SurfaceHit>],
    ) -> Result<(), SurfaceQueryError> {
        self.hit_surface_batch_shaded(rays, hits, &NoShadingNormals, out)
    }

    /// [`hit_surface_batch`](Self::hit_surface_batch) with vertex normals.
    pub fn hit_surface_batch_shaded<N: ShadingNormals + Sync + ?Sized>(
        &self,
        rays: &[Ray],
        hits: &[Option<Hit>],
        normals: &N,
        out: &mut [Option<SurfaceHit>],
    ) -> Result<(), SurfaceQueryError> {
        self.check_simulation()?;
        let data = self.data();
        let slot_of: std::collections::HashMap<u32, usize> = data
            .instances
            .iter()
            .enumerate()
            .map(|(slot, inst)| (inst.index, slot))
            .collect();
        // The slot table of each instance's child, looked up once per child.
        let mut bases: std::collections::HashMap<usize, u64> = Default::default();
        let base_of: Vec<u64> = (0..data.instances.len())
            .map(|slot| {
                self.triangle_child(slot).map_or(0, |g| {
                    *bases
                        .entry(Arc::as_ptr(g) as usize)
                        .or_insert_with(|| g.records_address())
                })
            })
            .collect();
        surfaces(self.context(), rays, hits, normals, out, |ray, h| {
            let Some(&slot) = slot_of.get(&h.instance_index) else {
                return Ok(None);
            };
            let inst = &data.instances[slot];
            if inst.instance_id != h.instance_id {
                return Ok(None);
            }
            let Some(gas) = self.triangle_child(slot) else {
                return Ok(None);
            };
            let object_ray = Ray {
                origin: inst.world_to_object.transform_point(ray.origin),
                direction: inst.world_to_object.transform_vector(ray.direction),
                ..*ray
            };
            Ok(gas.locate(
                base_of[slot],
                &object_ray,
                h,
                Some((inst.object_to_world, inst.world_to_object)),
            ))
        })
    }
}

impl CudaIas {
    /// Refuses, before any search, what the instance closest-point kernel cannot answer (as
    /// the CPU's `Ias::closest_point` refuses it, whatever the point): a child that is not a
    /// triangle GAS without motion (nested instances and transforms are the CPU's), or an
    /// instance that is not placed by a similarity. Else each instance slot's scale.
    fn closest_point_scales(&self) -> Result<Vec<f32>, SurfaceQueryError> {
        let data = self.data();
        let mut scales = vec![0.0f32; data.instances.len()];
        for (slot, inst) in data.instances.iter().enumerate() {
            let Some(child) = self.child(slot) else {
                if inst.mask == 0 && !inst.child.is_null() {
                    // The device keeps no child for an instance no ray can hit; the CPU's
                    // point query still searches it.
                    return Err(SurfaceQueryError::Unsupported(
                        "closest points under an instance of visibility mask 0 on the CUDA device",
                    ));
                }
                continue;
            };
            match child {
                CudaChild::Gas(g) if g.kind != GasKind::Triangles => {
                    return Err(SurfaceQueryError::NotTriangles(g.info.kind));
                }
                CudaChild::Gas(g) if g.motion.is_some() => {
                    return Err(SurfaceQueryError::Unsupported(
                        "a GAS with motion on the CUDA device",
                    ));
                }
                CudaChild::Gas(_) => {}
                CudaChild::Motion(_) => {
                    return Err(SurfaceQueryError::Unsupported(
                        "the closest point through a motion transform (a point query has no time)",
                    ));
                }
                CudaChild::Ias(_) | CudaChild::Static(_) => {
                    return Err(SurfaceQueryError::Unsupported(
                        "closest points through nested instances or static transforms on the CUDA device (the CPU answers them)",
                    ));
                }
            }
            scales[slot] = inst.object_to_world.similarity_scale().ok_or(
                SurfaceQueryError::Unsupported(
                    "the closest point through a transform that is not a similarity (a non-uniform scale or a shear)",
                ),
            )?;
        }
        Ok(scales)
    }

    /// The closest point of the triangles under this IAS (one level of instances of triangle
    /// GASes, placed by similarities) to every point, with the instance it lies under, as the
    /// CPU's `Ias::closest_point_batch`: the same point, distance, triangle, barycentrics and
    /// instance, ties between instances included (the nearer box, then the lower slot). What
    /// cannot be answered is refused before any search, whatever the points; then the first
    /// non-finite point (the lowest index) is the error and the others' results are written.
    pub fn closest_point_batch(
        &self,
        points: &[Vec3],
        out: &mut [Option<InstanceClosestPoint>],
    ) -> Result<(), SurfaceQueryError> {
        length_check(points.len(), out.len())?;
        let scales = self.closest_point_scales()?;
        let first = first_non_finite(points);
        check_batch(points.len()).map_err(query_error)?;
        let data = self.data();
        // Four float4 per instance slot: the object-to-world rows, then the child's slot-id
        // table address, the scale and the child's extent.
        let mut extras = vec![0u32; 16 * data.instances.len()];
        // Each child's slot-id table, address and extent, looked up once per child (an address
        // lookup records a stream event).
        let mut tables: std::collections::HashMap<usize, (Arc<SimulationTables>, u64, f32)> =
            Default::default();
        for (slot, inst) in data.instances.iter().enumerate() {
            let Some(gas) = self.triangle_child(slot) else {
                continue;
            };
            let key = Arc::as_ptr(gas) as usize;
            if let std::collections::hash_map::Entry::Vacant(v) = tables.entry(key) {
                let t = gas.simulation_tables().map_err(query_error)?;
                let ids = {
                    let (ids, _guard) = t.ids.device_ptr(&gas.ctx.stream);
                    ids
                };
                let b = gas.info.bounds;
                let extent = b.min.abs().max(b.max.abs()).max_element();
                v.insert((t, ids, if extent.is_finite() { extent } else { 0.0 }));
            }
            let (_, ids, extent) = &tables[&key];
            let e = &mut extras[16 * slot..16 * slot + 16];
            for (k, f) in inst.object_to_world.0.iter().enumerate() {
                e[k] = f.to_bits();
            }
            e[12] = *ids as u32;
            e[13] = (*ids >> 32) as u32;
            e[14] = scales[slot].to_bits();
            e[15] = extent.to_bits();
        }
        let n = points.len();
        let mut words = vec![0u32; 8 * n];
        if n > 0 && !data.instances.is_empty() {
            let ctx = self.context();
            let k = ctx.simulation_kernels().map_err(query_error)?;
            let s = &ctx.stream;
            let staged: Vec<[f32; 4]> = points
                .iter()
                .map(|p| {
                    if p.is_finite() {
                        [p.x, p.y, p.z, 0.0]
                    } else {
                        [0.0; 4]
                    }
                })
                .collect();
            let b = data.bounds;
            let top_extent = b.min.abs().max(b.max.abs()).max_element();
            let top_extent = if top_extent.is_finite() {
                top_extent
            } else {
                0.0
            };
            let n32 = n as u32;
            let mut run = || -> Result<(), CudaError> {
                let d_points = s
                    .clone_htod(bytemuck::cast_slice::<[f32; 4], f32>(&staged))
                    .map_err(driver("copying points to the device"))?;
                let d_extras = s
                    .clone_htod(&extras)
                    .map_err(driver("copying instance tables to the device"))?;
                let mut d_out = s
                    .alloc_zeros::<u32>(8 * n)
                    .map_err(driver("allocating point results"))?;
                let (nodes, instances) = self.device_tables();
                let mut launch = s.launch_builder(&k.instance_closest_points);
                launch
                    .arg(nodes)
                    .arg(instances)
                    .arg(&d_extras)
                    .arg(&d_points)
                    .arg(&mut d_out)
                    .arg(&top_extent)
                    .arg(&n32);
                // SAFETY: oxray_instance_closest_points(const float4* top, const float4* insts,
                // const float4* extras, const float4* points, uint4* out, float top_extent,
                // u32 n): this IAS's top-level nodes and instance slots (every child address a
                // live triangle GAS it keeps), 16 extra words per slot whose slot-id address is
                // that child's table (kept alive by `tables` through the call), `n` points of 4
                // words and 8 output words per point.
                unsafe { launch.launch(grid(n32)) }
                    .map_err(driver("launching the instance closest-point kernel"))?;
                s.memcpy_dtoh(&d_out, &mut words)
                    .map_err(driver("copying point results to the host"))?;
                ctx.synchronize()
            };
            run().map_err(query_error)?;
        }
        drop(tables);
        out.par_iter_mut()
            .zip(points.par_iter())
            .enumerate()
            .for_each(|(i, (o, p))| {
                if !p.is_finite() {
                    return;
                }
                let w = &words[8 * i..8 * i + 8];
                *o = (|| {
                    let inst = data.instances.get(w[7] as usize)?;
                    let gas = self.triangle_child(w[7] as usize)?;
                    let s = gas.slots.get(w[6] as usize)?;
                    Some(InstanceClosestPoint {
                        closest: ClosestPoint {
                            point: Vec3::new(
                                f32::from_bits(w[0]),
                                f32::from_bits(w[1]),
                                f32::from_bits(w[2]),
                            ),
                            distance: f32::from_bits(w[3]),
                            primitive_index: s.primitive_index,
                            build_input: s.build_input,
                            u: f32::from_bits(w[4]),
                            v: f32::from_bits(w[5]),
                        },
                        instance_id: inst.instance_id,
                        instance_index: inst.index,
                    })
                })();
            });
        first.map_or(Ok(()), Err)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use oxray_core::HitKind;

    #[test]
    fn the_simulation_kernels_compile_with_nvrtc_where_it_is_present() {
        let Some(ptx) = crate::context::ptx_or_skip(|| compile_simulation((9, 0))) else {
            return;
        };
        for entry in SIMULATION_ENTRIES {
            assert!(ptx.contains(&format!(".entry {entry}")), "{entry} missing");
        }
        // The query kernels are the trace module's, not compiled twice.
        assert!(!ptx.contains(".entry oxray_closest_bvh2"));
    }

    fn hit(t: f32, primitive_index: u32, instance_index: u32) -> Hit {
        Hit {
            t,
            u: 0.0,
            v: 0.0,
            primitive_index,
            sbt_gas_index: 0,
            build_input: 0,
            hit_kind: HitKind::TRIANGLE_FRONT_FACE,
            instance_id: !0,
            instance_index,
        }
    }

    #[test]
    fn repeats_are_dropped_and_lists_sorted_as_on_the_cpu() {
        // Offers in walk order: a primitive met twice (two leaves), two primitives at one t,
        // one primitive under two instances.
        let mut hits = [
            hit(3.0, 7, 0),
            hit(1.0, 2, 0),
            hit(3.0, 7, 0),
            hit(1.0, 1, 0),
            hit(2.0, 4, 1),
            hit(2.0, 4, 0),
        ];
        let kept = sort_distinct(&mut hits);
        let keys: Vec<(f32, u32, u32)> = hits[..kept]
            .iter()
            .map(|h| (h.t, h.primitive_index, h.instance_index))
            .collect();
        assert_eq!(
            keys,
            [
                (1.0, 1, 0),
                (1.0, 2, 0),
                (2.0, 4, 0),
                (2.0, 4, 1),
                (3.0, 7, 0)
            ]
        );
    }

    #[test]
    fn device_failures_keep_their_meaning_as_query_errors() {
        assert_eq!(
            query_error(CudaError::Unsupported("x")),
            SurfaceQueryError::Unsupported("x")
        );
        assert_eq!(
            query_error(CudaError::LengthMismatch {
                rays: 2,
                outputs: 3
            }),
            SurfaceQueryError::LengthMismatch {
                queries: 2,
                outputs: 3
            }
        );
        assert!(matches!(
            query_error(CudaError::TooLarge("a batch".into())),
            SurfaceQueryError::Device(m) if m.contains("a batch")
        ));
    }

    #[test]
    fn batch_checks_report_the_lowest_bad_index() {
        let mut rays = vec![Ray::new(Vec3::ZERO, Vec3::Z); 5];
        assert!(first_invalid(&rays).is_none());
        rays[3] = Ray::new(Vec3::NAN, Vec3::Z);
        rays[4] = Ray::new(Vec3::ZERO, Vec3::ZERO);
        assert!(matches!(
            first_invalid(&rays),
            Some(SurfaceQueryError::InvalidRay { index: 3, .. })
        ));
        let points = [Vec3::ZERO, Vec3::INFINITY, Vec3::NAN];
        assert!(matches!(
            first_non_finite(&points),
            Some(SurfaceQueryError::NonFinitePoint { index: 1, .. })
        ));
        assert!(length_check(2, 2).is_ok());
        assert!(length_check(2, 1).is_err());
    }
}
