//! Axis-aligned bounding boxes, the bounds of every primitive kind.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// An axis-aligned box, laid out as OptiX's `OptixAabb` (`minX, minY, minZ, maxX, maxY, maxZ`).
///
/// The empty box has `min = +inf` and `max = -inf`, so that growing it by any point gives that point.
///
/// ```
/// use oxray_core::Aabb;
/// use glam::Vec3;
/// let mut b = Aabb::EMPTY;
/// b.grow(Vec3::ZERO);
/// b.grow(Vec3::ONE);
/// assert_eq!(b.extent(), Vec3::ONE);
/// ```
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
#[doc(alias = "OptixAabb")]
pub struct Aabb {
    /// Smallest corner.
    pub min: Vec3,
    /// Largest corner.
    pub max: Vec3,
}

impl Default for Aabb {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl Aabb {
    /// The empty box: contains nothing, and is the identity of [`Aabb::union`].
    pub const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    /// The box with the given corners.
    #[must_use]
    pub const fn new(min: Vec3, max: Vec3) -> Self {
        Aabb { min, max }
    }

    /// The smallest box holding all the points.
    #[must_use]
    pub fn from_points(points: &[Vec3]) -> Self {
        points.iter().fold(Self::EMPTY, |mut b, &p| {
            b.grow(p);
            b
        })
    }

    /// Grows the box to hold `p`. NaN coordinates are ignored.
    #[inline]
    pub fn grow(&mut self, p: Vec3) {
        self.min = min3(self.min, p);
        self.max = max3(self.max, p);
    }

    /// The smallest box holding both boxes. NaN coordinates of `other` are ignored.
    #[inline]
    #[must_use]
    pub fn union(&self, other: &Aabb) -> Aabb {
        Aabb {
            min: min3(self.min, other.min),
            max: max3(self.max, other.max),
        }
    }

    /// `max - min`, negative on an empty box.
    #[inline]
    #[must_use]
    pub fn extent(&self) -> Vec3 {
        self.max - self.min
    }

    /// The centre, computed so that huge coordinates do not overflow.
    #[inline]
    #[must_use]
    pub fn center(&self) -> Vec3 {
        self.min * 0.5 + self.max * 0.5
    }

    /// Whether `min <= max` on every axis (NaN makes a box invalid).
    #[inline]
    #[must_use]
    pub fn is_valid(&self) -> bool {
        self.min.x <= self.max.x && self.min.y <= self.max.y && self.min.z <= self.max.z
    }

    /// Whether every coordinate is finite and `min <= max`.
    #[inline]
    #[must_use]
    pub fn is_finite_valid(&self) -> bool {
        self.is_valid() && self.min.is_finite() && self.max.is_finite()
    }

    /// Half the surface area; 0 for an empty or degenerate box. This is the SAH's measure.
    #[inline]
    #[must_use]
    pub fn half_area(&self) -> f32 {
        let e = self.extent();
        if e.x < 0.0 || e.y < 0.0 || e.z < 0.0 {
            return 0.0;
        }
        e.x * e.y + e.y * e.z + e.z * e.x
    }

    /// Whether `p` lies inside or on the box.
    #[inline]
    #[must_use]
    pub fn contains(&self, p: Vec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }

    /// Whether `other` lies inside or on the box.
    #[inline]
    #[must_use]
    pub fn contains_box(&self, other: &Aabb) -> bool {
        self.contains(other.min) && self.contains(other.max)
    }

    /// The axis of greatest extent (0, 1 or 2).
    #[must_use]
    pub fn largest_axis(&self) -> usize {
        let e = self.extent();
        if e.x >= e.y && e.x >= e.z {
            0
        } else if e.y >= e.z {
            1
        } else {
            2
        }
    }
}

/// Component-wise minimum that keeps `acc` where `x` is NaN; unlike `f32::min` it compiles to a
/// single `minss`, which matters in the builder's inner loops.
#[inline(always)]
fn min3(acc: Vec3, x: Vec3) -> Vec3 {
    let m = |a: f32, b: f32| if b < a { b } else { a };
    Vec3::new(m(acc.x, x.x), m(acc.y, x.y), m(acc.z, x.z))
}

/// Component-wise maximum that keeps `acc` where `x` is NaN.
#[inline(always)]
fn max3(acc: Vec3, x: Vec3) -> Vec3 {
    let m = |a: f32, b: f32| if b > a { b } else { a };
    Vec3::new(m(acc.x, x.x), m(acc.y, x.y), m(acc.z, x.z))
}
