//! The benchmark ray sets of `oxray bench` and the GPU comparisons — coherent camera rays,
//! incoherent (diffuse) rays and shadow rays — and "tricky" rays aimed at the corner cases of
//! traversal.
//!
//! # Stability
//!
//! The generated rays must stay **bit-identical** across versions: benchmark results (see
//! `docs/BENCHMARKS.md`), the rays exported for the Embree comparison and the GPU-against-CPU
//! checks are compared across versions of the engine, which is only meaningful on the same rays.
//! Changing any arithmetic here, the order of the random draws, or the seeds of [`BenchRays`] is
//! a change of the benchmark; the `pinned_hashes` test guards against doing it by accident.
//!
//! The functions take plain slices (`positions`, `triangles`), so that any mesh type can hand its
//! buffers over, and return [`oxray_core::Ray`]s.

use crate::mesh::bounds;
use crate::rng::Rng;
use glam::Vec3;
use oxray_core::Ray;

/// The seed of [`BenchRays::incoherent`].
pub const INCOHERENT_SEED: u64 = 7;

/// The seed of [`BenchRays::shadow`].
pub const SHADOW_SEED: u64 = 11;

/// The centre of the box around `positions` and the radius of its bounding sphere (half the
/// box's diagonal).
#[must_use]
pub fn center_radius(positions: &[[f32; 3]]) -> (Vec3, f32) {
    let (lo, hi) = bounds(positions);
    let (lo, hi) = (Vec3::from(lo), Vec3::from(hi));
    ((lo + hi) * 0.5, (hi - lo).length() * 0.5)
}

