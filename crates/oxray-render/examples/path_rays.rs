//! The built-in Cornell box traced by a minimal path tracer written straight over the query API
//! (`Gas::intersect`, `Gas::occluded`): Lambertian surfaces, one light sample a vertex with
//! MIS, Russian roulette from the third vertex, at most 8 vertices, the renderer's estimator
//! without its programs, pipeline, textures or sampler. What it is for (docs/BENCHMARKS.md,
//! "The Cornell box's own rays"):
//!
//! - its rate is a plain single-ray loop's: compare its M samples/s with `oxray render
//!   --sampler independent` at the same size, spp and threads (the renderer went through the
//!   pipeline, 1.30x slower than this loop; its wavefront now renders 1.2-1.3x faster than it);
//! - `--export DIR` writes the mesh and the first 262,144 camera, bounce and shadow rays of
//!   the paths (traced on one thread, in pixel order) as `DIR/pt.mesh`, `pt.coherent.rays`,
//!   `pt.incoherent.rays` and `pt.shadow.rays`, the files `oxray bench --export` writes, so that
//!   `scripts/embree3_bench.c` and the `ray_sets` benchmark trace the rays a renderer traces;
//! - `--count FILE` prints, for the rays of FILE, how many leaves and triangles of the built
//!   tree their whole segment enters, against a tree with one leaf per quad;
//! - `--tree` prints the built tree's nodes and leaves (count and box).
//!
//! ```text
//! cargo run --release -p oxray-render --example path_rays -- 32
//! cargo run --release -p oxray-render --example path_rays -- 8 --export bench-out/rays
//! cargo run --release -p oxray-render --example path_rays -- 1 --count bench-out/rays/pt.shadow.rays
//! ```

use oxray::glam::{Mat4, Vec3};
use oxray::{
    Aabb, BuildFlags, BuildOptions, IndexBuffer, Ray, RayRecord, TriangleInput, VertexBuffer,
};
use oxray_render::bsdf::Rng;
use oxray_render::programs::CameraFrame;
use oxray_render::{camera_frame, RenderOptions};
use std::f32::consts::{FRAC_1_PI, PI};
use std::time::Instant;

/// Rays a set of the export, as `oxray bench --export` writes.
const EXPORTED: usize = 262_144;

/// The image's width and height.
const SIDE: u32 = 256;

/// The box's triangles in world space, with each one's material.
struct Scene {
    positions: Vec<[f32; 3]>,
    triangles: Vec<[u32; 3]>,
    material: Vec<u32>,
    albedo: Vec<Vec3>,
    emission: Vec<Vec3>,
    lights: Vec<usize>,
    light_areas: Vec<f32>,
    light_area: f32,
    camera: CameraFrame,
}

/// The corners of triangle `i`.
fn corners(positions: &[[f32; 3]], triangles: &[[u32; 3]], i: usize) -> (Vec3, Vec3, Vec3) {
    let [a, b, c] = triangles[i].map(|v| Vec3::from(positions[v as usize]));
    (a, b, c)
}

impl Scene {
    /// The built-in box at `side` x `side` pixels, seen by the renderer's camera.
    fn cornell(side: u32) -> Scene {
        let desc = oxray_scene::cornell_box();
        let (mut positions, mut triangles, mut material) = (Vec::new(), Vec::new(), Vec::new());
        for inst in &desc.instances {
            let xf: Mat4 = inst.transform;
            for p in &desc.meshes[inst.mesh as usize].primitives {
                let base = positions.len() as u32;
                positions.extend(
                    p.positions
                        .iter()
                        .map(|q| xf.transform_point3(Vec3::from(*q)).to_array()),
                );
                for t in &p.triangles {
                    triangles.push(t.map(|i| i + base));
                    material.push(p.material);
                }
            }
        }
        let albedo = desc
            .materials
            .iter()
            .map(|m| Vec3::from_slice(&m.base_color[..3]))
            .collect();
        let emission: Vec<Vec3> = desc
            .materials
            .iter()
            .map(|m| Vec3::from(m.emissive))
            .collect();
        let lights: Vec<usize> = (0..triangles.len())
            .filter(|&i| emission[material[i] as usize] != Vec3::ZERO)
            .collect();
        let light_areas: Vec<f32> = lights
            .iter()
            .map(|&i| {
                let (a, b, c) = corners(&positions, &triangles, i);
                0.5 * (b - a).cross(c - a).length()
            })
            .collect();
        let opts = RenderOptions {
            width: side,
            height: side,
            ..Default::default()
        };
        Scene {
            light_area: light_areas.iter().sum(),
            camera: camera_frame(&desc, &opts).expect("the box's camera"),
            positions,
            triangles,
            material,
            albedo,
            emission,
            lights,
            light_areas,
        }
    }

