//! # oxray-cpu
//!
//! The CPU backend of oxray, the embedded default: acceleration structures in host memory,
//! traversal on all cores, and the programmable pipeline with programs written as Rust
//! closures.
//!
//! - [`Gas`] and [`Ias`] wrap the backend-neutral build data of `oxray-bvh` and implement
//!   [`Traversable`](oxray_core::Traversable), so their handles go wherever a
//!   [`TraversableHandle`](oxray_core::TraversableHandle) goes.
//! - Queries (closest hit, occlusion, any-hit filters, custom-primitive closures, parallel
//!   batches) and the pipeline's `optixTrace` are visitors of one traversal kernel.
//! - [`Cpu`] implements [`AccelBackend`](oxray_core::AccelBackend) for the `oxray` facade's
//!   `Device`.
//! - Traversal runs the SIMD kernel the processor has, chosen once ([`Isa`]: 8-wide nodes with
//!   AVX2 or AVX-512, 4-wide with SSE or NEON; `OXRAY_CPU_ISA` forces one); every kernel finds
//!   bit-identical hits.
//! - The program model: a [`Module`] registers Rust programs under OptiX entry names; each
//!   program kind receives its own context type with exactly the device functions the guide's
//!   §13 table allows it.
//!
//! ```
//! use oxray_cpu::Gas;
//! use oxray_core::{BuildOptions, Ray, TriangleInput, VertexBuffer};
//! use glam::Vec3;
//! let v = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
//! let gas = Gas::build(&BuildOptions::default(), &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()])?;
//! let hit = gas.intersect(&Ray::new(Vec3::Z, -Vec3::Z)).expect("a hit");
//! assert_eq!(hit.t, 1.0);
//! # Ok::<(), oxray_core::BuildError>(())
//! ```

#![warn(missing_docs)]
// Lane and axis loops index several arrays in step; iterator chains would hide that.
#![allow(clippy::needless_range_loop)]

mod backend;
pub mod cxx;
mod gas;
mod ias;
mod interrupt;
mod isa;
mod output;
pub mod pipeline;
pub mod program;
mod query;
pub mod simulation;
mod traversal;

pub use backend::{Cpu, CpuBatch};
pub use gas::Gas;
pub use ias::Ias;
pub use interrupt::{Interrupt, ProgramResult};
pub use isa::{Isa, ISA_ENV};
pub use output::OutputBuffer;
pub use pipeline::Pipeline;
pub use program::{
    AnyHitCtx, ClosestHitCtx, ContinuationCallableCtx, DirectCallableCtx, ExceptionCtx,
    HitGroupDesc, IntersectionCtx, MissCtx, Module, ProgramGroup, ProgramGroupKind, ProgramKind,
    RayGenCtx, TraceRay, TransformListEntry, TransformListKind,
};
pub use query::{CustomIntersector, NoCustomPrimitives};
pub use simulation::{
    AllHits, ClosestPoint, MeshError, NoShadingNormals, ShadingNormals, SurfaceHit,
    SurfaceQueryError, VertexNormals,
};

// The neutral types, nameable as `crate::X` in every module.
#[allow(unused_imports)]
use oxray_core::{
    Aabb, CandidateAction, CustomHit, CustomPrimitive, DeviceContext, Exception, ExceptionCode,
    Hit, HitKind, InstanceFlags, LaunchError, LogLevel, PipelineError, QueryError, Ray, RayFlags,
    Transform,
};
