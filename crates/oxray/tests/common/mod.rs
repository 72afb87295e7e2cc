//! Helpers shared by the integration tests: a brute-force reference for ray queries, a
//! deterministic random-number generator, mesh generators (icosphere, subdivided cube), a tiny
//! OBJ reader and the path of the Stanford bunny in `shared/data`.
//!
//! Each test binary uses a different subset of these helpers.
#![allow(dead_code)]

use glam::Vec3;
use oxray::bvh::triangle::{is_degenerate, TriangleHit, WatertightRay};
use oxray::{Hit, HitKind, Ray};
use std::collections::HashMap;
use std::path::PathBuf;

/// A triangle as three `f32` positions (the layout of a tightly packed `F32x3` soup).
pub type Tri = [[f32; 3]; 3];

/// One hit of the brute-force reference.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefHit {
    /// Index of the triangle in the soup.
    pub prim: u32,
    /// The watertight test's result.
    pub hit: TriangleHit,
}

/// Every hit of `ray` on the soup within the closed interval `[tmin, tmax]`, in triangle order.
/// Degenerate triangles (non-finite vertex or zero area) are skipped, as the builder makes them
/// inactive; an invalid ray hits nothing.
pub fn reference_hits(tris: &[Tri], ray: &Ray) -> Vec<RefHit> {
    if ray.validate().is_err() {
        return Vec::new();
    }
    let wr = WatertightRay::new(ray.origin, ray.direction);
    tris.iter()
        .enumerate()
        .filter(|(_, t)| !is_degenerate(t[0].into(), t[1].into(), t[2].into()))
        .filter_map(|(i, t)| {
            wr.intersect(&t[0], &t[1], &t[2], ray.tmin, ray.tmax)
                .map(|hit| RefHit {
                    prim: i as u32,
                    hit,
                })
        })
        .collect()
}

/// The closest reference hit (the lowest triangle index among equal distances).
pub fn reference_closest(tris: &[Tri], ray: &Ray) -> Option<RefHit> {
    closest_of(&reference_hits(tris, ray))
}

/// The closest of a set of reference hits (the first among equal distances).
pub fn closest_of(hits: &[RefHit]) -> Option<RefHit> {
    hits.iter()
        .copied()
        .fold(None, |best: Option<RefHit>, h| match best {
            Some(b) if b.hit.t <= h.hit.t => Some(b),
            _ => Some(h),
        })
}

/// Checks a GAS closest hit of a single-input triangle soup against the reference:
/// the distance must equal the reference's closest distance bit for bit, and the primitive
/// reported must itself be hit by the reference at exactly that distance (ties may pick another
/// primitive), with the same barycentrics and facing.
pub fn check_closest(got: Option<Hit>, tris: &[Tri], ray: &Ray) -> Result<(), String> {
    let hits = reference_hits(tris, ray);
    let best = closest_of(&hits);
    match (got, best) {
        (None, None) => Ok(()),
        (Some(g), None) => Err(format!(
            "GAS hit {g:?} but the reference misses; ray {ray:?}"
        )),
        (None, Some(b)) => Err(format!(
            "GAS missed but the reference hits {b:?}; ray {ray:?}"
        )),
        (Some(g), Some(b)) => {
            // Bit for bit, except that +0 and -0 are the same distance (a tie).
            let same = g.t.to_bits() == b.hit.t.to_bits() || (g.t == 0.0 && b.hit.t == 0.0);
            if !same {
                return Err(format!(
                    "closest t differs: GAS {g:?}, reference {b:?}; ray {ray:?}"
                ));
            }
            let Some(r) = hits
                .iter()
                .find(|h| h.prim == g.primitive_index && h.hit.t.to_bits() == g.t.to_bits())
            else {
                return Err(format!(
                    "GAS returned primitive {} at t = {}, which the reference does not hit at that t; \
                     reference hits: {hits:?}; ray {ray:?}",
                    g.primitive_index, g.t
                ));
            };
            if g.u.to_bits() != r.hit.u.to_bits() || g.v.to_bits() != r.hit.v.to_bits() {
                return Err(format!(
                    "barycentrics differ: GAS {g:?}, reference {r:?}; ray {ray:?}"
                ));
            }
            let kind = if r.hit.front_face {
                HitKind::TRIANGLE_FRONT_FACE
            } else {
                HitKind::TRIANGLE_BACK_FACE
            };
            if g.hit_kind != kind {
                return Err(format!("hit kind differs: GAS {g:?}, reference {r:?}"));
            }
            if g.build_input != 0 || g.sbt_gas_index != 0 {
                return Err(format!("single-input GAS reported {g:?}"));
            }
            Ok(())
        }
    }
}

/// Every field of a hit as bits: `t`, `u`, `v`, primitive index, SBT-GAS index, build input,
/// hit kind.
pub type HitBits = (u32, u32, u32, u32, u32, u32, u8);

