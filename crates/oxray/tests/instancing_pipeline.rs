//! Instances in the programmable pipeline:
//!
//! * visibility masks (guide §5.4, §13.2, §12; inventory J, U.1, Z0, Z7 G15);
//! * instance queries and current-hit transforms in IS, AH and CH (§13.7, §13.11; U.6, Z1.8,
//!   G21);
//! * traversable graph flags (§5.9.1, §6.3; O).

mod instancing_common;

use instancing_common::*;
use oxray::cpu::{Gas, Ias};
use oxray::{
    Aabb, AabbBuffer, BuildInput, BuildOptions, CustomPrimitiveInput, ExceptionCode, Instance,
    Module, PipelineCompileOptions, PrimitiveTypeFlags, StaticTransform, Transform,
    TraversableGraphFlags, TraversableHandle,
};
use std::sync::Arc;

fn ias(instances: &[Instance]) -> Ias {
    Ias::build(&BuildOptions::default(), &[instances.into()]).expect("IAS build")
}

fn handle_of(instances: &[Instance]) -> TraversableHandle {
    ias(instances).into()
}

fn at_x(x: f32) -> Transform {
    Transform::from_translation(Vec3::new(x, 0.0, 0.0))
}

/// A GAS of custom primitives with one box per element of `boxes`.
fn box_gas(boxes: &[Aabb]) -> Arc<Gas> {
    let input: BuildInput = CustomPrimitiveInput::new(AabbBuffer::new(boxes)).into();
    Arc::new(Gas::build(&BuildOptions::default(), &[input]).expect("GAS build"))
}

/// Payload word 0 on a miss.
const MISS: u32 = 0;
/// Payload word 0 on a hit.
const HIT: u32 = 1;

/// The programs of these tests. Closest hit (`__closesthit__log`): logs what it sees and writes
/// `[HIT, instance id, instance index, ray mask, record data]`. Any hit (`__anyhit__log`): logs.
/// Intersection (`__intersection__box`): logs, then reports the entry of the object ray into
/// the primitive's box (hit kind 1). Miss: writes [`MISS`] to word 0.
fn programs() -> Module<Lp> {
    module()
        .closest_hit("__closesthit__log", |ctx| {
            ctx.params().push(seen_ch(ctx));
            ctx.set_payload(0, HIT);
            ctx.set_payload(1, ctx.instance_id());
            ctx.set_payload(2, ctx.instance_index());
            ctx.set_payload(3, ctx.ray_visibility_mask() as u32);
            ctx.set_payload(4, ctx.sbt_data::<u32>().unwrap_or(!0));
            Ok(())
        })
        .unwrap()
        .any_hit("__anyhit__log", |ctx| {
            ctx.params().push(seen_ah(ctx));
            Ok(())
        })
        .unwrap()
        .intersection("__intersection__box", |ctx| {
            ctx.params().push(seen_is(ctx));
            let (o, d, b) = (
                ctx.object_ray_origin(),
                ctx.object_ray_direction(),
                ctx.primitive_aabb(),
            );
            let inv = d.recip();
            let (t0, t1) = ((b.min - o) * inv, (b.max - o) * inv);
            let (tn, tf) = (t0.min(t1).max_element(), t0.max(t1).min_element());
            if tn <= tf {
                let t = if tn >= ctx.ray_tmin() { tn } else { tf };
                ctx.report_intersection(t, 1, &[])?;
            }
            Ok(())
        })
        .unwrap()
        .miss("__miss__ms", |ctx| {
            ctx.set_payload(0, MISS);
            Ok(())
        })
        .unwrap()
}

const TRI: HitProgs<'static> = HitProgs {
    ch: Some("__closesthit__log"),
    ah: Some("__anyhit__log"),
    is: None,
};

const BOX: HitProgs<'static> = HitProgs {
    ch: Some("__closesthit__log"),
    ah: Some("__anyhit__log"),
    is: Some("__intersection__box"),
};

