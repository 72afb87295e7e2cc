//! A custom primitive: a sphere inside its AABB, intersected by an intersection program that
//! reads the sphere from its hit-group record and reports the normal as attributes (the
//! counterpart of the OptiX SDK's `optixSphere`).
//!
//! `cargo run -p oxray --example custom_sphere [out.png]`

mod common;

use glam::Vec3;
use oxray::cpu::Gas;
use oxray::{
    Aabb, AabbBuffer, BuildOptions, CustomPrimitiveInput, DeviceContext, HitGroupDesc, Module,
    OutputBuffer, Pipeline, PipelineCompileOptions, PipelineLinkOptions, ProgramGroup, SbtRegion,
    ShaderBindingTable, TraceRay, TraversableHandle,
};

/// Launch parameters.
#[derive(Clone)]
pub struct Params<'a> {
    pub image: &'a OutputBuffer<[u8; 4]>,
    pub handle: TraversableHandle,
    pub eye: Vec3,
}

/// The sphere, stored in the hit-group record.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Sphere {
    pub center: [f32; 3],
    pub radius: f32,
}

/// Renders the sphere; returns the pixels.
pub fn render(width: u32, height: u32) -> Result<Vec<[u8; 4]>, Box<dyn std::error::Error>> {
    let image = OutputBuffer::new((width * height) as usize);
    let sphere = Sphere {
        center: [0.0, 0.0, 0.0],
        radius: 1.5,
    };
    let c = Vec3::from(sphere.center);
    let aabbs = [Aabb::new(c - sphere.radius, c + sphere.radius)];
    let gas = Gas::build(
        &BuildOptions::default(),
        &[CustomPrimitiveInput::new(AabbBuffer::new(&aabbs)).into()],
    )?;

    let module = Module::<Params>::new()
        .raygen("__raygen__rg", |ctx| {
            let [x, y, _] = ctx.launch_index();
            let [w, h, _] = ctx.launch_dimensions();
            let p = ctx.params();
            let s = Vec3::new(
                (2.0 * (x as f32 + 0.5) / w as f32 - 1.0) * w as f32 / h as f32,
                1.0 - 2.0 * (y as f32 + 0.5) / h as f32,
                2.5,
            );
            let mut payload = [0u32; 3];
            ctx.trace(
                &TraceRay::new(&p.handle, p.eye, s.normalize()),
                &mut payload,
            )?;
            p.image.write(
                (y * w + x) as usize,
                common::rgba8(payload.map(f32::from_bits)),
            );
            Ok(())
        })?
        .intersection("__intersection__sphere", |ctx| {
            let Some(s) = ctx.sbt_data::<Sphere>() else {
                return Ok(());
            };
            let o = ctx.object_ray_origin() - Vec3::from(s.center);
            let d = ctx.object_ray_direction();
            // |o + t d|^2 = r^2, solved in the form that avoids cancellation.
            let a = d.dot(d);
            let b = o.dot(d);
            let disc = b * b - a * (o.dot(o) - s.radius * s.radius);
            if disc < 0.0 {
                return Ok(());
            }
            let q = -b - disc.sqrt().copysign(b);
            for t in [q / a, (o.dot(o) - s.radius * s.radius) / q] {
                let n = ((o + d * t) / s.radius).to_array().map(f32::to_bits);
                ctx.report_intersection(t, 0, &n)?;
            }
            Ok(())
        })?
        .closest_hit("__closesthit__normal", |ctx| {
            for i in 0..3 {
                ctx.set_payload_f32(i, f32::from_bits(ctx.attribute(i)) * 0.5 + 0.5);
            }
            Ok(())
        })?
        .miss("__miss__ms", |ctx| {
            for i in 0..3 {
                ctx.set_payload_f32(i, 0.1);
            }
            Ok(())
        })?;
    let raygen = ProgramGroup::raygen(&module, "__raygen__rg")?;
    let miss = ProgramGroup::miss(Some((&module, "__miss__ms")))?;
    let hit = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__normal")),
        intersection: Some((&module, "__intersection__sphere")),
        ..Default::default()
    })?;
    let compile = PipelineCompileOptions {
        num_payload_values: 3,
        num_attribute_values: 3,
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
        hitgroup: SbtRegion::from_records(&[(hit.pack_header(), sphere)]),
        ..Default::default()
    };
    let params = Params {
        image: &image,
        handle: gas.into(),
        eye: Vec3::new(0.0, 0.0, -5.0),
    };
    let report = pipeline.launch(&params, &sbt, width, height, 1)?;
    if report.exceptions > 0 {
        return Err(format!("the launch raised {:?}", report.first_exceptions).into());
    }
    Ok(image.to_vec())
}

#[allow(dead_code)]
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (w, h) = (512, 384);
    let pixels = render(w, h)?;
    let path = common::output_path("custom_sphere");
    common::write_png(&path, w, h, &pixels)?;
    println!("wrote {}", path.display());
    Ok(())
}
