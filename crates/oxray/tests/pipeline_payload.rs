//! Conformance of payload and intersection reporting (guide §13.3, §13.4, §13.7, §14; inventory
//! Z3, U.4, U.5, Z7 G21, G24, G25): copy-in/copy-out payload, `report_intersection`, hit kinds,
//! attributes, barycentrics and the instance queries of a GAS root.

mod pipeline_common;

use oxray::cpu::Gas;
use oxray::{ExceptionCode, Module, RayFlags, TraversableHandle};
use pipeline_common::*;

const CH: &str = "__closesthit__log";
const AH: &str = "__anyhit__log";
const MS: &str = "__miss__log";

fn logging_module() -> Module<Tp> {
    with_single_raygen(Module::new())
        .closest_hit(CH, log_ch)
        .unwrap()
        .any_hit(AH, log_ah)
        .unwrap()
        .miss(MS, log_ms)
        .unwrap()
}

fn setup(
    m: &Module<Tp>,
    ch: Option<&str>,
    ah: Option<&str>,
    is: Option<&str>,
    ms: Option<&str>,
) -> Setup {
    let hg = hit_group(m, ch, ah, is);
    let ms = miss_group(m, ms);
    Setup::new(m).hit(&hg, 0).miss(&ms, 0)
}

/// One box under `(0, 0)` whose top face is at height 0.5 (a ray down from height 10 enters it
/// at t = 9.5).
fn one_box() -> TraversableHandle {
    TraversableHandle::from(box_gas(&[cube(Vec3::ZERO, 0.5)]))
}

fn one_triangle() -> TraversableHandle {
    TraversableHandle::from(tri_gas(&[tri_at(0.0, 0.0, 0.0, 1.0)]))
}

const INIT: [u32; 8] = [0xA0, 0xA1, 0xA2, 0xA3, 0xA4, 0xA5, 0xA6, 0xA7];

/// §14 / Z3 / Z7 G24: payload words that no program sets come back unchanged; words set by the
/// programs of the trace come back with the last value set. Miss path, hit path, and a trace
/// whose programs are all absent.
#[test]
fn payload_words_never_set_come_back_unchanged_z3_g24() -> TestResult {
    let m = logging_module()
        .miss("__miss__set3", |ctx| {
            ctx.set_payload(3, 33);
            Ok(())
        })?
        .intersection("__intersection__set1", |ctx| {
            ctx.set_payload(1, 11);
            ctx.report_intersection(9.5, 0, &[])?;
            Ok(())
        })?
        .any_hit("__anyhit__set2", |ctx| {
            ctx.set_payload(2, 22);
            Ok(())
        })?
        .closest_hit("__closesthit__set4", |ctx| {
            ctx.set_payload(4, 44);
            ctx.set_payload(4, 45);
            Ok(())
        })?;
    let s = setup(
        &m,
        Some("__closesthit__set4"),
        Some("__anyhit__set2"),
        Some("__intersection__set1"),
        Some("__miss__set3"),
    );
    let out = s.run(&one_box(), RayDesc::down(0.0, 0.0), &INIT);
    assert_eq!(
        out.payload(),
        vec![0xA0, 11, 22, 0xA3, 45, 0xA5, 0xA6, 0xA7]
    );
    let out = s.run(&one_box(), RayDesc::down(5.0, 0.0), &INIT);
    assert_eq!(
        out.payload(),
        vec![0xA0, 0xA1, 0xA2, 33, 0xA4, 0xA5, 0xA6, 0xA7]
    );

    // No programs at all: an empty hit group and a no-op miss group.
    let s = setup(&m, None, None, None, None);
    for ray in [RayDesc::down(0.0, 0.0), RayDesc::down(5.0, 0.0)] {
        let out = s.run(&one_triangle(), ray, &INIT);
        assert_eq!(out.payload(), INIT.to_vec());
    }
    Ok(())
}

