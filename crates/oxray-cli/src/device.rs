//! `oxray raycast` and `oxray bench` on any device (`--backend cpu|cuda|cuda:N|auto`), through
//! the library's [`Device`]: the same host code builds the GAS and traces the rays on every
//! device. Where a device is asked for that this machine lacks, the command fails with one
//! error line, never a silent fall-back to the CPU.

use crate::bench::{build_gas_on, median, BenchRays};
use crate::raycast::{
    check_rays, encode_all_hits, encode_counts, encode_hits, encode_occlusion, load_inputs,
    result_bytes, write_results, RayCheck, RaycastError, RaycastQuery,
};
use oxray::{AllHits, BatchKind, BuildFlags, Device, DeviceError, Hit, QueryError, Ray};
use oxray_scene::mesh::Mesh;
use std::fmt;
use std::path::Path;
use std::time::Instant;
use thiserror::Error;

/// Why a command on a device failed.
#[derive(Debug, Error)]
pub enum DeviceCommandError {
    /// The device could not be opened (for CUDA: this machine has none).
    #[error("--backend {name}: {source}; use --backend cpu")]
    Open {
        /// The name asked for.
        name: String,
        /// Why.
        source: DeviceError,
    },
    /// Loading the inputs, building the GAS or writing the results failed.
    #[error(transparent)]
    Raycast(#[from] RaycastError),
    /// A query was refused or the device failed.
    #[error(transparent)]
    Query(#[from] QueryError),
    /// The GAS of a benchmark mesh could not be built.
    #[error(transparent)]
    Build(#[from] oxray::BuildError),
    /// The benchmark's CUDA C++ pipeline could not be made or launched.
    #[error("pipeline: {0}")]
    Pipeline(String),
}

/// Checks a `--backend` value without opening the device (for the argument parser).
pub fn parse_backend(name: &str) -> Result<String, String> {
    let n = name.trim().to_ascii_lowercase();
    let ok = matches!(n.as_str(), "cpu" | "cuda" | "gpu" | "auto")
        || n.strip_prefix("cuda:")
            .is_some_and(|k| k.parse::<usize>().is_ok());
    if ok {
        Ok(n)
    } else {
        Err("expected cpu, cuda, cuda:N or auto".into())
    }
}

/// Opens the device named by `--backend`.
pub fn open(name: &str) -> Result<Device, DeviceCommandError> {
    Device::from_name(name).map_err(|source| DeviceCommandError::Open {
        name: name.to_string(),
        source,
    })
}

/// Median seconds of `runs` calls of `f` after one warm-up call (which allocates the reused
/// buffers and lets the device settle).
fn time<E>(runs: usize, mut f: impl FnMut() -> Result<(), E>) -> Result<f64, E> {
    f()?;
    let mut times = Vec::with_capacity(runs);
    for _ in 0..runs.max(1) {
        let t = Instant::now();
        f()?;
        times.push(t.elapsed().as_secs_f64());
    }
    Ok(median(times))
}

fn mrays(n: usize, seconds: f64) -> f64 {
    n as f64 / seconds.max(1e-12) / 1e6
}

/// What a ray cast did.
#[derive(Clone, Copy, Debug)]
pub struct RaycastReport {
    /// Rays cast.
    pub rays: usize,
    /// Rays that hit (or, for occlusion, were occluded).
    pub hits: usize,
    /// The rays not traced (invalid) and those whose negative `tmin` was clamped.
    pub check: RayCheck,
    /// Mrays/s of the traversal alone, rays and results resident on the device.
    pub traced_mrays_per_s: f64,
    /// Mrays/s of the one-call query: rays in, traversal, results out.
    pub transfer_mrays_per_s: f64,
}

/// `oxray raycast`: builds the mesh's GAS for `device` (fast-trace flags, with the host's
/// builder: [`Device::with_host_builds`]), casts the rays of `rays_path` and writes the hits
/// (or, with `occlusion`, one u32 0/1 per ray) to `out_path`: the same bytes on every device,
/// ties at shared edges included. Each speed is that of one call after a warm-up call.
///
/// Before any work, `out_path` is checked to be neither the mesh nor the ray file and to lie
/// in a writable folder; it is written atomically. Rays follow [`check_rays`]: a negative
/// `tmin` is clamped to 0, and invalid rays are written as misses and counted in the report.
pub fn raycast(
    device: &Device,
    mesh_path: &Path,
    rays_path: &Path,
    out_path: &Path,
    query: RaycastQuery,
) -> Result<RaycastReport, DeviceCommandError> {
    oxray_scene::files::check_output(out_path, &[mesh_path, rays_path])
        .map_err(RaycastError::Output)?;
    let (mesh, sources, all_rays) = load_inputs(mesh_path, rays_path)?;
    // A glTF's buffer files are inputs too: refused before anything is written.
    let sources: Vec<&Path> = sources.iter().map(|p| p.as_path()).collect();
    oxray_scene::files::check_output(out_path, &sources).map_err(RaycastError::Output)?;
    // The results' size is known from the ray count: refused before anything is traced.
    result_bytes(query, all_rays.len())?;
    let (index, rays, check) = check_rays(&all_rays);
    let device = &device.clone().with_host_builds();
    let gas = build_gas_on(device, &mesh, BuildFlags::PREFER_FAST_TRACE)?;
    let root = gas.handle();
    let n = rays.len();
    let refused = |e: oxray::SurfaceQueryError| RaycastError::Results(e.to_string());
    // Results of the traced rays scattered back to file order; invalid rays stay misses.
    let (out, hits, traced, with_transfers) = match query {
        RaycastQuery::Occlusion | RaycastQuery::Closest => {
            let occlusion = query == RaycastQuery::Occlusion;
            let kind = if occlusion {
                BatchKind::Any
            } else {
                BatchKind::Closest
            };
            let traced = {
                let mut batch = device.upload_rays(&rays, kind)?;
                time(1, || device.trace_batch(&root, &mut batch))?
            };
            if occlusion {
                let mut occ = vec![false; n];
                let with = time(1, || device.intersect_any(&root, &rays, &mut occ))?;
                let count = occ.iter().filter(|&&o| o).count();
                let mut all = vec![false; all_rays.len()];
                for (&i, o) in index.iter().zip(occ) {
                    all[i] = o;
                }
                (encode_occlusion(&all), count, traced, with)
            } else {
                let mut hits = vec![None; n];
                let with = time(1, || device.intersect_closest(&root, &rays, &mut hits))?;
                let count = hits.iter().filter(|h| h.is_some()).count();
                let mut all = vec![None; all_rays.len()];
                for (&i, h) in index.iter().zip(hits) {
                    all[i] = h;
                }
                (encode_hits(&all), count, traced, with)
            }
        }
        RaycastQuery::Count => {
            let mut counts = vec![0u32; n];
            let t = Instant::now();
            gas.count_hits_batch(&rays, &mut counts).map_err(refused)?;
            let with = t.elapsed().as_secs_f64();
            let count = counts.iter().filter(|&&c| c > 0).count();
            let mut all = vec![0u32; all_rays.len()];
            for (&i, c) in index.iter().zip(counts) {
                all[i] = c;
            }
            (encode_counts(&all), count, with, with)
        }
        RaycastQuery::AllHits { max } => {
            let mut lists = AllHits::new();
            let t = Instant::now();
            gas.all_hits_batch(&rays, max, &mut lists)
                .map_err(refused)?;
            let with = t.elapsed().as_secs_f64();
            let count = (0..n).filter(|&k| !lists.hits(k).is_empty()).count();
            let mut all: Vec<Option<(&[Hit], bool)>> = vec![None; all_rays.len()];
            for (k, &i) in index.iter().enumerate() {
                all[i] = Some((lists.hits(k), lists.is_complete(k)));
            }
            (encode_all_hits(&all, max), count, with, with)
        }
    };
    write_results(out_path, &out)?;
    Ok(RaycastReport {
        rays: all_rays.len(),
        hits,
        check,
        traced_mrays_per_s: mrays(n, traced),
        transfer_mrays_per_s: mrays(n, with_transfers),
    })
}

/// The header of the `oxray bench --backend DEVICE` table (markdown, two lines).
pub const BENCH_HEADER: &str = "| mesh | tris | rays | query | CPU Mrays/s | device traced Mrays/s | device with transfers Mrays/s | traced / CPU | pipeline Mrays/s (/ traced) | hit rate | hits identical to CPU |\n|---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|";

/// The CUDA C++ programs of the pipeline benchmark: a ray-generation program traces ray `i` of a
/// buffer and stores the distance a one-line closest-hit program reports (issue 13's
/// comparison of the programmable pipeline with the fixed query kernel).
const RAY_PIPELINE: &str = r#"
#include <optix.h>
struct Params {
    const float4* rays;
    float* t;
    OptixTraversableHandle handle;
    unsigned int flags;
    unsigned int pad;
};
extern "C" __constant__ Params params;
extern "C" __global__ void __raygen__rays() {
    const unsigned int i = optixGetLaunchIndex().x;
    const float4 a = params.rays[2 * i];
    const float4 b = params.rays[2 * i + 1];
    unsigned int t = 0x7f800000u;
    optixTrace(params.handle, make_float3(a.x, a.y, a.z), make_float3(b.x, b.y, b.z), a.w, b.w,
               0.0f, OptixVisibilityMask(255), params.flags, 0, 1, 0, t);
    params.t[i] = __uint_as_float(t);
}
extern "C" __global__ void __miss__none() {}
extern "C" __global__ void __closesthit__t() { optixSetPayload_0(__float_as_uint(optixGetRayTmax())); }
"#;

/// The PTX of the benchmark's pipeline ([`RAY_PIPELINE`]: ray generation, one miss and one
/// closest-hit program) for compute capability `cc`, compiled with NVRTC as
/// `oxray bench --backend cuda` compiles it, without a GPU (`scripts/pipeline-sass.sh` reads its
/// machine code beside the query kernels').
pub fn ray_pipeline_ptx(cc: (i32, i32)) -> Result<String, oxray::cuda::CudaError> {
    ray_pipeline_ptx_with(cc, &ray_pipeline_options())
}

/// The benchmark pipeline's compile options: one payload word, and the default graph and
/// primitive-type flags (any graph, triangles and custom primitives), so that the kernel holds
/// the general traversal as an arbitrary pipeline's does.
fn ray_pipeline_options() -> oxray::PipelineCompileOptions {
    oxray::PipelineCompileOptions {
        num_payload_values: 1,
        ..Default::default()
    }
}

fn ray_pipeline_ptx_with(
    cc: (i32, i32),
    compile: &oxray::PipelineCompileOptions,
) -> Result<String, oxray::cuda::CudaError> {
    use oxray::cuda::{compile_pipeline_ptx, CudaHitGroupDesc, CudaModule, CudaProgramGroup};
    let module = CudaModule::from_source(RAY_PIPELINE);
    let groups = [
        CudaProgramGroup::raygen(&module, "__raygen__rays")?,
        CudaProgramGroup::miss(Some((&module, "__miss__none")))?,
        CudaProgramGroup::hit_group(CudaHitGroupDesc {
            closest_hit: Some((&module, "__closesthit__t")),
            ..Default::default()
        })?,
    ];
    compile_pipeline_ptx(cc, compile, &oxray::PipelineLinkOptions::default(), &groups)
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct RayParams {
    rays: u64,
    t: u64,
    handle: u64,
    flags: u32,
    pad: u32,
}

/// A pipeline of [`RAY_PIPELINE`] over one GAS of a CUDA device.
struct RayPipeline {
    pipeline: oxray::programs::Pipeline,
    sbt: oxray::ShaderBindingTable,
    handle: u64,
}

impl RayPipeline {
    /// `None` on a device that does not run CUDA C++ programs.
    fn new(device: &Device, gas: &oxray::Gas) -> Result<Option<RayPipeline>, DeviceCommandError> {
        use oxray::programs::{HitGroupDesc, ProgramGroup};
        use oxray::{ModuleSource, SbtRegion};
        if device.kind() != oxray::BackendKind::Cuda {
            return Ok(None);
        }
        let err = |e: &dyn std::fmt::Display| DeviceCommandError::Pipeline(e.to_string());
        let module = device
            .create_module(ModuleSource::CudaCpp(RAY_PIPELINE))
            .map_err(|e| err(&e))?;
        let raygen = ProgramGroup::raygen(&module, "__raygen__rays").map_err(|e| err(&e))?;
        let miss = ProgramGroup::miss(&module, "__miss__none").map_err(|e| err(&e))?;
        let hit = ProgramGroup::hit_group(HitGroupDesc {
            closest_hit: Some((&module, "__closesthit__t")),
            ..Default::default()
        })
        .map_err(|e| err(&e))?;
        let pipeline = device
            .create_pipeline(
                &ray_pipeline_options(),
                &oxray::PipelineLinkOptions::default(),
                Some("params"),
                &[raygen.clone(), miss.clone(), hit.clone()],
            )
            .map_err(|e| err(&e))?;
        let sbt = oxray::ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[raygen.pack_header()]),
            miss: SbtRegion::from_headers(&[miss.pack_header()]),
            hitgroup: SbtRegion::from_headers(&[hit.pack_header()]),
            ..Default::default()
        };
        let handle = gas.optix_handle().map_err(|e| err(&e))?;
        Ok(Some(RayPipeline {
            pipeline,
            sbt,
            handle,
        }))
    }

    /// Median seconds of tracing `rays` (resident on the device) with the pipeline, and the
    /// distances found (+inf for a miss). `first_hit` ends each ray at its first hit.
    fn trace(
        &self,
        device: &Device,
        rays: &[Ray],
        first_hit: bool,
        runs: usize,
    ) -> Result<(f64, Vec<f32>), DeviceCommandError> {
        let err = |e: &dyn std::fmt::Display| DeviceCommandError::Pipeline(e.to_string());
        let records: Vec<oxray::RayRecord> = rays.iter().map(|&r| r.into()).collect();
        let mut d_rays = device
            .create_buffer::<oxray::RayRecord>(records.len())
            .map_err(|e| err(&e))?;
        d_rays.write(&records).map_err(|e| err(&e))?;
        let d_t = device
            .create_buffer::<f32>(rays.len())
            .map_err(|e| err(&e))?;
        let params = RayParams {
            rays: d_rays.device_ptr(),
            t: d_t.device_ptr(),
            handle: self.handle,
            // OPTIX_RAY_FLAG_TERMINATE_ON_FIRST_HIT
            flags: if first_hit { 1 << 2 } else { 0 },
            pad: 0,
        };
        let n = u32::try_from(rays.len()).map_err(|e| err(&e))?;
        let seconds = time(runs, || {
            let report = self
                .pipeline
                .launch_with(&params, &self.sbt, n, 1, 1)
                .map_err(|e| err(&e))?;
            match report.exceptions {
                0 => Ok(()),
                k => Err(DeviceCommandError::Pipeline(format!(
                    "{k} launch indices raised exceptions"
                ))),
            }
        })?;
        Ok((seconds, d_t.download().map_err(|e| err(&e))?))
    }
}

/// One row of the device benchmark: one ray set and one query on one mesh.
#[derive(Clone, Debug)]
pub struct DeviceBenchRow {
    /// Mesh name.
    pub name: String,
    /// Triangles.
    pub triangles: usize,
    /// `coherent`, `incoherent` or `shadow`.
    pub set: &'static str,
    /// `closest` or `any`.
    pub query: &'static str,
    /// Mrays/s of the CPU device on the same rays and build.
    pub cpu: f64,
    /// Mrays/s of the traversal alone on the device (rays and results resident).
    pub traced: f64,
    /// Mrays/s of the one-call query (rays in, traversal, results out).
    pub with_transfers: f64,
    /// Mrays/s of a ray-generation program tracing the same rays (resident) through the
    /// programmable pipeline, where the device runs CUDA C++ programs.
    pub pipeline: Option<f64>,
    /// Percentage of rays whose device result equals the CPU's: the whole [`Hit`] for closest
    /// hit, the flag for any hit (and, with a pipeline, its distance or occlusion too).
    pub identical_pct: f64,
    /// Percentage of rays that hit.
    pub hit_rate_pct: f64,
}

impl fmt::Display for DeviceBenchRow {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "| {} | {} | {} | {} | {:.2} | {:.1} | {:.1} | {:.1}x | {} | {:.1}% | {:.4}% |",
            self.name,
            self.triangles,
            self.set,
            self.query,
            self.cpu,
            self.traced,
            self.with_transfers,
            self.traced / self.cpu.max(1e-12),
            match self.pipeline {
                Some(p) => format!("{p:.1} ({:.0}%)", 100.0 * p / self.traced.max(1e-12)),
                None => "-".into(),
            },
            self.hit_rate_pct,
            self.identical_pct
        )
    }
}