    fn corners(&self, i: usize) -> (Vec3, Vec3, Vec3) {
        corners(&self.positions, &self.triangles, i)
    }

    fn gas_data(&self) -> oxray::bvh::GasData {
        let input = TriangleInput::new(VertexBuffer::f32x3(&self.positions))
            .indices(IndexBuffer::u32x3(&self.triangles));
        oxray::bvh::GasData::build(
            &BuildOptions::new(BuildFlags::PREFER_FAST_TRACE),
            &[input.into()],
        )
        .expect("the Cornell box builds")
    }
}

/// One path's radiance and its ray count; `record` sees each ray traced, with its set (0:
/// camera, 1: bounce, 2: shadow).
fn path(
    s: &Scene,
    gas: &oxray::cpu::Gas,
    rng: &mut Rng,
    x: u32,
    y: u32,
    mut record: impl FnMut(usize, &Ray),
) -> (Vec3, u64) {
    let power = |a: f32, b: f32| (a * a) / (a * a + b * b);
    let c = &s.camera;
    let sx = 2.0 * (x as f32 + rng.uniform()) / SIDE as f32 - 1.0;
    let sy = 1.0 - 2.0 * (y as f32 + rng.uniform()) / SIDE as f32;
    let mut ray = Ray::new(c.origin, (c.forward + c.right * sx + c.up * sy).normalize());
    let (mut throughput, mut radiance, mut bsdf_pdf, mut rays) = (Vec3::ONE, Vec3::ZERO, 0.0, 0);
    for depth in 0..8 {
        rays += 1;
        record(usize::from(depth > 0), &ray);
        let Some(hit) = gas.intersect(&ray) else {
            break;
        };
        let i = hit.primitive_index as usize;
        let (a, b, c) = s.corners(i);
        let mut n = (b - a).cross(c - a).normalize();
        let wo = -ray.direction;
        let front = n.dot(wo) > 0.0;
        let m = s.material[i] as usize;
        if s.emission[m] != Vec3::ZERO && front {
            let w = if bsdf_pdf > 0.0 {
                let cos = n.dot(wo).abs().max(1e-6);
                power(bsdf_pdf, hit.t * hit.t / (cos * s.light_area))
            } else {
                1.0
            };
            radiance += throughput * s.emission[m] * w;
        }
        if !front {
            n = -n;
        }
        let p = ray.origin + ray.direction * hit.t;
        let f = s.albedo[m] * FRAC_1_PI;
        // One light sample: a light triangle by area, a point on it.
        let mut u = rng.uniform() * s.light_area;
        let mut k = 0;
        while k + 1 < s.lights.len() && u >= s.light_areas[k] {
            u -= s.light_areas[k];
            k += 1;
        }
        let (la, lb, lc) = s.corners(s.lights[k]);
        let (mut u1, mut u2) = (rng.uniform(), rng.uniform());
        if u1 + u2 > 1.0 {
            (u1, u2) = (1.0 - u1, 1.0 - u2);
        }
        let from = p + n * 1e-4;
        let to = la + (lb - la) * u1 + (lc - la) * u2 - from;
        let d = to.length();
        let wi = to / d;
        let cos_l = -(lb - la).cross(lc - la).normalize().dot(wi);
        let cos_s = n.dot(wi);
        if cos_l > 1e-6 && cos_s > 0.0 {
            rays += 1;
            let shadow = Ray::with_interval(from, wi, 0.0, d * (1.0 - 1e-4));
            record(2, &shadow);
            if !gas.occluded(&shadow) {
                let light_pdf = d * d / (cos_l * s.light_area);
                let le = s.emission[s.material[s.lights[k]] as usize];
                radiance +=
                    throughput * f * le * cos_s * power(light_pdf, cos_s * FRAC_1_PI) / light_pdf;
            }
        }
        // A cosine-weighted bounce.
        let (r1, r2) = (rng.uniform(), rng.uniform());
        let (phi, r) = (2.0 * PI * r1, r2.sqrt());
        let (t, bt) = n.any_orthonormal_pair();
        let wi = (t * (r * phi.cos()) + bt * (r * phi.sin()) + n * (1.0 - r2).max(0.0).sqrt())
            .normalize();
        throughput *= s.albedo[m];
        bsdf_pdf = n.dot(wi).max(1e-6) * FRAC_1_PI;
        ray = Ray::new(from, wi);
        if depth >= 2 {
            let q = throughput.max_element().clamp(0.05, 1.0);
            if rng.uniform() >= q {
                break;
            }
            throughput /= q;
        }
    }
    (radiance, rays)
}