/// The bits of every field of a hit, for exact comparisons.
pub fn hit_bits(h: &Option<Hit>) -> Option<HitBits> {
    h.map(|h| {
        (
            h.t.to_bits(),
            h.u.to_bits(),
            h.v.to_bits(),
            h.primitive_index,
            h.sbt_gas_index,
            h.build_input,
            h.hit_kind.0,
        )
    })
}

/// A proptest configuration with a fixed seed, so that every run checks the same cases and a
/// failure reproduces, and no regression files are written. `OXRAY_PROPTEST_SEED=<u64>` explores
/// other cases.
pub fn proptest_config(cases: u32) -> proptest::test_runner::Config {
    let seed = std::env::var("OXRAY_PROPTEST_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0x6f78_7261_7939);
    proptest::test_runner::Config {
        cases,
        rng_seed: proptest::test_runner::RngSeed::Fixed(seed),
        failure_persistence: None,
        max_shrink_iters: 2048,
        ..Default::default()
    }
}

/// A small deterministic generator (SplitMix64), so that tests do not depend on a crate's
/// stream staying the same across versions.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator from a seed.
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`.
    pub fn f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.f32()
    }

    /// Uniform in `0..n`.
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }

    /// A point uniform in the cube `[lo, hi]^3`.
    pub fn vec3(&mut self, lo: f32, hi: f32) -> Vec3 {
        Vec3::new(self.range(lo, hi), self.range(lo, hi), self.range(lo, hi))
    }

    /// A direction with components uniform in `[-1, 1)`, not too short.
    pub fn dir(&mut self) -> Vec3 {
        loop {
            let d = self.vec3(-1.0, 1.0);
            if d.length() > 0.1 {
                return d;
            }
        }
    }
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

/// An indexed mesh.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    /// Positions.
    pub vertices: Vec<[f32; 3]>,
    /// Counter-clockwise (seen from outside) index triplets.
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// The vertices of triangle `i`.
    pub fn tri(&self, i: usize) -> Tri {
        self.triangles[i].map(|k| self.vertices[k as usize])
    }

    /// The vertex position `i`.
    pub fn v(&self, i: u32) -> Vec3 {
        Vec3::from(self.vertices[i as usize])
    }

    /// The (unnormalised) geometric normal `(v1 - v0) x (v2 - v0)` of triangle `i`, in `f64`.
    pub fn face_normal(&self, i: usize) -> glam::DVec3 {
        let [a, b, c] = self.triangles[i].map(|k| self.v(k).as_dvec3());
        (b - a).cross(c - a)
    }

    /// Edge (sorted vertex pair) to the triangles that use it.
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
}

/// An icosphere of radius 1 around the origin: a closed mesh with shared vertices, `subdivisions`
/// times subdivided (20 * 4^subdivisions triangles), counter-clockwise seen from outside.
pub fn icosphere(subdivisions: u32) -> Mesh {
    let p = (1.0 + 5f64.sqrt()) / 2.0;
    let mut verts: Vec<glam::DVec3> = [
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
    ]
    .iter()
    .map(|v| glam::DVec3::from(*v).normalize())
    .collect();
    let mut faces: Vec<[u32; 3]> = vec![
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
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut midpoint = |a: u32, b: u32, verts: &mut Vec<glam::DVec3>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                verts.push(((verts[a as usize] + verts[b as usize]) * 0.5).normalize());
                verts.len() as u32 - 1
            })
        };
        let mut next = Vec::with_capacity(faces.len() * 4);
        for [a, b, c] in faces {
            let ab = midpoint(a, b, &mut verts);
            let bc = midpoint(b, c, &mut verts);
            let ca = midpoint(c, a, &mut verts);
            next.extend_from_slice(&[[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        faces = next;
    }
    Mesh {
        vertices: verts.iter().map(|v| v.as_vec3().to_array()).collect(),
        triangles: faces,
    }
}

/// The closed surface of the cube `[-1, 1]^3`, each face an `n` x `n` grid of quads split into two
/// triangles, with shared vertices; counter-clockwise seen from outside.
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
                mesh.vertices.push(p);
                mesh.vertices.len() as u32 - 1
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

/// Reads the `v` and `f` lines of a Wavefront OBJ text (faces with more than three vertices are
/// split into fans; `a/b/c` forms keep the position index; 1-based indices).
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
                mesh.vertices.push([c[0], c[1], c[2]]);
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
        .find(|&&i| i as usize >= mesh.vertices.len())
    {
        return Err(format!("face index {} out of range", bad + 1));
    }
    Ok(mesh)
}

/// The Stanford bunny of `shared/data/meshes`, if it is present.
pub fn bunny_path() -> Option<PathBuf> {
    let p = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../../shared/data/meshes/stanford-bunny.obj"
    ));
    p.is_file().then_some(p)
}

/// Loads the bunny, or prints why a test is skipped and returns `None`.
pub fn load_bunny(test: &str) -> Option<Mesh> {
    let Some(path) = bunny_path() else {
        println!("skipping {test}: ../shared/data/meshes/stanford-bunny.obj is absent");
        return None;
    };
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    Some(parse_obj(&text).unwrap_or_else(|e| panic!("cannot parse {}: {e}", path.display())))
}