/// `oxray bench --backend DEVICE` on one mesh: the GAS of the CPU benchmark (default build
/// flags) built on `device` and on the CPU, and the benchmark's ray sets traced on both, closest
/// and any hit, each timed as the median of `runs` after a warm-up. Returns six rows: closest
/// and any hit for the coherent (primary), incoherent (diffuse) and shadow rays.
pub fn bench_mesh(
    device: &Device,
    name: &str,
    mesh: &Mesh,
    rays: &BenchRays,
    runs: usize,
) -> Result<Vec<DeviceBenchRow>, DeviceCommandError> {
    let cpu = Device::cpu();
    let on_cpu = build_gas_on(&cpu, mesh, BuildFlags::empty())?.handle();
    let gas = build_gas_on(device, mesh, BuildFlags::empty())?;
    let on_device = gas.handle();
    // The pipeline's figures are an extra column: a device that cannot build it still gets
    // the query table, with the reason on stderr.
    let pipeline = RayPipeline::new(device, &gas).unwrap_or_else(|e| {
        eprintln!("warning: no pipeline column: {e}");
        None
    });
    if let Some(Ok((k, block))) = pipeline
        .as_ref()
        .and_then(|p| p.pipeline.as_cuda())
        .map(|p| p.kernel_info())
    {
        eprintln!(
            "pipeline kernel: {} registers, {} bytes of local memory per thread, {block} threads per block",
            k.registers, k.local_bytes
        );
        if let Some(Ok(kernels)) = device.as_cuda().map(|c| c.context().kernel_info()) {
            for q in kernels.iter().filter(|q| q.name.ends_with("bvh2")) {
                eprintln!(
                    "query kernel {}: {} registers, {} bytes of local memory per thread",
                    q.name, q.registers, q.local_bytes
                );
            }
        }
    }
    if let (Some(p), Some(one)) = (pipeline.as_ref(), rays.coherent.get(..1)) {
        launch_latency(device, &on_device, p, one)?;
    }
    let mut rows = Vec::with_capacity(6);
    for (set, rays) in [
        ("coherent", &rays.coherent),
        ("incoherent", &rays.incoherent),
        ("shadow", &rays.shadow),
    ] {
        let [closest, any] = bench_set(device, &on_cpu, &on_device, pipeline.as_ref(), rays, runs)?;
        for (query, r) in [("closest", closest), ("any", any)] {
            rows.push(DeviceBenchRow {
                name: name.to_string(),
                triangles: mesh.triangles.len(),
                set,
                query,
                ..r
            });
        }
    }
    Ok(rows)
}

