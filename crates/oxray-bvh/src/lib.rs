//! # oxray-bvh
//!
//! Bounding volume hierarchies for every oxray backend. Builders produce one canonical binary
//! BVH ([`Bvh2`]); traversal layouts are derived from it ([`Bvh4`], the 4-wide layout of the
//! CPU backend's SSE and portable kernels, from which the CUDA backend's node layouts are
//! derived in turn; [`Bvh8`], the 8-wide layout of its AVX2 and AVX-512 kernels). Leaf blocks
//! ([`Triangle4`]), sphere records ([`Sphere`]), curve segments ([`CurveSegment`]) and the
//! watertight triangle, robust sphere and exact curve tests live here too, so that every backend
//! intersects primitives with the same arithmetic and finds bit-identical hits.
//!
//! [`GasData`] is a built geometry acceleration structure as data: the layout, the primitives
//! in leaf-slot order and the tables that resolve a hit.
//!
//! ```
//! use oxray_bvh::{build_bvh2, BuildConfig, Bvh4};
//! use oxray_core::Aabb;
//! use glam::Vec3;
//! let boxes: Vec<Aabb> = (0..100)
//!     .map(|i| Aabb::new(Vec3::splat(i as f32), Vec3::splat(i as f32 + 0.5)))
//!     .collect();
//! let bvh2 = build_bvh2(&boxes, &BuildConfig::BALANCED);
//! assert_eq!(bvh2.prim_order.len(), 100);
//! let bvh4 = Bvh4::from(&bvh2);
//! assert!(bvh4.stats().leaves > 0);
//! ```

#![warn(missing_docs)]
// Lane and axis loops index several arrays in step; iterator chains would hide that.
#![allow(clippy::needless_range_loop)]

mod build;
mod bvh2;
mod bvh4;
mod bvh8;
pub mod curve;
pub mod export;
pub mod gas;
pub mod ias;
pub mod memory;
pub mod motion;
mod poly;
mod qbvh8;
pub mod random_access;
mod refit;
mod ribbon;
pub mod sbvh;
pub mod serialize;
pub mod sphere;
mod stats;
pub mod transfer;
pub mod triangle;
pub mod triangle4;
pub mod wide;

pub use build::{build_bvh2, temp_bytes, BuildConfig};
pub use bvh2::{Bvh2, Bvh2Node};
pub use bvh4::{Bvh4, Bvh4Node};
pub use bvh8::{Bvh8, Bvh8Node};
pub use curve::{CurveHit, CurveSegment};
pub use export::{ExportedTriangle, GasExport};
pub use gas::{
    spatial_splits, GasData, GasInfo, GasKind, GasMemory, InputRecord, InputShape, NodeWidth,
    NO_PRIMITIVE,
};
pub use ias::{IasData, InstanceData, PreparedIas, IAS_MAX_LEAF};
pub use memory::{compute_memory_usage, AccelBufferSizes};
pub use motion::GasMotion;
pub use qbvh8::{QBvh8, QBvh8Node};
pub use random_access::NO_SLOT;
pub use sbvh::{build_sbvh2, SpatialSplits};
pub use sphere::Sphere;
pub use stats::BvhStats;
pub use transfer::SlotPrimitives;
pub use triangle4::Triangle4;
pub use wide::WideNode;

/// A traversal stack of this many entries is always enough for a [`Bvh4`]: the builder bounds
/// the depth of [`Bvh2`] by [`MAX_BVH2_DEPTH`], and a 4-wide node pushes at most 3 entries per
/// level.
pub const TRAVERSAL_STACK_SIZE: usize = 3 * MAX_BVH2_DEPTH + 4;

/// The same for a [`Bvh8`] (and for a [`Bvh4`]): an 8-wide node pushes at most 7 entries per
/// level, and its depth is at most the binary tree's.
pub const WIDE_TRAVERSAL_STACK_SIZE: usize = 7 * MAX_BVH2_DEPTH + 8;

/// Past this depth the builder splits at the object median, so that the depth stays within
/// `FORCE_MEDIAN_DEPTH + log2(2^29)`.
pub(crate) const FORCE_MEDIAN_DEPTH: usize = 34;
/// The greatest depth a [`Bvh2`] built by oxray can have (root at depth 0).
pub const MAX_BVH2_DEPTH: usize = FORCE_MEDIAN_DEPTH + 30;

/// A new lineage for a freshly built (or loaded) structure: the identity an update or a
/// compaction keeps (see [`oxray_core::Traversable::lineage`]).
pub fn next_lineage() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static NEXT: AtomicU64 = AtomicU64::new(1);
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// Inputs shared by the unit tests of the layouts.
#[cfg(test)]
pub(crate) mod test_boxes {
    use glam::Vec3;
    use oxray_core::Aabb;

    /// `n` boxes at `offset + [0, size)^3`, each up to `size / 100` a side, from a fixed
    /// linear congruential sequence of `seed`.
    pub(crate) fn random_boxes(n: usize, seed: u64, offset: f32, size: f32) -> Vec<Aabb> {
        let mut s = seed;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        (0..n)
            .map(|_| {
                let p = Vec3::splat(offset) + Vec3::new(next(), next(), next()) * size;
                Aabb::new(p, p + Vec3::new(next(), next(), next()) * size * 0.01)
            })
            .collect()
    }
}
