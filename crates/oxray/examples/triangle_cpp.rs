//! The `triangle` example with its programs in CUDA C++ (`examples/programs/triangle.cu`), the
//! way an OptiX program is written, run through the device-neutral API on any device: NVRTC
//! compiles them for a GPU, the host's C++ compiler for the CPU. The image is the Rust
//! `triangle` example's, pixel for pixel.
//!
//! `cargo run -p oxray --example triangle_cpp [out.png] [cpu|cuda|cuda:N|auto]`

mod common;

use oxray::programs::{HitGroupDesc, ProgramGroup};
use oxray::{
    BuildOptions, Device, IndexBuffer, ModuleSource, PipelineCompileOptions, PipelineLinkOptions,
    SbtRegion, ShaderBindingTable, TriangleInput, VertexBuffer,
};

/// The programs, as an OptiX user writes them.
pub const PROGRAMS: &str = include_str!("programs/triangle.cu");

/// The launch parameters, laid out as `Params` in the programs.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Params {
    pub image: u64,
    pub handle: u64,
    pub width: u32,
    pub height: u32,
    pub eye: [f32; 3],
    pub u: [f32; 3],
    pub v: [f32; 3],
    pub w: [f32; 3],
}

/// Renders the triangle on `device`; returns the pixels.
pub fn render_on(
    device: &Device,
    width: u32,
    height: u32,
) -> Result<Vec<[u8; 4]>, Box<dyn std::error::Error>> {
    let vertices = [[-0.5f32, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0]];
    let triangles = [[0u32, 1, 2]];
    let input =
        TriangleInput::new(VertexBuffer::f32x3(&vertices)).indices(IndexBuffer::u32x3(&triangles));
    let gas = device.build_gas(&BuildOptions::default(), &[input.into()])?;

    let module = device.create_module(ModuleSource::CudaCpp(PROGRAMS))?;
    let raygen = ProgramGroup::raygen(&module, "__raygen__rg")?;
    let miss = ProgramGroup::miss(&module, "__miss__ms")?;
    let hit = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__ch")),
        ..Default::default()
    })?;
    let compile = PipelineCompileOptions {
        num_payload_values: 3,
        ..Default::default()
    };
    let pipeline = device.create_pipeline(
        &compile,
        &PipelineLinkOptions { max_trace_depth: 1 },
        Some("params"),
        &[raygen.clone(), miss.clone(), hit.clone()],
    )?;
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[raygen.pack_header()]),
        miss: SbtRegion::from_records(&[(miss.pack_header(), [0.3f32, 0.1, 0.2])]),
        hitgroup: SbtRegion::from_headers(&[hit.pack_header()]),
        ..Default::default()
    };
    let image = device.create_buffer::<[f32; 4]>((width * height) as usize)?;
    // A camera at z = -2 looking at the triangle, with a square field of view.
    let params = Params {
        image: image.device_ptr(),
        handle: gas.optix_handle()?,
        width,
        height,
        eye: [0.0, 0.0, -2.0],
        u: [(width as f32 / height as f32) * 0.5, 0.0, 0.0],
        v: [0.0, 0.5, 0.0],
        w: [0.0, 0.0, 1.0],
    };
    let report = pipeline.launch_with(&params, &sbt, width, height, 1)?;
    if report.exceptions > 0 {
        return Err(format!("the launch raised {:?}", report.first_exceptions).into());
    }
    Ok(image
        .download()?
        .into_iter()
        .map(|[r, g, b, _]| common::rgba8([r, g, b]))
        .collect())
}

/// Renders on the CPU device.
pub fn render(width: u32, height: u32) -> Result<Vec<[u8; 4]>, Box<dyn std::error::Error>> {
    render_on(&Device::cpu(), width, height)
}

#[allow(dead_code)]
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let device = Device::from_name(&std::env::args().nth(2).unwrap_or_else(|| "auto".into()))?;
    let (w, h) = (512, 384);
    let pixels = render_on(&device, w, h)?;
    let path = common::output_path("triangle_cpp");
    common::write_png(&path, w, h, &pixels)?;
    println!("wrote {} on the {} device", path.display(), device.kind());
    Ok(())
}
