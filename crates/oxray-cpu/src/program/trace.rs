//! `optixTrace` on the CPU: the rules of guide §13.2–§13.7 and §13.13 applied to the candidates
//! the traversal kernel finds, with the hit group of each chosen by the §7.3 formula.

use crate::interrupt::{Interrupt, InterruptKind, ProgramResult};
use crate::program::context::{
    AnyHitCtx, ClosestHitCtx, ContinuationCallableCtx, DirectCallableCtx, ExceptionCtx, Frame,
    IntersectionCtx, LaunchShared, MissCtx, NoReturn, RayGenCtx, Scratch,
};
use crate::program::group::GroupPrograms;
use crate::traversal::{traverse_node, Decision, Entry, GasVisitor, NodeRef, Path, SceneVisitor};
use crate::Gas;
use glam::Vec3;
use oxray_bvh::triangle::TriangleHit;
use oxray_bvh::GasKind;
use oxray_bvh::InstanceData as InstanceRecord;
use oxray_core::sbt::hit_group_index;
use oxray_core::{
    Exception, ExceptionCode, GeometryFlags, PrimitiveType, Ray, RayFlags, TraversableHandle,
};
use oxray_core::{HitKind, InstanceFlags};

/// The arguments of a trace (`optixTrace`), with OptiX's defaults: `tmin = 0`,
/// `tmax = +inf`, time 0, visibility mask `0xFF`, no flags, SBT offset 0, stride 1, miss
/// index 0.
#[derive(Clone, Debug)]
#[doc(alias = "optixTrace")]
pub struct TraceRay<'h> {
    /// Where traversal starts.
    pub handle: &'h TraversableHandle,
    /// Origin.
    pub origin: Vec3,
    /// Direction.
    pub direction: Vec3,
    /// Start of the interval (must be >= 0).
    pub tmin: f32,
    /// End of the interval.
    pub tmax: f32,
    /// Time, for motion blur.
    pub time: f32,
    /// Visibility mask; only the low 8 bits count.
    pub visibility_mask: u32,
    /// Ray flags.
    pub flags: RayFlags,
    /// SBT offset (ray type); only the low 4 bits count.
    pub sbt_offset: u32,
    /// SBT stride (ray-type count); only the low 4 bits count.
    pub sbt_stride: u32,
    /// Miss record index.
    pub miss_index: u32,
}

impl<'h> TraceRay<'h> {
    /// A ray with the defaults above.
    #[must_use]
    pub fn new(handle: &'h TraversableHandle, origin: Vec3, direction: Vec3) -> Self {
        TraceRay {
            handle,
            origin,
            direction,
            tmin: 0.0,
            tmax: f32::INFINITY,
            time: 0.0,
            visibility_mask: 0xFF,
            flags: RayFlags::empty(),
            sbt_offset: 0,
            sbt_stride: 1,
            miss_index: 0,
        }
    }

    /// Sets the interval.
    #[must_use]
    pub fn interval(mut self, tmin: f32, tmax: f32) -> Self {
        (self.tmin, self.tmax) = (tmin, tmax);
        self
    }

    /// Sets the ray flags.
    #[must_use]
    pub fn flags(mut self, flags: RayFlags) -> Self {
        self.flags = flags;
        self
    }

    /// Sets the SBT offset, stride and miss index.
    #[must_use]
    pub fn sbt(mut self, offset: u32, stride: u32, miss_index: u32) -> Self {
        (self.sbt_offset, self.sbt_stride, self.miss_index) = (offset, stride, miss_index);
        self
    }

    /// Sets the visibility mask.
    #[must_use]
    pub fn visibility_mask(mut self, mask: u32) -> Self {
        self.visibility_mask = mask;
        self
    }

    /// Sets the time.
    #[must_use]
    pub fn time(mut self, time: f32) -> Self {
        self.time = time;
        self
    }
}

/// The ray as hit and miss programs see it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct RayState {
    pub origin: Vec3,
    pub direction: Vec3,
    pub tmin: f32,
    pub tmax: f32,
    pub time: f32,
    pub flags: RayFlags,
    pub mask: u8,
}

/// A candidate or accepted hit.
#[derive(Clone, Copy, Debug)]
pub(crate) struct HitState {
    pub t: f32,
    pub primitive_index: u32,
    pub sbt_gas_index: u32,
    pub hit_kind: HitKind,
    pub attributes: [u32; 8],
    /// Hit-group record index.
    pub record: usize,
    /// Leaf slot of the primitive in its GAS (`u32::MAX` for none), for vertex fetches.
    pub slot: u32,
    /// Whether `primitive_index` is set; otherwise it is found from `slot` when a program
    /// may read it ([`PipelineVisitor::lookup`]).
    pub resolved: bool,
}

