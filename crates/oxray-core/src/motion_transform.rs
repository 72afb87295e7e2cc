//! Motion transforms (guide §5.10.4, §5.10.5): traversables that place their child with an
//! object-to-world transform given per motion key and interpolated at the ray's time.
//!
//! [`MatrixMotionTransform`] interpolates 3x4 matrices element by element;
//! [`SrtMotionTransform`] interpolates scale/shear, quaternion and translation ([`SrtData`])
//! component by component, normalises the quaternion (nlerp) and composes `C = T · R · S`.

use crate::aabb::Aabb;
use crate::error::BuildError;
use crate::handle::{BackendKind, Traversable, TraversableHandle, TraversableKind};
use crate::instance::MAX_TRAVERSABLE_GRAPH_DEPTH;
use crate::motion::{lerp, KeySample, MotionOptions};
use crate::transform::Transform;
use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// One key of an SRT motion transform (`OptixSRTData`, guide §5.10.5), sixteen floats in the
/// guide's order. The key's object-to-world transform is `C = T · R · S` with
/// `S = [[sx, a, b, pvx], [0, sy, c, pvy], [0, 0, sz, pvz]]` (scale, shear and a pivot
/// translation), `R` the rotation of the unit quaternion `(qx, qy, qz, qw)` and `T` the
/// translation `(tx, ty, tz)`.
///
/// ```
/// use oxray_core::SrtData;
/// use glam::Vec3;
/// // A quarter turn about z, then a translation by (1, 0, 0).
/// let h = std::f32::consts::FRAC_1_SQRT_2;
/// let key = SrtData { qz: h, qw: h, tx: 1.0, ..SrtData::IDENTITY };
/// let p = key.to_transform().transform_point(Vec3::X);
/// assert!((p - Vec3::new(1.0, 1.0, 0.0)).length() < 1e-6);
/// ```
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
#[allow(missing_docs)]
#[doc(alias = "OptixSRTData")]
pub struct SrtData {
    pub sx: f32,
    pub a: f32,
    pub b: f32,
    pub pvx: f32,
    pub sy: f32,
    pub c: f32,
    pub pvy: f32,
    pub sz: f32,
    pub pvz: f32,
    pub qx: f32,
    pub qy: f32,
    pub qz: f32,
    pub qw: f32,
    pub tx: f32,
    pub ty: f32,
    pub tz: f32,
}

impl Default for SrtData {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl SrtData {
    /// The identity: unit scale, no shear or pivot, the unit quaternion, no translation.
    pub const IDENTITY: SrtData = SrtData {
        sx: 1.0,
        a: 0.0,
        b: 0.0,
        pvx: 0.0,
        sy: 1.0,
        c: 0.0,
        pvy: 0.0,
        sz: 1.0,
        pvz: 0.0,
        qx: 0.0,
        qy: 0.0,
        qz: 0.0,
        qw: 1.0,
        tx: 0.0,
        ty: 0.0,
        tz: 0.0,
    };

    fn as_array(&self) -> &[f32; 16] {
        bytemuck::cast_ref(self)
    }

    /// Component-wise linear interpolation of two keys (the quaternion is not normalised
    /// here; [`to_transform`](Self::to_transform) does).
    #[must_use]
    pub fn lerp(&self, other: &SrtData, f: f32) -> SrtData {
        let (a, b) = (self.as_array(), other.as_array());
        let out: [f32; 16] = std::array::from_fn(|i| lerp(a[i], b[i], f));
        bytemuck::cast(out)
    }

    /// The object-to-world transform `C = T · R · S`, with the quaternion normalised first
    /// (guide §5.10.5).
    #[must_use]
    pub fn to_transform(&self) -> Transform {
        let n =
            (self.qx * self.qx + self.qy * self.qy + self.qz * self.qz + self.qw * self.qw).sqrt();
        let (x, y, z, w) = (self.qx / n, self.qy / n, self.qz / n, self.qw / n);
        let r = [
            [
                1.0 - 2.0 * (y * y + z * z),
                2.0 * (x * y - z * w),
                2.0 * (x * z + y * w),
            ],
            [
                2.0 * (x * y + z * w),
                1.0 - 2.0 * (x * x + z * z),
                2.0 * (y * z - x * w),
            ],
            [
                2.0 * (x * z - y * w),
                2.0 * (y * z + x * w),
                1.0 - 2.0 * (x * x + y * y),
            ],
        ];
        let s = [
            [self.sx, self.a, self.b, self.pvx],
            [0.0, self.sy, self.c, self.pvy],
            [0.0, 0.0, self.sz, self.pvz],
        ];
        let t = [self.tx, self.ty, self.tz];
        let mut m = [0.0f32; 12];
        for row in 0..3 {
            for col in 0..4 {
                let mut v = 0.0;
                for (k, s_row) in s.iter().enumerate() {
                    v += r[row][k] * s_row[col];
                }
                if col == 3 {
                    v += t[row];
                }
                m[row * 4 + col] = v;
            }
        }
        Transform(m)
    }

