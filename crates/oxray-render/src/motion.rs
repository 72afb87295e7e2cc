//! Motion blur: the shutter interval ([`Shutter`]) over which camera rays take their times, and
//! the motion keys that carry a scene's node animation ([`oxray_scene::animation`]) into the
//! acceleration structures.
//!
//! Each instance that the animation moves while the shutter is open is traced through an SRT
//! motion transform (guide §5.10.5) of evenly spaced keys over the shutter: its object-to-world
//! transform at each key is split into scale and shear, rotation and translation (a QR
//! decomposition, so hierarchies with non-uniform scale stay exact at the keys), and keys are
//! added until the interpolated transform follows the animation between them (a turn of at
//! most 10 degrees per key interval and the instance's box within 1/1000 of its size at every
//! interval's middle, up to [`MAX_KEYS`] keys).
//!
//! A camera that the animation moves (a glTF camera on an animated node, or below one) is
//! keyed by [`CAMERA_KEYS`](crate::CAMERA_KEYS) frames evenly spaced over the shutter, and
//! each camera ray starts from the frame at its time, linear between the keys
//! ([`CameraFrame::at`](crate::programs::CameraFrame::at)); a closed shutter sees the scene
//! from where the camera is at its time.
//!
//! A moving emitter is not sampled by next-event estimation (its triangles' places depend on
//! the ray's time); its light is found by the paths that hit it, with their full weight, so the
//! image stays unbiased.
//!
//! ```
//! use oxray_render::motion::Shutter;
//! let s: Shutter = "0,0.04".parse()?;
//! assert_eq!((s.open, s.close), (0.0, 0.04));
//! assert!("0.5,0.25".parse::<Shutter>().is_err());
//! # Ok::<(), oxray_render::motion::ShutterError>(())
//! ```

use glam::{Mat3, Mat4, Quat, Vec3};
use oxray::{MotionOptions, SrtData};
use oxray_scene::SceneDesc;
use std::str::FromStr;
use thiserror::Error;

/// The most motion keys an instance gets.
pub const MAX_KEYS: usize = 129;

/// The interval of animation time (seconds) during which the camera's shutter is open: each
/// camera ray takes a time uniformly in `[open, close]`, and the rays of its path keep it.
/// `open == close` renders the scene as posed at that time, without blur.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shutter {
    /// When the shutter opens.
    pub open: f32,
    /// When it closes (not before `open`).
    pub close: f32,
}

/// Why a shutter interval is refused.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ShutterError {
    /// Not two numbers separated by a comma.
    #[error("shutter '{0}': expected OPEN,CLOSE (two times in seconds, e.g. 0,0.02)")]
    Malformed(String),
    /// A time is not finite, or the shutter closes before it opens.
    #[error("shutter {open},{close}: the times must be finite and CLOSE not before OPEN")]
    Invalid {
        /// The opening time.
        open: f32,
        /// The closing time.
        close: f32,
    },
}

impl Shutter {
    /// A shutter open from `open` to `close`.
    pub fn new(open: f32, close: f32) -> Result<Shutter, ShutterError> {
        if !(open.is_finite() && close.is_finite() && open <= close) {
            return Err(ShutterError::Invalid { open, close });
        }
        Ok(Shutter { open, close })
    }

    /// The time of a camera ray for a uniform number `u` in [0, 1).
    #[must_use]
    pub fn time(&self, u: f32) -> f32 {
        (self.open + (self.close - self.open) * u).min(self.close)
    }

    /// Whether the shutter stays open for some time (rays then take different times).
    #[must_use]
    pub fn is_open(&self) -> bool {
        self.close > self.open
    }
}

impl FromStr for Shutter {
    type Err = ShutterError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let malformed = || ShutterError::Malformed(s.to_string());
        let (a, b) = s.split_once(',').ok_or_else(malformed)?;
        let open: f32 = a.trim().parse().map_err(|_| malformed())?;
        let close: f32 = b.trim().parse().map_err(|_| malformed())?;
        Shutter::new(open, close)
    }
}

/// How an instance is placed over the shutter.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Pose {
    /// One transform for the whole shutter.
    Still(Mat4),
    /// Motion keys over the shutter.
    Moving(MotionOptions, Vec<SrtData>),
}

