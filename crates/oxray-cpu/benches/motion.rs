//! What motion costs in traversal (guide §5.10.2): the same mesh traced as a static GAS and as
//! GASes with two motion keys — motionless (both keys equal: the cost of interpolating every
//! block tested), small motion (a translation of 2 % of the mesh's size) and large motion (half
//! its size, where the tree's boxes, the union over both keys, grow) — with camera rays at
//! random times and with incoherent rays. Prints Mrays/s and the ratio to the static GAS. The
//! large motion is traced with the structure's time parts (`oxray_bvh::MotionSegments`, built
//! in) and without them (one tree over the union boxes), and against separate GASes per time
//! segment, each with its own tree (the upper bound of splitting the time range).
//!
//! `cargo bench -p oxray-cpu --bench motion` (numbers depend on the machine and its load: compare
//! the ratios of one run).

use glam::Vec3;
use oxray_core::{BuildOptions, IndexBuffer, MotionOptions, Ray, TriangleInput, VertexBuffer};
use oxray_cpu::Gas;
use oxray_testkit::mesh::{find_mesh, icosphere_f32, load_obj, Mesh};
use oxray_testkit::rays::{camera_rays, hemisphere_rays};
use oxray_testkit::rng::Rng;
use std::time::Instant;

fn mesh() -> (String, Mesh) {
    if let Some(m) = find_mesh("stanford-bunny.obj").and_then(|p| load_obj(&p).ok()) {
        return ("bunny".into(), m);
    }
    ("icosphere(6)".into(), icosphere_f32(6))
}

fn build(m: &Mesh, later: Option<&[[f32; 3]]>) -> Gas {
    let input = TriangleInput::new(VertexBuffer::f32x3(&m.positions))
        .indices(IndexBuffer::u32x3(&m.triangles));
    match later {
        None => Gas::build(&BuildOptions::default(), &[input.into()]).unwrap(),
        Some(k1) => {
            let keys = [VertexBuffer::f32x3(k1)];
            let options = BuildOptions::default().with_motion(MotionOptions::new(2, 0.0, 1.0));
            Gas::build(&options, &[input.motion_vertices(&keys).into()]).unwrap()
        }
    }
}

fn mrays(gas: &Gas, rays: &[Ray], runs: usize) -> f64 {
    let mut hits = vec![None; rays.len()];
    gas.intersect_batch(rays, &mut hits).unwrap();
    let mut times: Vec<f64> = (0..runs)
        .map(|_| {
            let t = Instant::now();
            gas.intersect_batch(rays, &mut hits).unwrap();
            t.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    rays.len() as f64 / times[runs / 2] / 1e6
}

fn main() {
    let (name, m) = mesh();
    let (lo, hi) = oxray_testkit::mesh::bounds(&m.positions);
    let size = (Vec3::from(hi) - Vec3::from(lo)).max_element();
    let mut rng = Rng::new(7);
    let timed = |rays: Vec<Ray>, rng: &mut Rng| -> Vec<Ray> {
        rays.into_iter().map(|r| r.with_time(rng.f32())).collect()
    };
    let camera = timed(camera_rays(&m.positions, 512, 512), &mut rng);
    let diffuse = timed(
        hemisphere_rays(&m.positions, &m.triangles, 512 * 512, 11),
        &mut rng,
    );
    let shifted = |d: f32| -> Vec<[f32; 3]> {
        m.positions
            .iter()
            .map(|p| [p[0] + d * size, p[1], p[2]])
            .collect()
    };
    let cases: [(&str, Option<Vec<[f32; 3]>>); 5] = [
        ("static", None),
        ("motionless 2 keys", Some(shifted(0.0))),
        ("small motion (2 %)", Some(shifted(0.02))),
        ("large motion (50 %)", Some(shifted(0.5))),
        // The same GAS with its time parts removed: rays at every time walk one tree.
        ("large, one tree", Some(shifted(0.5))),
    ];
    println!(
        "{name}: {} triangles, {} threads; Mrays/s (ratio to static)",
        m.triangles.len(),
        rayon::current_num_threads()
    );
    println!("{:<22} {:>18} {:>18} {:>10}", "", "camera", "diffuse", "MB");
    let mut base = (0.0, 0.0);
    for (label, later) in cases {
        let mut gas = build(&m, later.as_deref());
        if label == "large, one tree" {
            let mut data = gas.data().clone();
            if let Some(m) = &mut data.motion {
                m.segments = None;
            }
            gas = Gas::from_data_with_isa(data, gas.isa());
        }
        let (c, d) = (mrays(&gas, &camera, 7), mrays(&gas, &diffuse, 7));
        if later.is_none() {
            base = (c, d);
        }
        println!(
            "{label:<22} {c:>10.2} ({:>4.2}) {d:>10.2} ({:>4.2}) {:>10.2}",
            c / base.0,
            d / base.1,
            gas.data().memory().output_bytes as f64 / 1e6
        );
    }
    // Whether splitting the time range pays (guide §5.10.2 leaves the motion BVH to the
    // implementation): the large motion's shutter cut into `n` segments, each a GAS of two keys
    // (the positions at its ends: the same triangles at every time, up to rounding) whose tree
    // bounds only that segment's motion; each ray traced by the GAS of its time. The rays are
    // sorted into their segments beforehand (a traversal would pick the segment's root per
    // ray at no cost), so the timing is the traversal's.
    let k1 = shifted(0.5);
    for n in [2usize, 4, 8] {
        let segments: Vec<Gas> = (0..n)
            .map(|s| {
                let at = |t: f32| -> Vec<[f32; 3]> {
                    m.positions
                        .iter()
                        .zip(&k1)
                        .map(|(a, b)| std::array::from_fn(|i| a[i] + (b[i] - a[i]) * t))
                        .collect()
                };
                let (t0, t1) = (s as f32 / n as f32, (s + 1) as f32 / n as f32);
                let (a, b) = (at(t0), at(t1));
                let input = TriangleInput::new(VertexBuffer::f32x3(&a))
                    .indices(IndexBuffer::u32x3(&m.triangles));
                let keys = [VertexBuffer::f32x3(&b)];
                let options = BuildOptions::default().with_motion(MotionOptions::new(2, t0, t1));
                Gas::build(&options, &[input.motion_vertices(&keys).into()]).unwrap()
            })
            .collect();
        let split = |rays: &[Ray]| -> Vec<Vec<Ray>> {
            let mut out = vec![Vec::new(); n];
            for r in rays {
                out[((r.time * n as f32) as usize).min(n - 1)].push(*r);
            }
            out
        };
        let mrays_split = |groups: &[Vec<Ray>], runs: usize| -> f64 {
            let total: usize = groups.iter().map(Vec::len).sum();
            let mut hits: Vec<Vec<Option<oxray_core::Hit>>> =
                groups.iter().map(|g| vec![None; g.len()]).collect();
            let mut times: Vec<f64> = (0..runs + 1)
                .map(|_| {
                    let t = Instant::now();
                    for ((gas, g), h) in segments.iter().zip(groups).zip(&mut hits) {
                        gas.intersect_batch(g, h).unwrap();
                    }
                    t.elapsed().as_secs_f64()
                })
                .skip(1)
                .collect();
            times.sort_by(f64::total_cmp);
            total as f64 / times[runs / 2] / 1e6
        };
        let (c, d) = (
            mrays_split(&split(&camera), 7),
            mrays_split(&split(&diffuse), 7),
        );
        let label = format!("large, {n} time segments");
        println!(
            "{label:<22} {c:>10.2} ({:>4.2}) {d:>10.2} ({:>4.2})",
            c / base.0,
            d / base.1
        );
    }
}
