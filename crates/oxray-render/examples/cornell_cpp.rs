//! The Cornell box rendered by the path tracer's CUDA C++ programs (`src/device_programs.cu`,
//! the counterpart of the OptiX SDK's optixPathTracer), on a GPU where there is one and on the
//! CPU otherwise (the same programs, compiled by the host's C++ compiler).
//!
//! `cargo run --release -p oxray-render --example cornell_cpp [out.png] [cpu|cuda|cuda:N|auto]`

use glam::Vec3;
use oxray_render::lights::Environment;
use oxray_render::{device::render_on, RenderOptions};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let out = args.next().unwrap_or_else(|| "cornell_cpp.png".into());
    let device = oxray::Device::from_name(&args.next().unwrap_or_else(|| "auto".into()))?;
    let opts = RenderOptions {
        width: 512,
        height: 512,
        spp: 64,
        max_depth: 8,
        ..Default::default()
    };
    let scene = oxray_scene::cornell_box();
    let started = std::time::Instant::now();
    // The box is lit by its ceiling panel only.
    let image = render_on(
        &device,
        &scene,
        &Environment::uniform(Vec3::ZERO),
        &opts,
        |_| {},
    )?;
    let seconds = started.elapsed().as_secs_f64();
    let out = std::path::PathBuf::from(out);
    if oxray_render::output::written_by_oxray(&out) || !out.exists() {
        image.save(&out)?;
    } else {
        return Err(format!("{} exists and was not written by oxray", out.display()).into());
    }
    let samples = (opts.width * opts.height * opts.spp) as f64;
    println!(
        "wrote {} on {}: {seconds:.2} s, {:.1} M samples/s",
        out.display(),
        device.describe(),
        samples / seconds / 1e6
    );
    Ok(())
}
