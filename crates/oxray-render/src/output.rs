//! Rendered images and their files: PNG (8-bit sRGB through a [`Look`]: an exposure and a tone
//! curve, see [`crate::tonemap`]) and OpenEXR (linear). Files are
//! written atomically (`oxray_scene::files::write_atomic`): to a temporary file in the target
//! folder, renamed into place once complete, so a failed or killed write never leaves a
//! truncated image nor loses the previous one.

use crate::tonemap::Look;
use std::path::Path;

/// The keyword and text of the PNG text chunk that marks an image as written by oxray.
pub const PNG_SOFTWARE: (&str, &str) = ("Software", "oxray");

/// Whether `path` is a PNG file that oxray wrote (it carries the [`PNG_SOFTWARE`] text
/// chunk): the `oxray` tool replaces such a file under its default output name, and no other.
#[must_use]
pub fn written_by_oxray(path: &Path) -> bool {
    let Ok(file) = std::fs::File::open(path) else {
        return false;
    };
    let decoder = png::Decoder::new(std::io::BufReader::new(file));
    let Ok(reader) = decoder.read_info() else {
        return false;
    };
    reader
        .info()
        .uncompressed_latin1_text
        .iter()
        .any(|t| t.keyword == PNG_SOFTWARE.0 && t.text == PNG_SOFTWARE.1)
}

/// A linear RGBA image, row-major from the top row.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Linear radiance; alpha is 1.
    pub pixels: Vec<[f32; 4]>,
}

impl Image {
    /// The image as 8-bit sRGB RGBA through the default [`Look`] (ACES, no exposure).
    #[must_use]
    pub fn to_srgb8(&self) -> Vec<u8> {
        self.to_srgb8_with(&Look::default())
    }

    /// The image as 8-bit sRGB RGBA through `look`.
    #[must_use]
    pub fn to_srgb8_with(&self, look: &Look) -> Vec<u8> {
        self.pixels
            .iter()
            .flat_map(|p| {
                let [r, g, b] = look.srgb8([p[0], p[1], p[2]]);
                [r, g, b, 255]
            })
            .collect()
    }

    /// Writes the image atomically with the default [`Look`]; the extension picks the format:
    /// `.exr` is linear 32-bit float RGBA, `.png` 8-bit sRGB, anything else an error.
    pub fn save(&self, path: &Path) -> Result<(), String> {
        self.save_with(path, &Look::default())
    }

    /// Writes the image atomically, a PNG through `look` (an EXR stays linear, as rendered).
    pub fn save_with(&self, path: &Path, look: &Look) -> Result<(), String> {
        let ext = oxray_scene::file_extension(path);
        let name = path.display();
        match ext.as_deref() {
            Some("exr") => write_atomic(path, |tmp| self.write_exr(tmp))
                .map_err(|e| format!("cannot write {name}: {e}")),
            Some("png") => write_atomic(path, |tmp| self.write_png(tmp, look))
                .map_err(|e| format!("cannot write {name}: {e}")),
            _ => Err(format!(
                "cannot write {name}: unknown image format (expected .png or .exr)"
            )),
        }
    }

    fn write_png(&self, path: &Path, look: &Look) -> Result<(), WriteError> {
        let mut file = std::io::BufWriter::new(std::fs::File::create(path)?);
        let mut enc = png::Encoder::new(&mut file, self.width, self.height);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        enc.add_text_chunk(PNG_SOFTWARE.0.into(), PNG_SOFTWARE.1.into())?;
        let mut writer = enc.write_header()?;
        writer.write_image_data(&self.to_srgb8_with(look))?;
        // Finishing and flushing report the errors of the last bytes (a full disk).
        writer.finish()?;
        std::io::Write::flush(&mut file)?;
        Ok(())
    }

