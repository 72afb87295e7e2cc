//! Helpers shared by the pipeline conformance tests (`tests/pipeline_*.rs`): pipeline options, a
//! deterministic random-number generator and triangle helpers (from `oxray-testkit`), small
//! scenes, and a single-ray harness that launches one ray-generation program tracing one
//! configurable ray and records every program that ran.
//!
//! Each test binary uses a different subset of these helpers.
#![allow(dead_code, unused_imports)]

pub use glam::Vec3;
use oxray::cpu::Gas;
use oxray::{
    Aabb, AabbBuffer, AnyHitCtx, BuildInput, BuildOptions, ClosestHitCtx, CustomPrimitiveInput,
    DeviceContext, ExceptionFlags, GeometryFlags, IntersectionCtx, LaunchReport, MissCtx, Module,
    Pipeline, PipelineCompileOptions, PipelineLinkOptions, ProgramGroup, ProgramResult, RayFlags,
    SbtRegion, ShaderBindingTable, TraceRay, TraversableHandle, TriangleInput, VertexBuffer,
};
pub use oxray_testkit::mesh::{random_soup, soup, tri_at, Tri};
pub use oxray_testkit::Rng;
use std::sync::{Arc, Mutex};

/// What the tests return, so that `?` works on the library's errors.
pub type TestResult = Result<(), Box<dyn std::error::Error>>;

/// Compile options with every exception check on.
pub fn compile(num_payload_values: u32, num_attribute_values: u32) -> PipelineCompileOptions {
    PipelineCompileOptions {
        num_payload_values,
        num_attribute_values,
        exception_flags: ExceptionFlags::all(),
        ..Default::default()
    }
}

/// Link options of the given trace depth.
pub fn link(max_trace_depth: u32) -> PipelineLinkOptions {
    PipelineLinkOptions { max_trace_depth }
}

/// A GAS of one triangle-soup input with one SBT record and the given flags.
pub fn tri_gas_flags(tris: &[Tri], flags: GeometryFlags) -> Arc<Gas> {
    let v = soup(tris);
    let f = [flags];
    let input = TriangleInput::new(VertexBuffer::f32x3(&v)).flags(&f);
    Arc::new(Gas::build(&BuildOptions::default(), &[input.into()]).expect("GAS build"))
}

/// A GAS of one triangle-soup input with one SBT record and no flags.
pub fn tri_gas(tris: &[Tri]) -> Arc<Gas> {
    tri_gas_flags(tris, GeometryFlags::empty())
}

/// A GAS of one custom-primitive input with one SBT record and the given flags.
pub fn box_gas_flags(boxes: &[Aabb], flags: GeometryFlags) -> Arc<Gas> {
    let f = [flags];
    let input: BuildInput = CustomPrimitiveInput::new(AabbBuffer::new(boxes))
        .flags(&f)
        .into();
    Arc::new(Gas::build(&BuildOptions::default(), &[input]).expect("GAS build"))
}

/// A GAS of one custom-primitive input with one SBT record and no flags.
pub fn box_gas(boxes: &[Aabb]) -> Arc<Gas> {
    box_gas_flags(boxes, GeometryFlags::empty())
}

/// The box `[c - h, c + h]`.
pub fn cube(c: Vec3, h: f32) -> Aabb {
    Aabb::new(c - Vec3::splat(h), c + Vec3::splat(h))
}

/// Which program an [`Ev`] records.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Prog {
    /// Intersection.
    Is,
    /// Any-hit.
    Ah,
    /// Closest-hit.
    Ch,
    /// Miss.
    Ms,
}

/// One program invocation as the program saw it.
#[derive(Clone, Debug, PartialEq)]
pub struct Ev {
    /// The program.
    pub prog: Prog,
    /// `primitive_index()` (0 for miss).
    pub prim: u32,
    /// `sbt_gas_index()` (0 for miss).
    pub gas: u32,
    /// `ray_tmin()`.
    pub tmin: f32,
    /// `ray_tmax()`.
    pub tmax: f32,
    /// `hit_kind()` (0 for miss and intersection).
    pub kind: u8,
    /// Attributes 0..8 (0 for miss and intersection).
    pub attrs: [u32; 8],
    /// The first word of the SBT record's data.
    pub data: u32,
}

