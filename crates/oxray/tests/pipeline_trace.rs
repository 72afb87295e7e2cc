//! Conformance of `optixTrace` (guide §13.2–§13.5, §13.13, §5.1; inventory U.1–U.4, Z7 G1–G14):
//! the null handle, the closed interval, closest-hit selection, tmin/tmax as each program sees
//! them, ignore and terminate, the ray flags, any-hit enablement and culling.

mod pipeline_common;

use oxray::cpu::Gas;
use oxray::{
    Aabb, AabbBuffer, BuildInput, BuildOptions, CustomPrimitiveInput, DeviceContext, GeometryFlags,
    Module, Pipeline, ProgramGroup, Ray, RayFlags, SbtRegion, ShaderBindingTable, TraceRay,
    TraversableHandle, TriangleInput, VertexBuffer,
};
use pipeline_common::*;
use std::collections::BTreeSet;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;

const CH: &str = "__closesthit__log";
const AH: &str = "__anyhit__log";
const MS: &str = "__miss__log";

/// A module with the harness raygen and the logging CH, AH and MS.
fn logging_module() -> Module<Tp> {
    with_single_raygen(Module::new())
        .closest_hit(CH, log_ch)
        .unwrap()
        .any_hit(AH, log_ah)
        .unwrap()
        .miss(MS, log_ms)
        .unwrap()
}

/// A setup with two hit records (data 0 and 1) of `(ch, ah, is)` and one miss record of [`MS`].
fn setup(m: &Module<Tp>, ch: Option<&str>, ah: Option<&str>, is: Option<&str>) -> Setup {
    let hg = hit_group(m, ch, ah, is);
    let ms = miss_group(m, Some(MS));
    Setup::new(m).hit(&hg, 0).hit(&hg, 1).miss(&ms, 0)
}

/// Triangles stacked under `(0, 0)` at the given heights (primitive `i` at `zs[i]`), each shifted
/// a little in x so that their barycentrics at `(0, 0)` differ. A ray [`RayDesc::down`]`(0, 0)`
/// hits primitive `i` at `t = 10 - zs[i]`.
fn stack(zs: &[f32]) -> Arc<Gas> {
    let tris: Vec<Tri> = zs
        .iter()
        .enumerate()
        .map(|(i, &z)| tri_at(0.01 * i as f32, 0.005 * i as f32, z, 1.0))
        .collect();
    tri_gas(&tris)
}

/// Boxes stacked under `(0, 0)` at the given heights, half-size 0.5.
fn box_stack(zs: &[f32]) -> Vec<Aabb> {
    zs.iter()
        .map(|&z| cube(Vec3::new(0.0, 0.0, z), 0.5))
        .collect()
}

/// An intersection program for boxes under a ray travelling down `-z` from height 10: reports the
/// box's top face with hit kind 3 and attributes `[prim, 7]`.
fn report_top(m: Module<Tp>, name: &str) -> Module<Tp> {
    m.intersection(name, |ctx| {
        ctx.params().push(ev_is(ctx));
        let t = 10.0 - ctx.primitive_aabb().max.z;
        let prim = ctx.primitive_index();
        ctx.report_intersection(t, 3, &[prim, 7])?;
        Ok(())
    })
    .unwrap()
}

/// §13.2 / U.1 / Z7 G1: tracing the null handle runs only the miss program: no intersection,
/// any-hit or closest-hit program, whatever lies along the ray.
#[test]
fn null_handle_runs_only_miss_13_2_g1() {
    let m = report_top(logging_module(), "__intersection__top");
    let s = setup(&m, Some(CH), Some(AH), Some("__intersection__top"));
    for ray in [
        RayDesc::down(0.0, 0.0),
        RayDesc::down(0.0, 0.0).interval(0.0, 1e30),
    ] {
        let out = s.run(&TraversableHandle::NULL, ray, &[5, 6]);
        assert_eq!(
            out.log.iter().map(|e| e.prog).collect::<Vec<_>>(),
            vec![Prog::Ms]
        );
        assert_eq!(out.payload(), vec![5, 6]);
    }
    assert!(TraversableHandle::NULL.is_null());
    // The same setup does hit a real structure there.
    let handle = TraversableHandle::from(box_gas(&box_stack(&[0.0])));
    let out = s.run(&handle, RayDesc::down(0.0, 0.0), &[5, 6]);
    assert_eq!(out.count(Prog::Ch), 1);
    assert_eq!(out.count(Prog::Ms), 0);
}

/// §13.2 / U.1 / Z7 G2: the interval is closed: a triangle hit at exactly `tmin` or exactly
/// `tmax` is reported (to AH and CH); one just outside is not (the MS runs, no AH).
#[test]
fn closed_interval_triangles_13_2_g2() {
    let m = logging_module();
    let s = setup(&m, Some(CH), Some(AH), None);
    let gas = stack(&[0.0]);
    let handle = TraversableHandle::from(gas.clone());
    let t = s.run(&handle, RayDesc::down(0.0, 0.0), &[]).ch().tmax;
    let q = gas
        .intersect(&Ray::new(Vec3::new(0.0, 0.0, 10.0), -Vec3::Z))
        .unwrap();
    assert_eq!(t, q.t, "CH's ray_tmax is the hit distance");
    for (tmin, tmax, hit) in [
        (t, t, true),
        (0.0, t, true),
        (t, f32::INFINITY, true),
        (0.0, next_down(t), false),
        (next_up(t), f32::INFINITY, false),
        (next_up(t), 2.0 * t, false),
    ] {
        let out = s.run(&handle, RayDesc::down(0.0, 0.0).interval(tmin, tmax), &[]);
        if hit {
            assert_eq!(out.ch().tmax, t, "[{tmin}, {tmax}]");
            assert_eq!(out.count(Prog::Ah), 1, "[{tmin}, {tmax}]");
            assert_eq!(out.count(Prog::Ms), 0);
        } else {
            assert_eq!(
                out.log.iter().map(|e| e.prog).collect::<Vec<_>>(),
                vec![Prog::Ms],
                "[{tmin}, {tmax}]"
            );
        }
    }
}

