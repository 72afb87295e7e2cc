//! Ray traversal: the per-ray constants, the kernel that walks one acceleration structure, and
//! the walk of a traversable graph across instances and transforms.

mod gas;
mod ray;
mod scene;

pub(crate) use gas::{with_stack, Decision, Entry, GasVisitor};

pub(crate) use scene::{traverse_node, Level, NodeRef, Path, SceneVisitor};
