//! Ray traversal: rays, and the kernel that walks a geometry acceleration structure.

mod gas;
mod ray;

pub(crate) use gas::{traverse_gas, Decision, GasVisitor, Primitives};
pub use gas::TraversalStack;
pub use ray::{Ray, RayError};
pub(crate) use ray::PreparedRay;
