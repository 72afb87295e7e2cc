//! Ray throughput on the GPU against the CPU backend, with an agreement check.
//!
//! ```text
//! cargo run --release -p oxray-cuda --example gpu_raycast -- [MESH.obj ...] [--icosphere N]
//!     [--side 1024] [--runs 9] [--layout bvh4|bvh2|both] [--out results.md]
//! ```
//!
//! For each mesh (default: the bunny from `../shared/data` when present, and an icosphere of 5
//! subdivisions) it builds a GAS with default flags, generates the ray sets of `oxray bench`
//! (`side` x `side` camera rays and as many hemisphere rays), traces them with the CPU backend
//! on all cores and on the GPU, checks that the hits agree and prints markdown tables of
//! Mrays/s: GPU kernel time (rays and results resident on the device) and GPU with transfers
//! (rays up, hits down and resolved into `oxray::Hit`s).

#[path = "../tests/common/mod.rs"]
mod common;

use common::{bench_rays, build_gas_with_tree, find_mesh, icosphere_f32, load_obj, Mesh};
use oxray_core::{BuildFlags, Ray};
use oxray_cpu::Gas;
use oxray_cuda::{
    CudaContext, CudaGas, DeviceHits, DeviceOcclusion, DeviceRays, HitRecord, NodeLayout,
};
use std::fmt::Write as _;
use std::time::Instant;

struct Args {
    meshes: Vec<String>,
    icosphere: Option<u32>,
    side: u32,
    runs: usize,
    layouts: Vec<NodeLayout>,
    out: Option<String>,
}

fn parse_args() -> Result<Args, String> {
    let mut a = Args {
        meshes: Vec::new(),
        icosphere: None,
        side: 1024,
        runs: 9,
        layouts: vec![NodeLayout::Bvh4, NodeLayout::Bvh2],
        out: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let mut value = |name: &str| it.next().ok_or(format!("{name} needs a value"));
        match arg.as_str() {
            "--side" => {
                a.side = value("--side")?
                    .parse()
                    .map_err(|e| format!("--side: {e}"))?
            }
            "--runs" => {
                a.runs = value("--runs")?
                    .parse()
                    .map_err(|e| format!("--runs: {e}"))?
            }
            "--icosphere" => {
                a.icosphere = Some(
                    value("--icosphere")?
                        .parse()
                        .map_err(|e| format!("--icosphere: {e}"))?,
                )
            }
            "--layout" => {
                a.layouts = match value("--layout")?.as_str() {
                    "bvh4" => vec![NodeLayout::Bvh4],
                    "bvh2" => vec![NodeLayout::Bvh2],
                    "both" => vec![NodeLayout::Bvh4, NodeLayout::Bvh2],
                    l => return Err(format!("--layout: unknown layout {l:?}")),
                }
            }
            "--out" => a.out = Some(value("--out")?),
            "-h" | "--help" => {
                return Err(
                    "usage: gpu_raycast [MESH.obj ...] [--icosphere N] [--side N] \
                            [--runs N] [--layout bvh4|bvh2|both] [--out FILE]"
                        .into(),
                )
            }
            s if s.starts_with('-') => return Err(format!("unknown option {s}")),
            s => a.meshes.push(s.to_string()),
        }
    }
    if a.side == 0 || a.side > 8192 {
        return Err(format!("--side must be in 1..=8192, got {}", a.side));
    }
    if a.runs == 0 {
        return Err("--runs must be at least 1".into());
    }
    if a.icosphere.is_some_and(|n| n > 9) {
        return Err("--icosphere must be at most 9".into());
    }
    Ok(a)
}

/// Median seconds of `runs` calls after one warm-up.
fn time<E>(runs: usize, mut f: impl FnMut() -> Result<(), E>) -> Result<f64, E> {
    f()?;
    let mut t = Vec::with_capacity(runs);
    for _ in 0..runs {
        let s = Instant::now();
        f()?;
        t.push(s.elapsed().as_secs_f64());
    }
    t.sort_by(f64::total_cmp);
    Ok(t[t.len() / 2])
}

fn mrays(n: usize, s: f64) -> f64 {
    n as f64 / s / 1e6
}

/// One row of results: a ray set and a query.
struct Row {
    mesh: String,
    triangles: usize,
    set: &'static str,
    query: &'static str,
    cpu: f64,
    /// Per layout: (kernel, with transfers, identical %, agree %).
    gpu: Vec<(NodeLayout, f64, f64, f64, f64)>,
}