/// Record 0 for triangles, record 1 for boxes.
fn harness(graph: TraversableGraphFlags) -> Harness {
    Harness::new(
        &programs(),
        Some("__miss__ms"),
        &[(TRI, 0), (BOX, 1)],
        graph,
    )
}

/// A triangle in z = 0 around the origin (CCW from +z).
fn unit_tri() -> Arc<Gas> {
    tri_gas(&[tri_at(0.0, 0.0, 0.0, 0.5)])
}

// ---------------------------------------------------------------------------------------------
// Visibility masks
// ---------------------------------------------------------------------------------------------

/// §5.4 / §13.2 / §12, J, U.1, G15: an instance is visited iff `ray mask & instance mask & 0xFF`
/// is not zero, for every 8-bit ray mask; a ray mask of 0 hits no instanced geometry; bits above
/// the eighth in the trace argument are ignored (and `ray_visibility_mask()` returns the low 8).
#[test]
fn g15_instance_visited_iff_masks_share_a_bit() {
    let masks = [0x01u32, 0x02, 0x80, 0x5A, 0xFF, 0x00];
    let gas = unit_tri();
    let instances: Vec<Instance> = masks
        .iter()
        .enumerate()
        .map(|(k, &m)| {
            Instance::new(gas.clone().into())
                .transform(at_x(2.0 * k as f32))
                .visibility_mask(m)
                .instance_id(k as u32)
        })
        .collect();
    let root = handle_of(&instances);
    let h = harness(TraversableGraphFlags::empty());
    let mut rays = Vec::new();
    let mut expect = Vec::new();
    for (k, &inst_mask) in masks.iter().enumerate() {
        for m in 0..=255u32 {
            for high in [0u32, 0x100, 0xFFFF_FF00, 0x8000_0000] {
                rays.push(RaySpec::down(2.0 * k as f32, 0.0).mask(high | m));
                expect.push((k, inst_mask, high | m, m & inst_mask != 0));
            }
        }
    }
    let out = h.run(&root, &rays);
    assert_eq!(out.report.exceptions, 0);
    for (i, &(k, inst_mask, ray_mask, visible)) in expect.iter().enumerate() {
        let p = out.payloads[i];
        assert_eq!(
            p[0] == HIT,
            visible,
            "instance mask {inst_mask:#x}, ray mask {ray_mask:#x}"
        );
        if visible {
            assert_eq!(p[2], k as u32);
            assert_eq!(p[3], ray_mask & 0xFF, "ray_visibility_mask()");
        } else {
            assert!(
                out.of(i as u32, Prog::Ah).is_empty(),
                "any hit on a culled instance"
            );
        }
    }
}

/// §5.4 / §13.2, G15: along a path of instances, every instance's mask must share a bit with the
/// ray's (a static transform has no mask).
#[test]
fn g15_nested_instances_each_test_the_mask() {
    let gas = unit_tri();
    let combos = [(0x0Fu32, 0xF0u32), (0x03, 0x01), (0xFF, 0x80), (0x00, 0xFF)];
    let mut top = Vec::new();
    for (k, &(parent, child)) in combos.iter().enumerate() {
        let mid = ias(&[Instance::new(gas.clone().into()).visibility_mask(child)]);
        let st = StaticTransform::new(mid.into(), at_x(2.0 * k as f32)).unwrap();
        top.push(Instance::new(st.into()).visibility_mask(parent));
    }
    let root = handle_of(&top);
    let mut rays = Vec::new();
    for k in 0..combos.len() {
        for m in 0..=255u32 {
            rays.push(RaySpec::down(2.0 * k as f32, 0.0).mask(m));
        }
    }
    let out = harness(TraversableGraphFlags::empty()).run(&root, &rays);
    for (k, &(parent, child)) in combos.iter().enumerate() {
        for m in 0..=255u32 {
            let p = out.payloads[k * 256 + m as usize];
            let visible = m & parent != 0 && m & child != 0;
            assert_eq!(
                p[0] == HIT,
                visible,
                "parent mask {parent:#x}, child mask {child:#x}, ray mask {m:#x}"
            );
        }
    }
}