/// §13.2 / §13.4 / U.4 / Z7 G2: an intersection reported at exactly `tmin` or `tmax` is accepted
/// (`report_intersection` returns true); one a float outside is not (returns false, no AH).
#[test]
fn closed_interval_custom_primitives_13_2_g2() {
    let m = logging_module()
        .intersection("__intersection__edges", |ctx| {
            let (tmin, tmax) = (ctx.ray_tmin(), ctx.ray_tmax());
            for (name, t) in [
                ("below tmin", next_down(tmin)),
                ("above tmax", next_up(tmax)),
                ("NaN", f32::NAN),
                ("at tmax", tmax),
                ("at tmin", tmin),
            ] {
                let r = ctx.report_intersection(t, 1, &[])?;
                ctx.params().note(format!("{name}: {r}"));
            }
            Ok(())
        })
        .unwrap();
    let s = setup(&m, Some(CH), Some(AH), Some("__intersection__edges"));
    let handle = TraversableHandle::from(box_gas(&box_stack(&[0.0])));
    let out = s.run(&handle, RayDesc::down(0.0, 0.0).interval(2.0, 30.0), &[]);
    assert_eq!(
        out.notes,
        vec![
            "below tmin: false",
            "above tmax: false",
            "NaN: false",
            "at tmax: true",
            "at tmin: true"
        ]
    );
    assert_eq!(
        out.of(Prog::Ah).iter().map(|e| e.tmax).collect::<Vec<_>>(),
        vec![30.0, 2.0]
    );
    assert_eq!(out.ch().tmax, 2.0);
}

/// §13.4 / U.4 / Z7 G3, G4: with every candidate accepted, each any-hit call sees a candidate no
/// farther than every hit accepted before it (the interval shrinks), and the closest-hit program
/// runs exactly once, for the closest hit, with that hit's primitive, hit kind and
/// barycentrics.
#[test]
fn closest_hit_runs_once_for_closest_accepted_hit_13_4_g3_g4() {
    let m = logging_module();
    let s = setup(&m, Some(CH), Some(AH), None);
    let mut rng = Rng::new(3);
    for case in 0..20 {
        let zs: Vec<f32> = (0..24).map(|_| rng.range(-5.0, 5.0)).collect();
        let gas = stack(&zs);
        let handle = TraversableHandle::from(gas.clone());
        let out = s.run(&handle, RayDesc::down(0.0, 0.0), &[]);
        let q = gas
            .intersect(&Ray::new(Vec3::new(0.0, 0.0, 10.0), -Vec3::Z))
            .unwrap();
        let ch = out.ch();
        let top = zs
            .iter()
            .enumerate()
            .fold(0, |b, (i, &z)| if z > zs[b] { i } else { b });
        assert_eq!(
            ch.prim, top as u32,
            "case {case}: the highest triangle is closest"
        );
        assert_eq!(
            (ch.prim, ch.tmax, ch.kind),
            (q.primitive_index, q.t, 0xFE),
            "case {case}"
        );
        assert_eq!(
            [ch.attrs[0], ch.attrs[1]],
            [q.u.to_bits(), q.v.to_bits()],
            "case {case}"
        );
        let ahs = out.of(Prog::Ah);
        assert!(
            ahs.iter().any(|e| e.prim == ch.prim),
            "case {case}: AH saw the closest hit"
        );
        let mut closest = f32::INFINITY;
        for e in &ahs {
            assert!(
                e.tmax <= closest,
                "case {case}: AH candidate at {} after accepting {closest}",
                e.tmax
            );
            closest = e.tmax;
        }
        // The AH saw each candidate's own attributes: the CH's match the AH call of its primitive.
        let ah_of_ch = ahs.iter().rev().find(|e| e.prim == ch.prim).unwrap();
        assert_eq!(ah_of_ch.attrs, ch.attrs, "case {case}");
        assert_eq!(
            *out.log.last().unwrap(),
            ch,
            "case {case}: CH runs after traversal"
        );
    }
}

/// §13.5 / U.4 / Z7 G5 (triangles): `ray_tmin()` is the trace's tmin in every program;
/// `ray_tmax()` is the candidate's t in AH, the hit's t in CH and the trace's tmax in MS.
#[test]
fn ray_tmin_tmax_per_program_triangles_13_5_g5() {
    let m = logging_module();
    let s = setup(&m, Some(CH), Some(AH), None);
    let gas = stack(&[0.0, -2.0]);
    let handle = TraversableHandle::from(gas);
    let out = s.run(&handle, RayDesc::down(0.0, 0.0).interval(0.5, 100.0), &[]);
    let ch = out.ch();
    assert_eq!((ch.tmin, ch.tmax), (0.5, 10.0));
    for e in out.of(Prog::Ah) {
        assert_eq!(e.tmin, 0.5);
        assert_eq!(
            e.tmax,
            if e.prim == 0 { 10.0 } else { 12.0 },
            "AH sees its candidate's t"
        );
    }
    let out = s.run(&handle, RayDesc::down(7.0, 7.0).interval(0.5, 100.0), &[]);
    let ms = out.of(Prog::Ms);
    assert_eq!(ms.len(), 1);
    assert_eq!((ms[0].tmin, ms[0].tmax), (0.5, 100.0));
    // The miss program sees the trace's tmax even when the ray passes hits beyond it.
    let out = s.run(&handle, RayDesc::down(0.0, 0.0).interval(0.25, 9.5), &[]);
    assert_eq!(
        out.of(Prog::Ms)
            .iter()
            .map(|e| (e.tmin, e.tmax))
            .collect::<Vec<_>>(),
        vec![(0.25, 9.5)]
    );
}

