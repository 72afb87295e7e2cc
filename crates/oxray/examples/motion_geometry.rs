//! Deforming geometry (guide §5.10.2): a sphere mesh given at three motion keys (round, then
//! squashed and stretched, then round again with a bulge), built into one GAS with vertex
//! motion. The triangles are interpolated between the two keys around each ray's time; every
//! pixel averages samples at random times, so the deformation shows as blur.
//!
//! `cargo run --release -p oxray --example motion_geometry [out.png]`

mod common;

use glam::Vec3;
use oxray::cpu::Gas;
use oxray::{
    BuildOptions, DeviceContext, HitGroupDesc, IndexBuffer, Module, MotionOptions, OutputBuffer,
    Pipeline, PipelineCompileOptions, PipelineLinkOptions, ProgramGroup, SbtRegion,
    ShaderBindingTable, TraceRay, TraversableHandle, TriangleInput, VertexBuffer,
};

/// Samples (ray times) per pixel.
pub const SAMPLES: u32 = 16;

/// Launch parameters.
#[derive(Clone)]
pub struct Params<'a> {
    pub image: &'a OutputBuffer<[u8; 4]>,
    pub handle: TraversableHandle,
    pub eye: Vec3,
    pub u: Vec3,
    pub v: Vec3,
    pub w: Vec3,
}

/// A unit UV sphere, each vertex passed through `shape`.
pub fn sphere(shape: impl Fn(Vec3) -> Vec3) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let (rings, segments) = (24u32, 48u32);
    let mut v = Vec::new();
    for r in 0..=rings {
        let th = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..segments {
            let ph = std::f32::consts::TAU * s as f32 / segments as f32;
            let p = Vec3::new(th.sin() * ph.cos(), th.cos(), th.sin() * ph.sin());
            v.push(shape(p).to_array());
        }
    }
    let mut t = Vec::new();
    for r in 0..rings {
        for s in 0..segments {
            let a = r * segments + s;
            let b = r * segments + (s + 1) % segments;
            t.push([a, a + segments, b]);
            t.push([b, a + segments, b + segments]);
        }
    }
    (v, t)
}

/// A time in [0, 1) for sample `s` of pixel `p` (a hash: the same image on every run).
pub fn sample_time(p: u32, s: u32) -> f32 {
    let mut x = (p as u64) << 32 | s as u64;
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 31;
    (x >> 40) as f32 / (1u64 << 24) as f32
}

/// The deforming sphere: three keys over [0, 1], the same triangles at every key.
pub fn scene() -> Result<TraversableHandle, Box<dyn std::error::Error>> {
    let (k0, tris) = sphere(|p| p);
    let (k1, _) = sphere(|p| Vec3::new(p.x * 1.5, p.y * 0.6, p.z * 1.5));
    let (k2, _) = sphere(|p| p * (1.0 + 0.35 * (4.0 * p.x).sin().max(0.0)));
    let later = [VertexBuffer::f32x3(&k1), VertexBuffer::f32x3(&k2)];
    let input = TriangleInput::new(VertexBuffer::f32x3(&k0))
        .indices(IndexBuffer::u32x3(&tris))
        .motion_vertices(&later);
    let options = BuildOptions::default().with_motion(MotionOptions::new(3, 0.0, 1.0));
    Ok(Gas::build(&options, &[input.into()])?.into())
}

/// Renders the deforming sphere; returns the pixels.
pub fn render(width: u32, height: u32) -> Result<Vec<[u8; 4]>, Box<dyn std::error::Error>> {
    let image = OutputBuffer::new((width * height) as usize);
    let module = Module::<Params>::new()
        .raygen("__raygen__camera", |ctx| {
            let [x, y, _] = ctx.launch_index();
            let [w, h, _] = ctx.launch_dimensions();
            let p = ctx.params();
            let d = Vec3::new(
                2.0 * (x as f32 + 0.5) / w as f32 - 1.0,
                1.0 - 2.0 * (y as f32 + 0.5) / h as f32,
                1.0,
            );
            let dir = (p.u * d.x + p.v * d.y + p.w * d.z).normalize();
            let mut sum = Vec3::ZERO;
            for s in 0..SAMPLES {
                let mut payload = [0u32; 3];
                let time = sample_time(y * w + x, s);
                ctx.trace(
                    &TraceRay::new(&p.handle, p.eye, dir).time(time),
                    &mut payload,
                )?;
                sum += Vec3::from(payload.map(f32::from_bits));
            }
            let c = sum / SAMPLES as f32;
            p.image
                .write((y * w + x) as usize, common::rgba8(c.to_array()));
            Ok(())
        })?
        .closest_hit("__closesthit__shade", |ctx| {
            // The hit triangle as it was at the ray's time.
            let [a, b, c] = ctx.triangle_vertex_data();
            let n = (b - a).cross(c - a).normalize();
            let n = if n.dot(ctx.world_ray_direction()) > 0.0 {
                -n
            } else {
                n
            };
            let light = Vec3::new(-0.5, 0.8, -0.4).normalize();
            let shade = 0.25 + 0.75 * n.dot(light).max(0.0);
            ctx.set_payload_vec3(0, Vec3::new(0.35, 0.85, 0.45) * shade);
            Ok(())
        })?
        .miss("__miss__bg", |ctx| {
            ctx.set_payload_vec3(0, Vec3::new(0.12, 0.1, 0.1));
            Ok(())
        })?;
    let raygen = ProgramGroup::raygen(&module, "__raygen__camera")?;
    let miss = ProgramGroup::miss(Some((&module, "__miss__bg")))?;
    let hit = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__shade")),
        ..Default::default()
    })?;
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &PipelineCompileOptions {
            uses_motion_blur: true,
            num_payload_values: 3,
            ..Default::default()
        },
        &PipelineLinkOptions { max_trace_depth: 1 },
        &[raygen.clone(), miss.clone(), hit.clone()],
    )?;
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[raygen.pack_header()]),
        miss: SbtRegion::from_headers(&[miss.pack_header()]),
        hitgroup: SbtRegion::from_headers(&[hit.pack_header()]),
        ..Default::default()
    };
    let aspect = width as f32 / height as f32;
    let params = Params {
        image: &image,
        handle: scene()?,
        eye: Vec3::new(0.0, 0.0, -5.0),
        u: Vec3::X * aspect * 0.5,
        v: Vec3::Y * 0.5,
        w: Vec3::Z,
    };
    let report = pipeline.launch(&params, &sbt, width, height, 1)?;
    if report.exceptions > 0 {
        return Err(format!("the launch raised {:?}", report.first_exceptions).into());
    }
    Ok(image.to_vec())
}

#[allow(dead_code)]
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (w, h) = (640, 480);
    let pixels = render(w, h)?;
    let path = common::output_path("motion_geometry");
    common::write_png(&path, w, h, &pixels)?;
    println!("wrote {}", path.display());
    Ok(())
}
