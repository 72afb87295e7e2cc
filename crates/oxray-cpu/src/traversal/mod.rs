//! Ray traversal, composed from orthogonal parts: node layouts ([`node`]), leaf intersectors
//! ([`leaf`]) and the visitors of queries and the pipeline, joined by one kernel ([`kernel`]);
//! the walk of a traversable graph across instances and transforms ([`scene`]); the
//! per-ray constants ([`ray`]); and batches of rays through one triangle structure ([`batch`]),
//! a small one tested whole, sixteen rays at a time ([`small`]).

mod batch;
mod kernel;
mod leaf;
mod motion;
mod node;
mod packet;
mod prefetch;
mod ray;
mod scene;
mod small;

pub(crate) use batch::triangle_gas_rays;
pub(crate) use kernel::{with_stack, Decision, Entry, GasVisitor, HeldStack};
pub(crate) use packet::{coherent, traverse_gas_packet, PACKET};
pub(crate) use scene::{traverse_node, Level, NodeRef, Path, SceneVisitor};
pub(crate) use small::{applies as small_applies, small_gas_rays};
