//! Triangle GASes built on the device: the inputs are validated on the host (the same rules and
//! typed errors as every backend, [`GasData::prepare`]), their vertices and indices copied to the
//! device, and the kernels of [`BUILD_SOURCE`] make a linear BVH (Karras 2012) collapsed into
//! leaves by the SAH, written straight into the binary node layout the trace kernels and
//! pipelines walk ([`crate::NodeLayout::Bvh2`]). Only the slot table (the sorted triangle ids, 4 bytes a
//! triangle) comes back to the host, where hits are resolved.
//!
//! Which builds run here is [`Cuda`](crate::Cuda)'s choice ([`GasBuilder`]); this module is the
//! builder itself, with its timings for benchmarks ([`build_gas`]).

use crate::context::{nvrtc_compile, CudaContext};
use crate::error::{driver, CudaError};
use crate::gas::CudaGas;
use crate::layout::{SlotInfo, MAX_SLOTS};
use crate::node_buffer::NodeBuffer;
use cudarc::driver::{CudaFunction, CudaSlice, DevicePtr, LaunchConfig, PushKernelArg};
use oxray_bvh::{AccelBufferSizes, Bvh2, BvhStats, GasData, GasInfo, GasKind, MAX_BVH2_DEPTH};
use oxray_core::{
    Aabb, BuildError, BuildFlags, BuildInput, BuildOptions, IndexFormat, TriangleInput,
    VertexFormat,
};
use rayon::prelude::*;
use std::time::Instant;
use thiserror::Error;

/// The CUDA C++ source of the builder's kernels, compiled by NVRTC on the first device build.
pub const BUILD_SOURCE: &str = include_str!("kernels/build.cu");

/// Threads per block of every build kernel (`BUILD_BLOCK`).
const BLOCK: u32 = 256;
/// Keys per tile of the radix sort and the prefix sums (`SORT_TILE`).
const TILE: usize = 2048;
/// Largest leaf the collapse makes in a GAS, as the CPU builder's presets.
pub const MAX_LEAF: u32 = 8;
/// Bytes of one node of the radix tree (`INode`).
const INODE_BYTES: usize = 64;

/// Where a [`Cuda`](crate::Cuda) backend builds triangle GASes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum GasBuilder {
    /// On the device, as OptiX does: the default. Builds the device does not make (spheres,
    /// curves, motion keys, the BVH4 layout: see [`Cuda`](crate::Cuda)) still run on the
    /// host.
    #[default]
    Device,
    /// On the host, with the binned SAH builder every backend shares, then uploaded.
    Host,
}

impl GasBuilder {
    /// The environment variable that overrides the default: `host` or `device`.
    pub const ENV: &'static str = "OXRAY_CUDA_GAS_BUILDER";

    /// The builder `OXRAY_CUDA_GAS_BUILDER` names (`device` when unset); an error names a value
    /// it does not know.
    pub fn from_env() -> Result<GasBuilder, CudaError> {
        match std::env::var(Self::ENV) {
            Err(_) => Ok(GasBuilder::Device),
            Ok(v) => v.parse(),
        }
    }

    /// `device` or `host`.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            GasBuilder::Device => "device",
            GasBuilder::Host => "host",
        }
    }
}

impl std::str::FromStr for GasBuilder {
    type Err = CudaError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "device" | "gpu" => Ok(GasBuilder::Device),
            "host" | "cpu" => Ok(GasBuilder::Host),
            other => Err(CudaError::Config(format!(
                "{}={other:?}: expected `device` or `host`",
                GasBuilder::ENV
            ))),
        }
    }
}

/// How the device builds one GAS.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DeviceBuildConfig {
    /// Bits of the Morton codes: 30 or 32 (32-bit keys, four sort passes; 32 takes the first
    /// 32 bits of the 60-bit code, so its cells are split once more in x and y), or 60 (64-bit
    /// keys, eight passes, finer cells for large meshes). Other values build as 60.
    pub morton_bits: u32,
    /// The deepest tree accepted (root's children at depth 1); a deeper one is refused with
    /// [`CudaError::TreeTooDeep`] (and [`Cuda`](crate::Cuda) builds on the host instead). The
    /// traversal stacks hold [`MAX_BVH2_DEPTH`] levels.
    pub max_depth: u32,
    /// `ALLOW_UPDATE`: inactive primitives (degenerate triangles, invalid boxes) keep a leaf
    /// slot with an empty box, since an update may make them active (guide §5.6), and the
    /// build keeps what the device's refit needs (the slots' primitives, the nodes by height).
    pub keep_inactive: bool,
    /// The largest leaf the SAH collapse makes: [`MAX_LEAF`] for a GAS,
    /// [`oxray_bvh::IAS_MAX_LEAF`] for the top level of an IAS (an instance costs a ray
    /// transform).
    pub max_leaf: u32,
}

impl DeviceBuildConfig {
    /// `PREFER_FAST_BUILD`: 32-bit codes, the first 32 bits of the 60-bit code (four sort
    /// passes, as 30-bit codes, but cells split once more in x and y: on a 7.9 M-triangle mesh
    /// the tree traces incoherent rays at 92 % of the host's fast-build tree against 84 % with
    /// 30 bits, for 0.2 ms more; `oxray bench --gas-builds` measures both). With 32-bit keys
    /// whose ties are broken by position, no tree is deeper than 32 + 31 levels, within the
    /// traversal's bound.
    pub const FAST_BUILD: DeviceBuildConfig = DeviceBuildConfig {
        morton_bits: 32,
        max_depth: MAX_BVH2_DEPTH as u32,
        keep_inactive: false,
        max_leaf: MAX_LEAF,
    };
    /// No preference, and `PREFER_FAST_TRACE`: 60-bit codes.
    pub const DEFAULT: DeviceBuildConfig = DeviceBuildConfig {
        morton_bits: 60,
        max_depth: MAX_BVH2_DEPTH as u32,
        keep_inactive: false,
        max_leaf: MAX_LEAF,
    };

    /// Above this many triangles, `PREFER_FAST_BUILD` uses 60-bit codes too: 30- and 32-bit
    /// cells grow too coarse (a 66 M-triangle mesh traced at 63 % of the host-built tree's speed with
    /// 30-bit codes, 104 % with 60-bit ones; 7.9 M triangles at 92 % with 32-bit codes:
    /// `docs/BENCHMARKS.md`).
    pub const FAST_BUILD_SHORT_CODES_MAX: u32 = 1 << 24;

    /// The configuration for a build of `num_primitives` primitives with these options:
    /// `PREFER_FAST_BUILD` takes 32-bit codes (up to [`Self::FAST_BUILD_SHORT_CODES_MAX`]
    /// primitives), every other preset 60-bit ones, and `ALLOW_UPDATE` keeps inactive
    /// primitives. `PREFER_FAST_TRACE` builds as the default preset: the SAH collapse into
    /// leaves of about two triangles, which suits the device's one-triangle-at-a-time leaf
    /// test, traces as fast as the host's fast-trace tree or faster (`docs/BENCHMARKS.md`, "GAS
    /// builds on the device").
    #[must_use]
    pub fn for_options(options: &BuildOptions, num_primitives: u32) -> DeviceBuildConfig {
        let f = options.flags;
        let base = if f.contains(BuildFlags::PREFER_FAST_BUILD)
            && num_primitives <= Self::FAST_BUILD_SHORT_CODES_MAX
        {
            Self::FAST_BUILD
        } else {
            Self::DEFAULT
        };
        DeviceBuildConfig {
            keep_inactive: f.contains(BuildFlags::ALLOW_UPDATE),
            ..base
        }
    }

