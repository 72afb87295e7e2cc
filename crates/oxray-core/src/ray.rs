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
