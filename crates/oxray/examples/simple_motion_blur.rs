//! Motion blur (guide §5.10), the counterpart of OptiX's `optixSimpleMotionBlur`: a cube whose
//! vertices move from one motion key to the next (a GAS with vertex motion) and a cube that
//! turns about its own centre under an SRT motion transform, both under an instance
//! acceleration structure with motion. Every pixel averages samples at random times in the
//! shutter interval [0, 1], which smears what moves.
//!
//! `cargo run --release -p oxray --example simple_motion_blur [out.png]`

mod common;

use glam::{Quat, Vec3};
use oxray::cpu::{Gas, Ias};
use oxray::{
    BuildOptions, DeviceContext, HitGroupDesc, IndexBuffer, Instance, Module, MotionOptions,
    OutputBuffer, Pipeline, PipelineCompileOptions, PipelineLinkOptions, ProgramGroup, SbtRegion,
    ShaderBindingTable, SrtData, SrtMotionTransform, TraceRay, TraversableHandle, TriangleInput,
    VertexBuffer,
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

/// A cube of half-size `h` centred on `c`: 8 vertices, 12 triangles.
pub fn cube(c: Vec3, h: f32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let v = (0..8)
        .map(|i| {
            let s = |b: u32| if i & b == 0 { -h } else { h };
            (c + Vec3::new(s(1), s(2), s(4))).to_array()
        })
        .collect();
    let t = vec![
        [0, 2, 1],
        [1, 2, 3],
        [4, 5, 6],
        [5, 7, 6],
        [0, 1, 4],
        [1, 5, 4],
        [2, 6, 3],
        [3, 6, 7],
        [0, 4, 2],
        [2, 4, 6],
        [1, 3, 5],
        [3, 7, 5],
    ];
    (v, t)
}

/// A time in [0, 1) for sample `s` of pixel `p`: a hash, so that every run and every thread
/// count gives the same image.
pub fn sample_time(p: u32, s: u32) -> f32 {
    let mut x = (p as u64) << 32 | s as u64;
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 31;
    (x >> 40) as f32 / (1u64 << 24) as f32
}

/// The scene: instance 0 is the translating cube, instance 1 the turning one.
pub fn scene() -> Result<TraversableHandle, Box<dyn std::error::Error>> {
    let motion = MotionOptions::new(2, 0.0, 1.0);
    // Vertex motion: key 0 at x = -2, key 1 at x = -0.8.
    let (k0, tris) = cube(Vec3::new(-2.0, 0.0, 0.0), 0.6);
    let (k1, _) = cube(Vec3::new(-0.8, 0.0, 0.0), 0.6);
    let later = [VertexBuffer::f32x3(&k1)];
    let input = TriangleInput::new(VertexBuffer::f32x3(&k0))
        .indices(IndexBuffer::u32x3(&tris))
        .motion_vertices(&later);
    let moving: TraversableHandle = Gas::build(
        &BuildOptions::default().with_motion(motion),
        &[input.into()],
    )?
    .into();
    // Transform motion: a cube at the origin, turned 0, 45 and 90 degrees about y, placed at
    // x = 1.6 by the translation that follows the rotation.
    let (v, t) = cube(Vec3::ZERO, 0.6);
    let input = TriangleInput::new(VertexBuffer::f32x3(&v)).indices(IndexBuffer::u32x3(&t));
    let still: TraversableHandle = Gas::build(&BuildOptions::default(), &[input.into()])?.into();
    let keys: Vec<SrtData> = [0.0f32, 45.0, 90.0]
        .iter()
        .map(|deg| {
            let q = Quat::from_rotation_y(deg.to_radians()) * Quat::from_rotation_x(0.5);
            SrtData {
                qx: q.x,
                qy: q.y,
                qz: q.z,
                qw: q.w,
                tx: 1.6,
                ..SrtData::IDENTITY
            }
        })
        .collect();
    let turning: TraversableHandle =
        SrtMotionTransform::new(still, MotionOptions::new(3, 0.0, 1.0), &keys)?.into();
    let instances = [
        Instance::new(moving).sbt_offset(0),
        Instance::new(turning).sbt_offset(1),
    ];
    // §5.10.3: an IAS over moving children is best built with motion; its two keys change
    // only performance here.
    let ias = Ias::build(
        &BuildOptions::default().with_motion(motion),
        &[(&instances[..]).into()],
    )?;
    Ok(ias.into())
}

/// Renders the two cubes with motion blur; returns the pixels.
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
                let time = sample_time(y * w + x, s);
                let mut payload = [0u32; 3];
                let ray = TraceRay::new(&p.handle, p.eye, dir).time(time);
                ctx.trace(&ray, &mut payload)?;
                sum += Vec3::from(payload.map(f32::from_bits));
            }
            let c = sum / SAMPLES as f32;
            p.image
                .write((y * w + x) as usize, common::rgba8(c.to_array()));
            Ok(())
        })?
        .closest_hit("__closesthit__shade", |ctx| {
            // The triangle and the transforms at the ray's time.
            let [a, b, c] = ctx.triangle_vertex_data();
            let n = ctx
                .transform_normal_to_world((b - a).cross(c - a))
                .normalize();
            let n = if n.dot(ctx.world_ray_direction()) > 0.0 {
                -n
            } else {
                n
            };
            let light = Vec3::new(-0.4, 0.7, -0.6).normalize();
            let shade = 0.3 + 0.7 * n.dot(light).max(0.0);
            let colour = Vec3::from(ctx.sbt_data::<[f32; 3]>().unwrap_or([1.0; 3])) * shade;
            ctx.set_payload_vec3(0, colour);
            Ok(())
        })?
        .miss("__miss__bg", |ctx| {
            ctx.set_payload_vec3(0, Vec3::new(0.1, 0.1, 0.15));
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
            // Rays carry their time only in a pipeline that uses motion blur (§13.5).
            uses_motion_blur: true,
            num_payload_values: 3,
            ..Default::default()
        },
        &PipelineLinkOptions { max_trace_depth: 1 },
        &[raygen.clone(), miss.clone(), hit.clone()],
    )?;
    let colours = [[0.9f32, 0.45, 0.1], [0.2, 0.55, 0.95]];
    let records: Vec<_> = colours.iter().map(|c| (hit.pack_header(), *c)).collect();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[raygen.pack_header()]),
        miss: SbtRegion::from_headers(&[miss.pack_header()]),
        hitgroup: SbtRegion::from_records(&records),
        ..Default::default()
    };
    let aspect = width as f32 / height as f32;
    let params = Params {
        image: &image,
        handle: scene()?,
        eye: Vec3::new(0.0, 0.5, -6.0),
        u: Vec3::X * aspect * 0.5,
        v: Vec3::Y * 0.5,
        w: Vec3::new(0.0, -0.08, 1.0),
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
    let path = common::output_path("simple_motion_blur");
    common::write_png(&path, w, h, &pixels)?;
    println!("wrote {}", path.display());
    Ok(())
}
