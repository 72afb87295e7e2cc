//! Meshes and rays shared by the tests and the `gpu_raycast` example. The rays are generated as
//! `oxray bench` generates them (crates/oxray-cli/src/bench.rs), so numbers are comparable.

#![allow(dead_code)]

use glam::Vec3;
use oxray_core::{BuildFlags, BuildOptions, IndexBuffer, Ray, TriangleInput, VertexBuffer};
use oxray_cpu::Gas;
use std::path::{Path, PathBuf};

/// An indexed triangle mesh.
#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub positions: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// A unit icosphere: 20 * 4^subdivisions triangles.
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
            let mut mid = std::collections::HashMap::new();
            let mut midpoint = |a: u32, b: u32, positions: &mut Vec<[f32; 3]>| {
                *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    let (p, q) = (positions[a as usize], positions[b as usize]);
                    positions.push(normalize([p[0] + q[0], p[1] + q[1], p[2] + q[2]]));
                    positions.len() as u32 - 1
                })
            };
            let mut next = Vec::with_capacity(triangles.len() * 4);
            for [a, b, c] in triangles {
                let ab = midpoint(a, b, &mut positions);
                let bc = midpoint(b, c, &mut positions);
                let ca = midpoint(c, a, &mut positions);
                next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
            }
            triangles = next;
        }
        Mesh {
            positions,
            triangles,
        }
    }

    /// Loads an OBJ file (all models, triangulated).
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

    /// The box around the vertices as `(min, max)`.
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

    /// Builds a GAS over the mesh.
    pub fn build(&self, flags: BuildFlags) -> Result<Gas, oxray_core::BuildError> {
        let input = TriangleInput::new(VertexBuffer::f32x3(&self.positions))
            .indices(IndexBuffer::u32x3(&self.triangles));
        Gas::build(&BuildOptions::new(flags), &[input.into()])
    }
}

fn normalize(p: [f32; 3]) -> [f32; 3] {
    let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    [p[0] / l, p[1] / l, p[2] / l]
}

/// Where the shared data meshes are: `$OXRAY_MESH_DIR`, `../shared/data/meshes` beside the
/// checkout, or `carry/meshes` under the working directory.
pub fn find_mesh(name: &str) -> Option<PathBuf> {
    let mut dirs: Vec<PathBuf> = Vec::new();
    if let Ok(d) = std::env::var("OXRAY_MESH_DIR") {
        dirs.push(d.into());
    }
    dirs.push(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/meshes"));
    dirs.push("carry/meshes".into());
    dirs.into_iter().map(|d| d.join(name)).find(|p| p.is_file())
}

/// SplitMix64, as `oxray bench` uses.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }
}

fn center_radius(mesh: &Mesh) -> (Vec3, f32) {
    let (lo, hi) = mesh.bounds();
    let (lo, hi) = (Vec3::from(lo), Vec3::from(hi));
    ((lo + hi) * 0.5, (hi - lo).length() * 0.5)
}

/// Primary rays of a `width` x `height` pinhole camera that frames the mesh (`oxray bench`'s
/// coherent rays).
pub fn camera_rays(mesh: &Mesh, width: u32, height: u32) -> Vec<Ray> {
    let (c, r) = center_radius(mesh);
    let eye = c + Vec3::new(0.35, 0.25, 1.0).normalize() * (2.2 * r);
    let fwd = (c - eye).normalize();
    let right = fwd.cross(Vec3::Y).normalize();
    let up = right.cross(fwd);
    let tan = (30f32.to_radians() * 0.5).tan();
    let aspect = width as f32 / height as f32;
    let mut rays = Vec::with_capacity((width * height) as usize);
    for y in 0..height {
        for x in 0..width {
            let sx = ((x as f32 + 0.5) / width as f32 * 2.0 - 1.0) * tan * aspect;
            let sy = (1.0 - (y as f32 + 0.5) / height as f32 * 2.0) * tan;
            let d = (fwd + right * sx + up * sy).normalize();
            rays.push(Ray::new(eye, d));
        }
    }
    rays
}