    fn key_bytes(&self) -> usize {
        if self.morton_bits == 30 || self.morton_bits == 32 {
            4
        } else {
            8
        }
    }
}

/// Why a device build failed: the inputs (the same errors as every backend's build), or the
/// device.
#[derive(Clone, Debug, Error, PartialEq)]
pub enum DeviceBuildError {
    /// The inputs break a rule of the guide.
    #[error(transparent)]
    Invalid(#[from] BuildError),
    /// The device failed, or the tree was deeper than the traversal allows.
    #[error(transparent)]
    Device(#[from] CudaError),
}

/// What a device build took.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BuildTimes {
    /// Host milliseconds validating and preparing the inputs (format conversions).
    pub prepare_ms: f64,
    /// Host milliseconds copying the vertices and indices to the device.
    pub upload_ms: f64,
    /// Device milliseconds of the build kernels, inputs resident (CUDA events): what OptiX's
    /// build time measures.
    pub kernels_ms: f64,
    /// Host milliseconds from the call to the structure ready, the slot table included.
    pub total_ms: f64,
}

/// The builder's kernels in one module.
#[derive(Debug)]
pub(crate) struct BuildKernels {
    bounds: CudaFunction,
    morton32: CudaFunction,
    morton64: CudaFunction,
    hist32: CudaFunction,
    hist64: CudaFunction,
    sort_scan: CudaFunction,
    scatter32: CudaFunction,
    scatter64: CudaFunction,
    karras32: CudaFunction,
    karras64: CudaFunction,
    bottom_up: CudaFunction,
    mark: CudaFunction,
    scan_reduce: CudaFunction,
    scan_sums: CudaFunction,
    scan_down: CudaFunction,
    write_nodes: CudaFunction,
    write_triangles: CudaFunction,
    bounds_aabbs: CudaFunction,
    write_aabbs: CudaFunction,
    heights: CudaFunction,
    pub(crate) refit_triangles: CudaFunction,
    pub(crate) refit_nodes: CudaFunction,
    pub(crate) refit_nodes4: CudaFunction,
}

/// Every kernel entry of [`BUILD_SOURCE`].
pub const BUILD_ENTRIES: [&str; 23] = [
    "oxray_build_bounds",
    "oxray_build_morton32",
    "oxray_build_morton64",
    "oxray_sort_hist32",
    "oxray_sort_hist64",
    "oxray_sort_scan",
    "oxray_sort_scatter32",
    "oxray_sort_scatter64",
    "oxray_build_karras32",
    "oxray_build_karras64",
    "oxray_build_bottom_up",
    "oxray_build_mark",
    "oxray_scan_reduce",
    "oxray_scan_sums",
    "oxray_scan_down",
    "oxray_build_write_nodes",
    "oxray_build_write_triangles",
    "oxray_refit_triangles",
    "oxray_refit_nodes",
    "oxray_refit_nodes4",
    "oxray_build_bounds_aabbs",
    "oxray_build_write_aabbs",
    "oxray_build_heights",
];

/// Compiles the builder for compute capability `cc` (PTX), with the trace kernels' options (no
/// FMA contraction, which the degeneracy test relies on).
pub(crate) fn compile_builder(cc: (i32, i32)) -> Result<cudarc::nvrtc::Ptx, CudaError> {
    nvrtc_compile(
        BUILD_SOURCE,
        crate::context::compile_options(cc),
        "oxray_build.cu",
    )
}

impl BuildKernels {
    pub(crate) fn load(ctx: &CudaContext) -> Result<BuildKernels, CudaError> {
        use crate::context::guarded;
        let ptx = compile_builder(ctx.device().compute_capability)?;
        let cu = ctx.stream.context().clone();
        let module = guarded("loading the build module", || cu.load_module(ptx))?;
        let f = |name: &'static str| guarded("loading a kernel", || module.load_function(name));
        // Freed device memory stays in the stream-ordered pool instead of going back to the
        // driver at every synchronisation, so that repeated builds do not map and unmap their
        // scratch memory each time.
        guarded("keeping freed memory in the pool", || {
            let mut pool = std::ptr::null_mut();
            // SAFETY: writes one pool handle through a valid pointer, for the context's device.
            unsafe { cudarc::driver::sys::cuDeviceGetDefaultMemPool(&mut pool, cu.cu_device()) }
                .result()?;
            let mut threshold = u64::MAX;
            // SAFETY: the release threshold attribute takes a pointer to a u64, which lives
            // through the call.
            unsafe {
                cudarc::driver::sys::cuMemPoolSetAttribute(
                    pool,
                    cudarc::driver::sys::CUmemPool_attribute::CU_MEMPOOL_ATTR_RELEASE_THRESHOLD,
                    (&mut threshold as *mut u64).cast(),
                )
            }
            .result()
        })?;
        Ok(BuildKernels {
            bounds: f("oxray_build_bounds")?,
            morton32: f("oxray_build_morton32")?,
            morton64: f("oxray_build_morton64")?,
            hist32: f("oxray_sort_hist32")?,
            hist64: f("oxray_sort_hist64")?,
            sort_scan: f("oxray_sort_scan")?,
            scatter32: f("oxray_sort_scatter32")?,
            scatter64: f("oxray_sort_scatter64")?,
            karras32: f("oxray_build_karras32")?,
            karras64: f("oxray_build_karras64")?,
            bottom_up: f("oxray_build_bottom_up")?,
            mark: f("oxray_build_mark")?,
            scan_reduce: f("oxray_scan_reduce")?,
            scan_sums: f("oxray_scan_sums")?,
            scan_down: f("oxray_scan_down")?,
            write_nodes: f("oxray_build_write_nodes")?,
            write_triangles: f("oxray_build_write_triangles")?,
            bounds_aabbs: f("oxray_build_bounds_aabbs")?,
            write_aabbs: f("oxray_build_write_aabbs")?,
            heights: f("oxray_build_heights")?,
            refit_triangles: f("oxray_refit_triangles")?,
            refit_nodes: f("oxray_refit_nodes")?,
            refit_nodes4: f("oxray_refit_nodes4")?,
        })
    }
}

/// How one build input reaches the device: its own buffers, or triangles decoded on the host.
enum Staged<'a> {
    /// f32 vertices and u32 indices (or none) read in place: bytes of the vertices, their stride
    /// in floats, bytes of the index triplets and their stride in words.
    Direct {
        vertices: &'a [u8],
        vstride: u32,
        indices: Option<&'a [u8]>,
        istride: u32,
    },
    /// u16 indices widened to u32 triplets.
    Widened {
        vertices: &'a [u8],
        vstride: u32,
        indices: Vec<u32>,
    },
    /// Other vertex formats, a stride the device cannot read as floats, or a pre-transform:
    /// the decoded triangles, nine floats each.
    Soup(Vec<f32>),
}