    fn quaternion(&self) -> [f32; 4] {
        [self.qx, self.qy, self.qz, self.qw]
    }
}

/// Why motion transform keys were refused (guide §5.10.4, §5.10.5, §5.10.6).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MotionKeyRule {
    /// The number of keys given differs from the motion options' `num_keys`.
    KeyCount,
    /// A key has a component that is not finite.
    NotFinite,
    /// A matrix key is singular.
    Singular,
    /// An SRT key's quaternion is zero.
    ZeroQuaternion,
    /// Two neighbouring SRT keys rotate by 180 degrees or more: their quaternions' dot product
    /// is not positive (§5.10.6).
    RotationTooLarge,
}

impl std::fmt::Display for MotionKeyRule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            MotionKeyRule::KeyCount => "the number of keys differs from numKeys",
            MotionKeyRule::NotFinite => "a component is not finite",
            MotionKeyRule::Singular => "the matrix is singular",
            MotionKeyRule::ZeroQuaternion => "the quaternion is zero",
            MotionKeyRule::RotationTooLarge => {
                "it rotates 180 degrees or more from the key before (quaternion dot product <= 0)"
            }
        })
    }
}

fn key_error(key: usize, rule: MotionKeyRule) -> BuildError {
    BuildError::InvalidMotionKey { key, rule }
}

fn check_depth(child: &TraversableHandle) -> Result<(), BuildError> {
    let depth = 1 + child.graph_depth();
    if depth > MAX_TRAVERSABLE_GRAPH_DEPTH {
        return Err(BuildError::GraphTooDeep {
            depth,
            limit: MAX_TRAVERSABLE_GRAPH_DEPTH,
        });
    }
    Ok(())
}

/// The bytes of an OptiX motion transform: child handle (0), `OptixMotionOptions` (`u16` keys,
/// `u16` flags, two `f32` times), three padding words, then the keys' floats; in 8-byte words
/// so that the handle is aligned.
fn optix_layout(motion: &MotionOptions, keys: &[f32]) -> Vec<u64> {
    let mut words: Vec<u32> = vec![
        0,
        0,
        motion.num_keys as u32 | (motion.flags.bits() as u32) << 16,
        motion.time_begin.to_bits(),
        motion.time_end.to_bits(),
        0,
        0,
        0,
    ];
    words.extend(keys.iter().map(|k| k.to_bits()));
    if words.len() % 2 == 1 {
        words.push(0);
    }
    words
        .chunks_exact(2)
        .map(|w| w[0] as u64 | (w[1] as u64) << 32)
        .collect()
}

/// Grows a box by a few ulps of its coordinates: a key interpolated in `f32` may round past
/// the boxes of its keys by an ulp.
#[must_use]
pub fn pad_motion_box(b: &Aabb) -> Aabb {
    if !b.is_valid() {
        return *b;
    }
    let scale = b.min.abs().max(b.max.abs()).max_element();
    let pad = Vec3::splat(scale * 4.0 * f32::EPSILON + f32::MIN_POSITIVE);
    Aabb::new(b.min - pad, b.max + pad)
}

/// A matrix motion transform (`OptixMatrixMotionTransform`, guide §5.10.4): one 3x4 row-major
/// object-to-world matrix per key, interpolated element by element at the ray's time.
///
/// ```
/// use oxray_core::{MatrixMotionTransform, MotionOptions, Transform, TraversableHandle};
/// use glam::Vec3;
/// let keys = [Transform::IDENTITY, Transform::from_translation(Vec3::new(2.0, 0.0, 0.0))];
/// let m = MatrixMotionTransform::new(TraversableHandle::NULL, MotionOptions::new(2, 0.0, 1.0), &keys)?;
/// let half = m.object_to_world_at(0.5).unwrap();
/// assert_eq!(half.transform_point(Vec3::ZERO), Vec3::new(1.0, 0.0, 0.0));
/// # Ok::<(), oxray_core::BuildError>(())
/// ```
#[derive(Clone, Debug)]
pub struct MatrixMotionTransform {
    child: TraversableHandle,
    motion: MotionOptions,
    keys: Vec<Transform>,
    layout: Vec<u64>,
}

