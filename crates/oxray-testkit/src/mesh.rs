//! Meshes for tests and benchmarks: an indexed mesh type, generators (icosphere, subdivided
//! cube, random triangle soups), OBJ reading, and the lookup of the shared data meshes (the
//! Stanford bunny and others in `../shared/data/meshes` beside the checkout).

use crate::rng::Rng;
use glam::{DVec3, Vec3};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// A triangle as three `f32` positions (the layout of a tightly packed `F32x3` soup).
pub type Tri = [[f32; 3]; 3];

/// An indexed triangle mesh.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub positions: Vec<[f32; 3]>,
    /// Triangles as vertex-index triplets; the generators make them counter-clockwise seen from
    /// outside.
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// The vertices of triangle `i`.
    #[must_use]
    pub fn tri(&self, i: usize) -> Tri {
        self.triangles[i].map(|k| self.positions[k as usize])
    }

    /// Every triangle as its three vertices, in order: the soup the oracle takes.
    #[must_use]
    pub fn soup(&self) -> Vec<Tri> {
        (0..self.triangles.len()).map(|i| self.tri(i)).collect()
    }

    /// The vertex position `i`.
    #[must_use]
    pub fn v(&self, i: u32) -> Vec3 {
        Vec3::from(self.positions[i as usize])
    }

    /// The (unnormalised) geometric normal `(v1 - v0) x (v2 - v0)` of triangle `i`, in `f64`.
    #[must_use]
    pub fn face_normal(&self, i: usize) -> DVec3 {
        let [a, b, c] = self.triangles[i].map(|k| self.v(k).as_dvec3());
        (b - a).cross(c - a)
    }

    /// Edge (sorted vertex pair) to the triangles that use it.
    #[must_use]
    pub fn edge_map(&self) -> HashMap<(u32, u32), Vec<usize>> {
        let mut m: HashMap<(u32, u32), Vec<usize>> = HashMap::new();
        for (f, t) in self.triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                m.entry((a.min(b), a.max(b))).or_default().push(f);
            }
        }
        m
    }

    /// The box around the vertices as `(min, max)` (see [`bounds`]).
    #[must_use]
    pub fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        bounds(&self.positions)
    }
}

/// The box around `positions` as `(min, max)`; `(+inf, -inf)` for no positions.
#[must_use]
pub fn bounds(positions: &[[f32; 3]]) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in positions {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    (lo, hi)
}

/// The twelve vertices of the icosahedron (golden-ratio rectangles), before normalisation.
fn icosahedron_vertex(p: f64, i: usize) -> [f64; 3] {
    [
        [-1.0, p, 0.0],
        [1.0, p, 0.0],
        [-1.0, -p, 0.0],
        [1.0, -p, 0.0],
        [0.0, -1.0, p],
        [0.0, 1.0, p],
        [0.0, -1.0, -p],
        [0.0, 1.0, -p],
        [p, 0.0, -1.0],
        [p, 0.0, 1.0],
        [-p, 0.0, -1.0],
        [-p, 0.0, 1.0],
    ][i]
}