/// The instance nearest to a hit and the transforms between its object space and world space.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Placement {
    pub instance_id: u32,
    pub instance_index: u32,
    /// Levels of transforms between world and object space.
    pub levels: u32,
    /// Object-to-world and world-to-object transforms; `None` for identity (no transforms,
    /// which keeps setting up a trace of a GAS cheap).
    pub transforms: Option<[crate::Transform; 2]>,
    /// Object-space ray.
    pub object_origin: Vec3,
    pub object_direction: Vec3,
}

impl Placement {
    /// The object-to-world transform.
    pub fn object_to_world(&self) -> crate::Transform {
        self.transforms.map_or(crate::Transform::IDENTITY, |t| t[0])
    }

    /// The world-to-object transform.
    pub fn world_to_object(&self) -> crate::Transform {
        self.transforms.map_or(crate::Transform::IDENTITY, |t| t[1])
    }

    fn world(ray: &RayState) -> Self {
        Placement {
            instance_id: !0,
            instance_index: 0,
            levels: 0,
            transforms: None,
            object_origin: ray.origin,
            object_direction: ray.direction,
        }
    }
}

/// What an intersection program reports to.
pub(crate) trait Reporter<P> {
    /// Runs the any-hit rules on a reported hit: whether it was accepted, or an interrupt
    /// (terminate or exception).
    fn report(
        &mut self,
        frame: Frame<'_, P>,
        ray: &RayState,
        hit: &HitState,
    ) -> Result<bool, Interrupt>;
    /// The trace's payload.
    fn payload(&mut self) -> &mut [u32];
    /// The trace's payload, read-only.
    fn payload_ref(&self) -> &[u32];
}

struct PipelineVisitor<'a, 'p, 's, P> {
    frame: Frame<'a, P>,
    /// The GAS being traversed and where it sits.
    gas: Option<&'s Gas>,
    /// SBT offsets summed over the instances above the GAS (§7.3.1).
    instance_sbt_offset: u32,
    /// The instance nearest to the GAS, whose flags count (§5.4).
    instance: Option<&'s InstanceRecord>,
    /// The transform list of the current GAS (kept only when there are transforms: `None`
    /// costs nothing to set up for a GAS root).
    path: Option<Path<'s>>,
    /// The transform list of the closest accepted hit.
    best_path: Option<Path<'s>>,
    /// The GAS of the closest accepted hit.
    best_gas: Option<&'s Gas>,
    /// Where the closest accepted hit's geometry sits; `None` for the world (a GAS root), which
    /// leaves the placement to be made only for a program that runs.
    best_place: Option<Placement>,
    /// Where the current GAS sits; `None` for the world.
    place: Option<Placement>,
    /// The trace's ray, borrowed: a copy would read back the fields `trace` just stored, in
    /// wider loads than they were stored with (a store-forwarding stall on every trace).
    ray: &'p RayState,
    sbt_offset: u32,
    sbt_stride: u32,
    payload: &'p mut [u32],
    best: Option<HitState>,
    pending: Option<Interrupt>,
}

impl<'a, P> PipelineVisitor<'a, '_, '_, P> {
    /// The primitive index (if found), SBT-GAS index and whether the index was found, of leaf
    /// `slot`. In a GAS with one SBT record the SBT-GAS index is 0 without a lookup, and the
    /// primitive index is found only when a program may read it ([`Self::resolved`]): the
    /// lookup is a cache miss on large meshes, and most candidates are replaced by nearer ones.
    #[inline(always)]
    fn lookup(gas: &Gas, slot: u32) -> (u32, u32, bool) {
        if gas.record_flags.len() == 1 {
            return (0, 0, false);
        }
        let (primitive_index, sbt_gas_index, _) = gas.resolve(slot);
        (primitive_index, sbt_gas_index, true)
    }

    /// `hit` with its primitive index found in `gas`, the GAS it was found in.
    #[inline(always)]
    fn resolved(gas: Option<&Gas>, mut hit: HitState) -> HitState {
        if let (false, Some(gas)) = (hit.resolved, gas) {
            hit.primitive_index = gas.resolve(hit.slot).0;
            hit.resolved = true;
        }
        hit
    }

