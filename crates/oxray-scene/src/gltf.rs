//! The glTF 2.0 loader: `.gltf` files with external or `data:` buffers and images, and `.glb`
//! files with an embedded binary chunk.
//!
//! The `gltf` crate parses and validates the JSON, but some of its accessors index or unwrap
//! without checking (a GLB header shorter than itself, an accessor with zero elements, an image
//! with a buffer view and no MIME type, a POSITION accessor index beyond the accessor list).
//! This loader therefore splits GLB files itself, checks the references that validation reads
//! unchecked, checks every accessor's bounds, types and sizes before handing it to the crate's
//! reader, and reads images and cameras from the JSON directly. Buffer views compressed with
//! `EXT_meshopt_compression` / `KHR_meshopt_compression` are decoded first, by meshoptimizer.

mod compression;

use super::animation::{Animation, Channel, Interpolation, Property};
use super::image::ImageError;
use super::{
    image, AlphaMode, Camera, InstanceDesc, LightKind, MaterialDesc, MeshDesc, NodeDesc, Primitive,
    PunctualLight, SceneDesc, SceneError, Texture, TextureRef, Wrap,
};
use ::gltf::json;
use ::gltf::mesh::{Mode, Semantic};
use ::gltf::{accessor::DataType, accessor::Dimensions, Accessor, Document};
use glam::{Mat4, Quat, Vec3};
use rayon::prelude::*;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Elements an accessor without a buffer view may declare: such an accessor is all zeros (plus
/// sparse values), so its count is not bounded by any data, and a larger count would let a tiny
/// file ask for gigabytes.
const MAX_ZERO_FILLED: usize = 1 << 20;

/// Decoded geometry a file may expand to, beyond [`EXPANSION`] times its own size: primitives
/// that share one accessor each get a copy, so a small file could otherwise ask for unbounded
/// memory.
const BASE_BUDGET: usize = 256 << 20;

/// See [`BASE_BUDGET`].
const EXPANSION: usize = 64;

/// Loads a `.gltf` or `.glb` file: the default scene (or the first, or every root node when the
/// file has no scenes), its meshes, materials, textures and perspective cameras. Textures that
/// cannot be read or decoded, unsupported primitive modes and orthographic cameras become
/// warnings; malformed JSON, missing buffers and out-of-range data are errors.
pub fn load(path: &Path) -> Result<SceneDesc, SceneError> {
    load_impl(path, true)
}

/// [`load`], optionally without decoding textures (for callers that only need the geometry; the
/// materials then have no texture references).
pub(crate) fn load_impl(path: &Path, textures: bool) -> Result<SceneDesc, SceneError> {
    let name = path.display().to_string();
    let bytes = crate::files::read_input(path).map_err(|e| SceneError::Io {
        path: name.clone(),
        message: e.to_string(),
    })?;
    let malformed = |message: String| SceneError::Malformed {
        path: name.clone(),
        message,
    };
    let (json_bytes, bin) = if bytes.starts_with(b"glTF") {
        split_glb(&bytes).map_err(malformed)?
    } else {
        (&bytes[..], None)
    };
    let (root, plan) = parse_root(json_bytes).map_err(malformed)?;
    let extension_warning = check_extensions(&root).map_err(malformed)?;
    check_references(&root).map_err(malformed)?;
    validate_json(&root).map_err(malformed)?;
    let doc = Document::from_json_without_validation(root);
    let base = path.parent().unwrap_or(Path::new("."));
    let mut sources = vec![path.to_path_buf()];
    let mut buffers = load_buffers(&doc, base, bin, &name, &mut sources, &plan.fallback)?;
    let input_size = bytes.len() + buffers.iter().map(Vec::len).sum::<usize>();
    let mut budget = BASE_BUDGET.saturating_add(input_size.saturating_mul(EXPANSION));
    let mut warnings = Vec::new();
    let doc = if plan.views.is_empty() {
        doc
    } else {
        let mut decompress = Decompress {
            base,
            name: &name,
            buffers: &mut buffers,
            budget: &mut budget,
            sources: &mut sources,
            warnings: &mut warnings,
        };
        decompress.run(doc, plan).map_err(malformed)?
    };
    let mut loader = Loader {
        name: name.clone(),
        doc: &doc,
        buffers: &buffers,
        budget,
        quantized: doc
            .as_json()
            .extensions_used
            .iter()
            .chain(&doc.as_json().extensions_required)
            .any(|e| e == "KHR_mesh_quantization"),
        dropped: Default::default(),
        scene: SceneDesc {
            sources,
            ..Default::default()
        },
    };
    loader
        .scene
        .warnings
        .extend(extension_warning.map(|w| format!("{name}: {w}")));
    loader.scene.warnings.append(&mut warnings);
    loader.materials(base, textures).map_err(malformed)?;
    loader.meshes().map_err(malformed)?;
    loader.nodes().map_err(malformed)?;
    loader.animations();
    let scene = loader.scene;
    scene.validate().map_err(malformed)?;
    Ok(scene)
}

/// Splits a GLB file into its JSON chunk and optional binary chunk.
fn split_glb(b: &[u8]) -> Result<(&[u8], Option<&[u8]>), String> {
    let word = |o: usize| -> Option<usize> {
        let s = b.get(o..o.checked_add(4)?)?;
        Some(u32::from_le_bytes([s[0], s[1], s[2], s[3]]) as usize)
    };
    let (Some(version), Some(length)) = (word(4), word(8)) else {
        return Err(format!(
            "truncated GLB: {} bytes is shorter than its header",
            b.len()
        ));
    };
    if version == 1 {
        return Err(GLTF1.into());
    }
    if version != 2 {
        return Err(format!("unsupported GLB version {version} (expected 2)"));
    }
    if length > b.len() {
        return Err(format!(
            "truncated GLB: the header says {length} bytes but the file has {}",
            b.len()
        ));
    }
    if length < 12 {
        return Err(format!("bad GLB length {length}"));
    }
    let b = &b[..length];
    let (mut json, mut bin) = (None, None);
    let mut pos = 12;
    while pos < length {
        let (Some(len), Some(ty)) = (word(pos), b.get(pos + 4..pos + 8)) else {
            return Err(format!(
                "truncated GLB: chunk header at byte {pos} is cut off"
            ));
        };
        let start = pos + 8;
        let end = start
            .checked_add(len)
            .filter(|&e| e <= length)
            .ok_or_else(|| {
                format!("truncated GLB: chunk at byte {pos} ({len} bytes) extends past the end")
            })?;
        match ty {
            b"JSON" if json.is_none() => json = Some(&b[start..end]),
            b"BIN\0" if json.is_some() && bin.is_none() => bin = Some(&b[start..end]),
            b"JSON" | b"BIN\0" => return Err(format!("unexpected GLB chunk at byte {pos}")),
            // Unknown chunk types are skipped, as the specification asks.
            _ => {}
        }
        pos = end;
    }
    let json = json.ok_or("GLB has no JSON chunk")?;
    Ok((json, bin))
}

const GLTF1: &str = "this is a glTF 1.0 file; oxray reads glTF 2.0 only (convert it, for example with gltf-pipeline or Blender)";

/// Parses the JSON document: glTF 1.0 is recognised and named, and what glTF 2.0 allows but
/// the `gltf` crate refuses is mended first (a scene without `nodes`). The meshopt compression
/// of buffer views, which the crate drops, is read from the JSON here.
fn parse_root(bytes: &[u8]) -> Result<(json::Root, compression::Plan), String> {
    let mut value: json::Value =
        json::deserialize::from_slice(bytes).map_err(|e| format!("invalid glTF JSON: {e}"))?;
    let version = value
        .get("asset")
        .and_then(|a| a.get("version"))
        .and_then(|v| v.as_str());
    // glTF 1.0 keeps its objects in dictionaries, 2.0 in arrays.
    let dictionaries = ["meshes", "accessors", "nodes", "scenes"]
        .iter()
        .any(|k| value.get(k).is_some_and(|v| v.is_object()));
    if version.is_some_and(|v| v.starts_with("1.")) || version.is_none() && dictionaries {
        return Err(GLTF1.into());
    }
    if let Some(scenes) = value.get_mut("scenes").and_then(|s| s.as_array_mut()) {
        for scene in scenes.iter_mut().filter_map(|s| s.as_object_mut()) {
            scene
                .entry("nodes")
                .or_insert_with(|| json::Value::Array(Vec::new()));
        }
    }
    let plan = compression::Plan::scan(&value);
    let root =
        json::deserialize::from_value(value).map_err(|e| format!("invalid glTF JSON: {e}"))?;
    Ok((root, plan))
}

/// Extensions whose data oxray reads.
const READ_EXTENSIONS: &[&str] = &[
    "EXT_meshopt_compression",
    "KHR_meshopt_compression",
    "KHR_mesh_quantization",
    "KHR_texture_transform",
    "KHR_materials_emissive_strength",
    "KHR_materials_transmission",
    "KHR_materials_ior",
    "KHR_materials_specular",
    "KHR_lights_punctual",
];

/// A required extension oxray cannot read is an error that names it; used extensions it
/// ignores are named once, in one warning (returned).
fn check_extensions(root: &json::Root) -> Result<Option<String>, String> {
    if let Some(ext) = root
        .extensions_required
        .iter()
        .find(|e| !READ_EXTENSIONS.contains(&e.as_str()))
    {
        let what = match ext.as_str() {
            "KHR_draco_mesh_compression" => " (Draco-compressed geometry)",
            "KHR_texture_basisu" => " (KTX2/Basis Universal textures)",
            _ => "",
        };
        return Err(format!(
            "the file requires extension {ext}{what}, which oxray does not support"
        ));
    }
    let mut ignored: Vec<&str> = root
        .extensions_used
        .iter()
        .map(String::as_str)
        .filter(|e| !READ_EXTENSIONS.contains(e))
        .collect();
    ignored.sort_unstable();
    ignored.dedup();
    Ok((!ignored.is_empty()).then(|| {
        format!(
            "ignoring extension{} {} (not supported by oxray)",
            if ignored.len() > 1 { "s" } else { "" },
            ignored.join(", ")
        )
    }))
}

/// Checks the references that the `gltf` crate's validation dereferences before checking them.
fn check_references(root: &json::Root) -> Result<(), String> {
    for (mi, mesh) in root.meshes.iter().enumerate() {
        for (pi, prim) in mesh.primitives.iter().enumerate() {
            for (semantic, index) in &prim.attributes {
                if index.value() >= root.accessors.len() {
                    return Err(format!(
                        "meshes[{mi}].primitives[{pi}].attributes: {} refers to missing accessor {}",
                        match semantic {
                            json::validation::Checked::Valid(s) => s.to_string(),
                            json::validation::Checked::Invalid => "an attribute".into(),
                        },
                        index.value()
                    ));
                }
            }
        }
    }
    Ok(())
}

/// Runs the `gltf` crate's validation and reports the first problem. A POSITION accessor without
/// `min`/`max` is tolerated: the bounds are not needed and many exporters omit them.
fn validate_json(root: &json::Root) -> Result<(), String> {
    use json::validation::Validate;
    let mut errors = Vec::new();
    root.validate(root, json::Path::new, &mut |path, error| {
        let path = path().to_string();
        let bounds = path.ends_with(".min") || path.ends_with(".max");
        // Extensions are checked by `check_extensions`; an accessor without a buffer view is
        // zero-filled, as the specification allows.
        let handled = path.starts_with("extensionsRequired")
            || path.starts_with("accessors[")
                && path.ends_with(".bufferView")
                && matches!(error, json::validation::Error::Missing);
        if !(bounds && path.contains("POSITION") || handled) {
            errors.push(format!("{path}: {error}"));
        }
    });
    match errors.len() {
        0 => Ok(()),
        1 => Err(format!("invalid glTF: {}", errors[0])),
        n => Err(format!(
            "invalid glTF: {} (and {} more problems)",
            errors[0],
            n - 1
        )),
    }
}

/// Reads every buffer: the GLB binary chunk, a `data:` URI or a file next to the glTF file.
/// Fallback buffers of meshopt compression (`fallback[i]`) are left empty: they are read only
/// where a view cannot be decoded (their files are still listed in `sources`).
fn load_buffers(
    doc: &Document,
    base: &Path,
    mut bin: Option<&[u8]>,
    name: &str,
    sources: &mut Vec<PathBuf>,
    fallback: &[bool],
) -> Result<Vec<Vec<u8>>, SceneError> {
    let mut out = Vec::new();
    for buffer in doc.buffers() {
        if fallback.get(buffer.index()).copied().unwrap_or(false) {
            if let ::gltf::buffer::Source::Uri(uri) = buffer.source() {
                if let (false, Ok(p)) = (uri.starts_with("data:"), uri_path(uri)) {
                    sources.push(base.join(p));
                }
            }
            out.push(Vec::new());
            continue;
        }
        let uri = match buffer.source() {
            ::gltf::buffer::Source::Bin => None,
            ::gltf::buffer::Source::Uri(uri) => Some(uri),
        };
        let i = buffer.index();
        out.push(read_buffer(
            i,
            uri,
            buffer.length(),
            base,
            &mut bin,
            name,
            sources,
        )?);
    }
    Ok(out)
}

/// Reads buffer `i` of `length` bytes (see [`load_buffers`]); a buffer without URI takes the
/// GLB binary chunk.
fn read_buffer(
    i: usize,
    uri: Option<&str>,
    length: usize,
    base: &Path,
    bin: &mut Option<&[u8]>,
    name: &str,
    sources: &mut Vec<PathBuf>,
) -> Result<Vec<u8>, SceneError> {
    let malformed = |message: String| SceneError::Malformed {
        path: name.to_string(),
        message,
    };
    let data = match uri {
        None => bin
            .take()
            .ok_or_else(|| malformed(format!("buffer {i} refers to a missing GLB binary chunk")))?
            .to_vec(),
        Some(uri) => {
            if let Some(data) = uri.strip_prefix("data:") {
                decode_data_uri(data)
                    .map_err(|e| malformed(format!("buffer {i}: bad data URI ({e})")))?
            } else {
                let file = base.join(uri_path(uri).map_err(|e| {
                    malformed(format!("buffer {i}: unsupported URI {uri:?} ({e})"))
                })?);
                if !sources.contains(&file) {
                    sources.push(file.clone());
                }
                crate::files::read_input(&file).map_err(|e| SceneError::Io {
                    path: name.to_string(),
                    message: format!("buffer {i}: cannot read {} ({e})", file.display()),
                })?
            }
        }
    };
    if data.len() < length {
        return Err(malformed(format!(
            "buffer {i} has {} bytes but its byteLength is {length}",
            data.len(),
        )));
    }
    Ok(data)
}

/// Decodes the meshopt-compressed buffer views of a file: each decoded view gets a buffer of
/// its own (appended to `buffers`, the view pointing at it from offset 0). A view that cannot be
/// decoded is an error when the file requires the extension; otherwise its uncompressed
/// fallback data is read instead, as the extension's specification asks, with a warning.
struct Decompress<'a> {
    base: &'a Path,
    name: &'a str,
    buffers: &'a mut Vec<Vec<u8>>,
    /// Decoded bytes still allowed (shared with the geometry's budget).
    budget: &'a mut usize,
    sources: &'a mut Vec<PathBuf>,
    warnings: &'a mut Vec<String>,
}