/// §13.2 / G15: the mask applies to instances only: a GAS traced directly is hit whatever the
/// ray mask, 0 included (and its custom primitives are intersected).
#[test]
fn g15_gas_root_ignores_the_visibility_mask() {
    let tri: TraversableHandle = unit_tri().into();
    let boxes: TraversableHandle =
        box_gas(&[Aabb::new(Vec3::splat(-0.5), Vec3::splat(0.5))]).into();
    let h = harness(TraversableGraphFlags::empty());
    // The box GAS's hit group is record 1: reach it with the trace's SBT offset.
    for (root, offset) in [(&tri, 0), (&boxes, 1)] {
        let rays: Vec<RaySpec> = [0u32, 0x100, 0x01, 0xFF]
            .iter()
            .map(|&m| RaySpec::down(0.0, 0.0).mask(m).sbt(offset, 1, 0))
            .collect();
        let out = h.run(root, &rays);
        for (i, p) in out.payloads.iter().enumerate() {
            assert_eq!(p[0], HIT, "GAS root, ray mask {:#x}", rays[i].mask);
        }
    }
}

/// §5.4 / G15: the query API (no ray mask argument) never visits an instance whose mask is 0,
/// and visits every other.
#[test]
fn g15_query_api_skips_instances_with_mask_zero() {
    let gas = unit_tri();
    let make = |mask: u32| {
        ias(&[Instance::new(gas.clone().into())
            .visibility_mask(mask)
            .instance_id(mask)])
    };
    let ray = oxray::Ray::new(Vec3::new(0.0, 0.0, 5.0), -Vec3::Z);
    for mask in [0u32, 1, 0x80, 0xFF] {
        let s = make(mask);
        assert_eq!(s.intersect(&ray).is_some(), mask != 0, "mask {mask:#x}");
        assert_eq!(s.occluded(&ray), mask != 0, "mask {mask:#x}");
    }
}

// ---------------------------------------------------------------------------------------------
// Instance queries and transforms
// ---------------------------------------------------------------------------------------------

/// §13.7 / U.6, G21: instance_id() and instance_index() in AH, CH and IS name the instance hit:
/// its user id (up to 2^28 - 1) and its position in the build input, for triangles and custom
/// primitives, whatever the order the BVH stores instances in.
#[test]
fn u6_instance_id_and_index_in_ah_ch_is() {
    let tri = unit_tri();
    let boxes = box_gas(&[Aabb::new(Vec3::splat(-0.4), Vec3::splat(0.4))]);
    let ids = [7u32, (1 << 28) - 1, 0, 12345, 99, 1 << 27];
    let instances: Vec<Instance> = ids
        .iter()
        .enumerate()
        .map(|(k, &id)| {
            let (gas, offset) = if k % 2 == 0 { (&tri, 0) } else { (&boxes, 1) };
            Instance::new(gas.clone().into())
                // Reverse order in x, so that input order and position differ.
                .transform(at_x(2.0 * (ids.len() - k) as f32))
                .instance_id(id)
                .sbt_offset(offset)
        })
        .collect();
    let root = handle_of(&instances);
    let rays: Vec<RaySpec> = (0..ids.len())
        .map(|k| RaySpec::down(2.0 * (ids.len() - k) as f32, 0.0))
        .collect();
    let out = harness(TraversableGraphFlags::empty()).run(&root, &rays);
    assert_eq!(out.report.exceptions, 0, "{:?}", out.report);
    for (k, &id) in ids.iter().enumerate() {
        let i = k as u32;
        assert_eq!(&out.payloads[k][..3], &[HIT, id, i], "instance {k}");
        let mut progs = vec![Prog::Ah, Prog::Ch];
        if k % 2 == 1 {
            progs.push(Prog::Is);
        }
        for p in progs {
            let seen = out.of(i, p);
            assert!(!seen.is_empty(), "no {p:?} for instance {k}");
            for s in seen {
                assert_eq!(
                    (s.instance_id, s.instance_index),
                    (id, i),
                    "{p:?}, instance {k}"
                );
            }
        }
    }
}

