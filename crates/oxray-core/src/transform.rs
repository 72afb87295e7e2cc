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
    pub fn from_translation(t: Vec3) -> Self {
        Self::from_affine(&Affine3A::from_translation(t))
    }

    /// From a `glam` affine transform.
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
    pub fn transform_normal_with_inverse(inverse: &Transform, n: Vec3) -> Vec3 {
        let r = &inverse.0;
        Vec3::new(
            r[0] * n.x + r[4] * n.y + r[8] * n.z,
            r[1] * n.x + r[5] * n.y + r[9] * n.z,
            r[2] * n.x + r[6] * n.y + r[10] * n.z,
        )
    }

    /// `self * other`: applies `other`, then `self`.
    pub fn then_after(&self, other: &Transform) -> Transform {
        Self::from_affine(&(self.to_affine() * other.to_affine()))
    }

    /// The inverse, or `None` if the transform is singular or not finite.
    pub fn inverse(&self) -> Option<Transform> {
        let a = self.to_affine();
        let det = a.matrix3.determinant();
        if !(det.is_finite() && det != 0.0 && self.0.iter().all(|x| x.is_finite())) {
            return None;
        }
        let inv = Self::from_affine(&a.inverse());
        inv.0.iter().all(|x| x.is_finite()).then_some(inv)
    }

    /// The box around the transformed corners of `b` (empty stays empty).
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
