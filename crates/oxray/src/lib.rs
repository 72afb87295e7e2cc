//! # oxray
//!
//! A programmable ray-tracing engine that implements the programming model of NVIDIA OptiX 9,
//! with an embedded CPU backend (pure Rust, all cores).
//!
//! This release provides geometry acceleration structures (GAS) over triangles and custom
//! primitives, built from OptiX-style build inputs, and ray queries on them:
//!
//! ```
//! use oxray::{BuildFlags, BuildOptions, Gas, IndexBuffer, Ray, TriangleInput, VertexBuffer};
//! use glam::Vec3;
//!
//! // A unit quad in the z = 0 plane, as two triangles.
//! let vertices = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
//! let triangles = [[0u32, 1, 2], [0, 2, 3]];
//! let input = TriangleInput::new(VertexBuffer::f32x3(&vertices))
//!     .indices(IndexBuffer::u32x3(&triangles));
//! let gas = Gas::build(&BuildOptions::new(BuildFlags::PREFER_FAST_TRACE), &[input.into()])?;
//!
//! // Closest hit of one ray...
//! let ray = Ray::new(Vec3::new(0.25, 0.75, 1.0), -Vec3::Z);
//! let hit = gas.intersect(&ray).expect("the ray hits the quad");
//! assert_eq!(hit.primitive_index, 1);
//! assert!(hit.hit_kind.is_triangle_front_face());
//!
//! // ... and occlusion of a batch, in parallel.
//! let rays = vec![ray; 1000];
//! let mut occluded = vec![false; rays.len()];
//! gas.occluded_batch(&rays, &mut occluded)?;
//! assert!(occluded.iter().all(|&o| o));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! The semantics are the guide's: the primitive index carries the input's offset, the SBT-GAS
//! index sums the records of earlier inputs (§7.3.2), hits lie in the closed interval
//! `[tmin, tmax]`, triangles report hit kind `0xFE`/`0xFF` for front/back faces, and
//! triangle intersection is watertight.
//!
//! On top sits the programmable pipeline of OptiX (guide chapters 6, 7, 10, 13, 15): a
//! [`Module`] registers Rust programs under entry names (`__raygen__*`, `__closesthit__*`,
//! `__anyhit__*`, `__miss__*`, `__intersection__*`, `__exception__*`, `__direct_callable__*`,
//! `__continuation_callable__*`); [`ProgramGroup`]s made from them are linked into a
//! [`Pipeline`] and named by the records of a [`ShaderBindingTable`]; [`Pipeline::launch`] runs
//! the ray-generation program over a 1-, 2- or 3-D grid on all cores. Each program kind receives
//! its own context ([`RayGenCtx`], [`ClosestHitCtx`], [`AnyHitCtx`], [`MissCtx`],
//! [`IntersectionCtx`], [`ExceptionCtx`], [`DirectCallableCtx`], [`ContinuationCallableCtx`])
//! with exactly the device functions the guide's §13 table allows it. Device functions that
//! never return in OptiX (a trace that raises, `optixThrowException`,
//! `optixIgnoreIntersection`, `optixTerminateRay`, a report whose any-hit terminated the ray, a
//! callable that raised) give an [`Interrupt`]. They take effect when called: the runtime
//! honours the first such call of a program once the program returns, whatever it returns, and
//! the program's later device calls do nothing. Passing the interrupt on with `?` (or `return`)
//! is the idiomatic way to leave the program at once, as OptiX does. See `examples/` (`hello`,
//! `triangle`, `custom_sphere`, `cutouts`).

#![warn(missing_docs)]
// Lane and axis loops index several arrays in step; iterator chains would hide that.
#![allow(clippy::needless_range_loop)]

pub mod accel;
pub mod error;
pub mod exception;
pub mod geometry;
mod output;
pub mod pipeline;
pub mod program;
mod query;
pub mod sbt;
pub mod traversal;

pub use accel::input::{
    AabbBuffer, BuildInput, BuildInputKind, CustomPrimitiveInput, IndexBuffer, SbtIndexOffsets,
    SbtIndexSize, TriangleInput, VertexBuffer,
};
pub use accel::options::{BuildFlags, BuildOperation, BuildOptions, GeometryFlags};
pub use accel::{
    compute_memory_usage, AccelBufferSizes, ExportedTriangle, Gas, GasExport, GasMemory, Ias,
    Instance, InstanceFlags, StaticTransform, Transform, TraversableHandle, TraversableKind,
};
pub use error::{BuildError, ErrorCode, LaunchError, PipelineError, QueryError};
pub use exception::{Exception, ExceptionCode, ExceptionFlags, Interrupt, ProgramResult};
pub use geometry::vertex::{IndexFormat, VertexFormat};
pub use geometry::Aabb;
pub use output::OutputBuffer;
pub use pipeline::{
    DeviceContext, LaunchReport, LogLevel, Pipeline, PipelineCompileOptions, PipelineLinkOptions,
    PrimitiveTypeFlags, TraversableGraphFlags,
};
pub use program::{
    AnyHitCtx, ClosestHitCtx, ContinuationCallableCtx, DirectCallableCtx, ExceptionCtx,
    HitGroupDesc, IntersectionCtx, MissCtx, Module, ProgramGroup, ProgramGroupKind, ProgramKind,
    RayFlags, RayGenCtx, TraceRay, TransformListEntry, TransformListKind,
};
pub use query::{
    CandidateAction, CustomHit, CustomIntersector, CustomPrimitive, Hit, HitKind,
    NoCustomPrimitives,
};
pub use sbt::{SbtHeader, SbtRegion, ShaderBindingTable};
pub use traversal::{Ray, RayError};

/// The README's example, compiled and run as a doctest.
#[cfg(doctest)]
#[doc = include_str!("../../../README.md")]
struct ReadmeDoctests;
