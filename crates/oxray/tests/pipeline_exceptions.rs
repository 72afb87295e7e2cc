//! Conformance of exceptions (guide §13.14, §4.3; inventory Z2, Z7 G38, G39): trace depth, user
//! exceptions and their details, the end of the launch index, the launch report standing in for
//! the built-in exception program, validation mode, invalid SBT indices and the pipeline's
//! traversable-graph and primitive-type flags.

mod pipeline_common;

use oxray::{
    DeviceContext, Exception, ExceptionCode, ExceptionCtx, LogLevel, Module, OutputBuffer,
    Pipeline, PrimitiveTypeFlags, ProgramGroup, SbtRegion, ShaderBindingTable, TraceRay,
    TraversableGraphFlags, TraversableHandle,
};
use pipeline_common::*;
use std::sync::{Arc, Mutex};

const CH: &str = "__closesthit__log";
const AH: &str = "__anyhit__log";
const MS: &str = "__miss__log";
const EX: &str = "__exception__note";

/// An exception program that notes `EX <code> <details> <launch index>`.
fn ex_note(ctx: &mut ExceptionCtx<'_, Tp>) {
    let e = ctx.exception();
    let note = format!(
        "EX {} {:?} {:?}",
        ctx.exception_code().0,
        e.details(),
        ctx.launch_index()
    );
    ctx.params().note(note);
}

fn logging_module() -> Module<Tp> {
    with_single_raygen(Module::new())
        .closest_hit(CH, log_ch)
        .unwrap()
        .any_hit(AH, log_ah)
        .unwrap()
        .miss(MS, log_ms)
        .unwrap()
        .exception(EX, ex_note)
        .unwrap()
}

/// A setup with one hit record, one miss record and the noting exception program.
fn setup(m: &Module<Tp>, ch: &str, ms: &str) -> Setup {
    let hg = hit_group(m, Some(ch), Some(AH), None);
    let ms = miss_group(m, Some(ms));
    let ex = ProgramGroup::exception(m, EX).unwrap();
    Setup::new(m).hit(&hg, 0).miss(&ms, 0).exception(&ex, 0)
}

fn one_triangle() -> TraversableHandle {
    TraversableHandle::from(tri_gas(&[tri_at(0.0, 0.0, 0.0, 1.0)]))
}

fn only_exception(out: &Outcome) -> Exception {
    assert_eq!(out.report.exceptions, 1, "{:?}", out.report);
    assert_eq!(out.report.first_exceptions.len(), 1);
    assert_eq!(out.report.first_exceptions[0].0, [0, 0, 0]);
    out.report.first_exceptions[0].1
}

/// §13.14 / §6.7 / Z2 / Z7 G38: with `max_trace_depth` 0 the ray-generation program may not
/// trace: its trace raises `TRACE_DEPTH_EXCEEDED` (-2) with no details, no other program runs, the
/// exception program runs, and the code after the trace does not.
#[test]
fn trace_depth_exceeded_with_max_depth_0_13_14_g38() {
    let m = logging_module();
    let s = setup(&m, CH, MS).depth(0);
    for handle in [one_triangle(), TraversableHandle::NULL] {
        let out = s.run(&handle, RayDesc::down(0.0, 0.0), &[]);
        assert_eq!(
            only_exception(&out).code,
            ExceptionCode::TRACE_DEPTH_EXCEEDED
        );
        assert_eq!(ExceptionCode::TRACE_DEPTH_EXCEEDED.0, -2);
        assert_eq!(out.notes, vec!["EX -2 [] [0, 0, 0]"]);
        assert!(out.log.is_empty(), "{:?}", out.log);
        assert!(out.payload.is_none(), "the trace returned");
    }
}

