//! Writes the PTX of `oxray bench --backend cuda`'s pipeline and of the trace kernels, compiled
//! with NVRTC as on a device of compute capability 9.0 (or the one given), into a folder: the
//! input of `scripts/pipeline-sass.sh`, which reads their machine code without a GPU.
//!
//! ```text
//! cargo run -p oxray-cli --example pipeline_ptx -- target/sass [MAJOR MINOR]
//! ```

use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let dir = PathBuf::from(args.next().ok_or("usage: pipeline_ptx DIR [MAJOR MINOR]")?);
    let major = args.next().map_or(Ok(9), |a| a.parse())?;
    let minor = args.next().map_or(Ok(0), |a| a.parse())?;
    std::fs::create_dir_all(&dir)?;
    let pipeline = oxray_cli::device::ray_pipeline_ptx((major, minor))?;
    std::fs::write(dir.join("pipeline.ptx"), pipeline)?;
    let kernels = oxray::cuda::trace_kernels_ptx((major, minor))?;
    std::fs::write(dir.join("trace.ptx"), kernels)?;
    println!("{}", dir.display());
    Ok(())
}