impl Decompress<'_> {
    fn run(&mut self, doc: Document, plan: compression::Plan) -> Result<Document, String> {
        let mut root = doc.into_json();
        for (vi, ext, compressed) in plan.views {
            let Some(view) = root.buffer_views.get(vi) else {
                continue;
            };
            let view_len = view.byte_length.0 as usize;
            let view_stride = view.byte_stride.map(|s| s.0);
            match compressed.and_then(|c| self.decode(&c, view_len, view_stride)) {
                Ok(bytes) => {
                    let mut buffer = root
                        .buffers
                        .get(view.buffer.value())
                        .cloned()
                        .ok_or_else(|| format!("buffer view {vi} refers to a missing buffer"))?;
                    buffer.uri = None;
                    buffer.extensions = None;
                    buffer.byte_length = json::validation::USize64(bytes.len() as u64);
                    let view = &mut root.buffer_views[vi];
                    view.buffer = json::Index::new(root.buffers.len() as u32);
                    view.byte_offset = Some(json::validation::USize64(0));
                    root.buffers.push(buffer);
                    self.buffers.push(bytes);
                }
                Err(e) => {
                    if root.extensions_required.iter().any(|r| r == ext) {
                        return Err(format!(
                            "buffer view {vi}: cannot decode its {ext} data ({e})"
                        ));
                    }
                    let b = view.buffer.value();
                    let have = self.buffers.get(b).is_some_and(|d| !d.is_empty());
                    if !have && plan.fallback.get(b).copied().unwrap_or(false) {
                        self.read_fallback(&root, b).map_err(|f| {
                            format!("buffer view {vi}: cannot decode its {ext} data ({e}), and its fallback buffer {b} {f}")
                        })?;
                    }
                    self.warnings.push(format!(
                        "{}: buffer view {vi}: cannot decode its {ext} data ({e}); using the uncompressed fallback",
                        self.name
                    ));
                }
            }
        }
        Ok(Document::from_json_without_validation(root))
    }

    /// Decodes one view after checking it against the budget; the result is the view's length
    /// (the decoded bytes, zero-padded where the view is longer).
    fn decode(
        &mut self,
        c: &compression::Compressed,
        view_len: usize,
        view_stride: Option<usize>,
    ) -> Result<Vec<u8>, String> {
        compression::check(c)?;
        if c.mode == compression::Mode::Attributes && view_stride.is_some_and(|s| s != c.stride) {
            return Err(format!(
                "byteStride {} differs from the buffer view's {}",
                c.stride,
                view_stride.unwrap_or(0)
            ));
        }
        let len = c.decoded_len().ok_or("the decoded size overflows")?;
        if len > view_len {
            return Err(format!(
                "{} elements of {} bytes do not fit in the {view_len}-byte buffer view",
                c.count, c.stride
            ));
        }
        if view_len > *self.budget {
            return Err(format!(
                "{view_len} decoded bytes are more than the file's size allows"
            ));
        }
        let source = self
            .buffers
            .get(c.buffer)
            .ok_or_else(|| format!("buffer {} does not exist", c.buffer))?;
        let mut bytes = compression::decode(c, source)?;
        *self.budget -= view_len;
        bytes.resize(view_len, 0);
        Ok(bytes)
    }

    /// Reads fallback buffer `b`, which [`load_buffers`] skipped.
    fn read_fallback(&mut self, root: &json::Root, b: usize) -> Result<(), String> {
        let buffer = &root.buffers[b];
        let Some(uri) = &buffer.uri else {
            return Err("has no data".into());
        };
        let length = buffer.byte_length.0 as usize;
        let data = read_buffer(
            b,
            Some(uri),
            length,
            self.base,
            &mut None,
            self.name,
            self.sources,
        )
        .map_err(|e| {
            let e = crate::strip_path(&e.to_string(), self.name);
            let prefix = format!("buffer {b}: ");
            e.strip_prefix(&prefix).unwrap_or(&e).to_string()
        })?;
        self.buffers[b] = data;
        Ok(())
    }
}

