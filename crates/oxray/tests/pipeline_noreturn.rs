//! Device functions that never return in OptiX (guide §13.13, §13.14; inventory Z1.14, Z2, N15):
//! `optixIgnoreIntersection`, `optixTerminateRay`, `optixThrowException`, a trace that raises, a
//! report whose any-hit terminated the ray, a callable that raised. In oxray they give an
//! `Interrupt`; these tests check that each takes effect at the call even when the program
//! drops the interrupt and returns `Ok(())`, that the first such call of a program wins over
//! later device calls, that passing the interrupt on with `?` is unchanged, and that without an
//! exception record or log callback the first five exceptions are printed to stderr as the
//! built-in exception program does.

mod pipeline_common;

use oxray::{
    DeviceContext, ExceptionCtx, LogLevel, Module, OutputBuffer, Pipeline, ProgramGroup, SbtRegion,
    ShaderBindingTable, TraceRay, TraversableHandle,
};
use pipeline_common::*;
use std::sync::{Arc, Mutex};

const CH: &str = "__closesthit__log";
const AH: &str = "__anyhit__log";
const MS: &str = "__miss__log";
const EX: &str = "__exception__note";

/// An exception program that notes `EX <code> <details>`.
fn ex_note(ctx: &mut ExceptionCtx<'_, Tp>) {
    let note = format!(
        "EX {} {:?}",
        ctx.exception_code().0,
        ctx.exception().details()
    );
    ctx.params().note(note);
}

/// The logging closest-hit, any-hit and miss programs and the noting exception program.
fn programs(m: Module<Tp>) -> Module<Tp> {
    m.closest_hit(CH, log_ch)
        .unwrap()
        .any_hit(AH, log_ah)
        .unwrap()
        .miss(MS, log_ms)
        .unwrap()
        .exception(EX, ex_note)
        .unwrap()
}

/// The harness's ray generation (trace `params.ray`, keep the payload) and [`programs`].
fn logging_module() -> Module<Tp> {
    programs(with_single_raygen(Module::new()))
}

/// One hit record, one miss record and the noting exception program.
fn setup(
    m: &Module<Tp>,
    ch: Option<&str>,
    ah: Option<&str>,
    is: Option<&str>,
    ms: Option<&str>,
) -> Setup {
    let hg = hit_group(m, ch, ah, is);
    let ms = miss_group(m, ms);
    let ex = ProgramGroup::exception(m, EX).unwrap();
    Setup::new(m).hit(&hg, 0).miss(&ms, 0).exception(&ex, 0)
}

/// `n` triangles stacked under `(0, 0)`, listed far to near: primitive `i` lies at height
/// `-(n - 1 - i)`, so a ray down from height 10 meets it at `t = 10 + (n - 1 - i)` and the
/// nearest is the last.
fn stack(n: usize) -> TraversableHandle {
    let tris: Vec<Tri> = (0..n)
        .map(|i| tri_at(0.0, 0.0, -((n - 1 - i) as f32), 1.0))
        .collect();
    TraversableHandle::from(tri_gas(&tris))
}

/// One box under `(0, 0)`, from height -1 to 1.
fn one_box() -> TraversableHandle {
    TraversableHandle::from(box_gas(&[cube(Vec3::ZERO, 1.0)]))
}

/// The one exception of a single-index launch, as `(code, details)`; `None` if there was none.
fn exception(out: &Outcome) -> Option<(i32, Vec<u32>)> {
    assert!(out.report.exceptions <= 1, "{:?}", out.report);
    assert_eq!(
        out.report.exceptions as usize,
        out.report.first_exceptions.len()
    );
    out.report.first_exceptions.first().map(|(index, e)| {
        assert_eq!(*index, [0, 0, 0]);
        (e.code.0, e.details().to_vec())
    })
}

/// The primitive index and `t` of every event of a program kind, in order.
fn prims(out: &Outcome, p: Prog) -> Vec<(u32, f32)> {
    out.of(p).iter().map(|e| (e.prim, e.tmax)).collect()
}

/// What an interrupt is, for notes: `ok`, `err <code>` for an exception, `err` otherwise.
fn describe<T>(r: &Result<T, oxray::Interrupt>) -> String {
    match r {
        Ok(_) => "ok".into(),
        Err(i) => match i.as_exception() {
            Some(e) => format!("err {}", e.code.0),
            None => "err".into(),
        },
    }
}

