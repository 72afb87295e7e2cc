//! Bounding volume hierarchies: the canonical binary BVH that the builder produces ([`Bvh2`])
//! and the 4-wide layout that CPU traversal uses ([`Bvh4`]), converted from it.

mod build;
mod bvh2;
mod bvh4;
mod stats;

pub use build::BuildConfig;
pub(crate) use build::{build_bvh2, temp_bytes};
pub use bvh2::{Bvh2, Bvh2Node};
pub use bvh4::{Bvh4, Bvh4Node};
pub use stats::BvhStats;

/// A traversal stack of this many entries is always enough: the builder bounds the depth of
/// [`Bvh2`] by [`MAX_BVH2_DEPTH`], and a 4-wide node pushes at most 3 entries per level.
pub const TRAVERSAL_STACK_SIZE: usize = 3 * MAX_BVH2_DEPTH + 4;

/// Past this depth the builder splits at the object median, so that the depth stays within
/// `FORCE_MEDIAN_DEPTH + log2(2^29)`.
pub(crate) const FORCE_MEDIAN_DEPTH: usize = 34;
/// The greatest depth a [`Bvh2`] built by oxray can have (root at depth 0).
pub const MAX_BVH2_DEPTH: usize = FORCE_MEDIAN_DEPTH + 30;