/// §13.5 / U.4 / Z7 G5 (custom primitives): in IS, `ray_tmax()` is the trace's tmax until a hit
/// is accepted, then the closest accepted t; `ray_tmin()` is the trace's tmin; in AH
/// `ray_tmax()` is the reported t.
#[test]
fn ray_tmin_tmax_per_program_custom_13_5_g5() {
    let m = logging_module()
        .intersection("__intersection__two", |ctx| {
            ctx.params().push(ev_is(ctx));
            let entry = 10.0 - ctx.primitive_aabb().max.z;
            let before = ctx.ray_tmax();
            let far = ctx.report_intersection(entry + 0.5, 1, &[])?;
            let mid = ctx.ray_tmax();
            let near = ctx.report_intersection(entry, 2, &[])?;
            let after = ctx.ray_tmax();
            ctx.params().note(format!(
                "prim {} tmin {} before {before} far {far} mid {mid} near {near} after {after}",
                ctx.primitive_index(),
                ctx.ray_tmin()
            ));
            Ok(())
        })
        .unwrap();
    let s = setup(&m, Some(CH), Some(AH), Some("__intersection__two"));
    // Entries at t = 9.5 and 13.5: the second box lies entirely beyond the first's hits.
    let boxes = box_stack(&[0.0, -4.0]);
    let handle = TraversableHandle::from(box_gas(&boxes));
    let out = s.run(&handle, RayDesc::down(0.0, 0.0).interval(0.5, 100.0), &[]);
    assert_eq!(
        out.notes,
        vec!["prim 0 tmin 0.5 before 100 far true mid 10 near true after 9.5"],
        "the farther box is not intersected once the interval ends before it"
    );
    assert_eq!(
        out.of(Prog::Ah)
            .iter()
            .map(|e| (e.tmin, e.tmax))
            .collect::<Vec<_>>(),
        vec![(0.5, 10.0), (0.5, 9.5)]
    );
    let ch = out.ch();
    assert_eq!((ch.prim, ch.tmin, ch.tmax, ch.kind), (0, 0.5, 9.5, 2));
}

/// §13.13 / U.4 / Z7 G6, G8: a hit ignored by AH never becomes the closest hit and does not shrink
/// the interval: the next hit behind it is found; with every hit ignored the ray misses and the
/// MS sees the full tmax. Payload written before `ignore_intersection` is kept, and the AH stops
/// at the ignore.
#[test]
fn ignore_intersection_13_13_g6_g8() {
    let m = logging_module()
        .any_hit("__anyhit__ignore_top", |ctx| {
            ctx.params().push(ev_ah(ctx));
            let calls = ctx.payload(0) + 1;
            ctx.set_payload(0, calls);
            if ctx.primitive_index() == 0 {
                ctx.set_payload(1, 0xAB);
                return ctx.ignore_intersection();
            }
            Ok(())
        })
        .unwrap()
        .any_hit("__anyhit__ignore_all", |ctx| {
            ctx.params().push(ev_ah(ctx));
            ctx.set_payload(2, ctx.payload(2) + 1);
            ctx.ignore_intersection()?;
            // Never reached: `ignore_intersection` always interrupts.
            ctx.set_payload(3, 0xDEAD);
            Ok(())
        })
        .unwrap();
    let handle = TraversableHandle::from(stack(&[0.0, -1.0, -2.0]));
    let s = setup(&m, Some(CH), Some("__anyhit__ignore_top"), None);
    let out = s.run(&handle, RayDesc::down(0.0, 0.0), &[0, 0, 0, 0]);
    let ch = out.ch();
    assert_eq!(
        (ch.prim, ch.tmax),
        (1, 11.0),
        "the hit behind the ignored one is closest"
    );
    let p = out.payload();
    assert_eq!(
        p[1], 0xAB,
        "payload written before the ignore reaches the caller"
    );
    assert_eq!(p[0] as usize, out.count(Prog::Ah));
    assert!(out.of(Prog::Ah).iter().any(|e| e.prim == 0));

    let s = setup(&m, Some(CH), Some("__anyhit__ignore_all"), None);
    let out = s.run(
        &handle,
        RayDesc::down(0.0, 0.0).interval(1.0, 50.0),
        &[0, 0, 0, 0],
    );
    assert_eq!(out.count(Prog::Ch), 0);
    let ms = out.of(Prog::Ms);
    assert_eq!(ms.len(), 1);
    assert_eq!(ms[0].tmax, 50.0, "ignored hits do not shrink tmax");
    let seen: BTreeSet<u32> = out.of(Prog::Ah).iter().map(|e| e.prim).collect();
    assert_eq!(
        seen,
        BTreeSet::from([0, 1, 2]),
        "with nothing accepted every hit is a candidate"
    );
    let p = out.payload();
    assert_eq!(p[2] as usize, out.count(Prog::Ah));
    assert_eq!(p[3], 0, "code after ignore_intersection does not run");
}

/// §13.13 / U.4 / Z7 G7 (triangles): `terminate_ray` accepts the current candidate and ends
/// traversal: no further AH calls, and the CH runs for that candidate even if closer
/// primitives exist.
#[test]
fn terminate_ray_triangles_13_13_g7() {
    let m = logging_module()
        .any_hit("__anyhit__terminate_bottom", |ctx| {
            ctx.params().push(ev_ah(ctx));
            if ctx.primitive_index() == 2 {
                ctx.set_payload(0, 0x77);
                return ctx.terminate_ray();
            }
            ctx.ignore_intersection()
        })
        .unwrap()
        .any_hit("__anyhit__terminate_first", |ctx| {
            ctx.params().push(ev_ah(ctx));
            ctx.terminate_ray()?;
            ctx.set_payload(1, 0xDEAD);
            Ok(())
        })
        .unwrap();
    let handle = TraversableHandle::from(stack(&[0.0, -1.0, -2.0, -3.0]));
    let s = setup(&m, Some(CH), Some("__anyhit__terminate_bottom"), None);
    let out = s.run(&handle, RayDesc::down(0.0, 0.0), &[0, 0]);
    let ch = out.ch();
    assert_eq!((ch.prim, ch.tmax), (2, 12.0));
    let ahs = out.of(Prog::Ah);
    assert_eq!(
        ahs.last().unwrap().prim,
        2,
        "no AH call after terminate: {ahs:#?}"
    );
    assert_eq!(ahs.iter().filter(|e| e.prim == 2).count(), 1);
    assert_eq!(out.payload(), vec![0x77, 0]);

    let s = setup(&m, Some(CH), Some("__anyhit__terminate_first"), None);
    let out = s.run(&handle, RayDesc::down(0.0, 0.0), &[0, 0]);
    let ahs = out.of(Prog::Ah);
    assert_eq!(ahs.len(), 1, "traversal ends at the first terminate");
    let ch = out.ch();
    assert_eq!(
        (ch.prim, ch.tmax, ch.attrs),
        (ahs[0].prim, ahs[0].tmax, ahs[0].attrs)
    );
    assert_eq!(
        out.payload(),
        vec![0, 0],
        "code after terminate_ray does not run"
    );
}