    fn record(&mut self, sbt_gas_index: u32) -> Option<usize> {
        let rec = hit_group_index(
            self.instance_sbt_offset,
            sbt_gas_index,
            self.sbt_stride,
            self.sbt_offset,
        );
        if rec >= self.frame.launch.hit_groups.len() as u64 {
            self.pending = Some(Interrupt::exception(
                ExceptionCode::INVALID_HIT_SBT,
                &[rec.min(u32::MAX as u64) as u32, sbt_gas_index],
            ));
            return None;
        }
        Some(rec as usize)
    }

    fn group(&self, record: usize) -> &'a GroupPrograms<P> {
        let launch = self.frame.launch;
        &launch.pipeline.groups[launch.hit_groups[record]]
            .inner
            .programs
    }

    fn record_bytes(&self, record: usize) -> &'a [u8] {
        self.frame.launch.sbt.hitgroup.record(record).unwrap_or(&[])
    }

    /// The any-hit rules of §13.2 / §13.13 for one candidate in the interval: geometry flags,
    /// overridden by the nearest instance's, overridden by the ray's (§5.1, §5.4).
    /// Whether any-hit is enabled for geometry with these flags: geometry flags, overridden by
    /// the nearest instance's, overridden by the ray's (§5.1, §5.4, §13.2).
    fn any_hit_enabled(&self, gflags: GeometryFlags) -> bool {
        let flags = self.ray.flags;
        let iflags = self.instance.map_or(InstanceFlags::empty(), |i| i.flags);
        let mut ah_on = !gflags.contains(GeometryFlags::DISABLE_ANYHIT);
        if iflags.contains(InstanceFlags::DISABLE_ANYHIT) {
            ah_on = false;
        } else if iflags.contains(InstanceFlags::ENFORCE_ANYHIT) {
            ah_on = true;
        }
        if flags.contains(RayFlags::DISABLE_ANYHIT) {
            ah_on = false;
        } else if flags.contains(RayFlags::ENFORCE_ANYHIT) {
            ah_on = true;
        }
        ah_on
    }

    /// `CULL_DISABLED_ANYHIT` / `CULL_ENFORCED_ANYHIT`: the primitive is not a candidate at all.
    fn culled_by_any_hit_state(&self, ah_on: bool) -> bool {
        let flags = self.ray.flags;
        (flags.contains(RayFlags::CULL_DISABLED_ANYHIT) && !ah_on)
            || (flags.contains(RayFlags::CULL_ENFORCED_ANYHIT) && ah_on)
    }

    fn candidate(&mut self, hit: HitState, gflags: GeometryFlags) -> Decision {
        let flags = self.ray.flags;
        let ah_on = self.any_hit_enabled(gflags);
        if self.culled_by_any_hit_state(ah_on) {
            return Decision::Ignore;
        }
        let mut terminate = flags.contains(RayFlags::TERMINATE_ON_FIRST_HIT);
        if ah_on {
            if let GroupPrograms::HitGroup {
                any_hit: Some(ah), ..
            } = self.group(hit.record)
            {
                let mut ctx = AnyHitCtx {
                    frame: Frame {
                        record: self.record_bytes(hit.record),
                        ..self.frame
                    },
                    ray: *self.ray,
                    hit: Self::resolved(self.gas, hit),
                    payload: self.payload,
                    path: self.path.as_ref(),
                    gas: self.gas,
                    place: &self.place.unwrap_or_else(|| Placement::world(self.ray)),
                    no_return: NoReturn::default(),
                };
                // What the program called first wins over what it returned (§13.13): an
                // ignore or terminate it dropped still takes effect.
                let r = ah(&mut ctx);
                match ctx.no_return.outcome(r) {
                    Ok(()) => {}
                    Err(Interrupt(InterruptKind::IgnoreIntersection)) => return Decision::Ignore,
                    Err(Interrupt(InterruptKind::TerminateRay)) => terminate = true,
                    Err(e) => {
                        self.pending = Some(e);
                        return Decision::Abort;
                    }
                }
            }
        }
        self.best = Some(hit);
        self.best_gas = self.gas;
        // The transform list and placement only change below transforms; copying them (the
        // list is large) is skipped for a GAS root, where they stay at their initial values.
        if self.path.is_some() {
            self.best_path = self.path;
            self.best_place = self.place;
        }
        if terminate {
            Decision::AcceptAndTerminate
        } else {
            Decision::Accept
        }
    }
}