/// Turns a relative URI into a relative path: percent-decoded, without scheme.
fn uri_path(uri: &str) -> Result<String, String> {
    if let Some(colon) = uri.find(':') {
        let scheme = &uri[..colon];
        // A one-letter "scheme" is a Windows drive letter, not a scheme.
        if scheme.len() > 1
            && scheme
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c))
        {
            return Err(format!("the {scheme}: scheme is not supported"));
        }
    }
    let b = uri.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = b
                .get(i + 1..i + 3)
                .and_then(|h| std::str::from_utf8(h).ok())
                .and_then(|h| u8::from_str_radix(h, 16).ok())
                .ok_or("bad percent escape")?;
            out.push(hex);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).map_err(|_| "the decoded path is not UTF-8".into())
}

/// Decodes the part of a `data:` URI after the scheme: `[mediatype][;base64],payload`.
fn decode_data_uri(data: &str) -> Result<Vec<u8>, String> {
    let (meta, payload) = data.split_once(',').ok_or("no comma")?;
    if !meta.ends_with(";base64") {
        return Err("only base64 data URIs are supported".into());
    }
    base64(payload)
}

/// Standard base64 (padding optional, whitespace ignored).
fn base64(s: &str) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(s.len() / 4 * 3 + 3);
    let (mut acc, mut bits) = (0u32, 0u32);
    for c in s.bytes() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            b'=' => break,
            c if c.is_ascii_whitespace() => continue,
            c => return Err(format!("invalid base64 character {:?}", c as char)),
        };
        acc = (acc << 6) | v as u32;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    Ok(out)
}

/// The accessor layouts a semantic accepts.
#[derive(Clone, Copy)]
enum Kind {
    /// POSITION, NORMAL: VEC3 of FLOAT.
    Vec3,
    /// TEXCOORD_n: VEC2 of FLOAT, normalized UNSIGNED_BYTE or normalized UNSIGNED_SHORT.
    Uv,
    /// COLOR_0: VEC3 or VEC4 of FLOAT, normalized UNSIGNED_BYTE or normalized UNSIGNED_SHORT
    /// (`KHR_mesh_quantization` adds nothing here).
    Color,
    /// Indices: SCALAR of UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT.
    Index,
    /// Animation keyframe times: SCALAR of FLOAT.
    Times,
    /// Animated translation or scale: VEC3 of FLOAT.
    Motion3,
    /// Animated rotation: VEC4 of FLOAT or normalized BYTE, UNSIGNED_BYTE, SHORT or
    /// UNSIGNED_SHORT.
    Rotation,
}

impl Kind {
    fn accepts(self, dims: Dimensions, ty: DataType) -> bool {
        match self {
            // KHR_mesh_quantization adds (normalized or not) 8- and 16-bit integers.
            Kind::Vec3 => {
                dims == Dimensions::Vec3
                    && matches!(
                        ty,
                        DataType::F32 | DataType::I8 | DataType::U8 | DataType::I16 | DataType::U16
                    )
            }
            Kind::Uv => {
                dims == Dimensions::Vec2
                    && matches!(
                        ty,
                        DataType::F32 | DataType::I8 | DataType::U8 | DataType::I16 | DataType::U16
                    )
            }
            Kind::Color => {
                matches!(dims, Dimensions::Vec3 | Dimensions::Vec4)
                    && matches!(ty, DataType::F32 | DataType::U8 | DataType::U16)
            }
            Kind::Index => {
                dims == Dimensions::Scalar
                    && matches!(ty, DataType::U8 | DataType::U16 | DataType::U32)
            }
            Kind::Times => dims == Dimensions::Scalar && ty == DataType::F32,
            Kind::Motion3 => dims == Dimensions::Vec3 && ty == DataType::F32,
            Kind::Rotation => {
                dims == Dimensions::Vec4
                    && matches!(
                        ty,
                        DataType::F32 | DataType::I8 | DataType::U8 | DataType::I16 | DataType::U16
                    )
            }
        }
    }

