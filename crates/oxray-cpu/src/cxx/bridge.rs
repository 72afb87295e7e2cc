//! The frame a CUDA C++ program runs in on the CPU, the runtime functions its device calls
//! reach, and the Rust programs that wrap each compiled entry point.
//!
//! `CFrame` is `__oxray_Frame` of `oxray_device_cpu.h`, field for field (checked against the
//! compiled unit when it is loaded). A program's wrapper makes the frame the thread's current
//! one; the frame's `ctx` points at the Rust context of the running program, whose kind is
//! `kind`, so that a device call that needs the runtime (`optixTrace`, a report, a callable)
//! comes back here and continues as the same call on that context would from Rust.

use crate::interrupt::{Interrupt, InterruptKind, ProgramResult};
use crate::program::context::{Frame, NoReturn};
use crate::program::module::Program;
use crate::program::{
    AnyHitCtx, ClosestHitCtx, ContinuationCallableCtx, DirectCallableCtx, ExceptionCtx,
    IntersectionCtx, MissCtx, ProgramKind, RayGenCtx, TraceRay, TransformListKind,
};
use crate::{ExceptionCode, RayFlags, Transform};
use glam::Vec3;
use oxray_core::TraversableHandle;
use std::any::Any;
use std::ffi::{c_char, c_void};
use std::sync::Arc;

use super::CxxLaunch;

pub(crate) const KIND_RG: u32 = 0;
pub(crate) const KIND_IS: u32 = 1;
pub(crate) const KIND_AH: u32 = 2;
pub(crate) const KIND_CH: u32 = 3;
pub(crate) const KIND_MS: u32 = 4;
pub(crate) const KIND_EX: u32 = 5;
pub(crate) const KIND_DC: u32 = 6;
pub(crate) const KIND_CC: u32 = 7;

const PENDING_NONE: u32 = 0;
const PENDING_THROW: u32 = 1;
const PENDING_IGNORE: u32 = 2;
const PENDING_TERMINATE: u32 = 3;
const PENDING_RAISED: u32 = 4;
const PENDING_MISUSE: u32 = 6;

/// The device functions a program kind may not call, by the index the header gives them (the
/// detail of the exception that ends such a launch index).
pub const MISUSED_FUNCTIONS: [&str; 19] = [
    "optixGetWorldRayOrigin",
    "optixGetWorldRayDirection",
    "optixGetObjectRayOrigin",
    "optixGetObjectRayDirection",
    "optixGetTriangleVertexData",
    "optixGetPayload",
    "optixSetPayload",
    "optixIgnoreIntersection",
    "optixTerminateRay",
    "optixReportIntersection",
    "optixTrace",
    "optixContinuationCall",
    "a transform of the current hit",
    "optixGetTransformListSize",
    "optixGetTransformListHandle",
    "optixGetGASTraversableHandle",
    "optixGetSphereData",
    "a curve's vertex data (optixGet*VertexData)",
    "optixGetRibbonNormal",
];

/// The user exception that ends a launch index whose C++ program misbehaved in a way OptiX
/// rejects at compile time: code `2^30 - 1`, detail 0 the reason (1: a C++ exception of the
/// program's own escaped it; 2: it called a device function its kind may not call, detail 1
/// being the function's index in [`MISUSED_FUNCTIONS`]).
pub const PROGRAM_ERROR_CODE: i32 = ExceptionCode::MAX_USER;

#[repr(C)]
pub(crate) struct CFrame {
    pub api: *const CApi,
    pub ctx: *mut c_void,
    pub kind: u32,
    pub pending: u32,
    pub launch_index: [u32; 3],
    pub launch_dims: [u32; 3],
    pub record: *const u8,
    pub org: [f32; 3],
    pub dir: [f32; 3],
    pub tmin: f32,
    pub tmax: f32,
    pub time: f32,
    pub flags: u32,
    pub mask: u32,
    pub obj_org: [f32; 3],
    pub obj_dir: [f32; 3],
    pub prim: u32,
    pub sbt_gas_index: u32,
    pub hit_kind: u32,
    pub instance_id: u32,
    pub instance_index: u32,
    pub nattr: u32,
    pub attr: [u32; 8],
    pub payload: *mut u32,
    pub npayload: u32,
    pub exception_code: i32,
    pub ndetails: u32,
    pub details: [u32; 8],
    pub misuse: u32,
}

/// What `__oxray_frame_layout` of a unit must give: the frame's size and field offsets.
pub(crate) fn frame_layout() -> [u64; 7] {
    use std::mem::{offset_of, size_of};
    [
        size_of::<CFrame>() as u64,
        offset_of!(CFrame, record) as u64,
        offset_of!(CFrame, obj_org) as u64,
        offset_of!(CFrame, attr) as u64,
        offset_of!(CFrame, payload) as u64,
        offset_of!(CFrame, details) as u64,
        offset_of!(CFrame, misuse) as u64,
    ]
}