/// §13.7 / §13.11, U.6, G21: without instances (a GAS traced directly) instance_id() is `!0`,
/// instance_index() 0, the transform list is empty, the transforms are the identity and the
/// object ray is the world ray, in AH, CH and IS.
#[test]
fn u6_gas_root_has_no_instance() {
    let tri: TraversableHandle = unit_tri().into();
    let boxes: TraversableHandle =
        box_gas(&[Aabb::new(Vec3::splat(-0.4), Vec3::splat(0.4))]).into();
    let h = harness(TraversableGraphFlags::empty());
    let ray = RaySpec::new(Vec3::new(0.1, 0.2, 5.0), Vec3::new(0.01, -0.02, -1.5));
    for (root, offset) in [(&tri, 0), (&boxes, 1)] {
        let out = h.run(root, &[ray.clone().sbt(offset, 1, 0)]);
        assert_eq!(
            out.payloads[0][..3],
            [HIT, !0, 0],
            "payload {:?}",
            out.payloads[0]
        );
        assert!(!out.seen.is_empty());
        for s in &out.seen {
            assert_eq!((s.instance_id, s.instance_index), (!0, 0), "{:?}", s.prog);
            if let Some(o) = s.object_origin {
                assert_eq!(o, ray.origin, "{:?}", s.prog);
                assert_eq!(s.object_dir, Some(ray.dir), "{:?}", s.prog);
            }
            if s.prog != Prog::Is {
                assert_eq!(s.levels, Some(0));
                assert_eq!(s.o2w, Some(Transform::IDENTITY));
                assert_eq!(s.w2o, Some(Transform::IDENTITY));
                let pr = s.probes.unwrap();
                assert_eq!(pr.point_to_world, PROBE);
                assert_eq!(pr.normal_to_object, PROBE);
            }
        }
    }
}

/// The linear part of an affine transform as a `Mat3`.
fn linear(a: &Affine3A) -> Mat3 {
    Mat3::from(a.matrix3)
}

/// Checks what a hit program saw against the composed object-to-world transform `o2w`.
fn check_transforms(s: &Seen, o2w: &Affine3A, levels: u32, what: &str) {
    let w2o = o2w.inverse();
    let tol = 2e-5;
    if let (Some(o), Some(d)) = (s.object_origin, s.object_dir) {
        assert!(
            vclose(o, w2o.transform_point3(s.world_origin), tol),
            "{what}: object ray origin {o} vs {}",
            w2o.transform_point3(s.world_origin)
        );
        assert!(
            vclose(d, w2o.transform_vector3(s.world_dir), tol),
            "{what}: object ray direction {d} vs {}",
            w2o.transform_vector3(s.world_dir)
        );
    }
    if s.prog == Prog::Is {
        return;
    }
    assert_eq!(s.levels, Some(levels), "{what}: transform_list_size()");
    let got = s.o2w.unwrap();
    assert!(
        tclose(&got, &Transform::from_affine(o2w), tol),
        "{what}: object_to_world {got:?} vs {:?}",
        Transform::from_affine(o2w)
    );
    let got = s.w2o.unwrap();
    assert!(
        tclose(&got, &Transform::from_affine(&w2o), tol),
        "{what}: world_to_object {got:?} vs {:?}",
        Transform::from_affine(&w2o)
    );
    let m = linear(o2w);
    let pr = s.probes.unwrap();
    let expect = [
        (
            "point to world",
            pr.point_to_world,
            o2w.transform_point3(PROBE),
        ),
        ("vector to world", pr.vector_to_world, m * PROBE),
        (
            "normal to world (inverse transpose)",
            pr.normal_to_world,
            m.inverse().transpose() * PROBE,
        ),
        (
            "point to object",
            pr.point_to_object,
            w2o.transform_point3(PROBE),
        ),
        ("vector to object", pr.vector_to_object, m.inverse() * PROBE),
        (
            "normal to object (transpose)",
            pr.normal_to_object,
            m.transpose() * PROBE,
        ),
    ];
    for (name, got, want) in expect {
        assert!(vclose(got, want, tol), "{what}: {name}: {got} vs {want}");
    }
}