/// The twenty faces of the icosahedron, counter-clockwise seen from outside.
const ICOSAHEDRON_FACES: [[u32; 3]; 20] = [
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

/// Splits every face into four `subdivisions` times, adding one vertex per edge with
/// `midpoint(a, b)` (shared between the edge's two faces).
fn subdivide<V>(
    verts: &mut Vec<V>,
    subdivisions: u32,
    midpoint: impl Fn(&V, &V) -> V,
) -> Vec<[u32; 3]> {
    let mut faces = ICOSAHEDRON_FACES.to_vec();
    for _ in 0..subdivisions {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut split = |a: u32, b: u32, verts: &mut Vec<V>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                let m = midpoint(&verts[a as usize], &verts[b as usize]);
                verts.push(m);
                verts.len() as u32 - 1
            })
        };
        let mut next = Vec::with_capacity(faces.len() * 4);
        for [a, b, c] in faces {
            let ab = split(a, b, verts);
            let bc = split(b, c, verts);
            let ca = split(c, a, verts);
            next.extend_from_slice(&[[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        faces = next;
    }
    faces
}

/// An icosphere of radius 1 around the origin: a closed mesh with shared vertices, `subdivisions`
/// times subdivided (20 * 4^subdivisions triangles, 10 * 4^subdivisions + 2 vertices),
/// counter-clockwise seen from outside. The vertices are computed in `f64` and rounded once, so
/// they lie on the sphere to `f32` precision (the engine's tests use this one).
#[must_use]
pub fn icosphere(subdivisions: u32) -> Mesh {
    let p = (1.0 + 5f64.sqrt()) / 2.0;
    let mut verts: Vec<DVec3> = (0..12)
        .map(|i| DVec3::from(icosahedron_vertex(p, i)).normalize())
        .collect();
    let triangles = subdivide(&mut verts, subdivisions, |a, b| {
        ((*a + *b) * 0.5).normalize()
    });
    Mesh {
        positions: verts.iter().map(|v| v.as_vec3().to_array()).collect(),
        triangles,
    }
}

/// The icosphere as `oxray bench` and `oxray_scene::mesh::Mesh::icosphere` make it: the same
/// topology as [`icosphere`], with the vertices computed in `f32` (so they differ from
/// [`icosphere`]'s in the last bits). The benchmark and GPU tests use this one, so that their
/// numbers compare with the command-line tool's.
#[must_use]
pub fn icosphere_f32(subdivisions: u32) -> Mesh {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut positions: Vec<[f32; 3]> = (0..12)
        .map(|i| normalize(icosahedron_vertex(t as f64, i).map(|x| x as f32)))
        .collect();
    let triangles = subdivide(&mut positions, subdivisions, |p, q| {
        normalize([p[0] + q[0], p[1] + q[1], p[2] + q[2]])
    });
    Mesh {
        positions,
        triangles,
    }
}

fn normalize(p: [f32; 3]) -> [f32; 3] {
    let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    [p[0] / l, p[1] / l, p[2] / l]
}

/// The closed surface of the cube `[-1, 1]^3`, each face an `n` x `n` grid of quads split into two
/// triangles, with shared vertices; counter-clockwise seen from outside.
#[must_use]
pub fn grid_cube(n: u32) -> Mesh {
    let mut mesh = Mesh::default();
    let mut index: HashMap<[i64; 3], u32> = HashMap::new();
    let coord = |i: u32| -1.0 + 2.0 * i as f32 / n as f32;
    // For each face: the fixed axis, its sign, and the two in-plane axes ordered so that
    // (a-axis) x (b-axis) points outwards.
    let faces = [
        (0, 1.0, 1, 2),
        (0, -1.0, 2, 1),
        (1, 1.0, 2, 0),
        (1, -1.0, 0, 2),
        (2, 1.0, 0, 1),
        (2, -1.0, 1, 0),
    ];
    for (axis, sign, ua, ub) in faces {
        let mut vid = |i: u32, j: u32, mesh: &mut Mesh| {
            let mut p = [0.0f32; 3];
            p[axis] = sign;
            p[ua] = coord(i);
            p[ub] = coord(j);
            let key = p.map(|x| (x as f64 * 1e6).round() as i64);
            *index.entry(key).or_insert_with(|| {
                mesh.positions.push(p);
                mesh.positions.len() as u32 - 1
            })
        };
        for i in 0..n {
            for j in 0..n {
                let a = vid(i, j, &mut mesh);
                let b = vid(i + 1, j, &mut mesh);
                let c = vid(i + 1, j + 1, &mut mesh);
                let d = vid(i, j + 1, &mut mesh);
                mesh.triangles.push([a, b, c]);
                mesh.triangles.push([a, c, d]);
            }
        }
    }
    mesh
}

/// `n` random triangles with vertices within `size` of a centre uniform in `[0, extent]^3`.
pub fn random_soup(rng: &mut Rng, n: usize, extent: f32, size: f32) -> Vec<Tri> {
    (0..n)
        .map(|_| {
            let c = rng.vec3(0.0, extent);
            std::array::from_fn(|_| (c + rng.vec3(-size, size)).to_array())
        })
        .collect()
}

/// A triangle in the plane `z`, counter-clockwise seen from `+z` (so a ray travelling along
/// `-z` hits its front face), containing the point `(x, y, z)` well inside it.
#[must_use]
pub fn tri_at(x: f32, y: f32, z: f32, s: f32) -> Tri {
    [[x - s, y - s, z], [x + s, y - s, z], [x, y + s, z]]
}

/// Flattens triangles into a soup vertex list.
#[must_use]
pub fn soup(tris: &[Tri]) -> Vec<[f32; 3]> {
    tris.iter().flat_map(|t| t.iter().copied()).collect()
}

/// Reads the `v` and `f` lines of a Wavefront OBJ text (faces with more than three vertices are
/// split into fans; `a/b/c` forms keep the position index; 1-based indices). A small reader
/// without dependencies, whose output the engine's tests pin (triangle order included).
pub fn parse_obj(text: &str) -> Result<Mesh, String> {
    let mut mesh = Mesh::default();
    for (n, line) in text.lines().enumerate() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let c: Vec<f32> = it
                    .take(3)
                    .map(|s| s.parse::<f32>().map_err(|e| format!("line {}: {e}", n + 1)))
                    .collect::<Result<_, _>>()?;
                if c.len() != 3 {
                    return Err(format!("line {}: a vertex needs 3 coordinates", n + 1));
                }
                mesh.positions.push([c[0], c[1], c[2]]);
            }
            Some("f") => {
                let idx: Vec<u32> = it
                    .map(|s| {
                        let first = s.split('/').next().unwrap_or("");
                        first
                            .parse::<u32>()
                            .ok()
                            .filter(|&i| i >= 1)
                            .map(|i| i - 1)
                            .ok_or_else(|| format!("line {}: bad face index {s:?}", n + 1))
                    })
                    .collect::<Result<_, _>>()?;
                if idx.len() < 3 {
                    return Err(format!("line {}: a face needs 3 vertices", n + 1));
                }
                for k in 1..idx.len() - 1 {
                    mesh.triangles.push([idx[0], idx[k], idx[k + 1]]);
                }
            }
            _ => {}
        }
    }
    if let Some(bad) = mesh
        .triangles
        .iter()
        .flatten()
        .find(|&&i| i as usize >= mesh.positions.len())
    {
        return Err(format!("face index {} out of range", bad + 1));
    }
    Ok(mesh)
}

