//! # oxray-core
//!
//! The backend-neutral half of oxray: what a user hands to any backend and what any backend
//! hands back. Build inputs are borrowed bytes with their formats ([`BuildInput`]), validated
//! once here ([`validate`]); options, rays and hits, instances and opaque traversable handles,
//! the shader binding table, exceptions and typed errors carrying the guide's `OptixResult`
//! codes; and the [`AccelBackend`] trait that the CPU and CUDA backends implement.
//!
//! Users depend on the `oxray` facade, which re-exports all of this; backends depend on this
//! crate and on `oxray-bvh`.
//!
//! ```
//! use oxray_core::{validate, BuildOptions, IndexBuffer, TriangleInput, VertexBuffer};
//! let vertices = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]];
//! let triangles = [[0u32, 1, 2]];
//! let input = TriangleInput::new(VertexBuffer::f32x3(&vertices))
//!     .indices(IndexBuffer::u32x3(&triangles));
//! let summary = validate::validate_structure(&BuildOptions::default(), &[input.into()])?;
//! assert_eq!(summary.num_primitives, 1);
//! # Ok::<(), oxray_core::BuildError>(())
//! ```

#![warn(missing_docs)]

pub mod aabb;
pub mod backend;
pub mod cache;
pub mod curve;
pub mod error;
pub mod exception;
pub mod handle;
pub mod hit;
pub mod input;
pub mod instance;
pub mod motion;
pub mod motion_transform;
pub mod options;
pub mod pipeline;
pub mod ray;
pub mod sbt;
pub mod simulation;
pub mod source;
pub mod transform;
pub mod validate;
pub mod vertex;

pub use aabb::Aabb;
pub use backend::{AccelBackend, BatchKind};
pub use curve::{CurveEndcaps, CurveInput, CurveType};
pub use error::{
    BufferKind, BuildError, ErrorCode, InputLocation, LaunchError, LoadError, PipelineError,
    QueryError, RandomAccessError, UpdateRule,
};
pub use exception::{Exception, ExceptionCode, ExceptionFlags};
pub use handle::{
    BackendKind, Traversable, TraversableHandle, TraversableKind, WeakTraversableHandle,
};
pub use hit::{CandidateAction, CustomHit, CustomPrimitive, Hit, HitKind, PrimitiveType};
pub use input::{
    AabbBuffer, BuildInput, BuildInputKind, CustomPrimitiveInput, IndexBuffer, SbtIndexOffsets,
    SbtIndexSize, SphereInput, TriangleInput, VertexBuffer,
};
pub use instance::{
    Instance, InstanceFlags, StaticTransform, MAX_INSTANCES_PER_IAS, MAX_INSTANCE_ID,
    MAX_SBT_OFFSET, MAX_TRAVERSABLE_GRAPH_DEPTH,
};
pub use motion::{KeySample, MotionFlags, MotionOptions, MotionRule};
pub use motion_transform::{MatrixMotionTransform, MotionKeyRule, SrtData, SrtMotionTransform};
pub use options::{
    AccelProperty, BuildFlags, BuildOperation, BuildOptions, EmittedProperty, GeometryFlags,
};
pub use pipeline::{
    DeviceContext, LaunchReport, LogLevel, PipelineCompileOptions, PipelineLinkOptions,
    PrimitiveTypeFlags, RayFlags, TraversableGraphFlags,
};
pub use ray::{Ray, RayError, RayRecord};
pub use sbt::{SbtHeader, SbtRegion, ShaderBindingTable};
pub use simulation::{
    AllHits, ClosestPoint, InstanceClosestPoint, NoShadingNormals, ShadingNormals, SurfaceHit,
    SurfaceQueryError,
};
pub use transform::Transform;
pub use validate::{MAX_PRIMITIVES_PER_GAS, MAX_SBT_RECORDS_PER_GAS};
pub use vertex::{IndexFormat, VertexFormat};
