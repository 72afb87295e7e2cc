//! 3x4 affine transforms as OptiX stores them (row-major, object to world).

use crate::aabb::Aabb;
use bytemuck::{Pod, Zeroable};
use glam::{Affine3A, Mat3A, Vec3, Vec3A};

/// A 3x4 row-major affine transform (`float transform[12]` of `OptixInstance` and
/// `OptixStaticTransform`): `p' = M p + t` with rows `[m00 m01 m02 t0]`, `[m10 m11 m12 t1]`,
/// `[m20 m21 m22 t2]`.
///
/// ```
/// use oxray_core::Transform;
/// use glam::Vec3;
/// let t = Transform::from_translation(Vec3::new(1.0, 2.0, 3.0));
/// assert_eq!(t.transform_point(Vec3::ZERO), Vec3::new(1.0, 2.0, 3.0));
/// assert_eq!(t.inverse().unwrap().transform_point(Vec3::new(1.0, 2.0, 3.0)), Vec3::ZERO);
/// ```
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
#[doc(alias = "OptixInstance")]
#[doc(alias = "OptixStaticTransform")]
pub struct Transform(pub [f32; 12]);

impl Default for Transform {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Transform {
    /// The identity.
    pub const IDENTITY: Transform =
        Transform([1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]);

    /// A translation.
    #[must_use]
    pub fn from_translation(t: Vec3) -> Self {
        Self::from_affine(&Affine3A::from_translation(t))
    }

    /// From a `glam` affine transform.
    #[must_use]
    pub fn from_affine(a: &Affine3A) -> Self {
        let m = a.matrix3;
        let t = a.translation;
        Transform([
            m.x_axis.x, m.y_axis.x, m.z_axis.x, t.x, //
            m.x_axis.y, m.y_axis.y, m.z_axis.y, t.y, //
            m.x_axis.z, m.y_axis.z, m.z_axis.z, t.z,
        ])
    }

    /// As a `glam` affine transform.
    #[must_use]
    pub fn to_affine(&self) -> Affine3A {
        let r = &self.0;
        Affine3A {
            matrix3: Mat3A::from_cols(
                Vec3A::new(r[0], r[4], r[8]),
                Vec3A::new(r[1], r[5], r[9]),
                Vec3A::new(r[2], r[6], r[10]),
            ),
            translation: Vec3A::new(r[3], r[7], r[11]),
        }
    }

    /// Applies the transform to a point.
    #[inline]
    #[must_use]
    pub fn transform_point(&self, p: Vec3) -> Vec3 {
        let r = &self.0;
        Vec3::new(
            r[0] * p.x + r[1] * p.y + r[2] * p.z + r[3],
            r[4] * p.x + r[5] * p.y + r[6] * p.z + r[7],
            r[8] * p.x + r[9] * p.y + r[10] * p.z + r[11],
        )
    }

    /// Applies the linear part to a vector.
    #[inline]
    #[must_use]
    pub fn transform_vector(&self, v: Vec3) -> Vec3 {
        let r = &self.0;
        Vec3::new(
            r[0] * v.x + r[1] * v.y + r[2] * v.z,
            r[4] * v.x + r[5] * v.y + r[6] * v.z,
            r[8] * v.x + r[9] * v.y + r[10] * v.z,
        )
    }

    /// Applies the inverse transpose of the linear part (for normals), given the inverse.
    #[inline]
    #[must_use]
    pub fn transform_normal_with_inverse(inverse: &Transform, n: Vec3) -> Vec3 {
        let r = &inverse.0;
        Vec3::new(
            r[0] * n.x + r[4] * n.y + r[8] * n.z,
            r[1] * n.x + r[5] * n.y + r[9] * n.z,
            r[2] * n.x + r[6] * n.y + r[10] * n.z,
        )
    }

    /// The factor by which the transform scales every distance, if it is a similarity (its
    /// linear part's columns orthogonal and of one length, within `f32` rounding: rotations,
    /// reflections, uniform scales and translations); `None` otherwise.
    ///
    /// ```
    /// use oxray_core::Transform;
    /// use glam::{Affine3A, Vec3};
    /// let t = Transform::from_affine(&Affine3A::from_scale(Vec3::splat(2.0)));
    /// assert_eq!(t.similarity_scale(), Some(2.0));
    /// let s = Transform::from_affine(&Affine3A::from_scale(Vec3::new(1.0, 2.0, 1.0)));
    /// assert_eq!(s.similarity_scale(), None);
    /// ```
    #[must_use]
    pub fn similarity_scale(&self) -> Option<f32> {
        let m = &self.0;
        let c = [
            Vec3::new(m[0], m[4], m[8]),
            Vec3::new(m[1], m[5], m[9]),
            Vec3::new(m[2], m[6], m[10]),
        ];
        let s2 = c[0].length_squared();
        let tol = 1e-5 * s2;
        let same = |x: f32| (x - s2).abs() <= tol;
        let orthogonal = |a: Vec3, b: Vec3| a.dot(b).abs() <= tol;
        (s2 > 0.0
            && s2.is_finite()
            && same(c[1].length_squared())
            && same(c[2].length_squared())
            && orthogonal(c[0], c[1])
            && orthogonal(c[0], c[2])
            && orthogonal(c[1], c[2]))
        .then(|| s2.sqrt())
    }