/// Bytes of a buffer of `count` elements of `size` bytes `stride` apart.
fn span(count: u32, stride: usize, size: usize) -> usize {
    if count == 0 {
        0
    } else {
        (count as usize - 1) * stride + size
    }
}

/// Whether the device reads the input's vertices in place.
fn direct_vertices(t: &TriangleInput<'_>) -> bool {
    t.vertices.format == VertexFormat::F32x3
        && t.vertices.effective_stride().is_multiple_of(4)
        && t.pre_transform.is_none()
}

/// Device bytes one input takes once staged (from the counts and formats alone).
fn staged_bytes(t: &TriangleInput<'_>) -> usize {
    let n = t.num_primitives();
    if !direct_vertices(t) {
        return 36 * n as usize;
    }
    let v = span(t.vertices.count, t.vertices.effective_stride(), 12);
    let i = match &t.indices {
        None => 0,
        Some(ix) if ix.format == IndexFormat::U32x3 && ix.effective_stride().is_multiple_of(4) => {
            span(ix.count, ix.effective_stride(), 12)
        }
        Some(ix) => 12 * ix.count as usize,
    };
    v + i
}

fn stage<'a>(t: &TriangleInput<'a>) -> Staged<'a> {
    if !direct_vertices(t) {
        let tris = oxray_bvh::gas::decode_triangles(t);
        return Staged::Soup(
            tris.iter()
                .flat_map(|t| t.iter().flat_map(|p| p.to_array()))
                .collect(),
        );
    }
    let vs = t.vertices.effective_stride();
    let vertices = &t.vertices.data[..span(t.vertices.count, vs, 12)];
    let vstride = (vs / 4) as u32;
    match &t.indices {
        None => Staged::Direct {
            vertices,
            vstride,
            indices: None,
            istride: 0,
        },
        Some(ix) if ix.format == IndexFormat::U32x3 && ix.effective_stride().is_multiple_of(4) => {
            let is = ix.effective_stride();
            Staged::Direct {
                vertices,
                vstride,
                indices: Some(&ix.data[..span(ix.count, is, 12)]),
                istride: (is / 4) as u32,
            }
        }
        Some(ix) => {
            let is = ix.effective_stride();
            let indices = (0..ix.count as usize)
                .into_par_iter()
                .flat_map_iter(|k| ix.format.decode(&ix.data[k * is..]))
                .collect();
            Staged::Widened {
                vertices,
                vstride,
                indices,
            }
        }
    }
}

/// Words of the build's counters (`C_*` in the kernels).
const COUNTERS: usize = 9;

/// The device memory a build of `n` triangles takes besides its staged inputs, in bytes: the
/// boxes, the sort's keys, values and counts, the radix tree, the parents of its leaves, the
/// kept-node flags and their prefix sum, the counters, and for an updatable build the nodes'
/// heights (some are freed before others are allocated: the sum bounds the peak).
fn scratch_bytes(n: usize, config: &DeviceBuildConfig) -> usize {
    let tiles = n.div_ceil(TILE).max(1);
    32 * n.max(1)
        + 2 * config.key_bytes() * n.max(1)
        + 2 * 4 * n.max(1)
        + 4 * 256 * tiles
        + 4 * 256
        + INODE_BYTES * n.max(2)
        + 3 * 4 * n.max(1)
        + 4 * tiles
        + 4 * COUNTERS
        + if config.keep_inactive {
            4 * n.max(1)
        } else {
            0
        }
}