/// The pose of instance `instance` under animation `animation` over `shutter`. `None` where a
/// key cannot be made into an SRT transform (a singular or non-finite placement: such an
/// instance is not traced).
pub(crate) fn pose(
    scene: &SceneDesc,
    instance: usize,
    animation: usize,
    shutter: Shutter,
) -> Option<Pose> {
    let at = |t: f32| scene.instance_transform_at(instance, animation, t);
    if !scene.is_animated(instance, animation) {
        return Some(Pose::Still(scene.instances.get(instance)?.transform));
    }
    let first = at(shutter.open);
    if !shutter.is_open() {
        return Some(Pose::Still(first));
    }
    let corners = object_box(scene, instance);
    let size = (corners[7] - corners[0]).length().max(1e-12);
    // At least a key per keyframe inside the shutter, so that the checks between keys cannot
    // miss a turn that comes back to where it started.
    let inside = scene.keyframes_between(instance, animation, shutter.open, shutter.close);
    let mut n = (inside + 2).min(MAX_KEYS);
    loop {
        let times: Vec<f32> = (0..n)
            .map(|k| shutter.open + (shutter.close - shutter.open) * k as f32 / (n - 1) as f32)
            .collect();
        let matrices: Vec<Mat4> = times.iter().map(|&t| at(t)).collect();
        if matrices.windows(2).all(|w| w[0] == w[1]) {
            return Some(Pose::Still(first));
        }
        let mut keys = Vec::with_capacity(n);
        for m in &matrices {
            let mut key = srt_of(*m)?;
            if let Some(prev) = keys.last() {
                align(prev, &mut key);
            }
            keys.push(key);
        }
        let follows = (0..n - 1).all(|k| {
            let (a, b) = (&keys[k], &keys[k + 1]);
            let dot = quat(a).dot(quat(b));
            let mid = at(0.5 * (times[k] + times[k + 1]));
            let lerped = a.lerp(b, 0.5).to_transform();
            dot >= (5f32.to_radians()).cos()
                && corners.iter().all(|&c| {
                    (mid.transform_point3(c) - lerped.transform_point(c)).length() <= 1e-3 * size
                })
        });
        if follows || n >= MAX_KEYS {
            let options = MotionOptions::new(n as u16, shutter.open, shutter.close);
            return Some(Pose::Moving(options, keys));
        }
        n = (2 * n - 1).min(MAX_KEYS);
    }
}

