//! The binned builder's cost per primitive and per level of the tree (`log2(n / 4)` levels) on
//! random boxes, one thread, from 1,024 to 524,288 primitives: flat where the work is in the
//! binning and partitioning, rising where memory or per-node overheads take over.
//!
//! ```sh
//! cargo run --release -p oxray-bvh --example scaling
//! ```

use glam::Vec3;
use oxray_bvh::{build_bvh2, BuildConfig};
use oxray_core::Aabb;
use std::time::Instant;
fn main() {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    pool.install(|| {
        let mut s = 1u64;
        let mut r = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        for n in [1usize << 10, 1 << 13, 1 << 16, 1 << 19] {
            let boxes: Vec<Aabb> = (0..n)
                .map(|_| {
                    let p = Vec3::new(r(), r(), r());
                    Aabb::new(p, p + Vec3::splat(0.01))
                })
                .collect();
            let reps = (1usize << 20) / n;
            let mut best = f64::MAX;
            for _ in 0..3 {
                let t = Instant::now();
                for _ in 0..reps {
                    std::hint::black_box(build_bvh2(&boxes, &BuildConfig::BALANCED));
                }
                best = best.min(t.elapsed().as_secs_f64() / reps as f64);
            }
            let levels = (n as f64 / 4.0).log2();
            println!(
                "n {n:7}: {:8.3} ms, {:6.1} ns per prim, {:5.1} ns per prim-level",
                best * 1e3,
                best * 1e9 / n as f64,
                best * 1e9 / n as f64 / levels
            );
        }
    });
}
