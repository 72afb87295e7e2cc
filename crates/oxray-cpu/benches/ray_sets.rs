//! One ray set of `oxray bench --export DIR` traced again and again: the tool for profiling
//! the CPU kernel (`perf record` on this binary sees only traversal) and for comparing two
//! kernels on exactly the rays `scripts/bench-vs-embree.sh` gives Embree.
//!
//! ```sh
//! target/release/oxray bench ogre.obj --export bench-out/rays --runs 1
//! cargo bench -p oxray-cpu --bench ray_sets -- bench-out/rays ogre shadow any 9 1
//! ```
//!
//! Arguments: DIR NAME SET (coherent, incoherent, shadow) QUERY (closest, any) RUNS THREADS.
//! Prints the median and the best Mrays/s (on a shared machine the best is the steadier
//! figure), the hit count (which must not change between kernels) and the
//! kernel used. `OXRAY_CPU_ISA` picks the kernel as everywhere else.

use oxray_core::{BuildOptions, IndexBuffer, Ray, TriangleInput, VertexBuffer};
use oxray_cpu::Gas;
use std::path::Path;
use std::time::Instant;

fn read(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn words(bytes: &[u8]) -> impl Iterator<Item = [u8; 4]> + '_ {
    bytes.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]])
}

fn load_mesh(path: &Path) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let b = read(path);
    let mut w = words(&b);
    let nv = u32::from_le_bytes(w.next().expect("vertex count")) as usize;
    let nt = u32::from_le_bytes(w.next().expect("triangle count")) as usize;
    let f: Vec<f32> = w.by_ref().take(nv * 3).map(f32::from_le_bytes).collect();
    let i: Vec<u32> = w.take(nt * 3).map(u32::from_le_bytes).collect();
    assert_eq!((f.len(), i.len()), (nv * 3, nt * 3), "truncated mesh");
    let v = f.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let t = i.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    (v, t)
}

fn load_rays(path: &Path) -> Vec<Ray> {
    let f: Vec<f32> = words(&read(path)).map(f32::from_le_bytes).collect();
    f.chunks_exact(8)
        .map(|r| {
            Ray::with_interval(
                [r[0], r[1], r[2]].into(),
                [r[4], r[5], r[6]].into(),
                r[3],
                r[7],
            )
        })
        .collect()
}

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| a != "--bench")
        .collect();
    if args.len() < 4 {
        eprintln!("usage: ray_sets DIR NAME SET QUERY [RUNS] [THREADS]");
        return;
    }
    let dir = Path::new(&args[0]);
    let (name, set, query) = (&args[1], &args[2], &args[3]);
    let runs: usize = args.get(4).map_or(9, |s| s.parse().expect("RUNS"));
    let threads: usize = args.get(5).map_or(1, |s| s.parse().expect("THREADS"));
    let (v, t) = load_mesh(&dir.join(format!("{name}.mesh")));
    let rays = load_rays(&dir.join(format!("{name}.{set}.rays")));
    let input = TriangleInput::new(VertexBuffer::f32x3(&v)).indices(IndexBuffer::u32x3(&t));
    let gas = Gas::build(&BuildOptions::default(), &[input.into()]).expect("build");
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool");
    let any = query == "any";
    let mut hits = vec![None; rays.len()];
    let mut blocked = vec![false; rays.len()];
    let mut trace = || {
        let start = Instant::now();
        pool.install(|| {
            if any {
                gas.occluded_batch(&rays, &mut blocked).expect("batch");
            } else {
                gas.intersect_batch(&rays, &mut hits).expect("batch");
            }
        });
        start.elapsed().as_secs_f64()
    };
    trace();
    let mut times: Vec<f64> = (0..runs).map(|_| trace()).collect();
    times.sort_by(f64::total_cmp);
    let count = if any {
        blocked.iter().filter(|&&b| b).count()
    } else {
        hits.iter().flatten().count()
    };
    println!(
        "{name} {set} {query}: {:.3} Mrays/s (median of {runs}; best {:.3}; {threads} thread(s), kernel {:?}), {count} of {} rays hit",
        rays.len() as f64 / times[runs / 2] / 1e6,
        rays.len() as f64 / times[0] / 1e6,
        gas.isa(),
        rays.len()
    );
}
