//! Hits as queries report them, and what an any-hit filter decides.

use crate::aabb::Aabb;

/// The kind of a hit (`optixGetHitKind`, guide §13.7): `0xFE`/`0xFF` for the front/back face of a
/// triangle, `0x8C`/`0x8D` for a sphere, `0x82..=0x97` for the curve types, `0..=127` as reported
/// for a custom primitive.
///
/// The guide leaves the values of built-in hit kinds other than the triangles' to the
/// implementation (they are read through `optixGetPrimitiveType`, `optixIsFrontFaceHit` and
/// `optixIsBackFaceHit`, §13.7); oxray's built-in kinds are `0x80 | (low byte of the
/// OptixPrimitiveType) << 1 | back face`, so that a sphere's are `0x8C` and `0x8D`.
///
/// ```
/// use oxray_core::{HitKind, PrimitiveType};
/// assert_eq!(HitKind::SPHERE_FRONT_FACE.primitive_type(), PrimitiveType::Sphere);
/// assert!(HitKind::SPHERE_FRONT_FACE.is_front_face());
/// assert_eq!(HitKind::custom(3).primitive_type(), PrimitiveType::Custom);
/// assert!(!HitKind::custom(3).is_front_face() && !HitKind::custom(3).is_back_face());
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[doc(alias = "optixGetHitKind")]
pub struct HitKind(pub u8);

/// The primitive type of a hit (`OptixPrimitiveType`, guide §13.7), for the kinds oxray builds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[doc(alias = "OptixPrimitiveType")]
pub enum PrimitiveType {
    /// `OPTIX_PRIMITIVE_TYPE_CUSTOM`.
    Custom,
    /// `OPTIX_PRIMITIVE_TYPE_SPHERE`.
    Sphere,
    /// `OPTIX_PRIMITIVE_TYPE_TRIANGLE`.
    Triangle,
    /// One of the curve types (`OPTIX_PRIMITIVE_TYPE_ROUND_*`, `_FLAT_QUADRATIC_BSPLINE`).
    Curve(crate::CurveType),
}

impl PrimitiveType {
    /// The `OptixPrimitiveType` value.
    #[doc(alias = "OptixPrimitiveType")]
    #[must_use]
    pub const fn code(self) -> u32 {
        match self {
            PrimitiveType::Custom => 0x2500,
            PrimitiveType::Sphere => 0x2506,
            PrimitiveType::Triangle => 0x2531,
            PrimitiveType::Curve(c) => c.code(),
        }
    }
}

impl HitKind {
    /// The front face of a sphere: the only sphere hit kind traversal reports, since a ray
    /// starting inside a sphere does not hit it (guide §9.4, §9.6).
    pub const SPHERE_FRONT_FACE: HitKind = HitKind(0x8C);
    /// The back face of a sphere: never reported (spheres are hollow and their back faces
    /// culled, guide §9.6), but `optixIsBackFaceHit` and `optixGetPrimitiveType` read it.
    #[doc(alias = "optixIsBackFaceHit")]
    #[doc(alias = "optixGetPrimitiveType")]
    pub const SPHERE_BACK_FACE: HitKind = HitKind(0x8D);

    /// The front (`back == false`) or back face of a curve of type `ty` (guide §9.3): round
    /// curves report front faces only (their tubes are hollow, §9.6); ribbons report either.
    #[must_use]
    pub const fn curve(ty: crate::CurveType, back: bool) -> HitKind {
        HitKind(0x80 | ((ty.code() & 0xFF) as u8) << 1 | back as u8)
    }

    /// `optixGetPrimitiveType(hitKind)`: which primitive type the kind belongs to.
    #[doc(alias = "optixGetPrimitiveType")]
    #[must_use]
    pub const fn primitive_type(self) -> PrimitiveType {
        match self.0 {
            0xFE | 0xFF => PrimitiveType::Triangle,
            0x8C | 0x8D => PrimitiveType::Sphere,
            k if k >= 0x80 => {
                match crate::CurveType::from_code(0x2500 | ((k & 0x7F) >> 1) as u32) {
                    Some(c) => PrimitiveType::Curve(c),
                    None => PrimitiveType::Custom,
                }
            }
            _ => PrimitiveType::Custom,
        }
    }