/// Row `y`'s paths, `spp` a pixel: their summed radiance and their ray count.
fn row(
    scene: &Scene,
    gas: &oxray::cpu::Gas,
    y: u32,
    spp: u32,
    mut record: impl FnMut(usize, &Ray),
) -> (Vec3, u64) {
    let (mut sum, mut rays) = (Vec3::ZERO, 0u64);
    for x in 0..SIDE {
        for s in 0..spp {
            let mut rng = Rng::new(y * SIDE + x, s, 0x7061_7468);
            let (l, n) = path(scene, gas, &mut rng, x, y, &mut record);
            sum += l;
            rays += n;
        }
    }
    (sum, rays)
}

/// Leaves and triangles of `data`'s tree whose boxes the segment of `r` enters.
fn entered(data: &oxray::bvh::GasData, r: &RayRecord) -> (u64, u64) {
    let (mut leaves, mut triangles) = (0, 0);
    let mut stack = vec![0usize];
    while let Some(n) = stack.pop() {
        let node = &data.bvh.nodes[n];
        for lane in 0..4 {
            if !node.is_used(lane) || !segment_enters(&node.child_bounds(lane), r) {
                continue;
            }
            match node.count[lane] {
                0 => stack.push(node.child[lane] as usize),
                count => {
                    leaves += 1;
                    triangles += u64::from(count);
                }
            }
        }
    }
    (leaves, triangles)
}