    fn describe(self) -> &'static str {
        match self {
            Kind::Vec3 => "VEC3 of FLOAT, BYTE, UNSIGNED_BYTE, SHORT or UNSIGNED_SHORT",
            Kind::Uv => "VEC2 of FLOAT, BYTE, UNSIGNED_BYTE, SHORT or UNSIGNED_SHORT",
            Kind::Color => {
                "VEC3 or VEC4 of FLOAT, normalized UNSIGNED_BYTE or normalized UNSIGNED_SHORT"
            }
            Kind::Index => "SCALAR of UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT",
            Kind::Times => "SCALAR of FLOAT",
            Kind::Motion3 => "VEC3 of FLOAT",
            Kind::Rotation => {
                "VEC4 of FLOAT or normalized BYTE, UNSIGNED_BYTE, SHORT or UNSIGNED_SHORT"
            }
        }
    }

    /// Bytes one element takes once decoded.
    fn decoded_size(self) -> usize {
        match self {
            Kind::Vec3 => 12,
            Kind::Uv => 8,
            Kind::Color | Kind::Rotation => 16,
            Kind::Index | Kind::Times => 4,
            Kind::Motion3 => 12,
        }
    }
}

/// Where an accessor's data lives, after checking.
enum Layout {
    /// The crate's reader can read it: every byte it touches is inside its buffer.
    Readable,
    /// No buffer view and no sparse values: `count` zeros.
    Zeros,
}

struct Loader<'a> {
    name: String,
    doc: &'a Document,
    buffers: &'a [Vec<u8>],
    /// Bytes of decoded geometry still allowed.
    budget: usize,
    /// Whether the file uses `KHR_mesh_quantization` (integer positions and normals).
    quantized: bool,
    /// Optional attributes dropped, by name: how many primitives, and the first reason.
    dropped: std::collections::BTreeMap<&'static str, (usize, String)>,
    scene: SceneDesc,
}