/// §13.14 / §6.7 / Z2 / Z7 G38: recursion from closest-hit (and from miss) programs: traces up to
/// depth `max_trace_depth` run, the one at depth `max_trace_depth + 1` raises
/// `TRACE_DEPTH_EXCEEDED`; no program returns past it, and the launch index ends.
#[test]
fn trace_depth_exceeded_by_recursion_13_14_g38() {
    let m = logging_module()
        .closest_hit("__closesthit__recurse", |ctx| {
            let depth = ctx.payload(0) + 1;
            ctx.set_payload(0, depth);
            ctx.params().note(format!("CH {depth}"));
            let p = ctx.params();
            let mut payload = [depth];
            ctx.trace(&p.ray.trace(&p.handle), &mut payload)?;
            ctx.params().note(format!("CH {depth} returned"));
            Ok(())
        })
        .unwrap()
        .miss("__miss__recurse", |ctx| {
            let depth = ctx.payload(0) + 1;
            ctx.params().note(format!("MS {depth}"));
            let p = ctx.params();
            let mut payload = [depth];
            ctx.trace(&p.ray.trace(&p.handle), &mut payload)?;
            ctx.params().note(format!("MS {depth} returned"));
            Ok(())
        })
        .unwrap();
    for max in [1u32, 2, 5, 31] {
        for (what, handle, ray) in [
            ("CH", one_triangle(), RayDesc::down(0.0, 0.0)),
            ("MS", one_triangle(), RayDesc::down(5.0, 5.0)),
        ] {
            let s = setup(&m, "__closesthit__recurse", "__miss__recurse").depth(max);
            let out = s.run(&handle, ray, &[0]);
            let mut expected: Vec<String> = (1..=max).map(|d| format!("{what} {d}")).collect();
            expected.push("EX -2 [] [0, 0, 0]".to_string());
            assert_eq!(out.notes, expected, "max_trace_depth {max}");
            assert_eq!(
                only_exception(&out).code,
                ExceptionCode::TRACE_DEPTH_EXCEEDED
            );
            assert!(out.payload.is_none());
        }
    }
    // A trace at exactly the maximum depth is fine.
    let m = logging_module()
        .closest_hit("__closesthit__once", |ctx| {
            let p = ctx.params();
            let mut payload = [0];
            ctx.trace(&p.ray.trace(&TraversableHandle::NULL), &mut payload)?;
            ctx.set_payload(0, 1 + payload[0]);
            Ok(())
        })
        .unwrap()
        .miss("__miss__one", |ctx| {
            ctx.set_payload(0, 10);
            Ok(())
        })
        .unwrap();
    let s = setup(&m, "__closesthit__once", "__miss__one").depth(2);
    let out = s.run(&one_triangle(), RayDesc::down(0.0, 0.0), &[0]);
    assert_eq!(out.report.exceptions, 0);
    assert_eq!(out.payload(), vec![11]);
}

/// Parameters of the multi-index exception tests.
#[derive(Clone)]
struct Xp {
    /// Per launch index: what the exception program saw, `[code, #details, details...]`.
    seen: Arc<OutputBuffer<[u32; 10]>>,
    /// Per launch index: 1 if the code after the throw ran.
    after: Arc<OutputBuffer<u32>>,
    /// Per launch index: 1 if the index finished normally.
    done: Arc<OutputBuffer<u32>>,
}

impl Xp {
    fn new(n: usize) -> Self {
        Xp {
            seen: Arc::new(OutputBuffer::new(n)),
            after: Arc::new(OutputBuffer::new(n)),
            done: Arc::new(OutputBuffer::new(n)),
        }
    }
}

fn linear(ctx_index: [u32; 3], dims: [u32; 3]) -> usize {
    (ctx_index[0] + dims[0] * (ctx_index[1] + dims[1] * ctx_index[2])) as usize
}

