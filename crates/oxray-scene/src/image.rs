//! Texture decoding shared by the glTF and OBJ loaders: PNG and JPEG into RGBA8, with size limits
//! so that a corrupt header cannot ask for gigabytes.

use super::{Texture, Wrap};
use std::io::Cursor;

/// Largest accepted texture side, in texels.
const MAX_SIDE: u32 = 16384;

/// Largest allocation the decoder may make for one image (an 8K x 8K RGBA8 texture).
const MAX_ALLOC: u64 = 256 << 20;

/// Decodes a PNG or JPEG held in memory into an RGBA8 texture with repeat wrapping. The error is
/// a short phrase for a warning line.
pub(crate) fn decode(name: &str, bytes: &[u8]) -> Result<Texture, String> {
    if bytes.is_empty() {
        return Err("the file is empty".into());
    }
    let mut reader = image::ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| e.to_string())?;
    if reader.format().is_none() {
        return Err("not a PNG or JPEG image".into());
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_SIDE);
    limits.max_image_height = Some(MAX_SIDE);
    limits.max_alloc = Some(MAX_ALLOC);
    reader.limits(limits);
    let img = reader.decode().map_err(|e| e.to_string())?.into_rgba8();
    let (width, height) = img.dimensions();
    if width == 0 || height == 0 {
        return Err("the image has no texels".into());
    }
    // Reinterpreted in place: copying would double the peak memory of a large texture.
    let texels = bytemuck::cast_vec::<u8, [u8; 4]>(img.into_raw());
    Ok(Texture {
        name: name.to_string(),
        width,
        height,
        texels,
        wrap_u: Wrap::Repeat,
        wrap_v: Wrap::Repeat,
    })
}

/// Reads and decodes an image file; the error is a short phrase for a warning line.
pub(crate) fn load_file(name: &str, path: &std::path::Path) -> Result<Texture, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read it ({e})"))?;
    decode(name, &bytes).map_err(|e| format!("cannot decode it ({e})"))
}