impl MatrixMotionTransform {
    /// Places `child` with one object-to-world matrix per key. Refused: invalid options
    /// (§5.10.1: at least two keys, `time_begin < time_end`), a key count other than
    /// `num_keys`, a key that is not finite or singular, a graph deeper than 31 levels.
    pub fn new(
        child: TraversableHandle,
        motion: MotionOptions,
        keys: &[Transform],
    ) -> Result<Self, BuildError> {
        motion.validate_for_transform()?;
        if keys.len() != motion.num_keys as usize {
            return Err(key_error(keys.len(), MotionKeyRule::KeyCount));
        }
        for (k, m) in keys.iter().enumerate() {
            if !m.0.iter().all(|x| x.is_finite()) {
                return Err(key_error(k, MotionKeyRule::NotFinite));
            }
            if m.inverse().is_none() {
                return Err(key_error(k, MotionKeyRule::Singular));
            }
        }
        check_depth(&child)?;
        Ok(MatrixMotionTransform {
            child,
            motion,
            keys: keys.to_vec(),
            layout: optix_layout(&motion, bytemuck::cast_slice(keys)),
        })
    }

    /// The child.
    #[must_use]
    pub fn child(&self) -> &TraversableHandle {
        &self.child
    }

    /// The motion options.
    #[must_use]
    pub fn motion_options(&self) -> &MotionOptions {
        &self.motion
    }

    /// The keys' object-to-world matrices.
    #[must_use]
    pub fn keys(&self) -> &[Transform] {
        &self.keys
    }

    /// The matrix between two keys.
    #[must_use]
    pub fn interpolate(&self, s: KeySample) -> Transform {
        let (a, b) = (&self.keys[s.key].0, &self.keys[s.next].0);
        Transform(std::array::from_fn(|i| lerp(a[i], b[i], s.fraction)))
    }

    /// The object-to-world transform at `time`; `None` where the transform vanishes.
    #[must_use]
    pub fn object_to_world_at(&self, time: f32) -> Option<Transform> {
        self.motion.sample(time).map(|s| self.interpolate(s))
    }
}

impl MatrixMotionTransform {
    /// The transform as `OptixMatrixMotionTransform` lays it out (guide §5.10.4, §5.10.5: a 32-byte header of
    /// child handle, motion options and padding, then every key), with a child handle of 0:
    /// what `optixGet…MotionTransformFromHandle` gives programs compiled for the CPU.
    #[doc(alias = "OptixMatrixMotionTransform")]
    #[must_use]
    pub fn optix_layout(&self) -> &[u8] {
        bytemuck::cast_slice(&self.layout)
    }
}

impl Traversable for MatrixMotionTransform {
    fn traversable_kind(&self) -> TraversableKind {
        TraversableKind::MatrixMotionTransform
    }

    /// The union of the child's box under every key: a corner under an interpolated matrix is
    /// the interpolation of the corner under the two keys, so it lies in their boxes.
    fn bounds(&self) -> Aabb {
        let child = self.child.bounds();
        let mut out = Aabb::EMPTY;
        for k in &self.keys {
            out = out.union(&k.transform_aabb(&child));
        }
        pad_motion_box(&out)
    }

    fn graph_depth(&self) -> u32 {
        1 + self.child.graph_depth()
    }

    fn backend(&self) -> BackendKind {
        self.child.backend().unwrap_or(BackendKind::Any)
    }

    fn describe(&self) -> String {
        format!(
            "matrix motion transform of {} keys over {:?}",
            self.keys.len(),
            self.child
        )
    }
}

