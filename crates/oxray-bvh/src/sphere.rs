//! Built-in spheres (guide §5.3, §9.4, §9.6): the record a GAS keeps per leaf slot, its bounds,
//! and the ray/sphere test every backend uses, so that all find the same hits.
//!
//! The test follows Haines, Günther and Akenine-Möller, "Precision Improvements for Ray/Sphere
//! Intersection" (Ray Tracing Gems, chapter 7): the discriminant is computed from the distance
//! of the centre to the ray's line (`r² - |f⊥|²`, no cancellation between two large squares
//! for a small or distant sphere), and the roots with the stable form of the quadratic formula
//! (`c / q` and `q / a`, no cancellation between `b` and the root of the discriminant).
//!
//! Spheres are hollow and their back faces are culled (§9.6): only the entry point (the front
//! face, the smaller root) is ever a hit, and only where it lies in `[tmin, tmax]`. So a ray
//! that starts inside a sphere (or whose interval starts inside it) does not hit it.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use oxray_core::Aabb;

/// One sphere: its centre and radius (what `optixGetSphereData` returns, guide §9.4).
///
/// ```
/// use oxray_bvh::sphere::Sphere;
/// use glam::Vec3;
/// let s = Sphere::new(Vec3::new(0.0, 0.0, 5.0), 1.0);
/// // A ray along +z enters the sphere at t = 4 (its front face).
/// assert_eq!(s.intersect(Vec3::ZERO, Vec3::Z, 0.0, f32::INFINITY), Some(4.0));
/// // From inside, the sphere is not hit (back faces are culled, guide §9.6).
/// assert_eq!(s.intersect(Vec3::new(0.0, 0.0, 5.0), Vec3::Z, 0.0, f32::INFINITY), None);
/// ```
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
#[doc(alias = "optixGetSphereData")]
pub struct Sphere {
    /// The centre, object space.
    pub center: [f32; 3],
    /// The radius.
    pub radius: f32,
}

impl Sphere {
    /// The record of an updatable structure's slot whose sphere is inactive: NaN, which no ray
    /// hits (its discriminant is NaN) and no bound includes.
    pub const INACTIVE: Sphere = Sphere {
        center: [f32::NAN; 3],
        radius: f32::NAN,
    };

    /// A sphere of `radius` around `center`.
    #[must_use]
    pub fn new(center: Vec3, radius: f32) -> Sphere {
        Sphere {
            center: center.to_array(),
            radius,
        }
    }

    /// `(x, y, z, radius)`, the `float4` of `optixGetSphereData`.
    #[doc(alias = "optixGetSphereData")]
    #[must_use]
    pub fn to_array(&self) -> [f32; 4] {
        let c = self.center;
        [c[0], c[1], c[2], self.radius]
    }

    /// Whether a ray can hit it: a finite centre and a finite, positive radius. A sphere of
    /// radius 0 has no area, like a degenerate triangle; a negative or NaN radius has no
    /// surface at all (the guide skips negative radii for Rocaps curves, §9.8, and says
    /// nothing else of them). Such spheres are inactive: left out of the tree, as a build
    /// leaves out degenerate triangles (§5.1).
    #[inline]
    #[must_use]
    pub fn is_active(&self) -> bool {
        self.center.iter().all(|c| c.is_finite()) && self.radius.is_finite() && self.radius > 0.0
    }

    /// The box around the sphere, rounded outwards by one part in 2^22 so that it holds every
    /// point of the sphere despite the rounding of `center ± radius`, and every hit the test
    /// reports.
    #[inline]
    #[must_use]
    pub fn bounds(&self) -> Aabb {
        let c = Vec3::from(self.center);
        let r = Vec3::splat(self.radius);
        let (lo, hi) = (c - r, c + r);
        let pad = |v: Vec3| v.abs() * (2.0 * f32::EPSILON);
        Aabb::new(lo - pad(lo), hi + pad(hi))
    }

