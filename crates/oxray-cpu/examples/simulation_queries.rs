//! The oxray side of `scripts/bench_simulation_queries.py`: times the simulation queries
//! (`oxray-cpu/src/simulation`) on a mesh, points and rays that the script writes, and writes
//! back the results it cross-checks against Open3D.
//!
//! ```text
//! cargo build --release -p oxray-cpu --example simulation_queries
//! printf 'count_hits\ncount_hits\n' | target/release/examples/simulation_queries DIR THREADS MAX_HITS
//! ```
//!
//! `DIR` holds `mesh.bin` (u32 vertex count, u32 triangle count, f32x3 vertices, u32x3
//! triangles), `points.bin` (f32x3) and `rays.bin` (f32x3 origin, f32x3 direction). The GAS is
//! built once (its seconds are the first line of stdout, `{"build": s}`); then every line of
//! stdin names a query of the batch API to run once on a rayon pool of `THREADS` threads
//! (`closest_point`, `signed_distance`, `all_hits` with at most `MAX_HITS` per ray,
//! `count_hits`), answered by one line `{"query": q, "wall": s, "cpu": s}`: wall-clock
//! seconds and the CPU seconds of every thread of the process (from
//! `/proc/self/task/*/schedstat`; -1 where it cannot be read). So the script interleaves these
//! runs with Open3D's, and a profiler can run one query many times. Each query writes its
//! results to `DIR`: `oxray.closest` (f32 distances), `oxray.signed` (f32), `oxray.counts`
//! (u32), `oxray.listed` (u64 total of the hits listed).

use glam::Vec3;
use oxray_core::Ray;
use oxray_cpu::{AllHits, Gas};
use std::io::BufRead;
use std::path::Path;
use std::time::Instant;

fn read(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn f32s(b: &[u8]) -> Vec<f32> {
    b.chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

fn u32s(b: &[u8]) -> Vec<u32> {
    b.chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// CPU seconds of every thread of this process so far (the first field of each thread's
/// `schedstat`, nanoseconds on the CPU), or -1 where they cannot be read.
fn cpu_seconds() -> f64 {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return -1.0;
    };
    let mut ns = 0u64;
    for task in tasks.flatten() {
        let Ok(s) = std::fs::read_to_string(task.path().join("schedstat")) else {
            return -1.0;
        };
        match s
            .split_whitespace()
            .next()
            .and_then(|x| x.parse::<u64>().ok())
        {
            Some(x) => ns += x,
            None => return -1.0,
        }
    }
    ns as f64 * 1e-9
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 4 {
        eprintln!("usage: simulation_queries DIR THREADS MAX_HITS < queries");
        std::process::exit(2);
    }
    let dir = Path::new(&args[1]);
    let threads: usize = args[2].parse().expect("THREADS");
    let max_hits: usize = args[3].parse().expect("MAX_HITS");
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_global()
        .expect("rayon pool");

    let mesh = read(&dir.join("mesh.bin"));
    let header = u32s(&mesh[..8]);
    let (nv, nt) = (header[0] as usize, header[1] as usize);
    let v: Vec<[f32; 3]> = f32s(&mesh[8..8 + 12 * nv])
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    let t: Vec<[u32; 3]> = u32s(&mesh[8 + 12 * nv..8 + 12 * nv + 12 * nt])
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    let points: Vec<Vec3> = f32s(&read(&dir.join("points.bin")))
        .chunks_exact(3)
        .map(|c| Vec3::new(c[0], c[1], c[2]))
        .collect();
    let rays: Vec<Ray> = f32s(&read(&dir.join("rays.bin")))
        .chunks_exact(6)
        .map(|c| Ray::new(Vec3::new(c[0], c[1], c[2]), Vec3::new(c[3], c[4], c[5])))
        .collect();

    let start = Instant::now();
    let gas = Gas::from_mesh(&v, &t).expect("mesh");
    println!("{{\"build\": {:.9}}}", start.elapsed().as_secs_f64());

    let mut closest = vec![None; points.len()];
    let mut signed = vec![0.0f32; points.len()];
    let mut all = AllHits::new();
    let mut counts = vec![0u32; rays.len()];
    for line in std::io::stdin().lock().lines() {
        let line = line.expect("stdin");
        let query = line.trim();
        if query.is_empty() {
            continue;
        }
        let (wall, cpu) = (Instant::now(), cpu_seconds());
        match query {
            "closest_point" => gas.closest_point_batch(&points, &mut closest).unwrap(),
            "signed_distance" => gas.signed_distance_batch(&points, &mut signed).unwrap(),
            "all_hits" => gas.all_hits_batch(&rays, max_hits, &mut all).unwrap(),
            "count_hits" => gas.count_hits_batch(&rays, &mut counts).unwrap(),
            _ => {
                eprintln!("unknown query {query:?}");
                std::process::exit(2);
            }
        }
        let wall = wall.elapsed().as_secs_f64();
        let cpu = match (cpu, cpu_seconds()) {
            (a, b) if a >= 0.0 && b >= a => b - a,
            _ => -1.0,
        };
        let (name, bytes): (&str, Vec<u8>) = match query {
            "closest_point" => (
                "oxray.closest",
                closest
                    .iter()
                    .flat_map(|c| c.map_or(f32::INFINITY, |c| c.distance).to_le_bytes())
                    .collect(),
            ),
            "signed_distance" => (
                "oxray.signed",
                signed.iter().flat_map(|x| x.to_le_bytes()).collect(),
            ),
            "all_hits" => (
                "oxray.listed",
                (all.all().len() as u64).to_le_bytes().to_vec(),
            ),
            _ => (
                "oxray.counts",
                counts.iter().flat_map(|x| x.to_le_bytes()).collect(),
            ),
        };
        std::fs::write(dir.join(name), bytes).expect("write");
        println!(
            "{{\"query\": \"{query}\", \"wall\": {wall:.9}, \"cpu\": {:.9}}}",
            if cpu.is_finite() && cpu >= 0.0 {
                cpu
            } else {
                -1.0
            }
        );
    }
}
