//! The device context of each program kind (guide §13): launch index and dimensions, launch
//! parameters, SBT data, payload, ray and hit queries, and tracing where the kind may trace.

use crate::interrupt::{Interrupt, InterruptKind, ProgramResult};
use crate::pipeline::PipelineShared;
use crate::program::trace::{self, HitState, Placement, RayState, TraceRay};
use crate::traversal::{Level, Path};
use bytemuck::Pod;
use glam::Vec3;
use oxray_core::sbt::{ShaderBindingTable, SBT_RECORD_HEADER_SIZE};
use oxray_core::{Exception, ExceptionCode, HitKind, PrimitiveType};
use std::cell::Cell;

/// What a transform-list entry is (`OptixTransformType`, with the instance's ids).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[doc(alias = "OptixTransformType")]
pub enum TransformListKind {
    /// An instance of an IAS.
    Instance {
        /// Its user id.
        instance_id: u32,
        /// Its position in the IAS's build input.
        instance_index: u32,
    },
    /// A static transform.
    StaticTransform,
    /// A matrix motion transform (guide §5.10.4); the entry's matrices are those at the ray's
    /// time.
    MatrixMotionTransform,
    /// An SRT motion transform (guide §5.10.5); the entry's matrices are those at the ray's
    /// time.
    SrtMotionTransform,
}

/// One entry of the transform list of the current hit (guide §13.11).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TransformListEntry {
    /// What the entry is.
    pub kind: TransformListKind,
    /// Its object-to-world transform.
    pub object_to_world: crate::Transform,
    /// Its world-to-object transform.
    pub world_to_object: crate::Transform,
}

/// What every program of one launch shares.
pub(crate) struct LaunchShared<'a, P> {
    pub pipeline: &'a PipelineShared<P>,
    pub params: &'a P,
    pub sbt: &'a ShaderBindingTable,
    /// Pipeline group index of every miss and hit-group record.
    pub miss_groups: &'a [usize],
    pub hit_groups: &'a [usize],
    /// Pipeline group index of the exception record, if any.
    pub exception_group: Option<usize>,
    /// Pipeline group index of every callables record.
    pub callable_groups: &'a [usize],
    pub dims: [u32; 3],
}

/// Where a program runs: its launch, launch index and SBT record.
pub(crate) struct Frame<'a, P> {
    pub launch: &'a LaunchShared<'a, P>,
    pub index: [u32; 3],
    /// Bytes of the current program's SBT record.
    pub record: &'a [u8],
    /// Trace nesting depth of the program (0 for ray generation).
    pub depth: u32,
    /// Callable nesting depth.
    pub calls: u32,
    /// What the thread running the index keeps for it.
    pub scratch: &'a Scratch,
}

/// What a thread keeps for the launch indices it runs in a row.
pub(crate) struct Scratch {
    /// The count of traces (`optixTrace` calls at every depth), for the launch report.
    pub traces: std::cell::Cell<u64>,
    /// The thread's traversal stack.
    pub stack: crate::traversal::HeldStack,
}

impl<P> Clone for Frame<'_, P> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<P> Copy for Frame<'_, P> {}

/// The first device call of one program invocation that, in OptiX, never returns (guide §13.13,
/// §13.14): `optixIgnoreIntersection`, `optixTerminateRay`, `optixThrowException`, a trace or a
/// callable that raised, a report whose any-hit terminated the ray. It is recorded at the call,
/// so that the runtime honours it once the program returns, whatever the program returns; and
/// later device calls of the same program give it back without doing anything (in OptiX they
/// are never reached). A cell in the program's context: no allocation, no lock.
#[derive(Default)]
pub(crate) struct NoReturn(Cell<Option<Interrupt>>);

impl NoReturn {
    /// The recorded interrupt, if a device call of the program did not return.
    #[inline]
    pub fn get(&self) -> Option<Interrupt> {
        self.0.get()
    }

    /// Whether a device call of the program did not return.
    #[inline]
    pub fn is_set(&self) -> bool {
        self.0.get().is_some()
    }

    /// Runs a device call unless an earlier one did not return (that one is given back), and
    /// records the interrupt the call gives, if any.
    #[inline]
    pub fn call<T>(&self, f: impl FnOnce() -> Result<T, Interrupt>) -> Result<T, Interrupt> {
        if let Some(i) = self.0.get() {
            return Err(i);
        }
        let r = f();
        if let Err(i) = r {
            self.0.set(Some(i));
        }
        r
    }

    /// What the program's run amounts to: the recorded interrupt, which came first, wins over
    /// what the program returned.
    #[inline]
    pub fn outcome<T>(&self, returned: Result<T, Interrupt>) -> Result<T, Interrupt> {
        match self.0.get() {
            Some(i) => Err(i),
            None => returned,
        }
    }
}