#[repr(C)]
pub(crate) struct CApi {
    trace: unsafe extern "C" fn(
        *mut CFrame,
        u64,
        *const f32,
        *const f32,
        f32,
        f32,
        f32,
        u32,
        u32,
        u32,
        u32,
        u32,
        *mut u32,
        u32,
    ) -> u32,
    report: unsafe extern "C" fn(*mut CFrame, f32, u32, *const u32, u32, *mut u32) -> u32,
    call:
        unsafe extern "C" fn(*mut CFrame, u32, u32, *mut c_void, *mut c_void, *const c_char) -> u32,
    transform: unsafe extern "C" fn(*mut CFrame, u32, *mut f32),
    transform_list:
        unsafe extern "C" fn(*mut CFrame, u32, *mut u32, *mut u32, *mut f32, *mut f32) -> u32,
    vertex_data: unsafe extern "C" fn(*mut CFrame, *mut f32),
    gas_handle: unsafe extern "C" fn(*mut CFrame) -> u64,
    sphere_data: unsafe extern "C" fn(*mut CFrame, *mut f32),
    curve_data: unsafe extern "C" fn(*mut CFrame, *mut f32),
    motion_transform: unsafe extern "C" fn(*mut CFrame, u32, u32) -> *const c_void,
    gas_motion: unsafe extern "C" fn(*mut CFrame, u64, *mut f32) -> u32,
    ribbon_normal: unsafe extern "C" fn(*mut CFrame, f32, f32, *mut f32),
    vertex_data_from_handle:
        unsafe extern "C" fn(*mut CFrame, u64, u32, u32, u32, f32, *mut f32) -> u32,
    instance_from_ias: unsafe extern "C" fn(
        *mut CFrame,
        u64,
        u32,
        *mut u32,
        *mut u32,
        *mut f32,
        *mut f32,
        *mut u64,
    ) -> u32,
}

static API: CApi = CApi {
    trace: api_trace,
    report: api_report,
    call: api_call,
    transform: api_transform,
    transform_list: api_transform_list,
    vertex_data: api_vertex_data,
    gas_handle: api_gas_handle,
    sphere_data: api_sphere_data,
    curve_data: api_curve_data,
    motion_transform: api_motion_transform,
    gas_motion: api_gas_motion,
    ribbon_normal: api_ribbon_normal,
    vertex_data_from_handle: api_vertex_data_from_handle,
    instance_from_ias: api_instance_from_ias,
};

/// A wrapped program: `__oxray_entry_<name>(frame)`, 0 when it returned, 1 when it unwound.
pub(crate) type ProgramEntry = unsafe extern "C" fn(*mut CFrame) -> u32;
/// A wrapped callable: `(frame, args, result, signature)`, 2 when the signatures differ.
pub(crate) type CallableEntry =
    unsafe extern "C" fn(*mut CFrame, *mut c_void, *mut c_void, *const c_char) -> u32;

/// A compiled entry point of a pipeline's unit.
#[derive(Clone, Copy)]
pub(crate) enum EntryFn {
    Program(ProgramEntry),
    Callable(CallableEntry),
}

/// The arguments of a C++ callable call as they travel through the Rust runtime.
pub(crate) struct CxxCall {
    args: *mut c_void,
    ret: *mut c_void,
    signature: *const c_char,
}

impl CFrame {
    fn new<P>(kind: u32, ctx: *mut c_void, frame: &Frame<'_, P>) -> CFrame {
        CFrame {
            api: &API,
            ctx,
            kind,
            pending: PENDING_NONE,
            launch_index: frame.index,
            launch_dims: frame.launch.dims,
            record: frame.record.as_ptr(),
            org: [0.0; 3],
            dir: [0.0; 3],
            tmin: 0.0,
            tmax: 0.0,
            time: 0.0,
            flags: 0,
            mask: 0,
            obj_org: [0.0; 3],
            obj_dir: [0.0; 3],
            prim: 0,
            sbt_gas_index: 0,
            hit_kind: 0,
            instance_id: 0,
            instance_index: 0,
            nattr: 0,
            attr: [0; 8],
            payload: std::ptr::null_mut(),
            npayload: 0,
            exception_code: 0,
            ndetails: 0,
            details: [0; 8],
            misuse: 0,
        }
    }

    fn ray(&mut self, r: &crate::program::trace::RayState) {
        self.org = r.origin.to_array();
        self.dir = r.direction.to_array();
        self.tmin = r.tmin;
        self.tmax = r.tmax;
        self.time = r.time;
        self.flags = r.flags.bits();
        self.mask = r.mask as u32;
    }

    fn hit(
        &mut self,
        h: &crate::program::trace::HitState,
        place: &crate::program::trace::Placement,
    ) {
        self.tmax = h.t;
        self.prim = h.primitive_index;
        self.sbt_gas_index = h.sbt_gas_index;
        self.hit_kind = h.hit_kind.0 as u32;
        self.instance_id = place.instance_id;
        self.instance_index = place.instance_index;
        self.attr = h.attributes;
        self.nattr = 8;
        self.obj_org = place.object_origin.to_array();
        self.obj_dir = place.object_direction.to_array();
    }