/// A launch where `throws(linear index)` gives the user exception (code, details) an index
/// throws from ray generation, if any.
fn user_exception_pipeline(
    throws: fn(usize) -> Option<(i32, Vec<u32>)>,
    with_exception_program: bool,
    context: DeviceContext,
) -> (Pipeline<Xp>, ShaderBindingTable) {
    let m = Module::<Xp>::new()
        .raygen("__raygen__throw", move |ctx| {
            let i = linear(ctx.launch_index(), ctx.launch_dimensions());
            if let Some((code, details)) = throws(i) {
                ctx.throw_exception(code, &details)?;
                ctx.params().after.write(i, 1);
            }
            ctx.params().done.write(i, 1);
            Ok(())
        })
        .unwrap()
        .exception("__exception__record", |ctx| {
            let i = linear(ctx.launch_index(), ctx.launch_dimensions());
            let mut seen = [0u32; 10];
            seen[0] = ctx.exception_code().0 as u32;
            seen[1] = ctx.exception().details().len() as u32;
            for k in 0..8 {
                seen[2 + k] = ctx.exception_detail(k);
            }
            ctx.params().seen.write(i, seen);
        })
        .unwrap();
    let rg = ProgramGroup::raygen(&m, "__raygen__throw").unwrap();
    let ex = ProgramGroup::exception(&m, "__exception__record").unwrap();
    let pipeline = Pipeline::new(
        &context,
        &compile(0, 2),
        &link(0),
        &[rg.clone(), ex.clone()],
    )
    .unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        exception: with_exception_program.then(|| SbtRegion::from_headers(&[ex.pack_header()])),
        ..Default::default()
    };
    (pipeline, sbt)
}

fn details_of(i: usize) -> Vec<u32> {
    (0..i as u32).map(|j| 0x100 * i as u32 + j).collect()
}

/// §13.14 / Z2 / Z7 G39: a user exception thrown with 0 to 8 details reaches the exception program
/// with its code and exactly those details; the code after the throw does not run.
#[test]
fn user_exception_code_and_details_13_14_g39() {
    let (pipeline, sbt) = user_exception_pipeline(
        |i| Some((100 + i as i32, details_of(i))),
        true,
        DeviceContext::new(),
    );
    let p = Xp::new(9);
    let report = pipeline.launch(&p, &sbt, 9, 1, 1).unwrap();
    assert_eq!(report.exceptions, 9);
    for (i, seen) in p.seen.to_vec().into_iter().enumerate() {
        let d = details_of(i);
        let mut expected = [0u32; 10];
        expected[0] = 100 + i as u32;
        expected[1] = i as u32;
        expected[2..2 + i].copy_from_slice(&d);
        assert_eq!(seen, expected, "launch index {i}");
    }
    assert!(
        p.after.to_vec().iter().all(|&a| a == 0),
        "code after a throw ran"
    );
    assert!(
        p.done.to_vec().iter().all(|&a| a == 0),
        "a launch index went on after a throw"
    );
    let firsts: Vec<([u32; 3], i32, Vec<u32>)> = report
        .first_exceptions
        .iter()
        .map(|(ix, e)| (*ix, e.code.0, e.details().to_vec()))
        .collect();
    let expected: Vec<_> = (0..5)
        .map(|i| ([i as u32, 0, 0], 100 + i as i32, details_of(i)))
        .collect();
    assert_eq!(firsts, expected);
}

/// §13.14 / N15: user codes span `0..=2^30 - 1`; codes outside (documented choice) become
/// `2^30 - 1`, so a program cannot raise a built-in (negative) code.
#[test]
fn user_exception_code_range_13_14_n15() {
    let (pipeline, sbt) = user_exception_pipeline(
        |i| Some(([0, (1 << 30) - 1, -2, 1 << 30, i32::MIN][i], vec![])),
        true,
        DeviceContext::new(),
    );
    let p = Xp::new(5);
    // Every launch index throws; the exception program records what it saw.
    let report = pipeline.launch(&p, &sbt, 5, 1, 1).unwrap();
    assert_eq!(report.exceptions, 5, "{:?}", report.first_exceptions);
    let codes: Vec<i32> = p.seen.to_vec().iter().map(|s| s[0] as i32).collect();
    let max = ExceptionCode::MAX_USER;
    assert_eq!(max, (1 << 30) - 1);
    assert_eq!(codes, vec![0, max, max, max, max]);
    assert!(codes.iter().all(|&c| ExceptionCode(c).is_user()));
}