/// The event of an any-hit program.
pub fn ev_ah(ctx: &AnyHitCtx<'_, Tp>) -> Ev {
    Ev {
        prog: Prog::Ah,
        prim: ctx.primitive_index(),
        gas: ctx.sbt_gas_index(),
        tmin: ctx.ray_tmin(),
        tmax: ctx.ray_tmax(),
        kind: ctx.hit_kind().0,
        attrs: std::array::from_fn(|i| ctx.attribute(i)),
        data: ctx.sbt_data::<u32>().unwrap_or(!0),
    }
}

/// The event of a closest-hit program.
pub fn ev_ch(ctx: &ClosestHitCtx<'_, Tp>) -> Ev {
    Ev {
        prog: Prog::Ch,
        prim: ctx.primitive_index(),
        gas: ctx.sbt_gas_index(),
        tmin: ctx.ray_tmin(),
        tmax: ctx.ray_tmax(),
        kind: ctx.hit_kind().0,
        attrs: std::array::from_fn(|i| ctx.attribute(i)),
        data: ctx.sbt_data::<u32>().unwrap_or(!0),
    }
}

/// The event of a miss program.
pub fn ev_ms(ctx: &MissCtx<'_, Tp>) -> Ev {
    Ev {
        prog: Prog::Ms,
        prim: 0,
        gas: 0,
        tmin: ctx.ray_tmin(),
        tmax: ctx.ray_tmax(),
        kind: 0,
        attrs: [0; 8],
        data: ctx.sbt_data::<u32>().unwrap_or(!0),
    }
}

/// The event of an intersection program.
pub fn ev_is(ctx: &IntersectionCtx<'_, '_, Tp>) -> Ev {
    Ev {
        prog: Prog::Is,
        prim: ctx.primitive_index(),
        gas: ctx.sbt_gas_index(),
        tmin: ctx.ray_tmin(),
        tmax: ctx.ray_tmax(),
        kind: 0,
        attrs: [0; 8],
        data: ctx.sbt_data::<u32>().unwrap_or(!0),
    }
}

/// A closest-hit program that only records itself.
pub fn log_ch(ctx: &mut ClosestHitCtx<'_, Tp>) -> ProgramResult {
    ctx.params().push(ev_ch(ctx));
    Ok(())
}

/// An any-hit program that only records itself (and so accepts the hit).
pub fn log_ah(ctx: &mut AnyHitCtx<'_, Tp>) -> ProgramResult {
    ctx.params().push(ev_ah(ctx));
    Ok(())
}

/// A miss program that only records itself.
pub fn log_ms(ctx: &mut MissCtx<'_, Tp>) -> ProgramResult {
    ctx.params().push(ev_ms(ctx));
    Ok(())
}

/// The ray of the single-ray harness: [`TraceRay`]'s arguments without the handle.
#[derive(Clone, Debug)]
pub struct RayDesc {
    /// Origin.
    pub origin: Vec3,
    /// Direction.
    pub dir: Vec3,
    /// Interval start.
    pub tmin: f32,
    /// Interval end.
    pub tmax: f32,
    /// Ray flags.
    pub flags: RayFlags,
    /// SBT offset.
    pub offset: u32,
    /// SBT stride.
    pub stride: u32,
    /// Miss index.
    pub miss: u32,
    /// Visibility mask.
    pub mask: u32,
    /// Ray time.
    pub time: f32,
}

impl RayDesc {
    /// A ray with `optixTrace`'s usual defaults: `[0, inf]`, no flags, offset 0, stride 1, miss 0.
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        RayDesc {
            origin,
            dir,
            tmin: 0.0,
            tmax: f32::INFINITY,
            flags: RayFlags::empty(),
            offset: 0,
            stride: 1,
            miss: 0,
            mask: 0xFF,
            time: 0.0,
        }
    }

    /// A ray from `(x, y, 10)` straight down `-z`.
    pub fn down(x: f32, y: f32) -> Self {
        Self::new(Vec3::new(x, y, 10.0), -Vec3::Z)
    }

    /// Sets the interval.
    pub fn interval(mut self, tmin: f32, tmax: f32) -> Self {
        (self.tmin, self.tmax) = (tmin, tmax);
        self
    }

    /// Sets the flags.
    pub fn flags(mut self, flags: RayFlags) -> Self {
        self.flags = flags;
        self
    }

    /// Sets SBT offset, stride and miss index.
    pub fn sbt(mut self, offset: u32, stride: u32, miss: u32) -> Self {
        (self.offset, self.stride, self.miss) = (offset, stride, miss);
        self
    }

    /// The trace arguments for `handle`.
    pub fn trace<'h>(&self, handle: &'h TraversableHandle) -> TraceRay<'h> {
        TraceRay::new(handle, self.origin, self.dir)
            .interval(self.tmin, self.tmax)
            .flags(self.flags)
            .sbt(self.offset, self.stride, self.miss)
            .visibility_mask(self.mask)
            .time(self.time)
    }
}

