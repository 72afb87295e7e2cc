//! Watertight ray/triangle intersection (Woop, Benthin, Wald: "Watertight Ray/Triangle
//! Intersection", JCGT 2013).
//!
//! The ray is sheared so that it runs along +z from the origin; the three 2-D edge functions of the
//! sheared triangle then decide the hit. Two triangles that share an edge evaluate that edge's
//! function on the same sheared vertices, with opposite signs, so a ray can never slip between them.
//! When an edge function is exactly zero (or overflows), it is recomputed in `f64` from the same
//! `f32` sheared coordinates, where the products are exact.

use glam::Vec3;

/// The per-ray constants of the watertight test.
#[derive(Clone, Copy, Debug)]
pub struct WatertightRay {
    /// The ray's origin.
    pub org: [f32; 3],
    /// Axis permutation: `k[2]` is the dominant axis of the direction.
    pub k: [usize; 3],
    /// `(dx/dz, dy/dz, 1/dz)` in the permuted axes.
    pub shear: [f32; 3],
}

/// A triangle hit: distance, barycentrics and facing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleHit {
    /// Distance along the ray, in units of the ray direction's length.
    pub t: f32,
    /// Barycentric weight of the second vertex (OptiX's `u`).
    pub u: f32,
    /// Barycentric weight of the third vertex (OptiX's `v`).
    pub v: f32,
    /// Whether the ray hit the front face: the vertices appear counter-clockwise, i.e. the ray
    /// travels against `(v1 - v0) x (v2 - v0)`.
    pub front_face: bool,
}