impl<'a, P> Frame<'a, P> {
    fn sbt_data<T: Pod>(&self) -> Option<T> {
        let d = self
            .record
            .get(SBT_RECORD_HEADER_SIZE..SBT_RECORD_HEADER_SIZE + std::mem::size_of::<T>())?;
        Some(bytemuck::pod_read_unaligned(d))
    }

    pub(crate) fn throw(&self, code: i32, details: &[u32]) -> ProgramResult {
        // Only user codes may be thrown; anything else is clamped into the user range's
        // complement so it cannot impersonate a built-in exception.
        let code = if (0..=ExceptionCode::MAX_USER).contains(&code) {
            code
        } else {
            ExceptionCode::MAX_USER
        };
        Err(Interrupt::exception(ExceptionCode(code), details))
    }
}

macro_rules! common_queries {
    () => {
        /// `optixGetLaunchIndex`.
        #[doc(alias = "optixGetLaunchIndex")]
        pub fn launch_index(&self) -> [u32; 3] {
            self.frame.index
        }

        /// `optixGetLaunchDimensions`.
        #[doc(alias = "optixGetLaunchDimensions")]
        pub fn launch_dimensions(&self) -> [u32; 3] {
            self.frame.launch.dims
        }

        /// The launch parameters (copied at launch, guide §10).
        pub fn params(&self) -> &P {
            self.frame.launch.params
        }

        /// The data of this program's SBT record (`optixGetSbtDataPointer`), read as `T`;
        /// `None` if the record is shorter than the header plus `T`.
        #[doc(alias = "optixGetSbtDataPointer")]
        pub fn sbt_data<T: Pod>(&self) -> Option<T> {
            self.frame.sbt_data()
        }

        /// The raw bytes of this program's SBT record after the 32-byte header.
        pub fn sbt_data_bytes(&self) -> &[u8] {
            &self.frame.record[SBT_RECORD_HEADER_SIZE..]
        }
    };
}

macro_rules! throw_fn {
    () => {
        /// `optixThrowException`: raises user exception `code` (in `0..2^30`; other values are
        /// clamped to `2^30 - 1`) with up to eight detail words. It takes effect when called:
        /// the launch index ends when this program returns, whatever it returns, and the
        /// exception program runs; later device calls of this program do nothing. Leave the
        /// program at once with `?` or `return` (the idiomatic way: in OptiX the call never
        /// returns).
        #[doc(alias = "optixThrowException")]
        pub fn throw_exception(&self, code: i32, details: &[u32]) -> ProgramResult {
            self.no_return.call(|| self.frame.throw(code, details))
        }
    };
}

macro_rules! direct_call_fn {
    () => {
        /// `optixDirectCall`: runs the direct callable of callables record `sbt_index` with
        /// `args`, returning its result. `A` and `R` must be the types it was registered with
        /// (otherwise `CALLABLE_PARAMETER_MISMATCH`); a bad index raises `CALLABLE_INVALID_SBT`.
        /// If the call raises (here or in the callable, even if the callable dropped the
        /// interrupt), an [`Interrupt`] comes back and takes effect as
        /// [`throw_exception`](Self::throw_exception) does: pass it on with `?`.
        #[doc(alias = "optixDirectCall")]
        pub fn direct_call<A: 'static, R: 'static>(
            &self,
            sbt_index: u32,
            args: A,
        ) -> Result<R, Interrupt> {
            self.no_return
                .call(|| trace::direct_call(self.frame, sbt_index, args))
        }
    };
}

macro_rules! continuation_call_fn {
    () => {
        /// `optixContinuationCall`: runs the continuation callable of callables record
        /// `sbt_index` with `args`; it may trace. If the call raises, an [`Interrupt`] comes
        /// back and takes effect as [`throw_exception`](Self::throw_exception) does: pass it on
        /// with `?`.
        #[doc(alias = "optixContinuationCall")]
        pub fn continuation_call<A: 'static, R: 'static>(
            &self,
            sbt_index: u32,
            args: A,
        ) -> Result<R, Interrupt> {
            self.no_return
                .call(|| trace::continuation_call(self.frame, sbt_index, args))
        }
    };
}