/// Primary rays of a `width` x `height` pinhole camera (30° vertical field of view) that frames
/// the mesh from above, right and in front, in scanline order from the top row: `oxray bench`'s
/// coherent rays.
#[must_use]
pub fn camera_rays(positions: &[[f32; 3]], width: u32, height: u32) -> Vec<Ray> {
    let (c, r) = center_radius(positions);
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

/// A uniform point on a random triangle with its unit normal; `None` when the triangle drawn is
/// degenerate (the caller draws again).
fn surface_point(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    rng: &mut Rng,
) -> Option<(Vec3, Vec3)> {
    let t = triangles[(rng.next_u64() % triangles.len() as u64) as usize];
    let [a, b, c] = t.map(|i| Vec3::from(positions[i as usize]));
    let nrm = (b - a).cross(c - a);
    if nrm.length_squared() == 0.0 || !nrm.is_finite() {
        return None;
    }
    let (mut u, mut v) = (rng.f32(), rng.f32());
    if u + v > 1.0 {
        (u, v) = (1.0 - u, 1.0 - v);
    }
    Some((a + (b - a) * u + (c - a) * v, nrm.normalize()))
}

/// Whether some triangle has an area: without one, [`surface_point`] would never succeed.
fn has_surface(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> bool {
    triangles.iter().any(|t| {
        let [a, b, c] = t.map(|i| Vec3::from(positions[i as usize]));
        let n = (b - a).cross(c - a);
        n.length_squared() > 0.0 && n.is_finite()
    })
}

/// `n` rays leaving random points of random (non-degenerate) triangles in cosine-distributed
/// directions about the triangle's normal, with `tmin = 1e-5 * radius`: the secondary rays of a
/// path tracer, `oxray bench`'s incoherent rays. A mesh without area gives no rays.
#[must_use]
pub fn hemisphere_rays(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    n: usize,
    seed: u64,
) -> Vec<Ray> {
    let (_, r) = center_radius(positions);
    let mut rng = Rng::new(seed);
    let mut rays = Vec::with_capacity(n);
    if !has_surface(positions, triangles) {
        return rays;
    }
    while rays.len() < n {
        let Some((p, nrm)) = surface_point(positions, triangles, &mut rng) else {
            continue;
        };
        let (r1, r2) = (rng.f32(), rng.f32());
        let phi = std::f32::consts::TAU * r1;
        let s = r2.sqrt();
        let (t1, t2) = nrm.any_orthonormal_pair();
        let d = (t1 * (phi.cos() * s) + t2 * (phi.sin() * s) + nrm * (1.0 - r2).sqrt()).normalize();
        rays.push(Ray::with_interval(p, d, 1e-5 * r, f32::INFINITY));
    }
    rays
}

/// The point light of [`shadow_rays`]: above and in front of the mesh.
#[must_use]
pub fn shadow_light(positions: &[[f32; 3]]) -> Vec3 {
    let (c, r) = center_radius(positions);
    c + Vec3::new(0.4, 1.2, 0.8) * (2.0 * r)
}

/// `n` shadow rays: from random surface points to a point light above and in front of the
/// mesh ([`shadow_light`]), unit direction, `tmin = 1e-5 * radius` and `tmax` the light's
/// distance. Points facing away from the light still cast their ray, as a renderer that tests
/// visibility before shading would. A mesh without area gives no rays.
#[must_use]
pub fn shadow_rays(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    n: usize,
    seed: u64,
) -> Vec<Ray> {
    let (_, r) = center_radius(positions);
    let light = shadow_light(positions);
    let mut rng = Rng::new(seed);
    let mut rays = Vec::with_capacity(n);
    if !has_surface(positions, triangles) {
        return rays;
    }
    while rays.len() < n {
        let Some((p, _)) = surface_point(positions, triangles, &mut rng) else {
            continue;
        };
        let to = light - p;
        let dist = to.length();
        rays.push(Ray::with_interval(p, to / dist, 1e-5 * r, dist));
    }
    rays
}

/// The ray sets of a benchmark.
#[derive(Clone, Debug)]
pub struct BenchRays {
    /// Primary rays: a pinhole camera's (coherent), [`camera_rays`].
    pub coherent: Vec<Ray>,
    /// Diffuse rays: cosine-distributed hemisphere rays from surface points (incoherent),
    /// [`hemisphere_rays`] with [`INCOHERENT_SEED`].
    pub incoherent: Vec<Ray>,
    /// Shadow rays: from surface points to a point light, bounded by its distance,
    /// [`shadow_rays`] with [`SHADOW_SEED`].
    pub shadow: Vec<Ray>,
}

impl BenchRays {
    /// `oxray bench`'s rays for a mesh: a `side` x `side` camera and as many diffuse and shadow
    /// rays.
    #[must_use]
    pub fn new(positions: &[[f32; 3]], triangles: &[[u32; 3]], side: u32) -> Self {
        let n = (side * side) as usize;
        BenchRays {
            coherent: camera_rays(positions, side, side),
            incoherent: hemisphere_rays(positions, triangles, n, INCOHERENT_SEED),
            shadow: shadow_rays(positions, triangles, n, SHADOW_SEED),
        }
    }
}

/// `n` rays that exercise the corner cases, cycling through six kinds: aimed exactly at a
/// vertex, at an edge midpoint (the exact-fallback path), axis-aligned through a vertex's
/// coordinates (zero direction components), an interval `[0, t]` ending exactly at the closest
/// hit, invalid rays (zero or infinite direction, NaN origin, negative `tmin`, `tmin > tmax`), and
/// rays from inside the mesh.
///
/// `closest_t` gives the distance of a ray's closest hit (`None` for a miss): the backend's
/// closest-hit query (e.g. `|r| gas.intersect(r).map(|h| h.t)`), or
/// [`crate::oracle::reference_closest`] on the mesh's triangles.
///
/// # Panics
///
/// If `triangles` is empty.
pub fn tricky_rays(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    n: usize,
    seed: u64,
    mut closest_t: impl FnMut(&Ray) -> Option<f32>,
) -> Vec<Ray> {
    assert!(!triangles.is_empty(), "tricky rays need a triangle");
    let (c, r) = center_radius(positions);
    let mut rng = Rng::new(seed);
    let mut rays = Vec::with_capacity(n);
    let axes = [Vec3::X, Vec3::Y, Vec3::Z, -Vec3::X, -Vec3::Y, -Vec3::Z];
    while rays.len() < n {
        let k = rays.len() % 6;
        let tri = triangles[(rng.next_u64() % triangles.len() as u64) as usize];
        let v = Vec3::from(positions[tri[(rng.next_u64() % 3) as usize] as usize]);
        let w = Vec3::from(positions[tri[(rng.next_u64() % 3) as usize] as usize]);
        let ray = match k {
            // Aimed exactly at a vertex.
            0 => {
                let o = c + Vec3::new(rng.f32() - 0.5, rng.f32() - 0.5, 1.0) * 3.0 * r;
                Ray::new(o, v - o)
            }
            // Aimed at an edge midpoint.
            1 => {
                let o = c - Vec3::new(1.0, rng.f32() - 0.5, rng.f32() - 0.5) * 3.0 * r;
                Ray::new(o, (v + w) * 0.5 - o)
            }
            // Axis-aligned from outside, through a vertex's coordinates.
            2 => {
                let d = axes[(rng.next_u64() % 6) as usize];
                Ray::new(v - d * 3.0 * r, d)
            }
            // An interval ending exactly at the closest hit (closed interval).
            3 => {
                let o = c + Vec3::new(rng.f32() - 0.5, 1.0, rng.f32() - 0.5) * 3.0 * r;
                let d = c + (Vec3::new(rng.f32(), rng.f32(), rng.f32()) - 0.5) * r - o;
                let t = closest_t(&Ray::new(o, d)).unwrap_or(f32::INFINITY);
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
                let d = Vec3::new(rng.f32() - 0.5, rng.f32() - 0.5, rng.f32() - 0.5);
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

/// A 64-bit FNV-1a hash of every field of the rays (origin, `tmin`, direction, `tmax`, time) as
/// bits: a fingerprint for checking that a ray set has not changed.
#[must_use]
pub fn ray_hash(rays: &[Ray]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for r in rays {
        let words = [
            r.origin.x,
            r.origin.y,
            r.origin.z,
            r.tmin,
            r.direction.x,
            r.direction.y,
            r.direction.z,
            r.tmax,
            r.time,
        ];
        for w in words {
            for b in w.to_bits().to_le_bytes() {
                h ^= b as u64;
                h = h.wrapping_mul(0x0000_0100_0000_01b3);
            }
        }
    }
    h
}

/// `n` rays from random points around `mesh` (0.2 to 1.5 of its diagonal from its centre)
/// towards random points inside its box, a quarter of them with a shortened interval: the rays
/// the update tests trace after each deformation.
pub fn rays_around(rng: &mut Rng, mesh: &crate::mesh::Mesh, n: usize) -> Vec<Ray> {
    let (lo, hi) = mesh.bounds();
    let (lo, hi) = (Vec3::from(lo), Vec3::from(hi));
    let c = (lo + hi) * 0.5;
    let r = (hi - lo).length().max(1e-3);
    (0..n)
        .map(|_| {
            let o = c + rng.unit() * r * rng.range(0.2, 1.5);
            let target = lo + (hi - lo) * Vec3::new(rng.f32(), rng.f32(), rng.f32());
            let mut ray = Ray::new(o, (target - o).normalize_or(Vec3::X));
            if rng.below(4) == 0 {
                ray.tmax = r * rng.f32();
            }
            ray
        })
        .collect()
}

/// `n` rays from a sphere around `mesh` (1.5 of its diagonal from its centre) aimed exactly at
/// its vertices and edge midpoints, half each: rays through primitives that share them, where
/// which primitive a query reports and how many it lists are decided by the rules for ties.
pub fn rays_at_features(rng: &mut Rng, mesh: &crate::mesh::Mesh, n: usize) -> Vec<Ray> {
    let (lo, hi) = mesh.bounds();
    let (lo, hi) = (Vec3::from(lo), Vec3::from(hi));
    let c = (lo + hi) * 0.5;
    let r = (hi - lo).length();
    (0..n)
        .map(|_| {
            let t = mesh.triangles[rng.below(mesh.triangles.len())];
            let a = Vec3::from(mesh.positions[t[0] as usize]);
            let b = Vec3::from(mesh.positions[t[1] as usize]);
            let target = if rng.below(2) == 0 { a } else { (a + b) * 0.5 };
            let o = c + rng.unit() * r * 1.5;
            Ray::new(o, target - o)
        })
        .collect()
}

/// Query points for closest-point and signed-distance tests: `random` points uniform in
/// `mesh`'s box grown by half, then `features` times a vertex, an edge midpoint and a point
/// 1e-3 off a vertex (points on the surface and just off it, where signs and ties are
/// decided).
pub fn points_near(
    rng: &mut Rng,
    mesh: &crate::mesh::Mesh,
    random: usize,
    features: usize,
) -> Vec<Vec3> {
    let (lo, hi) = mesh.bounds();
    let (lo, hi) = (Vec3::from(lo), Vec3::from(hi));
    let (c, e) = ((lo + hi) * 0.5, (hi - lo) * 0.75);
    let mut p: Vec<Vec3> = (0..random)
        .map(|_| {
            c + e * Vec3::new(
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
            )
        })
        .collect();
    for _ in 0..features {
        let t = mesh.triangles[rng.below(mesh.triangles.len())];
        let a = Vec3::from(mesh.positions[t[0] as usize]);
        let b = Vec3::from(mesh.positions[t[1] as usize]);
        p.extend([a, (a + b) * 0.5, a + rng.unit() * 1e-3]);
    }
    p
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{bunny_path, icosphere_f32, load_obj, Mesh};
    use crate::oracle::reference_closest;

    /// Tricky rays whose bounded interval ends at the brute-force reference's closest hit
    /// (which a correct GAS reports bit for bit).
    fn tricky_by_oracle(m: &Mesh, n: usize, seed: u64) -> Vec<Ray> {
        let soup = m.soup();
        tricky_rays(&m.positions, &m.triangles, n, seed, |r| {
            reference_closest(&soup, r).map(|h| h.hit.t)
        })
    }

    /// The ray sets' fingerprints, taken from the generators these functions were moved from
    /// (`oxray bench` and the GPU tests): a failure here means the benchmark rays changed.
    #[test]
    fn pinned_hashes() {
        let m = icosphere_f32(3);
        let b = BenchRays::new(&m.positions, &m.triangles, 32);
        assert_eq!(ray_hash(&b.coherent), 0xc6bd72a0b978b038);
        assert_eq!(ray_hash(&b.incoherent), 0xbd0f0704f5a283ac);
        assert_eq!(ray_hash(&b.shadow), 0x6694bb556f0b65de);
        assert_eq!(ray_hash(&tricky_by_oracle(&m, 600, 3)), 0xb41d20277300d136);
        let Some(path) = bunny_path() else {
            println!("skipping the bunny's ray sets: the bunny is absent");
            return;
        };
        let m = load_obj(&path).unwrap();
        let b = BenchRays::new(&m.positions, &m.triangles, 64);
        assert_eq!(ray_hash(&b.coherent), 0x887f76827688dfe5);
        assert_eq!(ray_hash(&b.incoherent), 0x3361996afbece2c0);
        assert_eq!(ray_hash(&b.shadow), 0xf8641ab7cad5c92f);
        assert_eq!(ray_hash(&tricky_by_oracle(&m, 4096, 3)), 0xde1e7321cd81a6ca);
    }

    #[test]
    fn counts_and_determinism() {
        let m = icosphere_f32(2);
        let (p, t) = (&m.positions[..], &m.triangles[..]);
        for side in [1, 7, 16] {
            let a = BenchRays::new(p, t, side);
            let b = BenchRays::new(p, t, side);
            let n = (side * side) as usize;
            assert_eq!(
                (a.coherent.len(), a.incoherent.len(), a.shadow.len()),
                (n, n, n)
            );
            assert_eq!(ray_hash(&a.coherent), ray_hash(&b.coherent));
            assert_eq!(ray_hash(&a.incoherent), ray_hash(&b.incoherent));
            assert_eq!(ray_hash(&a.shadow), ray_hash(&b.shadow));
        }
        assert_eq!(camera_rays(p, 13, 5).len(), 65);
        for n in [0, 1, 6, 100, 1001] {
            assert_eq!(hemisphere_rays(p, t, n, 1).len(), n);
            assert_eq!(shadow_rays(p, t, n, 1).len(), n);
            assert_eq!(tricky_rays(p, t, n, 1, |_| None).len(), n);
        }
        // A prefix of a longer set is the shorter set; other seeds give other rays.
        let long = hemisphere_rays(p, t, 100, 7);
        assert_eq!(
            ray_hash(&long[..10]),
            ray_hash(&hemisphere_rays(p, t, 10, 7))
        );
        assert_ne!(ray_hash(&long), ray_hash(&hemisphere_rays(p, t, 100, 8)));
        assert_ne!(ray_hash(&shadow_rays(p, t, 100, 7)), ray_hash(&long));
    }

    #[test]
    fn rays_have_the_documented_shape() {
        let m = icosphere_f32(3);
        let (p, t) = (&m.positions[..], &m.triangles[..]);
        let (c, r) = center_radius(p);
        assert!(c.length() < 1e-6 && (r - 3f32.sqrt()).abs() < 1e-5);
        // Camera rays: one eye, unit directions towards the mesh.
        let cam = camera_rays(p, 16, 8);
        assert!(cam.iter().all(|ray| ray.origin == cam[0].origin));
        assert!((cam[0].origin.length() - 2.2 * r).abs() < 1e-4);
        for ray in &cam {
            assert!((ray.direction.length() - 1.0).abs() < 1e-5);
            assert!(ray.direction.dot(-ray.origin) > 0.8 * ray.origin.length());
            assert_eq!((ray.tmin, ray.tmax), (0.0, f32::INFINITY));
        }
        // The top-left pixel looks up and left of the bottom-right one.
        assert!(cam[0].direction.y > cam[127].direction.y);
        // Diffuse rays leave the surface outwards.
        for ray in hemisphere_rays(p, t, 500, 7) {
            assert!((ray.origin.length() - 1.0).abs() < 0.02);
            assert!(ray.direction.dot(ray.origin) > -0.05);
            assert!((ray.direction.length() - 1.0).abs() < 1e-5);
            assert_eq!(ray.tmin, 1e-5 * r);
        }
        // Shadow rays end at the light.
        let light = shadow_light(p);
        for ray in shadow_rays(p, t, 500, 11) {
            assert!((ray.origin + ray.direction * ray.tmax - light).length() < 1e-4 * r);
        }
        // Tricky rays: every sixth is one of the invalid rays, the kind-3 rays end where the
        // closest-hit callback said.
        let tricky = tricky_rays(p, t, 60, 3, |_| Some(42.0));
        for (k, ray) in tricky.iter().enumerate() {
            match k % 6 {
                3 => assert_eq!((ray.tmin, ray.tmax), (0.0, 42.0)),
                4 => assert!(ray.validate().is_err(), "{ray:?}"),
                _ => assert!(ray.validate().is_ok(), "{ray:?}"),
            }
        }
    }

    #[test]
    fn meshes_without_area_give_no_rays_instead_of_looping() {
        let flat = Mesh {
            positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]],
            triangles: vec![[0, 1, 2]],
        };
        assert!(hemisphere_rays(&flat.positions, &flat.triangles, 10, 1).is_empty());
        assert!(shadow_rays(&flat.positions, &flat.triangles, 10, 1).is_empty());
        assert!(hemisphere_rays(&flat.positions, &[], 10, 1).is_empty());
    }
}
