//! Built-in curves (guide §5.2, §9.3): a head of hair, a few thousand cubic B-spline strands
//! growing out of a sphere and drooping under gravity, rendered on the CPU and shaded in the
//! closest-hit program from the strand's normal, computed from the segment's control points
//! (`curve_vertex_data()`, `optixGetCubicBSplineVertexData`) and `u` (`curve_parameter()`,
//! `optixGetCurveParameter`), as the guide asks programs to do (§9.3). The scalp is a built-in
//! sphere in a second GAS, both under one IAS.
//!
//! `cargo run --release -p oxray --example hair [strands] [out.png]`

mod common;

use glam::{Vec3, Vec4};
use oxray::cpu::{Gas, Ias};
use oxray::{
    BuildOptions, CurveInput, CurveType, DeviceContext, HitGroupDesc, Instance, Module,
    OutputBuffer, Pipeline, PipelineCompileOptions, PipelineLinkOptions, PrimitiveType,
    PrimitiveTypeFlags, ProgramGroup, SbtRegion, ShaderBindingTable, SphereInput, TraceRay,
    TraversableHandle,
};
use std::sync::Arc;
use std::time::Instant;

/// Launch parameters.
#[derive(Clone)]
pub struct Params {
    pub image: Arc<OutputBuffer<[u8; 4]>>,
    pub handle: TraversableHandle,
}

/// The scalp: a sphere of this radius at the origin.
const HEAD: f32 = 1.0;
/// Control points per strand (a cubic B-spline strand of `POINTS - 3` segments).
const POINTS: usize = 8;

/// `n` strands: control points, radii (thinning towards the tip) and segment starts, from a
/// fixed seed. Each root sits on the upper part of the scalp; the strand leaves along the
/// normal and bends down.
pub fn strands(n: usize) -> (Vec<[f32; 3]>, Vec<f32>, Vec<u32>) {
    let mut state = 0x2545_F491_4F6C_DD1Du64;
    let mut next = move || {
        // SplitMix64: deterministic on every platform.
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
    };
    let (mut points, mut radii, mut index) = (Vec::new(), Vec::new(), Vec::new());
    while index.len() < n * (POINTS - 3) {
        let dir = Vec3::new(next(), next(), next()) * 2.0 - 1.0;
        if dir.length() > 1.0 || dir.length() < 0.1 {
            continue;
        }
        let normal = dir.normalize();
        if normal.y < -0.2 {
            continue;
        }
        let length = 0.9 + 0.6 * next();
        let step = length / (POINTS - 3) as f32;
        let first = points.len() as u32;
        // The first control point is a phantom point below the root (guide §9.5), so that
        // the strand starts at the scalp.
        let mut p = normal * (HEAD - step);
        let mut heading = normal;
        for k in 0..POINTS {
            points.push(p.to_array());
            let t = k as f32 / (POINTS - 1) as f32;
            radii.push(0.006 * (1.0 - 0.7 * t));
            // Gravity pulls the heading down, a little noise keeps strands apart.
            heading = (heading
                + Vec3::new(0.0, -0.35, 0.0)
                + (Vec3::new(next(), next(), next()) - 0.5) * 0.15)
                .normalize();
            p += heading * step;
        }
        for s in 0..(POINTS - 3) as u32 {
            index.push(first + s);
        }
    }
    (points, radii, index)
}

/// The centre-line tangent of a cubic B-spline segment at `u` (its control points `p`).
fn bspline_tangent(p: &[Vec4; 4], u: f32) -> Vec3 {
    let (u2, v) = (u * u, 1.0 - u);
    let d = [
        -0.5 * v * v,
        1.5 * u2 - 2.0 * u,
        -1.5 * u2 + u + 0.5,
        0.5 * u2,
    ];
    (p[0] * d[0] + p[1] * d[1] + p[2] * d[2] + p[3] * d[3]).truncate()
}

