//! Rays, and the per-ray constants traversal precomputes.

use crate::geometry::triangle::WatertightRay;
use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use thiserror::Error;

/// A ray: `origin + t * direction` for `tmin <= t <= tmax`.
///
/// The layout is eight little-endian `f32` (`ox, oy, oz, tmin, dx, dy, dz, tmax`), the format of
/// `oxray raycast` ray files, so a byte buffer of rays can be cast to `&[Ray]` with `bytemuck`.
///
/// ```
/// use oxray::Ray;
/// use glam::Vec3;
/// let r = Ray::new(Vec3::ZERO, Vec3::Z);
/// assert_eq!((r.tmin, r.tmax), (0.0, f32::INFINITY));
/// assert!(r.validate().is_ok());
/// ```
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct Ray {
    /// Origin.
    pub origin: Vec3,
    /// Start of the interval.
    pub tmin: f32,
    /// Direction; need not be normalised (t is measured in its length).
    pub direction: Vec3,
    /// End of the interval.
    pub tmax: f32,
}

/// Why a ray is invalid. Queries treat an invalid ray as a miss; the pipeline's validation mode
/// raises an exception for it.
#[derive(Clone, Copy, Debug, Error, PartialEq, Eq)]
pub enum RayError {
    /// The origin has a NaN or infinite component.
    #[error("ray origin is not finite")]
    NonFiniteOrigin,
    /// The direction has a NaN or infinite component.
    #[error("ray direction is not finite")]
    NonFiniteDirection,
    /// The direction is the zero vector.
    #[error("ray direction is zero")]
    ZeroDirection,
    /// `tmin` or `tmax` is NaN.
    #[error("ray tmin or tmax is NaN")]
    NanInterval,
    /// `tmin < 0`.
    #[error("ray tmin is negative")]
    NegativeTmin,
    /// `tmin > tmax`.
    #[error("ray tmin is greater than tmax")]
    EmptyInterval,
}

impl Ray {
    /// A ray over `[0, +inf]`.
    pub fn new(origin: Vec3, direction: Vec3) -> Self {
        Ray {
            origin,
            tmin: 0.0,
            direction,
            tmax: f32::INFINITY,
        }
    }

    /// A ray over `[tmin, tmax]`.
    pub fn with_interval(origin: Vec3, direction: Vec3, tmin: f32, tmax: f32) -> Self {
        Ray {
            origin,
            tmin,
            direction,
            tmax,
        }
    }

    /// The point at distance `t`.
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.direction * t
    }

    /// Checks the ray as the guide's validation mode does (§13.14): a finite origin and
    /// direction, a non-zero direction, and `0 <= tmin <= tmax` (no NaN; `tmax` may be `+inf`).
    pub fn validate(&self) -> Result<(), RayError> {
        if !self.origin.is_finite() {
            return Err(RayError::NonFiniteOrigin);
        }
        if !self.direction.is_finite() {
            return Err(RayError::NonFiniteDirection);
        }
        if self.direction == Vec3::ZERO {
            return Err(RayError::ZeroDirection);
        }
        if self.tmin.is_nan() || self.tmax.is_nan() {
            return Err(RayError::NanInterval);
        }
        if self.tmin < 0.0 {
            return Err(RayError::NegativeTmin);
        }
        if self.tmin > self.tmax {
            return Err(RayError::EmptyInterval);
        }
        Ok(())
    }
}

/// The per-ray constants of box and triangle tests.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PreparedRay {
    pub org: [f32; 3],
    /// `1 / d`, with `+inf` for a zero component (of either sign).
    pub inv: [f32; 3],
    /// Index into `Bvh4Node::bounds` of each axis' near plane (the far plane is the other one).
    pub near: [usize; 3],
    pub far: [usize; 3],
    pub tri: WatertightRay,
    /// `org` and `inv` broadcast to four lanes, for the 4-wide box test.
    pub org4: [Lanes; 3],
    pub inv4: [Lanes; 3],
}

/// Four `f32` lanes, 16-byte aligned.
#[repr(C, align(16))]
#[derive(Clone, Copy, Debug)]
pub(crate) struct Lanes(pub [f32; 4]);

impl PreparedRay {
    /// `None` for an invalid ray, which can hit nothing.
    #[inline]
    pub fn new(ray: &Ray) -> Option<Self> {
        ray.validate().ok()?;
        let d = ray.direction.to_array();
        let mut inv = [0.0; 3];
        let mut near = [0; 3];
        let mut far = [0; 3];
        for a in 0..3 {
            // A zero component gets +inf whatever its sign: the slab test then yields NaN exactly
            // when the origin lies on a slab plane, and the NaN-ignoring min/max of the box test
            // treat that as "inside", which is right for a closed box.
            inv[a] = if d[a] == 0.0 {
                f32::INFINITY
            } else {
                1.0 / d[a]
            };
            if inv[a] >= 0.0 {
                near[a] = a;
                far[a] = a + 3;
            } else {
                near[a] = a + 3;
                far[a] = a;
            }
        }
        Some(PreparedRay {
            org: ray.origin.to_array(),
            inv,
            near,
            far,
            tri: WatertightRay::new(ray.origin, ray.direction),
            org4: ray.origin.to_array().map(|x| Lanes([x; 4])),
            inv4: inv.map(|x| Lanes([x; 4])),
        })
    }

    /// The scalar slab test against one box, conservative like the 4-wide one.
    #[inline]
    pub fn hits_box(&self, b: &crate::Aabb, tmin: f32, tmax: f32) -> bool {
        let lo = b.min.to_array();
        let hi = b.max.to_array();
        let mut t0 = tmin;
        let mut t1 = f32::INFINITY;
        for a in 0..3 {
            let (n, f) = if self.near[a] == a {
                (lo[a], hi[a])
            } else {
                (hi[a], lo[a])
            };
            let tn = (n - self.org[a]) * self.inv[a];
            let tf = (f - self.org[a]) * self.inv[a];
            t0 = max_ignore_nan(t0, tn);
            t1 = min_ignore_nan(t1, tf);
        }
        t0 <= min_ignore_nan(tmax * TMAX_SLACK, t1 * ROBUST_FAR)
    }
}

/// `1 + 2 * gamma(3)` (Ize 2013): scaling the far distance by it makes the slab test
/// conservative under `f32` rounding.
pub(crate) const ROBUST_FAR: f32 =
    1.0 + 2.0 * (3.0 * f32::EPSILON * 0.5) / (1.0 - 3.0 * f32::EPSILON * 0.5);

/// Boxes are tested against `tmax * TMAX_SLACK`: a triangle whose computed t equals tmax may
/// lie in a box whose computed entry distance is a few ulps larger (the two are rounded
/// differently), and the closed interval `[tmin, tmax]` must still find it. The slack costs at
/// most a few extra box visits.
pub(crate) const TMAX_SLACK: f32 = 1.0 + 1.0 / 16384.0;

/// `max(acc, x)` that keeps `acc` when `x` is NaN (compiles to `maxps`).
#[inline(always)]
pub(crate) fn max_ignore_nan(acc: f32, x: f32) -> f32 {
    if x > acc {
        x
    } else {
        acc
    }
}

/// `min(acc, x)` that keeps `acc` when `x` is NaN (compiles to `minps`).
#[inline(always)]
pub(crate) fn min_ignore_nan(acc: f32, x: f32) -> f32 {
    if x < acc {
        x
    } else {
        acc
    }
}