/// An SRT motion transform (`OptixSRTMotionTransform`, guide §5.10.5): one [`SrtData`] per key,
/// interpolated component by component at the ray's time, the quaternion normalised (nlerp),
/// composed as `C = T · R · S`.
///
/// ```
/// use oxray_core::{MotionOptions, SrtData, SrtMotionTransform, TraversableHandle};
/// use glam::Vec3;
/// // A half turn about z over two keys of a quarter turn each.
/// let h = std::f32::consts::FRAC_1_SQRT_2;
/// let keys = [
///     SrtData::IDENTITY,
///     SrtData { qz: h, qw: h, ..SrtData::IDENTITY },
///     SrtData { qz: 1.0, qw: 0.0, ..SrtData::IDENTITY },
/// ];
/// let m = SrtMotionTransform::new(TraversableHandle::NULL, MotionOptions::new(3, 0.0, 1.0), &keys)?;
/// let p = m.object_to_world_at(1.0).unwrap().transform_point(Vec3::X);
/// assert!((p - Vec3::new(-1.0, 0.0, 0.0)).length() < 1e-6);
/// # Ok::<(), oxray_core::BuildError>(())
/// ```
#[derive(Clone, Debug)]
pub struct SrtMotionTransform {
    child: TraversableHandle,
    motion: MotionOptions,
    keys: Vec<SrtData>,
    layout: Vec<u64>,
}

impl SrtMotionTransform {
    /// Places `child` with one SRT key per motion key. Refused: invalid options (§5.10.1), a key
    /// count other than `num_keys`, a component that is not finite, a zero quaternion,
    /// neighbouring quaternions whose dot product is not positive (§5.10.6), a graph deeper
    /// than 31 levels.
    pub fn new(
        child: TraversableHandle,
        motion: MotionOptions,
        keys: &[SrtData],
    ) -> Result<Self, BuildError> {
        motion.validate_for_transform()?;
        if keys.len() != motion.num_keys as usize {
            return Err(key_error(keys.len(), MotionKeyRule::KeyCount));
        }
        for (k, key) in keys.iter().enumerate() {
            if !key.as_array().iter().all(|x| x.is_finite()) {
                return Err(key_error(k, MotionKeyRule::NotFinite));
            }
            if key.quaternion().iter().all(|&x| x == 0.0) {
                return Err(key_error(k, MotionKeyRule::ZeroQuaternion));
            }
            if key.to_transform().inverse().is_none() {
                return Err(key_error(k, MotionKeyRule::Singular));
            }
            if k > 0 {
                let (p, q) = (keys[k - 1].quaternion(), key.quaternion());
                let dot: f32 = (0..4).map(|i| p[i] * q[i]).sum();
                if dot <= 0.0 {
                    return Err(key_error(k, MotionKeyRule::RotationTooLarge));
                }
            }
        }
        check_depth(&child)?;
        Ok(SrtMotionTransform {
            child,
            motion,
            keys: keys.to_vec(),
            layout: optix_layout(&motion, bytemuck::cast_slice(keys)),
        })
    }

    /// The child.
    #[must_use]
    pub fn child(&self) -> &TraversableHandle {
        &self.child
    }

    /// The motion options.
    #[must_use]
    pub fn motion_options(&self) -> &MotionOptions {
        &self.motion
    }

    /// The keys.
    #[must_use]
    pub fn keys(&self) -> &[SrtData] {
        &self.keys
    }

    /// The transform between two keys.
    #[must_use]
    pub fn interpolate(&self, s: KeySample) -> Transform {
        self.keys[s.key]
            .lerp(&self.keys[s.next], s.fraction)
            .to_transform()
    }

    /// The object-to-world transform at `time`; `None` where the transform vanishes.
    #[must_use]
    pub fn object_to_world_at(&self, time: f32) -> Option<Transform> {
        self.motion.sample(time).map(|s| self.interpolate(s))
    }
}

impl SrtMotionTransform {
    /// The transform as `OptixSRTMotionTransform` lays it out (guide §5.10.4, §5.10.5: a 32-byte header of
    /// child handle, motion options and padding, then every key), with a child handle of 0:
    /// what `optixGet…MotionTransformFromHandle` gives programs compiled for the CPU.
    #[doc(alias = "OptixSRTMotionTransform")]
    #[must_use]
    pub fn optix_layout(&self) -> &[u8] {
        bytemuck::cast_slice(&self.layout)
    }
}

impl Traversable for SrtMotionTransform {
    fn traversable_kind(&self) -> TraversableKind {
        TraversableKind::SrtMotionTransform
    }

