//! Rays, and the numeric contract every backend's box and triangle tests keep.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use thiserror::Error;

/// A ray: `origin + t * direction` for `tmin <= t <= tmax`.
///
/// The layout is nine `f32` (`ox, oy, oz, tmin, dx, dy, dz, tmax, time`). The first eight
/// are the record of `oxray raycast` ray files ([`RayRecord`]); the time is for motion blur
/// (guide §5.10) and is 0 unless set.
///
/// ```
/// use oxray_core::Ray;
/// use glam::Vec3;
/// let r = Ray::new(Vec3::ZERO, Vec3::Z).with_time(0.5);
/// assert_eq!((r.tmin, r.tmax, r.time), (0.0, f32::INFINITY, 0.5));
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
    /// Time, for motion blur (`optixGetRayTime`).
    pub time: f32,
}

/// A ray without its time: eight little-endian `f32` (`ox, oy, oz, tmin, dx, dy, dz, tmax`),
/// the record of `oxray raycast` ray files and of the GPU kernels' ray buffers, so that a
/// byte buffer of them can be cast with `bytemuck`.
///
/// ```
/// use oxray_core::{Ray, RayRecord};
/// use glam::Vec3;
/// let r = Ray::new(Vec3::X, Vec3::Z);
/// let rec = RayRecord::from(r);
/// assert_eq!(bytemuck::bytes_of(&rec).len(), 32);
/// assert_eq!(Ray::from(rec), r);
/// ```
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct RayRecord {
    /// Origin.
    pub origin: [f32; 3],
    /// Start of the interval.
    pub tmin: f32,
    /// Direction.
    pub direction: [f32; 3],
    /// End of the interval.
    pub tmax: f32,
}

impl From<Ray> for RayRecord {
    fn from(r: Ray) -> Self {
        RayRecord {
            origin: r.origin.to_array(),
            tmin: r.tmin,
            direction: r.direction.to_array(),
            tmax: r.tmax,
        }
    }
}

impl From<RayRecord> for Ray {
    /// A ray at time 0.
    fn from(r: RayRecord) -> Self {
        Ray::with_interval(r.origin.into(), r.direction.into(), r.tmin, r.tmax)
    }
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
    #[must_use]
    #[inline]
    pub fn new(origin: Vec3, direction: Vec3) -> Self {
        Ray {
            origin,
            tmin: 0.0,
            direction,
            tmax: f32::INFINITY,
            time: 0.0,
        }
    }

    /// A ray over `[tmin, tmax]`.
    #[must_use]
    #[inline]
    pub fn with_interval(origin: Vec3, direction: Vec3, tmin: f32, tmax: f32) -> Self {
        Ray {
            origin,
            tmin,
            direction,
            tmax,
            time: 0.0,
        }
    }

    /// The same ray at time `time`.
    #[must_use]
    #[inline]
    pub fn with_time(mut self, time: f32) -> Self {
        self.time = time;
        self
    }

    /// The point at distance `t`.
    #[must_use]
    #[inline]
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.direction * t
    }

    /// Checks the ray as the guide's validation mode does (§13.14): a finite origin and
    /// direction, a non-zero direction, and `0 <= tmin <= tmax` (no NaN; `tmax` may be `+inf`).
    #[inline]
    pub fn validate(&self) -> Result<(), RayError> {
        if self.is_valid() {
            Ok(())
        } else {
            self.invalid()
        }
    }

    /// Whether [`validate`](Self::validate) accepts the ray, without branches: every query
    /// asks it of every ray.
    #[inline]
    fn is_valid(&self) -> bool {
        let (o, d) = (self.origin, self.direction);
        // `x * 0` is zero for a finite `x` and NaN otherwise; NaN spreads through the sum.
        let z = |x: f32| x * 0.0;
        let finite = z(o.x) + z(o.y) + z(o.z) + z(d.x) + z(d.y) + z(d.z) == 0.0;
        let nonzero = (d.x != 0.0) | (d.y != 0.0) | (d.z != 0.0);
        // False for a NaN bound.
        let interval = (self.tmin >= 0.0) & (self.tmin <= self.tmax);
        finite & nonzero & interval
    }

    /// The error of a ray [`is_valid`](Self::is_valid) refused.
    #[cold]
    #[inline(never)]
    fn invalid(&self) -> Result<(), RayError> {
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

/// `1 + 2 * gamma(3)` (Ize 2013): scaling the far distance by it makes the slab test
/// conservative under `f32` rounding.
pub const ROBUST_FAR: f32 =
    1.0 + 2.0 * (3.0 * f32::EPSILON * 0.5) / (1.0 - 3.0 * f32::EPSILON * 0.5);

/// Boxes are tested against `tmax * TMAX_SLACK`: a triangle whose computed t equals tmax may
/// lie in a box whose computed entry distance is a few ulps larger (the two are rounded
/// differently), and the closed interval `[tmin, tmax]` must still find it. The slack costs at
/// most a few extra box visits.
pub const TMAX_SLACK: f32 = 1.0 + 1.0 / 16384.0;

/// `max(acc, x)` that keeps `acc` when `x` is NaN (compiles to `maxps`).
#[inline(always)]
#[must_use]
pub fn max_ignore_nan(acc: f32, x: f32) -> f32 {
    if x > acc {
        x
    } else {
        acc
    }
}

/// `min(acc, x)` that keeps `acc` when `x` is NaN (compiles to `minps`).
#[inline(always)]
#[must_use]
pub fn min_ignore_nan(acc: f32, x: f32) -> f32 {
    if x < acc {
        x
    } else {
        acc
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The branch-free check accepts exactly the rays the rule-by-rule one does (guide
    /// §13.14), over every mix of the values that sit on a rule's edge.
    #[test]
    fn the_quick_check_is_the_rules_check() {
        let values = [
            0.0,
            -0.0,
            1.0,
            -2.5,
            f32::MIN_POSITIVE / 8.0,
            f32::MAX,
            -f32::MAX,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
        ];
        let mut seen = [0usize; 2];
        for (i, &a) in values.iter().enumerate() {
            for &b in &values {
                for &c in &values[i % 3..] {
                    let rays = [
                        Ray::new(Vec3::new(a, 1.0, 2.0), Vec3::new(b, c, 0.0)),
                        Ray::new(Vec3::new(1.0, b, c), Vec3::new(0.0, 0.0, a)),
                        Ray::with_interval(Vec3::ZERO, Vec3::X, a, b),
                        Ray::with_interval(Vec3::new(c, 0.0, 0.0), Vec3::Y, b, a),
                    ];
                    for r in rays {
                        let quick = r.is_valid();
                        assert_eq!(quick, r.invalid().is_ok(), "{r:?}");
                        assert_eq!(quick, r.validate().is_ok(), "{r:?}");
                        seen[quick as usize] += 1;
                    }
                }
            }
        }
        assert!(seen[0] > 100 && seen[1] > 100, "{seen:?}");
    }
}