macro_rules! ray_queries {
    ($ray:ident) => {
        /// `optixGetWorldRayOrigin`.
        #[doc(alias = "optixGetWorldRayOrigin")]
        pub fn world_ray_origin(&self) -> Vec3 {
            self.$ray.origin
        }
        /// `optixGetWorldRayDirection`.
        #[doc(alias = "optixGetWorldRayDirection")]
        pub fn world_ray_direction(&self) -> Vec3 {
            self.$ray.direction
        }
        /// `optixGetRayTmin`: the trace's tmin.
        #[doc(alias = "optixGetRayTmin")]
        pub fn ray_tmin(&self) -> f32 {
            self.$ray.tmin
        }
        /// `optixGetRayTime` (0 in a pipeline without motion blur).
        #[doc(alias = "optixGetRayTime")]
        pub fn ray_time(&self) -> f32 {
            self.$ray.time
        }
        /// `optixGetRayFlags`.
        #[doc(alias = "optixGetRayFlags")]
        pub fn ray_flags(&self) -> crate::RayFlags {
            self.$ray.flags
        }
        /// `optixGetRayVisibilityMask`.
        #[doc(alias = "optixGetRayVisibilityMask")]
        pub fn ray_visibility_mask(&self) -> u8 {
            self.$ray.mask
        }
    };
}

macro_rules! payload_fns {
    () => {
        /// `optixGetPayload_i`. Words past the trace's payload read as 0.
        #[doc(alias = "optixGetPayload_i")]
        pub fn payload(&self, i: usize) -> u32 {
            self.payload.get(i).copied().unwrap_or(0)
        }
        /// `optixSetPayload_i`. Words past the trace's payload are ignored, and so are writes
        /// after a device call that does not return (in OptiX they are never reached).
        #[doc(alias = "optixSetPayload_i")]
        pub fn set_payload(&mut self, i: usize, v: u32) {
            if self.no_return.is_set() {
                return;
            }
            if let Some(p) = self.payload.get_mut(i) {
                *p = v;
            }
        }
        /// Payload word `i` as an `f32`.
        pub fn payload_f32(&self, i: usize) -> f32 {
            f32::from_bits(self.payload(i))
        }
        /// Sets payload word `i` to an `f32`.
        pub fn set_payload_f32(&mut self, i: usize, v: f32) {
            self.set_payload(i, v.to_bits())
        }
        /// Payload words `i..i + 3` as a vector of three `f32`.
        pub fn payload_vec3(&self, i: usize) -> Vec3 {
            Vec3::new(
                self.payload_f32(i),
                self.payload_f32(i + 1),
                self.payload_f32(i + 2),
            )
        }
        /// Sets payload words `i..i + 3` to a vector of three `f32`.
        pub fn set_payload_vec3(&mut self, i: usize, v: Vec3) {
            for (k, c) in v.to_array().into_iter().enumerate() {
                self.set_payload_f32(i + k, c);
            }
        }
        /// The payload words of the current trace.
        pub fn payload_words(&self) -> &[u32] {
            self.payload
        }
    };
}

