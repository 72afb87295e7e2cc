//! Direct and continuation callables (guide §15, inventory Z4) and their exceptions.

use glam::Vec3;
use oxray::cpu::Gas;
use oxray::{
    BuildOptions, DeviceContext, ExceptionCode, HitGroupDesc, Module, OutputBuffer, Pipeline,
    PipelineCompileOptions, PipelineLinkOptions, ProgramGroup, SbtRegion, ShaderBindingTable,
    TraceRay, TraversableHandle, TriangleInput, VertexBuffer,
};

#[derive(Clone)]
struct Params<'a> {
    out: &'a OutputBuffer<[u32; 2]>,
    handle: TraversableHandle,
    /// Which callable record the raygen program calls, and how.
    record: u32,
    mode: u32,
}

const MODE_DIRECT: u32 = 0;
const MODE_CONTINUATION: u32 = 1;
const MODE_WRONG_TYPES: u32 = 2;
const MODE_RECURSE: u32 = 3;

fn scene() -> Gas {
    let v = [[-1.0f32, -1.0, 1.0], [1.0, -1.0, 1.0], [0.0, 1.0, 1.0]];
    Gas::build(
        &BuildOptions::default(),
        &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()],
    )
    .unwrap()
}

/// Runs one launch index; returns what it wrote and the exception code, if any.
fn launch(record: u32, mode: u32) -> ([u32; 2], Option<ExceptionCode>) {
    let out = OutputBuffer::new(1);
    let module = Module::<Params>::new()
        .raygen("__raygen__rg", |ctx| {
            let p = ctx.params();
            let r: u32 = match p.mode {
                MODE_DIRECT => ctx.direct_call::<(u32, u32), u32>(p.record, (20, 22))?,
                MODE_CONTINUATION => ctx.continuation_call::<f32, u32>(p.record, 3.0)?,
                MODE_WRONG_TYPES => ctx.direct_call::<f32, f32>(p.record, 1.0)?.to_bits(),
                _ => ctx.direct_call::<u32, u32>(p.record, 0)?,
            };
            p.out.write(0, [r, 1]);
            Ok(())
        })
        .unwrap()
        // Record 0: a direct callable that adds its arguments and a scale from its SBT data.
        .direct_callable("__direct_callable__add", |ctx, (a, b): (u32, u32)| {
            Ok((a + b) * ctx.sbt_data::<u32>().unwrap_or(0))
        })
        .unwrap()
        // Record 1: a continuation callable that traces and returns the hit's primitive + 100.
        .continuation_callable("__continuation_callable__probe", |ctx, z: f32| {
            let p = ctx.params();
            let mut payload = [0u32; 1];
            ctx.trace(
                &TraceRay::new(&p.handle, Vec3::new(0.0, 0.0, -z), Vec3::Z),
                &mut payload,
            )?;
            Ok(payload[0] + 100)
        })
        .unwrap()
        // Record 2: a direct callable that calls itself forever.
        .direct_callable("__direct_callable__recurse", |ctx, n: u32| {
            ctx.direct_call::<u32, u32>(2, n + 1)
        })
        .unwrap()
        .closest_hit("__closesthit__ch", |ctx| {
            let prim = ctx.primitive_index();
            ctx.set_payload(0, prim + 1);
            // A direct call from closest hit (§15: allowed from CH).
            let doubled: u32 = ctx.direct_call::<(u32, u32), u32>(0, (prim + 1, 0))?;
            ctx.set_payload(0, doubled);
            Ok(())
        })
        .unwrap()
        .exception("__exception__ex", |ctx| {
            ctx.params()
                .out
                .write(0, [ctx.exception_code().0 as u32, 2]);
        })
        .unwrap();
    let rg = ProgramGroup::raygen(&module, "__raygen__rg").unwrap();
    let add = ProgramGroup::callables(Some((&module, "__direct_callable__add")), None).unwrap();
    let probe =
        ProgramGroup::callables(None, Some((&module, "__continuation_callable__probe"))).unwrap();
    let recurse =
        ProgramGroup::callables(Some((&module, "__direct_callable__recurse")), None).unwrap();
    let ms = ProgramGroup::miss(None).unwrap();
    let hg = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__ch")),
        ..Default::default()
    })
    .unwrap();
    let ex = ProgramGroup::exception(&module, "__exception__ex").unwrap();
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &PipelineCompileOptions {
            num_payload_values: 1,
            ..Default::default()
        },
        &PipelineLinkOptions { max_trace_depth: 2 },
        &[
            rg.clone(),
            add.clone(),
            probe.clone(),
            recurse.clone(),
            ms.clone(),
            hg.clone(),
            ex.clone(),
        ],
    )
    .unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        exception: Some(SbtRegion::from_headers(&[ex.pack_header()])),
        miss: SbtRegion::from_headers(&[ms.pack_header()]),
        hitgroup: SbtRegion::from_headers(&[hg.pack_header()]),
        callables: SbtRegion::from_records(&[
            (add.pack_header(), 2u32),
            (probe.pack_header(), 0u32),
            (recurse.pack_header(), 0u32),
        ]),
    };
    let params = Params {
        out: &out,
        handle: scene().into(),
        record,
        mode,
    };
    let report = pipeline.launch(&params, &sbt, 1, 1, 1).unwrap();
    let code = report.first_exceptions.first().map(|(_, e)| e.code);
    (out.read(0).unwrap(), code)
}

#[test]
fn direct_call_runs_the_records_callable_with_its_sbt_data_15_2() {
    assert_eq!(launch(0, MODE_DIRECT), ([84, 1], None));
}

#[test]
fn continuation_call_may_trace_and_closest_hit_may_call_direct_callables_15_1() {
    // The probe traces from z = -3 towards the triangle (primitive 0): CH sets 1, then doubles
    // it through record 0's scale of 2: (1 + 0) * 2 = 2; the callable adds 100.
    assert_eq!(launch(1, MODE_CONTINUATION), ([102, 1], None));
}

#[test]
fn out_of_range_callable_index_raises_callable_invalid_sbt() {
    let (out, code) = launch(7, MODE_DIRECT);
    assert_eq!(code, Some(ExceptionCode::CALLABLE_INVALID_SBT));
    assert_eq!(out, [ExceptionCode::CALLABLE_INVALID_SBT.0 as u32, 2]);
}

#[test]
fn calling_a_record_without_that_callable_kind_raises_its_exception() {
    assert_eq!(
        launch(1, MODE_DIRECT).1,
        Some(ExceptionCode::CALLABLE_NO_DC_SBT_RECORD)
    );
    assert_eq!(
        launch(0, MODE_CONTINUATION).1,
        Some(ExceptionCode::CALLABLE_NO_CC_SBT_RECORD)
    );
}

#[test]
fn wrong_argument_types_raise_parameter_mismatch() {
    assert_eq!(
        launch(0, MODE_WRONG_TYPES).1,
        Some(ExceptionCode::CALLABLE_PARAMETER_MISMATCH)
    );
}

#[test]
fn runaway_recursion_raises_stack_overflow_instead_of_crashing() {
    assert_eq!(
        launch(2, MODE_RECURSE).1,
        Some(ExceptionCode::STACK_OVERFLOW)
    );
}

#[test]
fn a_callables_group_needs_at_least_one_program() {
    assert!(matches!(
        ProgramGroup::<()>::callables(None, None),
        Err(oxray::PipelineError::EmptyCallables)
    ));
}
