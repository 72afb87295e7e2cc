//! Triangle-mesh loaders: OBJ (through `tobj`), PLY (ASCII and binary, faces and triangle
//! strips) and glTF (flattened into world space). Primitive indices follow the file: polygons are
//! fan-triangulated in place and strips are unrolled in order.

use std::path::Path;
use thiserror::Error;

/// A triangle mesh.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub positions: Vec<[f32; 3]>,
    /// Triangles as vertex-index triplets.
    pub triangles: Vec<[u32; 3]>,
}

/// Why a mesh could not be loaded.
#[derive(Debug, Error)]
pub enum MeshError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The file's extension names no supported format.
    #[error("{path}: unknown mesh format (expected .obj, .ply, .gltf or .glb)")]
    UnknownFormat {
        /// The file.
        path: String,
    },
    /// The OBJ parser failed.
    #[error("{path}: malformed OBJ: {message}")]
    Obj {
        /// The file.
        path: String,
        /// The parser's message.
        message: String,
    },
    /// The PLY parser failed.
    #[error("{path}: malformed PLY: {message}")]
    Ply {
        /// The file.
        path: String,
        /// What is wrong.
        message: String,
    },
    /// The glTF scene loader failed (its message names the file).
    #[error(transparent)]
    Scene(#[from] crate::SceneError),
    /// The flattened scene has more vertices or triangles than a mesh can index.
    #[error("{path}: the scene flattens to more than {limit} vertices or triangles")]
    TooLarge {
        /// The file.
        path: String,
        /// The limit.
        limit: u64,
    },
    /// The flattened scene is over the geometry memory limit.
    #[error("{path}: its {instances} instances flatten to {} of geometry, over the limit of {} (raise it with OXRAY_MAX_GEOMETRY_MB)", crate::files::mib(*bytes), crate::files::mib(*limit))]
    Budget {
        /// The file.
        path: String,
        /// Instances in the scene.
        instances: usize,
        /// Bytes the flattened mesh would take.
        bytes: u64,
        /// The limit.
        limit: u64,
    },
    /// A face refers to a vertex that does not exist.
    #[error(
        "{path}: triangle {triangle} refers to vertex {index} but there are {vertices} vertices"
    )]
    IndexOutOfRange {
        /// The file.
        path: String,
        /// The triangle.
        triangle: usize,
        /// The index.
        index: u32,
        /// The vertex count.
        vertices: usize,
    },
}

impl Mesh {
    /// Loads an `.obj`, `.ply`, `.gltf` or `.glb` file.
    ///
    /// A glTF scene is flattened into one world-space mesh: every node with a mesh (in the order
    /// of the file's `nodes` array, restricted to the scene that would be rendered) contributes
    /// each of its mesh's primitives in order, each primitive its triangles in order. So primitive
    /// index `k` of the result is the `k`-th triangle in that order. Materials, textures and
    /// cameras are not loaded, and the scene loader's warnings are dropped.
    pub fn load(path: &Path) -> Result<Mesh, MeshError> {
        Ok(Self::load_with_sources(path)?.0)
    }

    /// [`load`](Self::load), also returning every file that was read (a glTF's buffers and
    /// images as well as the file itself), so that a command can refuse to write over any of
    /// them.
    pub fn load_with_sources(path: &Path) -> Result<(Mesh, Vec<std::path::PathBuf>), MeshError> {
        let mut sources = vec![path.to_path_buf()];
        let name = path.display().to_string();
        let ext = crate::file_extension(path);
        let mesh = match ext.as_deref() {
            Some("obj") => load_obj(path, &name)?,
            Some("ply") => {
                let bytes = crate::files::read_input(path).map_err(|source| MeshError::Io {
                    path: name.clone(),
                    source,
                })?;
                parse_ply(&bytes).map_err(|message| MeshError::Ply {
                    path: name.clone(),
                    message,
                })?
            }
            Some("gltf") | Some("glb") => {
                let scene = crate::gltf::load_impl(path, false)?;
                sources.clone_from(&scene.sources);
                flatten(&scene, &name)?
            }
            _ => return Err(MeshError::UnknownFormat { path: name }),
        };
        mesh.check(&name)?;
        Ok((mesh, sources))
    }