    fn payload(&mut self, p: &mut [u32]) {
        self.payload = p.as_mut_ptr();
        self.npayload = p.len() as u32;
    }
}

/// What a program's run amounts to, from how it ended.
fn settle<P>(status: u32, f: &CFrame, no_return: &NoReturn, frame: &Frame<'_, P>) -> ProgramResult {
    if status == 0 {
        return no_return.outcome(Ok(()));
    }
    match f.pending {
        PENDING_THROW => {
            let n = (f.ndetails as usize).min(8);
            no_return.call(|| frame.throw(f.exception_code, &f.details[..n]))
        }
        PENDING_IGNORE => no_return.call(|| Err(Interrupt(InterruptKind::IgnoreIntersection))),
        PENDING_TERMINATE => no_return.call(|| Err(Interrupt(InterruptKind::TerminateRay))),
        PENDING_MISUSE => no_return.call(|| {
            Err(Interrupt::exception(
                ExceptionCode(PROGRAM_ERROR_CODE),
                &[2, f.misuse],
            ))
        }),
        PENDING_RAISED => no_return.outcome(Ok(())),
        // PENDING_ESCAPED, and anything else a wrapper could leave.
        _ => no_return.call(|| {
            Err(Interrupt::exception(
                ExceptionCode(PROGRAM_ERROR_CODE),
                &[1],
            ))
        }),
    }
}

/// The Rust program that runs compiled entry `index` of module `module` of a pipeline's unit.
pub(crate) fn program(kind: ProgramKind, module: u64, index: usize) -> Program<CxxLaunch> {
    macro_rules! run {
        ($ctx:ident, $kind:expr, $fill:expr) => {{
            let Some(EntryFn::Program(entry)) = $ctx.frame.launch.params.entry(module, index)
            else {
                return missing_entry(&$ctx.no_return);
            };
            let mut f = CFrame::new($kind, std::ptr::null_mut(), &$ctx.frame);
            #[allow(clippy::redundant_closure_call)]
            ($fill)(&mut f, &mut *$ctx);
            f.ctx = $ctx as *mut _ as *mut c_void;
            // SAFETY: `entry` is a wrapper the unit compiled for this entry (its type is the
            // wrapper's, see `unit.rs`); the frame and the context it points at outlive the call,
            // and the runtime functions the program reaches through the frame use the context
            // only while the program runs, on this thread.
            let status = unsafe { entry(&mut f) };
            settle(status, &f, &$ctx.no_return, &$ctx.frame)
        }};
    }
    match kind {
        ProgramKind::RayGen => Program::RayGen(Arc::new(move |ctx: &mut RayGenCtx<'_, _>| {
            run!(ctx, KIND_RG, |_: &mut CFrame, _: &mut RayGenCtx<'_, _>| {})
        })),
        ProgramKind::ClosestHit => {
            Program::ClosestHit(Arc::new(move |ctx: &mut ClosestHitCtx<'_, CxxLaunch>| {
                run!(
                    ctx,
                    KIND_CH,
                    |f: &mut CFrame, c: &mut ClosestHitCtx<'_, CxxLaunch>| {
                        f.ray(c.ray);
                        f.hit(c.hit, c.place);
                        f.payload(c.payload);
                    }
                )
            }))
        }
        ProgramKind::AnyHit => {
            Program::AnyHit(Arc::new(move |ctx: &mut AnyHitCtx<'_, CxxLaunch>| {
                run!(
                    ctx,
                    KIND_AH,
                    |f: &mut CFrame, c: &mut AnyHitCtx<'_, CxxLaunch>| {
                        f.ray(&c.ray);
                        f.hit(&c.hit, c.place);
                        f.payload(c.payload);
                    }
                )
            }))
        }
        ProgramKind::Miss => Program::Miss(Arc::new(move |ctx: &mut MissCtx<'_, CxxLaunch>| {
            run!(
                ctx,
                KIND_MS,
                |f: &mut CFrame, c: &mut MissCtx<'_, CxxLaunch>| {
                    f.ray(c.ray);
                    f.payload(c.payload);
                }
            )
        })),
        ProgramKind::Intersection => Program::Intersection(Arc::new(
            move |ctx: &mut IntersectionCtx<'_, '_, CxxLaunch>| {
                run!(ctx, KIND_IS, |f: &mut CFrame,
                                    c: &mut IntersectionCtx<
                    '_,
                    '_,
                    CxxLaunch,
                >| {
                    f.ray(&c.ray);
                    f.hit(&c.prim, c.place);
                    f.tmax = c.tmax;
                    f.hit_kind = 0;
                    f.payload(c.reporter.payload());
                })
            },
        )),
        ProgramKind::Exception => {
            Program::Exception(Arc::new(move |ctx: &mut ExceptionCtx<'_, CxxLaunch>| {
                let Some(EntryFn::Program(entry)) = ctx.frame.launch.params.entry(module, index)
                else {
                    return;
                };
                let mut f = CFrame::new(KIND_EX, std::ptr::null_mut(), &ctx.frame);
                f.exception_code = ctx.exception.code.0;
                let d = ctx.exception.details();
                f.ndetails = d.len() as u32;
                f.details[..d.len().min(8)].copy_from_slice(&d[..d.len().min(8)]);
                f.ctx = ctx as *mut _ as *mut c_void;
                // SAFETY: as for the other kinds; an exception program calls no runtime
                // function that uses its context, and how it ends changes nothing.
                let _ = unsafe { entry(&mut f) };
            }))
        }
        ProgramKind::DirectCallable => Program::DirectCallable(Arc::new(
            move |ctx: &mut DirectCallableCtx<'_, CxxLaunch>, slot: &mut dyn Any| {
                callable(ctx, KIND_DC, module, index, slot)
            },
        )),
        ProgramKind::ContinuationCallable => Program::ContinuationCallable(Arc::new(
            move |ctx: &mut ContinuationCallableCtx<'_, CxxLaunch>, slot: &mut dyn Any| {
                callable(ctx, KIND_CC, module, index, slot)
            },
        )),
    }
}

