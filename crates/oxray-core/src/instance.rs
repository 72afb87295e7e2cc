//! Instances and static transforms (guide §5.4, §5.9).

use crate::aabb::Aabb;
use crate::error::BuildError;
use crate::handle::{BackendKind, Traversable, TraversableHandle, TraversableKind};
use crate::transform::Transform;
use bitflags::bitflags;

bitflags! {
    /// Flags of an instance (`OptixInstanceFlags`, guide §5.4). The flags of the instance
    /// nearest to the geometry override those of its ancestors.
    #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
    #[doc(alias = "OptixInstanceFlags")]
    pub struct InstanceFlags: u32 {
        /// Triangles are never culled by facing, whatever the ray flags.
        const DISABLE_TRIANGLE_FACE_CULLING = 1 << 0;
        /// Clockwise triangles are front-facing.
        const FLIP_TRIANGLE_FACING = 1 << 1;
        /// No any-hit program runs (overrides the geometry flags; the ray's ENFORCE wins).
        const DISABLE_ANYHIT = 1 << 2;
        /// The any-hit program runs even on geometry that disables it (the ray's DISABLE wins).
        const ENFORCE_ANYHIT = 1 << 3;
        /// Accepted for compatibility; oxray has no opacity micromaps yet.
        const FORCE_OPACITY_MICROMAP_2_STATE = 1 << 4;
        /// Accepted for compatibility; oxray has no opacity micromaps yet.
        const DISABLE_OPACITY_MICROMAPS = 1 << 5;
    }
}

/// Largest instance id and SBT offset: 28 bits (guide §12).
pub const MAX_INSTANCE_ID: u32 = (1 << 28) - 1;
/// Largest instance SBT offset: 28 bits (guide §12).
pub const MAX_SBT_OFFSET: u32 = (1 << 28) - 1;
/// Most instances in one IAS (guide §12).
pub const MAX_INSTANCES_PER_IAS: u64 = 1 << 28;
/// Deepest traversable graph (guide §12).
pub const MAX_TRAVERSABLE_GRAPH_DEPTH: u32 = 31;

/// An instance of a traversable (`OptixInstance`).
///
/// ```
/// use oxray_core::{Instance, Transform, TraversableHandle};
/// use glam::Vec3;
/// let instance = Instance::new(TraversableHandle::NULL)
///     .transform(Transform::from_translation(Vec3::X))
///     .instance_id(7)
///     .sbt_offset(2);
/// assert_eq!(instance.visibility_mask, 0xFF);
/// ```
#[derive(Clone, Debug)]
#[doc(alias = "OptixInstance")]
pub struct Instance {
    /// Object-to-world transform.
    pub transform: Transform,
    /// User id (28 bits), returned by `instance_id()`.
    pub instance_id: u32,
    /// Added to the hit-group index of everything below (28 bits).
    pub sbt_offset: u32,
    /// The instance is traversed only if `ray mask & visibility_mask != 0` (8 bits).
    pub visibility_mask: u32,
    /// Flags.
    pub flags: InstanceFlags,
    /// What is instanced (a GAS, an IAS or a transform); the null handle is never hit.
    pub child: TraversableHandle,
}

impl Instance {
    /// An identity instance of `child` with id 0, SBT offset 0 and mask `0xFF`.
    #[must_use]
    pub fn new(child: TraversableHandle) -> Self {
        Instance {
            transform: Transform::IDENTITY,
            instance_id: 0,
            sbt_offset: 0,
            visibility_mask: 0xFF,
            flags: InstanceFlags::empty(),
            child,
        }
    }

    /// Sets the object-to-world transform.
    #[must_use]
    pub fn transform(mut self, t: Transform) -> Self {
        self.transform = t;
        self
    }

    /// Sets the user id.
    #[must_use]
    pub fn instance_id(mut self, id: u32) -> Self {
        self.instance_id = id;
        self
    }

    /// Sets the SBT offset.
    #[must_use]
    pub fn sbt_offset(mut self, offset: u32) -> Self {
        self.sbt_offset = offset;
        self
    }

    /// Sets the visibility mask.
    #[must_use]
    pub fn visibility_mask(mut self, mask: u32) -> Self {
        self.visibility_mask = mask;
        self
    }

    /// Sets the flags.
    #[must_use]
    pub fn flags(mut self, flags: InstanceFlags) -> Self {
        self.flags = flags;
        self
    }
}

/// A static transform (`OptixStaticTransform`): places its child with a fixed transform. The
/// inverse is computed, not trusted from the caller.
#[derive(Clone, Debug)]
#[doc(alias = "OptixStaticTransform")]
pub struct StaticTransform {
    child: TraversableHandle,
    transform: Transform,
    inverse: Transform,
}

impl StaticTransform {
    /// Places `child` with the object-to-world `transform`; refused if it is singular or not
    /// finite, or if the graph would be deeper than 31 levels.
    pub fn new(child: TraversableHandle, transform: Transform) -> Result<Self, BuildError> {
        let inverse = transform
            .inverse()
            .ok_or(BuildError::InvalidTransform { instance: None })?;
        let depth = 1 + child.graph_depth();
        if depth > MAX_TRAVERSABLE_GRAPH_DEPTH {
            return Err(BuildError::GraphTooDeep {
                depth,
                limit: MAX_TRAVERSABLE_GRAPH_DEPTH,
            });
        }
        Ok(StaticTransform {
            child,
            transform,
            inverse,
        })
    }

    /// The object-to-world transform.
    #[must_use]
    pub fn transform(&self) -> &Transform {
        &self.transform
    }

    /// The world-to-object transform (the inverse, computed when it was made).
    #[must_use]
    pub fn inverse(&self) -> &Transform {
        &self.inverse
    }

    /// The child.
    #[must_use]
    pub fn child(&self) -> &TraversableHandle {
        &self.child
    }
}

impl Traversable for StaticTransform {
    fn traversable_kind(&self) -> TraversableKind {
        TraversableKind::StaticTransform
    }

    fn bounds(&self) -> Aabb {
        self.transform.transform_aabb(&self.child.bounds())
    }

    fn graph_depth(&self) -> u32 {
        1 + self.child.graph_depth()
    }

    fn backend(&self) -> BackendKind {
        self.child.backend().unwrap_or(BackendKind::Any)
    }

    fn describe(&self) -> String {
        format!("static transform over {:?}", self.child)
    }
}