impl<'s, P> SceneVisitor<'s> for PipelineVisitor<'_, '_, 's, P> {
    #[inline]
    fn enter_gas(&mut self, gas: &'s Gas, path: &Path<'s>, object_ray: &Ray) {
        // The pipeline's primitive types (§6.3), wherever in the graph the GAS sits.
        let kinds = self.frame.launch.pipeline.compile.uses_primitive_type_flags;
        // An empty set means triangles and custom primitives; spheres must be enabled
        // explicitly (§9.1), else the GAS raises UNSUPPORTED_PRIMITIVE_TYPE.
        let allowed = match gas.kind {
            GasKind::Triangles => kinds.allows(PrimitiveType::Triangle),
            GasKind::CustomPrimitives => kinds.allows(PrimitiveType::Custom),
            GasKind::Spheres => kinds.allows(PrimitiveType::Sphere),
            // Every curve type the structure holds needs its own flag.
            GasKind::Curves => kinds.contains(gas.curve_types()),
        };
        if !allowed {
            self.pending = Some(Interrupt::exception(
                ExceptionCode::UNSUPPORTED_PRIMITIVE_TYPE,
                &[],
            ));
            self.gas = None;
            return;
        }
        self.gas = Some(gas);
        (self.instance_sbt_offset, self.instance) = (path.sbt_offset, path.instance);
        // The root GAS (entered once per trace, whose visitor starts with no path and the world
        // placement) needs nothing more.
        if path.len != 0 {
            self.enter_transformed(path, object_ray);
        }
    }

    fn ray_mask(&self) -> u8 {
        self.ray.mask
    }

    fn graph_too_deep(&mut self) {
        self.pending = Some(Interrupt::exception(
            ExceptionCode::TRAVERSAL_DEPTH_EXCEEDED,
            &[],
        ));
    }
}

impl<'s, P> PipelineVisitor<'_, '_, 's, P> {
    /// Keeps the transform list and placement of a GAS entered below transforms.
    #[inline(never)]
    fn enter_transformed(&mut self, path: &Path<'s>, object_ray: &Ray) {
        self.path = Some(*path);
        // One level (the common IAS over GASes) needs no composition.
        let (mut o2w, mut w2o) = (crate::Transform::IDENTITY, crate::Transform::IDENTITY);
        if let (1, Some(level)) = (path.len, path.levels().next()) {
            (o2w, w2o) = (level.object_to_world(), level.world_to_object());
        } else {
            for level in path.levels() {
                o2w = o2w.then_after(&level.object_to_world());
                w2o = level.world_to_object().then_after(&w2o);
            }
        }
        self.place = Some(Placement {
            instance_id: path.instance.map_or(!0, |i| i.instance_id),
            instance_index: path.instance.map_or(0, |i| i.index),
            levels: path.len as u32,
            transforms: Some([o2w, w2o]),
            object_origin: object_ray.origin,
            object_direction: object_ray.direction,
        });
    }
}