fn missing_entry(no_return: &NoReturn) -> ProgramResult {
    // A pipeline resolves every entry of its groups when it is made; this is unreachable
    // unless a group is launched by a pipeline it was not made for.
    no_return.call(|| {
        Err(Interrupt::exception(
            ExceptionCode(PROGRAM_ERROR_CODE),
            &[3],
        ))
    })
}

/// Both callable contexts: the frame and where to record a call that does not return.
trait CallableCtx {
    fn frame(&self) -> &Frame<'_, CxxLaunch>;
    fn no_return(&self) -> &NoReturn;
}
impl CallableCtx for DirectCallableCtx<'_, CxxLaunch> {
    fn frame(&self) -> &Frame<'_, CxxLaunch> {
        &self.frame
    }
    fn no_return(&self) -> &NoReturn {
        &self.no_return
    }
}
impl CallableCtx for ContinuationCallableCtx<'_, CxxLaunch> {
    fn frame(&self) -> &Frame<'_, CxxLaunch> {
        &self.frame
    }
    fn no_return(&self) -> &NoReturn {
        &self.no_return
    }
}

/// Runs a C++ callable on the caller's `(args, result)` slot; `Ok(false)` for a signature
/// mismatch (the caller raises `CALLABLE_PARAMETER_MISMATCH`).
fn callable<C: CallableCtx>(
    ctx: &mut C,
    kind: u32,
    module: u64,
    index: usize,
    slot: &mut dyn Any,
) -> Result<bool, Interrupt> {
    let Some(slot) = slot.downcast_mut::<(Option<CxxCall>, Option<()>)>() else {
        return Ok(false);
    };
    let Some(call) = slot.0.take() else {
        return Ok(false);
    };
    let Some(EntryFn::Callable(entry)) = ctx.frame().launch.params.entry(module, index) else {
        return Ok(false);
    };
    let mut f = CFrame::new(kind, std::ptr::null_mut(), ctx.frame());
    f.ctx = ctx as *mut C as *mut c_void;
    // SAFETY: `entry` is the wrapper of this callable; `call.args` and `call.ret` point at the
    // caller's tuple and result, alive in the caller's frame for the whole call, of the types
    // the caller's signature string names: the wrapper checks that string against the
    // callable's own before it reads them.
    let status = unsafe { entry(&mut f, call.args, call.ret, call.signature) };
    match status {
        0 => {
            slot.1 = Some(());
            Ok(true)
        }
        2 => Ok(false),
        _ => {
            settle(status, &f, ctx.no_return(), ctx.frame())?;
            Ok(true)
        }
    }
}

/// The context of the program running in `f`, as the type its kind says.
///
/// # Safety
/// `f.ctx` must point at a live context of type `T` (the one whose kind is `f.kind`), used by
/// nothing else during the borrow.
unsafe fn ctx_of<T>(f: &mut CFrame) -> &mut T {
    // SAFETY: the caller's contract.
    unsafe { &mut *(f.ctx as *mut T) }
}

type Rg = RayGenCtx<'static, CxxLaunch>;
type Ch = ClosestHitCtx<'static, CxxLaunch>;
type Ah = AnyHitCtx<'static, CxxLaunch>;
type Ms = MissCtx<'static, CxxLaunch>;
type Is = IntersectionCtx<'static, 'static, CxxLaunch>;
type Dc = DirectCallableCtx<'static, CxxLaunch>;
type Cc = ContinuationCallableCtx<'static, CxxLaunch>;