/// §14 / Z3 / Z7 G24: a payload set is visible to every later get of the same trace, within a
/// program and across programs: IS → AH → CH, and IS → MS when the AH ignores the hit. Every
/// program sees the caller's values of the words nobody set.
#[test]
fn payload_sets_visible_to_later_programs_is_ah_ch_z3_g24() -> TestResult {
    let m = logging_module()
        .intersection("__intersection__p", |ctx| {
            let caller = ctx.payload(5);
            ctx.set_payload(0, 1000 + caller);
            let again = ctx.payload(0);
            ctx.params().note(format!("IS {caller} {again}"));
            ctx.report_intersection(9.5, 0, &[])?;
            Ok(())
        })?
        .any_hit("__anyhit__p", |ctx| {
            let (p0, p5) = (ctx.payload(0), ctx.payload(5));
            ctx.params().note(format!("AH {p0} {p5}"));
            ctx.set_payload(1, p0 + 1);
            if p5 == 7 {
                return ctx.ignore_intersection();
            }
            Ok(())
        })?
        .closest_hit("__closesthit__p", |ctx| {
            let (p0, p1, p5) = (ctx.payload(0), ctx.payload(1), ctx.payload(5));
            ctx.params().note(format!("CH {p0} {p1} {p5}"));
            ctx.set_payload(2, p1 + 1);
            Ok(())
        })?
        .miss("__miss__p", |ctx| {
            let (p0, p1) = (ctx.payload(0), ctx.payload(1));
            ctx.params()
                .note(format!("MS {p0} {p1} {:?}", ctx.payload_words()));
            Ok(())
        })?;
    let s = setup(
        &m,
        Some("__closesthit__p"),
        Some("__anyhit__p"),
        Some("__intersection__p"),
        Some("__miss__p"),
    );
    let out = s.run(&one_box(), RayDesc::down(0.0, 0.0), &[0, 0, 0, 0, 0, 5]);
    assert_eq!(out.notes, vec!["IS 5 1005", "AH 1005 5", "CH 1005 1006 5"]);
    assert_eq!(out.payload(), vec![1005, 1006, 1007, 0, 0, 5]);
    let out = s.run(&one_box(), RayDesc::down(0.0, 0.0), &[0, 0, 0, 0, 0, 7]);
    assert_eq!(
        out.notes,
        vec![
            "IS 7 1007",
            "AH 1007 7",
            "MS 1007 1008 [1007, 1008, 0, 0, 0, 7]"
        ]
    );
    assert_eq!(out.payload(), vec![1007, 1008, 0, 0, 0, 7]);
    Ok(())
}

/// §14 / Z3 / Z7 G24: a trace from a closest-hit program has its own payload: the nested programs
/// see only the nested payload, the outer trace's payload is untouched by the nested trace, and
/// the nested result reaches the outer caller only through the CH's explicit copy.
#[test]
fn nested_trace_payload_does_not_leak_z3_g24() -> TestResult {
    let m = logging_module()
        .closest_hit("__closesthit__nest", |ctx| {
            let p = ctx.params();
            let mut nested = [9u32, 9, 9, 9];
            let ray = RayDesc::new(Vec3::new(50.0, 50.0, 10.0), -Vec3::Z).sbt(0, 1, 1);
            ctx.trace(&ray.trace(&p.handle), &mut nested)?;
            p.note(format!(
                "CH outer {:?} nested {nested:?}",
                ctx.payload_words()
            ));
            ctx.set_payload(3, nested[0]);
            Ok(())
        })?
        .miss("__miss__nested", |ctx| {
            ctx.params()
                .note(format!("nested MS {:?}", ctx.payload_words()));
            ctx.set_payload(0, 42);
            ctx.set_payload(1, 43);
            Ok(())
        })?;
    let hg = hit_group(&m, Some("__closesthit__nest"), None, None);
    let ms0 = miss_group(&m, Some(MS));
    let ms1 = miss_group(&m, Some("__miss__nested"));
    let s = Setup::new(&m)
        .hit(&hg, 0)
        .miss(&ms0, 0)
        .miss(&ms1, 1)
        .depth(2);
    let out = s.run(&one_triangle(), RayDesc::down(0.0, 0.0), &[1, 2, 3, 4]);
    assert_eq!(
        out.notes,
        vec![
            "nested MS [9, 9, 9, 9]",
            "CH outer [1, 2, 3, 4] nested [42, 43, 9, 9]"
        ]
    );
    assert_eq!(out.payload(), vec![1, 2, 3, 42]);
    Ok(())
}