/// §13.14 / Z2: an exception ends only its own launch index: the others run to completion, and
/// the exception program sees the launch index that raised it.
#[test]
fn exception_ends_only_its_launch_index_13_14() {
    fn throws(i: usize) -> Option<(i32, Vec<u32>)> {
        let (x, y) = (i % 16, i / 16);
        ((x * 7 + y) % 5 == 0).then(|| (i as i32, vec![x as u32, y as u32]))
    }
    let (pipeline, sbt) = user_exception_pipeline(throws, true, DeviceContext::new());
    let p = Xp::new(256);
    let report = pipeline.launch(&p, &sbt, 16, 16, 1).unwrap();
    let (seen, after, done) = (p.seen.to_vec(), p.after.to_vec(), p.done.to_vec());
    let mut n = 0;
    for i in 0..256 {
        match throws(i) {
            Some((code, d)) => {
                n += 1;
                assert_eq!(&seen[i][..4], &[code as u32, 2, d[0], d[1]], "index {i}");
                assert_eq!((after[i], done[i]), (0, 0), "index {i}");
            }
            None => {
                assert_eq!(seen[i], [0; 10], "index {i}: no exception");
                assert_eq!(done[i], 1, "index {i} finished");
            }
        }
    }
    assert_eq!(report.exceptions, n);
}

/// §13.14 / Z2 / N15: without an exception record the launch report stands in for the built-in
/// exception program: it counts every exception and keeps the first five by launch index (x
/// fastest, then y, then z), whatever the thread count; the first five are logged.
#[test]
fn exceptions_without_exception_record_are_reported_13_14() {
    fn throws(i: usize) -> Option<(i32, Vec<u32>)> {
        // Launch 40 x 30 x 2: x % 3 == 1, and none in the first row of the first slice.
        let (x, y) = (i % 40, (i / 40) % 30);
        (x % 3 == 1 && (y > 0 || i >= 1200)).then(|| (i as i32, vec![i as u32]))
    }
    let messages = Arc::new(Mutex::new(Vec::new()));
    let sink = messages.clone();
    let context =
        DeviceContext::new().log_callback(LogLevel::Print, move |level, _tag, message| {
            sink.lock().unwrap().push((level, message.to_string()));
        });
    let (pipeline, sbt) = user_exception_pipeline(throws, false, context);
    let expected_count = (0..2400).filter(|&i| throws(i).is_some()).count() as u64;
    let expected_first: Vec<([u32; 3], i32)> = (0..2400)
        .filter(|&i| throws(i).is_some())
        .take(5)
        .map(|i| {
            (
                [(i % 40) as u32, ((i / 40) % 30) as u32, (i / 1200) as u32],
                i as i32,
            )
        })
        .collect();
    for threads in [1, 4] {
        messages.lock().unwrap().clear();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let p = Xp::new(2400);
        let report = pool
            .install(|| pipeline.launch(&p, &sbt, 40, 30, 2))
            .unwrap();
        assert_eq!(report.exceptions, expected_count, "{threads} threads");
        let first: Vec<([u32; 3], i32)> = report
            .first_exceptions
            .iter()
            .map(|(ix, e)| (*ix, e.code.0))
            .collect();
        assert_eq!(first, expected_first, "{threads} threads");
        for (ix, e) in &report.first_exceptions {
            assert_eq!(e.details(), &[linear(*ix, [40, 30, 2]) as u32]);
        }
        assert!(
            p.seen.to_vec().iter().all(|s| *s == [0; 10]),
            "no exception program ran"
        );
        let logged = messages.lock().unwrap().clone();
        assert_eq!(logged.len(), 5, "{threads} threads: {logged:?}");
        assert!(logged.iter().all(|(level, _)| *level == LogLevel::Error));
    }
}

