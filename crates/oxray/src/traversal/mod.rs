//! Ray traversal: rays, and the kernel that walks a geometry acceleration structure.

mod gas;
mod ray;
mod scene;

pub(crate) use gas::{with_stack, Decision, Entry, GasVisitor};
pub use ray::{Ray, RayError};
pub(crate) use scene::{traverse_node, Level, NodeRef, Path, SceneVisitor};