/// §13.5 / §13.7 (Z7 G34 without SER): a closest-hit program's own hit state (ray, t, primitive,
/// hit kind, attributes, record data) is the same before and after it traces a nested ray that
/// hits something else.
#[test]
fn closest_hit_state_unchanged_by_nested_trace_13_5() -> TestResult {
    fn state(ctx: &oxray::ClosestHitCtx<'_, Tp>) -> String {
        format!(
            "{} {} {} {} {:?} {:?} {:?} {:?}",
            ctx.primitive_index(),
            ctx.ray_tmin(),
            ctx.ray_tmax(),
            ctx.hit_kind().0,
            ctx.triangle_barycentrics(),
            ctx.world_ray_origin(),
            ctx.sbt_data::<u32>(),
            ctx.launch_index()
        )
    }
    let m = logging_module().closest_hit("__closesthit__nest", |ctx| {
        let p = ctx.params();
        if ctx.payload(0) == 1 {
            // The nested hit.
            p.note(format!("nested {}", state(ctx)));
            return Ok(());
        }
        let before = state(ctx);
        let mut nested = [1u32];
        let ray = RayDesc::new(Vec3::new(3.0, 0.1, -10.0), Vec3::Z).interval(0.5, 100.0);
        ctx.trace(&ray.trace(&p.handle), &mut nested)?;
        let after = state(ctx);
        p.note(format!("outer {}", before == after));
        p.note(format!("outer {before}"));
        Ok(())
    })?;
    let hg = hit_group(&m, Some("__closesthit__nest"), None, None);
    let s = Setup::new(&m)
        .hit(&hg, 5)
        .miss(&miss_group(&m, None), 0)
        .depth(2);
    let handle = TraversableHandle::from(tri_gas(&[
        tri_at(0.0, 0.0, 0.0, 1.0),
        tri_at(3.0, 0.0, 0.0, 1.0),
    ]));
    let out = s.run(&handle, RayDesc::down(0.0, 0.0), &[0]);
    assert_eq!(out.notes.len(), 3, "{:?}", out.notes);
    assert!(
        out.notes[0].starts_with("nested 1 0.5 10 255 "),
        "{:?}",
        out.notes
    );
    assert_eq!(out.notes[1], "outer true");
    assert!(
        out.notes[2].starts_with("outer 0 0 10 254 "),
        "{:?}",
        out.notes
    );
    Ok(())
}

/// §13.3 / Z3 / N7: a trace may pass at most `num_payload_values` words; more raises
/// `PAYLOAD_TYPE_MISMATCH` and the trace does not return. Fewer (or exactly as many) is fine.
#[test]
fn payload_longer_than_num_payload_values_raises_z3() -> TestResult {
    let m = logging_module();
    for (num, len, ok) in [
        (4, 4, true),
        (4, 0, true),
        (4, 2, true),
        (4, 5, false),
        (0, 1, false),
        (32, 32, true),
        (32, 33, false),
    ] {
        let mut s = setup(&m, Some(CH), None, None, Some(MS));
        s.compile = compile(num, 2);
        let payload = vec![3u32; len];
        let out = s.run(&one_triangle(), RayDesc::down(0.0, 0.0), &payload);
        let what = format!("num_payload_values {num}, payload {len}");
        if ok {
            assert_eq!(out.report.exceptions, 0, "{what}");
            assert_eq!(out.payload(), payload, "{what}");
            assert_eq!(out.count(Prog::Ch), 1, "{what}");
        } else {
            assert_eq!(out.report.exceptions, 1, "{what}");
            assert_eq!(
                out.report.first_exceptions[0].1.code,
                ExceptionCode::PAYLOAD_TYPE_MISMATCH,
                "{what}"
            );
            assert!(out.payload.is_none(), "{what}: the trace returned");
            assert!(out.log.is_empty(), "{what}: programs ran: {:?}", out.log);
        }
    }
    Ok(())
}