/// §13.14 / Z2: an exception raised in an intersection, any-hit, closest-hit or miss program ends
/// the launch index: the exception program sees it, the trace does not return, and no other
/// program of the trace runs after it.
#[test]
fn user_exception_from_every_program_kind_13_14() {
    let m = logging_module()
        .intersection("__intersection__throw", |ctx| {
            ctx.params().push(ev_is(ctx));
            if ctx.params().payload[0] == 1 {
                ctx.throw_exception(1, &[ctx.primitive_index()])?;
                ctx.params().note("after IS throw");
            }
            ctx.report_intersection(9.5, 0, &[])?;
            Ok(())
        })
        .unwrap()
        .any_hit("__anyhit__throw", |ctx| {
            ctx.params().push(ev_ah(ctx));
            if ctx.params().payload[0] == 2 {
                ctx.throw_exception(2, &[7])?;
                ctx.params().note("after AH throw");
            }
            Ok(())
        })
        .unwrap()
        .closest_hit("__closesthit__throw", |ctx| {
            ctx.params().push(ev_ch(ctx));
            if ctx.params().payload[0] == 3 {
                ctx.throw_exception(3, &[8, 9])?;
                ctx.params().note("after CH throw");
            }
            Ok(())
        })
        .unwrap()
        .miss("__miss__throw", |ctx| {
            ctx.params().push(ev_ms(ctx));
            ctx.throw_exception(4, &[])?;
            ctx.params().note("after MS throw");
            Ok(())
        })
        .unwrap();
    let hg = hit_group(
        &m,
        Some("__closesthit__throw"),
        Some("__anyhit__throw"),
        Some("__intersection__throw"),
    );
    let ms = miss_group(&m, Some("__miss__throw"));
    let ex = ProgramGroup::exception(&m, EX).unwrap();
    let s = Setup::new(&m).hit(&hg, 0).miss(&ms, 0).exception(&ex, 0);
    let boxes = TraversableHandle::from(box_gas(&[cube(Vec3::ZERO, 0.5)]));
    let tris = one_triangle();
    let down = RayDesc::down(0.0, 0.0);
    for (which, handle, ray, note, programs) in [
        (
            1,
            &boxes,
            down.clone(),
            "EX 1 [0] [0, 0, 0]",
            vec![Prog::Is],
        ),
        (
            2,
            &boxes,
            down.clone(),
            "EX 2 [7] [0, 0, 0]",
            vec![Prog::Is, Prog::Ah],
        ),
        (
            3,
            &boxes,
            down.clone(),
            "EX 3 [8, 9] [0, 0, 0]",
            vec![Prog::Is, Prog::Ah, Prog::Ch],
        ),
        (
            4,
            &boxes,
            RayDesc::down(5.0, 5.0),
            "EX 4 [] [0, 0, 0]",
            vec![Prog::Ms],
        ),
        (2, &tris, down.clone(), "EX 2 [7] [0, 0, 0]", vec![Prog::Ah]),
        (
            3,
            &tris,
            down.clone(),
            "EX 3 [8, 9] [0, 0, 0]",
            vec![Prog::Ah, Prog::Ch],
        ),
    ] {
        let out = s.run(handle, ray, &[which]);
        assert_eq!(out.notes, vec![note], "program {which}");
        assert_eq!(
            out.log.iter().map(|e| e.prog).collect::<Vec<_>>(),
            programs,
            "program {which}"
        );
        assert!(out.payload.is_none(), "program {which}: the trace returned");
        assert_eq!(only_exception(&out).code.0, which as i32);
    }
}

