//! Built-in spheres (guide §5.3, §9.4): a point cloud of random spheres rendered on the CPU,
//! shaded in the closest-hit program from `sphere_data()` (`optixGetSphereData`); then the same
//! spheres as custom primitives with an intersection program (the path of the
//! `custom_sphere` example), to measure what the built-in buys: build time and camera rays per
//! second for both.
//!
//! `cargo run --release -p oxray --example spheres [count] [out.png]`

mod common;

use glam::Vec3;
use oxray::cpu::Gas;
use oxray::{
    Aabb, AabbBuffer, BuildOptions, CustomPrimitiveInput, DeviceContext, HitGroupDesc, Module,
    OutputBuffer, Pipeline, PipelineCompileOptions, PipelineLinkOptions, PrimitiveTypeFlags,
    ProgramGroup, SbtRegion, ShaderBindingTable, SphereInput, TraceRay, TraversableHandle,
};
use std::sync::Arc;
use std::time::Instant;

/// Launch parameters.
#[derive(Clone)]
pub struct Params {
    pub image: Arc<OutputBuffer<[u8; 4]>>,
    pub handle: TraversableHandle,
    /// The spheres `(x, y, z, r)`, read by the custom path's programs (the built-in path reads
    /// them from the structure).
    pub spheres: Arc<Vec<[f32; 4]>>,
}

/// `n` spheres in a ball of radius 10, radii 0.02 to 0.1, from a fixed seed.
pub fn cloud(n: usize) -> Vec<[f32; 4]> {
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = move || {
        // SplitMix64: deterministic on every platform.
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    };
    let mut out = Vec::with_capacity(n);
    while out.len() < n {
        let p = Vec3::new(next(), next(), next()) * 2.0 - 1.0;
        let r = 0.02 + 0.08 * next();
        if p.length() <= 1.0 {
            out.push([p.x * 10.0, p.y * 10.0, p.z * 10.0, r]);
        }
    }
    out
}

/// Which intersector the spheres go through.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Path {
    /// Built-in spheres (`SphereInput`).
    BuiltIn,
    /// Custom primitives with an intersection program.
    Custom,
}

/// Build milliseconds, launch seconds and the pixels of one render.
pub struct Run {
    pub build_ms: f64,
    pub launch_s: f64,
    pub pixels: Vec<[u8; 4]>,
}

/// Lambert shading of the hit sphere's normal under one light, with a little ambient.
fn shade(p: Vec3, s: [f32; 4]) -> [f32; 3] {
    let n = (p - Vec3::new(s[0], s[1], s[2])) / s[3];
    let l = Vec3::new(-0.4, 0.8, -0.45).normalize();
    let k = 0.1 + 0.9 * n.dot(l).max(0.0);
    let albedo = 0.5 + 0.5 * n;
    (albedo * k).to_array()
}