/// §13.13 / §13.4 / U.4 / Z7 G6, G7 (custom primitives): when AH terminates,
/// `report_intersection` interrupts the intersection program (code after the `?` does not run),
/// no other intersection or any-hit program runs, and the CH runs for the terminating hit.
#[test]
fn terminate_ray_custom_13_13_g7() {
    let m = logging_module()
        .intersection("__intersection__top", |ctx| {
            ctx.params().push(ev_is(ctx));
            let t = 10.0 - ctx.primitive_aabb().max.z;
            ctx.report_intersection(t, 0, &[ctx.primitive_index()])?;
            ctx.params().note("after report");
            Ok(())
        })
        .unwrap()
        .any_hit("__anyhit__terminate", |ctx| {
            ctx.params().push(ev_ah(ctx));
            ctx.terminate_ray()
        })
        .unwrap();
    let s = setup(
        &m,
        Some(CH),
        Some("__anyhit__terminate"),
        Some("__intersection__top"),
    );
    let handle = TraversableHandle::from(box_gas(&box_stack(&[0.0, -2.0, -4.0, -6.0])));
    let out = s.run(&handle, RayDesc::down(0.0, 0.0), &[]);
    assert!(
        out.notes.is_empty(),
        "code after a terminated report ran: {:?}",
        out.notes
    );
    assert_eq!(out.count(Prog::Is), 1, "{:#?}", out.log);
    assert_eq!(out.count(Prog::Ah), 1);
    let ah = &out.of(Prog::Ah)[0];
    let ch = out.ch();
    assert_eq!((ch.prim, ch.tmax, ch.attrs[0]), (ah.prim, ah.tmax, ah.prim));
}

/// §13.2 / U.2 / Z7 G9: with `TERMINATE_ON_FIRST_HIT` the first hit that AH does not ignore ends
/// traversal and becomes the closest hit, whose CH runs.
#[test]
fn terminate_on_first_hit_13_2_g9() {
    let m = logging_module()
        .any_hit("__anyhit__only_3", |ctx| {
            ctx.params().push(ev_ah(ctx));
            if ctx.primitive_index() != 3 {
                return ctx.ignore_intersection();
            }
            Ok(())
        })
        .unwrap();
    let zs = [0.0, -1.0, -2.0, -3.0, -4.0];
    let handle = TraversableHandle::from(stack(&zs));
    let first = RayDesc::down(0.0, 0.0).flags(RayFlags::TERMINATE_ON_FIRST_HIT);

    let s = setup(&m, Some(CH), Some(AH), None);
    let out = s.run(&handle, first.clone(), &[]);
    let ahs = out.of(Prog::Ah);
    assert_eq!(ahs.len(), 1, "the first accepted hit ends traversal");
    assert_eq!((out.ch().prim, out.ch().tmax), (ahs[0].prim, ahs[0].tmax));

    let s = setup(&m, Some(CH), Some("__anyhit__only_3"), None);
    let out = s.run(&handle, first.clone(), &[]);
    assert_eq!((out.ch().prim, out.ch().tmax), (3, 13.0));
    assert_eq!(
        out.of(Prog::Ah).last().unwrap().prim,
        3,
        "no AH after the first accepted hit"
    );
    let out = s.run(&handle, RayDesc::down(0.0, 0.0), &[]);
    assert_eq!(
        out.ch().prim,
        3,
        "without the flag the only accepted hit is closest too"
    );

    let s = setup(&m, Some(CH), None, None);
    let out = s.run(&handle, first, &[]);
    assert!(out.ch().prim < zs.len() as u32);
    assert_eq!(out.count(Prog::Ms), 0);
}

/// §13.2 / §13.4 / U.2 / Z7 G9 (custom primitives): with `TERMINATE_ON_FIRST_HIT` the first
/// accepted report ends traversal: `report_intersection` interrupts the intersection program, no
/// other intersection program runs, and the CH runs for that report.
#[test]
fn terminate_on_first_hit_custom_13_2_g9() {
    let m = logging_module()
        .intersection("__intersection__two_reports", |ctx| {
            ctx.params().push(ev_is(ctx));
            let t = 10.0 - ctx.primitive_aabb().max.z;
            ctx.report_intersection(t + 0.25, 1, &[ctx.primitive_index()])?;
            ctx.params().note("after first report");
            ctx.report_intersection(t, 2, &[ctx.primitive_index()])?;
            Ok(())
        })
        .unwrap();
    let s = setup(&m, Some(CH), Some(AH), Some("__intersection__two_reports"));
    let handle = TraversableHandle::from(box_gas(&box_stack(&[0.0, -2.0, -4.0])));
    let out = s.run(
        &handle,
        RayDesc::down(0.0, 0.0).flags(RayFlags::TERMINATE_ON_FIRST_HIT),
        &[],
    );
    assert!(
        out.notes.is_empty(),
        "the IS went on after a terminating report"
    );
    assert_eq!(out.count(Prog::Is), 1);
    let ah = out.of(Prog::Ah);
    assert_eq!(ah.len(), 1);
    let ch = out.ch();
    assert_eq!((ch.prim, ch.kind, ch.tmax), (ah[0].prim, 1, ah[0].tmax));
    // Without the flag both reports of every box along the ray are candidates until accepted.
    let out = s.run(&handle, RayDesc::down(0.0, 0.0), &[]);
    assert_eq!((out.ch().prim, out.ch().kind, out.ch().tmax), (0, 2, 9.5));
}

