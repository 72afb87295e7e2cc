//! Node animation (glTF 2.0 `animations`): keyframed translation, rotation and scale of nodes,
//! and the placements of a scene's instances at any time, for motion blur.
//!
//! A [`SceneDesc`] loaded from glTF keeps its node hierarchy ([`SceneDesc::nodes`], each
//! instance naming its node in [`InstanceDesc::node`]) and its [`Animation`]s. Sampling follows
//! the glTF specification: times before the first keyframe take the first value and times after
//! the last take the last; `STEP` holds a value until the next keyframe, `LINEAR` interpolates
//! (rotations by spherical interpolation) and `CUBICSPLINE` evaluates the Hermite spline of the
//! in- and out-tangents (rotations normalised afterwards). A node's animated local transform is
//! `T · R · S` with the channels it has and its rest values for the others.
//!
//! ```
//! use glam::{Quat, Vec3};
//! use oxray_scene::animation::{Animation, Channel, Interpolation, Property};
//! use oxray_scene::{InstanceDesc, MeshDesc, NodeDesc, SceneDesc};
//!
//! // One node sliding from x = 0 to x = 2 between t = 0 and t = 1.
//! let mut scene = SceneDesc::default();
//! scene.meshes.push(MeshDesc::default());
//! scene.nodes.push(NodeDesc::default());
//! scene.instances.push(InstanceDesc::new(0, glam::Mat4::IDENTITY).at_node(0));
//! scene.animations.push(Animation {
//!     name: "slide".into(),
//!     channels: vec![Channel {
//!         node: 0,
//!         property: Property::Translation,
//!         interpolation: Interpolation::Linear,
//!         times: vec![0.0, 1.0],
//!         values: vec![[0.0; 4], [2.0, 0.0, 0.0, 0.0]],
//!     }],
//! });
//! assert!(scene.is_animated(0, 0));
//! let m = scene.instance_transform_at(0, 0, 0.25);
//! assert_eq!(m.transform_point3(Vec3::ZERO), Vec3::new(0.5, 0.0, 0.0));
//! ```

use crate::{InstanceDesc, SceneDesc};
use glam::{Mat4, Quat, Vec3, Vec4};

/// A node of the scene's hierarchy (glTF `nodes`), with its rest transform.
#[derive(Clone, Debug, PartialEq)]
pub struct NodeDesc {
    /// The parent node, `None` for a root.
    pub parent: Option<u32>,
    /// Rest translation.
    pub translation: Vec3,
    /// Rest rotation (a unit quaternion).
    pub rotation: Quat,
    /// Rest scale.
    pub scale: Vec3,
    /// The node's matrix where the file gives one instead of translation, rotation and scale:
    /// such a node cannot be animated (glTF 2.0, 5.25), and its channels are ignored.
    pub matrix: Option<Mat4>,
}

impl Default for NodeDesc {
    fn default() -> Self {
        NodeDesc {
            parent: None,
            translation: Vec3::ZERO,
            rotation: Quat::IDENTITY,
            scale: Vec3::ONE,
            matrix: None,
        }
    }
}

/// What a channel animates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Property {
    /// The translation (values' first three components).
    Translation,
    /// The rotation, a quaternion `(x, y, z, w)`.
    Rotation,
    /// The scale (values' first three components).
    Scale,
}

/// How a channel's values are interpolated between keyframes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interpolation {
    /// The value of the previous keyframe.
    Step,
    /// Linear (spherical linear for rotations).
    Linear,
    /// Cubic Hermite spline: `values` holds, per keyframe, the in-tangent, the value and the
    /// out-tangent.
    CubicSpline,
}

/// One animated property of one node.
#[derive(Clone, Debug, PartialEq)]
pub struct Channel {
    /// The node (index into [`SceneDesc::nodes`]).
    pub node: u32,
    /// The property.
    pub property: Property,
    /// The interpolation.
    pub interpolation: Interpolation,
    /// Keyframe times in seconds, finite and increasing.
    pub times: Vec<f32>,
    /// Values (three per keyframe for [`Interpolation::CubicSpline`], else one), as four
    /// components (the fourth unused for translation and scale).
    pub values: Vec<[f32; 4]>,
}

