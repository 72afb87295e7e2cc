//! `oxray bench --simulation`: the simulation queries (closest point, signed distance, every
//! hit along a ray, hit counts) as batches on the CPU and, with `--backend cuda`, on the GPU,
//! with their agreement. Points are uniform in the mesh's box grown by 10 %; rays start on a
//! sphere around the mesh and aim at uniform points of its box (the inputs of
//! `scripts/bench_simulation_queries.py`, which measures the CPU against Open3D).

use crate::bench::{build_gas_on, median};
use crate::device::DeviceCommandError;
use glam::Vec3;
use oxray::{AllHits, BuildFlags, ClosestPoint, Device, Gas, Ray};
use oxray_scene::mesh::Mesh;
use oxray_testkit::rng::Rng;
use std::time::Instant;

/// The table's header.
pub const HEADER: &str = "| mesh | tris | query | queries | CPU Mq/s | device Mq/s | device / CPU | same results |\n|---|---:|---|---:|---:|---:|---:|---:|";

/// Most hits listed per ray by the all-hits row.
pub const MAX_HITS: usize = 64;

/// The query points and rays for `mesh` (seed 19).
pub fn inputs(mesh: &Mesh, n: usize) -> (Vec<Vec3>, Vec<Ray>) {
    let (lo, hi) = mesh.positions.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(Vec3::from(*p)), hi.max(Vec3::from(*p))),
    );
    let (c, half) = ((lo + hi) * 0.5, (hi - lo) * 0.5);
    let mut rng = Rng::new(19);
    let mut in_box = |grow: f32| {
        c + half
            * grow
            * Vec3::new(
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
            )
    };
    let points = (0..n).map(|_| in_box(1.1)).collect();
    let radius = half.length() * 2.0;
    let mut rng = Rng::new(20);
    let rays = (0..n)
        .map(|_| {
            let o = c + rng.unit() * radius;
            let t = c + half
                * Vec3::new(
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 1.0),
                    rng.range(-1.0, 1.0),
                );
            Ray::new(o, t - o)
        })
        .collect();
    (points, rays)
}

/// The results of one device, for the agreement column.
#[derive(Default)]
struct Results {
    closest: Vec<Option<ClosestPoint>>,
    signed: Vec<f32>,
    lists: AllHits,
    counts: Vec<u32>,
}

/// Median seconds of `runs` runs of `f` (after one warm-up).
fn time(
    runs: usize,
    mut f: impl FnMut() -> Result<(), oxray::SurfaceQueryError>,
) -> Result<f64, DeviceCommandError> {
    let mut secs = Vec::with_capacity(runs);
    for k in 0..=runs {
        let t = Instant::now();
        f().map_err(|e| DeviceCommandError::Pipeline(format!("simulation query: {e}")))?;
        if k > 0 {
            secs.push(t.elapsed().as_secs_f64());
        }
    }
    Ok(median(secs))
}

/// Runs the four batches on `gas`, `runs` times each; their median seconds and last results.
fn measure(
    gas: &Gas,
    points: &[Vec3],
    rays: &[Ray],
    runs: usize,
) -> Result<([f64; 4], Results), DeviceCommandError> {
    let mut r = Results {
        closest: vec![None; points.len()],
        signed: vec![0.0; points.len()],
        counts: vec![0; rays.len()],
        ..Default::default()
    };
    let secs = [
        time(runs, || gas.closest_point_batch(points, &mut r.closest))?,
        time(runs, || gas.signed_distance_batch(points, &mut r.signed))?,
        time(runs, || gas.all_hits_batch(rays, MAX_HITS, &mut r.lists))?,
        time(runs, || gas.count_hits_batch(rays, &mut r.counts))?,
    ];
    Ok((secs, r))
}

/// The table rows of one mesh: the CPU, and `device` beside it (or the CPU alone).
pub fn bench(
    device: Option<&Device>,
    name: &str,
    mesh: &Mesh,
    n: usize,
    runs: usize,
) -> Result<Vec<String>, DeviceCommandError> {
    let (points, rays) = inputs(mesh, n);
    let cpu_gas = build_gas_on(&Device::cpu(), mesh, BuildFlags::empty())?;
    let (cpu_secs, cpu) = measure(&cpu_gas, &points, &rays, runs)?;
    let other = match device {
        Some(d) => {
            let gas = build_gas_on(d, mesh, BuildFlags::empty())?;
            Some(measure(&gas, &points, &rays, runs)?)
        }
        None => None,
    };
    let agree = |q: usize, r: &Results| -> f64 {
        let same = match q {
            0 => cpu
                .closest
                .iter()
                .zip(&r.closest)
                .filter(|(a, b)| a == b)
                .count(),
            1 => cpu
                .signed
                .iter()
                .zip(&r.signed)
                .filter(|(a, b)| a.to_bits() == b.to_bits())
                .count(),
            2 => (0..rays.len())
                .filter(|&i| {
                    cpu.lists.hits(i) == r.lists.hits(i)
                        && cpu.lists.is_complete(i) == r.lists.is_complete(i)
                })
                .count(),
            _ => cpu
                .counts
                .iter()
                .zip(&r.counts)
                .filter(|(a, b)| a == b)
                .count(),
        };
        100.0 * same as f64 / n.max(1) as f64
    };
    let queries = [
        "closest point",
        "signed distance",
        "all hits (<= 64)",
        "hit counts",
    ];
    Ok(queries
        .iter()
        .enumerate()
        .map(|(q, label)| {
            let cpu_rate = n as f64 / cpu_secs[q] / 1e6;
            match &other {
                Some((secs, r)) => {
                    let rate = n as f64 / secs[q] / 1e6;
                    format!(
                        "| {name} | {} | {label} | {n} | {cpu_rate:.3} | {rate:.3} | {:.1}x | {:.2} % |",
                        mesh.triangles.len(),
                        rate / cpu_rate,
                        agree(q, r)
                    )
                }
                None => format!(
                    "| {name} | {} | {label} | {n} | {cpu_rate:.3} | - | - | - |",
                    mesh.triangles.len()
                ),
            }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_has_a_row_per_query_and_the_cpu_agrees_with_itself() {
        let mesh = Mesh::icosphere(2);
        let rows = bench(Some(&Device::cpu()), "ico", &mesh, 300, 1).unwrap();
        assert_eq!(rows.len(), 4);
        for row in &rows {
            assert!(row.ends_with("| 100.00 % |"), "{row}");
            assert_eq!(
                row.matches('|').count(),
                HEADER.lines().next().unwrap().matches('|').count()
            );
        }
        let (points, rays) = inputs(&mesh, 50);
        assert!(points.iter().all(|p| p.abs().max_element() < 1.2));
        assert!(rays.iter().all(|r| r.validate().is_ok()));
    }
}