/// §13.5 / U.4 / Z7 G3 (custom primitives): each intersection program sees as `ray_tmax()` the
/// closest hit accepted so far (or the trace's tmax), whatever order the primitives are visited
/// in; the CH gets the closest accepted report.
#[test]
fn intersection_sees_shrinking_tmax_13_5_g3() {
    let m = logging_module()
        .intersection("__intersection__centre", |ctx| {
            let b = ctx.primitive_aabb();
            let before = ctx.ray_tmax();
            let t = 10.0 - 0.5 * (b.min.z + b.max.z);
            let r = ctx.report_intersection(t, 0, &[])?;
            ctx.params().note(format!("{before} {t} {r}"));
            Ok(())
        })
        .unwrap();
    let s = setup(&m, Some(CH), None, Some("__intersection__centre"));
    let mut rng = Rng::new(35);
    for case in 0..30 {
        // Overlapping boxes of different sizes along the ray: entries before others' centres.
        let boxes: Vec<Aabb> = (0..6)
            .map(|_| {
                let z = rng.range(-2.0, 2.0);
                let h = rng.range(0.1, 2.0);
                Aabb::new(Vec3::new(-1.0, -1.0, z - h), Vec3::new(1.0, 1.0, z + h))
            })
            .collect();
        let handle = TraversableHandle::from(box_gas(&boxes));
        let out = s.run(&handle, RayDesc::down(0.0, 0.0).interval(0.0, 40.0), &[]);
        let mut closest = 40.0f32;
        for n in &out.notes {
            let v: Vec<&str> = n.split(' ').collect();
            let (before, t, r): (f32, f32, bool) = (
                v[0].parse().unwrap(),
                v[1].parse().unwrap(),
                v[2].parse().unwrap(),
            );
            assert_eq!(before, closest, "case {case}: {:?}", out.notes);
            assert_eq!(r, t <= closest, "case {case}: {:?}", out.notes);
            closest = closest.min(t);
        }
        let best = boxes
            .iter()
            .map(|b| 10.0 - 0.5 * (b.min.z + b.max.z))
            .fold(f32::INFINITY, f32::min);
        assert_eq!(out.ch().tmax, best, "case {case}");
    }
}

/// §13.2 / U.2 / Z7 G10: with `DISABLE_CLOSESTHIT` the CH never runs, the MS still runs on a miss,
/// and payload written by IS and AH reaches the caller.
#[test]
fn disable_closesthit_13_2_g10() {
    let m = logging_module()
        .any_hit("__anyhit__write", |ctx| {
            ctx.params().push(ev_ah(ctx));
            ctx.set_payload(1, 77);
            Ok(())
        })
        .unwrap()
        .intersection("__intersection__write", |ctx| {
            ctx.params().push(ev_is(ctx));
            ctx.set_payload(2, 55);
            let t = 10.0 - ctx.primitive_aabb().max.z;
            ctx.report_intersection(t, 0, &[])?;
            Ok(())
        })
        .unwrap();
    let no_ch = RayDesc::down(0.0, 0.0).flags(RayFlags::DISABLE_CLOSESTHIT);
    let s = setup(
        &m,
        Some(CH),
        Some("__anyhit__write"),
        Some("__intersection__write"),
    );

    let tris = TraversableHandle::from(stack(&[0.0]));
    let out = s.run(&tris, no_ch.clone(), &[1, 2, 3]);
    assert_eq!(out.count(Prog::Ch), 0);
    assert_eq!(out.count(Prog::Ms), 0, "a hit is not a miss");
    assert_eq!(out.count(Prog::Ah), 1);
    assert_eq!(out.payload(), vec![1, 77, 3]);

    let boxes = TraversableHandle::from(box_gas(&box_stack(&[0.0])));
    let out = s.run(&boxes, no_ch.clone(), &[1, 2, 3]);
    assert_eq!(out.count(Prog::Ch), 0);
    assert_eq!(out.count(Prog::Is), 1);
    assert_eq!(out.payload(), vec![1, 77, 55]);

    let mut miss = no_ch;
    miss.origin = Vec3::new(9.0, 9.0, 10.0);
    let out = s.run(&tris, miss, &[1, 2, 3]);
    assert_eq!(
        out.log.iter().map(|e| e.prog).collect::<Vec<_>>(),
        vec![Prog::Ms]
    );
}

/// A GAS of two single-record inputs: primitive 0 around `(0, 0, z0)` with `f0`, primitive 1
/// around `(5, 0, z1)` with `f1` (SBT-GAS indices 0 and 1). Triangles or boxes.
fn two_inputs(custom: bool, f0: GeometryFlags, f1: GeometryFlags, x1: f32, z1: f32) -> Arc<Gas> {
    let (fa, fb) = ([f0], [f1]);
    let b0 = [cube(Vec3::ZERO, 0.5)];
    let b1 = [cube(Vec3::new(x1, 0.0, z1), 0.5)];
    let v0 = soup(&[tri_at(0.0, 0.0, 0.0, 1.0)]);
    let v1 = soup(&[tri_at(x1, 0.0, z1, 1.0)]);
    let inputs: [BuildInput; 2] = if custom {
        [
            CustomPrimitiveInput::new(AabbBuffer::new(&b0))
                .flags(&fa)
                .into(),
            CustomPrimitiveInput::new(AabbBuffer::new(&b1))
                .flags(&fb)
                .primitive_index_offset(1)
                .into(),
        ]
    } else {
        [
            TriangleInput::new(VertexBuffer::f32x3(&v0))
                .flags(&fa)
                .into(),
            TriangleInput::new(VertexBuffer::f32x3(&v1))
                .flags(&fb)
                .primitive_index_offset(1)
                .into(),
        ]
    };
    Arc::new(Gas::build(&BuildOptions::default(), &inputs).unwrap())
}