/// Records an exception raised by the runtime for the program in `f`; 1 (the program unwinds).
fn raise(f: &mut CFrame, code: ExceptionCode, details: &[u32]) -> u32 {
    let e = || Err::<(), _>(Interrupt::exception(code, details));
    // SAFETY (each arm): `f.kind` names the type of `f.ctx` (set by `program` above).
    let _ = unsafe {
        match f.kind {
            KIND_RG => ctx_of::<Rg>(f).no_return.call(e),
            KIND_CH => ctx_of::<Ch>(f).no_return.call(e),
            KIND_AH => ctx_of::<Ah>(f).no_return.call(e),
            KIND_MS => ctx_of::<Ms>(f).no_return.call(e),
            KIND_IS => ctx_of::<Is>(f).no_return.call(e),
            KIND_DC => ctx_of::<Dc>(f).no_return.call(e),
            KIND_CC => ctx_of::<Cc>(f).no_return.call(e),
            _ => Ok(()),
        }
    };
    1
}

/// The launch of the program running in `f`.
fn launch_of(f: &mut CFrame) -> Option<&CxxLaunch> {
    // SAFETY (each arm): `f.kind` names the type of `f.ctx`.
    unsafe {
        Some(match f.kind {
            KIND_RG => ctx_of::<Rg>(f).frame.launch.params,
            KIND_CH => ctx_of::<Ch>(f).frame.launch.params,
            KIND_AH => ctx_of::<Ah>(f).frame.launch.params,
            KIND_MS => ctx_of::<Ms>(f).frame.launch.params,
            KIND_IS => ctx_of::<Is>(f).frame.launch.params,
            KIND_DC => ctx_of::<Dc>(f).frame.launch.params,
            KIND_CC => ctx_of::<Cc>(f).frame.launch.params,
            _ => return None,
        })
    }
}

#[allow(clippy::too_many_arguments)]
unsafe extern "C" fn api_trace(
    f: *mut CFrame,
    handle: u64,
    org: *const f32,
    dir: *const f32,
    tmin: f32,
    tmax: f32,
    time: f32,
    mask: u32,
    flags: u32,
    sbt_offset: u32,
    sbt_stride: u32,
    miss: u32,
    payload: *mut u32,
    n: u32,
) -> u32 {
    // SAFETY: the header passes the running program's frame, 3 floats at `org` and `dir`, and
    // `n` payload words at `payload` (a local array of the caller).
    let (f, org, dir, words) = unsafe {
        (
            &mut *f,
            Vec3::from_array(*(org as *const [f32; 3])),
            Vec3::from_array(*(dir as *const [f32; 3])),
            std::slice::from_raw_parts_mut(payload, n as usize),
        )
    };
    static NULL: TraversableHandle = TraversableHandle::NULL;
    // Borrowed from the launch's snapshot, not cloned: a clone would touch the structure's
    // shared reference count on every trace of every thread.
    let resolved: Option<*const TraversableHandle> = if handle == 0 {
        Some(&NULL)
    } else {
        launch_of(f)
            .and_then(|l| l.handle(handle))
            .map(|h| h as *const _)
    };
    let Some(h) = resolved else {
        return raise(f, ExceptionCode::TRAVERSAL_INVALID_TRAVERSABLE, &[]);
    };
    // SAFETY: `h` is the static null handle or lives in the launch's snapshot, which the launch
    // (and so every program of it) outlives; nothing mutates the snapshot during the launch.
    let h = unsafe { &*h };
    let ray = TraceRay::new(h, org, dir)
        .interval(tmin, tmax)
        .time(time)
        .visibility_mask(mask)
        .flags(RayFlags::from_bits_retain(flags))
        .sbt(sbt_offset, sbt_stride, miss);
    // SAFETY (each arm): `f.kind` names the type of `f.ctx`.
    let r = unsafe {
        match f.kind {
            KIND_RG => ctx_of::<Rg>(f).trace(&ray, words),
            KIND_CH => ctx_of::<Ch>(f).trace(&ray, words),
            KIND_MS => ctx_of::<Ms>(f).trace(&ray, words),
            KIND_CC => ctx_of::<Cc>(f).trace(&ray, words),
            _ => Ok(()),
        }
    };
    r.is_err() as u32
}

unsafe extern "C" fn api_report(
    f: *mut CFrame,
    t: f32,
    kind: u32,
    attr: *const u32,
    nattr: u32,
    accepted: *mut u32,
) -> u32 {
    // SAFETY: the header passes the running program's frame, `nattr` (at most 8) attribute
    // words and a result word.
    let (f, attr) = unsafe {
        (
            &mut *f,
            std::slice::from_raw_parts(attr, (nattr as usize).min(8)),
        )
    };
    if f.kind != KIND_IS {
        return 1;
    }
    // SAFETY: the kind is checked above.
    let ctx = unsafe { ctx_of::<Is>(f) };
    let r = ctx.report_intersection(t, (kind & 0x7F) as u8, attr);
    // An accepted hit shrinks the interval the program sees (guide §13.5: `optixGetRayTmax`
    // in an intersection program is the closest accepted hit so far).
    let tmax = ctx.ray_tmax();
    // The any-hit program may have written the payload through another borrow: take the
    // pointer again.
    let p = ctx.reporter.payload();
    let (ptr, len) = (p.as_mut_ptr(), p.len() as u32);
    f.payload = ptr;
    f.npayload = len;
    f.tmax = tmax;
    match r {
        Ok(a) => {
            // SAFETY: the result word of the caller.
            unsafe { *accepted = a as u32 };
            0
        }
        Err(_) => 1,
    }
}

