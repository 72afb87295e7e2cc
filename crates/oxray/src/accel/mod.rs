//! Acceleration structures: build inputs, options, validation, memory queries and the geometry
//! acceleration structure (GAS) itself.

pub mod bvh;
mod export;
mod gas;
mod handle;
mod ias;
pub mod input;
mod instance;
mod memory;
pub mod options;
mod transform;
pub(crate) mod validate;

pub use export::{ExportedTriangle, GasExport};
pub(crate) use gas::GasKind;
pub use gas::{Gas, GasMemory};
pub(crate) use handle::Traversable;
pub use handle::{TraversableHandle, TraversableKind};
pub use ias::Ias;
pub(crate) use ias::InstanceRecord;
pub use instance::{
    Instance, InstanceFlags, StaticTransform, MAX_INSTANCES_PER_IAS, MAX_INSTANCE_ID,
    MAX_SBT_OFFSET, MAX_TRAVERSABLE_GRAPH_DEPTH,
};
pub use memory::{compute_memory_usage, AccelBufferSizes};
pub use transform::Transform;
pub use validate::{MAX_PRIMITIVES_PER_GAS, MAX_SBT_RECORDS_PER_GAS};