    fn write_exr(&self, path: &Path) -> Result<(), WriteError> {
        use exr::prelude::*;
        let w = self.width as usize;
        let channels = SpecificChannels::rgba(|Vec2(x, y): Vec2<usize>| {
            let p = self.pixels[y * w + x];
            (p[0], p[1], p[2], p[3])
        });
        Image::from_encoded_channels((w, self.height as usize), EXR_ENCODING, channels)
            .write()
            .to_file(path)?;
        Ok(())
    }
}

/// How EXR files are encoded: the library's fast lossless encoding (run lengths in tiles of
/// 64x64), its tiles stored in increasing order. The tiles are compressed in parallel; without
/// an order the file would hold them in the order they finish, so the same image could make
/// files of different bytes.
const EXR_ENCODING: exr::prelude::Encoding = exr::prelude::Encoding {
    line_order: exr::prelude::LineOrder::Increasing,
    ..exr::prelude::Encoding::FAST_LOSSLESS
};

/// Writes `image` (channels `R`, `G`, `B`, `A`) and `aovs` (layers `albedo.{R,G,B}`,
/// `normal.{X,Y,Z}`, `depth.Z`, `samples.Y`) as one linear 32-bit float OpenEXR file,
/// atomically ([`crate::Rendered::save_exr`]); with `noisy` (the render before denoising,
/// `image` being the denoised one), also the layer `noisy.{R,G,B}`.
pub(crate) fn write_layers_exr(
    path: &Path,
    image: &Image,
    aovs: Option<&crate::Aovs>,
    noisy: Option<&Image>,
) -> Result<(), String> {
    let name = path.display();
    if oxray_scene::file_extension(path).as_deref() != Some("exr") {
        return Err(format!(
            "cannot write {name}: AOVs are written to OpenEXR files (.exr)"
        ));
    }
    let n = image.pixels.len();
    if let Some(a) = aovs {
        let sizes = [
            a.albedo.len(),
            a.normal.len(),
            a.depth.len(),
            a.samples.len(),
        ];
        if (a.width, a.height) != (image.width, image.height) || sizes.iter().any(|&l| l != n) {
            return Err(format!(
                "cannot write {name}: the AOVs are not the image's size"
            ));
        }
    }
    if noisy
        .is_some_and(|i| (i.width, i.height) != (image.width, image.height) || i.pixels.len() != n)
    {
        return Err(format!(
            "cannot write {name}: the noisy image is not the image's size"
        ));
    }
    write_atomic(path, |tmp| {
        use exr::prelude::*;
        let channel =
            |name: &str, values: Vec<f32>| AnyChannel::new(name, FlatSamples::F32(values));
        let mut list: SmallVec<[AnyChannel<FlatSamples>; 4]> = SmallVec::new();
        for (c, label) in ["R", "G", "B", "A"].iter().enumerate() {
            list.push(channel(label, image.pixels.iter().map(|p| p[c]).collect()));
        }
        if let Some(a) = aovs {
            for (c, label) in ["albedo.R", "albedo.G", "albedo.B"].iter().enumerate() {
                list.push(channel(label, a.albedo.iter().map(|p| p[c]).collect()));
            }
            for (c, label) in ["normal.X", "normal.Y", "normal.Z"].iter().enumerate() {
                list.push(channel(label, a.normal.iter().map(|p| p[c]).collect()));
            }
            list.push(channel("depth.Z", a.depth.clone()));
            list.push(channel("samples.Y", a.samples.clone()));
        }
        if let Some(noisy) = noisy {
            for (c, label) in ["noisy.R", "noisy.G", "noisy.B"].iter().enumerate() {
                list.push(channel(label, noisy.pixels.iter().map(|p| p[c]).collect()));
            }
        }
        let layer = Layer::new(
            (image.width as usize, image.height as usize),
            LayerAttributes::named("oxray"),
            EXR_ENCODING,
            AnyChannels::sort(list),
        );
        exr::prelude::Image::from_layer(layer)
            .write()
            .to_file(tmp)
            .map_err(WriteError::from)
    })
    .map_err(|e| format!("cannot write {name}: {e}"))
}