unsafe extern "C" fn api_call(
    f: *mut CFrame,
    continuation: u32,
    sbt_index: u32,
    args: *mut c_void,
    ret: *mut c_void,
    signature: *const c_char,
) -> u32 {
    // SAFETY: the header passes the running program's frame.
    let f = unsafe { &mut *f };
    let call = CxxCall {
        args,
        ret,
        signature,
    };
    // SAFETY (each arm): `f.kind` names the type of `f.ctx`.
    let r: Result<(), Interrupt> = unsafe {
        if continuation != 0 {
            match f.kind {
                KIND_RG => ctx_of::<Rg>(f).continuation_call(sbt_index, call),
                KIND_CH => ctx_of::<Ch>(f).continuation_call(sbt_index, call),
                KIND_MS => ctx_of::<Ms>(f).continuation_call(sbt_index, call),
                KIND_CC => ctx_of::<Cc>(f).continuation_call(sbt_index, call),
                _ => Ok(()),
            }
        } else {
            match f.kind {
                KIND_RG => ctx_of::<Rg>(f).direct_call(sbt_index, call),
                KIND_CH => ctx_of::<Ch>(f).direct_call(sbt_index, call),
                KIND_AH => ctx_of::<Ah>(f).direct_call(sbt_index, call),
                KIND_MS => ctx_of::<Ms>(f).direct_call(sbt_index, call),
                KIND_IS => ctx_of::<Is>(f).direct_call(sbt_index, call),
                KIND_DC => ctx_of::<Dc>(f).direct_call(sbt_index, call),
                KIND_CC => ctx_of::<Cc>(f).direct_call(sbt_index, call),
                _ => Ok(()),
            }
        }
    };
    r.is_err() as u32
}

fn write12(out: *mut f32, t: &Transform) {
    // SAFETY: the header passes 12 floats for every matrix.
    unsafe { std::ptr::copy_nonoverlapping(t.0.as_ptr(), out, 12) };
}

unsafe extern "C" fn api_transform(f: *mut CFrame, which: u32, out: *mut f32) {
    // SAFETY: the header passes the running program's frame.
    let f = unsafe { &mut *f };
    // SAFETY (each arm): `f.kind` names the type of `f.ctx`.
    let [o2w, w2o] = unsafe {
        match f.kind {
            KIND_CH => {
                let c = ctx_of::<Ch>(f);
                [c.object_to_world_transform(), c.world_to_object_transform()]
            }
            KIND_AH => {
                let c = ctx_of::<Ah>(f);
                [c.object_to_world_transform(), c.world_to_object_transform()]
            }
            KIND_IS => {
                let c = ctx_of::<Is>(f);
                [c.object_to_world_transform(), c.world_to_object_transform()]
            }
            _ => [Transform::IDENTITY; 2],
        }
    };
    write12(out, if which == 0 { &o2w } else { &w2o });
}

unsafe extern "C" fn api_transform_list(
    f: *mut CFrame,
    i: u32,
    id: *mut u32,
    index: *mut u32,
    o2w: *mut f32,
    w2o: *mut f32,
) -> u32 {
    // SAFETY: the header passes the running program's frame.
    let f = unsafe { &mut *f };
    // SAFETY (each arm): `f.kind` names the type of `f.ctx`.
    let (size, entry) = unsafe {
        match f.kind {
            KIND_CH => {
                let c = ctx_of::<Ch>(f);
                (c.transform_list_size(), c.transform_list_entry(i))
            }
            KIND_AH => {
                let c = ctx_of::<Ah>(f);
                (c.transform_list_size(), c.transform_list_entry(i))
            }
            KIND_IS => {
                let c = ctx_of::<Is>(f);
                (c.transform_list_size(), c.transform_list_entry(i))
            }
            _ => (0, None),
        }
    };
    if i == u32::MAX {
        return size;
    }
    let Some(e) = entry else {
        return 0;
    };
    let (ty, ids) = match e.kind {
        TransformListKind::Instance {
            instance_id,
            instance_index,
        } => (4, (instance_id, instance_index)),
        TransformListKind::StaticTransform => (1, (0, 0)),
        TransformListKind::MatrixMotionTransform => (2, (0, 0)),
        TransformListKind::SrtMotionTransform => (3, (0, 0)),
    };
    // SAFETY: the header passes two result words and two 12-float matrices.
    unsafe {
        *id = ids.0;
        *index = ids.1;
    }
    write12(o2w, &e.object_to_world);
    write12(w2o, &e.world_to_object);
    ty
}

