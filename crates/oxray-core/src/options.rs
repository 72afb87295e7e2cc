//! Build options and flags (guide §5, §5.5) and per-SBT-record geometry flags (§5.1).

use bitflags::bitflags;

bitflags! {
    /// How an acceleration structure is built and what may be done with it later
    /// (`OptixBuildFlags`, guide §5.5). Values match OptiX's.
    #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
    #[doc(alias = "OptixBuildFlags")]
    pub struct BuildFlags: u32 {
        /// Allows a later update (refit) of the structure (§5.6).
        const ALLOW_UPDATE = 1 << 0;
        /// Allows a later compaction (§5.8).
        const ALLOW_COMPACTION = 1 << 1;
        /// Spend more build time for faster traversal. Excludes `PREFER_FAST_BUILD`.
        const PREFER_FAST_TRACE = 1 << 2;
        /// Build faster at some cost in traversal speed. Excludes `PREFER_FAST_TRACE`.
        const PREFER_FAST_BUILD = 1 << 3;
        /// Allows fetching any primitive's vertices from the handle (§13.9).
        const ALLOW_RANDOM_VERTEX_ACCESS = 1 << 4;
        /// Allows fetching an instance's child from an instance AS (§13.12).
        const ALLOW_RANDOM_INSTANCE_ACCESS = 1 << 5;
        /// Allows a different opacity micromap array on update (§5.11).
        const ALLOW_OPACITY_MICROMAP_UPDATE = 1 << 6;
        /// Allows instances to disable opacity micromaps (§5.11).
        const ALLOW_DISABLE_OPACITY_MICROMAPS = 1 << 7;
    }
}

bitflags! {
    /// Flags of one SBT record of a build input (`OptixGeometryFlags`, guide §5.1).
    #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
    #[doc(alias = "OptixGeometryFlags")]
    pub struct GeometryFlags: u32 {
        /// The any-hit program is not called for these primitives: they are opaque, unless an
        /// instance or ray flag enforces any-hit.
        const DISABLE_ANYHIT = 1 << 0;
        /// The any-hit program is called at most once per primitive and ray.
        const REQUIRE_SINGLE_ANYHIT_CALL = 1 << 1;
        /// Triangles of this record are never culled by facing, whatever the ray flags.
        const DISABLE_TRIANGLE_FACE_CULLING = 1 << 2;
    }
}

/// A build or an in-place update of an existing structure (`OptixBuildOperation`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[doc(alias = "OptixBuildOperation")]
pub enum BuildOperation {
    /// Build from scratch.
    #[default]
    Build,
    /// Refit an existing structure built with [`BuildFlags::ALLOW_UPDATE`].
    Update,
}

/// Options of an acceleration-structure build (`OptixAccelBuildOptions`).
///
/// ```
/// use oxray_core::{BuildFlags, BuildOptions};
/// let opts = BuildOptions::new(BuildFlags::PREFER_FAST_TRACE);
/// assert_eq!(opts.flags, BuildFlags::PREFER_FAST_TRACE);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[doc(alias = "OptixAccelBuildOptions")]
pub struct BuildOptions {
    /// Build flags.
    pub flags: BuildFlags,
    /// Build or update.
    pub operation: BuildOperation,
    /// Motion keys and times (`motionOptions`, guide §5.10.1); the default (all zero) is no
    /// motion. A GAS with motion takes one vertex (box, centre and radius) buffer per key; an
    /// IAS's motion affects only which instances vanish outside its range (§5.10.3).
    pub motion: crate::motion::MotionOptions,
}

impl BuildOptions {
    /// A build with the given flags.
    #[must_use]
    pub fn new(flags: BuildFlags) -> Self {
        BuildOptions {
            flags,
            operation: BuildOperation::Build,
            motion: crate::motion::MotionOptions::NONE,
        }
    }

    /// The same options with motion (guide §5.10.1).
    ///
    /// ```
    /// use oxray_core::{BuildFlags, BuildOptions, MotionOptions};
    /// let opts = BuildOptions::new(BuildFlags::empty()).with_motion(MotionOptions::new(2, 0.0, 1.0));
    /// assert_eq!(opts.motion.key_count(), 2);
    /// ```
    #[must_use]
    pub fn with_motion(mut self, motion: crate::motion::MotionOptions) -> Self {
        self.motion = motion;
        self
    }
}

/// A property a build emits (`OptixAccelPropertyType`; guide §5.8, and the OptiX headers'
/// `optixAccelEmitProperty`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[doc(alias = "OptixAccelPropertyType")]
#[doc(alias = "optixAccelEmitProperty")]
pub enum AccelProperty {
    /// The size in bytes of the compacted structure (`OPTIX_PROPERTY_TYPE_COMPACTED_SIZE`);
    /// needs `ALLOW_COMPACTION`.
    CompactedSize,
    /// The box around the structure, one per motion key (`OPTIX_PROPERTY_TYPE_AABBS`).
    Aabbs,
}

/// The value of an emitted [`AccelProperty`].
#[derive(Clone, Debug, PartialEq)]
pub enum EmittedProperty {
    /// Bytes of the compacted structure.
    CompactedSize(u64),
    /// One box per motion key (one without motion).
    Aabbs(Vec<crate::Aabb>),
}