/// §5.1 / §13.2 / U.3 / Z7 G11: any-hit enablement: the geometry flag `DISABLE_ANYHIT` turns the
/// AH off, the ray flag `ENFORCE_ANYHIT` turns it back on, and the ray flag `DISABLE_ANYHIT`
/// turns it off whatever the geometry says. The hit is accepted either way. Triangles and
/// custom primitives.
#[test]
fn anyhit_enablement_precedence_u3_g11() {
    let m = report_top(logging_module(), "__intersection__top");
    let s = setup(&m, Some(CH), Some(AH), Some("__intersection__top"));
    for custom in [false, true] {
        let gas = two_inputs(
            custom,
            GeometryFlags::DISABLE_ANYHIT,
            GeometryFlags::empty(),
            5.0,
            0.0,
        );
        let handle = TraversableHandle::from(gas);
        for (x, flags, ah) in [
            (0.0, RayFlags::empty(), false),
            (0.0, RayFlags::ENFORCE_ANYHIT, true),
            (0.0, RayFlags::DISABLE_ANYHIT, false),
            (5.0, RayFlags::empty(), true),
            (5.0, RayFlags::ENFORCE_ANYHIT, true),
            (5.0, RayFlags::DISABLE_ANYHIT, false),
        ] {
            let out = s.run(&handle, RayDesc::down(x, 0.0).flags(flags), &[]);
            let what = format!("custom {custom}, x {x}, flags {flags:?}");
            assert_eq!(out.count(Prog::Ah), ah as usize, "{what}");
            assert_eq!(out.ch().prim, (x > 0.0) as u32, "{what}");
        }
    }
}

/// Launch parameters of the REQUIRE_SINGLE_ANYHIT_CALL test: one ray per launch index, one
/// counter per (ray, primitive).
#[derive(Clone)]
struct CountP {
    handle: TraversableHandle,
    rays: Arc<Vec<(Vec3, Vec3)>>,
    num_prims: usize,
    ah_calls: Arc<Vec<AtomicU32>>,
    is_calls: Arc<Vec<AtomicU32>>,
}

/// §5.1 / U.3 / Z7 G12: with `REQUIRE_SINGLE_ANYHIT_CALL`, AH runs at most once per primitive and
/// ray (and an intersection program at most once per custom primitive and ray); with every
/// candidate ignored, every primitive along the ray gets its AH call.
#[test]
fn require_single_anyhit_call_5_1_g12() {
    let m = Module::<CountP>::new()
        .raygen("__raygen__count", |ctx| {
            let p = ctx.params();
            let (o, d) = p.rays[ctx.launch_index()[0] as usize];
            ctx.trace(&TraceRay::new(&p.handle, o, d), &mut [])
        })
        .unwrap()
        .any_hit("__anyhit__count", |ctx| {
            let p = ctx.params();
            let i = ctx.launch_index()[0] as usize * p.num_prims + ctx.primitive_index() as usize;
            p.ah_calls[i].fetch_add(1, Ordering::Relaxed);
            ctx.ignore_intersection()
        })
        .unwrap()
        .intersection("__intersection__box", |ctx| {
            let p = ctx.params();
            let i = ctx.launch_index()[0] as usize * p.num_prims + ctx.primitive_index() as usize;
            p.is_calls[i].fetch_add(1, Ordering::Relaxed);
            // Report the box entry.
            let b = ctx.primitive_aabb();
            let (o, d) = (ctx.object_ray_origin(), ctx.object_ray_direction());
            let t0 = (b.min - o) / d;
            let t1 = (b.max - o) / d;
            let t = t0.min(t1).max_element().max(ctx.ray_tmin());
            ctx.report_intersection(t, 0, &[])?;
            Ok(())
        })
        .unwrap();
    let rg = ProgramGroup::raygen(&m, "__raygen__count").unwrap();
    let hg = ProgramGroup::hit_group(oxray::HitGroupDesc {
        any_hit: Some((&m, "__anyhit__count")),
        intersection: Some((&m, "__intersection__box")),
        ..Default::default()
    })
    .unwrap();
    let ms = ProgramGroup::miss(None).unwrap();
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &compile(0, 2),
        &link(1),
        &[rg.clone(), hg.clone(), ms.clone()],
    )
    .unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_headers(&[ms.pack_header()]),
        hitgroup: SbtRegion::from_headers(&[hg.pack_header()]),
        ..Default::default()
    };
    let mut rng = Rng::new(12);
    let n = 400;
    // Large overlapping triangles and boxes around the origin, so each ray meets many.
    let tris = random_soup(&mut rng, n, 4.0, 3.0);
    let boxes: Vec<Aabb> = (0..n)
        .map(|_| cube(rng.vec3(0.0, 4.0), rng.range(0.2, 1.5)))
        .collect();
    let rays: Vec<(Vec3, Vec3)> = (0..64)
        .map(|_| {
            let o = rng.vec3(-2.0, 6.0) + Vec3::new(0.0, 0.0, 12.0);
            let target = rng.vec3(1.0, 3.0);
            (o, target - o)
        })
        .collect();
    let flags = GeometryFlags::REQUIRE_SINGLE_ANYHIT_CALL;
    let gases = [
        ("triangles", tri_gas_flags(&tris, flags)),
        ("boxes", box_gas_flags(&boxes, flags)),
    ];
    for (what, gas) in gases {
        let params = CountP {
            handle: TraversableHandle::from(gas.clone()),
            rays: Arc::new(rays.clone()),
            num_prims: n,
            ah_calls: Arc::new((0..n * rays.len()).map(|_| AtomicU32::new(0)).collect()),
            is_calls: Arc::new((0..n * rays.len()).map(|_| AtomicU32::new(0)).collect()),
        };
        let report = pipeline
            .launch(&params, &sbt, rays.len() as u32, 1, 1)
            .unwrap();
        assert_eq!(report.exceptions, 0);
        let mut total = 0;
        for (r, &(o, d)) in rays.iter().enumerate() {
            for p in 0..n {
                let ah = params.ah_calls[r * n + p].load(Ordering::Relaxed);
                let is = params.is_calls[r * n + p].load(Ordering::Relaxed);
                assert!(ah <= 1, "{what}: ray {r} primitive {p}: {ah} AH calls");
                assert!(is <= 1, "{what}: ray {r} primitive {p}: {is} IS calls");
                total += ah;
            }
            if what == "triangles" {
                // Every triangle the query API finds along the ray got its (single) AH call.
                let mut along = BTreeSet::new();
                gas.intersect_filtered(&Ray::new(o, d), &mut oxray::NoCustomPrimitives, |h| {
                    along.insert(h.primitive_index as usize);
                    oxray::CandidateAction::Ignore
                });
                for p in along {
                    assert_eq!(
                        params.ah_calls[r * n + p].load(Ordering::Relaxed),
                        1,
                        "ray {r} primitive {p}"
                    );
                }
            }
        }
        assert!(
            total > rays.len() as u32 * 3,
            "{what}: the rays should meet many primitives ({total})"
        );
    }
}