/// Loads an OBJ file with `tobj` (all models, triangulated, points and lines ignored), as the
/// GPU tests and the `gpu_raycast` example load their meshes.
pub fn load_obj(path: &Path) -> Result<Mesh, String> {
    let opts = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
    };
    let (models, _) =
        tobj::load_obj(path, &opts).map_err(|e| format!("{}: {e}", path.display()))?;
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
    let n = mesh.positions.len();
    if mesh.triangles.iter().flatten().any(|&i| i as usize >= n) {
        return Err(format!("{}: vertex index out of range", path.display()));
    }
    Ok(mesh)
}

/// The environment variable naming a directory of data meshes, searched first.
pub const MESH_DIR_ENV: &str = "OXRAY_MESH_DIR";

/// The shared data meshes beside the checkout: `<workspace>/../shared/data/meshes`.
#[must_use]
pub fn shared_mesh_dir() -> PathBuf {
    // This crate sits at `<workspace>/crates/oxray-testkit`, as every crate of the workspace.
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/meshes")
}

/// Where data meshes are looked for, in order: `$OXRAY_MESH_DIR`, `../shared/data/meshes` beside
/// the checkout ([`shared_mesh_dir`]), and `carry/meshes` under the working directory.
#[must_use]
pub fn mesh_dirs() -> Vec<PathBuf> {
    let mut dirs: Vec<PathBuf> = Vec::new();
    if let Ok(d) = std::env::var(MESH_DIR_ENV) {
        dirs.push(d.into());
    }
    dirs.push(shared_mesh_dir());
    dirs.push("carry/meshes".into());
    dirs
}

/// The first file called `name` in the [`mesh_dirs`], if any.
#[must_use]
pub fn find_mesh(name: &str) -> Option<PathBuf> {
    mesh_dirs()
        .into_iter()
        .map(|d| d.join(name))
        .find(|p| p.is_file())
}

/// The file name of the Stanford bunny among the data meshes.
pub const BUNNY: &str = "stanford-bunny.obj";

/// The Stanford bunny (see [`find_mesh`]), if it is present.
#[must_use]
pub fn bunny_path() -> Option<PathBuf> {
    find_mesh(BUNNY)
}