/// §13.4 / U.4 / Z7 G6, G3: `report_intersection` returns false outside `[tmin, tmax]` (no AH
/// runs), false when the AH ignores the hit, true when the hit is accepted (the interval then
/// ends there, so a farther report returns false), and an `Interrupt` when the AH terminates the
/// ray; the CH then runs for the terminating hit.
#[test]
fn report_intersection_return_values_13_4_g6() -> TestResult {
    let m = logging_module()
        .intersection("__intersection__seq", |ctx| {
            let p = ctx.params().clone();
            let outside = ctx.report_intersection(100.0, 1, &[1])?;
            p.note(format!("outside {outside}"));
            let ignored = ctx.report_intersection(12.0, 1, &[2])?;
            p.note(format!("ignored {ignored} tmax {}", ctx.ray_tmax()));
            let accepted = ctx.report_intersection(11.0, 2, &[3])?;
            p.note(format!("accepted {accepted} tmax {}", ctx.ray_tmax()));
            let beyond = ctx.report_intersection(11.5, 2, &[4])?;
            p.note(format!("beyond {beyond}"));
            let r = ctx.report_intersection(10.5, 4, &[5]);
            p.note(format!("terminated {}", r.is_err()));
            r?;
            p.note("after terminate");
            Ok(())
        })?
        .any_hit("__anyhit__by_kind", |ctx| {
            ctx.params().push(ev_ah(ctx));
            match ctx.hit_kind().0 {
                1 => ctx.ignore_intersection(),
                4 => ctx.terminate_ray(),
                _ => Ok(()),
            }
        })?;
    let s = setup(
        &m,
        Some(CH),
        Some("__anyhit__by_kind"),
        Some("__intersection__seq"),
        Some(MS),
    );
    let out = s.run(&one_box(), RayDesc::down(0.0, 0.0).interval(1.0, 50.0), &[]);
    assert_eq!(
        out.notes,
        vec![
            "outside false",
            "ignored false tmax 50",
            "accepted true tmax 11",
            "beyond false",
            "terminated true"
        ]
    );
    let ahs: Vec<(u8, f32, u32)> = out
        .of(Prog::Ah)
        .iter()
        .map(|e| (e.kind, e.tmax, e.attrs[0]))
        .collect();
    assert_eq!(ahs, vec![(1, 12.0, 2), (2, 11.0, 3), (4, 10.5, 5)]);
    let ch = out.ch();
    assert_eq!((ch.kind, ch.tmax, ch.attrs[0]), (4, 10.5, 5));
    // Without an AH program the report is accepted.
    let s = setup(&m, Some(CH), None, Some("__intersection__seq"), Some(MS));
    let out = s.run(&one_box(), RayDesc::down(0.0, 0.0).interval(1.0, 50.0), &[]);
    assert_eq!(
        out.notes,
        vec![
            "outside false",
            "ignored true tmax 12",
            "accepted true tmax 11",
            "beyond false",
            "terminated false",
            "after terminate"
        ]
    );
    assert_eq!((out.ch().kind, out.ch().tmax), (4, 10.5));
    Ok(())
}

/// §13.4 / §12 / N9: only the low 7 bits of a reported hit kind count; a custom hit kind can never
/// look like a triangle's (`is_triangle_hit`, `is_front_face_hit`, `is_back_face_hit` false).
#[test]
fn custom_hit_kind_masked_to_7_bits_13_4_n9() -> TestResult {
    let m = with_single_raygen(Module::new())
        .intersection("__intersection__kind", |ctx| {
            let kind = ctx.params().payload[0] as u8;
            ctx.report_intersection(9.5, kind, &[])?;
            Ok(())
        })?
        .any_hit("__anyhit__kind", |ctx| {
            let k = ctx.hit_kind().0;
            let flags = (
                ctx.is_triangle_hit(),
                ctx.is_front_face_hit(),
                ctx.is_back_face_hit(),
            );
            ctx.params().note(format!("AH {k:#x} {flags:?}"));
            Ok(())
        })?
        .closest_hit("__closesthit__kind", |ctx| {
            let k = ctx.hit_kind().0;
            let flags = (
                ctx.is_triangle_hit(),
                ctx.is_front_face_hit(),
                ctx.is_back_face_hit(),
            );
            ctx.params().note(format!("CH {k:#x} {flags:?}"));
            Ok(())
        })?;
    let hg = hit_group(
        &m,
        Some("__closesthit__kind"),
        Some("__anyhit__kind"),
        Some("__intersection__kind"),
    );
    let s = Setup::new(&m).hit(&hg, 0).miss(&miss_group(&m, None), 0);
    for (kind, seen) in [
        (0x00u32, 0x00),
        (0x05, 0x05),
        (0x7F, 0x7F),
        (0x85, 0x05),
        (0xFE, 0x7E),
        (0xFF, 0x7F),
    ] {
        let out = s.run(&one_box(), RayDesc::down(0.0, 0.0), &[kind]);
        let expect = |p: &str| format!("{p} {seen:#x} (false, false, false)");
        assert_eq!(
            out.notes,
            vec![expect("AH"), expect("CH")],
            "reported {kind:#x}"
        );
    }
    Ok(())
}

