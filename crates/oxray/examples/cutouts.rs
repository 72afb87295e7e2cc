//! Alpha cutouts with an any-hit program: a checkerboard of holes is cut into a front quad by
//! an any-hit program that ignores hits in the holes, so the back quad shows through (the
//! counterpart of the OptiX SDK's `optixCutouts`). The two quads are two build inputs of one
//! GAS; the back one has `DISABLE_ANYHIT` and its own hit-group record (SBT-GAS index 1).
//!
//! `cargo run -p oxray --example cutouts [out.png]`

mod common;

use glam::Vec3;
use oxray::cpu::Gas;
use oxray::{
    BuildOptions, DeviceContext, GeometryFlags, HitGroupDesc, IndexBuffer, Module, OutputBuffer,
    Pipeline, PipelineCompileOptions, PipelineLinkOptions, ProgramGroup, SbtRegion,
    ShaderBindingTable, TraceRay, TraversableHandle, TriangleInput, VertexBuffer,
};

/// Launch parameters.
#[derive(Clone)]
pub struct Params<'a> {
    pub image: &'a OutputBuffer<[u8; 4]>,
    pub handle: TraversableHandle,
    pub eye: Vec3,
}

/// Checker cells per side of the front quad.
pub const CELLS: f32 = 6.0;

/// Renders the quads; returns the pixels.
pub fn render(width: u32, height: u32) -> Result<Vec<[u8; 4]>, Box<dyn std::error::Error>> {
    let image = OutputBuffer::new((width * height) as usize);
    // Counter-clockwise seen from the camera at -z: front faces.
    let quad = |z: f32, s: f32| [[-s, -s, z], [-s, s, z], [s, s, z], [s, -s, z]];
    let front = quad(0.0, 1.0);
    let back = quad(1.0, 2.0);
    let tris = [[0u32, 1, 2], [0, 2, 3]];
    let inputs = [
        TriangleInput::new(VertexBuffer::f32x3(&front))
            .indices(IndexBuffer::u32x3(&tris))
            .into(),
        TriangleInput::new(VertexBuffer::f32x3(&back))
            .indices(IndexBuffer::u32x3(&tris))
            .flags(&[GeometryFlags::DISABLE_ANYHIT])
            .into(),
    ];
    let gas = Gas::build(&BuildOptions::default(), &inputs)?;

    let module = Module::<Params>::new()
        .raygen("__raygen__rg", |ctx| {
            let [x, y, _] = ctx.launch_index();
            let [w, h, _] = ctx.launch_dimensions();
            let p = ctx.params();
            let s = Vec3::new(
                (2.0 * (x as f32 + 0.5) / w as f32 - 1.0) * w as f32 / h as f32,
                1.0 - 2.0 * (y as f32 + 0.5) / h as f32,
                2.0,
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
        .any_hit("__anyhit__checker", |ctx| {
            let hit = ctx.world_ray_origin() + ctx.world_ray_direction() * ctx.ray_tmax();
            // Cells of the front quad's [-1, 1]^2 face; odd cells are holes.
            let cell = |c: f32| ((c + 1.0) * 0.5 * CELLS).floor() as i32;
            if (cell(hit.x) + cell(hit.y)) % 2 != 0 {
                return ctx.ignore_intersection();
            }
            Ok(())
        })?
        .closest_hit("__closesthit__color", |ctx| {
            let c = ctx.sbt_data::<[f32; 3]>().unwrap_or_default();
            for (i, v) in c.into_iter().enumerate() {
                ctx.set_payload_f32(i, v);
            }
            Ok(())
        })?
        .miss("__miss__ms", |ctx| {
            for i in 0..3 {
                ctx.set_payload_f32(i, 0.05);
            }
            Ok(())
        })?;
    let raygen = ProgramGroup::raygen(&module, "__raygen__rg")?;
    let miss = ProgramGroup::miss(Some((&module, "__miss__ms")))?;
    let cutout = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__color")),
        any_hit: Some((&module, "__anyhit__checker")),
        ..Default::default()
    })?;
    let opaque = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__color")),
        ..Default::default()
    })?;
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &PipelineCompileOptions {
            num_payload_values: 3,
            ..Default::default()
        },
        &PipelineLinkOptions { max_trace_depth: 1 },
        &[raygen.clone(), miss.clone(), cutout.clone(), opaque.clone()],
    )?;
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[raygen.pack_header()]),
        miss: SbtRegion::from_headers(&[miss.pack_header()]),
        // SBT-GAS index 0: the front quad (orange); 1: the back quad (blue).
        hitgroup: SbtRegion::from_records(&[
            (cutout.pack_header(), [0.9f32, 0.5, 0.1]),
            (opaque.pack_header(), [0.1f32, 0.3, 0.9]),
        ]),
        ..Default::default()
    };
    let params = Params {
        image: &image,
        handle: gas.into(),
        eye: Vec3::new(0.0, 0.0, -4.0),
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
    let path = common::output_path("cutouts");
    common::write_png(&path, w, h, &pixels)?;
    println!("wrote {}", path.display());
    Ok(())
}