impl<P> GasVisitor for PipelineVisitor<'_, '_, '_, P> {
    fn triangle(&mut self, slot: u32, h: &TriangleHit) -> Decision {
        let Some(gas) = self.gas else {
            return if self.pending.is_some() {
                Decision::Abort
            } else {
                Decision::Ignore
            };
        };
        let (primitive_index, sbt_gas_index, resolved) = Self::lookup(gas, slot);
        let gflags = gas.record_flags[sbt_gas_index as usize];
        let iflags = self.instance.map_or(InstanceFlags::empty(), |i| i.flags);
        // Facing: counter-clockwise is front unless the nearest instance flips it (§5.4).
        let front = h.front_face != iflags.contains(InstanceFlags::FLIP_TRIANGLE_FACING);
        let no_culling = gflags.contains(GeometryFlags::DISABLE_TRIANGLE_FACE_CULLING)
            || iflags.contains(InstanceFlags::DISABLE_TRIANGLE_FACE_CULLING);
        if !no_culling {
            let flags = self.ray.flags;
            if (flags.contains(RayFlags::CULL_BACK_FACING_TRIANGLES) && !front)
                || (flags.contains(RayFlags::CULL_FRONT_FACING_TRIANGLES) && front)
            {
                return Decision::Ignore;
            }
        }
        let Some(record) = self.record(sbt_gas_index) else {
            return Decision::Abort;
        };
        let mut attributes = [0u32; 8];
        attributes[0] = h.u.to_bits();
        attributes[1] = h.v.to_bits();
        let hit = HitState {
            t: h.t,
            primitive_index,
            sbt_gas_index,
            hit_kind: if front {
                HitKind::TRIANGLE_FRONT_FACE
            } else {
                HitKind::TRIANGLE_BACK_FACE
            },
            attributes,
            record,
            slot,
            resolved,
        };
        self.candidate(hit, gflags)
    }

    fn sphere(&mut self, slot: u32, t: f32) -> Decision {
        let Some(gas) = self.gas else {
            return if self.pending.is_some() {
                Decision::Abort
            } else {
                Decision::Ignore
            };
        };
        let (primitive_index, sbt_gas_index, resolved) = Self::lookup(gas, slot);
        let gflags = gas.record_flags[sbt_gas_index as usize];
        let Some(record) = self.record(sbt_gas_index) else {
            return Decision::Abort;
        };
        // The triangle culling flags do not apply (§13.2 names triangles): a sphere's only hit
        // is its front face (§9.4, §9.6). The any-hit rules and CULL_*_ANYHIT do apply, in
        // `candidate`. A hit group's intersection program is not run: spheres use the
        // built-in intersector (§9.1), as triangles do.
        let hit = HitState {
            t,
            primitive_index,
            sbt_gas_index,
            hit_kind: HitKind::SPHERE_FRONT_FACE,
            attributes: [0; 8],
            record,
            slot,
            resolved,
        };
        self.candidate(hit, gflags)
    }

    fn curve(&mut self, slot: u32, h: &oxray_bvh::CurveHit) -> Decision {
        let Some(gas) = self.gas else {
            return if self.pending.is_some() {
                Decision::Abort
            } else {
                Decision::Ignore
            };
        };
        let (primitive_index, sbt_gas_index, resolved) = Self::lookup(gas, slot);
        let gflags = gas.record_flags[sbt_gas_index as usize];
        let Some(record) = self.record(sbt_gas_index) else {
            return Decision::Abort;
        };
        // As for spheres: no triangle culling flags, the built-in intersector, the any-hit
        // rules in `candidate`. Attributes are u (and a ribbon's v), guide §9.3, §13.4.
        let mut attributes = [0u32; 8];
        attributes[0] = h.u.to_bits();
        attributes[1] = h.v.to_bits();
        let hit = HitState {
            t: h.t,
            primitive_index,
            sbt_gas_index,
            hit_kind: HitKind::curve(gas.curves[slot as usize].curve_type(), h.back_face),
            attributes,
            record,
            slot,
            resolved,
        };
        self.candidate(hit, gflags)
    }

    fn custom(&mut self, slot: u32, tmin: f32, tmax: f32, _: &mut [Entry]) -> (Option<f32>, bool) {
        let Some(gas) = self.gas else {
            return (None, self.pending.is_some());
        };
        let (primitive_index, sbt_gas_index, _) = gas.resolve(slot);
        let Some(record) = self.record(sbt_gas_index) else {
            return (None, true);
        };
        let GroupPrograms::HitGroup {
            intersection: Some(is),
            ..
        } = self.group(record)
        else {
            return (None, false);
        };
        // A primitive culled by its any-hit state never reaches its intersection program.
        if self
            .culled_by_any_hit_state(self.any_hit_enabled(gas.record_flags[sbt_gas_index as usize]))
        {
            return (None, false);
        }
        let before = self.best.map(|h| h.t);
        let prim = HitState {
            t: tmax,
            primitive_index,
            sbt_gas_index,
            hit_kind: HitKind(0),
            attributes: [0; 8],
            record,
            slot: u32::MAX,
            resolved: true,
        };
        let frame = Frame {
            record: self.record_bytes(record),
            ..self.frame
        };
        let ray = RayState { tmin, ..*self.ray };
        // With motion, the box at the ray's time (guide §5.10.1).
        let aabb = gas
            .aabb_at(slot as usize, self.ray.time)
            .unwrap_or(oxray_core::Aabb::EMPTY);
        // Copies: the context also borrows the visitor, to report to it.
        let path = self.path;
        let place = self.place.unwrap_or_else(|| Placement::world(self.ray));
        let mut ctx = IntersectionCtx {
            frame,
            ray,
            tmax,
            prim,
            aabb,
            reporter: self,
            path: path.as_ref(),
            place: &place,
            no_return: NoReturn::default(),
        };
        let result = is(&mut ctx);
        // A terminate or exception from a report (recorded at the report) ends traversal even
        // if the program dropped it: in OptiX the report never returns.
        let mut stop = match ctx.no_return.outcome(result) {
            Ok(()) => false,
            Err(Interrupt(InterruptKind::TerminateRay)) => true,
            Err(Interrupt(InterruptKind::IgnoreIntersection)) => false,
            Err(e) => {
                self.pending = Some(e);
                true
            }
        };
        stop |= self.pending.is_some();
        let after = self.best.map(|h| h.t);
        let t = if after != before { after } else { None };
        (t, stop)
    }
}