    fn check(&self, path: &str) -> Result<(), MeshError> {
        let n = self.positions.len();
        for (triangle, t) in self.triangles.iter().enumerate() {
            if let Some(&index) = t.iter().find(|&&i| i as usize >= n) {
                return Err(MeshError::IndexOutOfRange {
                    path: path.to_string(),
                    triangle,
                    index,
                    vertices: n,
                });
            }
        }
        Ok(())
    }

    /// An icosphere: `subdivisions` rounds of 4-way splitting of an icosahedron, vertices shared.
    pub fn icosphere(subdivisions: u32) -> Mesh {
        let t = (1.0 + 5f32.sqrt()) / 2.0;
        let mut positions: Vec<[f32; 3]> = [
            [-1.0, t, 0.0],
            [1.0, t, 0.0],
            [-1.0, -t, 0.0],
            [1.0, -t, 0.0],
            [0.0, -1.0, t],
            [0.0, 1.0, t],
            [0.0, -1.0, -t],
            [0.0, 1.0, -t],
            [t, 0.0, -1.0],
            [t, 0.0, 1.0],
            [-t, 0.0, -1.0],
            [-t, 0.0, 1.0],
        ]
        .into_iter()
        .map(normalize)
        .collect();
        let mut triangles: Vec<[u32; 3]> = vec![
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ];
        for _ in 0..subdivisions {
            triangles = split4(&mut positions, &triangles, |p, q| {
                normalize([p[0] + q[0], p[1] + q[1], p[2] + q[2]])
            });
        }
        Mesh {
            positions,
            triangles,
        }
    }

    /// The same surface with every triangle split `levels` times into four at its edges'
    /// midpoints (so 4^`levels` times the triangles, vertices shared): a large mesh of a real
    /// shape for benchmarks. `None` if it would have more than 2^29 triangles (the guide's limit
    /// per GAS) or vertices that `u32` indices cannot name.
    ///
    /// ```
    /// let m = oxray_scene::mesh::Mesh::icosphere(0).subdivided(2).unwrap();
    /// assert_eq!(m.triangles.len(), 20 * 16);
    /// assert_eq!(m.bounds(), oxray_scene::mesh::Mesh::icosphere(0).bounds());
    /// ```
    #[must_use]
    pub fn subdivided(&self, levels: u32) -> Option<Mesh> {
        let tris = (self.triangles.len() as u64).checked_mul(4u64.checked_pow(levels)?)?;
        // Each split adds at most 3 vertices per triangle of the level before.
        let verts = self.positions.len() as u64 + 3 * tris;
        if tris > 1 << 29 || verts > u32::MAX as u64 {
            return None;
        }
        let mut positions = self.positions.clone();
        let mut triangles = self.triangles.clone();
        for _ in 0..levels {
            triangles = split4(&mut positions, &triangles, |p, q| {
                [
                    (p[0] + q[0]) * 0.5,
                    (p[1] + q[1]) * 0.5,
                    (p[2] + q[2]) * 0.5,
                ]
            });
        }
        Some(Mesh {
            positions,
            triangles,
        })
    }

    /// The box around the vertices as `(min, max)`.
    #[must_use]
    pub fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in &self.positions {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        (lo, hi)
    }
}

