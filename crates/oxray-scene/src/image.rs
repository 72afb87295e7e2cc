//! Texture decoding shared by the glTF and OBJ loaders: PNG and JPEG into RGBA8. The size is
//! read from the header and checked against [`Limits`] before anything is decoded, and the
//! decoder runs where a panic becomes an error.

use super::{Texture, Wrap};
use crate::files::{guard_panics, mib, Limits};
use std::io::Cursor;
use std::path::Path;

/// Largest accepted texture side, in texels.
const MAX_SIDE: u32 = 16384;

/// Why an image was not used.
#[derive(Debug)]
pub(crate) enum ImageError {
    /// The image cannot be read or decoded (missing, corrupt, unsupported): the scene renders
    /// without it, with a warning.
    Skip(String),
    /// The image is over a memory limit or is not a regular file: loading stops.
    Fatal(String),
}

fn reader(bytes: &[u8]) -> Result<image::ImageReader<Cursor<&[u8]>>, ImageError> {
    if bytes.is_empty() {
        return Err(ImageError::Skip("the file is empty".into()));
    }
    let reader = image::ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| ImageError::Skip(e.to_string()))?;
    if reader.format().is_none() {
        return Err(ImageError::Skip("not a PNG or JPEG image".into()));
    }
    Ok(reader)
}

/// The RGBA8 bytes an image will take once decoded, read from its header and checked against
/// the per-image limit.
pub(crate) fn decoded_size(bytes: &[u8]) -> Result<u64, ImageError> {
    let (w, h) = guard_panics(|| {
        reader(bytes)?
            .into_dimensions()
            .map_err(|e| ImageError::Skip(e.to_string()))
    })
    .map_err(ImageError::Skip)??;
    let size = w as u64 * h as u64 * 4;
    let limit = Limits::get().image_bytes;
    if w > MAX_SIDE || h > MAX_SIDE || size > limit {
        return Err(ImageError::Fatal(format!(
            "the image is {w}x{h}: decoded it takes {}, over the limit of {} per image and {MAX_SIDE} texels a side (raise it with OXRAY_MAX_IMAGE_MB)",
            mib(size),
            mib(limit)
        )));
    }
    if w == 0 || h == 0 {
        return Err(ImageError::Skip("the image has no texels".into()));
    }
    Ok(size)
}

/// Checks that images of these decoded sizes fit together in [`Limits::textures_bytes`].
pub(crate) fn check_total(sizes: impl IntoIterator<Item = u64>) -> Result<(), String> {
    let (mut total, mut count) = (0u64, 0usize);
    for s in sizes {
        total = total.saturating_add(s);
        count += 1;
    }
    let limit = Limits::get().textures_bytes;
    if total > limit {
        return Err(format!(
            "its {count} textures take {} once decoded, over the limit of {} (raise it with OXRAY_MAX_TEXTURES_MB)",
            mib(total),
            mib(limit)
        ));
    }
    Ok(())
}

/// Decodes a PNG or JPEG held in memory into an RGBA8 texture with repeat wrapping, after
/// [`decoded_size`] has accepted it. The error is a short phrase for a message.
pub(crate) fn decode(name: &str, bytes: &[u8]) -> Result<Texture, ImageError> {
    let size = decoded_size(bytes)?;
    let img = guard_panics(|| {
        let mut reader = reader(bytes)?;
        let mut limits = image::Limits::default();
        limits.max_image_width = Some(MAX_SIDE);
        limits.max_image_height = Some(MAX_SIDE);
        // The decoder's own buffer (up to 16 bytes a texel for 16-bit RGBA) and the RGBA8 copy.
        limits.max_alloc = Some(size.saturating_mul(4));
        reader.limits(limits);
        reader
            .decode()
            .map_err(|e| ImageError::Skip(format!("cannot decode it ({e})")))
            .map(|i| i.into_rgba8())
    })
    .map_err(|e| ImageError::Skip(format!("cannot decode it ({e})")))??;
    let (width, height) = img.dimensions();
    if width == 0 || height == 0 {
        return Err(ImageError::Skip("the image has no texels".into()));
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

/// Reads an image file: a missing or unreadable file is [`ImageError::Skip`], one that is not
/// a regular file or is over the file-size limit [`ImageError::Fatal`].
pub(crate) fn read_file(path: &Path) -> Result<Vec<u8>, ImageError> {
    crate::files::read_input(path).map_err(|e| {
        if e.kind() == std::io::ErrorKind::InvalidInput {
            ImageError::Fatal(format!("cannot read it ({e})"))
        } else {
            ImageError::Skip(format!("cannot read it ({e})"))
        }
    })
}