impl<P> Reporter<P> for PipelineVisitor<'_, '_, '_, P> {
    fn report(
        &mut self,
        _frame: Frame<'_, P>,
        _ray: &RayState,
        hit: &HitState,
    ) -> Result<bool, Interrupt> {
        let gflags = self.gas.map_or(GeometryFlags::empty(), |g| {
            g.record_flags[hit.sbt_gas_index as usize]
        });
        match self.candidate(*hit, gflags) {
            Decision::Ignore => Ok(false),
            Decision::Accept => Ok(true),
            // The intersection program's context records the interrupt, so that a program that
            // drops it still cannot continue traversal: in OptiX the report never returns.
            Decision::AcceptAndTerminate => Err(Interrupt(InterruptKind::TerminateRay)),
            // The exception also stays pending.
            Decision::Abort => Err(self
                .pending
                .unwrap_or(Interrupt(InterruptKind::TerminateRay))),
        }
    }

    fn payload(&mut self) -> &mut [u32] {
        self.payload
    }

    fn payload_ref(&self) -> &[u32] {
        self.payload
    }
}

/// The pipeline's traversable-graph and primitive-type flags (§5.9.1, §6.3) against the graph
/// under `root`.
fn check_graph<P>(
    pipe: &crate::pipeline::PipelineShared<P>,
    root: NodeRef<'_>,
    handle: &TraversableHandle,
) -> ProgramResult {
    use oxray_core::TraversableGraphFlags as G;
    let graph = pipe.compile.traversable_graph_flags;
    if !graph.is_empty() {
        let allowed = match root {
            NodeRef::Gas(_) => graph.contains(G::ALLOW_SINGLE_GAS),
            // One level of instances over GASes without transforms.
            NodeRef::Ias(ias) => {
                graph.contains(G::ALLOW_SINGLE_LEVEL_INSTANCING) && ias.single_level
            }
            // Transforms need ALLOW_ANY (§5.9.1), motion transforms included.
            NodeRef::Static(_) | NodeRef::MatrixMotion(_) | NodeRef::SrtMotion(_) => false,
        };
        if !allowed {
            let code = if matches!(root, NodeRef::Gas(_)) {
                ExceptionCode::UNSUPPORTED_SINGLE_LEVEL_GAS
            } else {
                ExceptionCode::TRAVERSAL_INVALID_TRAVERSABLE
            };
            return Err(Interrupt::exception(code, &[]));
        }
    }
    // Every traversable is at most MAX_TRAVERSABLE_GRAPH_DEPTH deep (its constructor checks),
    // so only a lowered limit needs the handle's depth.
    if pipe.max_traversable_graph_depth < oxray_core::MAX_TRAVERSABLE_GRAPH_DEPTH
        && handle.graph_depth() > pipe.max_traversable_graph_depth
    {
        return Err(Interrupt::exception(
            ExceptionCode::TRAVERSAL_DEPTH_EXCEEDED,
            &[],
        ));
    }
    Ok(())
}

/// `optixTrace` from a program running in `frame`.
pub(crate) fn trace<P>(
    frame: Frame<'_, P>,
    args: &TraceRay<'_>,
    payload: &mut [u32],
) -> ProgramResult {
    let traces = &frame.scratch.traces;
    traces.set(traces.get() + 1);
    let launch = frame.launch;
    let pipe = launch.pipeline;
    let n = payload.len();
    if n > pipe.compile.num_payload_values as usize {
        return Err(Interrupt::exception(
            ExceptionCode::PAYLOAD_TYPE_MISMATCH,
            &[n as u32, pipe.compile.num_payload_values],
        ));
    }
    let depth = frame.depth + 1;
    if depth > pipe.link.max_trace_depth {
        return Err(Interrupt::exception(
            ExceptionCode::TRACE_DEPTH_EXCEEDED,
            &[],
        ));
    }
    // Guide §13.5: without motion blur in the pipeline the ray time is ignored (0), for
    // traversal and for `optixGetRayTime` alike.
    let time = if pipe.compile.uses_motion_blur {
        args.time
    } else {
        0.0
    };
    let ray = Ray::with_interval(args.origin, args.direction, args.tmin, args.tmax).with_time(time);
    if pipe.validation_mode && ray.validate().is_err() {
        let o = args.origin.to_array().map(f32::to_bits);
        let d = args.direction.to_array().map(f32::to_bits);
        return Err(Interrupt::exception(
            ExceptionCode::INVALID_RAY,
            &[
                o[0],
                o[1],
                o[2],
                d[0],
                d[1],
                d[2],
                args.tmin.to_bits(),
                args.tmax.to_bits(),
            ],
        ));
    }
    let state = RayState {
        origin: args.origin,
        direction: args.direction,
        tmin: args.tmin,
        tmax: args.tmax,
        time,
        flags: args.flags,
        mask: (args.visibility_mask & 0xFF) as u8,
    };
    // Copy-in / copy-out (guide §14) needs no copy here: the caller is suspended for the whole
    // trace, so programs may work on its words directly and it sees them only on return. (If the
    // trace raises, the launch index ends and the words are not looked at again.)
    let frame = Frame { depth, ..frame };
    trace_into(frame, args, &state, &ray, payload)
}