/// §13.11 / Z1.8, U.6: in AH and CH the composed transforms, the six transform helpers (normals
/// with the inverse transpose) and the transform list size agree with the instance's transform;
/// in AH and IS the object ray is the world ray mapped by the inverse. Also: the world normal
/// from `transform_normal_to_world` is perpendicular to the world triangle, and the hit point
/// from the barycentrics, mapped to world, lies on the world ray at `ray_tmax()`.
#[test]
fn z18_transforms_and_object_ray_in_single_level_instances() {
    let obj_tri = tri_at(0.0, 0.0, 0.0, 0.5);
    let tri = tri_gas(&[obj_tri]);
    let boxes = box_gas(&[Aabb::new(Vec3::splat(-0.4), Vec3::splat(0.4))]);
    let mut rng = Rng::new(0xAFF1);
    let affines: Vec<Affine3A> = (0..16).map(|_| rng.affine(6.0)).collect();
    let instances: Vec<Instance> = affines
        .iter()
        .enumerate()
        .map(|(k, a)| {
            let (gas, offset) = if k % 4 == 3 { (&boxes, 1) } else { (&tri, 0) };
            Instance::new(gas.clone().into())
                .transform(Transform::from_affine(a))
                .instance_id(500 + k as u32)
                .sbt_offset(offset)
        })
        .collect();
    let root = handle_of(&instances);
    // Rays at the world image of the object-space centre, from random origins.
    let rays: Vec<RaySpec> = affines
        .iter()
        .map(|a| {
            let target = a.transform_point3(Vec3::new(0.0, -0.1, 0.0));
            let o = target + rng.unit() * 3.0;
            RaySpec::new(o, (target - o) * rng.range(0.5, 2.0))
        })
        .collect();
    let out = harness(TraversableGraphFlags::empty()).run(&root, &rays);
    assert_eq!(out.report.exceptions, 0, "{:?}", out.report);
    for (k, a) in affines.iter().enumerate() {
        let i = k as u32;
        // Other instances may be in the way: check only those the ray's closest hit is on.
        if out.payloads[k][2] != i {
            continue;
        }
        for s in out
            .seen
            .iter()
            .filter(|s| s.ray == i && s.instance_index == i)
        {
            let what = format!("instance {k}, {:?}", s.prog);
            check_transforms(s, a, 1, &what);
            if let Some([u, v]) = s.bary {
                let p = bary_point(&obj_tri, u, v);
                let hit = s.world_origin + s.world_dir * s.tmax;
                assert!(
                    vclose(a.transform_point3(p), hit, 1e-4),
                    "{what}: barycentric point {} vs ray at tmax {hit}",
                    a.transform_point3(p)
                );
                let n = s.probes.unwrap().z_normal_to_world;
                let w = obj_tri.map(|q| a.transform_point3(Vec3::from_array(q)));
                for e in [w[1] - w[0], w[2] - w[0]] {
                    assert!(
                        n.normalize().dot(e.normalize()).abs() < 1e-4,
                        "{what}: world normal {n} not perpendicular to edge {e}"
                    );
                }
            }
        }
        assert!(
            !out.of(i, Prog::Ch).is_empty() && !out.of(i, Prog::Ah).is_empty(),
            "instance {k}"
        );
        if k % 4 == 3 {
            assert!(
                !out.of(i, Prog::Is).is_empty(),
                "instance {k}: intersection"
            );
        }
    }
    let checked = (0..affines.len())
        .filter(|&k| out.payloads[k][2] == k as u32)
        .count();
    assert!(checked >= 12, "only {checked} rays hit their own instance");
}