/// Prints what a launch of one ray costs, the query kernel's and the pipeline's (the medians of
/// 200): the fixed cost per launch that the rows' rates include.
fn launch_latency(
    device: &Device,
    root: &oxray::TraversableHandle,
    pipeline: &RayPipeline,
    one: &[Ray],
) -> Result<(), DeviceCommandError> {
    const LAUNCHES: usize = 200;
    let mut batch = device.upload_rays(one, BatchKind::Closest)?;
    let query = time(LAUNCHES, || device.trace_batch(root, &mut batch))?;
    let (programs, _) = pipeline.trace(device, one, false, LAUNCHES)?;
    eprintln!(
        "a launch of one ray: query kernel {:.1} µs, pipeline {:.1} µs",
        query * 1e6,
        programs * 1e6
    );
    Ok(())
}

/// One row of `oxray bench --backend cuda --gas-builds`: one mesh and build preset, built by
/// the device's kernels and by the host's SAH builder (then uploaded), each tree traced on the
/// device with the same resident rays.
#[derive(Clone, Debug)]
pub struct BuildBenchRow {
    /// Mesh name.
    pub name: String,
    /// Triangles.
    pub triangles: usize,
    /// `fast-build`, `default` or `fast-trace`.
    pub preset: &'static str,
    /// Device build, median ms: the kernels with the inputs resident (CUDA events), and the
    /// whole call (validation, upload, kernels, slot table). `None` where the device does not
    /// build the preset.
    pub device_ms: Option<(f64, f64)>,
    /// Of the whole call, the host's validation and preparation, and the upload of the inputs
    /// (median ms).
    pub device_host_ms: Option<(f64, f64)>,
    /// Host build and upload, median ms.
    pub host_ms: f64,
    /// Runs of the host build the median is of.
    pub host_runs: usize,
    /// SAH cost of the device-built and the host-built tree (the device's binary tree; the
    /// host's 4-wide statistics).
    pub sah: (Option<f64>, f64),
    /// Coherent closest-hit Mrays/s through the device-built and the host-built tree.
    pub coherent: (Option<f64>, f64),
    /// Incoherent closest-hit Mrays/s through both.
    pub incoherent: (Option<f64>, f64),
    /// Percentage of incoherent rays whose distance is the same bit for bit on both trees.
    pub same_t_pct: Option<f64>,
}

