//! What the built-in curves buy (guide §5.2, §9): for each curve type, a head of hair-like
//! strands traced as built-in curves and as the same strands tessellated into triangle tubes
//! (8 sides, 4 rings per segment: a coarse but common approximation), on every device this
//! machine has (the CPU always, CUDA device 0 where there is one). Camera rays, closest hit
//! through the device-neutral batched query; prints the median Mrays/s of several runs and the
//! ratio curves / triangles.
//!
//! `cargo bench -p oxray --bench curves [strands] [runs]` (numbers depend on the machine and its
//! load: compare the ratios of one run).

use glam::{DVec3, Vec3};
use oxray::{
    BackendKind, BuildOptions, CurveInput, CurveSegment, CurveType, Device, IndexBuffer, Ray,
    TriangleInput, VertexBuffer,
};
use oxray_testkit::rays::camera_rays;
use oxray_testkit::rng::Rng;
use std::time::Instant;

/// Control points per strand.
const POINTS: usize = 8;
/// Tube sides and rings per segment of the tessellation.
const SIDES: usize = 8;
const RINGS: usize = 4;

/// `n` strands of `ty` standing out of the upper half of a unit sphere and bending down: their
/// control points, radii and segment starts (one strand is `POINTS` control points).
fn strands(ty: CurveType, n: usize) -> (Vec<[f32; 3]>, Vec<f32>, Vec<u32>) {
    let mut rng = Rng::new(0x5eed);
    let (mut points, mut radii, mut index) = (Vec::new(), Vec::new(), Vec::new());
    let k = ty.control_points();
    for _ in 0..n {
        let mut normal = rng.dir();
        normal.y = normal.y.abs();
        let first = points.len() as u32;
        let step = 0.25 + 0.1 * rng.range(0.0, 1.0);
        let mut p = normal;
        let mut h = normal;
        for j in 0..POINTS {
            points.push(p.to_array());
            radii.push(0.012 * (1.0 - 0.7 * j as f32 / POINTS as f32));
            h = (h + Vec3::new(0.0, -0.25, 0.0) + rng.vec3(-0.05, 0.05)).normalize();
            p += h * step;
        }
        // Segments of `k` consecutive control points: POINTS - k + 1 per strand.
        for s in 0..=(POINTS - k) {
            index.push(first + s as u32);
        }
    }
    (points, radii, index)
}

/// The segments of a curve input as the build decodes them (for the tessellation).
fn segments(ty: CurveType, points: &[[f32; 3]], radii: &[f32], index: &[u32]) -> Vec<CurveSegment> {
    index
        .iter()
        .map(|&s| {
            let cp: Vec<[f32; 4]> = (0..ty.control_points())
                .map(|k| {
                    let p = points[s as usize + k];
                    [p[0], p[1], p[2], radii[s as usize + k]]
                })
                .collect();
            CurveSegment::new(ty, &cp, 0, None)
        })
        .collect()
}

/// Each segment as a tube of triangles: `RINGS + 1` rings of `SIDES` vertices around the centre
/// line, at the radius. Ribbons become flat strips facing +z (the camera's side).
fn tessellate(segs: &[CurveSegment]) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let (mut v, mut t) = (Vec::new(), Vec::new());
    for s in segs {
        let ribbon = s.curve_type().is_ribbon();
        let sides = if ribbon { 2 } else { SIDES };
        let base = v.len() as u32;
        for r in 0..=RINGS {
            let u = r as f64 / RINGS as f64;
            let (c, rad) = s.eval(u);
            let tan = s.tangent(u).normalize_or(DVec3::X);
            let (e1, e2) = tan.any_orthonormal_pair();
            for k in 0..sides {
                let p = if ribbon {
                    let w = tan.cross(DVec3::Z).normalize_or(e1);
                    c + w * rad * if k == 0 { -1.0 } else { 1.0 }
                } else {
                    let a = std::f64::consts::TAU * k as f64 / sides as f64;
                    c + (e1 * a.cos() + e2 * a.sin()) * rad
                };
                v.push(p.as_vec3().to_array());
            }
        }
        let quads = if ribbon { 1 } else { sides };
        for r in 0..RINGS as u32 {
            for k in 0..quads as u32 {
                let (k1, s) = ((k + 1) % sides as u32, sides as u32);
                let (a, b) = (base + r * s + k, base + r * s + k1);
                let (c, d) = (a + s, b + s);
                t.push([a, b, d]);
                t.push([a, d, c]);
            }
        }
    }
    (v, t)
}

/// Median Mrays/s of `runs` closest-hit batches, and how many rays hit.
fn mrays(device: &Device, gas: &oxray::Gas, rays: &[Ray], runs: usize) -> (f64, usize) {
    let mut hits = vec![None; rays.len()];
    device
        .intersect_closest(&gas.handle(), rays, &mut hits)
        .unwrap();
    let mut rates: Vec<f64> = (0..runs)
        .map(|_| {
            let t = Instant::now();
            device
                .intersect_closest(&gas.handle(), rays, &mut hits)
                .unwrap();
            rays.len() as f64 / t.elapsed().as_secs_f64() / 1e6
        })
        .collect();
    rates.sort_by(f64::total_cmp);
    (rates[runs / 2], hits.iter().flatten().count())
}

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    let n: usize = args.first().and_then(|a| a.parse().ok()).unwrap_or(3000);
    let runs: usize = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(5).max(1);
    let mut devices = vec![Device::cpu()];
    match Device::cuda(0) {
        Ok(d) => devices.push(d),
        Err(e) => println!("CUDA skipped: {e}"),
    }
    println!(
        "{n} strands of {POINTS} control points, 1024x768 camera rays, median of {runs} runs; \
         triangles: {SIDES}-sided tubes, {RINGS} rings per segment"
    );
    println!(
        "| device | type | segments | curves Mrays/s | triangles | tri. Mrays/s | curves / tri. |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|");
    for ty in CurveType::ALL {
        let (points, radii, index) = strands(ty, n);
        let segs = segments(ty, &points, &radii, &index);
        let (tv, tt) = tessellate(&segs);
        let rays = camera_rays(&tv, 1024, 768);
        let (vb, rb) = (
            [bytemuck::cast_slice::<_, u8>(&points)],
            [bytemuck::cast_slice::<_, u8>(&radii)],
        );
        let curve_input = CurveInput::new(
            ty,
            &vb,
            points.len() as u32,
            &rb,
            bytemuck::cast_slice(&index),
            index.len() as u32,
        );
        let tri_input =
            TriangleInput::new(VertexBuffer::f32x3(&tv)).indices(IndexBuffer::u32x3(&tt));
        for device in &devices {
            let name = if device.kind() == BackendKind::Cuda {
                "cuda"
            } else {
                "cpu"
            };
            let options = BuildOptions::default();
            let curves = device.build_gas(&options, &[curve_input.into()]).unwrap();
            let tris = device.build_gas(&options, &[tri_input.into()]).unwrap();
            let (c, ch) = mrays(device, &curves, &rays, runs);
            let (t, th) = mrays(device, &tris, &rays, runs);
            println!(
                "| {name} | {ty} | {} | {c:.2} | {} | {t:.1} | {:.3} |",
                segs.len(),
                tt.len(),
                c / t
            );
            // Both cover the same pixels, up to the tessellation's error at silhouettes.
            assert!(
                ch > 0 && th > 0,
                "{ty}: {ch} curve hits, {th} triangle hits"
            );
        }
    }
}