/// Like [`Setup::run`], with callables records added to the pipeline and the SBT (record `i`
/// is `callables[i]`, its data `i`).
fn run_with_callables(
    s: &Setup,
    callables: &[ProgramGroup<Tp>],
    handle: &TraversableHandle,
    ray: RayDesc,
    payload: &[u32],
) -> Outcome {
    let mut groups = vec![s.raygen.clone()];
    groups.extend(s.miss.iter().map(|(g, _)| g.clone()));
    groups.extend(s.hit.iter().map(|(g, _)| g.clone()));
    groups.extend(s.exception.iter().map(|(g, _)| g.clone()));
    groups.extend(callables.iter().cloned());
    let pipeline =
        Pipeline::new(&DeviceContext::new(), &s.compile, &link(s.depth), &groups).unwrap();
    let (_, mut sbt) = s.build();
    let records: Vec<_> = callables
        .iter()
        .enumerate()
        .map(|(i, g)| (g.pack_header(), i as u32))
        .collect();
    sbt.callables = SbtRegion::from_records(&records);
    let params = Tp {
        handle: handle.clone(),
        ray,
        payload: payload.to_vec(),
        log: Default::default(),
        notes: Default::default(),
        result: Default::default(),
    };
    let report = pipeline.launch(&params, &sbt, 1, 1, 1).unwrap();
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

// ---------------------------------------------------------------------------------------------
// §13.13: ignore and terminate
// ---------------------------------------------------------------------------------------------

/// §13.13: "Causes the current potential intersection to be discarded. This intersection will
/// not become the new closest-hit intersection": an any-hit program that calls
/// `ignore_intersection` on the near triangle and drops the interrupt (`Ok(())`) still ignores
/// it, so the far triangle is the closest hit; the payload it wrote before the call stays, a
/// write after the call is dropped ("Any modifications to ray payload values must be set before
/// calling these functions").
#[test]
fn s13_13_ignore_dropped_still_ignores() -> TestResult {
    let m = logging_module().any_hit("__anyhit__ignore_near", |ctx| {
        ctx.params().push(ev_ah(ctx));
        ctx.set_payload(0, ctx.payload(0) + 1);
        if ctx.primitive_index() == 1 {
            let _ = ctx.ignore_intersection();
            ctx.set_payload(1, 0xBAD);
        }
        Ok(())
    })?;
    let s = setup(&m, Some(CH), Some("__anyhit__ignore_near"), None, Some(MS));
    let out = s.run(&stack(2), RayDesc::down(0.0, 0.0), &[0, 0]);
    assert_eq!(exception(&out), None);
    let mut ah = prims(&out, Prog::Ah);
    ah.sort_by_key(|a| a.0);
    assert_eq!(ah, vec![(0, 11.0), (1, 10.0)], "{:?}", out.log);
    assert_eq!(
        prims(&out, Prog::Ch),
        vec![(0, 11.0)],
        "the far triangle is hit"
    );
    assert_eq!(out.count(Prog::Ms), 0);
    assert_eq!(out.payload(), vec![2, 0]);
    Ok(())
}

/// §13.13: "Causes the traversal execution associated with the current ray to immediately
/// terminate. After termination, the closest-hit program associated with the ray is called":
/// an any-hit program that calls `terminate_ray` on every candidate and drops the interrupt
/// still ends traversal at the first candidate, which becomes the closest hit (of eight stacked
/// triangles listed far to near, only one any-hit runs and the closest-hit program sees it).
#[test]
fn s13_13_terminate_dropped_still_terminates() -> TestResult {
    let m = logging_module().any_hit("__anyhit__terminate", |ctx| {
        ctx.params().push(ev_ah(ctx));
        ctx.set_payload(0, ctx.payload(0) + 1);
        let _ = ctx.terminate_ray();
        ctx.set_payload(1, 0xBAD);
        Ok(())
    })?;
    let s = setup(&m, Some(CH), Some("__anyhit__terminate"), None, Some(MS));
    let out = s.run(&stack(8), RayDesc::down(0.0, 0.0), &[0, 0]);
    assert_eq!(exception(&out), None);
    let ah = prims(&out, Prog::Ah);
    assert_eq!(ah.len(), 1, "traversal went on: {:?}", out.log);
    assert_eq!(
        prims(&out, Prog::Ch),
        ah,
        "the terminating candidate is the hit"
    );
    assert_eq!(out.payload(), vec![1, 0]);
    Ok(())
}

/// §13.13: the two functions "do not return to the caller": after `ignore_intersection`, a
/// `terminate_ray` in the same any-hit program is never reached, so the first call wins and
/// every candidate is ignored (the miss program runs) — whether the program drops both
/// interrupts or returns the second.
#[test]
fn s13_13_ignore_then_terminate_first_wins() -> TestResult {
    let m = logging_module()
        .any_hit("__anyhit__ignore_terminate", |ctx| {
            ctx.params().push(ev_ah(ctx));
            let _ = ctx.ignore_intersection();
            let r = ctx.terminate_ray();
            if ctx.params().payload[0] == 1 {
                return r;
            }
            Ok(())
        })?
        .miss("__miss__note", |ctx| {
            ctx.params().note("miss");
            ctx.set_payload(1, 7);
            Ok(())
        })?;
    for returned in [0, 1] {
        let s = setup(
            &m,
            Some(CH),
            Some("__anyhit__ignore_terminate"),
            None,
            Some("__miss__note"),
        );
        let out = s.run(&stack(3), RayDesc::down(0.0, 0.0), &[returned, 0]);
        assert_eq!(exception(&out), None);
        let mut ah: Vec<u32> = prims(&out, Prog::Ah).iter().map(|p| p.0).collect();
        ah.sort();
        assert_eq!(ah, vec![0, 1, 2], "returned {returned}: {:?}", out.log);
        assert_eq!(out.count(Prog::Ch), 0, "returned {returned}");
        assert_eq!(out.notes, vec!["miss"]);
        assert_eq!(out.payload(), vec![returned, 7]);
    }
    Ok(())
}

/// §13.13: the other order: after `terminate_ray`, an `ignore_intersection` in the same any-hit
/// program is never reached: the first candidate is accepted and ends traversal.
#[test]
fn s13_13_terminate_then_ignore_first_wins() -> TestResult {
    let m = logging_module().any_hit("__anyhit__terminate_ignore", |ctx| {
        ctx.params().push(ev_ah(ctx));
        let _ = ctx.terminate_ray();
        ctx.ignore_intersection()
    })?;
    let s = setup(
        &m,
        Some(CH),
        Some("__anyhit__terminate_ignore"),
        None,
        Some(MS),
    );
    let out = s.run(&stack(8), RayDesc::down(0.0, 0.0), &[]);
    assert_eq!(exception(&out), None);
    let ah = prims(&out, Prog::Ah);
    assert_eq!(ah.len(), 1, "{:?}", out.log);
    assert_eq!(prims(&out, Prog::Ch), ah);
    assert_eq!(out.count(Prog::Ms), 0);
    Ok(())
}

/// §13.13 / §13.14: after `ignore_intersection`, a throw in the same any-hit program is never
/// reached: no exception, the candidate is ignored. After a throw, an ignore is never reached:
/// the launch index ends with the exception.
#[test]
fn s13_13_ignore_and_throw_first_wins() -> TestResult {
    let m = logging_module().any_hit("__anyhit__ignore_throw", |ctx| {
        ctx.params().push(ev_ah(ctx));
        if ctx.params().payload[0] == 0 {
            let _ = ctx.ignore_intersection();
            ctx.throw_exception(5, &[1])
        } else {
            let _ = ctx.throw_exception(6, &[2]);
            ctx.ignore_intersection()
        }
    })?;
    let s = setup(&m, Some(CH), Some("__anyhit__ignore_throw"), None, Some(MS));
    let out = s.run(&stack(1), RayDesc::down(0.0, 0.0), &[0]);
    assert_eq!(exception(&out), None);
    assert_eq!(out.count(Prog::Ah), 1);
    assert_eq!((out.count(Prog::Ch), out.count(Prog::Ms)), (0, 1));
    assert_eq!(out.payload(), vec![0]);

    let out = s.run(&stack(1), RayDesc::down(0.0, 0.0), &[1]);
    assert_eq!(exception(&out), Some((6, vec![2])));
    assert_eq!(out.notes, vec!["EX 6 [2]"]);
    assert_eq!(out.count(Prog::Ah), 1);
    assert_eq!((out.count(Prog::Ch), out.count(Prog::Ms)), (0, 0));
    assert_eq!(out.payload, None, "the trace did not return");
    Ok(())
}

/// §13.13 / §13.4: when the any-hit program terminates the ray during a report, the report
/// never returns in OptiX. An intersection program that drops that interrupt and reports again
/// (nearer) gets the interrupt back at once: no second any-hit runs, the second report is not
/// a hit, payload writes after it are dropped, and the closest hit is the terminating one.
#[test]
fn s13_13_report_after_terminate_does_nothing() -> TestResult {
    let m = logging_module()
        .intersection("__intersection__twice", |ctx| {
            let p = ctx.params().clone();
            p.push(ev_is(ctx));
            let first = ctx.report_intersection(10.5, 1, &[11]);
            p.note(format!("first {}", describe(&first)));
            let second = ctx.report_intersection(9.5, 2, &[22]);
            p.note(format!("second {}", describe(&second)));
            ctx.set_payload(1, 0xBAD);
            Ok(())
        })?
        .any_hit("__anyhit__terminate_kind1", |ctx| {
            ctx.params().push(ev_ah(ctx));
            ctx.set_payload(0, ctx.payload(0) + 1);
            match ctx.hit_kind().0 {
                1 => ctx.terminate_ray(),
                _ => Ok(()),
            }
        })?;
    let s = setup(
        &m,
        Some(CH),
        Some("__anyhit__terminate_kind1"),
        Some("__intersection__twice"),
        Some(MS),
    );
    let out = s.run(&one_box(), RayDesc::down(0.0, 0.0), &[0, 0]);
    assert_eq!(exception(&out), None);
    assert_eq!(out.notes, vec!["first err", "second err"]);
    assert_eq!(out.count(Prog::Is), 1);
    let ah = out.of(Prog::Ah);
    assert_eq!(ah.len(), 1, "{:?}", out.log);
    assert_eq!((ah[0].tmax, ah[0].kind, ah[0].attrs[0]), (10.5, 1, 11));
    let ch = out.ch();
    assert_eq!((ch.tmax, ch.kind, ch.attrs[0]), (10.5, 1, 11));
    assert_eq!(out.payload(), vec![1, 0]);
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// §13.14: exceptions
// ---------------------------------------------------------------------------------------------

/// §13.14: "Control does not return to the location that triggered the exception, and execution
/// of the launch index ends": a ray-generation program that throws and drops the interrupt
/// still ends with the exception, and the exception program runs. Its later trace does nothing
/// (no program of it runs) and gives the exception back.
#[test]
fn s13_14_throw_dropped_still_raises_from_raygen() -> TestResult {
    let m = programs(Module::new()).raygen(RG_SINGLE, |ctx| {
        let p = ctx.params();
        let _ = ctx.throw_exception(7, &[1, 2]);
        let mut payload = [0u32];
        let r = ctx.trace(&p.ray.trace(&p.handle), &mut payload);
        p.note(format!("trace {}", describe(&r)));
        *p.result.lock().unwrap() = Some(payload.to_vec());
        Ok(())
    })?;
    let s = setup(&m, Some(CH), Some(AH), None, Some(MS));
    let out = s.run(&stack(1), RayDesc::down(0.0, 0.0), &[]);
    assert_eq!(exception(&out), Some((7, vec![1, 2])));
    assert_eq!(out.notes, vec!["trace err 7", "EX 7 [1, 2]"]);
    assert!(out.log.is_empty(), "the trace ran: {:?}", out.log);
    Ok(())
}

/// §13.14: a closest-hit program that throws and drops the interrupt ends the launch index:
/// the trace does not return to the ray-generation program, the exception program runs.
#[test]
fn s13_14_throw_dropped_still_raises_from_closest_hit() -> TestResult {
    let m = logging_module().closest_hit("__closesthit__throw", |ctx| {
        ctx.params().push(ev_ch(ctx));
        let _ = ctx.throw_exception(8, &[3]);
        ctx.set_payload(0, 99);
        Ok(())
    })?;
    let s = setup(&m, Some("__closesthit__throw"), Some(AH), None, Some(MS));
    let out = s.run(&stack(1), RayDesc::down(0.0, 0.0), &[0]);
    assert_eq!(exception(&out), Some((8, vec![3])));
    assert_eq!(out.notes, vec!["EX 8 [3]"]);
    assert_eq!((out.count(Prog::Ah), out.count(Prog::Ch)), (1, 1));
    assert_eq!(out.payload, None, "the trace did not return");
    Ok(())
}

/// §13.14: a miss program that throws and drops the interrupt ends the launch index.
#[test]
fn s13_14_throw_dropped_still_raises_from_miss() -> TestResult {
    let m = logging_module().miss("__miss__throw", |ctx| {
        ctx.params().push(ev_ms(ctx));
        let _ = ctx.throw_exception(9, &[]);
        ctx.set_payload(0, 99);
        Ok(())
    })?;
    let s = setup(&m, Some(CH), Some(AH), None, Some("__miss__throw"));
    let out = s.run(&TraversableHandle::NULL, RayDesc::down(0.0, 0.0), &[0]);
    assert_eq!(exception(&out), Some((9, vec![])));
    assert_eq!(out.notes, vec!["EX 9 []"]);
    assert_eq!(out.count(Prog::Ms), 1);
    assert_eq!(out.payload, None, "the trace did not return");
    Ok(())
}

/// §13.14: an any-hit program that throws and drops the interrupt ends the launch index at once:
/// the candidate is not accepted, traversal goes no further (one any-hit of eight stacked
/// triangles), no closest-hit program runs.
#[test]
fn s13_14_throw_dropped_still_raises_from_any_hit() -> TestResult {
    let m = logging_module().any_hit("__anyhit__throw", |ctx| {
        ctx.params().push(ev_ah(ctx));
        let _ = ctx.throw_exception(10, &[ctx.primitive_index()]);
        Ok(())
    })?;
    let s = setup(&m, Some(CH), Some("__anyhit__throw"), None, Some(MS));
    let out = s.run(&stack(8), RayDesc::down(0.0, 0.0), &[]);
    let ah = prims(&out, Prog::Ah);
    assert_eq!(ah.len(), 1, "traversal went on: {:?}", out.log);
    assert_eq!(exception(&out), Some((10, vec![ah[0].0])));
    assert_eq!((out.count(Prog::Ch), out.count(Prog::Ms)), (0, 0));
    assert_eq!(out.payload, None, "the trace did not return");
    Ok(())
}

/// §13.14: an intersection program that throws and drops the interrupt ends the launch index:
/// its later report does nothing (no any-hit, no hit) and gives the exception back.
#[test]
fn s13_14_throw_dropped_still_raises_from_intersection() -> TestResult {
    let m = logging_module().intersection("__intersection__throw", |ctx| {
        let p = ctx.params().clone();
        p.push(ev_is(ctx));
        let _ = ctx.throw_exception(11, &[4, 5, 6]);
        let r = ctx.report_intersection(9.5, 0, &[]);
        p.note(format!("report {}", describe(&r)));
        Ok(())
    })?;
    let s = setup(
        &m,
        Some(CH),
        Some(AH),
        Some("__intersection__throw"),
        Some(MS),
    );
    let out = s.run(&one_box(), RayDesc::down(0.0, 0.0), &[]);
    assert_eq!(exception(&out), Some((11, vec![4, 5, 6])));
    assert_eq!(out.notes, vec!["report err 11", "EX 11 [4, 5, 6]"]);
    assert_eq!(out.count(Prog::Is), 1);
    assert_eq!(
        out.count(Prog::Ah) + out.count(Prog::Ch) + out.count(Prog::Ms),
        0
    );
    assert_eq!(out.payload, None);
    Ok(())
}

/// §13.14 / §13.4: an any-hit program that throws during a report ends the launch index even if
/// the intersection program drops what the report gave back and reports again: the second
/// report runs no any-hit.
#[test]
fn s13_14_raising_report_dropped_still_raises() -> TestResult {
    let m = logging_module()
        .intersection("__intersection__twice", |ctx| {
            let p = ctx.params().clone();
            let first = ctx.report_intersection(10.5, 1, &[]);
            let second = ctx.report_intersection(9.5, 2, &[]);
            p.note(format!("{} {}", describe(&first), describe(&second)));
            Ok(())
        })?
        .any_hit("__anyhit__throw", |ctx| {
            ctx.params().push(ev_ah(ctx));
            ctx.throw_exception(12, &[ctx.hit_kind().0 as u32])
        })?;
    let s = setup(
        &m,
        Some(CH),
        Some("__anyhit__throw"),
        Some("__intersection__twice"),
        Some(MS),
    );
    let out = s.run(&one_box(), RayDesc::down(0.0, 0.0), &[]);
    assert_eq!(exception(&out), Some((12, vec![1])));
    assert_eq!(out.notes, vec!["err 12 err 12", "EX 12 [1]"]);
    assert_eq!(out.count(Prog::Ah), 1);
    assert_eq!(out.count(Prog::Ch) + out.count(Prog::Ms), 0);
    Ok(())
}

/// §13.14 / §15: a direct callable (called from a closest-hit program) that throws and drops the
/// interrupt, returning a value, still raises: the call gives the exception back instead of the
/// value, and the launch index ends even though the closest-hit program drops that too.
#[test]
fn s13_14_throw_dropped_still_raises_from_direct_callable() -> TestResult {
    let m = logging_module()
        .closest_hit("__closesthit__call", |ctx| {
            let r = ctx.direct_call::<u32, u32>(0, 5);
            ctx.params().note(format!("call {}", describe(&r)));
            ctx.set_payload(0, r.unwrap_or(0));
            Ok(())
        })?
        .direct_callable("__direct_callable__throw", |ctx, x: u32| {
            let _ = ctx.throw_exception(13, &[x]);
            Ok(x + 1)
        })?;
    let dc = ProgramGroup::callables(Some((&m, "__direct_callable__throw")), None)?;
    let s = setup(&m, Some("__closesthit__call"), None, None, Some(MS));
    let out = run_with_callables(&s, &[dc], &stack(1), RayDesc::down(0.0, 0.0), &[0]);
    assert_eq!(exception(&out), Some((13, vec![5])));
    assert_eq!(out.notes, vec!["call err 13", "EX 13 [5]"]);
    assert_eq!(out.payload, None, "the trace did not return");
    Ok(())
}

/// §13.14 / §15: a continuation callable (called from the ray-generation program) that throws
/// and drops the interrupt still raises, and so does a direct callable called from an any-hit
/// program; the callers drop what the calls give back.
#[test]
fn s13_14_throw_dropped_still_raises_from_continuation_callable() -> TestResult {
    let m = programs(Module::new())
        .raygen(RG_SINGLE, |ctx| {
            let p = ctx.params();
            let r = ctx.continuation_call::<u32, u32>(0, 3);
            p.note(format!("call {}", describe(&r)));
            Ok(())
        })?
        .continuation_callable("__continuation_callable__throw", |ctx, x: u32| {
            let _ = ctx.throw_exception(14, &[x]);
            Ok(x)
        })?;
    let cc = ProgramGroup::callables(None, Some((&m, "__continuation_callable__throw")))?;
    let s = setup(&m, Some(CH), Some(AH), None, Some(MS));
    let out = run_with_callables(&s, &[cc], &stack(1), RayDesc::down(0.0, 0.0), &[]);
    assert_eq!(exception(&out), Some((14, vec![3])));
    assert_eq!(out.notes, vec!["call err 14", "EX 14 [3]"]);
    Ok(())
}

/// §13.14 / §15: a direct callable called from an any-hit program raises and drops it; the
/// any-hit program drops the call's interrupt too: the launch index ends, the candidate is not
/// accepted.
#[test]
fn s13_14_throw_dropped_still_raises_from_callable_in_any_hit() -> TestResult {
    let m = logging_module()
        .any_hit("__anyhit__call", |ctx| {
            ctx.params().push(ev_ah(ctx));
            let _ = ctx.direct_call::<u32, u32>(0, ctx.primitive_index());
            Ok(())
        })?
        .direct_callable("__direct_callable__throw", |ctx, x: u32| {
            let _ = ctx.throw_exception(15, &[x, ctx.sbt_data::<u32>().unwrap_or(!0)]);
            Ok(x)
        })?;
    let dc = ProgramGroup::callables(Some((&m, "__direct_callable__throw")), None)?;
    let s = setup(&m, Some(CH), Some("__anyhit__call"), None, Some(MS));
    let out = run_with_callables(&s, &[dc], &stack(1), RayDesc::down(0.0, 0.0), &[]);
    assert_eq!(exception(&out), Some((15, vec![0, 0])));
    assert_eq!(out.count(Prog::Ah), 1);
    assert_eq!(out.count(Prog::Ch) + out.count(Prog::Ms), 0);
    Ok(())
}

/// §13.14 / §6.7: a trace that raises (`TRACE_DEPTH_EXCEEDED` at `max_trace_depth` 0) ends the
/// launch index even if the ray-generation program drops what it gave back and returns
/// `Ok(())`; a second trace does nothing.
#[test]
fn s13_14_failing_trace_dropped_still_raises() -> TestResult {
    let m = programs(Module::new()).raygen(RG_SINGLE, |ctx| {
        let p = ctx.params();
        let mut payload = [0u32];
        let first = ctx.trace(&p.ray.trace(&p.handle), &mut payload);
        let second = ctx.trace(&p.ray.trace(&p.handle), &mut payload);
        p.note(format!("{} {}", describe(&first), describe(&second)));
        Ok(())
    })?;
    let s = setup(&m, Some(CH), Some(AH), None, Some(MS)).depth(0);
    let out = s.run(&stack(1), RayDesc::down(0.0, 0.0), &[]);
    assert_eq!(exception(&out), Some((-2, vec![])));
    assert_eq!(out.notes, vec!["err -2 err -2", "EX -2 []"]);
    assert!(out.log.is_empty(), "{:?}", out.log);
    Ok(())
}

/// §13.14: a nested trace that raises (here from a closest-hit program, past the trace depth)
/// ends the launch index even though the closest-hit program drops it: the outer trace does not
/// return.
#[test]
fn s13_14_failing_nested_trace_dropped_still_raises() -> TestResult {
    let m = logging_module().closest_hit("__closesthit__nest", |ctx| {
        let p = ctx.params();
        let mut payload = [0u32];
        let r = ctx.trace(&p.ray.trace(&p.handle), &mut payload);
        p.note(format!("nested {}", describe(&r)));
        ctx.set_payload(0, 99);
        Ok(())
    })?;
    let s = setup(&m, Some("__closesthit__nest"), Some(AH), None, Some(MS));
    let out = s.run(&stack(1), RayDesc::down(0.0, 0.0), &[0]);
    assert_eq!(exception(&out), Some((-2, vec![])));
    assert_eq!(out.notes, vec!["nested err -2", "EX -2 []"]);
    assert_eq!(out.count(Prog::Ah), 1);
    assert_eq!(out.payload, None, "the outer trace did not return");
    Ok(())
}

/// §13.14: an exception raised two traces deep (a user exception in the miss program of a trace
/// made by a closest-hit program), dropped at every level, ends the launch index.
#[test]
fn s13_14_exception_in_nested_miss_dropped_at_every_level_still_raises() -> TestResult {
    let m = programs(Module::new())
        .raygen(RG_SINGLE, |ctx| {
            let p = ctx.params();
            let mut payload = [0u32];
            let r = ctx.trace(&p.ray.trace(&p.handle), &mut payload);
            p.note(format!("outer {}", describe(&r)));
            Ok(())
        })?
        .closest_hit("__closesthit__nest", |ctx| {
            let mut payload = [0u32];
            let ray = TraceRay::new(&TraversableHandle::NULL, Vec3::ZERO, Vec3::X);
            let r = ctx.trace(&ray, &mut payload);
            ctx.params().note(format!("inner {}", describe(&r)));
            Ok(())
        })?
        .miss("__miss__throw", |ctx| {
            let _ = ctx.throw_exception(16, &[ctx.launch_index()[0]]);
            Ok(())
        })?;
    let s = setup(
        &m,
        Some("__closesthit__nest"),
        Some(AH),
        None,
        Some("__miss__throw"),
    )
    .depth(2);
    let out = s.run(&stack(1), RayDesc::down(0.0, 0.0), &[]);
    assert_eq!(exception(&out), Some((16, vec![0])));
    assert_eq!(out.notes, vec!["inner err 16", "outer err 16", "EX 16 [0]"]);
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Passing interrupts on with `?` (the idiomatic way) is unchanged
// ---------------------------------------------------------------------------------------------

/// §13.13: ignore and terminate returned from the any-hit program (with `return` and `?`) behave
/// as before: of five stacked triangles, the any-hit program ignores primitives 3 and 4 (the
/// nearest) and terminates on any other; nothing after the calls runs.
#[test]
fn s13_13_ignore_and_terminate_passed_on_unchanged() -> TestResult {
    let m = logging_module().any_hit("__anyhit__pass_on", |ctx| {
        ctx.params().push(ev_ah(ctx));
        if ctx.primitive_index() >= 3 {
            return ctx.ignore_intersection();
        }
        ctx.terminate_ray()?;
        ctx.params().note("after terminate");
        Ok(())
    })?;
    let s = setup(&m, Some(CH), Some("__anyhit__pass_on"), None, Some(MS));
    let out = s.run(&stack(5), RayDesc::down(0.0, 0.0), &[]);
    assert_eq!(exception(&out), None);
    assert!(out.notes.is_empty(), "{:?}", out.notes);
    // The terminating candidate is the last any-hit, and the closest hit.
    let ah = prims(&out, Prog::Ah);
    let last = *ah.last().unwrap();
    assert!(last.0 < 3, "{ah:?}");
    assert!(ah[..ah.len() - 1].iter().all(|p| p.0 >= 3), "{ah:?}");
    assert_eq!(prims(&out, Prog::Ch), vec![last]);
    Ok(())
}

/// §13.14: a throw, a raising trace and a raising callable passed on with `?` behave as before:
/// the code after them does not run and the launch index ends with the exception.
#[test]
fn s13_14_exceptions_passed_on_unchanged() -> TestResult {
    let m = programs(Module::new())
        .raygen(RG_SINGLE, |ctx| {
            let p = ctx.params();
            match p.payload[0] {
                0 => ctx.throw_exception(20, &[1])?,
                1 => {
                    let mut payload = [0u32];
                    ctx.trace(&p.ray.trace(&p.handle), &mut payload)?;
                }
                _ => {
                    ctx.direct_call::<u32, u32>(0, 2)?;
                }
            }
            p.note("after");
            Ok(())
        })?
        .closest_hit("__closesthit__throw", |ctx| {
            ctx.throw_exception(21, &[ctx.primitive_index()])?;
            ctx.params().note("CH after");
            Ok(())
        })?
        .direct_callable("__direct_callable__throw", |ctx, x: u32| {
            ctx.throw_exception(22, &[x])?;
            ctx.params().note("DC after");
            Ok(x)
        })?;
    let dc = ProgramGroup::callables(Some((&m, "__direct_callable__throw")), None)?;
    let s = setup(&m, Some("__closesthit__throw"), Some(AH), None, Some(MS));
    let expected = [
        (20, vec![1], "EX 20 [1]"),
        (21, vec![0], "EX 21 [0]"),
        (22, vec![2], "EX 22 [2]"),
    ];
    for (mode, (code, details, note)) in expected.into_iter().enumerate() {
        let out = run_with_callables(
            &s,
            std::slice::from_ref(&dc),
            &stack(1),
            RayDesc::down(0.0, 0.0),
            &[mode as u32],
        );
        assert_eq!(exception(&out), Some((code, details)), "mode {mode}");
        assert_eq!(out.notes, vec![note], "mode {mode}");
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// §13.14: the built-in exception program
// ---------------------------------------------------------------------------------------------

/// Launch parameters of the built-in exception program tests.
#[derive(Clone)]
struct Bp<'a> {
    out: &'a OutputBuffer<u32>,
}

/// A 16 x 1 launch whose odd launch indices throw `100 + x` with detail `x` (dropping the
/// interrupt), with or without an exception record, on `context`; returns the report and what
/// the exception program saw.
fn builtin_launch(context: &DeviceContext, with_exception_record: bool) -> (u64, Vec<u32>) {
    let out = OutputBuffer::new(16);
    let module = Module::<Bp>::new()
        .raygen("__raygen__odd_throw", |ctx| {
            let x = ctx.launch_index()[0];
            if x % 2 == 1 {
                let _ = ctx.throw_exception(100 + x as i32, &[x]);
            }
            Ok(())
        })
        .unwrap()
        .exception("__exception__mark", |ctx| {
            let x = ctx.launch_index()[0];
            ctx.params()
                .out
                .write(x as usize, ctx.exception_code().0 as u32);
        })
        .unwrap();
    let rg = ProgramGroup::raygen(&module, "__raygen__odd_throw").unwrap();
    let ex = ProgramGroup::exception(&module, "__exception__mark").unwrap();
    let pipeline =
        Pipeline::new(context, &compile(1, 2), &link(1), &[rg.clone(), ex.clone()]).unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        exception: with_exception_record.then(|| SbtRegion::from_headers(&[ex.pack_header()])),
        ..Default::default()
    };
    let report = pipeline.launch(&Bp { out: &out }, &sbt, 16, 1, 1).unwrap();
    (report.exceptions, out.to_vec())
}

/// Set in the child process that
/// [`s13_14_builtin_exception_program_prints_first_five_to_stderr`] starts.
const CHILD_ENV: &str = "OXRAY_TEST_BUILTIN_EXCEPTION_CHILD";

/// The child process's part of
/// [`s13_14_builtin_exception_program_prints_first_five_to_stderr`], whose stderr the parent
/// reads: three launches of eight exceptions each, separated by markers on stderr: no
/// exception record and no log callback; a log callback; an exception record.
fn builtin_exception_program_child() {
    eprintln!("--- no record, no callback");
    let (n, seen) = builtin_launch(&DeviceContext::new(), false);
    assert_eq!(n, 8);
    assert!(seen.iter().all(|&s| s == 0));

    eprintln!("--- callback");
    let messages = Arc::new(Mutex::new(Vec::new()));
    let sink = messages.clone();
    let context = DeviceContext::new().log_callback(LogLevel::Error, move |level, tag, msg| {
        sink.lock().unwrap().push(format!("{level:?} {tag} {msg}"));
    });
    let (n, _) = builtin_launch(&context, false);
    assert_eq!(n, 8);
    let messages = messages.lock().unwrap().clone();
    assert_eq!(messages.len(), 5, "{messages:?}");
    assert_eq!(
        messages[0],
        "Error EXCEPTION launch index [1, 0, 0]: user exception (code 101, details [1])"
    );

    eprintln!("--- record");
    let (n, seen) = builtin_launch(&DeviceContext::new(), true);
    assert_eq!(n, 8);
    let expected: Vec<u32> = (0..16)
        .map(|x| if x % 2 == 1 { 100 + x } else { 0 })
        .collect();
    assert_eq!(seen, expected);
    eprintln!("--- end");
}

/// §13.14: "If exception flags are specified but no exception program is provided, a default
/// exception program is provided by NVIDIA OptiX. This built-in exception program prints the
/// first five exceptions that occurred": without an exception record and without a log
/// callback, a launch of eight exceptions prints exactly the first five (by launch index), one
/// line each, to stderr (oxray keeps the caller's stdout clean). With a log callback they go to
/// the callback instead; with an exception record nothing is printed.
#[test]
fn s13_14_builtin_exception_program_prints_first_five_to_stderr() -> TestResult {
    if std::env::var_os(CHILD_ENV).is_some() {
        // The test's own stderr is what is under test: run the launches in this process.
        builtin_exception_program_child();
        return Ok(());
    }
    let out = std::process::Command::new(std::env::current_exe()?)
        .args([
            "--exact",
            "s13_14_builtin_exception_program_prints_first_five_to_stderr",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD_ENV, "1")
        .output()?;
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "child failed: {}\n{stderr}",
        String::from_utf8_lossy(&out.stdout)
    );
    let lines: Vec<&str> = stderr
        .lines()
        .filter(|l| l.starts_with("---") || l.contains("EXCEPTION"))
        .collect();
    let mut expected = vec!["--- no record, no callback".to_string()];
    expected.extend([1, 3, 5, 7, 9].map(|x| {
        format!(
            "[oxray][EXCEPTION] launch index [{x}, 0, 0]: user exception (code {}, details [{x}])",
            100 + x
        )
    }));
    expected.extend(["--- callback", "--- record", "--- end"].map(String::from));
    assert_eq!(lines, expected, "stderr:\n{stderr}");
    assert!(
        !String::from_utf8_lossy(&out.stdout).contains("EXCEPTION"),
        "nothing on stdout"
    );
    Ok(())
}
