//! Buffer views compressed with meshoptimizer's codecs (`EXT_meshopt_compression` and its
//! successor `KHR_meshopt_compression`): the view's bytes are decoded from another buffer, and
//! the view's own buffer is a fallback that holds the uncompressed data, or nothing.
//!
//! Decoding uses meshoptimizer itself (the `meshopt` crate), whose decoders are safe on
//! untrusted input; the preconditions it only asserts (strides, counts, filter layouts) are
//! checked here first, so a malformed file is an error, never an abort.

use ::gltf::json::Value;

/// The extensions this module reads, both with the same JSON and bitstreams (the KHR one adds
/// the COLOR filter and version 1 of the vertex codec, which the decoder reads for both).
pub(super) const EXTENSIONS: [&str; 2] = ["EXT_meshopt_compression", "KHR_meshopt_compression"];

/// How the compressed bytes encode the view.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Mode {
    /// Vertex attributes (the vertex codec).
    Attributes,
    /// A triangle list's indices (the index codec).
    Triangles,
    /// Any index sequence (the index sequence codec).
    Indices,
}

/// The filter applied to decoded vertex data.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Filter {
    None,
    Octahedral,
    Quaternion,
    Exponential,
    /// `KHR_meshopt_compression` only: YCoCg colours.
    Color,
}

impl Filter {
    /// The name the JSON gives it.
    fn name(self) -> &'static str {
        match self {
            Filter::None => "NONE",
            Filter::Octahedral => "OCTAHEDRAL",
            Filter::Quaternion => "QUATERNION",
            Filter::Exponential => "EXPONENTIAL",
            Filter::Color => "COLOR",
        }
    }
}

/// The compression of one buffer view.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct Compressed {
    /// Which of [`EXTENSIONS`] describes it.
    pub extension: &'static str,
    /// The buffer holding the compressed bytes.
    pub buffer: usize,
    /// Where they start in it.
    pub offset: usize,
    /// How many there are.
    pub length: usize,
    /// Bytes per decoded element.
    pub stride: usize,
    /// Decoded elements.
    pub count: usize,
    pub mode: Mode,
    pub filter: Filter,
}

impl Compressed {
    /// Bytes once decoded (`None` on overflow).
    pub fn decoded_len(&self) -> Option<usize> {
        self.count.checked_mul(self.stride)
    }
}

/// What the JSON says about compression, read before the `gltf` crate (which does not keep
/// these extensions) sees it.
#[derive(Debug, Default)]
pub(super) struct Plan {
    /// Per compressed buffer view: its index, the extension, and the compression or why it
    /// cannot be read.
    pub views: Vec<(usize, &'static str, Result<Compressed, String>)>,
    /// Per buffer: whether it is a fallback buffer (its data is needed only where decoding is
    /// not possible, and it may have none).
    pub fallback: Vec<bool>,
}

impl Plan {
    /// Reads the extensions' objects on buffer views and buffers.
    pub fn scan(root: &Value) -> Plan {
        let ext = |v: &Value| -> Option<(&'static str, Value)> {
            let e = v.get("extensions")?;
            EXTENSIONS
                .iter()
                .find_map(|&name| Some((name, e.get(name)?.clone())))
        };
        let array = |key| root.get(key).and_then(Value::as_array);
        let views = array("bufferViews")
            .into_iter()
            .flatten()
            .enumerate()
            .filter_map(|(i, v)| ext(v).map(|(name, e)| (i, name, parse(name, &e))))
            .collect();
        let fallback = array("buffers")
            .into_iter()
            .flatten()
            .map(|b| {
                ext(b)
                    .is_some_and(|(_, e)| e.get("fallback").and_then(Value::as_bool) == Some(true))
            })
            .collect();
        Plan { views, fallback }
    }
}

/// Reads one view's extension object.
fn parse(extension: &'static str, e: &Value) -> Result<Compressed, String> {
    let int = |key: &str, default: Option<usize>| -> Result<usize, String> {
        match e.get(key) {
            None => default.ok_or(format!("{extension} has no {key}")),
            Some(v) => v
                .as_u64()
                .and_then(|n| usize::try_from(n).ok())
                .ok_or(format!(
                    "{extension}: {key} {v} is not a non-negative integer"
                )),
        }
    };
    let text = |key: &str, default: Option<&'static str>| -> Result<String, String> {
        match e.get(key) {
            None => default
                .map(str::to_string)
                .ok_or(format!("{extension} has no {key}")),
            Some(v) => v
                .as_str()
                .map(str::to_string)
                .ok_or(format!("{extension}: {key} {v} is not a string")),
        }
    };
    let mode = match text("mode", None)?.as_str() {
        "ATTRIBUTES" => Mode::Attributes,
        "TRIANGLES" => Mode::Triangles,
        "INDICES" => Mode::Indices,
        m => return Err(format!("{extension}: unknown mode {m:?}")),
    };
    let filter = match text("filter", Some("NONE"))?.as_str() {
        "NONE" => Filter::None,
        "OCTAHEDRAL" => Filter::Octahedral,
        "QUATERNION" => Filter::Quaternion,
        "EXPONENTIAL" => Filter::Exponential,
        "COLOR" if extension.starts_with("KHR") => Filter::Color,
        f => return Err(format!("{extension}: unknown filter {f:?}")),
    };
    Ok(Compressed {
        extension,
        buffer: int("buffer", None)?,
        offset: int("byteOffset", Some(0))?,
        length: int("byteLength", None)?,
        stride: int("byteStride", None)?,
        count: int("count", None)?,
        mode,
        filter,
    })
}