/// `n` rays from random surface points in cosine-distributed directions (`oxray bench`'s
/// incoherent rays).
pub fn hemisphere_rays(mesh: &Mesh, n: usize, seed: u64) -> Vec<Ray> {
    let (_, r) = center_radius(mesh);
    let mut rng = Rng::new(seed);
    let mut rays = Vec::with_capacity(n);
    if mesh.triangles.is_empty() {
        return rays;
    }
    while rays.len() < n {
        let t = mesh.triangles[(rng.next_u64() % mesh.triangles.len() as u64) as usize];
        let [a, b, c] = t.map(|i| Vec3::from(mesh.positions[i as usize]));
        let nrm = (b - a).cross(c - a);
        if nrm.length_squared() == 0.0 || !nrm.is_finite() {
            continue;
        }
        let nrm = nrm.normalize();
        let (mut u, mut v) = (rng.next_f32(), rng.next_f32());
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        let p = a + (b - a) * u + (c - a) * v;
        let (r1, r2) = (rng.next_f32(), rng.next_f32());
        let phi = std::f32::consts::TAU * r1;
        let s = r2.sqrt();
        let (t1, t2) = nrm.any_orthonormal_pair();
        let d = (t1 * (phi.cos() * s) + t2 * (phi.sin() * s) + nrm * (1.0 - r2).sqrt()).normalize();
        rays.push(Ray::with_interval(p, d, 1e-5 * r, f32::INFINITY));
    }
    rays
}

/// The two ray sets of `oxray bench` for a mesh: a `side` x `side` camera and as many
/// hemisphere rays (seed 7).
pub fn bench_rays(mesh: &Mesh, side: u32) -> (Vec<Ray>, Vec<Ray>) {
    (
        camera_rays(mesh, side, side),
        hemisphere_rays(mesh, (side * side) as usize, 7),
    )
}

/// Rays that exercise the corner cases: through vertices and edges (exact-fallback path),
/// axis-aligned directions (zero direction components), short intervals ending exactly at a
/// hit, and invalid rays.
pub fn tricky_rays(mesh: &Mesh, gas: &Gas, n: usize, seed: u64) -> Vec<Ray> {
    let (c, r) = center_radius(mesh);
    let mut rng = Rng::new(seed);
    let mut rays = Vec::with_capacity(n);
    let axes = [Vec3::X, Vec3::Y, Vec3::Z, -Vec3::X, -Vec3::Y, -Vec3::Z];
    while rays.len() < n {
        let k = rays.len() % 6;
        let tri = mesh.triangles[(rng.next_u64() % mesh.triangles.len() as u64) as usize];
        let v = Vec3::from(mesh.positions[tri[(rng.next_u64() % 3) as usize] as usize]);
        let w = Vec3::from(mesh.positions[tri[(rng.next_u64() % 3) as usize] as usize]);
        let ray = match k {
            // Aimed exactly at a vertex.
            0 => {
                let o = c + Vec3::new(rng.next_f32() - 0.5, rng.next_f32() - 0.5, 1.0) * 3.0 * r;
                Ray::new(o, v - o)
            }
            // Aimed at an edge midpoint.
            1 => {
                let o = c - Vec3::new(1.0, rng.next_f32() - 0.5, rng.next_f32() - 0.5) * 3.0 * r;
                Ray::new(o, (v + w) * 0.5 - o)
            }
            // Axis-aligned from outside, through a vertex's coordinates.
            2 => {
                let d = axes[(rng.next_u64() % 6) as usize];
                Ray::new(v - d * 3.0 * r, d)
            }
            // An interval ending exactly at the closest hit (closed interval).
            3 => {
                let o = c + Vec3::new(rng.next_f32() - 0.5, 1.0, rng.next_f32() - 0.5) * 3.0 * r;
                let d =
                    c + (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5) * r - o;
                let t = gas
                    .intersect(&Ray::new(o, d))
                    .map_or(f32::INFINITY, |h| h.t);
                Ray::with_interval(o, d, 0.0, t)
            }
            // Invalid: zero direction, NaN, negative tmin, tmin > tmax.
            4 => {
                let bad = [
                    Ray::new(c, Vec3::ZERO),
                    Ray::new(Vec3::new(f32::NAN, 0.0, 0.0), Vec3::X),
                    Ray::with_interval(c, Vec3::X, -1.0, 1.0),
                    Ray::with_interval(c, Vec3::X, 2.0, 1.0),
                    Ray::new(c, Vec3::new(f32::INFINITY, 0.0, 0.0)),
                ];
                bad[(rng.next_u64() % bad.len() as u64) as usize]
            }
            // From inside the mesh, any direction.
            _ => {
                let d = Vec3::new(
                    rng.next_f32() - 0.5,
                    rng.next_f32() - 0.5,
                    rng.next_f32() - 0.5,
                );
                if d == Vec3::ZERO {
                    continue;
                }
                Ray::new(c + d * 0.1 * r, d)
            }
        };
        rays.push(ray);
    }
    rays
}
