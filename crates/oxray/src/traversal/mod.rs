//! Ray traversal: rays, and the kernel that walks a geometry acceleration structure.

mod gas;
mod ray;

pub use gas::TraversalStack;
pub(crate) use gas::{traverse_gas, Decision, GasVisitor, Primitives};
pub(crate) use ray::PreparedRay;
pub use ray::{Ray, RayError};