fn trace_into<P>(
    frame: Frame<'_, P>,
    args: &TraceRay<'_>,
    state: &RayState,
    ray: &Ray,
    payload: &mut [u32],
) -> ProgramResult {
    let launch = frame.launch;
    let pipe = launch.pipeline;
    if !args.handle.is_null() {
        // A structure of another backend cannot be entered by a CPU traversal.
        let Some(root) = NodeRef::of(args.handle) else {
            return Err(Interrupt::exception(
                ExceptionCode::TRAVERSAL_INVALID_TRAVERSABLE,
                &[],
            ));
        };
        check_graph(pipe, root, args.handle)?;
        let mut v = PipelineVisitor {
            frame,
            gas: None,
            instance_sbt_offset: 0,
            instance: None,
            path: None,
            best_path: None,
            best_gas: None,
            best_place: None,
            place: None,
            ray: state,
            sbt_offset: args.sbt_offset,
            sbt_stride: args.sbt_stride,
            payload: &mut *payload,
            best: None,
            pending: None,
        };
        frame
            .scratch
            .stack
            .with(|stack| traverse_node(root, &Path::ROOT, ray, &mut v, stack));
        if let Some(e) = v.pending {
            return Err(e);
        }
        if let Some(hit) = v.best {
            // The closest-hit program runs with the visitor's state in place: the hit's transform
            // list is large, and copying it out would cost every trace.
            return v.closest_hit(state, &hit);
        }
    }
    let idx = args.miss_index as usize;
    let Some(&g) = launch.miss_groups.get(idx) else {
        return Err(Interrupt::exception(
            ExceptionCode::INVALID_MISS_SBT,
            &[args.miss_index],
        ));
    };
    if let GroupPrograms::Miss(Some(ms)) = &pipe.groups[g].inner.programs {
        let mut ctx = MissCtx {
            frame: Frame {
                record: launch.sbt.miss.record(idx).unwrap_or(&[]),
                ..frame
            },
            ray: state,
            payload,
            no_return: NoReturn::default(),
        };
        let r = ms(&mut ctx);
        return only_exceptions(ctx.no_return.outcome(r));
    }
    Ok(())
}

impl<P> PipelineVisitor<'_, '_, '_, P> {
    /// Runs the closest-hit program of the accepted hit (unless the ray disables it).
    fn closest_hit(&mut self, state: &RayState, hit: &HitState) -> ProgramResult {
        if state.flags.contains(RayFlags::DISABLE_CLOSESTHIT) {
            return Ok(());
        }
        let launch = self.frame.launch;
        let g = &launch.pipeline.groups[launch.hit_groups[hit.record]]
            .inner
            .programs;
        let GroupPrograms::HitGroup {
            closest_hit: Some(ch),
            ..
        } = g
        else {
            return Ok(());
        };
        let hit = Self::resolved(self.best_gas, *hit);
        let mut ctx = ClosestHitCtx {
            frame: Frame {
                record: launch.sbt.hitgroup.record(hit.record).unwrap_or(&[]),
                ..self.frame
            },
            ray: state,
            hit: &hit,
            payload: self.payload,
            path: self.best_path.as_ref(),
            gas: self.best_gas,
            place: &self.best_place.unwrap_or_else(|| Placement::world(state)),
            no_return: NoReturn::default(),
        };
        let r = ch(&mut ctx);
        only_exceptions(ctx.no_return.outcome(r))
    }
}

/// Closest-hit and miss programs cannot ignore or terminate; only exceptions pass (whether
/// returned or only recorded at the call: the caller passes the outcome).
fn only_exceptions(r: ProgramResult) -> ProgramResult {
    match r {
        Err(Interrupt(InterruptKind::Exception(e))) => Err(Interrupt(InterruptKind::Exception(e))),
        _ => Ok(()),
    }
}