    /// `self * other`: applies `other`, then `self`.
    #[must_use]
    pub fn then_after(&self, other: &Transform) -> Transform {
        Self::from_affine(&(self.to_affine() * other.to_affine()))
    }

    /// The inverse, or `None` if the transform is singular or not finite.
    #[must_use]
    pub fn inverse(&self) -> Option<Transform> {
        let a = self.to_affine();
        let det = a.matrix3.determinant();
        if !(det.is_finite() && det != 0.0 && self.0.iter().all(|x| x.is_finite())) {
            return None;
        }
        let inv = Self::from_affine(&a.inverse());
        inv.0.iter().all(|x| x.is_finite()).then_some(inv)
    }

    /// The inverse by cofactors, in a fixed order of scalar `f32` operations (no SIMD lanes, no
    /// fused multiply-add), or `None` where [`inverse`](Self::inverse) gives `None`. The CUDA
    /// device repeats these operations bit for bit, so transforms made at trace time (a motion
    /// transform at the ray's time, guide §5.10.4) are inverted alike on every device.
    ///
    /// ```
    /// use oxray_core::Transform;
    /// use glam::Vec3;
    /// let t = Transform([2.0, 0.0, 0.0, 1.0, 0.0, 4.0, 0.0, 2.0, 0.0, 0.0, 1.0, 3.0]);
    /// let inv = t.inverse_cofactors().unwrap();
    /// assert_eq!(inv.transform_point(Vec3::new(1.0, 2.0, 3.0)), Vec3::ZERO);
    /// ```
    #[must_use]
    pub fn inverse_cofactors(&self) -> Option<Transform> {
        let m = &self.0;
        let (a, b, c, tx) = (m[0], m[1], m[2], m[3]);
        let (d, e, f, ty) = (m[4], m[5], m[6], m[7]);
        let (g, h, i, tz) = (m[8], m[9], m[10], m[11]);
        let c00 = e * i - f * h;
        let c01 = f * g - d * i;
        let c02 = d * h - e * g;
        let det = a * c00 + b * c01 + c * c02;
        if !(det.is_finite() && det != 0.0 && m.iter().all(|x| x.is_finite())) {
            return None;
        }
        let r = 1.0 / det;
        let l = [
            c00 * r,
            (c * h - b * i) * r,
            (b * f - c * e) * r,
            c01 * r,
            (a * i - c * g) * r,
            (c * d - a * f) * r,
            c02 * r,
            (b * g - a * h) * r,
            (a * e - b * d) * r,
        ];
        let inv = Transform([
            l[0],
            l[1],
            l[2],
            -(l[0] * tx + l[1] * ty + l[2] * tz),
            l[3],
            l[4],
            l[5],
            -(l[3] * tx + l[4] * ty + l[5] * tz),
            l[6],
            l[7],
            l[8],
            -(l[6] * tx + l[7] * ty + l[8] * tz),
        ]);
        inv.0.iter().all(|x| x.is_finite()).then_some(inv)
    }

    /// The box around the transformed corners of `b` (empty stays empty).
    #[must_use]
    pub fn transform_aabb(&self, b: &Aabb) -> Aabb {
        if !b.is_valid() {
            return Aabb::EMPTY;
        }
        let mut out = Aabb::EMPTY;
        for i in 0..8 {
            let c = Vec3::new(
                if i & 1 == 0 { b.min.x } else { b.max.x },
                if i & 2 == 0 { b.min.y } else { b.max.y },
                if i & 4 == 0 { b.min.z } else { b.max.z },
            );
            out.grow(self.transform_point(c));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cofactor_inverse_inverts_as_the_glam_one_does() {
        // A small LCG: no dependency for a handful of numbers.
        let mut s = 0x2545_f491_u32;
        let mut next = || {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (s >> 8) as f32 / (1u32 << 24) as f32 * 4.0 - 2.0
        };
        for _ in 0..200 {
            let t = Transform(std::array::from_fn(|_| next()));
            let (Some(a), Some(b)) = (t.inverse(), t.inverse_cofactors()) else {
                continue;
            };
            let p = Vec3::new(0.3, -1.2, 0.7);
            let back = b.transform_point(t.transform_point(p));
            assert!((back - p).length() < 1e-2, "{t:?}: {back:?}");
            let scale = a.0.iter().fold(1.0f32, |m, x| m.max(x.abs()));
            for (x, y) in a.0.iter().zip(&b.0) {
                assert!((x - y).abs() <= 1e-3 * scale, "{a:?} vs {b:?}");
            }
        }
        let singular = Transform([1.0, 2.0, 3.0, 0.0, 2.0, 4.0, 6.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
        assert_eq!(singular.inverse_cofactors(), None);
        let mut infinite = Transform::IDENTITY;
        infinite.0[3] = f32::INFINITY;
        assert_eq!(infinite.inverse_cofactors(), None);
        assert_eq!(
            Transform::IDENTITY.inverse_cofactors(),
            Some(Transform::IDENTITY)
        );
    }
}
