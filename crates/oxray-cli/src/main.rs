//! `oxray`: the command-line tool.

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand};
use oxray_cli::bench::{self, BenchRays};
use oxray_cli::mesh::Mesh;
use std::path::{Path, PathBuf};

#[derive(Parser)]
#[command(
    name = "oxray",
    version,
    about = "oxray: a programmable ray-tracing engine"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render the built-in Cornell box with the path tracer (scene files come in a later
    /// version).
    Render {
        /// Output image (.png).
        #[arg(short, long, default_value = "cornell.png")]
        output: PathBuf,
        /// Image size, WxH.
        #[arg(long, default_value = "512x512")]
        size: String,
        /// Samples per pixel.
        #[arg(long, default_value_t = 64)]
        spp: u32,
        /// Bounces at most.
        #[arg(long, default_value_t = 8)]
        max_depth: u32,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
    },
    /// Cast a file of rays (little-endian f32[8]: ox, oy, oz, tmin, dx, dy, dz, tmax) at a
    /// mesh; write hits (f32 t, u32 primitive, f32 u, f32 v; t = +inf and primitive 0xFFFFFFFF
    /// on a miss) or, with --occlusion, one u32 0/1 per ray. Primitive indices are triangles in
    /// file order (polygons fan-triangulated, strips unrolled).
    Raycast {
        /// The mesh (.obj, .ply).
        mesh: PathBuf,
        /// The ray file.
        #[arg(long)]
        rays: PathBuf,
        /// Where to write the results.
        #[arg(long)]
        out: PathBuf,
        /// Any hit instead of closest hit.
        #[arg(long)]
        occlusion: bool,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
    },
    /// Triangle and instance counts and BVH statistics of a mesh.
    Info {
        /// The mesh (.obj, .ply).
        mesh: PathBuf,
    },
    /// Build time and Mrays/s (closest and any hit; coherent and incoherent rays) on meshes.
    /// Without MESH, the bunny and igea from ../shared/data when present, else a generated
    /// icosphere.
    Bench {
        /// Meshes (.obj, .ply).
        meshes: Vec<PathBuf>,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
        /// Rays per set are SIDE x SIDE.
        #[arg(long, default_value_t = 1024)]
        side: u32,
        /// Repetitions of each measurement (the median is reported).
        #[arg(long, default_value_t = 5)]
        runs: usize,
        /// Also write each mesh and its rays here, for scripts/bench_embree.py.
        #[arg(long)]
        export: Option<PathBuf>,
        /// Also build an IAS of this many instances of the first mesh and trace through it.
        #[arg(long)]
        instances: Option<usize>,
    },
}