/// §13.11 / Z1.8: transform_list_size() counts every instance and static transform on the path,
/// and the composed transforms are their product (root first); the object ray in AH and IS is
/// the world ray mapped by the inverse of that product.
#[test]
fn z18_transform_list_of_multilevel_paths() {
    let tri = unit_tri();
    let boxes = box_gas(&[Aabb::new(Vec3::splat(-0.4), Vec3::splat(0.4))]);
    let mut rng = Rng::new(0x7157);
    let small = |rng: &mut Rng| rng.affine(0.3);
    for custom in [false, true] {
        let (gas, offset): (TraversableHandle, u32) = if custom {
            (boxes.clone().into(), 1)
        } else {
            (tri.clone().into(), 0)
        };
        let (a, b, c) = (small(&mut rng), small(&mut rng), small(&mut rng));
        let inst = |h: TraversableHandle, t: &Affine3A| {
            Instance::new(h)
                .transform(Transform::from_affine(t))
                .sbt_offset(offset)
        };
        let one =
            |h: TraversableHandle, t: &Affine3A| -> TraversableHandle { handle_of(&[inst(h, t)]) };
        let st = |h: TraversableHandle, t: &Affine3A| -> TraversableHandle {
            StaticTransform::new(h, Transform::from_affine(t))
                .unwrap()
                .into()
        };
        // Offsets of nested instances add up: only the innermost carries the offset.
        let one0 = |h: TraversableHandle, t: &Affine3A| -> TraversableHandle {
            handle_of(&[Instance::new(h).transform(Transform::from_affine(t))])
        };
        // (graph, composed object-to-world, levels)
        let graphs: Vec<(&str, TraversableHandle, Affine3A, u32)> = vec![
            ("IAS > GAS", one(gas.clone(), &a), a, 1),
            ("IAS > IAS > GAS", one0(one(gas.clone(), &b), &a), a * b, 2),
            ("IAS > static > GAS", one(st(gas.clone(), &b), &a), a * b, 2),
            (
                "IAS > static > IAS > GAS",
                one0(st(one(gas.clone(), &c), &b), &a),
                a * b * c,
                3,
            ),
            (
                "IAS > static > static > GAS",
                one(st(st(gas.clone(), &c), &b), &a),
                a * b * c,
                3,
            ),
        ];
        let h = harness(TraversableGraphFlags::empty());
        for (name, root, o2w, levels) in graphs {
            let target = o2w.transform_point3(Vec3::new(0.05, -0.1, 0.0));
            let o = target + Vec3::new(0.3, 0.2, 4.0);
            let out = h.run(&root, &[RaySpec::new(o, target - o)]);
            assert_eq!(out.report.exceptions, 0, "{name}: {:?}", out.report);
            assert_eq!(out.payloads[0][0], HIT, "{name}, custom {custom}");
            let mut progs: Vec<Prog> = out.seen.iter().map(|s| s.prog).collect();
            progs.dedup();
            assert!(
                progs.contains(&Prog::Ch) && progs.contains(&Prog::Ah),
                "{name}"
            );
            assert_eq!(progs.contains(&Prog::Is), custom, "{name}");
            for s in &out.seen {
                check_transforms(s, &o2w, levels, &format!("{name}, {:?}", s.prog));
            }
        }
    }
}

