//! Acceleration structures: build inputs, options, validation, memory queries and the geometry
//! acceleration structure (GAS) itself.

pub mod bvh;
mod gas;
pub mod input;
mod memory;
pub mod options;
pub(crate) mod validate;

pub use gas::{Gas, GasMemory};
pub use memory::{compute_memory_usage, AccelBufferSizes};
pub use validate::{MAX_PRIMITIVES_PER_GAS, MAX_SBT_RECORDS_PER_GAS};