/// A named set of channels played together (glTF `animation`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Animation {
    /// A name for messages.
    pub name: String,
    /// The channels.
    pub channels: Vec<Channel>,
}

impl Channel {
    /// Why the channel cannot be sampled (for loaders), or `None` when it can.
    #[must_use]
    pub fn problem(&self) -> Option<String> {
        if self.times.is_empty() {
            return Some("no keyframes".into());
        }
        if !self.times.iter().all(|t| t.is_finite()) {
            return Some("a keyframe time is not finite".into());
        }
        if self.times.windows(2).any(|w| w[1] <= w[0]) {
            return Some("keyframe times do not increase".into());
        }
        let per = match self.interpolation {
            Interpolation::CubicSpline => 3,
            _ => 1,
        };
        if self.values.len() != self.times.len() * per {
            return Some(format!(
                "{} values for {} keyframes",
                self.values.len(),
                self.times.len()
            ));
        }
        if !self.values.iter().flatten().all(|v| v.is_finite()) {
            return Some("a value is not finite".into());
        }
        None
    }

    /// The value at `time` (clamped to the keyframes), as four components.
    #[must_use]
    pub fn sample(&self, time: f32) -> Vec4 {
        let n = self.times.len();
        let value = |k: usize| -> Vec4 {
            let i = match self.interpolation {
                Interpolation::CubicSpline => 3 * k + 1,
                _ => k,
            };
            Vec4::from(self.values[i])
        };
        if n == 0 {
            return Vec4::ZERO;
        }
        if n == 1 || time.is_nan() || time <= self.times[0] {
            return value(0);
        }
        if time >= self.times[n - 1] {
            return value(n - 1);
        }
        let k = self.times.partition_point(|&t| t <= time) - 1;
        let (t0, t1) = (self.times[k], self.times[k + 1]);
        let dt = t1 - t0;
        let s = ((time - t0) / dt).clamp(0.0, 1.0);
        let rotation = self.property == Property::Rotation;
        match self.interpolation {
            Interpolation::Step => value(k),
            Interpolation::Linear if rotation => {
                let q = quat(value(k)).slerp(quat(value(k + 1)), s);
                Vec4::from(q)
            }
            Interpolation::Linear => value(k).lerp(value(k + 1), s),
            Interpolation::CubicSpline => {
                let (p0, p1) = (value(k), value(k + 1));
                let m0 = Vec4::from(self.values[3 * k + 2]) * dt;
                let m1 = Vec4::from(self.values[3 * (k + 1)]) * dt;
                let (s2, s3) = (s * s, s * s * s);
                let v = p0 * (2.0 * s3 - 3.0 * s2 + 1.0)
                    + m0 * (s3 - 2.0 * s2 + s)
                    + p1 * (-2.0 * s3 + 3.0 * s2)
                    + m1 * (s3 - s2);
                if rotation {
                    Vec4::from(quat(v))
                } else {
                    v
                }
            }
        }
    }
}

/// A unit quaternion from four components (the identity for a zero or non-finite one).
fn quat(v: Vec4) -> Quat {
    let q = Quat::from_vec4(v);
    let len = q.length();
    if len.is_finite() && len > 0.0 {
        q / len
    } else {
        Quat::IDENTITY
    }
}

impl InstanceDesc {
    /// A placement of mesh `mesh` by `transform`, at no node.
    #[must_use]
    pub fn new(mesh: u32, transform: Mat4) -> InstanceDesc {
        InstanceDesc {
            mesh,
            transform,
            node: None,
        }
    }

    /// The same placement, made by node `node` (which animations may move).
    #[must_use]
    pub fn at_node(mut self, node: u32) -> InstanceDesc {
        self.node = Some(node);
        self
    }
}

