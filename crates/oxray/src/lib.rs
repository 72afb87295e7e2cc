//! # oxray
//!
//! A programmable ray-tracing engine that implements the programming model of NVIDIA OptiX 9,
//! with one host API over several backends: the CPU (pure Rust, all cores; the default,
//! everywhere) and CUDA GPUs.
//!
//! A [`Device`] is chosen at run time and every build and query goes through it:
//!
//! ```
//! use oxray::{BuildFlags, BuildOptions, Device, IndexBuffer, Ray, TriangleInput, VertexBuffer};
//! use glam::Vec3;
//!
//! // "cpu" here; "cuda" or "auto" run the same code on a GPU where there is one.
//! let device = Device::from_name("cpu")?;
//!
//! // A unit quad in the z = 0 plane, as two triangles.
//! let vertices = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
//! let triangles = [[0u32, 1, 2], [0, 2, 3]];
//! let input = TriangleInput::new(VertexBuffer::f32x3(&vertices))
//!     .indices(IndexBuffer::u32x3(&triangles));
//! let gas = device.build_gas(&BuildOptions::new(BuildFlags::PREFER_FAST_TRACE), &[input.into()])?;
//!
//! // Closest hits and occlusion of a batch, in parallel.
//! let rays = vec![Ray::new(Vec3::new(0.25, 0.75, 1.0), -Vec3::Z); 1000];
//! let mut hits = vec![None; rays.len()];
//! device.intersect_closest(&gas.handle(), &rays, &mut hits)?;
//! let hit = hits[0].expect("the ray hits the quad");
//! assert_eq!(hit.primitive_index, 1);
//! assert!(hit.hit_kind.is_triangle_front_face());
//! let mut occluded = vec![false; rays.len()];
//! device.intersect_any(&gas.handle(), &rays, &mut occluded)?;
//! assert!(occluded.iter().all(|&o| o));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! The semantics are the guide's: the primitive index carries the input's offset, the SBT-GAS
//! index sums the records of earlier inputs (§7.3.2), hits lie in the closed interval
//! `[tmin, tmax]`, triangles report hit kind `0xFE`/`0xFF` for front/back faces, and
//! triangle intersection is watertight, with bit-identical results on every device.
//!
//! On top sits the programmable pipeline of OptiX (guide chapters 6, 7, 10, 13, 15): a
//! [`Module`] registers programs under entry names (`__raygen__*`, `__closesthit__*`,
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
//! is the idiomatic way to leave the program at once, as OptiX does.
//! Those programs are Rust closures, run by the CPU backend. The same pipeline model through
//! [`Device`] takes CUDA C++ programs written against `optix.h` ([`ModuleSource::CudaCpp`]):
//! the CUDA backend compiles them with NVRTC, the CPU backend with the host's C++ compiler, and
//! both devices trace triangles, custom primitives, built-in spheres and curves and instance
//! graphs with them (motion blur is the CPU's only). See `examples/`: `hello`, `triangle`,
//! `triangle_cpp`, `custom_sphere`, `cutouts`, `instancing`, `spheres`, `hair`,
//! `motion_geometry`, `simple_motion_blur`.
//!
//! The crates behind the facade, each reachable here: [`core`](oxray_core) (neutral types and
//! the backend traits), [`bvh`] (the canonical BVH and its layouts), [`cpu`] (the CPU backend,
//! with per-ray queries and closures), and `cuda` (the CUDA backend, with the `cuda` feature).

#![warn(missing_docs)]

mod accel;
mod device;
pub mod programs;

pub use accel::{Gas, Ias};
pub use device::{Device, DeviceError, RayBatch};
#[cfg(feature = "cuda")]
pub use programs::{ModuleSource, ProgramError};

/// The CPU backend: per-ray queries, any-hit filters and custom-primitive closures on CPU
/// structures, and the program model's types.
pub mod cpu {
    pub use oxray_cpu::*;
}

/// The CUDA backend: its GAS, node layouts, device buffers and kernels.
#[cfg(feature = "cuda")]
pub mod cuda {
    pub use oxray_cuda::*;
}

pub use oxray_bvh as bvh;
pub use oxray_core::{error, exception, sbt, validate};

pub use oxray_core::Aabb;
pub use oxray_core::{
    AabbBuffer, AccelProperty, BackendKind, BatchKind, BufferKind, BuildError, BuildFlags,
    BuildInput, BuildInputKind, BuildOperation, BuildOptions, CandidateAction, CurveEndcaps,
    CurveInput, CurveType, CustomHit, CustomPrimitive, CustomPrimitiveInput, DeviceContext,
    EmittedProperty, ErrorCode, Exception, ExceptionCode, ExceptionFlags, GeometryFlags, Hit,
    HitKind, IndexBuffer, IndexFormat, InputLocation, Instance, InstanceClosestPoint,
    InstanceFlags, KeySample, LaunchError, LaunchReport, LoadError, LogLevel,
    MatrixMotionTransform, MotionFlags, MotionKeyRule, MotionOptions, MotionRule,
    PipelineCompileOptions, PipelineError, PipelineLinkOptions, PrimitiveType, PrimitiveTypeFlags,
    QueryError, RandomAccessError, Ray, RayError, RayFlags, RayRecord, SbtHeader, SbtIndexOffsets,
    SbtIndexSize, SbtRegion, ShaderBindingTable, SphereInput, SrtData, SrtMotionTransform,
    StaticTransform, Transform, Traversable, TraversableGraphFlags, TraversableHandle,
    TraversableKind, TriangleInput, UpdateRule, VertexBuffer, VertexFormat, MAX_INSTANCES_PER_IAS,
    MAX_INSTANCE_ID, MAX_PRIMITIVES_PER_GAS, MAX_SBT_OFFSET, MAX_SBT_RECORDS_PER_GAS,
    MAX_TRAVERSABLE_GRAPH_DEPTH,
};

pub use oxray_bvh::{
    compute_memory_usage, AccelBufferSizes, BvhStats, CurveHit, CurveSegment, ExportedTriangle,
    GasExport, GasMemory, Sphere,
};
pub use oxray_cpu::{
    AllHits, AnyHitCtx, ClosestHitCtx, ClosestPoint, ContinuationCallableCtx, CustomIntersector,
    DirectCallableCtx, ExceptionCtx, HitGroupDesc, Interrupt, IntersectionCtx, MeshError, MissCtx,
    Module, NoCustomPrimitives, NoShadingNormals, OutputBuffer, Pipeline, ProgramGroup,
    ProgramGroupKind, ProgramKind, ProgramResult, RayGenCtx, ShadingNormals, SurfaceHit,
    SurfaceQueryError, TraceRay, TransformListEntry, TransformListKind, VertexNormals,
};

/// The math and plain-data crates the public API uses, at the versions it uses.
pub use bytemuck;
pub use glam;

// The README's examples are compiled and run as doctests of `oxray-render`, which depends on
// this crate and on the renderer that one of them uses.