/// The header of the `--gas-builds` table (markdown, two lines).
pub const BUILD_BENCH_HEADER: &str = "| mesh | tris | preset | device build ms: kernels / end-to-end | host build + upload ms | SAH device / host | coherent closest Mrays/s device-built / host-built | incoherent closest Mrays/s device-built / host-built (ratio) | same t |\n|---|---:|---|---:|---:|---:|---:|---:|---:|";

impl fmt::Display for BuildBenchRow {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let opt = |v: Option<f64>, digits: usize| match v {
            Some(v) => format!("{v:.digits$}"),
            None => "host".into(),
        };
        write!(
            f,
            "| {} | {} | {} | {} | {:.1}{} | {} / {:.1} | {} / {:.1} | {} / {:.1}{} | {} |",
            self.name,
            self.triangles,
            self.preset,
            match (self.device_ms, self.device_host_ms) {
                (Some((k, t)), Some((p, u))) => {
                    format!("{k:.2} / {t:.1} (prepare {p:.1}, upload {u:.1})")
                }
                _ => "- (built on the host)".into(),
            },
            self.host_ms,
            if self.host_runs == 1 { " (1 run)" } else { "" },
            opt(self.sah.0, 1),
            self.sah.1,
            opt(self.coherent.0, 1),
            self.coherent.1,
            opt(self.incoherent.0, 1),
            self.incoherent.1,
            match self.incoherent.0 {
                Some(d) => format!(" ({:.0}%)", 100.0 * d / self.incoherent.1.max(1e-12)),
                None => String::new(),
            },
            match self.same_t_pct {
                Some(p) => format!("{p:.3}%"),
                None => "-".into(),
            }
        )
    }
}