impl SceneDesc {
    /// The local transform of node `node` at `time` under animation `animation` (its rest
    /// transform where no channel of that animation targets it).
    #[must_use]
    pub fn node_transform_at(&self, node: u32, animation: usize, time: f32) -> Mat4 {
        let Some(n) = self.nodes.get(node as usize) else {
            return Mat4::IDENTITY;
        };
        if let Some(m) = n.matrix {
            return m;
        }
        let (mut t, mut r, mut s) = (n.translation, n.rotation, n.scale);
        if let Some(a) = self.animations.get(animation) {
            for c in a.channels.iter().filter(|c| c.node == node) {
                let v = c.sample(time);
                match c.property {
                    Property::Translation => t = v.truncate(),
                    Property::Rotation => r = quat(v),
                    Property::Scale => s = v.truncate(),
                }
            }
        }
        Mat4::from_scale_rotation_translation(s, r, t)
    }

    /// Whether animation `animation` moves instance `instance` (a channel targets its node or
    /// one of the node's ancestors).
    #[must_use]
    pub fn is_animated(&self, instance: usize, animation: usize) -> bool {
        let Some(a) = self.animations.get(animation) else {
            return false;
        };
        self.chain(instance).any(|node| {
            self.nodes[node as usize].matrix.is_none() && a.channels.iter().any(|c| c.node == node)
        })
    }

    /// How many keyframes of animation `animation` that move instance `instance` (on its node
    /// or an ancestor) fall strictly between `open` and `close`: how finely the motion must be
    /// keyed to follow them.
    #[must_use]
    pub fn keyframes_between(
        &self,
        instance: usize,
        animation: usize,
        open: f32,
        close: f32,
    ) -> usize {
        let Some(a) = self.animations.get(animation) else {
            return 0;
        };
        self.chain(instance)
            .flat_map(|node| a.channels.iter().filter(move |c| c.node == node))
            .map(|c| {
                let lo = c.times.partition_point(|&t| t <= open);
                let hi = c.times.partition_point(|&t| t < close);
                hi.saturating_sub(lo)
            })
            .sum()
    }

    /// The object-to-world transform of instance `instance` at `time` under animation
    /// `animation`: the product of its node's and its ancestors' animated local transforms. An
    /// instance the animation does not move keeps [`InstanceDesc::transform`].
    #[must_use]
    pub fn instance_transform_at(&self, instance: usize, animation: usize, time: f32) -> Mat4 {
        let Some(inst) = self.instances.get(instance) else {
            return Mat4::IDENTITY;
        };
        if !self.is_animated(instance, animation) {
            return inst.transform;
        }
        self.chain(instance).fold(Mat4::IDENTITY, |below, node| {
            self.node_transform_at(node, animation, time) * below
        })
    }

    /// Whether animation `animation` moves `camera` (a channel targets its node or one of the
    /// node's ancestors).
    #[must_use]
    pub fn is_camera_animated(&self, camera: &crate::Camera, animation: usize) -> bool {
        let Some(a) = self.animations.get(animation) else {
            return false;
        };
        self.chain_from(camera.node).any(|node| {
            self.nodes[node as usize].matrix.is_none() && a.channels.iter().any(|c| c.node == node)
        })
    }

    /// The camera-to-world transform of `camera` at `time` under animation `animation`: the
    /// product of its node's and its ancestors' animated local transforms. A camera the
    /// animation does not move keeps [`Camera::to_world`](crate::Camera::to_world).
    #[must_use]
    pub fn camera_transform_at(&self, camera: &crate::Camera, animation: usize, time: f32) -> Mat4 {
        if !self.is_camera_animated(camera, animation) {
            return camera.to_world;
        }
        self.chain_from(camera.node)
            .fold(Mat4::IDENTITY, |below, node| {
                self.node_transform_at(node, animation, time) * below
            })
    }