/// Loads the bunny with [`parse_obj`], or prints why `test` is skipped and returns `None`.
///
/// # Panics
///
/// If the file is present but cannot be read or parsed.
#[must_use]
pub fn load_bunny(test: &str) -> Option<Mesh> {
    let Some(path) = bunny_path() else {
        println!(
            "skipping {test}: {BUNNY} is absent from ../shared/data/meshes (set {MESH_DIR_ENV})"
        );
        return None;
    };
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    Some(parse_obj(&text).unwrap_or_else(|e| panic!("cannot parse {}: {e}", path.display())))
}

/// Deformation `round` of `base` into `m` (same topology): a smooth wave whose amplitude grows
/// with the round, random jitter, a few vertices thrown far away, a few triangles collapsed to
/// a point (inactive) and earlier collapsed ones restored: what the update tests (guide §5.6)
/// refit to.
pub fn deform(rng: &mut Rng, base: &Mesh, m: &mut Mesh, round: u32) {
    let amp = 0.05 * round as f32;
    for (p, b) in m.positions.iter_mut().zip(&base.positions) {
        let b = Vec3::from(*b);
        let wave = Vec3::new((b.y * 3.0).sin(), (b.z * 2.0).cos(), (b.x * 5.0).sin()) * amp;
        *p = (b + wave + rng.vec3(-0.02, 0.02)).to_array();
    }
    for _ in 0..3 {
        let k = rng.below(m.positions.len());
        m.positions[k] = (Vec3::from(m.positions[k]) * 4.0).to_array();
    }
    for _ in 0..5 {
        let t = m.triangles[rng.below(m.triangles.len())];
        let p = m.positions[t[0] as usize];
        m.positions[t[1] as usize] = p;
        m.positions[t[2] as usize] = p;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_closed_and_outward(m: &Mesh) {
        for (e, faces) in m.edge_map() {
            assert_eq!(faces.len(), 2, "edge {e:?} used by {faces:?}");
        }
        let c = m
            .positions
            .iter()
            .fold(DVec3::ZERO, |s, p| s + Vec3::from(*p).as_dvec3())
            / m.positions.len() as f64;
        for i in 0..m.triangles.len() {
            let centroid = m
                .tri(i)
                .iter()
                .fold(DVec3::ZERO, |s, p| s + Vec3::from(*p).as_dvec3() / 3.0);
            assert!(
                m.face_normal(i).dot(centroid - c) > 0.0,
                "face {i} points inwards"
            );
        }
        // Euler characteristic of a sphere.
        let chi = m.positions.len() as i64 - m.edge_map().len() as i64 + m.triangles.len() as i64;
        assert_eq!(chi, 2);
    }

    #[test]
    fn icospheres_have_the_expected_counts_and_are_closed() {
        for s in 0..4 {
            let n = 4u32.pow(s) as usize;
            for m in [icosphere(s), icosphere_f32(s)] {
                assert_eq!(m.triangles.len(), 20 * n);
                assert_eq!(m.positions.len(), 10 * n + 2);
                assert_closed_and_outward(&m);
                for p in &m.positions {
                    assert!((Vec3::from(*p).length() - 1.0).abs() < 1e-6);
                }
            }
            assert_eq!(icosphere(s).triangles, icosphere_f32(s).triangles);
        }
    }

    #[test]
    fn icospheres_are_deterministic() {
        assert_eq!(icosphere(3), icosphere(3));
        assert_eq!(icosphere_f32(3), icosphere_f32(3));
        // The two arithmetics round differently somewhere.
        assert_ne!(icosphere(3).positions, icosphere_f32(3).positions);
    }

    fn fnv(words: impl Iterator<Item = u32>) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for w in words {
            for b in w.to_le_bytes() {
                h ^= b as u64;
                h = h.wrapping_mul(0x0000_0100_0000_01b3);
            }
        }
        h
    }

    fn mesh_hash(m: &Mesh) -> u64 {
        fnv(m
            .positions
            .iter()
            .flatten()
            .map(|x| x.to_bits())
            .chain(m.triangles.iter().flatten().copied()))
    }

    /// Fingerprints of the generated meshes, taken from the generators these were moved from:
    /// the tests built on them (and the benchmark's icosphere) depend on every bit.
    #[test]
    fn pinned_hashes() {
        assert_eq!(mesh_hash(&icosphere(4)), 0xacf8c3ac32012985);
        assert_eq!(mesh_hash(&icosphere_f32(4)), 0x1e57e45cdaaa0f2d);
        assert_eq!(mesh_hash(&grid_cube(6)), 0xb75faa89fabe688d);
        let s = random_soup(&mut Rng::new(5), 100, 10.0, 1.0);
        assert_eq!(
            fnv(s.iter().flatten().flatten().map(|x| x.to_bits())),
            0xa25afcba1e0993a3
        );
    }

    #[test]
    fn grid_cubes_have_the_expected_counts_and_are_closed() {
        for n in 1..5u32 {
            let m = grid_cube(n);
            assert_eq!(m.triangles.len() as u32, 12 * n * n);
            assert_eq!(m.positions.len() as u32, 6 * n * n + 2);
            assert_closed_and_outward(&m);
            assert_eq!(m.bounds(), ([-1.0; 3], [1.0; 3]));
        }
    }

    #[test]
    fn random_soups_are_deterministic_and_in_range() {
        let a = random_soup(&mut Rng::new(1), 50, 10.0, 0.5);
        let b = random_soup(&mut Rng::new(1), 50, 10.0, 0.5);
        assert_eq!(a, b);
        assert_eq!(a.len(), 50);
        assert!(a
            .iter()
            .flatten()
            .flatten()
            .all(|&x| (-0.5..=10.5).contains(&x)));
        assert_eq!(soup(&a).len(), 150);
        assert_eq!(soup(&a)[3], a[1][0]);
    }

    #[test]
    fn tri_at_contains_its_point_and_faces_up() {
        let t = tri_at(1.0, 2.0, 3.0, 0.5);
        let m = Mesh {
            positions: t.to_vec(),
            triangles: vec![[0, 1, 2]],
        };
        assert!(m.face_normal(0).z > 0.0);
        assert!(t.iter().all(|p| p[2] == 3.0));
    }

    #[test]
    fn parse_obj_reads_positions_and_fans() {
        let m = parse_obj("# c\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nf 1/1/1 2 3 4\n")
            .unwrap();
        assert_eq!(m.positions.len(), 4);
        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert!(parse_obj("v 0 0\n").is_err());
        assert!(parse_obj("v 0 0 0\nf 1 2\n").is_err());
        assert!(parse_obj("v 0 0 0\nf 0 1 1\n").is_err());
        assert!(parse_obj("v 0 0 0\nf 1 1 2\n").is_err());
    }

    #[test]
    fn load_obj_agrees_with_parse_obj_on_triangles() {
        let text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 1\nf 1 2 3\nf 1 3 4\n";
        let dir = std::env::temp_dir().join(format!("oxray-testkit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("quad.obj");
        std::fs::write(&path, text).unwrap();
        let loaded = load_obj(&path);
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(loaded.unwrap(), parse_obj(text).unwrap());
        assert!(load_obj(Path::new("/nonexistent/oxray-testkit.obj")).is_err());
    }

    #[test]
    fn mesh_dirs_end_with_the_shared_data_and_carry() {
        let dirs = mesh_dirs();
        let n = dirs.len();
        assert_eq!(dirs[n - 2], shared_mesh_dir());
        assert_eq!(dirs[n - 1], PathBuf::from("carry/meshes"));
        assert!(shared_mesh_dir().ends_with("shared/data/meshes"));
        assert_eq!(find_mesh("no such mesh.obj"), None);
    }

    #[test]
    fn the_bunny_loads_with_both_readers() {
        let Some(m) = load_bunny("the_bunny_loads_with_both_readers") else {
            return;
        };
        assert_eq!((m.positions.len(), m.triangles.len()), (35947, 69451));
        // `tobj` drops unused vertices and renumbers the rest; the triangles are the same, in
        // the same order.
        let t = load_obj(&bunny_path().unwrap()).unwrap();
        assert_eq!(t.triangles.len(), m.triangles.len());
        assert!(t.positions.len() < m.positions.len());
        assert!(t.soup() == m.soup());
    }
}
