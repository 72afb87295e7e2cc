//! The geometric normal of a ribbon (flat quadratic B-spline, guide §5.2, §9.3):
//! `optixGetRibbonNormal`. Every backend computes it with this arithmetic (the CUDA device
//! header repeats it operation for operation in double precision).
//!
//! A ribbon is the ruled surface `S(u, v) = c(u) + v r(u) w(u)`, `v ∈ [-1, 1]`, whose width
//! direction is `w = m / |m|` with `m = n(u) × c'(u)` for the linearly interpolated normals
//! `n(u)` of a ribbon with normals, and `m = c'(u) × d` (facing the ray's direction `d`)
//! without them (see [`crate::curve`]). Its normal is `∂S/∂u × w`, with
//! `∂S/∂u = c' + v (r' w + r w')` and `w' = (m' - w (w · m')) / |m|`: at `v = 0` it is
//! `c' × w`, the normal whose side is the front face.

use crate::curve::{CurveSegment, HAS_NORMALS};
use glam::{DVec3, Vec3};

impl CurveSegment {
    /// The unit geometric normal, in object space, of this ribbon at `(u, v)` (a hit's
    /// [`CurveHit::u`](crate::CurveHit::u) and [`v`](crate::CurveHit::v)), pointing out of its
    /// front face; `dir` is the ray's object-space direction (it orients a ribbon without
    /// normals, which faces the ray). Zero for a segment that is not a ribbon, and where the
    /// ribbon has no normal (its width direction is undefined there).
    ///
    /// ```
    /// use oxray_bvh::curve::CurveSegment;
    /// use oxray_core::CurveType;
    /// use glam::Vec3;
    /// // A straight ribbon along x, its normals +z: the surface faces +z.
    /// let pts = [[-1.0, 0.0, 0.0, 0.5], [1.0, 0.0, 0.0, 0.5], [3.0, 0.0, 0.0, 0.5]];
    /// let s = CurveSegment::new(CurveType::FlatQuadraticBSpline, &pts, 0, Some([Vec3::Z; 2]));
    /// let n = s.ribbon_normal(0.5, 0.2, -Vec3::Z);
    /// assert!((n - Vec3::Z).length() < 1e-6);
    /// ```
    pub fn ribbon_normal(&self, u: f32, v: f32, dir: Vec3) -> Vec3 {
        if !self.curve_type().is_ribbon() {
            return Vec3::ZERO;
        }
        let (u, v) = (u as f64, v as f64);
        let p = |i: usize, d: usize| self.points[i][d] as f64;
        // The quadratic B-spline's power basis: c(u) = a0 + a1 u + a2 u², the radius alike.
        let mut a = [[0.0f64; 4]; 3];
        for d in 0..4 {
            a[0][d] = 0.5 * (p(0, d) + p(1, d));
            a[1][d] = p(1, d) - p(0, d);
            a[2][d] = 0.5 * (p(0, d) - 2.0 * p(1, d) + p(2, d));
        }
        let vec = |k: usize| DVec3::new(a[k][0], a[k][1], a[k][2]);
        let tangent = vec(1) + vec(2) * (2.0 * u);
        let second = vec(2) * 2.0;
        let r = (a[2][3] * u + a[1][3]) * u + a[0][3];
        let dr = 2.0 * a[2][3] * u + a[1][3];
        let (m, dm) = if self.flags & HAS_NORMALS != 0 {
            let n0 = DVec3::from(self.normals[0].map(f64::from));
            let n1 = DVec3::from(self.normals[1].map(f64::from));
            let n = n0 + (n1 - n0) * u;
            let dn = n1 - n0;
            (n.cross(tangent), dn.cross(tangent) + n.cross(second))
        } else {
            let d = dir.as_dvec3();
            (tangent.cross(d), second.cross(d))
        };
        let len = m.length();
        if len.is_nan() || len <= 0.0 {
            return Vec3::ZERO;
        }
        let w = m / len;
        let dw = (dm - w * w.dot(dm)) / len;
        let du = tangent + (w * dr + dw * r) * v;
        let normal = du.cross(w);
        let nl = normal.length();
        if nl.is_nan() || nl <= 0.0 {
            return Vec3::ZERO;
        }
        (normal / nl).as_vec3()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use oxray_core::CurveType;

    fn random(seed: &mut u64) -> f32 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*seed >> 40) as f32) / (1u64 << 24) as f32 * 2.0 - 1.0
    }

    /// §9.3: the normal is that of the surface: perpendicular to finite differences of
    /// `S(u, v)` in u and v at random points of random ribbons, with and without normals, and
    /// on the front face's side (against the ray) at every hit.
    #[test]
    fn s9_3_the_ribbon_normal_is_the_surfaces() {
        let mut seed = 3u64;
        let mut checked = 0;
        for k in 0..400 {
            let pts: Vec<[f32; 4]> = (0..3)
                .map(|_| {
                    let mut q = [0.0; 4];
                    for c in q.iter_mut().take(3) {
                        *c = random(&mut seed);
                    }
                    q[3] = 0.1 + 0.1 * random(&mut seed).abs();
                    q
                })
                .collect();
            let normals = (k % 2 == 0).then(|| {
                [0, 1].map(|_| {
                    Vec3::new(random(&mut seed), random(&mut seed), random(&mut seed)).normalize()
                })
            });
            let s = CurveSegment::new(CurveType::FlatQuadraticBSpline, &pts, 0, normals);
            let dir = Vec3::new(
                random(&mut seed),
                random(&mut seed),
                random(&mut seed) - 1.5,
            )
            .normalize();
            // Hits of rays along `dir` through a point of the ribbon's centre line.
            let target = s.eval(0.5 + 0.45 * random(&mut seed) as f64).0.as_vec3();
            let Some(hit) = s.intersect(target - dir * 5.0, dir, 0.0, f32::INFINITY) else {
                continue;
            };
            let n = s.ribbon_normal(hit.u, hit.v, dir);
            if n == Vec3::ZERO {
                continue;
            }
            assert!((n.length() - 1.0).abs() < 1e-5);
            // The surface point from the segment's own basis, and its finite differences.
            let surface = |u: f64, v: f64| {
                let (c, r) = s.eval(u);
                let t = s.tangent(u);
                let m = match normals {
                    Some([n0, n1]) => (n0.as_dvec3() + (n1 - n0).as_dvec3() * u).cross(t),
                    None => t.cross(dir.as_dvec3()),
                };
                c + m.normalize() * (r * v)
            };
            let (u, v) = (hit.u as f64, hit.v as f64);
            let h = 1e-5;
            let su = (surface(u + h, v) - surface(u - h, v)) / (2.0 * h);
            let sv = (surface(u, v + h) - surface(u, v - h)) / (2.0 * h);
            let nd = n.as_dvec3();
            assert!(nd.dot(su).abs() < 1e-3 * su.length(), "{k}: {nd} {su}");
            assert!(nd.dot(sv).abs() < 1e-3 * sv.length(), "{k}: {nd} {sv}");
            // The front face is the side of c' × w, the normal on the centre line (v = 0; off
            // it a fast-twisting ribbon's normal turns with the surface).
            let centre = s.ribbon_normal(hit.u, 0.0, dir);
            let cw = s
                .tangent(u)
                .cross((surface(u, 1.0) - surface(u, -1.0)) * 0.5);
            assert!((centre.as_dvec3() - cw.normalize()).length() < 1e-4, "{k}");
            assert_eq!(
                centre.dot(dir) < 0.0,
                !hit.back_face,
                "{k}: the front face's side"
            );
            checked += 1;
        }
        assert!(checked > 200, "{checked} hits checked");
        // Not a ribbon: zero.
        let round = CurveSegment::new(
            CurveType::RoundLinear,
            &[[0.0, 0.0, 0.0, 0.5], [1.0, 0.0, 0.0, 0.5]],
            0,
            None,
        );
        assert_eq!(round.ribbon_normal(0.5, 0.0, Vec3::Z), Vec3::ZERO);
    }
}