unsafe extern "C" fn api_vertex_data(f: *mut CFrame, out: *mut f32) {
    // SAFETY: the header passes the running program's frame.
    let f = unsafe { &mut *f };
    // SAFETY (each arm): `f.kind` names the type of `f.ctx`.
    let v = unsafe {
        match f.kind {
            KIND_CH => ctx_of::<Ch>(f).triangle_vertex_data(),
            KIND_AH => ctx_of::<Ah>(f).triangle_vertex_data(),
            _ => [Vec3::ZERO; 3],
        }
    };
    let flat: [f32; 9] = [
        v[0].x, v[0].y, v[0].z, v[1].x, v[1].y, v[1].z, v[2].x, v[2].y, v[2].z,
    ];
    // SAFETY: the header passes 9 floats.
    unsafe { std::ptr::copy_nonoverlapping(flat.as_ptr(), out, 9) };
}

unsafe extern "C" fn api_sphere_data(f: *mut CFrame, out: *mut f32) {
    // SAFETY: the header passes the running program's frame.
    let f = unsafe { &mut *f };
    // SAFETY (each arm): `f.kind` names the type of `f.ctx`.
    let s = unsafe {
        match f.kind {
            KIND_CH => ctx_of::<Ch>(f).sphere_data(),
            KIND_AH => ctx_of::<Ah>(f).sphere_data(),
            _ => [0.0; 4],
        }
    };
    // SAFETY: the header passes 4 floats.
    unsafe { std::ptr::copy_nonoverlapping(s.as_ptr(), out, 4) };
}

unsafe extern "C" fn api_curve_data(f: *mut CFrame, out: *mut f32) {
    // SAFETY: the header passes the running program's frame.
    let f = unsafe { &mut *f };
    // SAFETY (each arm): `f.kind` names the type of `f.ctx`.
    let p = unsafe {
        match f.kind {
            KIND_CH => ctx_of::<Ch>(f).curve_vertex_data(),
            KIND_AH => ctx_of::<Ah>(f).curve_vertex_data(),
            _ => [[0.0; 4]; 4],
        }
    };
    let flat = p.as_flattened();
    // SAFETY: the header passes 16 floats.
    unsafe { std::ptr::copy_nonoverlapping(flat.as_ptr(), out, 16) };
}

unsafe extern "C" fn api_ribbon_normal(f: *mut CFrame, u: f32, v: f32, out: *mut f32) {
    // SAFETY: the header passes the running program's frame.
    let f = unsafe { &mut *f };
    // SAFETY (each arm): `f.kind` names the type of `f.ctx`.
    let n = unsafe {
        match f.kind {
            KIND_CH => ctx_of::<Ch>(f).ribbon_normal([u, v]),
            KIND_AH => ctx_of::<Ah>(f).ribbon_normal([u, v]),
            _ => glam::Vec3::ZERO,
        }
    };
    // SAFETY: the header passes 3 floats.
    unsafe { std::ptr::copy_nonoverlapping(n.to_array().as_ptr(), out, 3) };
}

unsafe extern "C" fn api_motion_transform(f: *mut CFrame, i: u32, kind: u32) -> *const c_void {
    // SAFETY: the header passes the running program's frame.
    let f = unsafe { &mut *f };
    // The layouts live in the transforms, which the traced handle keeps alive for the launch.
    fn layout<C: MotionLookup>(c: &C, i: u32, kind: u32) -> *const c_void {
        let bytes = match kind {
            2 => c.matrix(i).map(|m| m.optix_layout()),
            3 => c.srt(i).map(|m| m.optix_layout()),
            _ => None,
        };
        bytes.map_or(std::ptr::null(), |b| b.as_ptr().cast())
    }
    // SAFETY (each arm): `f.kind` names the type of `f.ctx`.
    unsafe {
        match f.kind {
            KIND_CH => layout(ctx_of::<Ch>(f), i, kind),
            KIND_AH => layout(ctx_of::<Ah>(f), i, kind),
            KIND_IS => layout(ctx_of::<Is>(f), i, kind),
            _ => std::ptr::null(),
        }
    }
}

/// The motion transforms of a hit's transform list, whatever the program kind.
trait MotionLookup {
    fn matrix(&self, i: u32) -> Option<&oxray_core::MatrixMotionTransform>;
    fn srt(&self, i: u32) -> Option<&oxray_core::SrtMotionTransform>;
}

macro_rules! motion_lookup {
    ($($t:ty),*) => {$(
        impl MotionLookup for $t {
            fn matrix(&self, i: u32) -> Option<&oxray_core::MatrixMotionTransform> {
                self.matrix_motion_transform(i)
            }
            fn srt(&self, i: u32) -> Option<&oxray_core::SrtMotionTransform> {
                self.srt_motion_transform(i)
            }
        }
    )*};
}
motion_lookup!(Ch, Ah, Is);