/// Splits every triangle into four at its edges' midpoints (`mid` makes a midpoint), each edge's
/// midpoint made once and shared; the corners keep their order, so facing is kept.
fn split4(
    positions: &mut Vec<[f32; 3]>,
    triangles: &[[u32; 3]],
    mid: impl Fn([f32; 3], [f32; 3]) -> [f32; 3],
) -> Vec<[u32; 3]> {
    let mut made = std::collections::HashMap::new();
    let mut midpoint = |a: u32, b: u32, positions: &mut Vec<[f32; 3]>| {
        *made.entry((a.min(b), a.max(b))).or_insert_with(|| {
            positions.push(mid(positions[a as usize], positions[b as usize]));
            positions.len() as u32 - 1
        })
    };
    let mut next = Vec::with_capacity(triangles.len() * 4);
    for &[a, b, c] in triangles {
        let ab = midpoint(a, b, positions);
        let bc = midpoint(b, c, positions);
        let ca = midpoint(c, a, positions);
        next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
    }
    next
}

/// Most vertices or triangles a flattened scene may have: indices are `u32`. Instancing lets a
/// small file describe far more geometry than fits in memory once copied per instance, so the
/// bytes are bounded too ([`Limits::geometry_bytes`](crate::files::Limits)).
const MAX_FLAT: u64 = 1 << 28;

/// Copies every instance's primitives into one world-space mesh, in instance order, then
/// primitive order (see [`Mesh::load`]).
fn flatten(scene: &crate::SceneDesc, name: &str) -> Result<Mesh, MeshError> {
    let prims = || {
        scene.instances.iter().flat_map(|inst| {
            let prims = scene
                .meshes
                .get(inst.mesh as usize)
                .map(|m| m.primitives.as_slice());
            prims.unwrap_or(&[]).iter().map(move |p| (inst, p))
        })
    };
    let (mut vertices, mut triangles) = (0u64, 0u64);
    for (_, p) in prims() {
        vertices += p.positions.len() as u64;
        triangles += p.triangles.len() as u64;
    }
    if vertices > MAX_FLAT || triangles > MAX_FLAT {
        return Err(MeshError::TooLarge {
            path: name.to_string(),
            limit: MAX_FLAT,
        });
    }
    let bytes = (vertices + triangles).saturating_mul(12);
    let limit = crate::files::Limits::get().geometry_bytes;
    if bytes > limit {
        return Err(MeshError::Budget {
            path: name.to_string(),
            instances: scene.instances.len(),
            bytes,
            limit,
        });
    }
    let mut mesh = Mesh {
        positions: Vec::with_capacity(vertices as usize),
        triangles: Vec::with_capacity(triangles as usize),
    };
    for (inst, p) in prims() {
        let base = mesh.positions.len() as u32;
        mesh.positions.extend(p.positions.iter().map(|&v| {
            inst.transform
                .transform_point3(glam::Vec3::from(v))
                .to_array()
        }));
        mesh.triangles
            .extend(p.triangles.iter().map(|t| t.map(|i| base + i)));
    }
    Ok(mesh)
}

fn normalize(p: [f32; 3]) -> [f32; 3] {
    let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    [p[0] / l, p[1] / l, p[2] / l]
}

fn load_obj(path: &Path, name: &str) -> Result<Mesh, MeshError> {
    let opts = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
    };
    let bytes = crate::files::read_input(path).map_err(|source| MeshError::Io {
        path: name.to_string(),
        source,
    })?;
    let bytes = crate::text::fix_obj(crate::text::to_utf8(bytes));
    // Material libraries are not read: only the geometry is needed, and tobj's MTL parser panics
    // on some malformed files (a colour with fewer than three numbers).
    check_obj_indices(&bytes).map_err(|message| MeshError::Obj {
        path: name.to_string(),
        message,
    })?;
    let (models, _) = tobj::load_obj_buf(&mut &bytes[..], &opts, |_| Ok(Default::default()))
        .map_err(|e| MeshError::Obj {
            path: name.to_string(),
            message: e.to_string(),
        })?;
    let mut mesh = Mesh::default();
    for m in models {
        let base = mesh.positions.len() as u32;
        mesh.positions
            .extend(m.mesh.positions.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));
        mesh.triangles.extend(
            m.mesh
                .indices
                .chunks_exact(3)
                .map(|c| [base + c[0], base + c[1], base + c[2]]),
        );
    }
    Ok(mesh)
}