/// §4.3 / §13.14 / Z2: in validation mode an invalid ray (NaN or infinite origin or direction,
/// zero direction, negative tmin, tmin > tmax, NaN interval) raises `INVALID_RAY`; without
/// validation mode the same ray just misses (the miss program runs, nothing is raised).
#[test]
fn invalid_ray_in_validation_mode_4_3() {
    let m = logging_module();
    let handle = one_triangle();
    let nan = f32::NAN;
    let down = RayDesc::down(0.0, 0.0);
    let cases: Vec<(&str, RayDesc)> = vec![
        (
            "NaN origin",
            RayDesc::new(Vec3::new(nan, 0.0, 10.0), -Vec3::Z),
        ),
        (
            "infinite origin",
            RayDesc::new(Vec3::new(0.0, f32::INFINITY, 10.0), -Vec3::Z),
        ),
        (
            "NaN direction",
            RayDesc::new(Vec3::new(0.0, 0.0, 10.0), Vec3::new(0.0, nan, -1.0)),
        ),
        (
            "zero direction",
            RayDesc::new(Vec3::new(0.0, 0.0, 10.0), Vec3::ZERO),
        ),
        ("negative tmin", down.clone().interval(-1.0, 100.0)),
        ("tmin > tmax", down.clone().interval(5.0, 2.0)),
        ("NaN tmin", down.clone().interval(nan, 100.0)),
        ("NaN tmax", down.clone().interval(0.0, nan)),
    ];
    for validation in [true, false] {
        let mut s = setup(&m, CH, MS);
        s.validation = validation;
        for (what, ray) in &cases {
            let out = s.run(&handle, ray.clone(), &[]);
            if validation {
                assert_eq!(
                    only_exception(&out).code,
                    ExceptionCode::INVALID_RAY,
                    "{what}"
                );
                assert!(out.log.is_empty(), "{what}: {:?}", out.log);
                assert_eq!(out.notes.len(), 1, "{what}");
                assert!(
                    out.notes[0].starts_with("EX -9 "),
                    "{what}: {:?}",
                    out.notes
                );
            } else {
                assert_eq!(out.report.exceptions, 0, "{what}");
                assert_eq!(
                    out.log.iter().map(|e| e.prog).collect::<Vec<_>>(),
                    vec![Prog::Ms],
                    "{what}"
                );
            }
        }
        // A valid ray is fine either way.
        let out = s.run(&handle, down.clone().interval(0.0, f32::INFINITY), &[]);
        assert_eq!(out.report.exceptions, 0);
        assert_eq!(out.count(Prog::Ch), 1);
    }
}

/// §7.2 / §13.2 / Z2: a miss with a miss index past the miss records raises `INVALID_MISS_SBT`
/// (-6), also with no miss records at all and with the null handle.
#[test]
fn invalid_miss_sbt_index_13_14() {
    let m = logging_module();
    let hg = hit_group(&m, Some(CH), None, None);
    let ms = miss_group(&m, Some(MS));
    let ex = ProgramGroup::exception(&m, EX).unwrap();
    let two = Setup::new(&m)
        .hit(&hg, 0)
        .miss(&ms, 0)
        .miss(&ms, 1)
        .exception(&ex, 0);
    let none = Setup::new(&m).hit(&hg, 0).exception(&ex, 0);
    for (s, miss, ok) in [
        (&two, 0, true),
        (&two, 1, true),
        (&two, 2, false),
        (&two, 0x10, false),
        (&none, 0, false),
    ] {
        for handle in [one_triangle(), TraversableHandle::NULL] {
            let out = s.run(&handle, RayDesc::down(5.0, 5.0).sbt(0, 1, miss), &[]);
            if ok {
                assert_eq!(out.report.exceptions, 0, "miss index {miss}");
                assert_eq!(out.count(Prog::Ms), 1);
            } else {
                assert_eq!(
                    only_exception(&out).code,
                    ExceptionCode::INVALID_MISS_SBT,
                    "miss index {miss}"
                );
                assert!(out.notes[0].starts_with("EX -6 "));
                assert!(out.log.is_empty());
            }
        }
    }
    assert_eq!(ExceptionCode::INVALID_MISS_SBT.0, -6);
}