/// §13.2 / §13.7 / U.2 / Z7 G13: culling by facing. A triangle counter-clockwise as seen by the
/// ray is front-facing (hit kind 0xFE); `CULL_BACK_FACING_TRIANGLES` and
/// `CULL_FRONT_FACING_TRIANGLES` skip back and front faces (no AH, no CH; hits behind are still
/// found), and the geometry flag `DISABLE_TRIANGLE_FACE_CULLING` overrides both.
#[test]
fn triangle_face_culling_13_2_g13() {
    let m = logging_module();
    let s = setup(&m, Some(CH), Some(AH), None);
    let down = RayDesc::down(0.0, 0.0);
    let up = RayDesc::new(Vec3::new(0.0, 0.0, -10.0), Vec3::Z);
    let cull_back = RayFlags::CULL_BACK_FACING_TRIANGLES;
    let cull_front = RayFlags::CULL_FRONT_FACING_TRIANGLES;
    for no_culling in [false, true] {
        let gflags = if no_culling {
            GeometryFlags::DISABLE_TRIANGLE_FACE_CULLING
        } else {
            GeometryFlags::empty()
        };
        let handle = TraversableHandle::from(tri_gas_flags(&[tri_at(0.0, 0.0, 0.0, 1.0)], gflags));
        for (ray, front) in [(down.clone(), true), (up.clone(), false)] {
            for flags in [RayFlags::empty(), cull_back, cull_front] {
                let out = s.run(&handle, ray.clone().flags(flags), &[]);
                let culled = !no_culling
                    && ((flags == cull_back && !front) || (flags == cull_front && front));
                let what = format!(
                    "front {front}, flags {flags:?}, DISABLE_TRIANGLE_FACE_CULLING {no_culling}"
                );
                if culled {
                    assert_eq!(
                        out.log.iter().map(|e| e.prog).collect::<Vec<_>>(),
                        vec![Prog::Ms],
                        "{what}"
                    );
                } else {
                    assert_eq!(out.ch().kind, if front { 0xFE } else { 0xFF }, "{what}");
                    assert_eq!(out.count(Prog::Ah), 1, "{what}");
                }
            }
        }
    }
    // A culled back face does not hide the front face behind it.
    let flipped = {
        let [a, b, c] = tri_at(0.0, 0.0, 0.0, 1.0);
        [b, a, c]
    };
    let handle = TraversableHandle::from(tri_gas(&[flipped, tri_at(0.0, 0.0, -1.0, 1.0)]));
    let out = s.run(&handle, down.clone().flags(cull_back), &[]);
    assert_eq!((out.ch().prim, out.ch().kind), (1, 0xFE));
    assert!(
        out.of(Prog::Ah).iter().all(|e| e.prim == 1),
        "no AH for the culled face"
    );
    let out = s.run(&handle, down.clone(), &[]);
    assert_eq!((out.ch().prim, out.ch().kind), (0, 0xFF));
    // Facing flags do not apply to custom primitives.
    let m = report_top(logging_module(), "__intersection__top");
    let s = setup(&m, Some(CH), Some(AH), Some("__intersection__top"));
    let handle = TraversableHandle::from(box_gas(&box_stack(&[0.0])));
    for flags in [cull_back, cull_front] {
        let out = s.run(&handle, down.clone().flags(flags), &[]);
        assert_eq!(out.ch().kind, 3, "{flags:?}");
    }
}

/// §13.2 / U.2 / Z7 G14: `CULL_DISABLED_ANYHIT` skips primitives whose any-hit is disabled and
/// `CULL_ENFORCED_ANYHIT` those whose any-hit is enabled (by the geometry flag), so the hit
/// behind a culled primitive becomes the closest. Triangles and custom primitives.
#[test]
fn cull_disabled_and_enforced_anyhit_13_2_g14() {
    let m = report_top(logging_module(), "__intersection__top");
    let s = setup(&m, Some(CH), Some(AH), Some("__intersection__top"));
    for custom in [false, true] {
        // Primitive 0 (AH disabled) in front of primitive 1 (AH enabled).
        let gas = two_inputs(
            custom,
            GeometryFlags::DISABLE_ANYHIT,
            GeometryFlags::empty(),
            0.0,
            -3.0,
        );
        let handle = TraversableHandle::from(gas);
        for (flags, closest, ah_prims) in [
            (RayFlags::empty(), 0, vec![]),
            (RayFlags::CULL_DISABLED_ANYHIT, 1, vec![1]),
            (RayFlags::CULL_ENFORCED_ANYHIT, 0, vec![]),
        ] {
            let out = s.run(&handle, RayDesc::down(0.0, 0.0).flags(flags), &[]);
            let what = format!("custom {custom}, flags {flags:?}");
            assert_eq!(out.ch().prim, closest, "{what}");
            if flags != RayFlags::empty() {
                assert_eq!(
                    out.of(Prog::Ah).iter().map(|e| e.prim).collect::<Vec<_>>(),
                    ah_prims,
                    "{what}"
                );
            }
        }
        // Only culled geometry along the ray: a miss.
        let gas = two_inputs(
            custom,
            GeometryFlags::empty(),
            GeometryFlags::empty(),
            0.0,
            -3.0,
        );
        let out = s.run(
            &TraversableHandle::from(gas),
            RayDesc::down(0.0, 0.0).flags(RayFlags::CULL_ENFORCED_ANYHIT),
            &[],
        );
        assert_eq!(
            out.log
                .iter()
                .filter(|e| e.prog != Prog::Is)
                .map(|e| e.prog)
                .collect::<Vec<_>>(),
            vec![Prog::Ms]
        );
    }
}