/// Rejects OBJ face, line and point indices that no file can satisfy: positive indices larger
/// than the file, and negative (relative) ones reaching before the first vertex, texture
/// coordinate or normal. tobj turns both into huge offsets whose arithmetic overflows (a panic).
pub(crate) fn check_obj_indices(bytes: &[u8]) -> Result<(), String> {
    let limit = bytes.len() as u128;
    // Vertices, texture coordinates and normals read so far.
    let mut counts = [0u128; 3];
    for (n, line) in bytes.split(|&b| b == b'\n').enumerate() {
        let line = String::from_utf8_lossy(line);
        let mut words = line.split_whitespace();
        match words.next() {
            Some("v") => counts[0] += 1,
            Some("vt") => counts[1] += 1,
            Some("vn") => counts[2] += 1,
            Some("f" | "l" | "p") => {
                for w in words {
                    for (k, part) in w.split('/').enumerate().take(3) {
                        let Ok(x) = part.parse::<i128>() else {
                            continue;
                        };
                        if x > 0 && x as u128 > limit || x < 0 && x.unsigned_abs() > counts[k] {
                            return Err(format!("line {}: index {x} is out of range", n + 1));
                        }
                    }
                }
            }
            _ => {}
        }
    }
    Ok(())
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Encoding {
    Ascii,
    BinaryLe,
    BinaryBe,
}

#[derive(Clone, Copy, Debug)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Scalar> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
}

#[derive(Clone, Debug)]
struct Property {
    name: String,
    /// `Some(count type)` for a list.
    list: Option<Scalar>,
    ty: Scalar,
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

/// Reads values from the body of a PLY file.
struct Reader<'a> {
    enc: Encoding,
    bytes: &'a [u8],
    pos: usize,
}