/// Runs the ray-generation program of one launch index, then the exception program if an
/// exception ended it; counts the index's traces in `scratch`. Returns the exception, if any.
/// Inlined into the launch loop, which keeps the index in registers.
#[inline(always)]
pub(crate) fn run_raygen<P>(
    launch: &LaunchShared<'_, P>,
    index: [u32; 3],
    raygen_group: usize,
    scratch: &Scratch,
) -> Option<Exception> {
    let frame = Frame {
        launch,
        index,
        record: launch.sbt.raygen.record(0).unwrap_or(&[]),
        depth: 0,
        calls: 0,
        scratch,
    };
    let GroupPrograms::RayGen(rg) = &launch.pipeline.groups[raygen_group].inner.programs else {
        return None;
    };
    let mut ctx = RayGenCtx {
        frame,
        no_return: NoReturn::default(),
    };
    // An exception recorded at a call ends the launch index whatever the program returned.
    let r = rg(&mut ctx);
    let Err(Interrupt(InterruptKind::Exception(e))) = ctx.no_return.outcome(r) else {
        return None;
    };
    run_exception(frame, e);
    Some(e)
}

/// Runs the exception program (if the SBT has one) for exception `e` of `frame`'s index.
#[cold]
#[inline(never)]
fn run_exception<P>(frame: Frame<'_, P>, e: Exception) {
    let launch = frame.launch;
    if let Some(region) = &launch.sbt.exception {
        if let Some(&g) = launch.exception_group.as_ref() {
            if let GroupPrograms::Exception(ex) = &launch.pipeline.groups[g].inner.programs {
                let mut ctx = ExceptionCtx {
                    frame: Frame {
                        record: region.record(0).unwrap_or(&[]),
                        ..frame
                    },
                    exception: e,
                };
                ex(&mut ctx);
            }
        }
    }
}

/// Deepest nesting of callables before `STACK_OVERFLOW` is raised (so that runaway recursion
/// ends the launch index instead of the process).
pub(crate) const MAX_CALL_DEPTH: u32 = 64;

fn callable_group<P>(frame: &Frame<'_, P>, sbt_index: u32) -> Result<(usize, u32), Interrupt> {
    if frame.calls >= MAX_CALL_DEPTH {
        return Err(Interrupt::exception(ExceptionCode::STACK_OVERFLOW, &[]));
    }
    match frame.launch.callable_groups.get(sbt_index as usize) {
        Some(&g) => Ok((g, frame.calls + 1)),
        None => Err(Interrupt::exception(
            ExceptionCode::CALLABLE_INVALID_SBT,
            &[sbt_index],
        )),
    }
}

/// Defines a call into the callables region: the two kinds differ only in which program of
/// the record runs, its context type, and the exception for a record without it.
macro_rules! callable_call {
    ($(#[$doc:meta])* $name:ident, $field:ident, $ctx:ident, $missing:expr) => {
        $(#[$doc])*
        pub(crate) fn $name<P, A: 'static, R: 'static>(
            frame: Frame<'_, P>,
            sbt_index: u32,
            args: A,
        ) -> Result<R, Interrupt> {
            let (g, calls) = callable_group(&frame, sbt_index)?;
            let launch = frame.launch;
            let GroupPrograms::Callables {
                $field: Some(program),
                ..
            } = &launch.pipeline.groups[g].inner.programs
            else {
                return Err(Interrupt::exception($missing, &[sbt_index]));
            };
            let record = launch.sbt.callables.record(sbt_index as usize).unwrap_or(&[]);
            let mut ctx = $ctx {
                frame: Frame {
                    record,
                    calls,
                    ..frame
                },
                no_return: NoReturn::default(),
            };
            // The erased program fills the result half of the caller's (args, result) slot.
            let mut slot: (Option<A>, Option<R>) = (Some(args), None);
            // An exception the callable raised ends the launch index even if it dropped it.
            let r = program(&mut ctx, &mut slot);
            let ok = ctx.no_return.outcome(r)?;
            match (ok, slot.1) {
                (true, Some(r)) => Ok(r),
                _ => Err(Interrupt::exception(
                    ExceptionCode::CALLABLE_PARAMETER_MISMATCH,
                    &[sbt_index],
                )),
            }
        }
    };
}

callable_call!(
    /// `optixDirectCall`.
    direct_call,
    direct,
    DirectCallableCtx,
    ExceptionCode::CALLABLE_NO_DC_SBT_RECORD
);
callable_call!(
    /// `optixContinuationCall`.
    continuation_call,
    continuation,
    ContinuationCallableCtx,
    ExceptionCode::CALLABLE_NO_CC_SBT_RECORD
);
