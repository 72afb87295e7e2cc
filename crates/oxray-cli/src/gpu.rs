//! The CUDA backend of `oxray raycast` and `oxray bench` (`--backend cuda`).
//!
//! The GAS is built on the CPU exactly as for the CPU backend, uploaded with
//! [`CudaGas::upload`] and traced by the CUDA batch API. Where this machine has no CUDA,
//! [`open`] fails with [`GpuError::Unavailable`]: a user who asks for the CUDA backend gets an
//! error, never a silent fall-back to the CPU.

use crate::bench::{build_gas, median, BenchRays};
use crate::raycast::{encode_hits, encode_occlusion, load_inputs, write_results, RaycastError};
use oxray::cpu::Gas;
use oxray::{BuildFlags, Hit, Ray};
use oxray_cuda::{CudaContext, CudaError, CudaGas, DeviceHits, DeviceOcclusion, DeviceRays};
use oxray_scene::mesh::Mesh;
use std::fmt;
use std::path::Path;
use std::time::Instant;
use thiserror::Error;

/// Which backend traces the rays of `oxray raycast` and `oxray bench`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Backend {
    /// The CPU backend, on all worker threads.
    #[default]
    Cpu,
    /// The CUDA backend (`oxray-cuda`) on GPU 0; the GAS is still built on the CPU.
    Cuda,
}