/// Launch parameters of the single-ray harness.
#[derive(Clone)]
pub struct Tp {
    /// What the ray-generation program traces.
    pub handle: TraversableHandle,
    /// The ray.
    pub ray: RayDesc,
    /// The payload passed to the trace.
    pub payload: Vec<u32>,
    /// Program invocations, in order.
    pub log: Arc<Mutex<Vec<Ev>>>,
    /// Free-form notes programs write.
    pub notes: Arc<Mutex<Vec<String>>>,
    /// The payload after the trace returned (`None` if it did not).
    pub result: Arc<Mutex<Option<Vec<u32>>>>,
}

impl Tp {
    /// Records an event.
    pub fn push(&self, e: Ev) {
        self.log.lock().unwrap().push(e);
    }

    /// Records a note.
    pub fn note(&self, s: impl Into<String>) {
        self.notes.lock().unwrap().push(s.into());
    }
}

/// Entry name of the harness's ray-generation program.
pub const RG_SINGLE: &str = "__raygen__single";

/// Adds the harness's ray-generation program: it traces `params.ray` at `params.handle` with
/// `params.payload` and stores the payload in `params.result` once the trace has returned.
pub fn with_single_raygen(m: Module<Tp>) -> Module<Tp> {
    m.raygen(RG_SINGLE, |ctx| {
        let p = ctx.params();
        let mut payload = p.payload.clone();
        ctx.trace(&p.ray.trace(&p.handle), &mut payload)?;
        *p.result.lock().unwrap() = Some(payload);
        Ok(())
    })
    .expect("raygen registers")
}

/// A hit group of the module's programs.
pub fn hit_group(
    m: &Module<Tp>,
    ch: Option<&str>,
    ah: Option<&str>,
    is: Option<&str>,
) -> ProgramGroup<Tp> {
    ProgramGroup::hit_group(oxray::HitGroupDesc {
        closest_hit: ch.map(|n| (m, n)),
        any_hit: ah.map(|n| (m, n)),
        intersection: is.map(|n| (m, n)),
    })
    .expect("hit group")
}

/// A miss group of the module's program (or a no-op miss group).
pub fn miss_group(m: &Module<Tp>, ms: Option<&str>) -> ProgramGroup<Tp> {
    ProgramGroup::miss(ms.map(|n| (m, n))).expect("miss group")
}

/// What one single-ray launch did.
#[derive(Debug)]
pub struct Outcome {
    /// The launch report.
    pub report: LaunchReport,
    /// Program invocations, in order.
    pub log: Vec<Ev>,
    /// Notes, in order.
    pub notes: Vec<String>,
    /// The payload after the trace, if it returned.
    pub payload: Option<Vec<u32>>,
}

impl Outcome {
    /// The events of one program kind.
    pub fn of(&self, p: Prog) -> Vec<Ev> {
        self.log.iter().filter(|e| e.prog == p).cloned().collect()
    }

    /// How many times a program kind ran.
    pub fn count(&self, p: Prog) -> usize {
        self.log.iter().filter(|e| e.prog == p).count()
    }

    /// The one closest-hit event (panics unless exactly one ran).
    pub fn ch(&self) -> Ev {
        let ch = self.of(Prog::Ch);
        assert_eq!(
            ch.len(),
            1,
            "expected exactly one closest-hit call: {:#?}",
            self.log
        );
        ch[0].clone()
    }

    /// The payload (panics if the trace did not return).
    pub fn payload(&self) -> Vec<u32> {
        self.payload.clone().expect("the trace returned")
    }
}

