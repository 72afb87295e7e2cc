//! The closest point through an IAS (`Ias::closest_point_batch`) as instances grow: a grid of
//! `N` tetrahedra (one GAS, translated), 20,000 points spread over the grid's box, median
//! seconds of `RUNS` batches after a warm-up, on all threads.
//!
//! ```text
//! cargo bench -p oxray-cpu --bench instanced_points -- RUNS N [N ...]
//! ```

use glam::Vec3;
use oxray_core::{BuildOptions, Instance, Transform};
use oxray_cpu::{Gas, Ias};
use std::time::Instant;

fn main() {
    // `cargo bench` passes `--bench`; the numbers are ours.
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let (runs, counts) = match args.split_first() {
        Some((&runs, counts)) if !counts.is_empty() => (runs.max(1), counts.to_vec()),
        _ => (5, vec![1_000, 10_000, 100_000]),
    };
    let v = [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
    ];
    let gas = std::sync::Arc::new(
        Gas::from_mesh(&v, &[[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]).expect("a tetrahedron"),
    );
    println!("| instances | points | median s (min-max) | Mpoints/s |");
    println!("|---:|---:|---:|---:|");
    for n in counts {
        let side = (n as f32).cbrt().ceil() as usize;
        let instances: Vec<Instance> = (0..n)
            .map(|i| {
                let p = Vec3::new(
                    (i % side) as f32,
                    ((i / side) % side) as f32,
                    (i / side / side) as f32,
                ) * 3.0;
                Instance::new(gas.clone().into())
                    .transform(Transform::from_translation(p))
                    .instance_id(i as u32)
            })
            .collect();
        let ias = Ias::build(&BuildOptions::default(), &[(&instances[..]).into()])
            .expect("the instances build");
        let extent = side as f32 * 3.0;
        let points: Vec<Vec3> = (0..20_000u64)
            .map(|i| {
                Vec3::new(
                    (i * 7919 % 1000) as f32,
                    (i * 104_729 % 1000) as f32,
                    (i * 1_299_709 % 1000) as f32,
                ) * (extent / 1000.0)
            })
            .collect();
        let mut out = vec![None; points.len()];
        let mut secs = Vec::with_capacity(runs);
        for k in 0..=runs {
            let t = Instant::now();
            ias.closest_point_batch(&points, &mut out)
                .expect("finite points");
            if k > 0 {
                secs.push(t.elapsed().as_secs_f64());
            }
        }
        secs.sort_by(f64::total_cmp);
        let median = secs[secs.len() / 2];
        println!(
            "| {n} | {} | {median:.4} ({:.4}-{:.4}) | {:.2} |",
            points.len(),
            secs[0],
            secs[secs.len() - 1],
            points.len() as f64 / median / 1e6
        );
    }
}