    /// Conservative: between two keys a corner `c` of the child's box moves to
    /// `T(t) + R(t) S(t) c`. `S(t) c` is linear in `t`, so it lies in the box `A` of the corners
    /// under both keys' `S`; a rotation keeps lengths, so `R(t) S(t) c` lies within the radius
    /// of `A`'s farthest corner; `T(t)` lies in the box of the two translations.
    fn bounds(&self) -> Aabb {
        let child = self.child.bounds();
        if !child.is_valid() {
            return Aabb::EMPTY;
        }
        let scale = |k: &SrtData| {
            Transform([
                k.sx, k.a, k.b, k.pvx, 0.0, k.sy, k.c, k.pvy, 0.0, 0.0, k.sz, k.pvz,
            ])
        };
        let mut out = Aabb::EMPTY;
        for pair in self.keys.windows(2) {
            let a = scale(&pair[0])
                .transform_aabb(&child)
                .union(&scale(&pair[1]).transform_aabb(&child));
            let r = a.min.abs().max(a.max.abs()).length();
            let t0 = Vec3::new(pair[0].tx, pair[0].ty, pair[0].tz);
            let t1 = Vec3::new(pair[1].tx, pair[1].ty, pair[1].tz);
            out = out.union(&Aabb::new(
                t0.min(t1) - Vec3::splat(r),
                t0.max(t1) + Vec3::splat(r),
            ));
        }
        pad_motion_box(&out)
    }

    fn graph_depth(&self) -> u32 {
        1 + self.child.graph_depth()
    }

    fn backend(&self) -> BackendKind {
        self.child.backend().unwrap_or(BackendKind::Any)
    }