    /// The front-face hit of the ray `org + t dir` (`dir` need not be normalised: t is in its
    /// units, as across instance transforms): the entry point, if it lies in `[tmin, tmax]`.
    #[inline(always)]
    #[must_use]
    pub fn intersect(&self, org: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<f32> {
        let t = self.entry(org, dir);
        // NaN (an inactive sphere, a miss) fails both compares.
        (t >= tmin && t <= tmax).then_some(t)
    }

    /// The smaller root of `|org + t dir - center|² = radius²`, or NaN when the line misses.
    #[inline(always)]
    #[must_use]
    pub fn entry(&self, org: Vec3, dir: Vec3) -> f32 {
        let c = Vec3::from(self.center);
        let r = self.radius;
        let f = org - c;
        let a = dir.dot(dir);
        let b = -f.dot(dir);
        // The centre's offset from the ray's line: disc = a (r² - |f⊥|²) (RTG ch. 7, eq. 7.7),
        // written as (r - |f⊥|)(r + |f⊥|) so that a tangent ray's small difference is exact.
        let perp = f + dir * (b / a);
        let p = perp.length();
        let disc = a * ((r - p) * (r + p));
        // A miss, or NaN (an inactive sphere): no entry point.
        if disc.is_nan() || disc < 0.0 {
            return f32::NAN;
        }
        let cc = f.dot(f) - r * r;
        // The stable roots (RTG ch. 7, eq. 7.8): q never adds terms of opposite signs.
        let q = b + disc.sqrt().copysign(b);
        let (t0, t1) = (cc / q, q / a);
        t0.min(t1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_entry_point_is_the_front_face_hit_9_4() {
        let s = Sphere::new(Vec3::new(1.0, 2.0, 10.0), 2.0);
        let t = s.intersect(Vec3::new(1.0, 2.0, 0.0), Vec3::Z, 0.0, 100.0);
        assert_eq!(t, Some(8.0));
        // Scaled directions scale t.
        let t = s.intersect(Vec3::new(1.0, 2.0, 0.0), Vec3::Z * 2.0, 0.0, 100.0);
        assert_eq!(t, Some(4.0));
        // Behind the origin: no hit.
        assert_eq!(
            s.intersect(Vec3::new(1.0, 2.0, 20.0), Vec3::Z, 0.0, 100.0),
            None
        );
        // An interval that ends before the entry, or starts after it (inside): no hit.
        assert_eq!(
            s.intersect(Vec3::new(1.0, 2.0, 0.0), Vec3::Z, 0.0, 7.9),
            None
        );
        assert_eq!(
            s.intersect(Vec3::new(1.0, 2.0, 0.0), Vec3::Z, 8.5, 100.0),
            None
        );
    }

    #[test]
    fn a_ray_from_inside_does_not_hit_9_6() {
        let s = Sphere::new(Vec3::ZERO, 1.0);
        for d in [Vec3::X, -Vec3::Y, Vec3::new(0.3, -0.2, 0.9)] {
            assert_eq!(s.intersect(Vec3::new(0.2, 0.1, 0.0), d, 0.0, 1e30), None);
        }
    }

    #[test]
    fn inactive_spheres_are_never_hit_and_have_no_surface_5_3() {
        for s in [
            Sphere::INACTIVE,
            Sphere::new(Vec3::ZERO, 0.0),
            Sphere::new(Vec3::ZERO, -1.0),
            Sphere::new(Vec3::new(f32::NAN, 0.0, 0.0), 1.0),
            Sphere::new(Vec3::ZERO, f32::INFINITY),
        ] {
            assert!(!s.is_active(), "{s:?}");
        }
        assert_eq!(
            Sphere::INACTIVE.intersect(Vec3::new(0.0, 0.0, -5.0), Vec3::Z, 0.0, 1e30),
            None
        );
    }

    #[test]
    fn bounds_hold_the_sphere_and_its_hits() {
        let s = Sphere::new(Vec3::new(1e4, -3.0, 0.1), 0.37);
        let b = s.bounds();
        for d in [Vec3::X, Vec3::Y, Vec3::Z] {
            for sign in [-1.0, 1.0] {
                let p = Vec3::from(s.center) + d * sign * s.radius;
                assert!(b.contains(p));
            }
        }
    }
}