/// `oxray bench --backend cuda --gas-builds` on one mesh: for each preset (fast build, default,
/// fast trace), the device build timed `runs` times after a warm-up, the host build (and
/// upload) timed as often (once for meshes over 4 M triangles, whose host builds take seconds),
/// and both trees traced with the coherent and incoherent ray sets resident on the device.
pub fn bench_builds(
    device: &Device,
    name: &str,
    mesh: &Mesh,
    rays: &BenchRays,
    runs: usize,
) -> Result<Vec<BuildBenchRow>, DeviceCommandError> {
    use oxray::cuda::device_build::{build_gas, DeviceBuildConfig};
    use oxray::cuda::{CudaGas, DeviceHits, DeviceRays};
    use oxray::{BuildOptions, IndexBuffer, TriangleInput, VertexBuffer};
    let Some(cuda) = device.as_cuda() else {
        return Err(DeviceCommandError::Pipeline(
            "--gas-builds compares the CUDA device's builder with the host's: use --backend cuda"
                .into(),
        ));
    };
    let ctx = cuda.context();
    let gpu = |e: &dyn fmt::Display| DeviceCommandError::Pipeline(e.to_string());
    let inputs = [TriangleInput::new(VertexBuffer::f32x3(&mesh.positions))
        .indices(IndexBuffer::u32x3(&mesh.triangles))
        .into()];
    let coherent = DeviceRays::upload(ctx, &rays.coherent).map_err(|e| gpu(&e))?;
    let incoherent = DeviceRays::upload(ctx, &rays.incoherent).map_err(|e| gpu(&e))?;
    let mut hits_c = DeviceHits::new(ctx, coherent.len()).map_err(|e| gpu(&e))?;
    let mut hits_i = DeviceHits::new(ctx, incoherent.len()).map_err(|e| gpu(&e))?;
    // Median Mrays/s of both sets through a tree, and the incoherent distances.
    let mut trace = |gas: &CudaGas| -> Result<(f64, f64, Vec<u32>), DeviceCommandError> {
        let c = time(runs, || gas.intersect_device(&coherent, &mut hits_c)).map_err(|e| gpu(&e))?;
        let i =
            time(runs, || gas.intersect_device(&incoherent, &mut hits_i)).map_err(|e| gpu(&e))?;
        let t = hits_i.download(ctx).map_err(|e| gpu(&e))?;
        Ok((
            mrays(coherent.len(), c),
            mrays(incoherent.len(), i),
            t.iter().map(|h| h.t.to_bits()).collect(),
        ))
    };
    let host_runs = if mesh.triangles.len() > 4 << 20 {
        1
    } else {
        runs
    };
    let mut rows = Vec::new();
    // The fast-build preset with 30-bit codes too (cells of 2^10 per axis; the preset's 32 bits
    // split them once more in x and y in the same four sort passes), for what finer cells buy.
    let coarser = DeviceBuildConfig {
        morton_bits: 30,
        ..DeviceBuildConfig::FAST_BUILD
    };
    for (preset, flags, forced) in [
        ("fast-build", BuildFlags::PREFER_FAST_BUILD, None),
        (
            "fast-build, 30-bit codes",
            BuildFlags::PREFER_FAST_BUILD,
            Some(coarser),
        ),
        ("default", BuildFlags::empty(), None),
        ("fast-trace", BuildFlags::PREFER_FAST_TRACE, None),
    ] {
        let options = BuildOptions::new(flags);
        let mut host_times = Vec::new();
        let mut host_gas = None;
        for _ in 0..host_runs {
            drop(host_gas.take());
            let t = Instant::now();
            let (data, tree) = oxray::bvh::GasData::build_with_tree(&options, &inputs)?;
            let gas = CudaGas::upload(ctx, &data, &tree).map_err(|e| gpu(&e))?;
            host_times.push(t.elapsed().as_secs_f64() * 1e3);
            host_gas = Some((gas, data.stats().sah_cost));
        }
        let Some((host_gas, host_sah)) = host_gas else {
            continue;
        };
        let (hc, hi, ht) = trace(&host_gas)?;
        drop(host_gas);
        let mut device = None;
        {
            let config = forced.unwrap_or_else(|| {
                DeviceBuildConfig::for_options(&options, mesh.triangles.len() as u32)
            });
            let mut kernels = Vec::new();
            let mut total = Vec::new();
            let mut prepare = Vec::new();
            let mut upload = Vec::new();
            let mut last = None;
            for k in 0..=runs {
                drop(last.take());
                let (gas, times) =
                    build_gas(ctx, &options, &inputs, &config).map_err(|e| gpu(&e))?;
                if k > 0 {
                    kernels.push(times.kernels_ms);
                    total.push(times.total_ms);
                    prepare.push(times.prepare_ms);
                    upload.push(times.upload_ms);
                }
                last = Some(gas);
            }
            if let Some(gas) = last {
                let (dc, di, dt) = trace(&gas)?;
                let same = dt.iter().zip(&ht).filter(|(a, b)| a == b).count();
                device = Some((
                    (median(kernels), median(total)),
                    (median(prepare), median(upload)),
                    gas.info().stats.sah_cost,
                    dc,
                    di,
                    100.0 * same as f64 / ht.len().max(1) as f64,
                ));
            }
        }
        rows.push(BuildBenchRow {
            name: name.to_string(),
            triangles: mesh.triangles.len(),
            preset,
            device_ms: device.as_ref().map(|d| d.0),
            device_host_ms: device.as_ref().map(|d| d.1),
            host_ms: median(host_times),
            host_runs,
            sah: (device.as_ref().map(|d| d.2), host_sah),
            coherent: (device.as_ref().map(|d| d.3), hc),
            incoherent: (device.as_ref().map(|d| d.4), hi),
            same_t_pct: device.as_ref().map(|d| d.5),
        });
    }
    Ok(rows)
}