    /// `optixIsFrontFaceHit(hitKind)`: a built-in primitive's front face (never a custom kind).
    #[doc(alias = "optixIsFrontFaceHit")]
    #[must_use]
    pub const fn is_front_face(self) -> bool {
        self.0 >= 0x80 && self.0 & 1 == 0
    }

    /// `optixIsBackFaceHit(hitKind)`: a built-in primitive's back face (never a custom kind).
    #[doc(alias = "optixIsBackFaceHit")]
    #[must_use]
    pub const fn is_back_face(self) -> bool {
        self.0 >= 0x80 && self.0 & 1 == 1
    }

    /// `OPTIX_HIT_KIND_TRIANGLE_FRONT_FACE`.
    #[doc(alias = "OPTIX_HIT_KIND_TRIANGLE_FRONT_FACE")]
    pub const TRIANGLE_FRONT_FACE: HitKind = HitKind(0xFE);
    /// `OPTIX_HIT_KIND_TRIANGLE_BACK_FACE`.
    #[doc(alias = "OPTIX_HIT_KIND_TRIANGLE_BACK_FACE")]
    pub const TRIANGLE_BACK_FACE: HitKind = HitKind(0xFF);

    /// A custom hit kind: only the low 7 bits are kept (guide §12).
    #[must_use]
    pub const fn custom(kind: u8) -> HitKind {
        HitKind(kind & 0x7F)
    }

    /// Whether this is a triangle's front face.
    #[must_use]
    pub const fn is_triangle_front_face(self) -> bool {
        self.0 == 0xFE
    }

    /// Whether this is a triangle's back face.
    #[must_use]
    pub const fn is_triangle_back_face(self) -> bool {
        self.0 == 0xFF
    }
}

/// A hit returned by a query.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the ray.
    pub t: f32,
    /// First barycentric (weight of the triangle's second vertex), or the custom hit's `u`.
    pub u: f32,
    /// Second barycentric (weight of the third vertex), or the custom hit's `v`.
    pub v: f32,
    /// Index of the primitive within its build input, plus the input's primitive index offset.
    pub primitive_index: u32,
    /// SBT-GAS index: the records of earlier inputs plus the primitive's SBT index offset.
    pub sbt_gas_index: u32,
    /// Which build input the primitive came from.
    pub build_input: u32,
    /// Front or back face of a triangle, or the custom hit kind.
    pub hit_kind: HitKind,
    /// User id of the instance nearest to the hit geometry; `!0` without instances (guide
    /// §13.7).
    pub instance_id: u32,
    /// Position of that instance in its IAS's build input; 0 without instances.
    pub instance_index: u32,
}

/// A custom primitive handed to an intersection closure.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CustomPrimitive {
    /// Primitive index (with the input's offset).
    pub primitive_index: u32,
    /// SBT-GAS index.
    pub sbt_gas_index: u32,
    /// Build input.
    pub build_input: u32,
    /// The primitive's box.
    pub aabb: Aabb,
}

/// An intersection reported by a custom-primitive closure.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CustomHit {
    /// Distance along the ray; ignored unless within the ray's current `[tmin, tmax]`.
    pub t: f32,
    /// Hit kind; only the low 7 bits are kept.
    pub hit_kind: u8,
    /// User value returned as [`Hit::u`].
    pub u: f32,
    /// User value returned as [`Hit::v`].
    pub v: f32,
}

/// What an any-hit filter decides about a candidate (guide §13.13).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CandidateAction {
    /// Accept: the candidate becomes the closest hit so far and the interval shrinks to it.
    Accept,
    /// Ignore (`optixIgnoreIntersection`): not a hit; the interval stays.
    Ignore,
    /// Accept and stop traversal (`optixTerminateRay`).
    Terminate,
}