unsafe extern "C" fn api_gas_motion(f: *mut CFrame, gas: u64, times: *mut f32) -> u32 {
    // SAFETY: the header passes the running program's frame.
    let f = unsafe { &mut *f };
    let found = gas_by_handle(f, gas).map(|g| g.motion_options());
    let Some(m) = found else {
        return 0;
    };
    // SAFETY: the header passes two floats.
    unsafe {
        *times = m.time_begin;
        *times.add(1) = m.time_end;
    }
    m.key_count() as u32
}

/// Random vertex access (guide §13.9) through a GAS handle: `kind` 0 a triangle (9 floats),
/// 1 a sphere (4), 2 a curve segment (16). Returns 0 and writes NaN where the access is
/// refused (a value that names no GAS, a GAS without `ALLOW_RANDOM_VERTEX_ACCESS` or of
/// another kind, no such primitive), which OptiX leaves undefined.
unsafe extern "C" fn api_vertex_data_from_handle(
    f: *mut CFrame,
    gas: u64,
    kind: u32,
    prim: u32,
    sbt: u32,
    time: f32,
    out: *mut f32,
) -> u32 {
    // SAFETY: the header passes the running program's frame.
    let f = unsafe { &mut *f };
    let words: usize = match kind {
        0 => 9,
        1 => 4,
        _ => 16,
    };
    let read = |g: &crate::Gas| -> Option<Vec<f32>> {
        match kind {
            0 => g
                .triangle_vertex_data(prim, sbt, time)
                .ok()
                .map(|t| t.iter().flat_map(|p| p.to_array()).collect()),
            1 => g.sphere_data(prim, sbt, time).ok().map(|s| s.to_vec()),
            _ => g
                .curve_vertex_data(prim, sbt, time)
                .ok()
                .map(|c| c.iter().flatten().copied().collect()),
        }
    };
    let found = gas_by_handle(f, gas).and_then(read);
    let ok = found.is_some();
    let values = found.unwrap_or_else(|| vec![f32::NAN; words]);
    for (k, v) in values.iter().take(words).enumerate() {
        // SAFETY: the header passes `words` floats for this kind.
        unsafe { *out.add(k) = *v };
    }
    u32::from(ok)
}

/// Random instance access (guide §13.12): instance `index` of the IAS a registered handle
/// names, if it was built with `ALLOW_RANDOM_INSTANCE_ACCESS`; 0 otherwise (OptiX leaves that
/// undefined).
#[allow(clippy::too_many_arguments)]
unsafe extern "C" fn api_instance_from_ias(
    f: *mut CFrame,
    ias: u64,
    index: u32,
    id: *mut u32,
    inst_index: *mut u32,
    o2w: *mut f32,
    w2o: *mut f32,
    child: *mut u64,
) -> u32 {
    // SAFETY: the header passes the running program's frame.
    let f = unsafe { &mut *f };
    let Some(inst) = launch_of(f)
        .and_then(|l| l.handle(ias))
        .and_then(|h| h.downcast_ref::<crate::Ias>())
        .and_then(|i| i.data().instance_by_index(index).ok())
    else {
        return 0;
    };
    // SAFETY: the header passes one u32 each, 12 floats per matrix and one u64.
    unsafe {
        *id = inst.instance_id;
        *inst_index = inst.index;
        for k in 0..12 {
            *o2w.add(k) = inst.object_to_world.0[k];
            *w2o.add(k) = inst.world_to_object.0[k];
        }
        *child = inst.child.address();
    }
    1
}

/// The GAS a handle value names: the hit's GAS by its address, or a structure registered for
/// the launch; a value is never followed as a pointer.
fn gas_by_handle(f: &mut CFrame, gas: u64) -> Option<&crate::Gas> {
    // SAFETY (each arm): `f.kind` names the type of `f.ctx`.
    let hit_gas = unsafe {
        match f.kind {
            KIND_CH => ctx_of::<Ch>(f).gas,
            KIND_AH => ctx_of::<Ah>(f).gas,
            _ => None,
        }
    };
    match hit_gas.filter(|g| *g as *const crate::Gas as usize as u64 == gas) {
        Some(g) => Some(g),
        None => launch_of(f)
            .and_then(|l| l.handle(gas))
            .and_then(|h| h.downcast_ref::<crate::Gas>()),
    }
}

unsafe extern "C" fn api_gas_handle(f: *mut CFrame) -> u64 {
    // SAFETY: the header passes the running program's frame.
    let f = unsafe { &mut *f };
    // SAFETY (each arm): `f.kind` names the type of `f.ctx`.
    let gas = unsafe {
        match f.kind {
            KIND_CH => ctx_of::<Ch>(f).gas,
            KIND_AH => ctx_of::<Ah>(f).gas,
            _ => None,
        }
    };
    // The structure's address: the value `optix_handle` gives a GAS traced directly.
    gas.map_or(0, |g| g as *const crate::Gas as usize as u64)
}