/// §7.3 / Z2: a hit whose hit-group index lies past the hit records raises `INVALID_HIT_SBT` (-7)
/// before any program of that record runs (triangles and custom primitives).
#[test]
fn invalid_hit_sbt_index_13_14() {
    let m = logging_module()
        .intersection("__intersection__i", |ctx| {
            ctx.params().push(ev_is(ctx));
            ctx.report_intersection(9.5, 0, &[])?;
            Ok(())
        })
        .unwrap();
    let hg = hit_group(&m, Some(CH), Some(AH), Some("__intersection__i"));
    let ms = miss_group(&m, Some(MS));
    let ex = ProgramGroup::exception(&m, EX).unwrap();
    let s = Setup::new(&m)
        .hit(&hg, 0)
        .hit(&hg, 1)
        .miss(&ms, 0)
        .exception(&ex, 0);
    let tris = one_triangle();
    let boxes = TraversableHandle::from(box_gas(&[cube(Vec3::ZERO, 0.5)]));
    for handle in [tris, boxes] {
        for (offset, stride, ok) in [
            (0, 1, true),
            (1, 1, true),
            (2, 1, false),
            (0x12, 1, false),
            (0x11, 0x10, true),
            (5, 0, false),
        ] {
            let out = s.run(&handle, RayDesc::down(0.0, 0.0).sbt(offset, stride, 0), &[]);
            let what = format!("offset {offset:#x} stride {stride:#x}");
            if ok {
                assert_eq!(out.report.exceptions, 0, "{what}");
                assert_eq!(out.count(Prog::Ch), 1, "{what}");
            } else {
                assert_eq!(
                    only_exception(&out).code,
                    ExceptionCode::INVALID_HIT_SBT,
                    "{what}"
                );
                assert!(out.notes[0].starts_with("EX -7 "), "{what}");
                assert!(out.log.is_empty(), "{what}: {:?}", out.log);
            }
        }
    }
    assert_eq!(ExceptionCode::INVALID_HIT_SBT.0, -7);
}

/// §6.3 / §5.9.1: a pipeline whose traversable-graph flags do not allow a single GAS raises
/// `UNSUPPORTED_SINGLE_LEVEL_GAS` when a GAS is traced directly; flags that allow it (or no
/// flags) do not.
#[test]
fn traversable_graph_flags_single_gas_6_3() {
    let m = logging_module();
    let allow_gas = TraversableGraphFlags::ALLOW_SINGLE_GAS;
    let instancing = TraversableGraphFlags::ALLOW_SINGLE_LEVEL_INSTANCING;
    for (flags, ok) in [
        (TraversableGraphFlags::empty(), true),
        (allow_gas, true),
        (allow_gas | instancing, true),
        (instancing, false),
    ] {
        let mut s = setup(&m, CH, MS);
        s.compile.traversable_graph_flags = flags;
        let out = s.run(&one_triangle(), RayDesc::down(0.0, 0.0), &[]);
        if ok {
            assert_eq!(out.report.exceptions, 0, "{flags:?}");
            assert_eq!(out.count(Prog::Ch), 1);
        } else {
            assert_eq!(
                only_exception(&out).code,
                ExceptionCode::UNSUPPORTED_SINGLE_LEVEL_GAS,
                "{flags:?}"
            );
            assert!(out.log.is_empty());
        }
    }
}