macro_rules! transform_queries {
    ($hit:ident) => {
        /// Entry `i` of the transform list (`optixGetTransformListHandle` and the queries on
        /// its handle): index 0 is the level nearest the root. `None` past the list.
        #[doc(alias = "optixGetTransformListHandle")]
        pub fn transform_list_entry(&self, i: u32) -> Option<TransformListEntry> {
            let level = self.path?.levels().nth(i as usize)?;
            Some(match level {
                Level::Instance(inst) => TransformListEntry {
                    kind: TransformListKind::Instance {
                        instance_id: inst.instance_id,
                        instance_index: inst.index,
                    },
                    object_to_world: inst.object_to_world,
                    world_to_object: inst.world_to_object,
                },
                Level::Static(st) => TransformListEntry {
                    kind: TransformListKind::StaticTransform,
                    object_to_world: *st.transform(),
                    world_to_object: *st.inverse(),
                },
                Level::MatrixMotion(..) => TransformListEntry {
                    kind: TransformListKind::MatrixMotionTransform,
                    object_to_world: level.object_to_world(),
                    world_to_object: level.world_to_object(),
                },
                Level::SrtMotion(..) => TransformListEntry {
                    kind: TransformListKind::SrtMotionTransform,
                    object_to_world: level.object_to_world(),
                    world_to_object: level.world_to_object(),
                },
            })
        }

        /// `optixGetMatrixMotionTransformFromHandle` on entry `i` of the transform list: the
        /// traversable, with its keys and motion options (guide §13.11). `None` if the entry
        /// is not a matrix motion transform.
        #[doc(alias = "optixGetMatrixMotionTransformFromHandle")]
        pub fn matrix_motion_transform(
            &self,
            i: u32,
        ) -> Option<&oxray_core::MatrixMotionTransform> {
            match self.path?.levels().nth(i as usize)? {
                Level::MatrixMotion(m, _) => Some(m),
                _ => None,
            }
        }

        /// `optixGetSRTMotionTransformFromHandle` on entry `i` of the transform list: the
        /// traversable, with its keys and motion options (guide §13.11). `None` if the entry
        /// is not an SRT motion transform.
        #[doc(alias = "optixGetSRTMotionTransformFromHandle")]
        pub fn srt_motion_transform(&self, i: u32) -> Option<&oxray_core::SrtMotionTransform> {
            match self.path?.levels().nth(i as usize)? {
                Level::SrtMotion(m, _) => Some(m),
                _ => None,
            }
        }

        /// `optixGetTransformListSize`: transforms (instances and static transforms) between
        /// world and object space.
        #[doc(alias = "optixGetTransformListSize")]
        pub fn transform_list_size(&self) -> u32 {
            self.place.levels
        }
        /// `optixGetObjectToWorldTransformMatrix`: the composed object-to-world transform.
        #[doc(alias = "optixGetObjectToWorldTransformMatrix")]
        pub fn object_to_world_transform(&self) -> crate::Transform {
            self.place.object_to_world()
        }
        /// `optixGetWorldToObjectTransformMatrix`: the composed world-to-object transform.
        #[doc(alias = "optixGetWorldToObjectTransformMatrix")]
        pub fn world_to_object_transform(&self) -> crate::Transform {
            self.place.world_to_object()
        }
        /// `optixTransformPointFromObjectToWorldSpace`.
        #[doc(alias = "optixTransformPointFromObjectToWorldSpace")]
        pub fn transform_point_to_world(&self, p: Vec3) -> Vec3 {
            self.place.object_to_world().transform_point(p)
        }
        /// `optixTransformVectorFromObjectToWorldSpace`.
        #[doc(alias = "optixTransformVectorFromObjectToWorldSpace")]
        pub fn transform_vector_to_world(&self, v: Vec3) -> Vec3 {
            self.place.object_to_world().transform_vector(v)
        }
        /// `optixTransformNormalFromObjectToWorldSpace` (inverse transpose).
        #[doc(alias = "optixTransformNormalFromObjectToWorldSpace")]
        pub fn transform_normal_to_world(&self, n: Vec3) -> Vec3 {
            crate::Transform::transform_normal_with_inverse(&self.place.world_to_object(), n)
        }
        /// `optixTransformPointFromWorldToObjectSpace`.
        #[doc(alias = "optixTransformPointFromWorldToObjectSpace")]
        pub fn transform_point_to_object(&self, p: Vec3) -> Vec3 {
            self.place.world_to_object().transform_point(p)
        }
        /// `optixTransformVectorFromWorldToObjectSpace`.
        #[doc(alias = "optixTransformVectorFromWorldToObjectSpace")]
        pub fn transform_vector_to_object(&self, v: Vec3) -> Vec3 {
            self.place.world_to_object().transform_vector(v)
        }
        /// `optixTransformNormalFromWorldToObjectSpace` (inverse transpose).
        #[doc(alias = "optixTransformNormalFromWorldToObjectSpace")]
        pub fn transform_normal_to_object(&self, n: Vec3) -> Vec3 {
            crate::Transform::transform_normal_with_inverse(&self.place.object_to_world(), n)
        }
    };
}