/// Why an image could not be written: the message of the encoder or of the file system.
#[derive(Debug)]
pub struct WriteError(String);

impl std::fmt::Display for WriteError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl From<std::io::Error> for WriteError {
    fn from(e: std::io::Error) -> Self {
        WriteError(e.to_string())
    }
}

impl From<png::EncodingError> for WriteError {
    fn from(e: png::EncodingError) -> Self {
        WriteError(e.to_string())
    }
}

impl From<exr::error::Error> for WriteError {
    fn from(e: exr::error::Error) -> Self {
        WriteError(e.to_string())
    }
}

use oxray_scene::files::write_atomic;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pngs_follow_the_look() {
        use crate::tonemap::ToneMap;
        let img = Image {
            width: 2,
            height: 1,
            pixels: vec![[0.18, 0.18, 0.18, 1.0], [4.0, 0.5, 0.0, 1.0]],
        };
        let linear = Look {
            tone_map: ToneMap::Linear,
            exposure: 0.0,
        };
        assert_eq!(img.to_srgb8_with(&linear)[..4], [118, 118, 118, 255]);
        assert_eq!(img.to_srgb8_with(&linear)[4..7], [255, 188, 0]);
        assert_eq!(img.to_srgb8(), img.to_srgb8_with(&Look::default()));
        let path = std::env::temp_dir().join(format!("oxray-look-{}.png", std::process::id()));
        img.save_with(&path, &linear).unwrap();
        let decoder =
            png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size()];
        reader.next_frame(&mut buf).unwrap();
        std::fs::remove_file(&path).ok();
        assert_eq!(buf[..8], img.to_srgb8_with(&linear)[..]);
    }

    #[test]
    fn exr_round_trips_linear_values() {
        let img = Image {
            width: 3,
            height: 2,
            pixels: (0..6).map(|i| [i as f32 * 1.5, 0.25, 100.0, 1.0]).collect(),
        };
        let path = std::env::temp_dir().join(format!("oxray-exr-{}.exr", std::process::id()));
        img.save(&path).unwrap();
        let back = exr::prelude::read_first_rgba_layer_from_file(
            &path,
            |res, _| vec![[0f32; 4]; res.width() * res.height()],
            |px: &mut Vec<[f32; 4]>, pos, (r, g, b, a): (f32, f32, f32, f32)| {
                px[pos.y() * 3 + pos.x()] = [r, g, b, a];
            },
        )
        .unwrap();
        std::fs::remove_file(&path).ok();
        assert_eq!(back.layer_data.channel_data.pixels, img.pixels);
        assert!(img
            .save(Path::new("x.bmp"))
            .unwrap_err()
            .contains("unknown image format"));
    }

    #[test]
    fn exr_files_hold_their_tiles_in_order() {
        // Tiles compressed in parallel, stored in increasing order: the same image makes the
        // same bytes, whichever tile finished first.
        let (w, h) = (300u32, 200u32);
        let img = Image {
            width: w,
            height: h,
            pixels: (0..w * h)
                .map(|i| [(i % 97) as f32 * 0.1, (i / w) as f32, 0.5, 1.0])
                .collect(),
        };
        let dir = std::env::temp_dir();
        let paths: Vec<_> = (0..3)
            .map(|k| dir.join(format!("oxray-tiles-{}-{k}.exr", std::process::id())))
            .collect();
        for p in &paths {
            img.save(p).unwrap();
        }
        let bytes: Vec<Vec<u8>> = paths.iter().map(|p| std::fs::read(p).unwrap()).collect();
        let meta = exr::meta::MetaData::read_from_file(&paths[0], false).unwrap();
        for p in &paths {
            std::fs::remove_file(p).ok();
        }
        assert_eq!(
            meta.headers[0].line_order,
            exr::meta::attribute::LineOrder::Increasing
        );
        assert!(meta.headers[0].chunk_count > 4, "one tile proves nothing");
        assert!(bytes.windows(2).all(|b| b[0] == b[1]));
    }
}