/// The memory query of a device build (`optixAccelComputeMemoryUsage` on this device), from the
/// inputs' counts and formats: the output is the node and triangle arrays at their largest (one
/// node per triangle, 64 bytes, and 48 bytes of triangle per triangle); the temporary memory is
/// the staged inputs and the scratch arrays, exactly what [`build_gas`] allocates; an update
/// (of a build with `ALLOW_UPDATE`) stages the inputs again.
/// Validates as the build does, short of reading the buffers.
#[doc(alias = "optixAccelComputeMemoryUsage")]
pub fn memory_usage(
    options: &BuildOptions,
    inputs: &[BuildInput<'_>],
    config: &DeviceBuildConfig,
) -> Result<AccelBufferSizes, BuildError> {
    let summary = oxray_core::validate::validate_structure(options, inputs)?;
    let n = summary.num_primitives as usize;
    let staged: usize = inputs
        .iter()
        .map(|i| match i {
            BuildInput::Triangles(t) => staged_bytes(t) + 32,
            BuildInput::CustomPrimitives(c) => 24 * c.aabbs.count as usize,
            _ => 0,
        })
        .sum();
    let per_prim = match inputs.first() {
        Some(BuildInput::CustomPrimitives(_)) => 32,
        _ => 48,
    };
    Ok(AccelBufferSizes {
        output_size_in_bytes: 64 * n.max(1) + per_prim * n.max(1),
        temp_size_in_bytes: staged + scratch_bytes(n, config),
        temp_update_size_in_bytes: if options.flags.contains(BuildFlags::ALLOW_UPDATE) {
            staged
        } else {
            0
        },
    })
}

fn grid(n: usize) -> LaunchConfig {
    LaunchConfig {
        grid_dim: ((n.max(1) as u32).div_ceil(BLOCK), 1, 1),
        block_dim: (BLOCK, 1, 1),
        shared_mem_bytes: 0,
    }
}

fn blocks(count: usize) -> LaunchConfig {
    LaunchConfig {
        grid_dim: (count.max(1) as u32, 1, 1),
        block_dim: (BLOCK, 1, 1),
        shared_mem_bytes: 0,
    }
}

/// Memory every element of which a kernel writes before any is read.
fn scratch<T: cudarc::driver::DeviceRepr>(
    ctx: &CudaContext,
    len: usize,
) -> Result<CudaSlice<T>, CudaError> {
    // SAFETY: the memory is left uninitialised; every caller passes it to kernels that write
    // each element they (or later kernels) read, in stream order.
    unsafe { ctx.stream.alloc::<T>(len.max(1)) }.map_err(driver("allocating build memory"))
}

/// Builds a GAS of triangles or custom primitives (guide §5.3: boxes) on the device with
/// `config`. Validation errors are the host builder's; a tree deeper than `config.max_depth` is
/// [`CudaError::TreeTooDeep`] (nothing is kept). Spheres and curves are built by the host.
pub fn build_gas(
    ctx: &CudaContext,
    options: &BuildOptions,
    inputs: &[BuildInput<'_>],
    config: &DeviceBuildConfig,
) -> Result<(CudaGas, BuildTimes), DeviceBuildError> {
    let start = Instant::now();
    let mut prepared = GasData::prepare(options, inputs)?;
    if !matches!(
        prepared.kind,
        GasKind::Triangles | GasKind::CustomPrimitives
    ) {
        return Err(CudaError::Unsupported("device builds of sphere and curve GASes").into());
    }
    let n = prepared.num_primitives as usize;
    if n > MAX_SLOTS {
        return Err(CudaError::TooLarge(format!("{n} primitives; at most {MAX_SLOTS}")).into());
    }
    let kernels = ctx.build_kernels()?;
    let prepare_start = start.elapsed().as_secs_f64() * 1e3;
    let s = &ctx.stream;
    // Triangles are fetched by the kernels through their inputs' table; boxes are decoded by
    // the host into one array of six floats each.
    let (d_inputs, d_boxes, staged_ms) = if prepared.kind == GasKind::Triangles {
        let d = upload_inputs(ctx, &prepared.inputs, inputs)?;
        let ms = d.prepare_ms;
        (Some(d), None, ms)
    } else {
        let t = Instant::now();
        let boxes = stage_aabbs(inputs);
        let ms = t.elapsed().as_secs_f64() * 1e3;
        let d = s
            .clone_htod(&boxes[..])
            .map_err(driver("copying build inputs to the device"))?;
        ctx.synchronize()?;
        (None, Some(d), ms)
    };
    let prims = match (&d_inputs, &d_boxes) {
        (Some(d), _) => DevicePrims::Triangles {
            table: &d.table,
            n_in: d.count,
        },
        (None, Some(b)) => DevicePrims::Boxes(b),
        (None, None) => unreachable!("one of the two is staged"),
    };
    let prepare_ms = prepare_start + staged_ms;
    let upload_ms = start.elapsed().as_secs_f64() * 1e3 - prepare_ms;

    let timing = |what| driver(what);
    let t0 = s.record_event(Some(cudarc::driver::sys::CUevent_flags::CU_EVENT_DEFAULT));
    let t0 = t0.map_err(timing("recording an event"))?;
    let result = run_kernels(ctx, kernels, &prims, n, config)?;
    let t1 = s
        .record_event(Some(cudarc::driver::sys::CUevent_flags::CU_EVENT_DEFAULT))
        .map_err(timing("recording an event"))?;
    let kernels_ms = t0.elapsed_ms(&t1).map_err(timing("reading an event"))? as f64;
    drop((d_inputs, d_boxes));

    // The slot table: the sorted triangle ids, resolved on the host.
    let mut ids = vec![0u32; result.active];
    if result.active > 0 {
        s.memcpy_dtoh(&result.values.slice(..result.active), &mut ids[..])
            .map_err(driver("copying the slot table to the host"))?;
    }
    ctx.synchronize()?;
    drop(result.values);
    let slots: Vec<SlotInfo> = ids
        .par_iter()
        .with_min_len(1 << 14)
        .map(|&g| {
            let (primitive_index, sbt_gas_index, build_input) = prepared.resolve_global(g);
            SlotInfo {
                primitive_index,
                sbt_gas_index,
                build_input,
            }
        })
        .collect();
    prepared.bounds = result.bounds;
    // What an update needs: the inputs' shapes (its rules compare them), every slot's
    // primitive and the nodes by height (the refit's launches).
    let refit = match &result.heights {
        Some(h) => Some(crate::refit::RefitPlan::from_heights(ctx, ids, h)?),
        None => {
            prepared.shapes = Vec::new();
            None
        }
    };
    let info = GasInfo {
        kind: prepared.kind(),
        build_flags: prepared.build_flags,
        num_primitives: prepared.num_primitives,
        num_active_primitives: result.live as u32,
        num_build_inputs: prepared.inputs.len(),
        record_flags: prepared.record_flags.clone(),
        bounds: result.bounds,
        stats: result.stats,
    };
    let mut gas = CudaGas::from_device_build(
        ctx,
        result.nodes,
        result.num_nodes,
        result.triangles,
        slots,
        info,
        prepared,
    );
    gas.refit = refit;
    let total_ms = start.elapsed().as_secs_f64() * 1e3;
    Ok((
        gas,
        BuildTimes {
            prepare_ms,
            upload_ms,
            kernels_ms,
            total_ms,
        },
    ))
}

/// The configuration of an IAS's top-level tree on the device: the GAS presets' Morton codes
/// ([`DeviceBuildConfig::for_options`]), leaves of up to [`oxray_bvh::IAS_MAX_LEAF`]
/// instances, and no inactive slots (the prepared boxes already hold every instance that needs
/// one: [`oxray_bvh::PreparedIas::boxes`]).
#[must_use]
pub fn ias_config(options: &BuildOptions, num_instances: u32) -> DeviceBuildConfig {
    DeviceBuildConfig {
        keep_inactive: false,
        max_leaf: oxray_bvh::IAS_MAX_LEAF,
        ..DeviceBuildConfig::for_options(options, num_instances)
    }
}

/// A binary tree over `boxes` (each finite and valid, as [`oxray_bvh::PreparedIas::boxes`])
/// built by the device's kernels with `config`, read back to the host: what an IAS's top
/// level is built with on the device. Its `prim_order` maps each leaf slot to its box. The
/// words read back are checked as loaded bytes are ([`CudaError::DeviceData`] otherwise); a
/// tree deeper than `config.max_depth` is [`CudaError::TreeTooDeep`].
pub fn build_box_tree(
    ctx: &CudaContext,
    boxes: &[Aabb],
    config: &DeviceBuildConfig,
) -> Result<(Bvh2, BuildTimes), CudaError> {
    let start = Instant::now();
    let n = boxes.len();
    if n > MAX_SLOTS {
        return Err(CudaError::TooLarge(format!(
            "{n} boxes; at most {MAX_SLOTS}"
        )));
    }
    if n == 0 {
        return Ok((Bvh2::default(), BuildTimes::default()));
    }
    let kernels = ctx.build_kernels()?;
    let flat: Vec<f32> = boxes
        .par_iter()
        .flat_map_iter(|b| [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z])
        .collect();
    let prepare_ms = start.elapsed().as_secs_f64() * 1e3;
    let s = &ctx.stream;
    let d = s
        .clone_htod(&flat[..])
        .map_err(driver("copying instance boxes to the device"))?;
    ctx.synchronize()?;
    let upload_ms = start.elapsed().as_secs_f64() * 1e3 - prepare_ms;
    let timing = |what| driver(what);
    let t0 = s
        .record_event(Some(cudarc::driver::sys::CUevent_flags::CU_EVENT_DEFAULT))
        .map_err(timing("recording an event"))?;
    let result = run_kernels(ctx, kernels, &DevicePrims::Boxes(&d), n, config)?;
    let t1 = s
        .record_event(Some(cudarc::driver::sys::CUevent_flags::CU_EVENT_DEFAULT))
        .map_err(timing("recording an event"))?;
    let kernels_ms = t0.elapsed_ms(&t1).map_err(timing("reading an event"))? as f64;
    let mut words = vec![0u32; 16 * result.num_nodes];
    s.memcpy_dtoh(&result.nodes.nodes(), &mut words[..])
        .map_err(driver("copying the tree to the host"))?;
    let mut order = vec![0u32; result.active];
    s.memcpy_dtoh(&result.values.slice(..result.active), &mut order[..])
        .map_err(driver("copying the leaf order to the host"))?;
    ctx.synchronize()?;
    let mut tree = crate::relocate::tree_of_words(&words)
        .map_err(|e| CudaError::DeviceData(format!("the top-level tree: {e}")))?;
    // Every box in exactly one slot, and every slot in exactly one leaf.
    let mut seen = vec![false; n];
    if order.len() != n
        || order
            .iter()
            .any(|&k| (k as usize) >= n || std::mem::replace(&mut seen[k as usize], true))
    {
        return Err(CudaError::DeviceData(format!(
            "the leaf order holds {} of {n} boxes",
            order.len()
        )));
    }
    let mut covered = vec![false; n];
    for node in tree.nodes.iter().filter(|m| m.count > 0) {
        let (first, count) = (node.left_first as usize, node.count as usize);
        let range = covered.get_mut(first..first.saturating_add(count));
        if !range.is_some_and(|r| r.iter_mut().all(|c| !std::mem::replace(c, true))) {
            return Err(CudaError::DeviceData(format!(
                "a leaf of slots {first}..{} overlaps another or passes {n}",
                first.saturating_add(count)
            )));
        }
    }
    if covered.contains(&false) {
        return Err(CudaError::DeviceData("a slot in no leaf".into()));
    }
    tree.prim_order = order;
    Ok((
        tree,
        BuildTimes {
            prepare_ms,
            upload_ms,
            kernels_ms,
            total_ms: start.elapsed().as_secs_f64() * 1e3,
        },
    ))
}

/// The inputs' vertices and indices in device memory and their table of `InputDesc`s (8 words
/// each): what the build and update kernels fetch triangles through.
pub(crate) struct DeviceInputs {
    /// The buffers the table points into, kept until the kernels that read them are done.
    _buffers: Vec<CudaSlice<u8>>,
    /// The `InputDesc` table.
    pub(crate) table: CudaSlice<u32>,
    /// Entries of the table.
    pub(crate) count: u32,
    /// Host milliseconds spent converting formats before the copies.
    pub(crate) prepare_ms: f64,
}

/// Copies the triangle inputs to the device (in place where the device reads their format,
/// converted on the host otherwise; see [`Staged`]), `records` giving each input's first global
/// triangle. Returns when the copies are done.
pub(crate) fn upload_inputs(
    ctx: &CudaContext,
    records: &[oxray_bvh::InputRecord],
    inputs: &[BuildInput<'_>],
) -> Result<DeviceInputs, CudaError> {
    let start = Instant::now();
    let staged: Vec<Staged<'_>> = inputs
        .par_iter()
        .map(|i| match i {
            BuildInput::Triangles(t) => stage(t),
            _ => Staged::Soup(Vec::new()),
        })
        .collect();
    let prepare_ms = start.elapsed().as_secs_f64() * 1e3;
    let s = &ctx.stream;
    let up = || driver("copying build inputs to the device");
    let mut buffers: Vec<CudaSlice<u8>> = Vec::new();
    let mut table: Vec<u32> = Vec::with_capacity(8 * inputs.len());
    for (input, st) in records.iter().zip(&staged) {
        let (v, vstride, ix, istride): (&[u8], u32, Option<&[u8]>, u32) = match st {
            Staged::Direct {
                vertices,
                vstride,
                indices,
                istride,
            } => (vertices, *vstride, *indices, *istride),
            Staged::Widened {
                vertices,
                vstride,
                indices,
            } => (vertices, *vstride, Some(bytemuck::cast_slice(indices)), 3),
            Staged::Soup(f) => (bytemuck::cast_slice(f), 3, None, 0),
        };
        let mut address = |bytes: &[u8]| -> Result<u64, CudaError> {
            if bytes.is_empty() {
                return Ok(0);
            }
            let b = s.clone_htod(bytes).map_err(up())?;
            let p = {
                let (p, _guard) = b.device_ptr(s);
                p
            };
            // Kept until the kernels that read through `p` are done.
            buffers.push(b);
            Ok(p)
        };
        let va = address(v)?;
        let ia = match ix {
            Some(ix) => address(ix)?,
            None => 0,
        };
        table.extend_from_slice(&[
            va as u32,
            (va >> 32) as u32,
            ia as u32,
            (ia >> 32) as u32,
            input.first,
            vstride,
            istride,
            0,
        ]);
    }
    if table.is_empty() {
        table.resize(8, 0);
    }
    let d_table = s.clone_htod(&table[..]).map_err(up())?;
    drop(staged);
    ctx.synchronize()?;
    Ok(DeviceInputs {
        _buffers: buffers,
        table: d_table,
        count: records.len() as u32,
        prepare_ms,
    })
}

/// What the kernels leave: the layout's arrays and what the host keeps of the build.
struct Built {
    nodes: NodeBuffer,
    num_nodes: usize,
    triangles: CudaSlice<u32>,
    /// The sorted triangle ids (the first `active` are the slots').
    values: CudaSlice<u32>,
    /// Primitives in the tree: the active ones, or all of them with `keep_inactive`.
    active: usize,
    /// Active primitives.
    live: usize,
    /// With `keep_inactive`, the height of every node (1 above leaves only).
    heights: Option<Vec<u32>>,
    bounds: Aabb,
    stats: BvhStats,
}

/// What the build kernels read the primitives from.
enum DevicePrims<'a> {
    /// Triangles, through the inputs' table of `n_in` descriptors ([`upload_inputs`]).
    Triangles {
        table: &'a CudaSlice<u32>,
        n_in: u32,
    },
    /// Boxes, six floats each ([`stage_aabbs`]).
    Boxes(&'a CudaSlice<f32>),
}

/// The boxes of custom-primitive inputs as one array of six floats each (lower, upper corner),
/// in global primitive order.
fn stage_aabbs(inputs: &[BuildInput<'_>]) -> Vec<f32> {
    let mut out = Vec::new();
    for input in inputs {
        if let BuildInput::CustomPrimitives(c) = input {
            let a = c.aabbs;
            let stride = a.effective_stride();
            out.par_extend((0..a.count as usize).into_par_iter().flat_map_iter(|i| {
                (0..6).map(move |k| {
                    let at = i * stride + 4 * k;
                    a.data
                        .get(at..at + 4)
                        .and_then(|b| b.try_into().ok())
                        .map_or(f32::NAN, f32::from_le_bytes)
                })
            }));
        }
    }
    if out.is_empty() {
        out.resize(6, f32::NAN);
    }
    out
}

/// Queues the build's kernels over the `n` primitives of `prims`.
fn run_kernels(
    ctx: &CudaContext,
    k: &BuildKernels,
    prims: &DevicePrims<'_>,
    n: usize,
    config: &DeviceBuildConfig,
) -> Result<Built, CudaError> {
    let s = &ctx.stream;
    let n32 = n as u32;
    let launch = |what| driver(what);

    // Counters: centroid minima start at the largest order-preserving value, the rest at 0.
    let mut init = [0u32; COUNTERS];
    init[..3].fill(u32::MAX);
    let mut counters = s
        .clone_htod(&init[..])
        .map_err(launch("copying the build counters"))?;
    let mut boxes: CudaSlice<f32> = scratch(ctx, 8 * n)?;
    let keep = u32::from(config.keep_inactive);
    match prims {
        DevicePrims::Triangles { table, n_in } => {
            let mut b = s.launch_builder(&k.bounds);
            b.arg(*table)
                .arg(n_in)
                .arg(&n32)
                .arg(&keep)
                .arg(&mut boxes)
                .arg(&mut counters);
            // SAFETY: oxray_build_bounds(const InputDesc*, u32 n_in, u32 n, u32 keep_inactive,
            // float4* boxes, u32* counters): the table holds n_in descriptors of buffers alive
            // until the kernels are done, whose triangles 0..n have in-range indices (checked
            // by `GasData::prepare`); boxes holds 8 floats per triangle, counters COUNTERS
            // words.
            unsafe { b.launch(grid(n)) }.map_err(launch("launching the bounds kernel"))?;
        }
        DevicePrims::Boxes(aabbs) => {
            let mut b = s.launch_builder(&k.bounds_aabbs);
            b.arg(*aabbs)
                .arg(&n32)
                .arg(&keep)
                .arg(&mut boxes)
                .arg(&mut counters);
            // SAFETY: oxray_build_bounds_aabbs(const float* aabbs, u32 n, u32 keep_inactive,
            // float4* boxes, u32* counters): 6 floats per primitive for n primitives
            // (`stage_aabbs` of inputs whose counts sum to n), 8 floats of boxes per
            // primitive, counters COUNTERS words.
            unsafe { b.launch(grid(n)) }.map_err(launch("launching the bounds kernel"))?;
        }
    }

    let wide = config.key_bytes() == 8;
    let passes: u32 = if wide { 8 } else { 4 };
    let tiles = n.div_ceil(TILE).max(1);
    let tiles32 = tiles as u32;
    let mut values: CudaSlice<u32> = scratch(ctx, n)?;
    let mut values_alt: CudaSlice<u32> = scratch(ctx, n)?;
    let mut counts: CudaSlice<u32> = scratch(ctx, 256 * tiles)?;
    let mut totals: CudaSlice<u32> = scratch(ctx, 256)?;
    let mut inodes: CudaSlice<u32> = scratch(ctx, (INODE_BYTES / 4) * n.max(2))?;
    let mut leaf_parent: CudaSlice<u32> = scratch(ctx, n)?;

    macro_rules! sort_and_tree {
        ($key:ty, $morton:expr, $hist:expr, $scatter:expr, $karras:expr) => {{
            let mut keys: CudaSlice<$key> = scratch(ctx, n)?;
            let mut keys_alt: CudaSlice<$key> = scratch(ctx, n)?;
            {
                let mut b = s.launch_builder($morton);
                b.arg(&boxes)
                    .arg(&n32)
                    .arg(&counters)
                    .arg(&config.morton_bits)
                    .arg(&mut keys)
                    .arg(&mut values);
                // SAFETY: oxray_build_morton(const float4* boxes, u32 n, const u32* counters,
                // u32 bits, K* keys, u32* values): n boxes written above, n keys and values.
                unsafe { b.launch(grid(n)) }.map_err(launch("launching the Morton kernel"))?;
            }
            for pass in 0..passes {
                let shift = 8 * pass;
                // Even passes read the primary buffers, odd ones the alternates; an even number
                // of passes leaves the result in the primary ones.
                let (kin, vin, kout, vout) = if pass % 2 == 0 {
                    (&keys, &values, &mut keys_alt, &mut values_alt)
                } else {
                    (&keys_alt, &values_alt, &mut keys, &mut values)
                };
                let mut b = s.launch_builder($hist);
                b.arg(kin)
                    .arg(&n32)
                    .arg(&shift)
                    .arg(&mut counts)
                    .arg(&tiles32);
                // SAFETY: oxray_sort_hist(const K* keys, u32 n, u32 shift, u32* counts,
                // u32 tiles): n keys, 256 * tiles counts; one block per tile.
                unsafe { b.launch(blocks(tiles)) }.map_err(launch("launching the sort"))?;
                let mut b = s.launch_builder(&k.sort_scan);
                b.arg(&mut counts).arg(&tiles32).arg(&mut totals);
                // SAFETY: oxray_sort_scan(u32* counts, u32 tiles, u32* totals): one block per
                // digit (256), each over its `tiles` counts; 256 totals.
                unsafe { b.launch(blocks(256)) }.map_err(launch("launching the sort"))?;
                let mut b = s.launch_builder($scatter);
                b.arg(kin)
                    .arg(vin)
                    .arg(kout)
                    .arg(vout)
                    .arg(&n32)
                    .arg(&shift)
                    .arg(&counts)
                    .arg(&tiles32)
                    .arg(&totals);
                // SAFETY: oxray_sort_scatter(const K*, const u32*, K*, u32*, u32 n, u32 shift,
                // const u32* counts, u32 tiles, const u32* totals): n keys and values in and
                // out (distinct buffers); every destination is below n, as the counts of the
                // same keys place them.
                unsafe { b.launch(blocks(tiles)) }.map_err(launch("launching the sort"))?;
            }
            let mut b = s.launch_builder($karras);
            b.arg(&keys)
                .arg(&counters)
                .arg(&mut inodes)
                .arg(&mut leaf_parent);
            // SAFETY: oxray_build_karras(const K* keys, const u32* counters, INode* nodes,
            // u32* leaf_parent): threads below n_act - 1 (from the counters, at most n - 1)
            // write their node and their children's parents: n - 1 nodes and n parents fit.
            unsafe { b.launch(grid(n)) }.map_err(launch("launching the hierarchy kernel"))?;
        }};
    }
    if wide {
        sort_and_tree!(u64, &k.morton64, &k.hist64, &k.scatter64, &k.karras64);
    } else {
        sort_and_tree!(u32, &k.morton32, &k.hist32, &k.scatter32, &k.karras32);
    }
    drop((values_alt, counts, totals));

    {
        let mut b = s.launch_builder(&k.bottom_up);
        b.arg(&mut inodes)
            .arg(&leaf_parent)
            .arg(&boxes)
            .arg(&values)
            .arg(&counters)
            .arg(&config.max_leaf);
        // SAFETY: oxray_build_bottom_up(INode*, const u32* leaf_parent, const float4* boxes,
        // const u32* values, const u32* counters, u32 max_leaf): threads below n_act walk
        // from their leaf's parent to the root through nodes the hierarchy kernel linked.
        unsafe { b.launch(grid(n)) }.map_err(launch("launching the bottom-up kernel"))?;
    }
    let mut kept: CudaSlice<u32> = scratch(ctx, n)?;
    let mut sums: CudaSlice<u32> = scratch(ctx, tiles)?;
    {
        let mut b = s.launch_builder(&k.mark);
        b.arg(&inodes)
            .arg(&counters)
            .arg(&n32)
            .arg(&config.max_leaf)
            .arg(&mut kept);
        // SAFETY: oxray_build_mark(const INode*, const u32* counters, u32 cap, u32 max_leaf,
        // u32* kept): n flags; nodes and parents as linked above.
        unsafe { b.launch(grid(n)) }.map_err(launch("launching the collapse kernel"))?;
    }
    let mut index = s
        .clone_dtod(&kept)
        .map_err(launch("copying the kept-node flags"))?;
    {
        let mut b = s.launch_builder(&k.scan_reduce);
        b.arg(&index).arg(&n32).arg(&mut sums);
        // SAFETY: oxray_scan_reduce(const u32* v, u32 len, u32* sums): n words, one sum per
        // tile, one block per tile.
        unsafe { b.launch(blocks(tiles)) }.map_err(launch("launching a prefix sum"))?;
        let mut total = counters.slice_mut(7..8);
        let mut b = s.launch_builder(&k.scan_sums);
        b.arg(&mut sums).arg(&tiles32).arg(&mut total);
        // SAFETY: oxray_scan_sums(u32* sums, u32 tiles, u32* total): one block over the tile
        // sums; the total goes to counter 7.
        unsafe { b.launch(blocks(1)) }.map_err(launch("launching a prefix sum"))?;
        let mut b = s.launch_builder(&k.scan_down);
        b.arg(&mut index).arg(&n32).arg(&sums);
        // SAFETY: oxray_scan_down(u32* v, u32 len, const u32* sums): n words, one block per
        // tile.
        unsafe { b.launch(blocks(tiles)) }.map_err(launch("launching a prefix sum"))?;
    }
    drop(sums);

    // What the tree came to: its triangles, kept nodes, active triangles, and the root.
    let mut c = [0u32; COUNTERS];
    s.memcpy_dtoh(&counters, &mut c[..])
        .map_err(launch("copying the build counters"))?;
    let mut root = [0u32; INODE_BYTES / 4];
    s.memcpy_dtoh(&inodes.slice(..INODE_BYTES / 4), &mut root[..])
        .map_err(launch("copying the root"))?;
    ctx.synchronize()?;
    let active = c[6] as usize;
    let kept_nodes = c[7] as usize;
    let live = c[8] as usize;
    let f = f32::from_bits;
    let (height, bounds, stat) = if active >= 2 {
        (
            root[6] & 0x7FFF_FFFF,
            Aabb::new(
                [f(root[9]), f(root[10]), f(root[11])].into(),
                [f(root[12]), f(root[13]), f(root[14])].into(),
            ),
            f(root[8]) as f64,
        )
    } else {
        (u32::from(active == 1), Aabb::EMPTY, 0.0)
    };
    if height > config.max_depth {
        return Err(CudaError::TreeTooDeep {
            depth: height,
            max: config.max_depth,
        });
    }

    let num_nodes = kept_nodes.max(1);
    let mut nodes = NodeBuffer::uninit(ctx, 16 * num_nodes)?;
    {
        let mut out = nodes.nodes_mut();
        let mut b = s.launch_builder(&k.write_nodes);
        b.arg(&inodes)
            .arg(&kept)
            .arg(&index)
            .arg(&boxes)
            .arg(&values)
            .arg(&counters)
            .arg(&mut out);
        // SAFETY: oxray_build_write_nodes(const INode*, const u32* kept, const u32* index,
        // const float4* boxes, const u32* values, const u32* counters, float4* out): each kept
        // node writes 16 words at its index, below the kept count `num_nodes` was sized by
        // (with fewer than two active triangles, thread 0 writes node 0).
        unsafe { b.launch(grid(active.saturating_sub(1).max(1))) }
            .map_err(launch("launching the node writer"))?;
    }
    let heights = if config.keep_inactive {
        let mut h: CudaSlice<u32> = scratch(ctx, num_nodes)?;
        let mut b = s.launch_builder(&k.heights);
        b.arg(&inodes)
            .arg(&kept)
            .arg(&index)
            .arg(&counters)
            .arg(&mut h);
        // SAFETY: oxray_build_heights(const INode*, const u32* kept, const u32* index,
        // const u32* counters, u32* out): each kept node writes the word at its index, below
        // the kept count `num_nodes` (thread 0 writes word 0 with fewer than two triangles),
        // which is every word of `h`.
        unsafe { b.launch(grid(active.saturating_sub(1).max(1))) }
            .map_err(launch("launching the height kernel"))?;
        let mut host = vec![0u32; num_nodes];
        s.memcpy_dtoh(&h, &mut host[..])
            .map_err(launch("copying the node heights"))?;
        Some(host)
    } else {
        None
    };
    let per_slot = match prims {
        DevicePrims::Triangles { .. } => 12,
        DevicePrims::Boxes(_) => 8,
    };
    let mut triangles: CudaSlice<u32> = scratch(ctx, per_slot * active.max(1))?;
    let a32 = active as u32;
    match prims {
        _ if active == 0 => s
            .memset_zeros(&mut triangles)
            .map_err(launch("clearing the primitive array"))?,
        DevicePrims::Triangles { table, n_in } => {
            let mut b = s.launch_builder(&k.write_triangles);
            b.arg(*table)
                .arg(n_in)
                .arg(&values)
                .arg(&boxes)
                .arg(&a32)
                .arg(&mut triangles);
            // SAFETY: oxray_build_write_triangles(const InputDesc*, u32 n_in,
            // const u32* values, const float4* boxes, u32 n_act, float4* out): `active` sorted
            // ids of triangles of the inputs, whose boxes the bounds kernel wrote; 12 words
            // each.
            unsafe { b.launch(grid(active)) }.map_err(launch("launching the triangle writer"))?;
        }
        DevicePrims::Boxes(_) => {
            let mut b = s.launch_builder(&k.write_aabbs);
            b.arg(&boxes).arg(&values).arg(&a32).arg(&mut triangles);
            // SAFETY: oxray_build_write_aabbs(const float4* boxes, const u32* values,
            // u32 n_act, float4* out): `active` sorted ids of primitives whose boxes (8 floats
            // each) the bounds kernel wrote; 8 words each out.
            unsafe { b.launch(grid(active)) }.map_err(launch("launching the box writer"))?;
        }
    }
    // The single-triangle tree's box: that triangle's.
    let bounds = if active == 1 {
        let mut id = [0u32; 1];
        s.memcpy_dtoh(&values.slice(..1), &mut id[..])
            .map_err(launch("copying the root"))?;
        ctx.synchronize()?;
        let mut b = [0f32; 8];
        s.memcpy_dtoh(
            &boxes.slice(8 * id[0] as usize..8 * id[0] as usize + 8),
            &mut b[..],
        )
        .map_err(launch("copying the root"))?;
        ctx.synchronize()?;
        Aabb::new([b[0], b[1], b[2]].into(), [b[4], b[5], b[6]].into())
    } else {
        bounds
    };
    let area = bounds.half_area() as f64;
    let stats = BvhStats {
        nodes: num_nodes,
        leaves: if active == 0 { 0 } else { kept_nodes + 1 },
        max_depth: height as usize,
        mean_leaf_size: if active == 0 {
            0.0
        } else {
            active as f64 / (kept_nodes + 1) as f64
        },
        sah_cost: if active >= 2 && area > 0.0 {
            stat / area
        } else {
            1.0 + active as f64
        },
        node_bytes: 64 * num_nodes,
        // A device build references each active triangle once (no spatial splits).
        references: active,
    };
    Ok(Built {
        nodes,
        num_nodes,
        triangles,
        values,
        active,
        live,
        heights,
        bounds,
        stats,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use oxray_core::{IndexBuffer, VertexBuffer};

    #[test]
    fn the_builder_name_comes_from_the_environment_value() {
        assert_eq!("device".parse::<GasBuilder>().unwrap(), GasBuilder::Device);
        assert_eq!(" Host ".parse::<GasBuilder>().unwrap(), GasBuilder::Host);
        let e = "sah".parse::<GasBuilder>().unwrap_err();
        assert!(e.to_string().contains(GasBuilder::ENV), "{e}");
        assert_eq!(GasBuilder::default(), GasBuilder::Device);
    }

    #[test]
    fn presets_choose_the_device_build() {
        let with = |f| DeviceBuildConfig::for_options(&BuildOptions::new(f), 1000);
        assert_eq!(with(BuildFlags::empty()), DeviceBuildConfig::DEFAULT);
        assert_eq!(
            with(BuildFlags::PREFER_FAST_BUILD | BuildFlags::ALLOW_COMPACTION),
            DeviceBuildConfig::FAST_BUILD
        );
        // Large meshes get the finer codes whatever the preset.
        let big = DeviceBuildConfig::FAST_BUILD_SHORT_CODES_MAX + 1;
        let fast = BuildOptions::new(BuildFlags::PREFER_FAST_BUILD);
        assert_eq!(
            DeviceBuildConfig::for_options(&fast, big),
            DeviceBuildConfig::DEFAULT
        );
        assert_eq!(
            with(BuildFlags::PREFER_FAST_TRACE),
            DeviceBuildConfig::DEFAULT
        );
        // Updatable builds keep inactive primitives, with either code width.
        let updatable = DeviceBuildConfig {
            keep_inactive: true,
            ..DeviceBuildConfig::DEFAULT
        };
        assert_eq!(with(BuildFlags::ALLOW_UPDATE), updatable);
        assert_eq!(
            with(BuildFlags::ALLOW_UPDATE | BuildFlags::PREFER_FAST_TRACE),
            updatable
        );
        assert!(with(BuildFlags::ALLOW_UPDATE | BuildFlags::PREFER_FAST_BUILD).keep_inactive);
        const { assert!(!DeviceBuildConfig::FAST_BUILD.keep_inactive) };
        // 32-bit keys with position tie-breaks: at most 32 + 31 levels, within the traversal's.
        const { assert!(32 + 31 <= MAX_BVH2_DEPTH) };
    }

    #[test]
    fn inputs_the_device_reads_in_place_or_after_conversion() {
        let v = [
            [0.0f32, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 1.0, 0.0],
        ];
        let i32s = [[0u32, 1, 2], [1, 3, 2]];
        let t = TriangleInput::new(VertexBuffer::f32x3(&v)).indices(IndexBuffer::u32x3(&i32s));
        match stage(&t) {
            Staged::Direct {
                vertices,
                vstride,
                indices,
                istride,
            } => {
                assert_eq!((vertices.len(), vstride, istride), (48, 3, 3));
                assert_eq!(indices.map(<[u8]>::len), Some(24));
            }
            _ => panic!("f32 vertices with u32 indices are read in place"),
        }
        assert_eq!(staged_bytes(&t), 48 + 24);
        let i16s = [[0u16, 1, 2], [1, 3, 2]];
        let t16 = TriangleInput::new(VertexBuffer::f32x3(&v)).indices(IndexBuffer::u16x3(&i16s));
        match stage(&t16) {
            Staged::Widened { indices, .. } => assert_eq!(indices, vec![0, 1, 2, 1, 3, 2]),
            _ => panic!("u16 indices are widened"),
        }
        assert_eq!(staged_bytes(&t16), 48 + 24);
        let moved = t.pre_transform([1.0, 0.0, 0.0, 5.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
        match stage(&moved) {
            Staged::Soup(f) => {
                assert_eq!(f.len(), 18);
                // The second triangle's first vertex, vertex 1 moved by 5 along x.
                assert_eq!(&f[9..12], &[6.0, 0.0, 0.0]);
            }
            _ => panic!("a pre-transform is applied on the host"),
        }
        assert_eq!(staged_bytes(&moved), 72);
    }

    #[test]
    fn the_memory_query_bounds_what_a_build_allocates() {
        let v = vec![[0.0f32; 3]; 300];
        let idx: Vec<[u32; 3]> = (0..100).map(|k| [3 * k, 3 * k + 1, 3 * k + 2]).collect();
        let inputs = [TriangleInput::new(VertexBuffer::f32x3(&v))
            .indices(IndexBuffer::u32x3(&idx))
            .into()];
        let o = BuildOptions::default();
        let sizes = memory_usage(&o, &inputs, &DeviceBuildConfig::DEFAULT).unwrap();
        assert_eq!(sizes.output_size_in_bytes, 112 * 100);
        let tiles = 1;
        let scratch =
            32 * 100 + 16 * 100 + 8 * 100 + 1024 * tiles + 1024 + 64 * 100 + 1200 + 4 + 36;
        assert_eq!(sizes.temp_size_in_bytes, 3600 + 1200 + 32 + scratch);
        assert_eq!(sizes.temp_update_size_in_bytes, 0);
        let fast = memory_usage(&o, &inputs, &DeviceBuildConfig::FAST_BUILD).unwrap();
        assert_eq!(sizes.temp_size_in_bytes - fast.temp_size_in_bytes, 800);
        // An updatable build keeps the nodes' heights; its update stages the inputs again.
        let u = BuildOptions::new(BuildFlags::ALLOW_UPDATE);
        let config = DeviceBuildConfig::for_options(&u, 100);
        let up = memory_usage(&u, &inputs, &config).unwrap();
        assert_eq!(up.temp_size_in_bytes - sizes.temp_size_in_bytes, 400);
        assert_eq!(up.temp_update_size_in_bytes, 3600 + 1200 + 32);
        // The same validation as the build.
        let bad = BuildOptions::new(BuildFlags::PREFER_FAST_BUILD | BuildFlags::PREFER_FAST_TRACE);
        assert_eq!(
            memory_usage(&bad, &inputs, &DeviceBuildConfig::DEFAULT).unwrap_err(),
            oxray_bvh::compute_memory_usage(&bad, &inputs).unwrap_err()
        );
    }

    #[test]
    fn the_builder_compiles_with_nvrtc_where_it_is_present() {
        let Some(ptx) = crate::context::ptx_or_skip(|| compile_builder((9, 0))) else {
            return;
        };
        for entry in BUILD_ENTRIES {
            assert!(ptx.contains(&format!(".entry {entry}")), "{entry} missing");
        }
    }
}