/// The centre of a cubic B-spline segment at `u`.
fn bspline_point(p: &[Vec4; 4], u: f32) -> Vec3 {
    let v = 1.0 - u;
    let w = [
        v * v * v / 6.0,
        (3.0 * u * u * u - 6.0 * u * u + 4.0) / 6.0,
        (-3.0 * u * u * u + 3.0 * u * u + 3.0 * u + 1.0) / 6.0,
        u * u * u / 6.0,
    ];
    (p[0] * w[0] + p[1] * w[1] + p[2] * w[2] + p[3] * w[3]).truncate()
}

/// Build milliseconds, launch seconds and the pixels of one render.
pub struct Run {
    pub build_ms: f64,
    pub launch_s: f64,
    pub pixels: Vec<[u8; 4]>,
}

/// Renders `n` strands; `w` x `h` camera rays.
pub fn render_with(n: usize, w: u32, h: u32) -> Result<Run, Box<dyn std::error::Error>> {
    let start = Instant::now();
    let (points, radii, index) = strands(n);
    let v = [bytemuck::cast_slice::<_, u8>(&points)];
    let r = [bytemuck::cast_slice::<_, u8>(&radii)];
    let input = CurveInput::new(
        CurveType::RoundCubicBSpline,
        &v,
        points.len() as u32,
        &r,
        bytemuck::cast_slice(&index),
        index.len() as u32,
    );
    let hair: TraversableHandle = Gas::build(&BuildOptions::default(), &[input.into()])?.into();
    let build_ms = start.elapsed().as_secs_f64() * 1e3;
    let centre = [[0.0f32; 3]];
    let radius = [HEAD * 0.995];
    let (c, rr) = (
        [bytemuck::cast_slice::<_, u8>(&centre)],
        [bytemuck::cast_slice::<_, u8>(&radius)],
    );
    let scalp: TraversableHandle = Gas::build(
        &BuildOptions::default(),
        &[SphereInput::new(&c, 1, &rr).into()],
    )?
    .into();
    // Record 0 for the hair, record 1 for the scalp.
    let instances = [Instance::new(hair), Instance::new(scalp).sbt_offset(1)];
    let ias = Ias::build(&BuildOptions::default(), &[(&instances[..]).into()])?;

    let module = Module::<Params>::new()
        .raygen("__raygen__rg", |ctx| {
            let [x, y, _] = ctx.launch_index();
            let [w, h, _] = ctx.launch_dimensions();
            let p = ctx.params();
            let eye = Vec3::new(0.0, 0.6, -5.5);
            let d = Vec3::new(
                (2.0 * (x as f32 + 0.5) / w as f32 - 1.0) * w as f32 / h as f32,
                1.0 - 2.0 * (y as f32 + 0.5) / h as f32 - 0.15,
                2.4,
            );
            let mut payload = [0u32; 3];
            ctx.trace(&TraceRay::new(&p.handle, eye, d.normalize()), &mut payload)?;
            p.image.write(
                (y * w + x) as usize,
                common::rgba8(payload.map(f32::from_bits)),
            );
            Ok(())
        })?
        .closest_hit("__closesthit__hair", |ctx| {
            // The guide's way (§9.3): the program computes the normal from the segment's
            // control points and u. For a round curve it is the hit point minus the centre at
            // u, projected off the tangent.
            let cp = ctx.curve_vertex_data().map(Vec4::from);
            let u = ctx.curve_parameter();
            let world = ctx.world_ray_origin() + ctx.world_ray_direction() * ctx.ray_tmax();
            let o = ctx.transform_point_to_object(world);
            let tangent = ctx
                .transform_vector_to_world(bspline_tangent(&cp, u))
                .normalize_or_zero();
            let radial = o - bspline_point(&cp, u);
            let radial = ctx.transform_vector_to_world(radial);
            let n = (radial - tangent * radial.dot(tangent)).normalize_or_zero();
            let l = Vec3::new(-0.5, 0.8, -0.4).normalize();
            let view = -ctx.world_ray_direction().normalize();
            // Kajiya-Kay: diffuse from the tangent, a highlight along the strand.
            let tl = tangent.dot(l);
            let diffuse = (1.0 - tl * tl).max(0.0).sqrt();
            let th = tangent.dot((l + view).normalize());
            let spec = (1.0 - th * th).max(0.0).sqrt().powf(40.0);
            let rim = 0.15 * n.dot(l).max(0.0);
            let base = Vec3::new(0.36, 0.2, 0.09);
            let c = base * (0.15 + 0.75 * diffuse + rim) + Vec3::splat(0.35 * spec);
            debug_assert!(matches!(ctx.primitive_type(), PrimitiveType::Curve(_)));
            for (i, v) in c.to_array().into_iter().enumerate() {
                ctx.set_payload_f32(i, v);
            }
            Ok(())
        })?
        .closest_hit("__closesthit__scalp", |ctx| {
            let s = ctx.sphere_data();
            let world = ctx.world_ray_origin() + ctx.world_ray_direction() * ctx.ray_tmax();
            let p = ctx.transform_point_to_object(world);
            let n = (p - Vec3::new(s[0], s[1], s[2])) / s[3];
            let k = 0.1 + 0.5 * n.dot(Vec3::new(-0.5, 0.8, -0.4).normalize()).max(0.0);
            for (i, v) in [0.8f32, 0.6, 0.5].into_iter().enumerate() {
                ctx.set_payload_f32(i, v * k);
            }
            Ok(())
        })?
        .miss("__miss__ms", |ctx| {
            let [_, y, _] = ctx.launch_index();
            let [_, h, _] = ctx.launch_dimensions();
            let g = 0.08 + 0.12 * y as f32 / h as f32;
            for (i, v) in [g, g, g * 1.2].into_iter().enumerate() {
                ctx.set_payload_f32(i, v);
            }
            Ok(())
        })?;
    let raygen = ProgramGroup::raygen(&module, "__raygen__rg")?;
    let miss = ProgramGroup::miss(Some((&module, "__miss__ms")))?;
    let hair_hit = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__hair")),
        ..Default::default()
    })?;
    let scalp_hit = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__scalp")),
        ..Default::default()
    })?;
    let compile = PipelineCompileOptions {
        num_payload_values: 3,
        // Curves and spheres must be enabled explicitly (guide §9.1).
        uses_primitive_type_flags: PrimitiveTypeFlags::ROUND_CUBIC_BSPLINE
            | PrimitiveTypeFlags::SPHERE,
        ..Default::default()
    };
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &compile,
        &PipelineLinkOptions { max_trace_depth: 1 },
        &[
            raygen.clone(),
            miss.clone(),
            hair_hit.clone(),
            scalp_hit.clone(),
        ],
    )?;
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[raygen.pack_header()]),
        miss: SbtRegion::from_headers(&[miss.pack_header()]),
        hitgroup: SbtRegion::from_headers(&[hair_hit.pack_header(), scalp_hit.pack_header()]),
        ..Default::default()
    };
    let image = Arc::new(OutputBuffer::new((w * h) as usize));
    let params = Params {
        image: image.clone(),
        handle: ias.into(),
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

/// Renders 3 000 strands; returns the pixels.
pub fn render(width: u32, height: u32) -> Result<Vec<[u8; 4]>, Box<dyn std::error::Error>> {
    Ok(render_with(3_000, width, height)?.pixels)
}

#[allow(dead_code)]
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(5_000);
    let (w, h) = (800, 600);
    let run = render_with(n, w, h)?;
    println!(
        "{n} strands ({} segments), build {:.1} ms, {w}x{h} camera rays in {:.1} ms: {:.2} Mrays/s",
        n * (POINTS - 3),
        run.build_ms,
        run.launch_s * 1e3,
        (w * h) as f64 / run.launch_s / 1e6
    );
    let path = std::env::args()
        .nth(2)
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| common::default_output("hair"));
    common::write_png(&path, w, h, &run.pixels)?;
    println!("wrote {}", path.display());
    Ok(())
}