/// The pipeline's timing and distances, or `None` with the reason on stderr.
fn traced_or_warn(r: Result<(f64, Vec<f32>), DeviceCommandError>) -> Option<(f64, Vec<f32>)> {
    r.map_err(|e| eprintln!("warning: no pipeline column: {e}"))
        .ok()
}

/// Times one ray set, closest and any hit; the rows' names are filled in by the caller.
fn bench_set(
    device: &Device,
    on_cpu: &oxray::TraversableHandle,
    on_device: &oxray::TraversableHandle,
    pipeline: Option<&RayPipeline>,
    rays: &[Ray],
    runs: usize,
) -> Result<[DeviceBenchRow; 2], DeviceCommandError> {
    let n = rays.len();
    let cpu = Device::cpu();
    let pct = |k: usize| 100.0 * k as f64 / n.max(1) as f64;
    let row = |cpu, traced, with_transfers, pipeline: Option<f64>, same, hit| DeviceBenchRow {
        name: String::new(),
        triangles: 0,
        set: "",
        query: "",
        cpu: mrays(n, cpu),
        traced: mrays(n, traced),
        with_transfers: mrays(n, with_transfers),
        pipeline: pipeline.map(|s| mrays(n, s)),
        identical_pct: pct(same),
        hit_rate_pct: pct(hit),
    };

    let mut cpu_hits: Vec<Option<Hit>> = vec![None; n];
    let cpu_s = time(runs, || cpu.intersect_closest(on_cpu, rays, &mut cpu_hits))?;
    let mut batch = device.upload_rays(rays, BatchKind::Closest)?;
    let traced = time(runs, || device.trace_batch(on_device, &mut batch))?;
    drop(batch);
    let mut dev_hits: Vec<Option<Hit>> = vec![None; n];
    let with = time(runs, || {
        device.intersect_closest(on_device, rays, &mut dev_hits)
    })?;
    let programs = pipeline.and_then(|p| traced_or_warn(p.trace(device, rays, false, runs)));
    // A ray agrees when its query hit equals the CPU's and, with a pipeline, the distance its
    // closest-hit program reported does too.
    let t_of = |h: &Option<Hit>| h.map_or(f32::INFINITY, |h| h.t).to_bits();
    let same = (0..n)
        .filter(|&i| cpu_hits[i] == dev_hits[i])
        .filter(|&i| {
            programs
                .as_ref()
                .is_none_or(|(_, t)| t[i].to_bits() == t_of(&cpu_hits[i]))
        })
        .count();
    let hit = cpu_hits.iter().filter(|h| h.is_some()).count();
    let closest = row(cpu_s, traced, with, programs.map(|p| p.0), same, hit);
    drop((cpu_hits, dev_hits));

    let mut cpu_occ = vec![false; n];
    let cpu_s = time(runs, || cpu.intersect_any(on_cpu, rays, &mut cpu_occ))?;
    let mut batch = device.upload_rays(rays, BatchKind::Any)?;
    let traced = time(runs, || device.trace_batch(on_device, &mut batch))?;
    drop(batch);
    let mut dev_occ = vec![false; n];
    let with = time(runs, || device.intersect_any(on_device, rays, &mut dev_occ))?;
    let programs = pipeline.and_then(|p| traced_or_warn(p.trace(device, rays, true, runs)));
    let same = (0..n)
        .filter(|&i| cpu_occ[i] == dev_occ[i])
        .filter(|&i| {
            programs
                .as_ref()
                .is_none_or(|(_, t)| (t[i] != f32::INFINITY) == cpu_occ[i])
        })
        .count();
    let hit = cpu_occ.iter().filter(|&&o| o).count();
    Ok([
        closest,
        row(cpu_s, traced, with, programs.map(|p| p.0), same, hit),
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_device_is_reported_in_one_line_that_suggests_the_cpu() {
        let e = DeviceCommandError::Open {
            name: "cuda".into(),
            source: DeviceError::CudaUnavailable("no CUDA driver found".into()),
        };
        let msg = e.to_string();
        assert!(msg.contains("CUDA is not available"), "{msg}");
        assert!(msg.contains("--backend cpu"), "{msg}");
        assert_eq!(msg.lines().count(), 1, "{msg}");
    }

    #[test]
    fn backend_names_are_checked_before_any_device_is_opened() {
        for ok in ["cpu", "CUDA", "cuda:1", "auto"] {
            assert!(parse_backend(ok).is_ok(), "{ok}");
        }
        for bad in ["bogus", "cuda:x", "cuda:", ""] {
            assert!(parse_backend(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn open_fails_cleanly_or_opens_a_device() {
        assert_eq!(open("cpu").unwrap().kind(), oxray::BackendKind::Cpu);
        match open("cuda") {
            Ok(d) => assert!(d.describe().contains("sm_")),
            Err(e) => assert!(e.to_string().contains("--backend cpu"), "{e}"),
        }
    }

    #[test]
    fn raycast_on_the_cpu_device_traces_the_ray_file() {
        let dir = std::env::temp_dir().join(format!("oxray-device-raycast-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mesh = dir.join("tri.obj");
        std::fs::write(&mesh, "v -1 -1 0\nv 1 -1 0\nv 0 1 0\nf 1 2 3\n").unwrap();
        let rays: Vec<u8> = [
            [0.0f32, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0, f32::INFINITY],
            [5.0, 5.0, 1.0, 0.0, 0.0, 0.0, -1.0, f32::INFINITY],
        ]
        .iter()
        .flatten()
        .flat_map(|f| f.to_le_bytes())
        .collect();
        let rays_path = dir.join("rays.bin");
        std::fs::write(&rays_path, rays).unwrap();
        let out = dir.join("hits.bin");
        let r = raycast(
            &Device::cpu(),
            &mesh,
            &rays_path,
            &out,
            crate::raycast::RaycastQuery::Closest,
        )
        .unwrap();
        assert_eq!((r.rays, r.hits), (2, 1));
        let bytes = std::fs::read(&out).unwrap();
        assert_eq!(f32::from_le_bytes(bytes[0..4].try_into().unwrap()), 1.0);
        assert_eq!(
            u32::from_le_bytes(bytes[20..24].try_into().unwrap()),
            u32::MAX
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_benchmark_pipeline_compiles_with_nvrtc_where_it_is_present() {
        match ray_pipeline_ptx((9, 0)) {
            Ok(ptx) => assert!(ptx.contains("params"), "the params variable keeps its name"),
            Err(oxray::cuda::CudaError::NoNvrtc(why)) => {
                assert!(
                    std::env::var_os("OXRAY_REQUIRE_NVRTC").is_none(),
                    "OXRAY_REQUIRE_NVRTC is set but NVRTC is missing: {why}"
                );
                println!("skipping: {why}");
            }
            Err(e) => panic!("{e}"),
        }
    }

    /// Guide §5.9.1 and §6.3 restrict a pipeline's graphs and primitive types; a CUDA
    /// pipeline is compiled without the walks they exclude, and with every walk when its
    /// flags allow any graph and the types.
    #[test]
    fn a_pipeline_leaves_out_the_walks_its_flags_exclude_5_9_1_and_6_3() {
        let single_gas_of_triangles = oxray::PipelineCompileOptions {
            traversable_graph_flags: oxray::TraversableGraphFlags::ALLOW_SINGLE_GAS,
            uses_primitive_type_flags: oxray::PrimitiveTypeFlags::TRIANGLE,
            ..ray_pipeline_options()
        };
        let narrow = match ray_pipeline_ptx_with((9, 0), &single_gas_of_triangles) {
            Ok(ptx) => ptx,
            Err(oxray::cuda::CudaError::NoNvrtc(why)) => {
                assert!(
                    std::env::var_os("OXRAY_REQUIRE_NVRTC").is_none(),
                    "OXRAY_REQUIRE_NVRTC is set but NVRTC is missing: {why}"
                );
                println!("skipping: {why}");
                return;
            }
            Err(e) => panic!("{e}"),
        };
        let every_type = oxray::PipelineCompileOptions {
            uses_primitive_type_flags: oxray::PrimitiveTypeFlags::TRIANGLE
                | oxray::PrimitiveTypeFlags::CUSTOM
                | oxray::PrimitiveTypeFlags::SPHERE
                | oxray::PrimitiveTypeFlags::ROUND_LINEAR,
            ..ray_pipeline_options()
        };
        let wide = ray_pipeline_ptx_with((9, 0), &every_type).unwrap();
        for walk in [
            "__oxray_walk_ias",
            "__oxray_walk_custom",
            "__oxray_walk_spheres",
            "__oxray_walk_curves",
        ] {
            assert!(
                wide.contains(walk),
                "{walk} missing where the flags allow it"
            );
            assert!(
                !narrow.contains(walk),
                "{walk} in a single-GAS triangle pipeline"
            );
        }
        assert!(narrow.contains("__oxray_walk_triangles"));
        // The default flags (the benchmark's): any graph, triangles and custom primitives.
        let default = ray_pipeline_ptx_with((9, 0), &ray_pipeline_options()).unwrap();
        assert!(default.contains("__oxray_walk_ias") && default.contains("__oxray_walk_custom"));
        assert!(!default.contains("__oxray_walk_spheres"));
    }

    #[test]
    fn bench_rows_print_as_markdown_rows_of_the_header() {
        let r = DeviceBenchRow {
            name: "m".into(),
            triangles: 3,
            set: "coherent",
            query: "closest",
            cpu: 10.0,
            traced: 500.0,
            with_transfers: 100.0,
            pipeline: Some(450.0),
            identical_pct: 100.0,
            hit_rate_pct: 50.0,
        };
        let line = r.to_string();
        let columns = |s: &str| s.matches('|').count();
        let header = BENCH_HEADER.lines().next().unwrap_or_default();
        assert_eq!(columns(&line), columns(header), "{line}");
        assert!(line.contains("| 50.0x |"), "{line}");
        assert!(
            line.contains("| 450.0 (90%) | 50.0% | 100.0000% |"),
            "{line}"
        );
    }
}