macro_rules! hit_queries {
    ($hit:ident) => {
        /// `optixGetPrimitiveIndex`: index within the build input plus its offset.
        #[doc(alias = "optixGetPrimitiveIndex")]
        pub fn primitive_index(&self) -> u32 {
            self.$hit.primitive_index
        }
        /// `optixGetSbtGASIndex`.
        #[doc(alias = "optixGetSbtGASIndex")]
        pub fn sbt_gas_index(&self) -> u32 {
            self.$hit.sbt_gas_index
        }
        /// `optixGetInstanceId`: the user id of the instance nearest to the geometry; `!0` when
        /// there is no instance (a GAS traced directly: guide §13.7; the OptiX 9.0 header says
        /// 0, oxray follows the guide).
        #[doc(alias = "optixGetInstanceId")]
        pub fn instance_id(&self) -> u32 {
            self.place.instance_id
        }
        /// `optixGetInstanceIndex`: that instance's position in its IAS's build input; 0 when
        /// there is no instance.
        #[doc(alias = "optixGetInstanceIndex")]
        pub fn instance_index(&self) -> u32 {
            self.place.instance_index
        }
        transform_queries!($hit);
        /// `optixGetHitKind`.
        #[doc(alias = "optixGetHitKind")]
        pub fn hit_kind(&self) -> HitKind {
            self.$hit.hit_kind
        }
        /// `optixIsFrontFaceHit`: the front face of a built-in primitive (a triangle, or a
        /// sphere, whose hits are always front-face hits: guide §9.4); false for a custom one.
        #[doc(alias = "optixIsFrontFaceHit")]
        pub fn is_front_face_hit(&self) -> bool {
            self.$hit.hit_kind.is_front_face()
        }
        /// `optixIsBackFaceHit`: the back face of a built-in primitive (only triangles have
        /// back-face hits); false for a custom one.
        #[doc(alias = "optixIsBackFaceHit")]
        pub fn is_back_face_hit(&self) -> bool {
            self.$hit.hit_kind.is_back_face()
        }
        /// `optixGetPrimitiveType`: triangle, sphere, a curve type or custom (guide §13.7).
        #[doc(alias = "optixGetPrimitiveType")]
        pub fn primitive_type(&self) -> PrimitiveType {
            self.$hit.hit_kind.primitive_type()
        }
        /// `optixGetSphereData`: the object-space centre and radius `(x, y, z, r)` of the hit
        /// sphere (guide §9.4; no build flag needed). Zeros for another primitive type.
        #[doc(alias = "optixGetSphereData")]
        pub fn sphere_data(&self) -> [f32; 4] {
            // A sphere with motion is the one at the ray's time (guide §5.10.2).
            match self
                .gas
                .and_then(|g| g.sphere_at(self.$hit.slot as usize, self.ray.time))
            {
                Some(s) => s.to_array(),
                None => [0.0; 4],
            }
        }
        /// `optixGetCurveParameter`: the hit's `u` in its curve segment, exactly 0 or 1 on a
        /// flat end cap (guide §9.3). 0 when the hit is not a curve.
        #[doc(alias = "optixGetCurveParameter")]
        pub fn curve_parameter(&self) -> f32 {
            match self.$hit.hit_kind.primitive_type() {
                PrimitiveType::Curve(_) => f32::from_bits(self.$hit.attributes[0]),
                _ => 0.0,
            }
        }
        /// `optixGetRibbonParameters`: a ribbon hit's `(u, v)`, `v ∈ [-1, 1]` across the
        /// ribbon (guide §9.3). Zeros when the hit is not a ribbon.
        #[doc(alias = "optixGetRibbonParameters")]
        pub fn ribbon_parameters(&self) -> [f32; 2] {
            match self.$hit.hit_kind.primitive_type() {
                PrimitiveType::Curve(c) if c.is_ribbon() => [
                    f32::from_bits(self.$hit.attributes[0]),
                    f32::from_bits(self.$hit.attributes[1]),
                ],
                _ => [0.0; 2],
            }
        }
        /// The control points `(x, y, z, radius)` of the hit curve segment in object space, as
        /// `optixGetLinearCurveVertexData`, `optixGetQuadraticBSplineVertexData`,
        /// `optixGetCubicBSplineVertexData`, `optixGetCatmullRomVertexData`,
        /// `optixGetCubicBezierVertexData`, their Rocaps variants and
        /// `optixGetRibbonVertexData` give them (guide §9.3; no build flag needed): as many as
        /// the type has (2, 3 or 4), then zeros. Zeros when the hit is not a curve.
        #[doc(alias = "optixGetLinearCurveVertexData")]
        #[doc(alias = "optixGetQuadraticBSplineVertexData")]
        #[doc(alias = "optixGetCubicBSplineVertexData")]
        #[doc(alias = "optixGetCatmullRomVertexData")]
        #[doc(alias = "optixGetCubicBezierVertexData")]
        #[doc(alias = "optixGetRibbonVertexData")]
        pub fn curve_vertex_data(&self) -> [[f32; 4]; 4] {
            // A segment with motion is the one at the ray's time (guide §5.10.2).
            match self.hit_curve() {
                Some(s) => s.points,
                None => [[0.0; 4]; 4],
            }
        }
        /// `optixGetRibbonNormal`: the unit geometric normal, in object space, of the hit
        /// ribbon at `ribbon_parameters` (usually [`ribbon_parameters`](Self::ribbon_parameters)),
        /// pointing out of its front face (guide §9.3; see
        /// [`CurveSegment::ribbon_normal`](oxray_bvh::CurveSegment::ribbon_normal)). Zero when
        /// the hit is not a ribbon.
        #[doc(alias = "optixGetRibbonNormal")]
        pub fn ribbon_normal(&self, ribbon_parameters: [f32; 2]) -> Vec3 {
            match self.hit_curve() {
                Some(s) => s.ribbon_normal(
                    ribbon_parameters[0],
                    ribbon_parameters[1],
                    self.place.object_direction,
                ),
                None => Vec3::ZERO,
            }
        }
        /// The hit curve segment at the ray's time; `None` when the hit is not a curve.
        fn hit_curve(&self) -> Option<oxray_bvh::CurveSegment> {
            self.gas
                .filter(|g| g.kind == oxray_bvh::GasKind::Curves)
                .and_then(|g| g.curve_at(self.$hit.slot as usize, self.ray.time))
        }
        /// `optixGetGASMotionTimeBegin`, `…TimeEnd` and `…StepCount` of the hit's GAS
        /// (guide §13.10): its motion options (the default, no motion, for a static GAS).
        #[doc(alias = "optixGetGASMotionTimeBegin")]
        pub fn gas_motion_options(&self) -> oxray_core::MotionOptions {
            self.gas
                .map_or(oxray_core::MotionOptions::NONE, |g| g.motion_options())
        }
        /// `optixIsTriangleHit`.
        #[doc(alias = "optixIsTriangleHit")]
        pub fn is_triangle_hit(&self) -> bool {
            self.$hit.hit_kind.0 >= 0xFE
        }
        /// `optixGetAttribute_i` (0 past the reported attributes).
        #[doc(alias = "optixGetAttribute_i")]
        pub fn attribute(&self, i: usize) -> u32 {
            self.$hit.attributes.get(i).copied().unwrap_or(0)
        }
        /// `optixGetTriangleVertexData`: the object-space vertices of the hit triangle (zeros
        /// for a custom primitive).
        #[doc(alias = "optixGetTriangleVertexData")]
        pub fn triangle_vertex_data(&self) -> [Vec3; 3] {
            // A triangle with motion is the one at the ray's time, interpolated as traversal
            // interpolated it (guide §13.9).
            let slot = self.$hit.slot as usize;
            match self.gas.and_then(|g| g.triangle_at(slot, self.ray.time)) {
                Some(t) => t.map(Vec3::from),
                None => [Vec3::ZERO; 3],
            }
        }
        /// `optixGetTriangleBarycentrics`: attributes 0 and 1 as floats.
        #[doc(alias = "optixGetTriangleBarycentrics")]
        pub fn triangle_barycentrics(&self) -> [f32; 2] {
            [
                f32::from_bits(self.attribute(0)),
                f32::from_bits(self.attribute(1)),
            ]
        }
    };
}

