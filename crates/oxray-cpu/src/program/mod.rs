//! Programs (guide §6): modules of Rust programs registered under OptiX entry names, the
//! program groups made from them, and the device context each kind of program receives.
//!
//! Each program kind gets its own context type exposing exactly the device functions the guide's
//! §13 table allows it, so calling, say, `trace` from an any-hit program does not compile.

pub(crate) mod context;
mod group;
pub(crate) mod module;
pub(crate) mod trace;

pub use context::{
    AnyHitCtx, ClosestHitCtx, ContinuationCallableCtx, DirectCallableCtx, ExceptionCtx,
    IntersectionCtx, MissCtx, RayGenCtx, TransformListEntry, TransformListKind,
};
pub use group::{HitGroupDesc, ProgramGroup, ProgramGroupKind};
pub use module::{Module, ProgramKind};
pub use trace::TraceRay;

pub(crate) use context::{LaunchShared, Scratch};
pub(crate) use trace::run_raygen;