/// Why a CUDA ray cast or benchmark failed.
#[derive(Debug, Error)]
pub enum GpuError {
    /// This machine has no CUDA (no driver, no device or no NVRTC).
    #[error("--backend cuda: CUDA is not available on this machine: {0}; use --backend cpu")]
    Unavailable(CudaError),
    /// A CUDA call failed on a machine that has CUDA.
    #[error("CUDA backend: {0}")]
    Cuda(CudaError),
    /// Loading the inputs, building the GAS or writing the results failed.
    #[error(transparent)]
    Raycast(#[from] RaycastError),
    /// A CPU query of the comparison was refused.
    #[error(transparent)]
    Query(#[from] oxray::QueryError),
    /// The GAS of a benchmark mesh could not be built.
    #[error(transparent)]
    Build(#[from] oxray::BuildError),
}

impl From<CudaError> for GpuError {
    fn from(e: CudaError) -> Self {
        if e.is_unavailable() {
            GpuError::Unavailable(e)
        } else {
            GpuError::Cuda(e)
        }
    }
}

/// Opens GPU 0 and compiles the trace kernels; [`GpuError::Unavailable`] where this machine
/// has no CUDA.
pub fn open() -> Result<CudaContext, GpuError> {
    Ok(CudaContext::new()?)
}

/// One line naming the device, e.g. `NVIDIA H100 80GB HBM3 (sm_90, 132 SMs)`.
pub fn describe(ctx: &CudaContext) -> String {
    let d = ctx.device();
    format!(
        "{} (sm_{}{}, {} SMs)",
        d.name, d.compute_capability.0, d.compute_capability.1, d.multiprocessors
    )
}

/// Median seconds of `runs` calls of `f` after one warm-up call (which allocates the reused
/// buffers and lets the driver settle).
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

/// What a CUDA ray cast did.
#[derive(Clone, Copy, Debug)]
pub struct GpuRaycastReport {
    /// Rays cast.
    pub rays: usize,
    /// Rays that hit (or, for occlusion, were occluded).
    pub hits: usize,
    /// Mrays/s of the kernel alone, rays and results resident on the GPU.
    pub kernel_mrays_per_s: f64,
    /// Mrays/s of the one-call query: rays up, the kernel, results down and resolved.
    pub transfer_mrays_per_s: f64,
}

/// `oxray raycast --backend cuda`: casts the rays of `rays_path` at the mesh on the GPU of
/// `ctx` and writes the same file as the CPU backend (hits, or with `occlusion` one u32 0/1
/// per ray). Each speed is that of one call after a warm-up call.
pub fn raycast(
    ctx: &CudaContext,
    mesh_path: &Path,
    rays_path: &Path,
    out_path: &Path,
    occlusion: bool,
) -> Result<GpuRaycastReport, GpuError> {
    let (gas, rays) = load_inputs(mesh_path, rays_path)?;
    let gpu = CudaGas::upload(ctx, &gas)?;
    let n = rays.len();
    let d_rays = DeviceRays::upload(ctx, &rays)?;
    let (out, hits, kernel, with_transfers) = if occlusion {
        let mut d_occ = DeviceOcclusion::new(ctx, n)?;
        let kernel = time(1, || gpu.occluded_device(&d_rays, &mut d_occ))?;
        drop(d_occ);
        let mut occ = vec![false; n];
        let with = time(1, || gpu.occluded_batch_into(&rays, &mut occ))?;
        let count = occ.iter().filter(|&&o| o).count();
        (encode_occlusion(&occ), count, kernel, with)
    } else {
        let mut d_hits = DeviceHits::new(ctx, n)?;
        let kernel = time(1, || gpu.intersect_device(&d_rays, &mut d_hits))?;
        drop(d_hits);
        let mut hits = vec![None; n];
        let with = time(1, || gpu.intersect_batch_into(&rays, &mut hits))?;
        let count = hits.iter().filter(|h| h.is_some()).count();
        (encode_hits(&hits), count, kernel, with)
    };
    write_results(out_path, &out)?;
    Ok(GpuRaycastReport {
        rays: n,
        hits,
        kernel_mrays_per_s: mrays(n, kernel),
        transfer_mrays_per_s: mrays(n, with_transfers),
    })
}

/// The header of the `oxray bench --backend cuda` table (markdown, two lines).
pub const BENCH_HEADER: &str = "| mesh | tris | rays | query | CPU Mrays/s | GPU kernel Mrays/s | GPU with transfers Mrays/s | kernel / CPU | hit rate | hits identical to CPU |\n|---|---:|---|---|---:|---:|---:|---:|---:|---:|";

/// One row of the CUDA benchmark: one ray set and one query on one mesh.
#[derive(Clone, Debug)]
pub struct GpuBenchRow {
    /// Mesh name.
    pub name: String,
    /// Triangles.
    pub triangles: usize,
    /// `coherent`, `incoherent` or `shadow`.
    pub set: &'static str,
    /// `closest` or `any`.
    pub query: &'static str,
    /// Mrays/s of the CPU backend on the same rays and GAS.
    pub cpu: f64,
    /// Mrays/s of the kernel alone (rays and results resident on the GPU).
    pub kernel: f64,
    /// Mrays/s of the one-call query (rays up, kernel, results down and resolved).
    pub with_transfers: f64,
    /// Percentage of rays whose GPU result equals the CPU's: the whole [`Hit`] for closest
    /// hit, the flag for any hit.
    pub identical_pct: f64,
    /// Percentage of rays that hit.
    pub hit_rate_pct: f64,
}

impl fmt::Display for GpuBenchRow {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "| {} | {} | {} | {} | {:.2} | {:.1} | {:.1} | {:.0}x | {:.1}% | {:.4}% |",
            self.name,
            self.triangles,
            self.set,
            self.query,
            self.cpu,
            self.kernel,
            self.with_transfers,
            self.kernel / self.cpu.max(1e-12),
            self.hit_rate_pct,
            self.identical_pct
        )
    }
}

/// `oxray bench --backend cuda` on one mesh: the GAS of the CPU benchmark (default build
/// flags), uploaded, and the benchmark's ray sets traced on the CPU (current rayon pool) and the
/// GPU, closest and any hit, each timed as the median of `runs` after a warm-up. Returns six
/// rows: closest and any hit for the coherent (primary), incoherent (diffuse) and shadow rays.
pub fn bench_mesh(
    ctx: &CudaContext,
    name: &str,
    mesh: &Mesh,
    rays: &BenchRays,
    runs: usize,
) -> Result<Vec<GpuBenchRow>, GpuError> {
    let gas = build_gas(mesh, BuildFlags::empty())?;
    let gpu = CudaGas::upload(ctx, &gas)?;
    let mut rows = Vec::with_capacity(6);
    for (set, rays) in [
        ("coherent", &rays.coherent),
        ("incoherent", &rays.incoherent),
        ("shadow", &rays.shadow),
    ] {
        let [closest, any] = bench_set(ctx, &gas, &gpu, rays, runs)?;
        for (query, r) in [("closest", closest), ("any", any)] {
            rows.push(GpuBenchRow {
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

/// Times one ray set, closest and any hit; the rows' names are filled in by the caller.
fn bench_set(
    ctx: &CudaContext,
    gas: &Gas,
    gpu: &CudaGas,
    rays: &[Ray],
    runs: usize,
) -> Result<[GpuBenchRow; 2], GpuError> {
    let n = rays.len();
    let pct = |k: usize| 100.0 * k as f64 / n.max(1) as f64;
    let row = |cpu, kernel, with_transfers, same, hit| GpuBenchRow {
        name: String::new(),
        triangles: 0,
        set: "",
        query: "",
        cpu: mrays(n, cpu),
        kernel: mrays(n, kernel),
        with_transfers: mrays(n, with_transfers),
        identical_pct: pct(same),
        hit_rate_pct: pct(hit),
    };
    let d_rays = DeviceRays::upload(ctx, rays)?;

    let mut cpu_hits: Vec<Option<Hit>> = vec![None; n];
    let cpu = time(runs, || gas.intersect_batch(rays, &mut cpu_hits))?;
    let mut d_hits = DeviceHits::new(ctx, n)?;
    let kernel = time(runs, || gpu.intersect_device(&d_rays, &mut d_hits))?;
    drop(d_hits);
    let mut gpu_hits: Vec<Option<Hit>> = vec![None; n];
    let with = time(runs, || gpu.intersect_batch_into(rays, &mut gpu_hits))?;
    let same = cpu_hits
        .iter()
        .zip(&gpu_hits)
        .filter(|(c, g)| c == g)
        .count();
    let hit = cpu_hits.iter().filter(|h| h.is_some()).count();
    let closest = row(cpu, kernel, with, same, hit);
    drop((cpu_hits, gpu_hits));

    let mut cpu_occ = vec![false; n];
    let cpu = time(runs, || gas.occluded_batch(rays, &mut cpu_occ))?;
    let mut d_occ = DeviceOcclusion::new(ctx, n)?;
    let kernel = time(runs, || gpu.occluded_device(&d_rays, &mut d_occ))?;
    drop(d_occ);
    let mut gpu_occ = vec![false; n];
    let with = time(runs, || gpu.occluded_batch_into(rays, &mut gpu_occ))?;
    let same = cpu_occ.iter().zip(&gpu_occ).filter(|(c, g)| c == g).count();
    let hit = cpu_occ.iter().filter(|&&o| o).count();
    Ok([closest, row(cpu, kernel, with, same, hit)])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_cuda_is_reported_as_unavailable_in_one_line() {
        let e = GpuError::from(CudaError::NoDriver("libcuda could not be loaded".into()));
        assert!(matches!(e, GpuError::Unavailable(_)));
        let msg = e.to_string();
        assert!(msg.contains("CUDA is not available"), "{msg}");
        assert!(msg.contains("--backend cpu"), "{msg}");
        assert_eq!(msg.lines().count(), 1, "{msg}");
        let e = GpuError::from(CudaError::TooLarge("a batch".into()));
        assert!(matches!(e, GpuError::Cuda(_)), "{e}");
    }

    #[test]
    fn open_fails_cleanly_or_opens_a_device() {
        match open() {
            Ok(ctx) => assert!(describe(&ctx).contains("sm_")),
            Err(e) => assert!(
                matches!(e, GpuError::Unavailable(_) | GpuError::Cuda(_)),
                "{e}"
            ),
        }
    }

    #[test]
    fn bench_rows_print_as_markdown_rows_of_the_header() {
        let r = GpuBenchRow {
            name: "m".into(),
            triangles: 3,
            set: "coherent",
            query: "closest",
            cpu: 10.0,
            kernel: 500.0,
            with_transfers: 100.0,
            identical_pct: 100.0,
            hit_rate_pct: 50.0,
        };
        let line = r.to_string();
        let columns = |s: &str| s.matches('|').count();
        let header = BENCH_HEADER.lines().next().unwrap_or_default();
        assert_eq!(columns(&line), columns(header), "{line}");
        assert!(line.contains("| 50x |"), "{line}");
        assert!(line.contains("| 50.0% | 100.0000% |"), "{line}");
    }
}