/// Checks the layout rules of the specification (which the decoders assert).
pub(super) fn check(c: &Compressed) -> Result<(), String> {
    let stride = c.stride;
    match c.mode {
        Mode::Attributes if stride == 0 || !stride.is_multiple_of(4) || stride > 256 => {
            return Err(format!(
                "byteStride {stride} of ATTRIBUTES data is not a multiple of 4 in 4..=256"
            ))
        }
        Mode::Triangles | Mode::Indices if stride != 2 && stride != 4 => {
            return Err(format!("byteStride {stride} of index data is not 2 or 4"))
        }
        Mode::Triangles if !c.count.is_multiple_of(3) => {
            return Err(format!(
                "count {} of TRIANGLES data is not a multiple of 3",
                c.count
            ))
        }
        Mode::Triangles | Mode::Indices if c.filter != Filter::None => {
            return Err("filters apply to ATTRIBUTES data only".into())
        }
        _ => {}
    }
    let ok = match c.filter {
        Filter::None | Filter::Exponential => true,
        Filter::Octahedral | Filter::Color => stride == 4 || stride == 8,
        Filter::Quaternion => stride == 8,
    };
    if !ok {
        return Err(format!(
            "byteStride {stride} does not suit the {} filter",
            c.filter.name()
        ));
    }
    Ok(())
}