fn main() {
    if let Err(e) = run() {
        eprintln!("gpu_raycast: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let args = parse_args()?;
    let mut meshes: Vec<(String, Mesh)> = Vec::new();
    for m in &args.meshes {
        let name = std::path::Path::new(m)
            .file_stem()
            .map_or(m.clone(), |s| s.to_string_lossy().into_owned());
        meshes.push((name, load_obj(std::path::Path::new(m))?));
    }
    if args.meshes.is_empty() && args.icosphere.is_none() {
        match find_mesh("stanford-bunny.obj") {
            Some(p) => meshes.push(("bunny".into(), load_obj(&p)?)),
            None => eprintln!("stanford-bunny.obj not found; using the icosphere only"),
        }
    }
    if let Some(n) = args.icosphere.or(args.meshes.is_empty().then_some(5)) {
        meshes.push((format!("icosphere-{n}"), icosphere_f32(n)));
    }

    let ctx = CudaContext::new()?;
    let dev = ctx.device();
    let mut md = String::new();
    writeln!(
        md,
        "device: {} (sm_{}{}, {} SMs, {:.0} GiB), driver {}, NVRTC {}.{}; CPU: {} threads; \
         {} rays per set; median of {} runs",
        dev.name,
        dev.compute_capability.0,
        dev.compute_capability.1,
        dev.multiprocessors,
        dev.total_memory as f64 / (1u64 << 30) as f64,
        dev.driver_version,
        dev.nvrtc_version.0,
        dev.nvrtc_version.1,
        rayon::current_num_threads(),
        args.side as usize * args.side as usize,
        args.runs
    )?;
    writeln!(md)?;
    for k in ctx.kernel_info()? {
        writeln!(
            md,
            "- `{}`: {} registers, {} bytes of local memory per thread",
            k.name, k.registers, k.local_bytes
        )?;
    }
    writeln!(md)?;

    let mut rows: Vec<Row> = Vec::new();
    let mut layout_md = String::new();
    writeln!(
        layout_md,
        "| mesh | layout | nodes | node bytes | device MB (nodes + triangles) | upload ms |"
    )?;
    writeln!(layout_md, "|---|---|---:|---:|---:|---:|")?;
    for (name, mesh) in &meshes {
        let t = Instant::now();
        let (gas, tree) = build_gas_with_tree(mesh, BuildFlags::empty())?;
        eprintln!(
            "{name}: {} triangles, built in {:.1} ms",
            mesh.triangles.len(),
            t.elapsed().as_secs_f64() * 1e3
        );
        let (coherent, incoherent) = bench_rays(mesh, args.side);
        let mut gpus = Vec::new();
        for &layout in &args.layouts {
            let t = Instant::now();
            let g = CudaGas::upload_with_layout(&ctx, &gas, &tree, layout)?;
            let ms = t.elapsed().as_secs_f64() * 1e3;
            writeln!(
                layout_md,
                "| {name} | {} | {} | {} | {:.1} | {ms:.1} |",
                layout.name(),
                g.num_nodes(),
                layout.node_bytes(),
                g.device_bytes() as f64 / 1e6,
            )?;
            gpus.push(g);
        }
        for (set, rays) in [("coherent", &coherent), ("incoherent", &incoherent)] {
            rows.extend(measure(
                &ctx, name, mesh, &gas, &gpus, set, rays, args.runs,
            )?);
        }
    }

    writeln!(md, "{layout_md}")?;
    write!(md, "| mesh | triangles | rays | query | CPU Mrays/s |")?;
    for &l in &args.layouts {
        write!(md, " GPU {0} kernel | GPU {0} with transfers |", l.name())?;
    }
    writeln!(
        md,
        " kernel speed-up over CPU | hits identical / agreeing |"
    )?;
    write!(md, "|---|---:|---|---|---:|")?;
    for _ in &args.layouts {
        write!(md, "---:|---:|")?;
    }
    writeln!(md, "---:|---|")?;
    for r in &rows {
        write!(
            md,
            "| {} | {} | {} | {} | {:.1} |",
            r.mesh, r.triangles, r.set, r.query, r.cpu
        )?;
        for g in &r.gpu {
            write!(md, " {:.0} | {:.0} |", g.1, g.2)?;
        }
        let best = r.gpu.iter().map(|g| g.1).fold(0.0, f64::max);
        let agree: Vec<String> = r
            .gpu
            .iter()
            .map(|g| format!("{}: {:.4} % / {:.4} %", g.0.name(), g.3, g.4))
            .collect();
        writeln!(md, " {:.0}x | {} |", best / r.cpu, agree.join(", "))?;
    }
    println!("{md}");
    if let Some(out) = &args.out {
        std::fs::write(out, &md)?;
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn measure(
    ctx: &CudaContext,
    name: &str,
    mesh: &Mesh,
    gas: &Gas,
    gpus: &[CudaGas],
    set: &'static str,
    rays: &[Ray],
    runs: usize,
) -> Result<Vec<Row>, Box<dyn std::error::Error>> {
    let n = rays.len();
    let mut cpu_hits = vec![None; n];
    let mut cpu_occ = vec![false; n];
    let cpu_closest = time(runs, || gas.intersect_batch(rays, &mut cpu_hits))?;
    let cpu_any = time(runs, || gas.occluded_batch(rays, &mut cpu_occ))?;

    let mut closest = Row {
        mesh: name.to_string(),
        triangles: mesh.triangles.len(),
        set,
        query: "closest",
        cpu: mrays(n, cpu_closest),
        gpu: Vec::new(),
    };
    let mut any = Row {
        query: "any",
        cpu: mrays(n, cpu_any),
        gpu: Vec::new(),
        mesh: name.to_string(),
        triangles: mesh.triangles.len(),
        set,
    };
    let d_rays = DeviceRays::upload(ctx, rays)?;
    let mut d_hits = DeviceHits::new(ctx, n)?;
    let mut d_occ = DeviceOcclusion::new(ctx, n)?;
    let mut records = vec![HitRecord::default(); n];
    for g in gpus {
        // Kernel only: rays and results stay on the device.
        let k_closest = time(runs, || g.intersect_device(&d_rays, &mut d_hits))?;
        let k_any = time(runs, || g.occluded_device(&d_rays, &mut d_occ))?;
        // With transfers: the one-call API into preallocated outputs (as the CPU is timed):
        // rays up, results down and resolved into `oxray::Hit`s.
        let mut gpu_hits = vec![None; n];
        let x_closest = time(runs, || g.intersect_batch_into(rays, &mut gpu_hits))?;
        let mut gpu_occ = vec![false; n];
        let x_any = time(runs, || g.occluded_batch_into(rays, &mut gpu_occ))?;
        // Where the time of the one-call API goes (closest hit).
        let mut d_rays_w = DeviceRays::upload(ctx, rays)?;
        let up = time(runs, || d_rays_w.write(ctx, rays))?;
        let down = time(runs, || d_hits.download_into(ctx, &mut records))?;
        let mut resolved = vec![None; n];
        let res = time(runs, || {
            g.resolve_into(&records, &mut resolved);
            Ok::<(), oxray_cuda::CudaError>(())
        })?;
        eprintln!(
            "{name} {set} {}: closest hit, ms: upload {:.2}, kernel {:.2}, download {:.2}, \
             resolve {:.2}; one call {:.2}",
            g.layout().name(),
            up * 1e3,
            k_closest * 1e3,
            down * 1e3,
            res * 1e3,
            x_closest * 1e3
        );
        let identical = cpu_hits
            .iter()
            .zip(&gpu_hits)
            .filter(|(c, g)| c == g)
            .count();
        let agree = cpu_hits
            .iter()
            .zip(&gpu_hits)
            .filter(|(c, g)| match (c, g) {
                (None, None) => true,
                (Some(c), Some(g)) => (c.t - g.t).abs() <= 1e-5 * c.t.abs(),
                _ => false,
            })
            .count();
        let occ_agree = cpu_occ.iter().zip(&gpu_occ).filter(|(c, g)| c == g).count();
        let pct = |k: usize| 100.0 * k as f64 / n.max(1) as f64;
        let hit_rate = records.iter().filter(|r| r.is_hit()).count();
        eprintln!(
            "{name} {set} {}: hit rate {:.1} %, closest {:.4} % identical / {:.4} % agree, \
             occlusion {:.4} % agree",
            g.layout().name(),
            pct(hit_rate),
            pct(identical),
            pct(agree),
            pct(occ_agree)
        );
        closest.gpu.push((
            g.layout(),
            mrays(n, k_closest),
            mrays(n, x_closest),
            pct(identical),
            pct(agree),
        ));
        any.gpu.push((
            g.layout(),
            mrays(n, k_any),
            mrays(n, x_any),
            pct(occ_agree),
            pct(occ_agree),
        ));
    }
    Ok(vec![closest, any])
}