/// Renders the spheres through `path`; `w` x `h` camera rays.
pub fn render_with(
    spheres: &[[f32; 4]],
    path: Path,
    w: u32,
    h: u32,
) -> Result<Run, Box<dyn std::error::Error>> {
    let start = Instant::now();
    let gas = match path {
        Path::BuiltIn => {
            let centres: Vec<[f32; 3]> = spheres.iter().map(|s| [s[0], s[1], s[2]]).collect();
            let radii: Vec<f32> = spheres.iter().map(|s| s[3]).collect();
            let c = [bytemuck::cast_slice::<_, u8>(&centres)];
            let r = [bytemuck::cast_slice::<_, u8>(&radii)];
            let input = SphereInput::new(&c, spheres.len() as u32, &r);
            Gas::build(&BuildOptions::default(), &[input.into()])?
        }
        Path::Custom => {
            let boxes: Vec<Aabb> = spheres
                .iter()
                .map(|s| {
                    let c = Vec3::new(s[0], s[1], s[2]);
                    Aabb::new(c - s[3], c + s[3])
                })
                .collect();
            let input = CustomPrimitiveInput::new(AabbBuffer::new(&boxes));
            Gas::build(&BuildOptions::default(), &[input.into()])?
        }
    };
    let build_ms = start.elapsed().as_secs_f64() * 1e3;

    let module = Module::<Params>::new()
        .raygen("__raygen__rg", |ctx| {
            let [x, y, _] = ctx.launch_index();
            let [w, h, _] = ctx.launch_dimensions();
            let p = ctx.params();
            let eye = Vec3::new(0.0, 0.0, -30.0);
            let d = Vec3::new(
                (2.0 * (x as f32 + 0.5) / w as f32 - 1.0) * w as f32 / h as f32,
                1.0 - 2.0 * (y as f32 + 0.5) / h as f32,
                2.8,
            );
            let mut payload = [0u32; 3];
            ctx.trace(&TraceRay::new(&p.handle, eye, d.normalize()), &mut payload)?;
            p.image.write(
                (y * w + x) as usize,
                common::rgba8(payload.map(f32::from_bits)),
            );
            Ok(())
        })?
        .closest_hit("__closesthit__builtin", |ctx| {
            // The built-in path: the sphere comes from the structure (guide §9.4).
            let p = ctx.world_ray_origin() + ctx.world_ray_direction() * ctx.ray_tmax();
            let c = shade(p, ctx.sphere_data());
            for (i, v) in c.into_iter().enumerate() {
                ctx.set_payload_f32(i, v);
            }
            Ok(())
        })?
        .closest_hit("__closesthit__custom", |ctx| {
            let s = ctx.params().spheres[ctx.primitive_index() as usize];
            let p = ctx.world_ray_origin() + ctx.world_ray_direction() * ctx.ray_tmax();
            let c = shade(p, s);
            for (i, v) in c.into_iter().enumerate() {
                ctx.set_payload_f32(i, v);
            }
            Ok(())
        })?
        .intersection("__intersection__sphere", |ctx| {
            // The same front-face-only test as the built-in one, so that both paths find the
            // same hits and only the way there differs.
            let s = ctx.params().spheres[ctx.primitive_index() as usize];
            let sphere = oxray::Sphere::new(Vec3::new(s[0], s[1], s[2]), s[3]);
            let (o, d) = (ctx.object_ray_origin(), ctx.object_ray_direction());
            if let Some(t) = sphere.intersect(o, d, ctx.ray_tmin(), ctx.ray_tmax()) {
                ctx.report_intersection(t, 0, &[])?;
            }
            Ok(())
        })?
        .miss("__miss__ms", |ctx| {
            for i in 0..3 {
                ctx.set_payload_f32(i, 0.02);
            }
            Ok(())
        })?;
    let raygen = ProgramGroup::raygen(&module, "__raygen__rg")?;
    let miss = ProgramGroup::miss(Some((&module, "__miss__ms")))?;
    let hit = ProgramGroup::hit_group(match path {
        Path::BuiltIn => HitGroupDesc {
            closest_hit: Some((&module, "__closesthit__builtin")),
            ..Default::default()
        },
        Path::Custom => HitGroupDesc {
            closest_hit: Some((&module, "__closesthit__custom")),
            intersection: Some((&module, "__intersection__sphere")),
            ..Default::default()
        },
    })?;
    let compile = PipelineCompileOptions {
        num_payload_values: 3,
        // Spheres must be enabled explicitly (guide §9.1).
        uses_primitive_type_flags: match path {
            Path::BuiltIn => PrimitiveTypeFlags::SPHERE,
            Path::Custom => PrimitiveTypeFlags::CUSTOM,
        },
        ..Default::default()
    };
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &compile,
        &PipelineLinkOptions { max_trace_depth: 1 },
        &[raygen.clone(), miss.clone(), hit.clone()],
    )?;
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[raygen.pack_header()]),
        miss: SbtRegion::from_headers(&[miss.pack_header()]),
        hitgroup: SbtRegion::from_headers(&[hit.pack_header()]),
        ..Default::default()
    };
    let image = Arc::new(OutputBuffer::new((w * h) as usize));
    let params = Params {
        image: image.clone(),
        handle: gas.into(),
        spheres: Arc::new(spheres.to_vec()),
    };
    let start = Instant::now();
    let report = pipeline.launch(&params, &sbt, w, h, 1)?;
    let launch_s = start.elapsed().as_secs_f64();
    if report.exceptions > 0 {
        return Err(format!("the launch raised {:?}", report.first_exceptions).into());
    }
    Ok(Run {
        build_ms,
        launch_s,
        pixels: image.to_vec(),
    })
}

/// Renders 20 000 built-in spheres; returns the pixels.
pub fn render(width: u32, height: u32) -> Result<Vec<[u8; 4]>, Box<dyn std::error::Error>> {
    Ok(render_with(&cloud(20_000), Path::BuiltIn, width, height)?.pixels)
}

#[allow(dead_code)]
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(300_000);
    let (w, h) = (1024, 768);
    let spheres = cloud(n);
    let mut images = Vec::new();
    for path in [Path::BuiltIn, Path::Custom] {
        // One launch to warm caches and the thread pool, then the measured one.
        render_with(&spheres, path, 256, 192)?;
        let run = render_with(&spheres, path, w, h)?;
        println!(
            "{path:?}: {n} spheres, build {:.1} ms, {w}x{h} camera rays in {:.1} ms: {:.2} Mrays/s",
            run.build_ms,
            run.launch_s * 1e3,
            (w * h) as f64 / run.launch_s / 1e6
        );
        images.push(run.pixels);
    }
    let differ = images[0]
        .iter()
        .zip(&images[1])
        .filter(|(a, b)| a != b)
        .count();
    println!("pixels that differ between the two paths: {differ}");
    let path = std::env::args()
        .nth(2)
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| common::default_output("spheres"));
    common::write_png(&path, w, h, &images[0])?;
    println!("wrote {}", path.display());
    Ok(())
}