fn segment_enters(b: &Aabb, r: &RayRecord) -> bool {
    let (mut t0, mut t1) = (r.tmin, r.tmax);
    for a in 0..3 {
        if r.direction[a] == 0.0 {
            if r.origin[a] < b.min[a] || r.origin[a] > b.max[a] {
                return false;
            }
            continue;
        }
        let inv = 1.0 / r.direction[a];
        let (n, f) = (
            (b.min[a] - r.origin[a]) * inv,
            (b.max[a] - r.origin[a]) * inv,
        );
        t0 = t0.max(n.min(f));
        t1 = t1.min(n.max(f));
    }
    t0 <= t1
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let spp: u32 = args.first().map_or(Ok(16), |s| s.parse())?;
    let option = |name: &str| {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1))
            .map(std::path::PathBuf::from)
    };
    let scene = Scene::cornell(SIDE);
    let data = scene.gas_data();
    if args.iter().any(|a| a == "--tree") {
        for (n, node) in data.bvh.nodes.iter().enumerate() {
            for lane in (0..4).filter(|&l| node.is_used(l)) {
                let b = node.child_bounds(lane);
                match node.count[lane] {
                    0 => println!("node {n}.{lane}: node {}", node.child[lane]),
                    c => println!("node {n}.{lane}: leaf of {c} {:.3?}-{:.3?}", b.min, b.max),
                }
            }
        }
        return Ok(());
    }
    if let Some(file) = option("--count") {
        let bytes = std::fs::read(&file)?;
        let rays: &[RayRecord] = oxray::bytemuck::try_cast_slice(&bytes)
            .map_err(|e| format!("{}: not a ray file ({e})", file.display()))?;
        let (mut leaves, mut triangles, mut quads) = (0, 0, 0);
        let quad_boxes: Vec<Aabb> = (0..scene.triangles.len() / 2)
            .map(|q| {
                let mut b = Aabb::EMPTY;
                for t in [2 * q, 2 * q + 1] {
                    let (a, bb, c) = scene.corners(t);
                    [a, bb, c].into_iter().for_each(|p| b.grow(p));
                }
                b
            })
            .collect();
        for r in rays {
            let (l, t) = entered(&data, r);
            leaves += l;
            triangles += t;
            quads += quad_boxes.iter().filter(|b| segment_enters(b, r)).count() as u64;
        }
        let n = rays.len().max(1) as f64;
        println!(
            "{} rays: the tree's leaves entered {:.2}, their triangles {:.2}; with one leaf a quad: {:.2} leaves, {:.2} triangles",
            rays.len(),
            leaves as f64 / n,
            triangles as f64 / n,
            quads as f64 / n,
            2.0 * quads as f64 / n
        );
        return Ok(());
    }
    let export = option("--export");
    let gas = oxray::cpu::Gas::from(data);
    let start = Instant::now();
    let mut sets: [Vec<RayRecord>; 3] = Default::default();
    // The export keeps the paths' order: one thread.
    let rows: Vec<(Vec3, u64)> = if export.is_some() {
        (0..SIDE)
            .map(|y| {
                row(&scene, &gas, y, spp, |k, r| {
                    sets[k].push(RayRecord::from(*r))
                })
            })
            .collect()
    } else {
        use rayon::prelude::*;
        (0..SIDE)
            .into_par_iter()
            .map(|y| row(&scene, &gas, y, spp, |_, _| {}))
            .collect()
    };
    let secs = start.elapsed().as_secs_f64();
    let side = SIDE;
    let samples = f64::from(side * side * spp);
    let rays: u64 = rows.iter().map(|r| r.1).sum();
    let mean = rows.iter().map(|r| r.0).sum::<Vec3>() / samples as f32;
    println!(
        "{side}x{side}, {spp} spp: {secs:.3} s, {:.2} M samples/s, {:.2} rays a sample, mean radiance {mean:?}",
        samples / secs / 1e6,
        rays as f64 / samples
    );
    if let Some(dir) = export {
        let n = sets.iter().map(Vec::len).min().unwrap_or(0).min(EXPORTED);
        std::fs::create_dir_all(&dir)?;
        let mut mesh = Vec::new();
        mesh.extend((scene.positions.len() as u32).to_le_bytes());
        mesh.extend((scene.triangles.len() as u32).to_le_bytes());
        mesh.extend_from_slice(oxray::bytemuck::cast_slice(&scene.positions));
        mesh.extend_from_slice(oxray::bytemuck::cast_slice(&scene.triangles));
        write_new(&dir.join("pt.mesh"), &mesh)?;
        for (set, name) in sets.iter().zip(["coherent", "incoherent", "shadow"]) {
            let bytes: &[u8] = oxray::bytemuck::cast_slice(&set[..n]);
            write_new(&dir.join(format!("pt.{name}.rays")), bytes)?;
        }
        println!("wrote {n} rays a set to {}", dir.display());
    }
    Ok(())
}

/// Writes `bytes` to `path` through a temporary file renamed into place.
fn write_new(path: &std::path::Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path)
}