/// A single-ray pipeline: the harness's ray generation plus miss, hit-group and exception
/// records (each record's data is one `u32`).
pub struct Setup {
    /// The ray-generation group.
    pub raygen: ProgramGroup<Tp>,
    /// Miss records.
    pub miss: Vec<(ProgramGroup<Tp>, u32)>,
    /// Hit-group records.
    pub hit: Vec<(ProgramGroup<Tp>, u32)>,
    /// Exception record.
    pub exception: Option<(ProgramGroup<Tp>, u32)>,
    /// Compile options.
    pub compile: PipelineCompileOptions,
    /// Trace depth.
    pub depth: u32,
    /// Validation mode.
    pub validation: bool,
}

impl Setup {
    /// A setup whose ray generation is `m`'s [`RG_SINGLE`], with 8 payload words, 8 attribute
    /// words, trace depth 1 and no records.
    pub fn new(m: &Module<Tp>) -> Self {
        Setup {
            raygen: ProgramGroup::raygen(m, RG_SINGLE).expect("raygen group"),
            miss: Vec::new(),
            hit: Vec::new(),
            exception: None,
            compile: compile(8, 8),
            depth: 1,
            validation: false,
        }
    }

    /// Adds a hit-group record whose data is `data`.
    pub fn hit(mut self, g: &ProgramGroup<Tp>, data: u32) -> Self {
        self.hit.push((g.clone(), data));
        self
    }

    /// Adds a miss record whose data is `data`.
    pub fn miss(mut self, g: &ProgramGroup<Tp>, data: u32) -> Self {
        self.miss.push((g.clone(), data));
        self
    }

    /// Sets the exception record.
    pub fn exception(mut self, g: &ProgramGroup<Tp>, data: u32) -> Self {
        self.exception = Some((g.clone(), data));
        self
    }

    /// Sets the trace depth.
    pub fn depth(mut self, d: u32) -> Self {
        self.depth = d;
        self
    }

    /// Builds the pipeline and the SBT.
    pub fn build(&self) -> (Pipeline<Tp>, ShaderBindingTable) {
        let mut groups = vec![self.raygen.clone()];
        groups.extend(self.miss.iter().map(|(g, _)| g.clone()));
        groups.extend(self.hit.iter().map(|(g, _)| g.clone()));
        groups.extend(self.exception.iter().map(|(g, _)| g.clone()));
        let ctx = DeviceContext::new().validation_mode(self.validation);
        let pipeline =
            Pipeline::new(&ctx, &self.compile, &link(self.depth), &groups).expect("pipeline");
        let records = |v: &[(ProgramGroup<Tp>, u32)]| {
            let r: Vec<_> = v.iter().map(|(g, d)| (g.pack_header(), *d)).collect();
            SbtRegion::from_records(&r)
        };
        let sbt = ShaderBindingTable {
            raygen: SbtRegion::from_records(&[(self.raygen.pack_header(), 0u32)]),
            exception: self
                .exception
                .as_ref()
                .map(|(g, d)| SbtRegion::from_records(&[(g.pack_header(), *d)])),
            miss: records(&self.miss),
            hitgroup: records(&self.hit),
            ..Default::default()
        };
        (pipeline, sbt)
    }

    /// Launches one ray-generation program tracing `ray` at `handle` with `payload`.
    pub fn run(&self, handle: &TraversableHandle, ray: RayDesc, payload: &[u32]) -> Outcome {
        let (pipeline, sbt) = self.build();
        let params = Tp {
            handle: handle.clone(),
            ray,
            payload: payload.to_vec(),
            log: Default::default(),
            notes: Default::default(),
            result: Default::default(),
        };
        // In validation mode a built-in exception fails the launch (§4.3); the harness reports
        // it like any other exception so that tests can inspect it.
        let report = match pipeline.launch(&params, &sbt, 1, 1, 1) {
            Ok(report) => report,
            Err(oxray::LaunchError::ValidationFailure { index, exception }) => {
                oxray::LaunchReport {
                    exceptions: 1,
                    first_exceptions: vec![(index, exception)],
                    ..Default::default()
                }
            }
            Err(e) => panic!("launch: {e}"),
        };
        let log = params.log.lock().unwrap().clone();
        let notes = params.notes.lock().unwrap().clone();
        let payload = params.result.lock().unwrap().clone();
        Outcome {
            report,
            log,
            notes,
            payload,
        }
    }
}

/// The next float above `x` (for finite positive `x`).
pub fn next_up(x: f32) -> f32 {
    f32::from_bits(x.to_bits() + 1)
}

/// The next float below `x` (for finite positive `x`).
pub fn next_down(x: f32) -> f32 {
    f32::from_bits(x.to_bits() - 1)
}