/// §13.2 / U.2 / Z7 G14: culled geometry is not intersected at all ("prevents intersection of
/// geometry"): the intersection program of a custom primitive culled by `CULL_DISABLED_ANYHIT`
/// or `CULL_ENFORCED_ANYHIT` does not run (it cannot write the payload or have side effects).
#[test]
fn culled_custom_primitives_run_no_intersection_program_13_2_g14() {
    let m = logging_module()
        .intersection("__intersection__mark", |ctx| {
            ctx.params().push(ev_is(ctx));
            ctx.set_payload(0, ctx.payload(0) | (1 << ctx.primitive_index()));
            let t = 10.0 - ctx.primitive_aabb().max.z;
            ctx.report_intersection(t, 0, &[])?;
            Ok(())
        })
        .unwrap();
    let s = setup(&m, Some(CH), Some(AH), Some("__intersection__mark"));
    let gas = two_inputs(
        true,
        GeometryFlags::DISABLE_ANYHIT,
        GeometryFlags::empty(),
        0.0,
        -3.0,
    );
    let handle = TraversableHandle::from(gas);
    let out = s.run(
        &handle,
        RayDesc::down(0.0, 0.0).flags(RayFlags::CULL_DISABLED_ANYHIT),
        &[0],
    );
    assert_eq!(out.ch().prim, 1);
    assert!(
        out.of(Prog::Is).iter().all(|e| e.prim == 1),
        "the IS of culled primitive 0 ran: {:#?}",
        out.of(Prog::Is)
    );
    assert_eq!(
        out.payload(),
        vec![0b10],
        "a culled primitive's IS wrote the payload"
    );
    let out = s.run(
        &handle,
        RayDesc::down(0.0, 0.0).flags(RayFlags::CULL_ENFORCED_ANYHIT),
        &[0],
    );
    assert!(
        out.of(Prog::Is).iter().all(|e| e.prim == 0),
        "the IS of culled primitive 1 ran"
    );
}

/// §13.5 / Z7 G30 / G15: the ray queries return the trace's arguments in IS, AH, CH and MS:
/// world origin and direction, flags, visibility mask; `ray_time()` is 0 in a pipeline without
/// motion blur whatever time was traced; the visibility mask does not apply to a GAS root
/// (a mask of 0 still hits).
#[test]
fn ray_information_13_5_g30() {
    macro_rules! note_ray {
        ($ctx:expr, $what:expr) => {{
            let c = &$ctx;
            c.params().note(format!(
                "{} {:?} {:?} {:?} {:#x} {}",
                $what,
                c.world_ray_origin(),
                c.world_ray_direction(),
                c.ray_flags(),
                c.ray_visibility_mask(),
                c.ray_time()
            ));
        }};
    }
    let m = with_single_raygen(Module::new())
        .intersection("__intersection__i", |ctx| {
            note_ray!(ctx, "IS");
            ctx.report_intersection(9.5, 0, &[])?;
            Ok(())
        })
        .unwrap()
        .any_hit("__anyhit__a", |ctx| {
            note_ray!(ctx, "AH");
            Ok(())
        })
        .unwrap()
        .closest_hit("__closesthit__c", |ctx| {
            note_ray!(ctx, "CH");
            Ok(())
        })
        .unwrap()
        .miss("__miss__m", |ctx| {
            note_ray!(ctx, "MS");
            Ok(())
        })
        .unwrap();
    let hg = hit_group(
        &m,
        Some("__closesthit__c"),
        Some("__anyhit__a"),
        Some("__intersection__i"),
    );
    let ms = miss_group(&m, Some("__miss__m"));
    let s = Setup::new(&m).hit(&hg, 0).miss(&ms, 0);
    let flags = RayFlags::ENFORCE_ANYHIT | RayFlags::CULL_BACK_FACING_TRIANGLES;
    let mut ray = RayDesc::new(Vec3::new(0.25, -0.5, 10.0), Vec3::new(0.0, 0.0, -2.0)).flags(flags);
    ray.time = 0.7;
    ray.mask = 0xA5;
    let expect = |what: &str, o: Vec3| {
        format!(
            "{what} {:?} {:?} {flags:?} 0xa5 0",
            o,
            Vec3::new(0.0, 0.0, -2.0)
        )
    };
    let handle = TraversableHandle::from(box_gas(&box_stack(&[0.0])));
    let out = s.run(&handle, ray.clone(), &[]);
    let o = ray.origin;
    assert_eq!(
        out.notes,
        vec![expect("IS", o), expect("AH", o), expect("CH", o)]
    );
    ray.origin = Vec3::new(5.0, 5.0, 10.0);
    let out = s.run(&handle, ray.clone(), &[]);
    assert_eq!(out.notes, vec![expect("MS", ray.origin)]);

    // Visibility mask 0 on a GAS root: still a hit.
    let m = logging_module();
    let s = setup(&m, Some(CH), None, None);
    let mut ray = RayDesc::down(0.0, 0.0);
    ray.mask = 0;
    let out = s.run(&TraversableHandle::from(stack(&[0.0])), ray, &[]);
    assert_eq!(out.count(Prog::Ch), 1);
}