/// The context of a ray-generation program.
pub struct RayGenCtx<'a, P> {
    pub(crate) frame: Frame<'a, P>,
    pub(crate) no_return: NoReturn,
}

impl<P> RayGenCtx<'_, P> {
    common_queries!();
    throw_fn!();
    direct_call_fn!();
    continuation_call_fn!();

    /// `optixTrace`: traces a ray with `payload` as the payload words (copied in, and out when
    /// the trace returns). An exception raised by the trace comes back as an [`Interrupt`]; it
    /// takes effect as [`throw_exception`](Self::throw_exception) does (the launch index ends
    /// even if the program drops it): pass it on with `?`.
    #[doc(alias = "optixTrace")]
    pub fn trace(&self, ray: &TraceRay<'_>, payload: &mut [u32]) -> ProgramResult {
        self.no_return
            .call(|| trace::trace(self.frame, ray, payload))
    }
}

/// The context of a closest-hit program.
pub struct ClosestHitCtx<'a, P> {
    pub(crate) frame: Frame<'a, P>,
    // Borrowed from the trace (not copied): a closest-hit program runs once per trace.
    pub(crate) ray: &'a RayState,
    pub(crate) hit: &'a HitState,
    pub(crate) payload: &'a mut [u32],
    pub(crate) path: Option<&'a Path<'a>>,
    pub(crate) gas: Option<&'a crate::Gas>,
    pub(crate) place: &'a Placement,
    pub(crate) no_return: NoReturn,
}

impl<P> ClosestHitCtx<'_, P> {
    common_queries!();
    throw_fn!();
    direct_call_fn!();
    continuation_call_fn!();
    ray_queries!(ray);
    payload_fns!();
    hit_queries!(hit);

    /// `optixGetRayTmax`: the distance of the closest hit.
    #[doc(alias = "optixGetRayTmax")]
    pub fn ray_tmax(&self) -> f32 {
        self.hit.t
    }

    /// `optixTrace` from a closest-hit program (recursion, up to the pipeline's depth).
    /// An exception it raises takes effect when it returns: pass it on with `?`.
    #[doc(alias = "optixTrace")]
    pub fn trace(&self, ray: &TraceRay<'_>, payload: &mut [u32]) -> ProgramResult {
        self.no_return
            .call(|| trace::trace(self.frame, ray, payload))
    }
}

/// The context of an any-hit program.
pub struct AnyHitCtx<'a, P> {
    pub(crate) frame: Frame<'a, P>,
    pub(crate) ray: RayState,
    pub(crate) hit: HitState,
    pub(crate) payload: &'a mut [u32],
    pub(crate) path: Option<&'a Path<'a>>,
    pub(crate) gas: Option<&'a crate::Gas>,
    pub(crate) place: &'a Placement,
    pub(crate) no_return: NoReturn,
}