    /// The nodes from an instance's node up to its root (none without a node).
    fn chain(&self, instance: usize) -> impl Iterator<Item = u32> + '_ {
        self.chain_from(self.instances.get(instance).and_then(|i| i.node))
    }

    /// The nodes from `node` up to its root (none without a node). Bounded by the number of
    /// nodes, so that a malformed parent cycle ends.
    fn chain_from(&self, node: Option<u32>) -> impl Iterator<Item = u32> + '_ {
        let start = node.filter(|&n| (n as usize) < self.nodes.len());
        std::iter::successors(start, move |&n| {
            self.nodes[n as usize]
                .parent
                .filter(|&p| (p as usize) < self.nodes.len())
        })
        .take(self.nodes.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channel(property: Property, interpolation: Interpolation, values: Vec<[f32; 4]>) -> Channel {
        let per = if interpolation == Interpolation::CubicSpline {
            3
        } else {
            1
        };
        Channel {
            node: 0,
            property,
            interpolation,
            times: (0..values.len() / per).map(|k| k as f32).collect(),
            values,
        }
    }

    #[test]
    fn sampling_clamps_steps_and_interpolates() {
        let c = channel(
            Property::Translation,
            Interpolation::Linear,
            vec![[0.0; 4], [2.0, 4.0, 0.0, 0.0], [2.0, 0.0, 0.0, 0.0]],
        );
        assert_eq!(c.problem(), None);
        assert_eq!(c.sample(-1.0), Vec4::ZERO);
        assert_eq!(c.sample(0.5), Vec4::new(1.0, 2.0, 0.0, 0.0));
        assert_eq!(c.sample(1.5), Vec4::new(2.0, 2.0, 0.0, 0.0));
        assert_eq!(c.sample(9.0), Vec4::new(2.0, 0.0, 0.0, 0.0));
        assert_eq!(c.sample(f32::NAN), Vec4::ZERO);
        let step = Channel {
            interpolation: Interpolation::Step,
            ..c.clone()
        };
        assert_eq!(step.sample(0.99), Vec4::ZERO);
        assert_eq!(step.sample(1.0), Vec4::new(2.0, 4.0, 0.0, 0.0));
    }

    #[test]
    fn rotations_interpolate_on_the_sphere() {
        let h = std::f32::consts::FRAC_1_SQRT_2;
        // Identity to a half turn about y: halfway is a quarter turn, of unit length.
        let c = channel(
            Property::Rotation,
            Interpolation::Linear,
            vec![[0.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.0, 0.0]],
        );
        let q = Quat::from_vec4(c.sample(0.5));
        assert!((q.length() - 1.0).abs() < 1e-6);
        assert!(q.abs_diff_eq(Quat::from_xyzw(0.0, h, 0.0, h), 1e-6));
    }

    #[test]
    fn cubic_splines_follow_their_tangents() {
        // p(s) with p0 = 0, p1 = 1, both tangents 0 over a 2-second segment: smoothstep.
        let c = Channel {
            node: 0,
            property: Property::Scale,
            interpolation: Interpolation::CubicSpline,
            times: vec![0.0, 2.0],
            values: vec![[0.0; 4], [0.0; 4], [0.0; 4], [0.0; 4], [1.0; 4], [0.0; 4]],
        };
        assert_eq!(c.problem(), None);
        assert!((c.sample(0.5).x - 0.15625).abs() < 1e-6);
        assert!((c.sample(1.0).x - 0.5).abs() < 1e-6);
        // A constant out-tangent of 1 per second on a constant value: the linear term is
        // m0 (s^3 - 2 s^2 + s) with m0 = 1 * dt.
        let mut slope = c.clone();
        slope.values = vec![[0.0; 4], [0.0; 4], [1.0; 4], [0.0; 4], [0.0; 4], [0.0; 4]];
        let s: f32 = 0.25;
        let want = 2.0 * (s.powi(3) - 2.0 * s * s + s);
        assert!((slope.sample(0.5).x - want).abs() < 1e-6);
    }

    #[test]
    fn bad_channels_are_named() {
        let mut c = channel(
            Property::Translation,
            Interpolation::Linear,
            vec![[0.0; 4], [1.0; 4]],
        );
        c.times = vec![1.0, 1.0];
        assert!(c.problem().unwrap().contains("increase"));
        c.times = vec![0.0, f32::INFINITY];
        assert!(c.problem().unwrap().contains("finite"));
        c.times = vec![0.0];
        assert!(c.problem().unwrap().contains("values for 1"));
        c.times.clear();
        assert!(c.problem().is_some());
    }

    #[test]
    fn hierarchies_compose_and_cycles_end() {
        let mut scene = SceneDesc::default();
        scene.meshes.push(Default::default());
        // Node 1 (with the mesh) is a child of node 0, which turns a quarter about z in 1 s.
        scene.nodes.push(NodeDesc::default());
        scene.nodes.push(NodeDesc {
            parent: Some(0),
            translation: Vec3::X,
            ..Default::default()
        });
        scene
            .instances
            .push(InstanceDesc::new(0, Mat4::from_translation(Vec3::X)).at_node(1));
        let h = std::f32::consts::FRAC_1_SQRT_2;
        scene.animations.push(Animation {
            name: "turn".into(),
            channels: vec![Channel {
                node: 0,
                property: Property::Rotation,
                interpolation: Interpolation::Linear,
                times: vec![0.0, 1.0],
                values: vec![[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, h, h]],
            }],
        });
        assert!(scene.is_animated(0, 0));
        assert!(!scene.is_animated(0, 1));
        assert_eq!(scene.keyframes_between(0, 0, 0.0, 1.0), 0);
        assert_eq!(scene.keyframes_between(0, 0, -1.0, 1.0), 1);
        assert_eq!(scene.keyframes_between(0, 0, -1.0, 2.0), 2);
        let p = scene
            .instance_transform_at(0, 0, 1.0)
            .transform_point3(Vec3::ZERO);
        assert!((p - Vec3::Y).length() < 1e-6, "{p}");
        // No such animation: the rest placement.
        assert_eq!(
            scene.instance_transform_at(0, 1, 1.0),
            Mat4::from_translation(Vec3::X)
        );
        // A parent cycle (a malformed scene built by hand) ends.
        scene.nodes[0].parent = Some(1);
        let _ = scene.instance_transform_at(0, 0, 0.5);
        // A node given by a matrix is not animated.
        scene.nodes[0].parent = None;
        scene.nodes[0].matrix = Some(Mat4::IDENTITY);
        assert!(!scene.is_animated(0, 0));
    }

    #[test]
    fn cameras_move_with_their_node_and_its_ancestors() {
        // A camera at (0, 0, 5) on node 1, a child of node 0, which slides along x.
        let mut scene = SceneDesc::default();
        scene.nodes.push(NodeDesc::default());
        scene.nodes.push(NodeDesc {
            parent: Some(0),
            translation: Vec3::new(0.0, 0.0, 5.0),
            ..Default::default()
        });
        let camera = crate::Camera {
            to_world: Mat4::from_translation(Vec3::new(0.0, 0.0, 5.0)),
            yfov: 0.5,
            aspect: None,
            node: Some(1),
        };
        assert!(!scene.is_camera_animated(&camera, 0));
        assert_eq!(scene.camera_transform_at(&camera, 0, 0.5), camera.to_world);
        scene.animations.push(Animation {
            name: "pan".into(),
            channels: vec![Channel {
                node: 0,
                property: Property::Translation,
                interpolation: Interpolation::Linear,
                times: vec![0.0, 1.0],
                values: vec![[1.0, 0.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 0.0]],
            }],
        });
        assert!(scene.is_camera_animated(&camera, 0));
        assert!(!scene.is_camera_animated(&camera, 1));
        let eye = |t: f32| {
            scene
                .camera_transform_at(&camera, 0, t)
                .transform_point3(Vec3::ZERO)
        };
        assert_eq!(eye(0.0), Vec3::new(1.0, 0.0, 5.0));
        assert_eq!(eye(0.75), Vec3::new(-0.5, 0.0, 5.0));
        // A camera on no node, or under no animation, stays where it was placed.
        let free = crate::Camera {
            node: None,
            ..camera
        };
        assert!(!scene.is_camera_animated(&free, 0));
        assert_eq!(scene.camera_transform_at(&camera, 1, 0.75), camera.to_world);
    }
}