impl Loader<'_> {
    fn warn(&mut self, message: String) {
        self.scene
            .warnings
            .push(format!("{}: {message}", self.name));
    }

    /// Checks that `range` (relative to the view) of buffer view `view` lies inside its buffer,
    /// and that elements of `elem` bytes at `stride` fit in it.
    fn check_view(
        &self,
        view: &::gltf::buffer::View,
        offset: usize,
        count: usize,
        elem: usize,
        what: &str,
    ) -> Result<(), String> {
        let buffer_len = self.buffers.get(view.buffer().index()).map_or(0, Vec::len);
        let view_end = view.offset().checked_add(view.length());
        if view_end.is_none_or(|e| e > buffer_len) {
            return Err(format!(
                "{what}: buffer view {} (bytes {}..+{}) lies outside its {buffer_len}-byte buffer",
                view.index(),
                view.offset(),
                view.length()
            ));
        }
        let stride = view.stride().unwrap_or(elem);
        if stride < elem {
            return Err(format!(
                "{what}: byteStride {stride} is smaller than the {elem}-byte element"
            ));
        }
        let end = count
            .checked_sub(1)
            .and_then(|c| c.checked_mul(stride))
            .and_then(|b| b.checked_add(elem))
            .and_then(|b| b.checked_add(offset));
        if end.is_none_or(|e| e > view.length()) {
            return Err(format!(
                "{what}: {count} elements at byte offset {offset} do not fit in buffer view {} ({} bytes)",
                view.index(),
                view.length()
            ));
        }
        Ok(())
    }

    /// Checks an accessor's type, bounds and size before the crate's reader touches it, and
    /// charges its decoded size to the budget.
    fn check_accessor(&mut self, a: &Accessor, kind: Kind) -> Result<Layout, String> {
        let what = format!("accessor {}", a.index());
        // Core glTF 2.0 allows integer vertex data only for normalized texture coordinates;
        // KHR_mesh_quantization allows the rest.
        let core = match kind {
            Kind::Vec3 => a.data_type() == DataType::F32,
            Kind::Uv | Kind::Color => {
                a.data_type() == DataType::F32
                    || a.normalized() && matches!(a.data_type(), DataType::U8 | DataType::U16)
            }
            Kind::Index | Kind::Times | Kind::Motion3 => true,
            Kind::Rotation => a.data_type() == DataType::F32 || a.normalized(),
        };
        if !core && matches!(kind, Kind::Color | Kind::Rotation) {
            return Err(format!(
                "{what}: {:?} of {:?}{} where {} is expected",
                a.dimensions(),
                a.data_type(),
                if a.normalized() {
                    ""
                } else {
                    " (not normalized)"
                },
                kind.describe()
            ));
        }
        if !core && !self.quantized {
            return Err(format!(
                "{what}: {:?} of {:?} needs KHR_mesh_quantization, which the file does not list in extensionsUsed",
                a.dimensions(),
                a.data_type(),
            ));
        }
        if !kind.accepts(a.dimensions(), a.data_type()) {
            return Err(format!(
                "{what}: {:?} of {:?} where {} is expected",
                a.dimensions(),
                a.data_type(),
                kind.describe()
            ));
        }
        let count = a.count();
        if count == 0 {
            return Err(format!("{what} has no elements"));
        }
        match a.view() {
            Some(view) => self.check_view(&view, a.offset(), count, a.size(), &what)?,
            None if count > MAX_ZERO_FILLED => {
                return Err(format!(
                    "{what}: {count} elements without a buffer view (at most {MAX_ZERO_FILLED})"
                ))
            }
            None => {}
        }
        let decoded = count.saturating_mul(kind.decoded_size());
        if decoded > self.budget {
            return Err(format!(
                "{what}: the file expands to more geometry than its size allows"
            ));
        }
        self.budget -= decoded;
        let Some(sparse) = a.sparse() else {
            return Ok(if a.view().is_some() {
                Layout::Readable
            } else {
                Layout::Zeros
            });
        };
        let n = sparse.count();
        if n == 0 || n > count {
            return Err(format!("{what}: sparse count {n} is not in 1..={count}"));
        }
        let indices = sparse.indices();
        let index_size = indices.index_type().size();
        self.check_view(
            &indices.view(),
            indices.offset(),
            n,
            index_size,
            &format!("{what} sparse indices"),
        )?;
        let values = sparse.values();
        self.check_view(
            &values.view(),
            values.offset(),
            n,
            a.size(),
            &format!("{what} sparse values"),
        )?;
        Ok(Layout::Readable)
    }

    fn buffer(&self, b: ::gltf::Buffer) -> Option<&[u8]> {
        self.buffers.get(b.index()).map(Vec::as_slice)
    }

    fn read_vec3(&mut self, a: &Accessor) -> Result<Vec<[f32; 3]>, String> {
        if let Layout::Zeros = self.check_accessor(a, Kind::Vec3)? {
            return Ok(vec![[0.0; 3]; a.count()]);
        }
        self.read_floats::<3>(a)
    }

    fn read_uv(&mut self, a: &Accessor) -> Result<Vec<[f32; 2]>, String> {
        if let Layout::Zeros = self.check_accessor(a, Kind::Uv)? {
            return Ok(vec![[0.0; 2]; a.count()]);
        }
        self.read_floats::<2>(a)
    }

    /// Reads COLOR_0 as linear RGBA (alpha 1 for RGB colours).
    fn read_color(&mut self, a: &Accessor) -> Result<Vec<[f32; 4]>, String> {
        let rgb = a.dimensions() == Dimensions::Vec3;
        if let Layout::Zeros = self.check_accessor(a, Kind::Color)? {
            let alpha = if rgb { 1.0 } else { 0.0 };
            return Ok(vec![[0.0, 0.0, 0.0, alpha]; a.count()]);
        }
        Ok(if rgb {
            self.read_floats::<3>(a)?
                .into_iter()
                .map(|[r, g, b]| [r, g, b, 1.0])
                .collect()
        } else {
            self.read_floats::<4>(a)?
        })
    }

    /// Reads an optional attribute of `n` vertices; one that cannot be used (bad layout, wrong
    /// count, over the budget) is dropped instead of failing the file, and named in one
    /// warning per attribute (see [`Loader::meshes`]).
    fn optional<T>(
        &mut self,
        at: &dyn Fn(String) -> String,
        name: &'static str,
        accessor: Option<Accessor>,
        n: usize,
        read: fn(&mut Self, &Accessor) -> Result<Vec<T>, String>,
    ) -> Vec<T> {
        let Some(a) = accessor else {
            return Vec::new();
        };
        let why = match read(self, &a) {
            Ok(v) if v.len() == n => return v,
            Ok(v) => format!("{} values for {n} positions", v.len()),
            Err(e) => e,
        };
        let entry = self.dropped.entry(name).or_insert((0, at(why)));
        entry.0 += 1;
        Vec::new()
    }

    /// Reads a checked accessor of `N` components as floats: integer components are
    /// normalized when the accessor says so (`c / 255`, `max(c / 127, -1)`, ...) and converted
    /// as they are otherwise (glTF 2.0 and `KHR_mesh_quantization`).
    fn read_floats<const N: usize>(&self, a: &Accessor) -> Result<Vec<[f32; N]>, String>
    where
        [f32; N]: ::gltf::accessor::Item,
        [i8; N]: ::gltf::accessor::Item,
        [u8; N]: ::gltf::accessor::Item,
        [i16; N]: ::gltf::accessor::Item,
        [u16; N]: ::gltf::accessor::Item,
    {
        use ::gltf::accessor::Iter;
        let err = || format!("accessor {} cannot be read", a.index());
        let get = |b| self.buffer(b);
        let norm = a.normalized();
        let conv = |x: f32, max: f32| if norm { (x / max).max(-1.0) } else { x };
        Ok(match a.data_type() {
            DataType::I8 => Iter::<[i8; N]>::new(a.clone(), get)
                .ok_or_else(err)?
                .map(|v| v.map(|c| conv(c as f32, 127.0)))
                .collect(),
            DataType::U8 => Iter::<[u8; N]>::new(a.clone(), get)
                .ok_or_else(err)?
                .map(|v| v.map(|c| conv(c as f32, 255.0)))
                .collect(),
            DataType::I16 => Iter::<[i16; N]>::new(a.clone(), get)
                .ok_or_else(err)?
                .map(|v| v.map(|c| conv(c as f32, 32767.0)))
                .collect(),
            DataType::U16 => Iter::<[u16; N]>::new(a.clone(), get)
                .ok_or_else(err)?
                .map(|v| v.map(|c| conv(c as f32, 65535.0)))
                .collect(),
            _ => Iter::<[f32; N]>::new(a.clone(), get)
                .ok_or_else(err)?
                .collect(),
        })
    }

    fn read_indices(&mut self, a: &Accessor) -> Result<Vec<u32>, String> {
        use ::gltf::accessor::Iter;
        let layout = self.check_accessor(a, Kind::Index)?;
        if let Layout::Zeros = layout {
            return Ok(vec![0; a.count()]);
        }
        let err = || format!("accessor {} cannot be read", a.index());
        let get = |b| self.buffer(b);
        Ok(match a.data_type() {
            DataType::U8 => Iter::<u8>::new(a.clone(), get)
                .ok_or_else(err)?
                .map(u32::from)
                .collect(),
            DataType::U16 => Iter::<u16>::new(a.clone(), get)
                .ok_or_else(err)?
                .map(u32::from)
                .collect(),
            _ => Iter::<u32>::new(a.clone(), get).ok_or_else(err)?.collect(),
        })
    }

    /// Converts every material, decoding the textures they use (in parallel).
    fn materials(&mut self, base: &Path, textures: bool) -> Result<(), String> {
        let root = self.doc.as_json();
        // Texture slots used by the materials, in order, as (material, slot, texture, texCoord).
        let mut materials = Vec::new();
        let mut wanted: Vec<usize> = Vec::new();
        for m in self.doc.materials() {
            let pbr = m.pbr_metallic_roughness();
            // KHR_texture_transform as (offset, rotation, scale); its texCoord override
            // replaces the slot's set.
            let khr = |info: &::gltf::texture::Info| {
                info.texture_transform().map(|t| {
                    (
                        (t.offset(), t.rotation(), t.scale()),
                        t.tex_coord().unwrap_or(info.tex_coord()),
                    )
                })
            };
            let info = |i: Option<::gltf::texture::Info>| {
                i.map(|t| match khr(&t) {
                    Some((tr, set)) => (t.texture().index(), set, Some(tr)),
                    None => (t.texture().index(), t.tex_coord(), None),
                })
            };
            let refs = [
                info(pbr.base_color_texture()),
                info(pbr.metallic_roughness_texture()),
                info(m.emissive_texture()),
                // The gltf crate exposes no transform on normal textures.
                m.normal_texture()
                    .map(|t| (t.texture().index(), t.tex_coord(), None)),
            ];
            let mut slots = [None; 4];
            for (slot, r) in refs.into_iter().enumerate() {
                let Some((texture, set, transform)) = r else {
                    continue;
                };
                if set > 1 {
                    self.warn(format!(
                        "material {} uses texture coordinate set {set}; only sets 0 and 1 are supported, so the texture is ignored",
                        m.index().unwrap_or(0)
                    ));
                    continue;
                }
                if transform.is_some_and(|(o, r, sc): ([f32; 2], f32, [f32; 2])| {
                    !(o.iter().chain(&sc).all(|x| x.is_finite()) && r.is_finite())
                }) {
                    return Err(format!(
                        "material {}: non-finite KHR_texture_transform",
                        m.index().unwrap_or(0)
                    ));
                }
                if textures {
                    slots[slot] = Some((texture, set, transform));
                    wanted.push(texture);
                }
            }
            let emissive_strength = m.emissive_strength().unwrap_or(1.0);
            let e = m.emissive_factor();
            let alpha_mode = match m.alpha_mode() {
                ::gltf::material::AlphaMode::Opaque => AlphaMode::Opaque,
                ::gltf::material::AlphaMode::Mask => AlphaMode::Mask {
                    cutoff: m.alpha_cutoff().unwrap_or(0.5),
                },
                ::gltf::material::AlphaMode::Blend => AlphaMode::Blend,
            };
            let ior = m.ior().unwrap_or(1.5);
            let desc = MaterialDesc {
                name: m
                    .name()
                    .map(str::to_string)
                    .unwrap_or_else(|| format!("material {}", m.index().unwrap_or(0))),
                base_color: pbr.base_color_factor(),
                base_color_texture: None,
                metallic: pbr.metallic_factor().clamp(0.0, 1.0),
                roughness: pbr.roughness_factor().clamp(0.0, 1.0),
                metallic_roughness_texture: None,
                emissive: e.map(|c| c * emissive_strength),
                emissive_texture: None,
                normal_texture: None,
                normal_scale: m.normal_texture().map_or(1.0, |n| n.scale()),
                alpha_mode,
                double_sided: m.double_sided(),
                transmission: m
                    .transmission()
                    .map_or(0.0, |t| t.transmission_factor())
                    .clamp(0.0, 1.0),
                // KHR_materials_ior allows 0 to mean "infinite"; anything below 1 is not a
                // physical dielectric, so fall back to the extension's default.
                ior: if ior.is_finite() && ior >= 1.0 {
                    ior
                } else {
                    1.5
                },
                // KHR_materials_specular's factor (its colour and textures are not read): 0
                // leaves a Lambertian diffuse surface under no specular coat.
                specular: m
                    .specular()
                    .map_or(1.0, |s| s.specular_factor())
                    .clamp(0.0, 1.0),
            };
            materials.push((desc, slots));
        }

        // Decode each image once, whatever number of textures and samplers use it.
        let mut images: Vec<usize> = wanted
            .iter()
            .filter_map(|&t| root.textures.get(t).map(|t| t.source.value()))
            .collect();
        images.sort_unstable();
        images.dedup();
        let mut sources = Vec::with_capacity(images.len());
        for &i in &images {
            let (label, file, bytes) = self.image_bytes(i, base);
            self.scene.sources.extend(file);
            sources.push((i, label, bytes));
        }
        // Every image's decoded size is checked against the limits before any is decoded.
        let mut sizes = Vec::new();
        for (_, label, bytes) in &sources {
            let size = match bytes {
                Ok(b) => image::decoded_size(b),
                Err(ImageError::Fatal(e)) => Err(ImageError::Fatal(e.clone())),
                Err(ImageError::Skip(_)) => continue,
            };
            match size {
                Ok(size) => sizes.push(size),
                Err(ImageError::Fatal(e)) => return Err(format!("texture {label}: {e}")),
                Err(ImageError::Skip(_)) => {}
            }
        }
        image::check_total(sizes)?;
        let decoded: Vec<(usize, String, Result<Texture, ImageError>)> = sources
            .into_par_iter()
            .map(|(i, label, bytes)| {
                let tex = bytes.and_then(|b| image::decode(&label, &b));
                (i, label, tex)
            })
            .collect();
        let mut decoded_by_image: HashMap<usize, Option<Texture>> = HashMap::new();
        for (i, label, tex) in decoded {
            match tex {
                Ok(t) => {
                    decoded_by_image.insert(i, Some(t));
                }
                Err(ImageError::Fatal(e)) => return Err(format!("texture {label}: {e}")),
                Err(ImageError::Skip(e)) => {
                    self.warn(format!("texture {label}: {e}; rendering without it"));
                    decoded_by_image.insert(i, None);
                }
            }
        }

        // One scene texture per (image, wrap_u, wrap_v).
        let mut by_key: HashMap<(usize, Wrap, Wrap), u32> = HashMap::new();
        let mut texture_ref = |t: usize, scene: &mut SceneDesc| -> Option<TextureRef> {
            let tj = root.textures.get(t)?;
            let image = tj.source.value();
            let img = decoded_by_image.get(&image)?.as_ref()?;
            let sampler = self.doc.textures().nth(t)?.sampler();
            let (wu, wv) = (wrap(sampler.wrap_s()), wrap(sampler.wrap_t()));
            let index = *by_key.entry((image, wu, wv)).or_insert_with(|| {
                scene.textures.push(Texture {
                    wrap_u: wu,
                    wrap_v: wv,
                    ..img.clone()
                });
                scene.textures.len() as u32 - 1
            });
            Some(TextureRef::new(index))
        };
        let mut scene = std::mem::take(&mut self.scene);
        for (mut desc, slots) in materials {
            let mut r = slots.map(|s| {
                s.and_then(|(t, set, transform)| {
                    let r = texture_ref(t, &mut scene)?.with_tex_coord(set);
                    Some(match transform {
                        Some((offset, rotation, scale)) => {
                            r.with_khr_transform(offset, rotation, scale)
                        }
                        None => r,
                    })
                })
            });
            desc.base_color_texture = r[0].take();
            desc.metallic_roughness_texture = r[1].take();
            desc.emissive_texture = r[2].take();
            desc.normal_texture = r[3].take();
            scene.materials.push(desc);
        }
        scene.warnings.append(&mut self.scene.warnings);
        self.scene = scene;
        Ok(())
    }

    /// The bytes of image `i`, a label for messages and the file read, if any; failing to get
    /// them is a warning, unless the file is not a regular file or is over the size limit.
    fn image_bytes(
        &self,
        i: usize,
        base: &Path,
    ) -> (String, Option<PathBuf>, Result<Vec<u8>, ImageError>) {
        let skip = |e: &str| Err(ImageError::Skip(e.to_string()));
        let Some(img) = self.doc.as_json().images.get(i) else {
            return (format!("image {i}"), None, skip("missing image"));
        };
        if let Some(view) = &img.buffer_view {
            let label = img.name.clone().unwrap_or_else(|| format!("image {i}"));
            let Some(v) = self.doc.views().nth(view.value()) else {
                return (label, None, skip("missing buffer view"));
            };
            let bytes = self
                .buffers
                .get(v.buffer().index())
                .and_then(|b| b.get(v.offset()..v.offset().checked_add(v.length())?));
            return match bytes {
                Some(b) => (label, None, Ok(b.to_vec())),
                None => (label, None, skip("buffer view lies outside its buffer")),
            };
        }
        let Some(uri) = &img.uri else {
            return (format!("image {i}"), None, skip("no uri or bufferView"));
        };
        if let Some(data) = uri.strip_prefix("data:") {
            let label = img.name.clone().unwrap_or_else(|| format!("image {i}"));
            return (
                label,
                None,
                decode_data_uri(data).map_err(|e| ImageError::Skip(format!("bad data URI ({e})"))),
            );
        }
        let label = uri.clone();
        match uri_path(uri) {
            Err(e) => (
                label,
                None,
                Err(ImageError::Skip(format!("unsupported URI ({e})"))),
            ),
            Ok(p) => {
                let file = base.join(p);
                let bytes = image::read_file(&file).map_err(|e| match e {
                    ImageError::Skip(e) => {
                        ImageError::Skip(e.replace("cannot read it", "cannot read"))
                    }
                    fatal => fatal,
                });
                (label, Some(file), bytes)
            }
        }
    }

    /// Converts every mesh; primitives without a material get a default one.
    fn meshes(&mut self) -> Result<(), String> {
        let mut default_material = None;
        let mut ignored = std::collections::BTreeSet::new();
        for mesh in self.doc.meshes() {
            let mi = mesh.index();
            let mut desc = MeshDesc {
                name: mesh
                    .name()
                    .map(str::to_string)
                    .unwrap_or_else(|| format!("mesh {mi}")),
                primitives: Vec::new(),
            };
            let mut skipped = false;
            for prim in mesh.primitives() {
                let pi = prim.index();
                for (semantic, _) in prim.attributes() {
                    // Tangents are derived from the positions and texture coordinates.
                    if !matches!(
                        semantic,
                        Semantic::Positions
                            | Semantic::Normals
                            | Semantic::Tangents
                            | Semantic::TexCoords(0 | 1)
                            | Semantic::Colors(0)
                    ) {
                        ignored.insert(semantic.to_string());
                    }
                }
                let mode = prim.mode();
                if !matches!(
                    mode,
                    Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
                ) {
                    skipped = true;
                    continue;
                }
                let at = |e: String| format!("mesh {mi} primitive {pi}: {e}");
                let Some(pos) = prim.get(&Semantic::Positions) else {
                    return Err(at("no POSITION attribute".into()));
                };
                let positions = self.read_vec3(&pos).map_err(at)?;
                let n = positions.len();
                let mut normals = match prim.get(&Semantic::Normals) {
                    Some(a) => self.read_vec3(&a).map_err(at)?,
                    None => Vec::new(),
                };
                if !normals.is_empty() && normals.len() != n {
                    self.warn(at(format!(
                        "{} normals for {n} positions; ignoring the normals",
                        normals.len()
                    )));
                    normals.clear();
                }
                let mut uvs = match prim.get(&Semantic::TexCoords(0)) {
                    Some(a) => self.read_uv(&a).map_err(at)?,
                    None => Vec::new(),
                };
                if !uvs.is_empty() && uvs.len() != n {
                    self.warn(at(format!(
                        "{} texture coordinates for {n} positions; ignoring them",
                        uvs.len()
                    )));
                    uvs.clear();
                }
                let uvs1 = self.optional(
                    &at,
                    "TEXCOORD_1",
                    prim.get(&Semantic::TexCoords(1)),
                    n,
                    Self::read_uv,
                );
                let colors = self.optional(
                    &at,
                    "COLOR_0",
                    prim.get(&Semantic::Colors(0)),
                    n,
                    Self::read_color,
                );
                let indices = match prim.indices() {
                    Some(a) => self.read_indices(&a).map_err(at)?,
                    None => (0..n as u32).collect(),
                };
                let triangles = assemble(mode, &indices);
                let material = match prim.material().index() {
                    Some(m) => m as u32,
                    None => *default_material.get_or_insert_with(|| {
                        self.scene.materials.push(MaterialDesc::default());
                        self.scene.materials.len() as u32 - 1
                    }),
                };
                desc.primitives.push(Primitive {
                    positions,
                    normals,
                    uvs,
                    uvs1,
                    colors,
                    triangles,
                    material,
                });
            }
            if skipped {
                self.warn(format!(
                    "mesh {mi} ({}): point and line primitives are not supported; skipping them",
                    desc.name
                ));
            }
            self.scene.meshes.push(desc);
        }
        for (name, (count, first)) in std::mem::take(&mut self.dropped) {
            let more = match count {
                1 => String::new(),
                n => format!(" (and in {} more primitives)", n - 1),
            };
            self.warn(format!("ignoring {name}: {first}{more}"));
        }
        if !ignored.is_empty() {
            let names: Vec<String> = ignored.into_iter().collect();
            self.warn(format!(
                "ignoring vertex attribute{} {} (oxray uses POSITION, NORMAL, TANGENT, TEXCOORD_0, TEXCOORD_1 and COLOR_0)",
                if names.len() > 1 { "s" } else { "" },
                names.join(", ")
            ));
        }
        Ok(())
    }

    /// Walks the node hierarchy of the scene to render: instances for nodes with a mesh and
    /// cameras for nodes with a perspective camera, both in node index order.
    fn nodes(&mut self) -> Result<(), String> {
        let doc = self.doc;
        let root = doc.as_json();
        let n = root.nodes.len();
        let roots: Vec<usize> = match doc.default_scene().or_else(|| doc.scenes().next()) {
            Some(s) => s.nodes().map(|n| n.index()).collect(),
            None => {
                let mut is_child = vec![false; n];
                for node in &root.nodes {
                    for c in node.children.iter().flatten() {
                        is_child[c.value()] = true;
                    }
                }
                (0..n).filter(|&i| !is_child[i]).collect()
            }
        };
        // Iterative, and every node at most once: a malformed file with a cycle, or with a node
        // shared between parents (which could multiply instances exponentially), is an error
        // instead of a stack overflow or a hang.
        let mut visited = vec![false; n];
        self.scene.nodes = doc
            .nodes()
            .map(|node| match node.transform() {
                ::gltf::scene::Transform::Matrix { matrix } => NodeDesc {
                    matrix: Some(Mat4::from_cols_array_2d(&matrix)),
                    ..Default::default()
                },
                ::gltf::scene::Transform::Decomposed {
                    translation,
                    rotation,
                    scale,
                } => NodeDesc {
                    translation: translation.into(),
                    rotation: Quat::from_array(rotation),
                    scale: scale.into(),
                    ..Default::default()
                },
            })
            .collect();
        let mut stack: Vec<(usize, Mat4)> =
            roots.iter().rev().map(|&r| (r, Mat4::IDENTITY)).collect();
        let mut instances = Vec::new();
        let mut cameras = Vec::new();
        let mut lights = Vec::new();
        while let Some((ni, parent)) = stack.pop() {
            if std::mem::replace(&mut visited[ni], true) {
                return Err(format!(
                    "node {ni} appears twice in the node hierarchy (a cycle or a node with two parents)"
                ));
            }
            let node = doc.nodes().nth(ni).ok_or(format!("missing node {ni}"))?;
            let global = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
            if let Some(mesh) = node.mesh() {
                instances.push((
                    ni,
                    InstanceDesc {
                        mesh: mesh.index() as u32,
                        transform: global,
                        node: Some(ni as u32),
                    },
                ));
            }
            if let Some(ci) = root.nodes[ni].camera.map(|c| c.value()) {
                if let Some(cam) = self.camera(ci, global) {
                    cameras.push((ni, cam.at_node(ni as u32)));
                }
            }
            let light = root.nodes[ni]
                .extensions
                .as_ref()
                .and_then(|e| e.khr_lights_punctual.as_ref())
                .map(|l| l.light.value());
            if let Some(li) = light {
                if let Some(l) = self.light(li, global) {
                    lights.push((ni, l));
                }
            }
            for child in node.children().collect::<Vec<_>>().into_iter().rev() {
                if let Some(c) = self.scene.nodes.get_mut(child.index()) {
                    c.parent = Some(ni as u32);
                }
                stack.push((child.index(), global));
            }
        }
        // A file (or scene) without nodes places nothing; show each mesh once, untransformed,
        // as viewers do.
        let nothing_placed = n == 0
            || doc
                .default_scene()
                .or_else(|| doc.scenes().next())
                .is_some_and(|s| s.nodes().next().is_none());
        if nothing_placed && !self.scene.meshes.is_empty() {
            instances = (0..self.scene.meshes.len())
                .map(|m| {
                    (
                        m,
                        InstanceDesc {
                            mesh: m as u32,
                            transform: Mat4::IDENTITY,
                            node: None,
                        },
                    )
                })
                .collect();
            self.warn("no node places a mesh; placing each mesh once at the origin".into());
        }
        lights.sort_by_key(|(ni, _)| *ni);
        self.scene.lights = lights.into_iter().map(|(_, l)| l).collect();
        instances.sort_by_key(|(ni, _)| *ni);
        cameras.sort_by_key(|(ni, _)| *ni);
        self.scene.instances = instances.into_iter().map(|(_, i)| i).collect();
        self.scene.cameras = cameras.into_iter().map(|(_, c)| c).collect();
        Ok(())
    }

    /// Reads the node animations. Animation is optional for a still image, so a channel that
    /// cannot be used (a bad accessor, inconsistent keyframes, a matrix node, morph target
    /// weights) is dropped with a warning instead of failing the file.
    fn animations(&mut self) {
        use json::animation::{Interpolation as J, Property as P};
        use json::validation::Checked;
        let doc = self.doc;
        let root = doc.as_json();
        let mut dropped: Vec<String> = Vec::new();
        let mut morph = 0usize;
        for (ai, a) in root.animations.iter().enumerate() {
            let mut channels = Vec::new();
            for (ci, c) in a.channels.iter().enumerate() {
                let at = |why: String| format!("animation {ai} channel {ci}: {why}");
                let node = c.target.node.value();
                let property = match c.target.path {
                    Checked::Valid(P::Translation) => Property::Translation,
                    Checked::Valid(P::Rotation) => Property::Rotation,
                    Checked::Valid(P::Scale) => Property::Scale,
                    Checked::Valid(P::MorphTargetWeights) => {
                        morph += 1;
                        continue;
                    }
                    Checked::Invalid => {
                        dropped.push(at("unknown target path".into()));
                        continue;
                    }
                };
                let Some(sampler) = a.samplers.get(c.sampler.value()) else {
                    dropped.push(at(format!("missing sampler {}", c.sampler.value())));
                    continue;
                };
                if self
                    .scene
                    .nodes
                    .get(node)
                    .is_none_or(|n| n.matrix.is_some())
                {
                    dropped.push(at(format!(
                        "node {node} is missing or given by a matrix, which cannot be animated"
                    )));
                    continue;
                }
                let interpolation = match sampler.interpolation {
                    Checked::Valid(J::Step) => Interpolation::Step,
                    Checked::Valid(J::Linear) => Interpolation::Linear,
                    Checked::Valid(J::CubicSpline) => Interpolation::CubicSpline,
                    Checked::Invalid => {
                        dropped.push(at("unknown interpolation".into()));
                        continue;
                    }
                };
                let read =
                    self.channel_data(sampler.input.value(), sampler.output.value(), property);
                let channel = match read {
                    Ok((times, values)) => Channel {
                        node: node as u32,
                        property,
                        interpolation,
                        times,
                        values,
                    },
                    Err(e) => {
                        dropped.push(at(e));
                        continue;
                    }
                };
                match channel.problem() {
                    None => channels.push(channel),
                    Some(why) => dropped.push(at(why)),
                }
            }
            let name = a.name.clone().unwrap_or_else(|| format!("animation {ai}"));
            self.scene.animations.push(Animation { name, channels });
        }
        if morph > 0 {
            self.warn(format!(
                "{morph} animation channel{} of morph target weights ignored (the base shapes are rendered)",
                if morph > 1 { "s" } else { "" }
            ));
        }
        if let Some(first) = dropped.first() {
            let more = match dropped.len() {
                1 => String::new(),
                n => format!(" (and {} more channels)", n - 1),
            };
            self.warn(format!("ignoring {first}{more}"));
        }
    }

    /// The keyframe times and values of a sampler, checked and charged to the budget.
    fn channel_data(
        &mut self,
        input: usize,
        output: usize,
        property: Property,
    ) -> Result<(Vec<f32>, Vec<[f32; 4]>), String> {
        use ::gltf::accessor::Iter;
        let doc = self.doc;
        let get = |i: usize| {
            doc.accessors()
                .nth(i)
                .ok_or_else(|| format!("missing accessor {i}"))
        };
        let (ia, oa) = (get(input)?, get(output)?);
        let times = match self.check_accessor(&ia, Kind::Times)? {
            Layout::Zeros => vec![0.0; ia.count()],
            Layout::Readable => Iter::<f32>::new(ia.clone(), |b| self.buffer(b))
                .ok_or_else(|| format!("accessor {input} cannot be read"))?
                .collect(),
        };
        let values = if property == Property::Rotation {
            match self.check_accessor(&oa, Kind::Rotation)? {
                Layout::Zeros => vec![[0.0; 4]; oa.count()],
                Layout::Readable => self.read_floats::<4>(&oa)?,
            }
        } else {
            match self.check_accessor(&oa, Kind::Motion3)? {
                Layout::Zeros => vec![[0.0; 4]; oa.count()],
                Layout::Readable => self
                    .read_floats::<3>(&oa)?
                    .into_iter()
                    .map(|[x, y, z]| [x, y, z, 0.0])
                    .collect(),
            }
        };
        Ok((times, values))
    }

    /// The `KHR_lights_punctual` light `li` placed by `to_world` (it shines down its local -Z),
    /// or `None` with a warning when it is missing or its values are not usable. Read from the
    /// JSON, as the crate's accessors unwrap.
    fn light(&mut self, li: usize, to_world: Mat4) -> Option<PunctualLight> {
        use json::extensions::scene::khr_lights_punctual::Type;
        let root = self.doc.as_json();
        let Some(light) = root
            .extensions
            .as_ref()
            .and_then(|e| e.khr_lights_punctual.as_ref())
            .and_then(|l| l.lights.get(li))
        else {
            self.warn(format!("light {li} does not exist; skipping it"));
            return None;
        };
        let intensity = Vec3::from(light.color) * light.intensity;
        let position = to_world.transform_point3(Vec3::ZERO);
        let direction = to_world.transform_vector3(-Vec3::Z).normalize_or_zero();
        let range = light.range.filter(|r| r.is_finite() && *r > 0.0);
        let kind = match (&light.type_, &light.spot) {
            (json::validation::Checked::Valid(Type::Directional), _) => LightKind::Directional,
            (json::validation::Checked::Valid(Type::Point), _) => LightKind::Point,
            (json::validation::Checked::Valid(Type::Spot), Some(spot)) => LightKind::Spot {
                inner_cone: spot.inner_cone_angle,
                outer_cone: spot.outer_cone_angle,
            },
            _ => {
                self.warn(format!("light {li}: unknown type; skipping it"));
                return None;
            }
        };
        let cones_ok = match kind {
            LightKind::Spot {
                inner_cone,
                outer_cone,
            } => {
                (0.0..=std::f32::consts::FRAC_PI_2).contains(&outer_cone)
                    && (0.0..=outer_cone).contains(&inner_cone)
            }
            _ => true,
        };
        if !(intensity.is_finite()
            && intensity.min_element() >= 0.0
            && position.is_finite()
            && cones_ok
            && (direction != Vec3::ZERO || kind == LightKind::Point))
        {
            self.warn(format!(
                "light {li}: invalid intensity, placement or cone angles; skipping it"
            ));
            return None;
        }
        Some(PunctualLight {
            kind,
            position,
            direction,
            intensity,
            range,
        })
    }

    /// A perspective camera placed by `to_world`, or `None` (with a warning) for an
    /// orthographic or degenerate one.
    fn camera(&mut self, ci: usize, to_world: Mat4) -> Option<Camera> {
        let cam = self.doc.as_json().cameras.get(ci)?;
        match (&cam.type_, &cam.perspective) {
            (json::validation::Checked::Valid(json::camera::Type::Perspective), Some(p)) => {
                if !(p.yfov > 0.0 && p.yfov < std::f32::consts::PI) {
                    self.warn(format!(
                        "camera {ci}: vertical field of view {} is not in (0, pi); skipping it",
                        p.yfov
                    ));
                    return None;
                }
                Some(Camera {
                    to_world,
                    yfov: p.yfov,
                    aspect: p.aspect_ratio.filter(|a| a.is_finite() && *a > 0.0),
                    node: None,
                })
            }
            _ => {
                self.warn(format!(
                    "camera {ci}: only perspective cameras are supported; skipping it"
                ));
                None
            }
        }
    }
}

fn wrap(w: ::gltf::texture::WrappingMode) -> Wrap {
    match w {
        ::gltf::texture::WrappingMode::ClampToEdge => Wrap::ClampToEdge,
        ::gltf::texture::WrappingMode::MirroredRepeat => Wrap::MirroredRepeat,
        ::gltf::texture::WrappingMode::Repeat => Wrap::Repeat,
    }
}

/// Turns an index list into triangles for a triangle mode, following the glTF specification's
/// vertex order (strips alternate the winding, fans pivot on the first vertex). A trailing
/// incomplete triangle is dropped.
fn assemble(mode: Mode, idx: &[u32]) -> Vec<[u32; 3]> {
    match mode {
        Mode::TriangleStrip => (0..idx.len().saturating_sub(2))
            .map(|i| {
                if i % 2 == 0 {
                    [idx[i], idx[i + 1], idx[i + 2]]
                } else {
                    [idx[i], idx[i + 2], idx[i + 1]]
                }
            })
            .collect(),
        Mode::TriangleFan => (1..idx.len().saturating_sub(1))
            .map(|i| [idx[i], idx[i + 1], idx[0]])
            .collect(),
        _ => idx.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
    }
}