/// §13.4 / U.4 / Z7 G4: the attributes reported with a hit reach its AH and, for the closest
/// accepted hit, the CH (up to 8 words), whichever primitive or report came first.
#[test]
fn attributes_reach_anyhit_and_closesthit_13_4() -> TestResult {
    let m = logging_module().intersection("__intersection__attrs", |ctx| {
        let p = ctx.primitive_index();
        let entry = 10.0 - ctx.primitive_aabb().max.z;
        let a: Vec<u32> = (0..8).map(|i| p * 100 + i).collect();
        ctx.report_intersection(entry + 0.25, 1, &a)?;
        let b: Vec<u32> = (0..8).map(|i| p * 100 + 50 + i).collect();
        ctx.report_intersection(entry, 2, &b)?;
        Ok(())
    })?;
    let s = setup(
        &m,
        Some(CH),
        Some(AH),
        Some("__intersection__attrs"),
        Some(MS),
    );
    // Two overlapping boxes: primitive 1 (top at 1.5) is in front of primitive 0 (top at 0.5).
    let handle = TraversableHandle::from(box_gas(&[
        cube(Vec3::ZERO, 0.5),
        cube(Vec3::new(0.0, 0.0, 0.9), 0.6),
    ]));
    let out = s.run(&handle, RayDesc::down(0.0, 0.0), &[]);
    for e in out.of(Prog::Ah) {
        let base = e.prim * 100 + if e.kind == 2 { 50 } else { 0 };
        assert_eq!(e.attrs, std::array::from_fn(|i| base + i as u32), "{e:?}");
    }
    let ch = out.ch();
    assert_eq!((ch.prim, ch.kind), (1, 2));
    assert_eq!(ch.attrs, std::array::from_fn(|i| 150 + i as u32));
    assert!((ch.tmax - 8.5).abs() < 1e-6);
    Ok(())
}

/// §13.4 / §6.3 / N8: `num_attribute_values` below 2 counts as 2 (so two reported attribute words
/// and triangle barycentrics always arrive), and every word up to `num_attribute_values` reaches
/// the AH and CH.
#[test]
fn num_attribute_values_below_2_become_2_13_4_n8() -> TestResult {
    let m = logging_module().intersection("__intersection__attrs", |ctx| {
        ctx.report_intersection(9.5, 0, &[11, 12, 13, 14, 15, 16, 17, 18])?;
        Ok(())
    })?;
    for (num, kept) in [(0u32, 2usize), (1, 2), (2, 2), (3, 3), (8, 8)] {
        let mut s = setup(
            &m,
            Some(CH),
            Some(AH),
            Some("__intersection__attrs"),
            Some(MS),
        );
        s.compile = compile(8, num);
        let out = s.run(&one_box(), RayDesc::down(0.0, 0.0), &[]);
        let expected: Vec<u32> = (11..11 + kept as u32).collect();
        assert_eq!(
            out.of(Prog::Ah)[0].attrs[..kept],
            expected[..],
            "num_attribute_values {num}"
        );
        assert_eq!(
            out.ch().attrs[..kept],
            expected[..],
            "num_attribute_values {num}"
        );
        let out = s.run(&one_triangle(), RayDesc::down(0.25, 0.0), &[]);
        let [u, v] = [out.ch().attrs[0], out.ch().attrs[1]].map(f32::from_bits);
        assert!(
            u > 0.0 && v > 0.0 && u + v < 1.0,
            "num_attribute_values {num}: ({u}, {v})"
        );
    }
    Ok(())
}