/// §13.7 / U.6: in an IS program, the object ray of a transformed instance gives the world t:
/// the reported hit, seen in CH at `ray_tmax()`, lies on the world image of the box.
#[test]
fn u6_intersection_program_object_ray_gives_world_t() {
    let b = Aabb::new(Vec3::new(-0.4, -0.3, -0.2), Vec3::new(0.4, 0.3, 0.2));
    let boxes = box_gas(&[b]);
    let mut rng = Rng::new(0xB0C5);
    for k in 0..8 {
        let a = rng.affine(3.0);
        let root = handle_of(&[Instance::new(boxes.clone().into())
            .transform(Transform::from_affine(&a))
            .instance_id(k)
            .sbt_offset(1)]);
        let target = a.transform_point3(Vec3::new(0.1, 0.05, 0.0));
        let o = target + rng.unit() * 4.0;
        let out =
            harness(TraversableGraphFlags::empty()).run(&root, &[RaySpec::new(o, target - o)]);
        assert_eq!(out.payloads[0][0], HIT, "instance {k}");
        let ch = out.of(0, Prog::Ch)[0].clone();
        let p = a
            .inverse()
            .transform_point3(ch.world_origin + ch.world_dir * ch.tmax);
        let on_face =
            (0..3).any(|i| (p[i] - b.min[i]).abs() < 1e-4 || (p[i] - b.max[i]).abs() < 1e-4);
        let inside = (0..3).all(|i| p[i] >= b.min[i] - 1e-4 && p[i] <= b.max[i] + 1e-4);
        assert!(
            on_face && inside,
            "instance {k}: object hit point {p} not on the box {b:?}"
        );
        for s in out.of(0, Prog::Is) {
            assert_eq!((s.instance_id, s.instance_index), (k, 0));
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Traversable graph flags
// ---------------------------------------------------------------------------------------------

/// §5.9.1 / §6.3, O: the pipeline's traversable graph flags against the graph traced.
/// ALLOW_SINGLE_LEVEL_INSTANCING allows an IAS over GASes only (no IAS or transform below);
/// ALLOW_SINGLE_GAS only allows a GAS root; empty flags allow any graph.
#[test]
fn o_traversable_graph_flags_restrict_the_graph() {
    let gas = unit_tri();
    let gas_h: TraversableHandle = gas.clone().into();
    let single: TraversableHandle = handle_of(&[Instance::new(gas.clone().into())]);
    let two_level: TraversableHandle = handle_of(&[Instance::new(single.clone())]);
    let with_static: TraversableHandle = handle_of(&[Instance::new(
        StaticTransform::new(gas.clone().into(), Transform::IDENTITY)
            .unwrap()
            .into(),
    )]);
    let nulls: TraversableHandle = handle_of(&[Instance::new(TraversableHandle::NULL)]);
    let mixed: TraversableHandle = handle_of(&[
        Instance::new(gas.clone().into()).transform(at_x(4.0)),
        Instance::new(single.clone()),
    ]);
    let g = TraversableGraphFlags::ALLOW_SINGLE_GAS;
    let l = TraversableGraphFlags::ALLOW_SINGLE_LEVEL_INSTANCING;
    let any = TraversableGraphFlags::empty();
    let invalid = Some(ExceptionCode::TRAVERSAL_INVALID_TRAVERSABLE);
    // (flags, root, name, expected exception, hit expected)
    let cases: Vec<(
        TraversableGraphFlags,
        &TraversableHandle,
        &str,
        Option<ExceptionCode>,
        bool,
    )> = vec![
        (l, &single, "IAS > GAS", None, true),
        (l, &nulls, "IAS > null", None, false),
        (l, &two_level, "IAS > IAS > GAS", invalid, false),
        (l, &with_static, "IAS > static > GAS", invalid, false),
        (l, &mixed, "IAS > {GAS, IAS}", invalid, false),
        (
            l,
            &gas_h,
            "GAS",
            Some(ExceptionCode::UNSUPPORTED_SINGLE_LEVEL_GAS),
            false,
        ),
        (g, &gas_h, "GAS", None, true),
        (g, &single, "IAS > GAS", invalid, false),
        (g, &two_level, "IAS > IAS > GAS", invalid, false),
        (g | l, &gas_h, "GAS", None, true),
        (g | l, &single, "IAS > GAS", None, true),
        (g | l, &two_level, "IAS > IAS > GAS", invalid, false),
        (any, &two_level, "IAS > IAS > GAS", None, true),
        (any, &with_static, "IAS > static > GAS", None, true),
        (any, &single, "IAS > GAS", None, true),
        (any, &gas_h, "GAS", None, true),
    ];
    for (flags, root, name, exception, hit) in cases {
        let out = harness(flags).run(root, &[RaySpec::down(0.0, 0.0)]);
        let what = format!("{name} with {flags:?}");
        match exception {
            Some(code) => {
                assert_eq!(out.exception_codes(), vec![code], "{what}");
                assert_eq!(
                    out.payloads[0], [UNSET; PAYLOAD],
                    "{what}: the trace returned"
                );
                assert!(out.seen.is_empty(), "{what}: programs ran");
            }
            None => {
                assert_eq!(out.report.exceptions, 0, "{what}: {:?}", out.report);
                assert_eq!(out.payloads[0][0] == HIT, hit, "{what}");
            }
        }
    }
}

/// §6.3 / O (`usesPrimitiveTypeFlags`): a pipeline's primitive-type flags apply to every GAS the
/// trace reaches, not only to a GAS root: with triangles only, custom primitives below an
/// instance raise `UNSUPPORTED_PRIMITIVE_TYPE` exactly as the same GAS traced directly does
/// (and with custom primitives only, triangles below an instance do).
#[test]
fn o_primitive_type_flags_apply_below_instances() {
    let tri = unit_tri();
    let boxes = box_gas(&[Aabb::new(Vec3::splat(-0.4), Vec3::splat(0.4))]);
    for (allowed, gas, offset) in [
        (PrimitiveTypeFlags::TRIANGLE, &boxes, 1),
        (PrimitiveTypeFlags::CUSTOM, &tri, 0),
    ] {
        let compile = PipelineCompileOptions {
            uses_primitive_type_flags: allowed,
            ..Harness::compile_options()
        };
        let h = Harness::with_compile(
            &programs(),
            Some("__miss__ms"),
            &[(TRI, 0), (BOX, 1)],
            &compile,
        );
        let ray = RaySpec::down(0.0, 0.0).sbt(offset, 1, 0);
        let direct: TraversableHandle = gas.clone().into();
        let out = h.run(&direct, std::slice::from_ref(&ray));
        assert_eq!(
            out.exception_codes(),
            vec![ExceptionCode::UNSUPPORTED_PRIMITIVE_TYPE],
            "GAS root, allowed {allowed:?}"
        );
        let instanced = handle_of(&[Instance::new(gas.clone().into()).sbt_offset(offset)]);
        let out = h.run(&instanced, &[RaySpec::down(0.0, 0.0)]);
        assert_eq!(
            out.exception_codes(),
            vec![ExceptionCode::UNSUPPORTED_PRIMITIVE_TYPE],
            "IAS > GAS, allowed {allowed:?}: programs saw {:?}, payload {:?}",
            out.seen.iter().map(|s| s.prog).collect::<Vec<_>>(),
            out.payloads[0]
        );
    }
}

/// §2.5 / §13.11, O, U.6: a static transform may be the root of a trace: its transform is the
/// transform list (size 1), and there is no instance (id `!0`, index 0); the visibility mask does
/// not apply to it.
#[test]
fn o_static_transform_root() {
    let a = Rng::new(0x57a7).affine(2.0);
    let root: TraversableHandle =
        StaticTransform::new(unit_tri().into(), Transform::from_affine(&a))
            .unwrap()
            .into();
    let target = a.transform_point3(Vec3::new(0.0, -0.1, 0.0));
    let o = target + Vec3::new(0.2, -0.3, 5.0);
    let rays = [
        RaySpec::new(o, target - o),
        RaySpec::new(o, target - o).mask(0),
    ];
    let out = harness(TraversableGraphFlags::empty()).run(&root, &rays);
    assert_eq!(out.report.exceptions, 0, "{:?}", out.report);
    for i in 0..2 {
        assert_eq!(out.payloads[i][..3], [HIT, !0, 0], "ray {i}");
        for s in out.seen.iter().filter(|s| s.ray == i as u32) {
            assert_eq!((s.instance_id, s.instance_index), (!0, 0));
            check_transforms(s, &a, 1, &format!("static root, ray {i}, {:?}", s.prog));
        }
    }
}