impl Reader<'_> {
    fn token(&mut self) -> Result<&str, String> {
        let b = self.bytes;
        while self.pos < b.len() && b[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        let start = self.pos;
        while self.pos < b.len() && !b[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        if start == self.pos {
            return Err("unexpected end of data".into());
        }
        std::str::from_utf8(&b[start..self.pos]).map_err(|_| "invalid text in ASCII body".into())
    }

    fn read(&mut self, ty: Scalar) -> Result<f64, String> {
        if self.enc == Encoding::Ascii {
            let t = self.token()?;
            return t.parse::<f64>().map_err(|_| format!("bad number {t:?}"));
        }
        let n = ty.size();
        let Some(raw) = self.bytes.get(self.pos..self.pos + n) else {
            return Err("file is truncated".into());
        };
        self.pos += n;
        let mut a = [0u8; 8];
        a[..n].copy_from_slice(raw);
        if self.enc == Encoding::BinaryBe {
            a[..n].reverse();
        }
        Ok(match ty {
            Scalar::I8 => a[0] as i8 as f64,
            Scalar::U8 => a[0] as f64,
            Scalar::I16 => i16::from_le_bytes([a[0], a[1]]) as f64,
            Scalar::U16 => u16::from_le_bytes([a[0], a[1]]) as f64,
            Scalar::I32 => i32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::U32 => u32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::F32 => f32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::F64 => f64::from_le_bytes(a),
        })
    }
}

/// Largest list a PLY face or strip may have; longer lists mean a corrupt file.
const MAX_LIST: usize = 1 << 28;

/// Parses a PLY file held in memory.
pub fn parse_ply(bytes: &[u8]) -> Result<Mesh, String> {
    let header_end = find_header_end(bytes).ok_or("missing end_header")?;
    let header = std::str::from_utf8(&bytes[..header_end]).map_err(|_| "header is not text")?;
    let mut lines = header.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err("not a PLY file (missing 'ply' magic)".into());
    }
    let mut enc = None;
    let mut elements: Vec<Element> = Vec::new();
    for line in lines {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] | ["end_header"] => {}
            ["format", f, _] => {
                enc = Some(match *f {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::BinaryLe,
                    "binary_big_endian" => Encoding::BinaryBe,
                    _ => return Err(format!("unknown format {f:?}")),
                })
            }
            ["element", name, count] => elements.push(Element {
                name: name.to_string(),
                count: count
                    .parse()
                    .map_err(|_| format!("bad element count {count:?}"))?,
                props: Vec::new(),
            }),
            ["property", "list", ct, ty, name] => {
                let e = elements.last_mut().ok_or("property before any element")?;
                e.props.push(Property {
                    name: name.to_string(),
                    list: Some(Scalar::parse(ct).ok_or(format!("bad type {ct:?}"))?),
                    ty: Scalar::parse(ty).ok_or(format!("bad type {ty:?}"))?,
                });
            }
            ["property", ty, name] => {
                let e = elements.last_mut().ok_or("property before any element")?;
                e.props.push(Property {
                    name: name.to_string(),
                    list: None,
                    ty: Scalar::parse(ty).ok_or(format!("bad type {ty:?}"))?,
                });
            }
            _ => return Err(format!("bad header line {line:?}")),
        }
    }
    let enc = enc.ok_or("missing format line")?;
    let mut r = Reader {
        enc,
        bytes,
        pos: header_end + "end_header".len(),
    };
    // Skip the rest of the end_header line.
    while r.pos < bytes.len() && bytes[r.pos] != b'\n' {
        r.pos += 1;
    }
    r.pos += 1;

    let mut mesh = Mesh::default();
    let mut list = Vec::new();
    for e in &elements {
        let is_vertex = e.name == "vertex";
        let is_face = e.name == "face";
        let is_strip = e.name == "tristrips";
        // An element without properties takes no bytes, whatever its count: there is nothing
        // to read (looping over a count of 2^63 would never end).
        if e.props.is_empty() {
            continue;
        }
        // Each instance of an element with properties takes at least one byte (a binary
        // scalar, an ASCII digit and its separator, or a list count), so a larger count means
        // a corrupt header: refused before any time or memory is spent on it.
        if e.count > bytes.len().saturating_sub(r.pos) {
            return Err(format!(
                "element {:?} declares {} instances, more than the {} bytes of data can hold",
                e.name,
                e.count,
                bytes.len().saturating_sub(r.pos)
            ));
        }
        if is_vertex {
            for axis in ["x", "y", "z"] {
                if !e.props.iter().any(|p| p.name == axis && p.list.is_none()) {
                    return Err(format!("vertex element has no scalar property {axis:?}"));
                }
            }
            // Each vertex needs at least one byte; a larger count means a corrupt header.
            if e.count > bytes.len() {
                return Err(format!("{} vertices cannot fit in the file", e.count));
            }
            mesh.positions.reserve(e.count);
        }
        for _ in 0..e.count {
            let mut p = [0.0f32; 3];
            for prop in &e.props {
                match prop.list {
                    None => {
                        let v = r.read(prop.ty)?;
                        if is_vertex {
                            match prop.name.as_str() {
                                "x" => p[0] = v as f32,
                                "y" => p[1] = v as f32,
                                "z" => p[2] = v as f32,
                                _ => {}
                            }
                        }
                    }
                    Some(ct) => {
                        let n = r.read(ct)?;
                        if !(0.0..=MAX_LIST as f64).contains(&n) {
                            return Err(format!("bad list length {n}"));
                        }
                        list.clear();
                        for _ in 0..n as usize {
                            list.push(r.read(prop.ty)?);
                        }
                        let wanted = prop.name == "vertex_indices" || prop.name == "vertex_index";
                        if wanted && is_face {
                            fan(&list, &mut mesh.triangles)?;
                        } else if wanted && is_strip {
                            strip(&list, &mut mesh.triangles)?;
                        }
                    }
                }
            }
            if is_vertex {
                mesh.positions.push(p);
            }
        }
    }
    Ok(mesh)
}