/// §13.4 / §13.7 / Z7 G25: for triangles, attributes 0 and 1 are the barycentrics
/// (`triangle_barycentrics()`), with OptiX's convention: the hit point is
/// `(1 - u - v) * v0 + u * v1 + v * v2`; AH and CH agree.
#[test]
fn triangle_barycentrics_are_attributes_0_1_13_4_g25() -> TestResult {
    let m = with_single_raygen(Module::new())
        .any_hit("__anyhit__bary", |ctx| {
            let [u, v] = ctx.triangle_barycentrics();
            let same = u.to_bits() == ctx.attribute(0) && v.to_bits() == ctx.attribute(1);
            ctx.params().note(format!("AH {u} {v} {same}"));
            Ok(())
        })?
        .closest_hit("__closesthit__bary", |ctx| {
            let [u, v] = ctx.triangle_barycentrics();
            let same = u.to_bits() == ctx.attribute(0) && v.to_bits() == ctx.attribute(1);
            ctx.params().note(format!("CH {u} {v} {same}"));
            ctx.set_payload_f32(0, u);
            ctx.set_payload_f32(1, v);
            ctx.set_payload_f32(2, ctx.ray_tmax());
            Ok(())
        })?;
    let hg = hit_group(&m, Some("__closesthit__bary"), Some("__anyhit__bary"), None);
    let s = Setup::new(&m).hit(&hg, 0).miss(&miss_group(&m, None), 0);
    let mut rng = Rng::new(25);
    let mut checked = 0;
    for case in 0..60 {
        let tri: Tri = std::array::from_fn(|_| rng.vec3(-2.0, 2.0).to_array());
        let [a, b, c] = tri.map(Vec3::from);
        let n = (b - a).cross(c - a);
        if n.length() < 0.5 {
            continue;
        }
        let (u, v) = (rng.range(0.05, 0.9), rng.range(0.05, 0.9));
        if u + v > 0.95 {
            continue;
        }
        let p = (1.0 - u - v) * a + u * b + v * c;
        let origin = p + rng.dir() * 5.0;
        let handle = TraversableHandle::from(tri_gas(&[tri]));
        let out = s.run(&handle, RayDesc::new(origin, p - origin), &[0, 0, 0]);
        let w = out.payload();
        let (hu, hv, t) = (
            f32::from_bits(w[0]),
            f32::from_bits(w[1]),
            f32::from_bits(w[2]),
        );
        if out.notes.is_empty() {
            // The random origin may lie in the triangle's plane; skip such grazing rays.
            continue;
        }
        assert_eq!(out.notes.len(), 2, "case {case}");
        assert!(
            out.notes.iter().all(|n| n.ends_with("true")),
            "case {case}: {:?}",
            out.notes
        );
        assert_eq!(
            out.notes[0][2..],
            out.notes[1][2..],
            "case {case}: AH and CH agree"
        );
        assert!(
            (hu - u).abs() < 1e-3 && (hv - v).abs() < 1e-3,
            "case {case}: ({hu}, {hv}) vs ({u}, {v})"
        );
        let hit = (1.0 - hu - hv) * a + hu * b + hv * c;
        let along = origin + (p - origin) * t;
        assert!(
            (hit - along).length() < 1e-3,
            "case {case}: {hit} vs {along}"
        );
        checked += 1;
    }
    assert!(checked >= 20, "only {checked} cases hit");
    Ok(())
}

/// §13.7 / U.5 / N9: triangle hits report hit kind 0xFE (front, counter-clockwise as seen by the
/// ray) or 0xFF (back), and `is_triangle_hit`, `is_front_face_hit`, `is_back_face_hit` agree, in
/// AH and CH.
#[test]
fn triangle_hit_kinds_and_facing_13_7_u5() -> TestResult {
    let m = with_single_raygen(Module::new())
        .any_hit("__anyhit__face", |ctx| {
            let f = (
                ctx.hit_kind().0,
                ctx.is_triangle_hit(),
                ctx.is_front_face_hit(),
                ctx.is_back_face_hit(),
            );
            ctx.params().note(format!("AH {f:x?}"));
            Ok(())
        })?
        .closest_hit("__closesthit__face", |ctx| {
            let f = (
                ctx.hit_kind().0,
                ctx.is_triangle_hit(),
                ctx.is_front_face_hit(),
                ctx.is_back_face_hit(),
            );
            ctx.params().note(format!("CH {f:x?}"));
            Ok(())
        })?;
    let hg = hit_group(&m, Some("__closesthit__face"), Some("__anyhit__face"), None);
    let s = Setup::new(&m).hit(&hg, 0).miss(&miss_group(&m, None), 0);
    let ccw = tri_at(0.0, 0.0, 0.0, 1.0);
    let cw = [ccw[0], ccw[2], ccw[1]];
    let down = RayDesc::down(0.0, 0.0);
    let up = RayDesc::new(Vec3::new(0.0, 0.0, -10.0), Vec3::Z);
    for (tri, ray, front) in [
        (ccw, down.clone(), true),
        (ccw, up.clone(), false),
        (cw, down, false),
        (cw, up, true),
    ] {
        let out = s.run(&TraversableHandle::from(tri_gas(&[tri])), ray, &[]);
        let f = if front {
            "(fe, true, true, false)"
        } else {
            "(ff, true, false, true)"
        };
        assert_eq!(out.notes, vec![format!("AH {f}"), format!("CH {f}")]);
    }
    Ok(())
}