/// §6.3 / §9.1: a pipeline whose primitive-type flags exclude the primitives of the traced GAS
/// raises `UNSUPPORTED_PRIMITIVE_TYPE`: triangles only with custom primitives, custom only with
/// triangles. Empty flags mean triangles and custom primitives.
#[test]
fn primitive_type_flags_6_3() {
    let m = logging_module()
        .intersection("__intersection__i", |ctx| {
            ctx.report_intersection(9.5, 0, &[])?;
            Ok(())
        })
        .unwrap();
    let hg = hit_group(&m, Some(CH), None, Some("__intersection__i"));
    let ms = miss_group(&m, Some(MS));
    let ex = ProgramGroup::exception(&m, EX).unwrap();
    let boxes = TraversableHandle::from(box_gas(&[cube(Vec3::ZERO, 0.5)]));
    let tri = PrimitiveTypeFlags::TRIANGLE;
    let custom = PrimitiveTypeFlags::CUSTOM;
    for (flags, handle, ok) in [
        (PrimitiveTypeFlags::empty(), one_triangle(), true),
        (PrimitiveTypeFlags::empty(), boxes.clone(), true),
        (tri, one_triangle(), true),
        (tri, boxes.clone(), false),
        (custom, boxes.clone(), true),
        (custom, one_triangle(), false),
        (tri | custom, boxes.clone(), true),
        (tri | custom, one_triangle(), true),
    ] {
        let mut s = Setup::new(&m).hit(&hg, 0).miss(&ms, 0).exception(&ex, 0);
        s.compile.uses_primitive_type_flags = flags;
        let out = s.run(&handle, RayDesc::down(0.0, 0.0), &[]);
        if ok {
            assert_eq!(out.report.exceptions, 0, "{flags:?} {handle:?}");
            assert_eq!(out.count(Prog::Ch), 1);
        } else {
            assert_eq!(
                only_exception(&out).code,
                ExceptionCode::UNSUPPORTED_PRIMITIVE_TYPE,
                "{flags:?} {handle:?}"
            );
        }
    }
}

/// §13.14: an exception from a nested trace (here a user exception in the nested miss program)
/// unwinds through the closest-hit program that traced: neither the CH nor the ray-generation
/// program continues.
#[test]
fn exception_in_nested_trace_unwinds_all_levels_13_14() {
    let m = logging_module()
        .closest_hit("__closesthit__nest", |ctx| {
            let p = ctx.params();
            let mut payload = [0u32];
            let r = ctx.trace(
                &TraceRay::new(&TraversableHandle::NULL, Vec3::ZERO, Vec3::X),
                &mut payload,
            );
            p.note(format!("CH nested error {}", r.is_err()));
            r?;
            p.note("CH after nested");
            Ok(())
        })
        .unwrap()
        .miss("__miss__throw", |ctx| {
            ctx.throw_exception(77, &[1, 2, 3])?;
            Ok(())
        })
        .unwrap();
    let s = setup(&m, "__closesthit__nest", "__miss__throw").depth(2);
    let out = s.run(&one_triangle(), RayDesc::down(0.0, 0.0), &[]);
    assert_eq!(
        out.notes,
        vec!["CH nested error true", "EX 77 [1, 2, 3] [0, 0, 0]"]
    );
    assert!(out.payload.is_none());
}

/// §4.3: "The error `OPTIX_ERROR_VALIDATION_FAILURE` is signaled if an error is caught when
/// validation mode is enabled. Function `optixLaunch` will synchronize after the launch and report
/// errors": in validation mode, a launch in which a built-in (non-user) exception was raised —
/// here `INVALID_RAY` — returns an error instead of `Ok`.
#[test]
fn validation_mode_launch_signals_failure_4_3() {
    let m = logging_module();
    let mut s = setup(&m, CH, MS);
    s.validation = true;
    let (pipeline, sbt) = s.build();
    let params = Tp {
        handle: one_triangle(),
        ray: RayDesc::down(0.0, 0.0).interval(-1.0, 100.0),
        payload: Vec::new(),
        log: Default::default(),
        notes: Default::default(),
        result: Default::default(),
    };
    let r = pipeline.launch(&params, &sbt, 4, 1, 1);
    assert!(
        r.is_err(),
        "validation mode caught INVALID_RAY but the launch returned {r:?}"
    );
}