fn find_header_end(bytes: &[u8]) -> Option<usize> {
    let pat = b"end_header";
    bytes
        .windows(pat.len())
        .take(1 << 20)
        .position(|w| w == pat)
}

fn index(v: f64) -> Result<u32, String> {
    if v >= 0.0 && v <= u32::MAX as f64 && v.fract() == 0.0 {
        Ok(v as u32)
    } else {
        Err(format!("bad vertex index {v}"))
    }
}

fn fan(list: &[f64], out: &mut Vec<[u32; 3]>) -> Result<(), String> {
    if list.len() < 3 {
        return Ok(());
    }
    let a = index(list[0])?;
    for w in list[1..].windows(2) {
        out.push([a, index(w[0])?, index(w[1])?]);
    }
    Ok(())
}

/// Unrolls a triangle strip; `-1` restarts it. Every other triangle is flipped to keep the
/// winding. Triangles with a repeated vertex (strip stitching) are kept, so that triangle `k` of a
/// run is always the one at strip position `k`; the GAS treats them as inactive.
fn strip(list: &[f64], out: &mut Vec<[u32; 3]>) -> Result<(), String> {
    for run in list.split(|&v| v < 0.0) {
        for (k, w) in run.windows(3).enumerate() {
            let (a, b, c) = (index(w[0])?, index(w[1])?, index(w[2])?);
            out.push(if k % 2 == 0 { [a, b, c] } else { [b, a, c] });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ascii_ply_with_faces_and_quads() {
        let ply = b"ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n4 0 1 2 3\n";
        let m = parse_ply(ply).unwrap();
        assert_eq!(m.positions.len(), 4);
        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 1, 2], [0, 2, 3]]);
    }

    #[test]
    fn binary_strips_unroll_with_alternating_winding() {
        let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nelement tristrips 1\nproperty list int int vertex_indices\nend_header\n".to_vec();
        for p in [[0f32, 0., 0.], [1., 0., 0.], [0., 1., 0.], [1., 1., 0.]] {
            for c in p {
                b.extend(c.to_le_bytes());
            }
        }
        for v in [5i32, 0, 1, 2, 3, -1] {
            b.extend(v.to_le_bytes());
        }
        let m = parse_ply(&b).unwrap();
        assert_eq!(m.triangles, vec![[0, 1, 2], [2, 1, 3]]);
    }

    #[test]
    fn truncated_and_garbage_files_are_errors() {
        let ply = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1 0";
        assert!(parse_ply(ply).is_err());
        assert!(parse_ply(b"hello").is_err());
        assert!(parse_ply(b"ply\nformat binary_little_endian 1.0\nelement vertex 99999999999\nproperty float x\nproperty float y\nproperty float z\nend_header\n").is_err());
    }

    #[test]
    fn elements_without_properties_and_huge_counts_end_at_once() {
        // The 214-byte file that never finished: nothing to read, 2^63 times.
        let ply = b"ply\nformat binary_little_endian 1.0\nelement junk 9223372036854775807\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0";
        let t = std::time::Instant::now();
        assert_eq!(parse_ply(ply).unwrap().positions.len(), 3);
        let huge = b"ply\nformat ascii 1.0\nelement face 9223372036854775807\nproperty list uchar int vertex_indices\nend_header\n3 0 1 2\n";
        assert!(parse_ply(huge).unwrap_err().contains("more than"));
        assert!(t.elapsed().as_secs() < 1);
    }

    #[test]
    fn icosphere_is_closed() {
        let m = Mesh::icosphere(2);
        assert_eq!(m.triangles.len(), 320);
        let mut edges = std::collections::HashMap::new();
        for t in &m.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
            }
        }
        assert!(edges.values().all(|&n| n == 2));
    }
}