/// §13.4 / §13.7 / §7.3.2: an intersection program sees its primitive: the primitive index (with
/// the input's offset), the SBT-GAS index and the primitive's box from the build input.
#[test]
fn intersection_program_sees_its_primitive_13_7() -> TestResult {
    use oxray::{
        AabbBuffer, BuildInput, BuildOptions, CustomPrimitiveInput, GeometryFlags, SbtIndexOffsets,
    };
    let m = with_single_raygen(Module::new()).intersection("__intersection__who", |ctx| {
        let b = ctx.primitive_aabb();
        ctx.params().note(format!(
            "{} {} {:?} {:?}",
            ctx.primitive_index(),
            ctx.sbt_gas_index(),
            b.min.to_array(),
            b.max.to_array()
        ));
        Ok(())
    })?;
    let hg = hit_group(&m, None, None, Some("__intersection__who"));
    let s = Setup::new(&m)
        .hit(&hg, 0)
        .hit(&hg, 1)
        .hit(&hg, 2)
        .miss(&miss_group(&m, None), 0);
    let a = [
        cube(Vec3::new(0.0, 0.0, 0.0), 0.5),
        cube(Vec3::new(3.0, 0.0, 0.0), 0.25),
    ];
    let b = [oxray::Aabb::new(
        Vec3::new(5.5, -0.5, -1.0),
        Vec3::new(6.5, 0.75, 0.0),
    )];
    let flags2 = [GeometryFlags::empty(); 2];
    let offsets = [1u8, 0];
    let inputs: [BuildInput; 2] = [
        CustomPrimitiveInput::new(AabbBuffer::new(&a))
            .flags(&flags2)
            .sbt_index_offsets(SbtIndexOffsets::u8(&offsets))
            .primitive_index_offset(40)
            .into(),
        CustomPrimitiveInput::new(AabbBuffer::new(&b))
            .primitive_index_offset(7)
            .into(),
    ];
    let handle = TraversableHandle::from(Gas::build(&BuildOptions::default(), &inputs)?);
    for (x, expected) in [
        (0.0, "40 1 [-0.5, -0.5, -0.5] [0.5, 0.5, 0.5]"),
        (3.0, "41 0 [2.75, -0.25, -0.25] [3.25, 0.25, 0.25]"),
        (6.0, "7 2 [5.5, -0.5, -1.0] [6.5, 0.75, 0.0]"),
    ] {
        let out = s.run(&handle, RayDesc::down(x, 0.0), &[]);
        assert_eq!(out.notes, vec![expected], "x = {x}");
    }
    Ok(())
}

/// §13.7 / U.6 / Z7 G21 (documented choice: the guide's values): with a GAS as the traced handle,
/// `instance_id()` is `!0` and `instance_index()` is 0 in AH and CH, for triangles and custom
/// primitives.
#[test]
fn instance_queries_with_gas_root_13_7_g21() -> TestResult {
    let m = with_single_raygen(Module::new())
        .intersection("__intersection__i", |ctx| {
            ctx.report_intersection(9.5, 0, &[])?;
            Ok(())
        })?
        .any_hit("__anyhit__inst", |ctx| {
            ctx.params().note(format!(
                "AH {:#x} {}",
                ctx.instance_id(),
                ctx.instance_index()
            ));
            Ok(())
        })?
        .closest_hit("__closesthit__inst", |ctx| {
            ctx.params().note(format!(
                "CH {:#x} {}",
                ctx.instance_id(),
                ctx.instance_index()
            ));
            Ok(())
        })?;
    let hg = hit_group(
        &m,
        Some("__closesthit__inst"),
        Some("__anyhit__inst"),
        Some("__intersection__i"),
    );
    let s = Setup::new(&m).hit(&hg, 0).miss(&miss_group(&m, None), 0);
    for handle in [one_triangle(), one_box()] {
        let out = s.run(
            &handle,
            RayDesc::down(0.0, 0.0).flags(RayFlags::ENFORCE_ANYHIT),
            &[],
        );
        assert_eq!(out.notes, vec!["AH 0xffffffff 0", "CH 0xffffffff 0"]);
    }
    Ok(())
}
