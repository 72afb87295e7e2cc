//! One triangle seen by a pinhole camera: ray generation traces a ray per pixel, the closest-hit
//! program shades by barycentrics, the miss program returns a background colour from its SBT
//! record (the counterpart of the OptiX SDK's `optixTriangle`).
//!
//! `cargo run -p oxray --example triangle [out.png]`

mod common;

use glam::Vec3;
use oxray::cpu::Gas;
use oxray::{
    BuildOptions, DeviceContext, HitGroupDesc, IndexBuffer, Module, OutputBuffer, Pipeline,
    PipelineCompileOptions, PipelineLinkOptions, ProgramGroup, SbtRegion, ShaderBindingTable,
    TraceRay, TraversableHandle, TriangleInput, VertexBuffer,
};

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

/// Renders the triangle; returns the pixels.
pub fn render(width: u32, height: u32) -> Result<Vec<[u8; 4]>, Box<dyn std::error::Error>> {
    let image = OutputBuffer::new((width * height) as usize);
    let vertices = [[-0.5f32, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0]];
    let triangles = [[0u32, 1, 2]];
    let input =
        TriangleInput::new(VertexBuffer::f32x3(&vertices)).indices(IndexBuffer::u32x3(&triangles));
    let gas = Gas::build(&BuildOptions::default(), &[input.into()])?;

    let module = Module::<Params>::new()
        .raygen("__raygen__rg", |ctx| {
            let [x, y, _] = ctx.launch_index();
            let [w, h, _] = ctx.launch_dimensions();
            let p = ctx.params();
            let d = Vec3::new(
                2.0 * (x as f32 + 0.5) / w as f32 - 1.0,
                1.0 - 2.0 * (y as f32 + 0.5) / h as f32,
                1.0,
            );
            let dir = (p.u * d.x + p.v * d.y + p.w * d.z).normalize();
            let mut payload = [0u32; 3];
            ctx.trace(
                &TraceRay::new(&p.handle, p.eye, dir).sbt(0, 1, 0),
                &mut payload,
            )?;
            let rgb = payload.map(f32::from_bits);
            p.image.write((y * w + x) as usize, common::rgba8(rgb));
            Ok(())
        })?
        .miss("__miss__ms", |ctx| {
            let bg = ctx.sbt_data::<[f32; 3]>().unwrap_or_default();
            for (i, c) in bg.into_iter().enumerate() {
                ctx.set_payload_f32(i, c);
            }
            Ok(())
        })?
        .closest_hit("__closesthit__ch", |ctx| {
            let [b1, b2] = ctx.triangle_barycentrics();
            let rgb = [1.0 - b1 - b2, b1, b2];
            for (i, c) in rgb.into_iter().enumerate() {
                ctx.set_payload_f32(i, c);
            }
            Ok(())
        })?;
    let raygen = ProgramGroup::raygen(&module, "__raygen__rg")?;
    let miss = ProgramGroup::miss(Some((&module, "__miss__ms")))?;
    let hit = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__ch")),
        ..Default::default()
    })?;
    let compile = PipelineCompileOptions {
        num_payload_values: 3,
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
        miss: SbtRegion::from_records(&[(miss.pack_header(), [0.3f32, 0.1, 0.2])]),
        hitgroup: SbtRegion::from_headers(&[hit.pack_header()]),
        ..Default::default()
    };
    // A camera at z = -2 looking at the triangle, with a square field of view.
    let params = Params {
        image: &image,
        handle: gas.into(),
        eye: Vec3::new(0.0, 0.0, -2.0),
        u: Vec3::X * (width as f32 / height as f32) * 0.5,
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
    let (w, h) = (512, 384);
    let pixels = render(w, h)?;
    let path = common::output_path("triangle");
    common::write_png(&path, w, h, &pixels)?;
    println!("wrote {}", path.display());
    Ok(())
}