fn main() {
    if let Err(e) = run(Cli::parse()) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn default_meshes() -> Vec<PathBuf> {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/meshes");
    ["stanford-bunny.obj", "igea.ply"]
        .iter()
        .map(|f| data.join(f))
        .filter(|p| p.exists())
        .collect()
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Render {
            output,
            size,
            spp,
            max_depth,
            threads,
        } => {
            let (w, h) = size
                .split_once('x')
                .and_then(|(w, h)| Some((w.parse::<u32>().ok()?, h.parse::<u32>().ok()?)))
                .filter(|&(w, h)| w > 0 && h > 0 && w <= 16384 && h <= 16384)
                .with_context(|| format!("--size must be WxH within 1..=16384, got {size:?}"))?;
            if spp == 0 || spp > 1 << 16 {
                bail!("--spp must be in 1..=65536, got {spp}");
            }
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads.unwrap_or(0))
                .build()
                .context("cannot start the worker threads")?;
            let start = std::time::Instant::now();
            let pixels = pool
                .install(|| {
                    oxray_cli::render::render_cornell(w, h, spp, max_depth.clamp(1, 64))
                        .map_err(|e| e.to_string())
                })
                .map_err(anyhow::Error::msg)?;
            oxray_cli::render::write_png(&output, w, h, &pixels)
                .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", output.display()))?;
            println!(
                "wrote {} ({w}x{h}, {spp} spp) in {:.1} s",
                output.display(),
                start.elapsed().as_secs_f64()
            );
            Ok(())
        }
        Command::Raycast {
            mesh,
            rays,
            out,
            occlusion,
            threads,
        } => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads.unwrap_or(0))
                .build()
                .context("cannot start the worker threads")?;
            let r = pool.install(|| oxray_cli::raycast::raycast(&mesh, &rays, &out, occlusion))?;
            println!(
                "{} rays, {} {} ({:.2} Mrays/s on {} threads)",
                r.rays,
                r.hits,
                if occlusion { "occluded" } else { "hits" },
                r.mrays_per_s,
                pool.current_num_threads()
            );
            Ok(())
        }
        Command::Info { mesh } => {
            println!("{}", oxray_cli::raycast::info(&mesh)?);
            Ok(())
        }
        Command::Bench {
            meshes,
            threads,
            side,
            runs,
            export,
            instances,
        } => {
            if side == 0 || side > 16384 {
                bail!("--side must be in 1..=16384, got {side}");
            }
            if runs == 0 {
                bail!("--runs must be at least 1");
            }
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads.unwrap_or(0))
                .build()
                .context("cannot start the worker threads")?;
            let mut sets: Vec<(String, Mesh)> = Vec::new();
            let paths = if meshes.is_empty() {
                default_meshes()
            } else {
                meshes
            };
            if paths.is_empty() {
                println!(
                    "(no meshes given and ../shared/data absent: using a generated icosphere)"
                );
                sets.push(("icosphere-7".into(), Mesh::icosphere(7)));
            }
            for p in paths {
                let mesh = Mesh::load(&p)?;
                let name = p
                    .file_stem()
                    .and_then(|s| s.to_str())
                    .unwrap_or("mesh")
                    .to_string();
                sets.push((name, mesh));
            }
            println!(
                "threads: {}, rays per set: {}, median of {runs} runs",
                pool.current_num_threads(),
                side * side
            );
            println!(
                "| mesh | tris | build ms (default / fast-build / fast-trace) | SAH (default / fast-build / fast-trace) | coherent closest | coherent any | incoherent closest | incoherent any | incoherent closest by build (default / fast-build / fast-trace) | pipeline coherent closest vs the same rays as queries, alternated |"
            );
            println!("|---|---:|---|---|---:|---:|---:|---:|---|---:|");
            for (name, mesh) in &sets {
                let rays = BenchRays::new(mesh, side);
                if let Some(dir) = &export {
                    let gas = bench::build_gas(mesh, oxray::BuildFlags::empty())?;
                    bench::export(dir, name, mesh, &rays)
                        .and_then(|_| bench::export_hits(dir, name, &gas, &rays))
                        .with_context(|| format!("cannot write to {}", dir.display()))?;
                }
                let r = pool
                    .install(|| bench::run(name, mesh, runs, &rays).map_err(|e| e.to_string()))
                    .map_err(anyhow::Error::msg)?;
                println!(
                    "| {} | {} | {:.1} / {:.1} / {:.1} | {:.1} / {:.1} / {:.1} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} / {:.2} / {:.2} | {:.2} vs {:.2} ({:.0}%) |",
                    r.name, r.triangles, r.build_ms[0], r.build_ms[1], r.build_ms[2],
                    r.sah[0], r.sah[1], r.sah[2],
                    r.mrays[0], r.mrays[1], r.mrays[2], r.mrays[3],
                    r.mrays_by_flags[0], r.mrays_by_flags[1], r.mrays_by_flags[2],
                    r.pipeline_mrays.0,
                    r.pipeline_mrays.1,
                    100.0 * r.pipeline_mrays.0 / r.pipeline_mrays.1,
                );
                eprintln!(
                    "  {}: {:.1} Mtris/s build, hit rate coherent {:.1}%, incoherent {:.1}%",
                    r.name,
                    r.triangles as f64 / r.build_ms[0] / 1e3,
                    100.0 * r.hit_rate[0],
                    100.0 * r.hit_rate[1]
                );
            }
            if let (Some(n), Some((name, mesh))) = (instances, sets.first()) {
                if n == 0 || n > 1 << 28 {
                    bail!("--instances must be in 1..=2^28, got {n}");
                }
                let r = pool
                    .install(|| bench::instances(mesh, n, side, runs).map_err(|e| e.to_string()))
                    .map_err(anyhow::Error::msg)?;
                println!();
                println!("| instanced mesh | instances | triangles (instanced) | IAS build ms | camera closest Mrays/s | random closest Mrays/s | camera hit rate |");
                println!("|---|---:|---:|---:|---:|---:|---:|");
                println!(
                    "| {name} | {} | {} | {:.1} | {:.2} | {:.2} | {:.1}% |",
                    r.instances,
                    r.mesh_triangles as u64 * r.instances as u64,
                    r.build_ms,
                    r.coherent_mrays,
                    r.incoherent_mrays,
                    100.0 * r.hit_rate
                );
            }
            Ok(())
        }
    }
}
