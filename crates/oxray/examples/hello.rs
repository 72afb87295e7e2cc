//! The smallest launch: a ray-generation program writes the colour stored in its SBT record
//! into every pixel (the counterpart of the OptiX SDK's `optixHello`).
//!
//! `cargo run -p oxray --example hello [out.png]`

mod common;

use oxray::{
    DeviceContext, Module, OutputBuffer, Pipeline, PipelineCompileOptions, PipelineLinkOptions,
    ProgramGroup, SbtRegion, ShaderBindingTable,
};

/// Launch parameters: where to write.
#[derive(Clone)]
pub struct Params<'a> {
    pub image: &'a OutputBuffer<[u8; 4]>,
}

/// Renders the image; returns its pixels.
pub fn render(
    width: u32,
    height: u32,
    color: [f32; 3],
) -> Result<Vec<[u8; 4]>, Box<dyn std::error::Error>> {
    // The buffer outlives the pipeline, whose parameters borrow it.
    let image = OutputBuffer::new((width * height) as usize);
    let module = Module::<Params>::new().raygen("__raygen__draw_solid_color", |ctx| {
        let [x, y, _] = ctx.launch_index();
        let [w, _, _] = ctx.launch_dimensions();
        let color = ctx.sbt_data::<[f32; 3]>().unwrap_or_default();
        ctx.params()
            .image
            .write((y * w + x) as usize, common::rgba8(color));
        Ok(())
    })?;
    let raygen = ProgramGroup::raygen(&module, "__raygen__draw_solid_color")?;
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &PipelineCompileOptions::default(),
        &PipelineLinkOptions { max_trace_depth: 0 },
        std::slice::from_ref(&raygen),
    )?;
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_records(&[(raygen.pack_header(), color)]),
        ..Default::default()
    };
    let report = pipeline.launch(&Params { image: &image }, &sbt, width, height, 1)?;
    if report.exceptions > 0 {
        return Err(format!("the launch raised {:?}", report.first_exceptions).into());
    }
    Ok(image.to_vec())
}

#[allow(dead_code)]
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (w, h) = (512, 384);
    let pixels = render(w, h, [0.462, 0.725, 0.0])?;
    let path = common::output_path("hello");
    common::write_png(&path, w, h, &pixels)?;
    println!("wrote {}", path.display());
    Ok(())
}