    fn describe(&self) -> String {
        format!(
            "SRT motion transform of {} keys over {:?}",
            self.keys.len(),
            self.child
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::motion::{MotionFlags, MotionRule};

    #[test]
    fn s5_10_5_srt_composes_t_r_s_with_the_pivot_in_s() {
        // S scales x by 2 and moves by the pivot column; R turns a quarter about z; T moves
        // last.
        let key = SrtData {
            sx: 2.0,
            pvx: -1.0,
            qz: std::f32::consts::FRAC_1_SQRT_2,
            qw: std::f32::consts::FRAC_1_SQRT_2,
            tx: 1.0,
            ..SrtData::IDENTITY
        };
        let m = key.to_transform();
        // S (3,0,0) = (5,0,0); R (quarter turn about z) = (0,5,0); T = (1,5,0).
        let p = m.transform_point(Vec3::new(3.0, 0.0, 0.0));
        assert!((p - Vec3::new(1.0, 5.0, 0.0)).length() < 1e-5, "{p}");
        // Shear a: x += a*y.
        let shear = SrtData {
            a: 0.5,
            ..SrtData::IDENTITY
        };
        let p = shear
            .to_transform()
            .transform_point(Vec3::new(0.0, 2.0, 0.0));
        assert_eq!(p, Vec3::new(1.0, 2.0, 0.0));
    }

    #[test]
    fn s5_10_5_the_interpolated_quaternion_is_normalised() {
        // Key 1 turns 120 degrees about z. Half-way the lerped quaternion (0, 0, .433, .75) is
        // not of unit length; normalised it turns 60 degrees (nlerp and slerp agree at the
        // middle), and a pure rotation keeps lengths.
        let (s, c) = (60f32.to_radians().sin(), 60f32.to_radians().cos());
        let keys = [
            SrtData::IDENTITY,
            SrtData {
                qz: s,
                qw: c,
                ..SrtData::IDENTITY
            },
        ];
        let t = SrtMotionTransform::new(
            TraversableHandle::NULL,
            MotionOptions::new(2, 0.0, 1.0),
            &keys,
        )
        .unwrap();
        let p = t.object_to_world_at(0.5).unwrap().transform_point(Vec3::X);
        assert!((p - Vec3::new(c, s, 0.0)).length() < 1e-6, "{p}");
        // Without the normalisation the point would be scaled by |q|^2 = 0.75.
        let raw = keys[0].lerp(&keys[1], 0.5);
        let n2 = raw.qz * raw.qz + raw.qw * raw.qw;
        assert!((n2 - 0.75).abs() < 1e-6);
    }

    #[test]
    fn s5_10_6_neighbouring_srt_keys_rotate_less_than_180_degrees() {
        let keys = [
            SrtData::IDENTITY,
            SrtData {
                qz: 1.0,
                qw: 0.0,
                ..SrtData::IDENTITY
            },
        ];
        let err = SrtMotionTransform::new(
            TraversableHandle::NULL,
            MotionOptions::new(2, 0.0, 1.0),
            &keys,
        )
        .unwrap_err();
        assert_eq!(
            err,
            BuildError::InvalidMotionKey {
                key: 1,
                rule: MotionKeyRule::RotationTooLarge
            }
        );
    }

    #[test]
    fn s5_10_1_motion_transforms_need_two_keys_and_an_increasing_range() {
        let one = [Transform::IDENTITY];
        let err = MatrixMotionTransform::new(
            TraversableHandle::NULL,
            MotionOptions::new(1, 0.0, 1.0),
            &one,
        )
        .unwrap_err();
        assert_eq!(
            err,
            BuildError::InvalidMotionOptions(MotionRule::TransformKeys)
        );
        let two = [Transform::IDENTITY; 2];
        let err = MatrixMotionTransform::new(
            TraversableHandle::NULL,
            MotionOptions::new(2, 1.0, 1.0),
            &two,
        )
        .unwrap_err();
        assert_eq!(
            err,
            BuildError::InvalidMotionOptions(MotionRule::TransformTimes)
        );
        let err = MatrixMotionTransform::new(
            TraversableHandle::NULL,
            MotionOptions::new(3, 0.0, 1.0),
            &two,
        )
        .unwrap_err();
        assert!(matches!(
            err,
            BuildError::InvalidMotionKey {
                rule: MotionKeyRule::KeyCount,
                ..
            }
        ));
        let mut singular = Transform::IDENTITY;
        singular.0[0] = 0.0;
        let err = MatrixMotionTransform::new(
            TraversableHandle::NULL,
            MotionOptions::new(2, 0.0, 1.0),
            &[Transform::IDENTITY, singular],
        )
        .unwrap_err();
        assert_eq!(
            err,
            BuildError::InvalidMotionKey {
                key: 1,
                rule: MotionKeyRule::Singular
            }
        );
    }

    #[test]
    fn s5_10_4_matrix_keys_interpolate_element_wise_and_vanish_by_flags() {
        let keys = [
            Transform::IDENTITY,
            Transform::from_translation(Vec3::new(4.0, 0.0, 0.0)),
        ];
        let m = MatrixMotionTransform::new(
            TraversableHandle::NULL,
            MotionOptions::new(2, 0.0, 2.0).with_flags(MotionFlags::START_VANISH),
            &keys,
        )
        .unwrap();
        let at = |t: f32| {
            m.object_to_world_at(t)
                .map(|x| x.transform_point(Vec3::ZERO))
        };
        assert_eq!(at(0.5), Some(Vec3::new(1.0, 0.0, 0.0)));
        assert_eq!(at(9.0), Some(Vec3::new(4.0, 0.0, 0.0)));
        assert_eq!(at(-0.1), None);
    }

    #[test]
    fn s5_10_4_s5_10_5_the_optix_layouts_have_the_guides_sizes() {
        let m = MotionOptions::new(3, -1.0, 1.5).with_flags(MotionFlags::END_VANISH);
        let srt =
            SrtMotionTransform::new(TraversableHandle::NULL, m, &[SrtData::IDENTITY; 3]).unwrap();
        // sizeof(OptixSRTMotionTransform) = 8 + 12 + 12 + 2 * 64, plus one key.
        assert_eq!(srt.optix_layout().len(), 8 + 12 + 12 + 3 * 64);
        let mat = MatrixMotionTransform::new(TraversableHandle::NULL, m, &[Transform::IDENTITY; 3])
            .unwrap();
        assert_eq!(mat.optix_layout().len(), 32 + 3 * 48);
        let b = mat.optix_layout();
        let word = |at: usize| u32::from_le_bytes(b[at..at + 4].try_into().unwrap());
        assert_eq!(word(0) as u64 | (word(4) as u64) << 32, 0, "child handle");
        assert_eq!((word(8) & 0xFFFF, word(8) >> 16), (3, 2), "numKeys, flags");
        assert_eq!(f32::from_bits(word(12)), -1.0);
        assert_eq!(f32::from_bits(word(16)), 1.5);
        assert_eq!(f32::from_bits(word(32)), 1.0, "the first key's m00");
        let srt_bytes = srt.optix_layout();
        let qw = f32::from_le_bytes(srt_bytes[32 + 12 * 4..32 + 13 * 4].try_into().unwrap());
        assert_eq!(qw, 1.0, "the first key's qw");
    }
}