impl WatertightRay {
    /// Precomputes the shear for a ray. `dir` must be non-zero and finite.
    #[inline]
    #[must_use]
    pub fn new(org: Vec3, dir: Vec3) -> Self {
        let a = dir.abs();
        let kz = if a.x >= a.y && a.x >= a.z {
            0
        } else if a.y >= a.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        let d = dir.to_array();
        // Swapping keeps the winding of the projected triangle independent of the ray's sign.
        if d[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        WatertightRay {
            org: org.to_array(),
            k: [kx, ky, kz],
            shear: [d[kx] / d[kz], d[ky] / d[kz], 1.0 / d[kz]],
        }
    }

    /// Intersects the triangle `(p0, p1, p2)`; reports a hit only for `tmin <= t <= tmax`.
    #[inline(always)]
    #[must_use]
    pub fn intersect(
        &self,
        p0: &[f32; 3],
        p1: &[f32; 3],
        p2: &[f32; 3],
        tmin: f32,
        tmax: f32,
    ) -> Option<TriangleHit> {
        let [kx, ky, kz] = self.k;
        let [sx, sy, sz] = self.shear;
        let o = &self.org;
        let a = [p0[0] - o[0], p0[1] - o[1], p0[2] - o[2]];
        let b = [p1[0] - o[0], p1[1] - o[1], p1[2] - o[2]];
        let c = [p2[0] - o[0], p2[1] - o[1], p2[2] - o[2]];
        let ax = a[kx] - sx * a[kz];
        let ay = a[ky] - sy * a[kz];
        let bx = b[kx] - sx * b[kz];
        let by = b[ky] - sy * b[kz];
        let cx = c[kx] - sx * c[kz];
        let cy = c[ky] - sy * c[kz];

        let u = cx * by - cy * bx;
        let v = ax * cy - ay * cx;
        let w = bx * ay - by * ax;

        let az = sz * a[kz];
        let bz = sz * b[kz];
        let cz = sz * c[kz];

        let det = u + v + w;
        let t_scaled = u * az + v * bz + w * cz;
        if needs_f64(u, v, w, det, t_scaled) {
            return Self::intersect_f64([ax, ay, az], [bx, by, bz], [cx, cy, cz], tmin, tmax);
        }
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        let inv = 1.0 / det;
        // `+ 0.0` turns a -0.0 distance into +0.0.
        let t = t_scaled * inv + 0.0;
        if !(t >= tmin && t <= tmax) {
            return None;
        }
        Some(TriangleHit {
            t,
            u: v * inv,
            v: w * inv,
            front_face: det > 0.0,
        })
    }

    /// The exact fallback: products of `f32` values are exact in `f64`, so the signs of the edge
    /// functions are right even where the `f32` ones round to zero or overflow.
    #[cold]
    #[inline(never)]
    fn intersect_f64(
        a: [f32; 3],
        b: [f32; 3],
        c: [f32; 3],
        tmin: f32,
        tmax: f32,
    ) -> Option<TriangleHit> {
        let (ax, ay, az) = (a[0] as f64, a[1] as f64, a[2] as f64);
        let (bx, by, bz) = (b[0] as f64, b[1] as f64, b[2] as f64);
        let (cx, cy, cz) = (c[0] as f64, c[1] as f64, c[2] as f64);
        let u = cx * by - cy * bx;
        let v = ax * cy - ay * cx;
        let w = bx * ay - by * ax;
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        let det = u + v + w;
        // A zero determinant is a ray in the triangle's plane (or a degenerate triangle): no hit.
        if det == 0.0 || !det.is_finite() {
            return None;
        }
        let t_scaled = u * az + v * bz + w * cz;
        let inv = 1.0 / det;
        let t = (t_scaled * inv) as f32 + 0.0;
        if !(t >= tmin && t <= tmax) {
            return None;
        }
        Some(TriangleHit {
            t,
            u: (v * inv) as f32,
            v: (w * inv) as f32,
            front_face: det > 0.0,
        })
    }
}

/// Below this magnitude a determinant or a scaled distance may have lost precision to underflow.
pub const F32_TINY: f32 = 1.0 / (1u128 << 96) as f32;

/// Whether the `f32` results may be wrong, so that the exact `f64` path must decide: an edge
/// function of zero (the ray meets an edge or vertex exactly), a determinant or scaled distance
/// that overflowed or underflowed (distances grow with the cube of the coordinates), or NaN.
#[inline(always)]
#[must_use]
pub fn needs_f64(u: f32, v: f32, w: f32, det: f32, t_scaled: f32) -> bool {
    let ok = |x: f32| x.abs() >= F32_TINY && x.abs() < f32::INFINITY;
    u == 0.0 || v == 0.0 || w == 0.0 || !ok(det) || !ok(t_scaled)
}

/// Whether a triangle can never be hit: a non-finite vertex or zero area. The builder leaves such
/// triangles out of the acceleration structure (they are inactive).
#[must_use]
pub fn is_degenerate(p0: Vec3, p1: Vec3, p2: Vec3) -> bool {
    if !(p0.is_finite() && p1.is_finite() && p2.is_finite()) {
        return true;
    }
    // In f64 so that tiny but valid triangles are not mistaken for degenerate ones.
    let d = |p: Vec3| glam::DVec3::new(p.x as f64, p.y as f64, p.z as f64);
    let n = (d(p1) - d(p0)).cross(d(p2) - d(p0));
    n == glam::DVec3::ZERO
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hit(o: Vec3, d: Vec3, t: [[f32; 3]; 3]) -> Option<TriangleHit> {
        WatertightRay::new(o, d).intersect(&t[0], &t[1], &t[2], 0.0, f32::INFINITY)
    }

    const TRI: [[f32; 3]; 3] = [[0.0, 0.0, 1.0], [0.0, 1.0, 1.0], [1.0, 0.0, 1.0]];

    #[test]
    fn barycentrics_follow_optix_convention() {
        let h = hit(Vec3::new(0.25, 0.5, 0.0), Vec3::Z, TRI).unwrap();
        assert_eq!(h.t, 1.0);
        // The hit point is (1-u-v)*p0 + u*p1 + v*p2.
        assert_eq!((h.u, h.v), (0.5, 0.25));
    }

    #[test]
    fn front_face_is_counter_clockwise_seen_from_the_ray() {
        // (p1 - p0) x (p2 - p0) = -Z for TRI, so a ray along +Z sees its front face.
        for (dir, front) in [(Vec3::Z, true), (-Vec3::Z, false)] {
            let o = Vec3::new(0.25, 0.25, 1.0) - dir;
            assert_eq!(hit(o, dir, TRI).unwrap().front_face, front);
        }
        // The same holds whichever axis dominates the direction.
        for d in [
            Vec3::new(0.3, 0.2, 1.0),
            Vec3::new(-0.9, 0.1, 0.95),
            Vec3::new(0.1, -0.99, 0.98),
        ] {
            let target = Vec3::new(0.2, 0.2, 1.0);
            let h = hit(target - d, d, TRI).unwrap();
            assert!(h.front_face);
            let h = hit(target + d, -d, TRI).unwrap();
            assert!(!h.front_face);
        }
    }

    #[test]
    fn interval_is_inclusive() {
        let r = WatertightRay::new(Vec3::new(0.25, 0.25, 0.0), Vec3::Z);
        let [a, b, c] = TRI;
        assert!(r.intersect(&a, &b, &c, 1.0, 1.0).is_some());
        assert!(r.intersect(&a, &b, &c, 0.0, 0.999_999).is_none());
        assert!(r.intersect(&a, &b, &c, 1.000_001, 2.0).is_none());
    }

    #[test]
    fn ray_in_plane_misses() {
        assert!(hit(Vec3::new(-1.0, 0.25, 1.0), Vec3::X, TRI).is_none());
    }

    #[test]
    fn shared_edge_is_hit_exactly_once_or_twice_never_zero() {
        // Two triangles sharing the diagonal of the unit square; rays through the diagonal.
        let q = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ];
        for i in 0..=64 {
            let s = i as f32 / 64.0;
            let o = Vec3::new(s, s, -1.0);
            let d = Vec3::new(0.001 * (i as f32 - 32.0), 0.0007, 1.0);
            let r = WatertightRay::new(o - d * 0.0, d);
            let h1 = r.intersect(&q[0], &q[1], &q[2], 0.0, f32::INFINITY);
            let h2 = r.intersect(&q[0], &q[2], &q[3], 0.0, f32::INFINITY);
            let p = o + d;
            let inside = (0.0..=1.0).contains(&p.x) && (0.0..=1.0).contains(&p.y);
            if inside {
                assert!(h1.is_some() || h2.is_some(), "ray {i} leaked");
            }
        }
    }

    #[test]
    fn degenerate_triangles_are_detected() {
        let z = Vec3::ZERO;
        assert!(is_degenerate(z, Vec3::X, Vec3::X * 2.0));
        assert!(is_degenerate(z, Vec3::X, Vec3::new(f32::NAN, 0.0, 0.0)));
        assert!(is_degenerate(
            z,
            Vec3::X,
            Vec3::new(0.0, f32::INFINITY, 0.0)
        ));
        assert!(!is_degenerate(z, Vec3::X * 1e-20, Vec3::Y * 1e-20));
    }

    #[test]
    fn huge_coordinates_use_the_exact_fallback() {
        let s = 1e20f32;
        let t = [[0.0, 0.0, s], [0.0, s, s], [s, 0.0, s]];
        let h = hit(Vec3::new(0.25 * s, 0.25 * s, 0.0), Vec3::Z, t).unwrap();
        assert_eq!(h.t, s);
        assert!((h.u - 0.25).abs() < 1e-6 && (h.v - 0.25).abs() < 1e-6);
    }
}
