//! What the examples share: writing an RGBA8 image as PNG and converting colours.

#![allow(dead_code)]

use std::path::Path;

/// Writes `pixels` (row-major, top row first) as an 8-bit RGBA PNG.
pub fn write_png(
    path: &Path,
    width: u32,
    height: u32,
    pixels: &[[u8; 4]],
) -> Result<(), Box<dyn std::error::Error>> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    let file = std::io::BufWriter::new(std::fs::File::create(path)?);
    let mut enc = png::Encoder::new(file, width, height);
    enc.set_color(png::ColorType::Rgba);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header()?;
    w.write_image_data(bytemuck::cast_slice(pixels))?;
    Ok(())
}

/// A linear colour in [0, 1] to 8-bit RGBA (clamped, no gamma: the examples write flat colours).
pub fn rgba8(c: [f32; 3]) -> [u8; 4] {
    let q = |x: f32| (x.clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
    [q(c[0]), q(c[1]), q(c[2]), 255]
}

/// The output path: the first command-line argument, else `target/examples/<name>.png`.
pub fn output_path(name: &str) -> std::path::PathBuf {
    std::env::args()
        .nth(1)
        .map(Into::into)
        .unwrap_or_else(|| default_output(name))
}

/// `target/examples/<name>.png`, for examples whose first argument is not the output path.
pub fn default_output(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../target/examples")
        .join(format!("{name}.png"))
}