/// The corners of the object-space box of an instance's mesh (the unit cube around the origin
/// for an empty one), lowest first and highest last.
fn object_box(scene: &SceneDesc, instance: usize) -> [Vec3; 8] {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    let mesh = scene
        .instances
        .get(instance)
        .and_then(|i| scene.meshes.get(i.mesh as usize));
    for p in mesh.into_iter().flat_map(|m| &m.primitives) {
        for &v in &p.positions {
            let v = Vec3::from(v);
            if v.is_finite() {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
    }
    if lo.x > hi.x {
        (lo, hi) = (Vec3::splat(-1.0), Vec3::ONE);
    }
    std::array::from_fn(|i| {
        Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        )
    })
}

fn quat(k: &SrtData) -> Quat {
    Quat::from_xyzw(k.qx, k.qy, k.qz, k.qw)
}

/// Flips `key`'s quaternion to the hemisphere of `prev`'s (the same rotation), so that
/// interpolation between them takes the short way round.
fn align(prev: &SrtData, key: &mut SrtData) {
    if quat(prev).dot(quat(key)) < 0.0 {
        (key.qx, key.qy, key.qz, key.qw) = (-key.qx, -key.qy, -key.qz, -key.qw);
    }
}

/// An affine object-to-world matrix as one SRT key: `M = T · R · S` with `R` a rotation and
/// `S` upper triangular (scale and shear; a mirroring matrix gets a negative `sz`), by
/// Gram–Schmidt on the linear part's columns. `None` for a singular or non-finite matrix.
pub(crate) fn srt_of(m: Mat4) -> Option<SrtData> {
    if !m.is_finite() {
        return None;
    }
    let l = Mat3::from_mat4(m);
    let (c0, c1, c2) = (l.x_axis, l.y_axis, l.z_axis);
    let sx = c0.length();
    if sx <= 1e-30 {
        return None;
    }
    let r0 = c0 / sx;
    let a = r0.dot(c1);
    let u1 = c1 - r0 * a;
    let sy = u1.length();
    if sy <= 1e-30 * sx {
        return None;
    }
    let r1 = u1 / sy;
    let b = r0.dot(c2);
    let c = r1.dot(c2);
    let u2 = c2 - r0 * b - r1 * c;
    let mut sz = u2.length();
    if sz <= 1e-30 * sx {
        return None;
    }
    let mut r2 = u2 / sz;
    if r0.cross(r1).dot(r2) < 0.0 {
        r2 = -r2;
        sz = -sz;
    }
    let q = Quat::from_mat3(&Mat3::from_cols(r0, r1, r2)).normalize();
    let t = m.w_axis.truncate();
    Some(SrtData {
        sx,
        a,
        b,
        sy,
        c,
        sz,
        qx: q.x,
        qy: q.y,
        qz: q.z,
        qw: q.w,
        tx: t.x,
        ty: t.y,
        tz: t.z,
        ..SrtData::IDENTITY
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use oxray_scene::animation::{Animation, Channel, Interpolation, Property};
    use oxray_scene::{InstanceDesc, MeshDesc, NodeDesc, Primitive};

    #[test]
    fn srt_keys_reproduce_their_matrices() {
        let cases = [
            Mat4::IDENTITY,
            Mat4::from_scale_rotation_translation(
                Vec3::new(2.0, 0.5, 3.0),
                Quat::from_euler(glam::EulerRot::XYZ, 0.3, -1.2, 2.5),
                Vec3::new(1.0, -2.0, 3.0),
            ),
            // A rotated parent over a non-uniformly scaled child: a shear.
            Mat4::from_rotation_z(0.7) * Mat4::from_scale(Vec3::new(3.0, 1.0, 1.0)),
            Mat4::from_scale(Vec3::new(1.0, 0.25, 4.0)) * Mat4::from_rotation_y(1.1),
            // Mirrored.
            Mat4::from_scale(Vec3::new(-1.0, 1.0, 1.0)) * Mat4::from_rotation_x(0.4),
        ];
        for m in cases {
            let key = srt_of(m).unwrap();
            let back = key.to_transform();
            for p in [
                Vec3::ZERO,
                Vec3::X,
                Vec3::Y,
                Vec3::Z,
                Vec3::new(1.0, -2.0, 0.5),
            ] {
                let d = (m.transform_point3(p) - back.transform_point(p)).length();
                assert!(d < 1e-5, "{m}: {p} off by {d}");
            }
        }
        assert_eq!(srt_of(Mat4::from_scale(Vec3::new(1.0, 0.0, 1.0))), None);
        assert_eq!(srt_of(Mat4::from_scale(Vec3::splat(f32::NAN))), None);
    }

    fn spinning(turns: f32) -> SceneDesc {
        let mut scene = SceneDesc::default();
        scene.meshes.push(MeshDesc {
            name: "blade".into(),
            primitives: vec![Primitive {
                positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.1, 0.0]],
                triangles: vec![[0, 1, 2]],
                ..Default::default()
            }],
        });
        scene.nodes.push(NodeDesc::default());
        scene
            .instances
            .push(InstanceDesc::new(0, Mat4::IDENTITY).at_node(0));
        // `turns` turns about z in one second, keyed every eighth of a turn.
        let steps = (turns * 8.0).round() as usize;
        let times = (0..=steps).map(|k| k as f32 / steps as f32).collect();
        let values = (0..=steps)
            .map(|k| {
                let q =
                    Quat::from_rotation_z(std::f32::consts::TAU * turns * k as f32 / steps as f32);
                q.to_array()
            })
            .collect();
        scene.animations.push(Animation {
            name: "spin".into(),
            channels: vec![Channel {
                node: 0,
                property: Property::Rotation,
                interpolation: Interpolation::Linear,
                times,
                values,
            }],
        });
        scene
    }

    #[test]
    fn keys_follow_a_fast_turn() {
        let scene = spinning(2.0);
        let shutter = Shutter::new(0.0, 1.0).unwrap();
        let Some(Pose::Moving(options, keys)) = pose(&scene, 0, 0, shutter) else {
            panic!("a spinning blade moves");
        };
        assert_eq!(options.num_keys as usize, keys.len());
        assert!(keys.len() > 2 && keys.len() <= MAX_KEYS, "{}", keys.len());
        let m = oxray::SrtMotionTransform::new(oxray::TraversableHandle::NULL, options, &keys)
            .expect("the keys are a valid SRT motion transform");
        for i in 0..=100 {
            let t = i as f32 / 100.0;
            let want = scene
                .instance_transform_at(0, 0, t)
                .transform_point3(Vec3::X);
            let got = m.object_to_world_at(t).unwrap().transform_point(Vec3::X);
            assert!((want - got).length() < 2e-3, "t = {t}: {want} vs {got}");
        }
    }

    #[test]
    fn still_and_closed_shutters_pose_once() {
        let scene = spinning(1.0);
        let closed = Shutter::new(0.25, 0.25).unwrap();
        let Some(Pose::Still(m)) = pose(&scene, 0, 0, closed) else {
            panic!("a closed shutter poses once");
        };
        assert!((m.transform_point3(Vec3::X) - Vec3::Y).length() < 1e-6);
        // No such animation: the rest placement.
        let open = Shutter::new(0.0, 1.0).unwrap();
        assert_eq!(pose(&scene, 0, 3, open), Some(Pose::Still(Mat4::IDENTITY)));
        // Past the last keyframe the animation holds still.
        let late = Shutter::new(2.0, 3.0).unwrap();
        assert!(matches!(pose(&scene, 0, 0, late), Some(Pose::Still(_))));
    }

    #[test]
    fn shutters_parse_and_refuse() {
        assert_eq!(
            " 1 , 2 ".parse::<Shutter>().unwrap(),
            Shutter {
                open: 1.0,
                close: 2.0
            }
        );
        for bad in ["", "1", "1,", "a,b", "1,2,3"] {
            assert!(
                matches!(bad.parse::<Shutter>(), Err(ShutterError::Malformed(_))),
                "{bad}"
            );
        }
        for bad in ["2,1", "nan,1", "0,inf"] {
            assert!(
                matches!(bad.parse::<Shutter>(), Err(ShutterError::Invalid { .. })),
                "{bad}"
            );
        }
        let s = Shutter::new(1.0, 3.0).unwrap();
        assert_eq!(s.time(0.0), 1.0);
        assert_eq!(s.time(0.5), 2.0);
        assert!(s.time(0.999_999_9) <= 3.0);
    }
}
