//! Hits as queries report them, and what an any-hit filter decides.

use crate::aabb::Aabb;

/// The kind of a hit (`optixGetHitKind`, guide §13.7): `0xFE`/`0xFF` for the front/back face of a
/// triangle, `0..=127` as reported for a custom primitive.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct HitKind(pub u8);

impl HitKind {
    /// `OPTIX_HIT_KIND_TRIANGLE_FRONT_FACE`.
    pub const TRIANGLE_FRONT_FACE: HitKind = HitKind(0xFE);
    /// `OPTIX_HIT_KIND_TRIANGLE_BACK_FACE`.
    pub const TRIANGLE_BACK_FACE: HitKind = HitKind(0xFF);

    /// A custom hit kind: only the low 7 bits are kept (guide §12).
    pub const fn custom(kind: u8) -> HitKind {
        HitKind(kind & 0x7F)
    }

    /// Whether this is a triangle's front face.
    pub const fn is_triangle_front_face(self) -> bool {
        self.0 == 0xFE
    }

    /// Whether this is a triangle's back face.
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