/// Decodes `c` from `source` (the whole buffer it names) into `c.count * c.stride` bytes.
pub(super) fn decode(c: &Compressed, source: &[u8]) -> Result<Vec<u8>, String> {
    check(c)?;
    let len = c.decoded_len().ok_or("the decoded size overflows")?;
    let src = c
        .offset
        .checked_add(c.length)
        .and_then(|end| source.get(c.offset..end))
        .ok_or_else(|| {
            format!(
                "bytes {}..+{} lie outside the {}-byte buffer {}",
                c.offset,
                c.length,
                source.len(),
                c.buffer
            )
        })?;
    if c.count == 0 {
        return Ok(Vec::new());
    }
    // Words, so that the filters' SIMD paths see aligned data.
    let mut words = vec![0u32; len.div_ceil(4)];
    let dst = words.as_mut_ptr().cast::<std::ffi::c_void>();
    let (count, stride) = (c.count, c.stride);
    // SAFETY: `dst` holds at least `count * stride` bytes, `src` is a live slice, and `check`
    // established the strides and counts the decoders assert; the decoders read only
    // `src.len()` bytes and write only `count * stride` bytes.
    let rc = unsafe {
        use ::meshopt::ffi;
        match c.mode {
            Mode::Attributes => {
                ffi::meshopt_decodeVertexBuffer(dst, count, stride, src.as_ptr(), src.len())
            }
            Mode::Triangles => {
                ffi::meshopt_decodeIndexBuffer(dst, count, stride, src.as_ptr(), src.len())
            }
            Mode::Indices => {
                ffi::meshopt_decodeIndexSequence(dst, count, stride, src.as_ptr(), src.len())
            }
        }
    };
    if rc != 0 {
        return Err(format!(
            "the compressed data is malformed (meshoptimizer error {rc})"
        ));
    }
    // SAFETY: as above; the filters rewrite `count` elements of `stride` bytes in place.
    unsafe {
        use ::meshopt::ffi;
        match c.filter {
            Filter::None => {}
            Filter::Octahedral => ffi::meshopt_decodeFilterOct(dst, count, stride),
            Filter::Quaternion => ffi::meshopt_decodeFilterQuat(dst, count, stride),
            Filter::Exponential => ffi::meshopt_decodeFilterExp(dst, count, stride),
            Filter::Color => ffi::meshopt_decodeFilterColor(dst, count, stride),
        }
    }
    let mut bytes: Vec<u8> = bytemuck::cast_slice(&words).to_vec();
    bytes.truncate(len);
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(mode: Mode, filter: Filter, stride: usize, count: usize, data: &[u8]) -> Compressed {
        Compressed {
            extension: EXTENSIONS[1],
            buffer: 0,
            offset: 0,
            length: data.len(),
            stride,
            count,
            mode,
            filter,
        }
    }

    #[test]
    fn vertex_and_index_codecs_round_trip_through_meshoptimizers_encoders() {
        let vertices: Vec<[u16; 4]> = (0..50u16).map(|i| [i, i * 3, 65535 - i, 7]).collect();
        let enc = ::meshopt::encode_vertex_buffer(&vertices).unwrap();
        let c = spec(Mode::Attributes, Filter::None, 8, 50, &enc);
        let out = decode(&c, &enc).unwrap();
        assert_eq!(out, bytemuck::cast_slice::<_, u8>(&vertices));

        // The triangle codec may rotate a triangle's vertices (keeping its winding).
        let tris: Vec<u32> = vec![0, 1, 2, 2, 1, 3, 3, 1, 4, 4, 5, 3];
        let rotated = |t: &[u32]| -> Vec<[u32; 3]> {
            t.chunks(3)
                .map(|c| {
                    let k = (0..3).min_by_key(|&k| c[k]).unwrap();
                    [c[k], c[(k + 1) % 3], c[(k + 2) % 3]]
                })
                .collect()
        };
        let enc = ::meshopt::encode_index_buffer(&tris, 6).unwrap();
        let out = decode(&spec(Mode::Triangles, Filter::None, 4, 12, &enc), &enc).unwrap();
        assert_eq!(rotated(bytemuck::cast_slice(&out)), rotated(&tris));
        let out = decode(&spec(Mode::Triangles, Filter::None, 2, 12, &enc), &enc).unwrap();
        let short: Vec<u32> = bytemuck::cast_slice::<_, u16>(&out)
            .iter()
            .map(|&i| i as u32)
            .collect();
        assert_eq!(rotated(&short), rotated(&tris));

        let seq: Vec<u32> = vec![5, 9, 1, 0, 0, 7, 3];
        let enc = ::meshopt::encode_index_sequence(&seq, 10).unwrap();
        let out = decode(&spec(Mode::Indices, Filter::None, 4, 7, &enc), &enc).unwrap();
        assert_eq!(out, bytemuck::cast_slice::<_, u8>(&seq));
        // Corrupt data is an error, not garbage or a crash.
        assert!(decode(
            &spec(Mode::Indices, Filter::None, 4, 7, &enc[..3]),
            &enc[..3]
        )
        .is_err());
    }

    #[test]
    fn filters_decode_what_meshoptimizer_encodes() {
        let close =
            |a: &[f32], b: &[f32], tol: f32| a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol);
        // Octahedral unit vectors, 16-bit.
        let normals = [
            [0.0f32, 0.0, 1.0, 1.0],
            [0.6, 0.8, 0.0, 1.0],
            [-0.48, 0.6, -0.64, 1.0],
        ];
        let oct = ::meshopt::encode_filter_oct::<i16>(&normals, 16);
        let enc = ::meshopt::encode_vertex_buffer(&oct).unwrap();
        let out = decode(
            &spec(Mode::Attributes, Filter::Octahedral, 8, 3, &enc),
            &enc,
        )
        .unwrap();
        let out: &[[i16; 4]] = bytemuck::cast_slice(&out);
        for (o, n) in out.iter().zip(&normals) {
            let v: Vec<f32> = o[..3].iter().map(|&c| c as f32 / 32767.0).collect();
            assert!(close(&v, &n[..3], 1e-3), "{v:?} {n:?}");
        }
        // Quaternions.
        let h = std::f32::consts::FRAC_1_SQRT_2;
        let quats = [[0.0f32, 0.0, 0.0, 1.0], [h, 0.0, 0.0, h]];
        let q = ::meshopt::encode_filter_quat(&quats, 12);
        let enc = ::meshopt::encode_vertex_buffer(&q).unwrap();
        let out = decode(
            &spec(Mode::Attributes, Filter::Quaternion, 8, 2, &enc),
            &enc,
        )
        .unwrap();
        let out: &[[i16; 4]] = bytemuck::cast_slice(&out);
        for (o, n) in out.iter().zip(&quats) {
            let v: Vec<f32> = o.iter().map(|&c| c as f32 / 32767.0).collect();
            assert!(close(&v, n, 2e-3), "{v:?} {n:?}");
        }
        // Exponential floats.
        let floats = [[1.5f32, -2.25, 1000.0], [0.001, 3.0, -7.5]];
        let e = ::meshopt::encode_filter_exp(&floats, 16, ::meshopt::EncodeExpMode::Separate);
        let enc = ::meshopt::encode_vertex_buffer(&e).unwrap();
        let out = decode(
            &spec(Mode::Attributes, Filter::Exponential, 12, 2, &enc),
            &enc,
        )
        .unwrap();
        let out: &[[f32; 3]] = bytemuck::cast_slice(&out);
        for (o, n) in out.iter().zip(&floats) {
            assert!(
                o.iter()
                    .zip(n)
                    .all(|(a, b)| (a - b).abs() <= b.abs() * 1e-4),
                "{o:?} {n:?}"
            );
        }
        // YCoCg colours.
        let colours = [[1.0f32, 0.5, 0.25, 1.0], [0.0, 0.2, 0.9, 0.5]];
        let col = ::meshopt::encode_filter_color::<u8>(&colours, 8);
        let enc = ::meshopt::encode_vertex_buffer(&col).unwrap();
        let out = decode(&spec(Mode::Attributes, Filter::Color, 4, 2, &enc), &enc).unwrap();
        for (o, n) in out.chunks(4).zip(&colours) {
            let v: Vec<f32> = o.iter().map(|&c| c as f32 / 255.0).collect();
            assert!(close(&v, n, 0.02), "{v:?} {n:?}");
        }
    }

    #[test]
    fn layouts_the_decoders_assert_are_errors() {
        let data = [0u8; 64];
        for (mode, filter, stride, count) in [
            (Mode::Attributes, Filter::None, 6, 1),
            (Mode::Attributes, Filter::None, 260, 1),
            (Mode::Attributes, Filter::None, 0, 1),
            (Mode::Triangles, Filter::None, 4, 4),
            (Mode::Indices, Filter::None, 8, 3),
            (Mode::Triangles, Filter::Octahedral, 4, 3),
            (Mode::Attributes, Filter::Octahedral, 12, 1),
            (Mode::Attributes, Filter::Quaternion, 4, 1),
            (Mode::Attributes, Filter::Color, 16, 1),
        ] {
            let c = spec(mode, filter, stride, count, &data);
            assert!(decode(&c, &data).is_err(), "{c:?}");
        }
        let mut c = spec(Mode::Attributes, Filter::None, 4, 1, &data);
        c.offset = 60;
        assert!(decode(&c, &data).unwrap_err().contains("outside"));
        c.count = usize::MAX;
        assert!(decode(&c, &data).unwrap_err().contains("overflow"));
    }

    #[test]
    fn the_json_is_read_with_defaults_and_errors() {
        let root: Value = ::gltf::json::deserialize::from_str(
            r#"{"bufferViews":[{"buffer":1},
                {"buffer":1,"extensions":{"EXT_meshopt_compression":{"buffer":0,"byteLength":9,"byteStride":4,"count":3,"mode":"INDICES"}}},
                {"buffer":1,"extensions":{"EXT_meshopt_compression":{"buffer":0,"byteLength":9,"byteStride":4,"count":3,"mode":"ATTRIBUTES","filter":"COLOR"}}},
                {"buffer":1,"extensions":{"KHR_meshopt_compression":{"buffer":0,"byteLength":9,"byteStride":4,"mode":"ATTRIBUTES"}}}],
              "buffers":[{"byteLength":9},{"byteLength":12,"extensions":{"EXT_meshopt_compression":{"fallback":true}}}]}"#,
        )
        .unwrap();
        let plan = Plan::scan(&root);
        assert_eq!(plan.fallback, [false, true]);
        assert_eq!(plan.views.len(), 3);
        let (i, ext, c) = &plan.views[0];
        let c = c.as_ref().unwrap();
        assert_eq!(
            (*i, c.offset, c.mode, c.filter),
            (1, 0, Mode::Indices, Filter::None)
        );
        assert_eq!(*ext, "EXT_meshopt_compression");
        assert!(plan.views[1]
            .2
            .as_ref()
            .unwrap_err()
            .contains("unknown filter"));
        assert_eq!(plan.views[2].1, "KHR_meshopt_compression");
        assert!(plan.views[2].2.as_ref().unwrap_err().contains("no count"));
    }
}