impl<P> AnyHitCtx<'_, P> {
    common_queries!();
    throw_fn!();
    direct_call_fn!();
    ray_queries!(ray);
    payload_fns!();
    hit_queries!(hit);

    /// `optixGetRayTmax`: the candidate's distance.
    #[doc(alias = "optixGetRayTmax")]
    pub fn ray_tmax(&self) -> f32 {
        self.hit.t
    }
    /// `optixGetObjectRayOrigin`: the ray in the object space of the hit geometry.
    #[doc(alias = "optixGetObjectRayOrigin")]
    pub fn object_ray_origin(&self) -> Vec3 {
        self.place.object_origin
    }
    /// `optixGetObjectRayDirection` (not normalised: t is the same in both spaces).
    #[doc(alias = "optixGetObjectRayDirection")]
    pub fn object_ray_direction(&self) -> Vec3 {
        self.place.object_direction
    }

    /// `optixIgnoreIntersection`: the candidate is not a hit and the interval stays. It takes
    /// effect when called: once the program returns, whatever it returns, the candidate is
    /// ignored; later device calls of the program (a terminate, a throw, payload writes) do
    /// nothing, as in OptiX they are never reached. Write the payload before, and leave the
    /// program at once: `return ctx.ignore_intersection();` (or `?`).
    #[doc(alias = "optixIgnoreIntersection")]
    pub fn ignore_intersection(&self) -> ProgramResult {
        self.no_return
            .call(|| Err(Interrupt(InterruptKind::IgnoreIntersection)))
    }

    /// `optixTerminateRay`: the candidate is accepted and traversal ends; the closest-hit
    /// program then runs. It takes effect when called, as
    /// [`ignore_intersection`](Self::ignore_intersection) does: leave the program at once with
    /// `return ctx.terminate_ray();` (or `?`).
    #[doc(alias = "optixTerminateRay")]
    pub fn terminate_ray(&self) -> ProgramResult {
        self.no_return
            .call(|| Err(Interrupt(InterruptKind::TerminateRay)))
    }
}

/// The context of a miss program.
pub struct MissCtx<'a, P> {
    pub(crate) frame: Frame<'a, P>,
    pub(crate) ray: &'a RayState,
    pub(crate) payload: &'a mut [u32],
    pub(crate) no_return: NoReturn,
}

impl<P> MissCtx<'_, P> {
    common_queries!();
    throw_fn!();
    direct_call_fn!();
    continuation_call_fn!();
    ray_queries!(ray);
    payload_fns!();

    /// `optixGetRayTmax`: the trace's tmax.
    #[doc(alias = "optixGetRayTmax")]
    pub fn ray_tmax(&self) -> f32 {
        self.ray.tmax
    }

    /// `optixTrace` from a miss program.
    /// An exception it raises takes effect when it returns: pass it on with `?`.
    #[doc(alias = "optixTrace")]
    pub fn trace(&self, ray: &TraceRay<'_>, payload: &mut [u32]) -> ProgramResult {
        self.no_return
            .call(|| trace::trace(self.frame, ray, payload))
    }
}

/// The context of an intersection program: the candidate custom primitive and the current
/// interval.
pub struct IntersectionCtx<'a, 'v, P> {
    pub(crate) frame: Frame<'a, P>,
    pub(crate) ray: RayState,
    pub(crate) tmax: f32,
    pub(crate) prim: HitState,
    pub(crate) aabb: crate::Aabb,
    pub(crate) reporter: &'v mut dyn trace::Reporter<P>,
    pub(crate) path: Option<&'v Path<'v>>,
    pub(crate) place: &'v Placement,
    pub(crate) no_return: NoReturn,
}

impl<P> IntersectionCtx<'_, '_, P> {
    common_queries!();
    throw_fn!();
    direct_call_fn!();
    ray_queries!(ray);

    /// `optixGetRayTmax`: the closest accepted hit so far, or the trace's tmax.
    #[doc(alias = "optixGetRayTmax")]
    pub fn ray_tmax(&self) -> f32 {
        self.tmax
    }
    /// `optixGetObjectRayOrigin`: the ray in the object space of the primitive.
    #[doc(alias = "optixGetObjectRayOrigin")]
    pub fn object_ray_origin(&self) -> Vec3 {
        self.place.object_origin
    }
    /// `optixGetObjectRayDirection` (not normalised: t is the same in both spaces).
    #[doc(alias = "optixGetObjectRayDirection")]
    pub fn object_ray_direction(&self) -> Vec3 {
        self.place.object_direction
    }
    transform_queries!(prim);

    /// `optixGetInstanceId` (`!0` without instances).
    #[doc(alias = "optixGetInstanceId")]
    pub fn instance_id(&self) -> u32 {
        self.place.instance_id
    }
    /// `optixGetInstanceIndex` (0 without instances).
    #[doc(alias = "optixGetInstanceIndex")]
    pub fn instance_index(&self) -> u32 {
        self.place.instance_index
    }
    /// `optixGetPrimitiveIndex`.
    #[doc(alias = "optixGetPrimitiveIndex")]
    pub fn primitive_index(&self) -> u32 {
        self.prim.primitive_index
    }
    /// `optixGetSbtGASIndex`.
    #[doc(alias = "optixGetSbtGASIndex")]
    pub fn sbt_gas_index(&self) -> u32 {
        self.prim.sbt_gas_index
    }
    /// The primitive's bounding box from the build input.
    pub fn primitive_aabb(&self) -> crate::Aabb {
        self.aabb
    }
    /// `optixGetPayload_i`.
    #[doc(alias = "optixGetPayload_i")]
    pub fn payload(&self, i: usize) -> u32 {
        self.reporter.payload_ref().get(i).copied().unwrap_or(0)
    }
    /// `optixSetPayload_i` (ignored after a device call that does not return).
    #[doc(alias = "optixSetPayload_i")]
    pub fn set_payload(&mut self, i: usize, v: u32) {
        if self.no_return.is_set() {
            return;
        }
        if let Some(p) = self.reporter.payload().get_mut(i) {
            *p = v;
        }
    }

    /// `optixReportIntersection`: reports a hit at `t` with hit kind `hit_kind` (low 7 bits)
    /// and up to `num_attribute_values` attribute words. Outside `[tmin, tmax]` it is ignored and `Ok(false)` comes
    /// back; otherwise the any-hit program runs: `Ok(false)` if it ignored the hit, `Ok(true)`
    /// if the hit was accepted (the interval then ends at `t`). If the any-hit program
    /// terminated the ray or raised, an [`Interrupt`] comes back; it takes effect when this
    /// returns (traversal ends, whatever the program then returns, and later reports do
    /// nothing): pass it on with `?`.
    #[doc(alias = "optixReportIntersection")]
    pub fn report_intersection(
        &mut self,
        t: f32,
        hit_kind: u8,
        attributes: &[u32],
    ) -> Result<bool, Interrupt> {
        if let Some(i) = self.no_return.get() {
            return Err(i);
        }
        if !(t >= self.ray.tmin && t <= self.tmax) {
            return Ok(false);
        }
        let mut hit = self.prim;
        hit.t = t;
        hit.hit_kind = HitKind::custom(hit_kind);
        // Attributes past the pipeline's `num_attribute_values` (at least 2, at most 8) are
        // dropped, as they would not fit the registers OptiX reserves.
        let limit = self
            .frame
            .launch
            .pipeline
            .compile
            .num_attribute_values
            .clamp(2, 8) as usize;
        let n = attributes.len().min(limit);
        hit.attributes = [0; 8];
        hit.attributes[..n].copy_from_slice(&attributes[..n]);
        let accepted = self
            .no_return
            .call(|| self.reporter.report(self.frame, &self.ray, &hit))?;
        if accepted {
            self.tmax = t;
        }
        Ok(accepted)
    }
}

/// The context of an exception program.
pub struct ExceptionCtx<'a, P> {
    pub(crate) frame: Frame<'a, P>,
    pub(crate) exception: Exception,
}

impl<P> ExceptionCtx<'_, P> {
    common_queries!();

    /// `optixGetExceptionCode`.
    #[doc(alias = "optixGetExceptionCode")]
    #[must_use]
    pub fn exception_code(&self) -> ExceptionCode {
        self.exception.code
    }

    /// `optixGetExceptionDetail_i`: 0 past the details given.
    #[doc(alias = "optixGetExceptionDetail_i")]
    #[must_use]
    pub fn exception_detail(&self, i: usize) -> u32 {
        self.exception.details().get(i).copied().unwrap_or(0)
    }

    /// The whole exception.
    #[must_use]
    pub fn exception(&self) -> &Exception {
        &self.exception
    }
}

/// The context of a direct callable: no payload, no tracing (guide §15).
pub struct DirectCallableCtx<'a, P> {
    pub(crate) frame: Frame<'a, P>,
    pub(crate) no_return: NoReturn,
}

impl<P> DirectCallableCtx<'_, P> {
    common_queries!();
    throw_fn!();
    direct_call_fn!();
}

/// The context of a continuation callable: it may trace and call other callables (guide §15).
pub struct ContinuationCallableCtx<'a, P> {
    pub(crate) frame: Frame<'a, P>,
    pub(crate) no_return: NoReturn,
}

impl<P> ContinuationCallableCtx<'_, P> {
    common_queries!();
    throw_fn!();
    direct_call_fn!();
    continuation_call_fn!();

    /// `optixTrace` from a continuation callable.
    /// An exception it raises takes effect when it returns: pass it on with `?`.
    #[doc(alias = "optixTrace")]
    pub fn trace(&self, ray: &TraceRay<'_>, payload: &mut [u32]) -> ProgramResult {
        self.no_return
            .call(|| trace::trace(self.frame, ray, payload))
    }
}
