//! Multi-level traversable graphs (guide §2.5, §5.4, §5.9, §7.3.1; inventory J, O, U.3, U.5,
//! Z7 G11, G13, G18, G23):
//!
//! * IAS → IAS → GAS, IAS → static transform → GAS and IAS → static transform → IAS → GAS give
//!   the hits of the same geometry flattened into one GAS, with the nearest instance reported;
//! * the SBT offsets of all instances on the path are summed into the hit-group index;
//! * the nearest instance's flags override its ancestors' (any-hit, facing, culling);
//! * instance any-hit flags against geometry and ray flags (U.3 precedence).

mod instancing_common;

use instancing_common::*;
use oxray::cpu::{Gas, Ias};
use oxray::{
    BuildOptions, GeometryFlags, HitKind, Instance, InstanceFlags, Module, RayFlags,
    StaticTransform, Transform, TraversableGraphFlags, TraversableHandle,
};
use proptest::prelude::any;
use proptest::test_runner::{TestCaseError, TestRunner};
use std::sync::Arc;

fn ias(instances: &[Instance]) -> Ias {
    Ias::build(&BuildOptions::default(), &[instances.into()]).expect("IAS build")
}

fn handle_of(instances: &[Instance]) -> TraversableHandle {
    ias(instances).into()
}

/// A random soup per GAS.
fn soups(rng: &mut Rng, n: usize) -> Vec<Vec<Tri>> {
    (0..n)
        .map(|_| {
            let k = 6 + rng.below(20);
            random_soup(rng, k, 1.0, 0.6)
        })
        .collect()
}

/// The shapes of graph the randomized test builds.
#[derive(Clone, Copy, Debug)]
enum Shape {
    /// Top IAS → mid IAS → GAS.
    NestedIas,
    /// Top IAS → static transform → GAS.
    StaticThenGas,
    /// Top IAS → static transform → mid IAS → GAS.
    StaticThenIas,
}

/// A random two-level scene of the given shape, its leaves (one per path to a GAS) and the
/// flattened GAS.
fn multilevel_scene(rng: &mut Rng, shape: Shape) -> (Ias, Vec<Leaf>, Gas) {
    let soups = soups(rng, 3);
    let gases: Vec<Arc<Gas>> = soups.iter().map(|s| tri_gas(s)).collect();
    // Mid level: 2 IASes of 2-3 instances each (ids distinct from the top level's).
    struct Mid {
        ias: Arc<Ias>,
        /// (transform, gas, id) of each instance.
        inst: Vec<(Transform, usize, u32)>,
    }
    let mids: Vec<Mid> = (0..2)
        .map(|m| {
            let inst: Vec<(Transform, usize, u32)> = (0..2 + rng.below(2))
                .map(|j| {
                    (
                        Transform::from_affine(&rng.affine(2.5)),
                        rng.below(3),
                        1000 * (m + 1) as u32 + j as u32,
                    )
                })
                .collect();
            let instances: Vec<Instance> = inst
                .iter()
                .map(|&(t, g, id)| {
                    Instance::new(gases[g].clone().into())
                        .transform(t)
                        .instance_id(id)
                })
                .collect();
            Mid {
                ias: Arc::new(ias(&instances)),
                inst,
            }
        })
        .collect();
    let mut leaves = Vec::new();
    let mut top = Vec::new();
    for i in 0..3 + rng.below(3) {
        let t_top = Transform::from_affine(&rng.affine(5.0));
        let id = 10 + i as u32;
        match shape {
            Shape::NestedIas | Shape::StaticThenIas => {
                let m = rng.below(2);
                // Under StaticThenIas, a static transform sits between the top instance and
                // the mid IAS.
                let (child, st): (TraversableHandle, Transform) = match shape {
                    Shape::NestedIas => (mids[m].ias.clone().into(), Transform::IDENTITY),
                    _ => {
                        let s = Transform::from_affine(&rng.affine(1.0));
                        let h = StaticTransform::new(mids[m].ias.clone().into(), s)
                            .expect("static transform")
                            .into();
                        (h, s)
                    }
                };
                for (j, &(t_mid, g, mid_id)) in mids[m].inst.iter().enumerate() {
                    let object = transform_tris(&t_mid, &soups[g]);
                    leaves.push(Leaf {
                        world: transform_tris(&t_top, &transform_tris(&st, &object)),
                        instance_id: mid_id,
                        instance_index: j as u32,
                    });
                }
                top.push(Instance::new(child).transform(t_top).instance_id(id));
            }
            Shape::StaticThenGas => {
                let g = rng.below(3);
                let s = Transform::from_affine(&rng.affine(1.0));
                let child: TraversableHandle = StaticTransform::new(gases[g].clone().into(), s)
                    .expect("static transform")
                    .into();
                leaves.push(Leaf {
                    world: transform_tris(&t_top, &transform_tris(&s, &soups[g])),
                    instance_id: id,
                    instance_index: i as u32,
                });
                top.push(Instance::new(child).transform(t_top).instance_id(id));
            }
        }
    }
    let flat = flattened_gas(&leaves.iter().map(|l| l.world.clone()).collect::<Vec<_>>());
    (ias(&top), leaves, flat)
}

fn run_shape(shape: Shape, cases: u32) {
    let mut runner = TestRunner::new(proptest_config(cases));
    let total = std::cell::RefCell::new(Stats::default());
    let result = runner.run(&any::<u64>(), |seed| {
        let mut rng = Rng::new(seed);
        let (ias, leaves, flat) = multilevel_scene(&mut rng, shape);
        let mut st = Stats::default();
        for ray in aimed_rays(&mut rng, &leaves, 12.0, 300) {
            compare_ray(&ias, &flat, &leaves, &ray, &mut st).map_err(TestCaseError::fail)?;
        }
        total.borrow_mut().add(&st);
        Ok(())
    });
    if let Err(e) = result {
        panic!("{shape:?}: {e}");
    }
    total.into_inner().check(&format!("{shape:?} vs flattened"));
}

/// §5.4 / §2.5, J, O, G23: IAS → IAS → GAS against the flattened scene; hits report the nearest
/// (lower-level) instance.
#[test]
fn j_o_ias_of_ias_of_gas_matches_flattened() {
    run_shape(Shape::NestedIas, 24);
}

/// §5.4 / §2.5, O: IAS → static transform → GAS against the flattened scene; hits report the
/// instance above the static transform.
#[test]
fn o_ias_static_transform_gas_matches_flattened() {
    run_shape(Shape::StaticThenGas, 24);
}

/// §2.5, O: IAS → static transform → IAS → GAS against the flattened scene.
#[test]
fn o_ias_static_transform_ias_gas_matches_flattened() {
    run_shape(Shape::StaticThenIas, 16);
}

// ---------------------------------------------------------------------------------------------
// Pipeline: SBT offsets and flags along the path
// ---------------------------------------------------------------------------------------------

/// Payload word 0 after a miss.
const MISS: u32 = 0xFFFF_0000;

/// A module whose closest hit writes `[record data, instance id, hit kind, instance index]` to
/// payload words 0..4, whose any hit logs itself, and whose miss writes [`MISS`] to word 0.
fn recording_module() -> Module<Lp> {
    module()
        .closest_hit("__closesthit__rec", |ctx| {
            ctx.set_payload(0, ctx.sbt_data::<u32>().unwrap_or(!0));
            ctx.set_payload(1, ctx.instance_id());
            ctx.set_payload(2, ctx.hit_kind().0 as u32);
            ctx.set_payload(3, ctx.instance_index());
            Ok(())
        })
        .unwrap()
        .any_hit("__anyhit__log", |ctx| {
            ctx.params().push(seen_ah(ctx));
            Ok(())
        })
        .unwrap()
        .miss("__miss__ms", |ctx| {
            ctx.set_payload(0, MISS);
            Ok(())
        })
        .unwrap()
}

/// A harness over [`recording_module`] with `n` hit-group records (closest hit and any hit),
/// record `k` holding `k`.
fn recording_harness(n: u32) -> Harness {
    let m = recording_module();
    let hits: Vec<(HitProgs, u32)> = (0..n)
        .map(|k| {
            (
                HitProgs {
                    ch: Some("__closesthit__rec"),
                    ah: Some("__anyhit__log"),
                    is: None,
                },
                k,
            )
        })
        .collect();
    Harness::new(
        &m,
        Some("__miss__ms"),
        &hits,
        TraversableGraphFlags::empty(),
    )
}

/// §7.3.1 / §5.4, J, G18, G23: the SBT offsets of every instance on the path are summed, also
/// through a static transform, and added to `sbtGASIndex * stride + offset`.
#[test]
fn g23_sbt_offsets_are_summed_over_ancestor_instances() {
    // A GAS of two build inputs (SBT-GAS indices 0 and 1) at x = 0 and x = 0.5.
    let gas: Arc<Gas> = Arc::new(flattened_gas(&[
        vec![tri_at(0.0, 0.0, 0.0, 0.2)],
        vec![tri_at(0.5, 0.0, 0.0, 0.2)],
    ]));
    let b = [0u32, 3, 7];
    let mid_inst: Vec<Instance> = (0..3)
        .map(|j| {
            Instance::new(gas.clone().into())
                .transform(Transform::from_translation(Vec3::new(
                    2.0 * j as f32,
                    0.0,
                    0.0,
                )))
                .instance_id(100 + j)
                .sbt_offset(b[j as usize])
        })
        .collect();
    let mid: Arc<Ias> = Arc::new(ias(&mid_inst));
    // Top: rows y = 0, 2 are the mid IAS with offsets 10 and 20; row y = 4 is the mid IAS
    // under a static transform with offset 9 (the transform moves it to y = 4); row y = 6 is the
    // GAS under a static transform with offset 5.
    let a = [10u32, 20, 9, 5];
    let shift = |y: f32| Transform::from_translation(Vec3::new(0.0, y, 0.0));
    let top_inst = vec![
        Instance::new(mid.clone().into())
            .sbt_offset(a[0])
            .instance_id(1),
        Instance::new(mid.clone().into())
            .transform(shift(2.0))
            .sbt_offset(a[1])
            .instance_id(2),
        Instance::new(
            StaticTransform::new(mid.clone().into(), shift(4.0))
                .unwrap()
                .into(),
        )
        .sbt_offset(a[2])
        .instance_id(3),
        Instance::new(
            StaticTransform::new(gas.clone().into(), shift(3.0))
                .unwrap()
                .into(),
        )
        .transform(shift(3.0))
        .sbt_offset(a[3])
        .instance_id(4),
    ];
    let root = handle_of(&top_inst);
    // (ray, expected instance offset sum, expected nearest instance id and index, gas index)
    let mut cases = Vec::new();
    for (row, &a_i) in a.iter().enumerate().take(3) {
        for (j, &b_j) in b.iter().enumerate() {
            for g in 0..2 {
                let x = 2.0 * j as f32 + 0.5 * g as f32;
                cases.push((x, 2.0 * row as f32, a_i + b_j, 100 + j as u32, j as u32, g));
            }
        }
    }
    for g in 0..2 {
        cases.push((0.5 * g as f32, 6.0, a[3], 4, 3, g));
    }
    let h = recording_harness(a[1] + b[2] + 2 + 1 + 1);
    for (stride, offset) in [(1u32, 0u32), (2, 1), (0x12, 0x31)] {
        let rays: Vec<RaySpec> = cases
            .iter()
            .map(|&(x, y, ..)| RaySpec::down(x, y).sbt(offset, stride, 0))
            .collect();
        let out = h.run(&root, &rays);
        assert_eq!(out.report.exceptions, 0, "{:?}", out.report);
        for (k, &(x, y, sum, id, index, g)) in cases.iter().enumerate() {
            let expected = sum + g * (stride & 0xF) + (offset & 0xF);
            let p = out.payloads[k];
            assert_eq!(
                p[0], expected,
                "ray at ({x}, {y}), stride {stride}, offset {offset}: record {} instead of \
                 {expected} (payload {p:?})",
                p[0]
            );
            assert_eq!((p[1], p[3]), (id, index), "nearest instance at ({x}, {y})");
        }
    }
}

/// A two-level graph: a top instance with `parent` flags over a mid IAS whose one instance has
/// `child` flags over `gas`.
fn nested(parent: InstanceFlags, child: InstanceFlags, gas: &Arc<Gas>) -> TraversableHandle {
    let mid = ias(&[Instance::new(gas.clone().into())
        .flags(child)
        .instance_id(2)]);
    handle_of(&[Instance::new(mid.into()).flags(parent).instance_id(1)])
}

/// One ray down onto a triangle at the origin through `h`; returns (payload, any-hit calls).
fn one_ray(h: &Harness, root: &TraversableHandle, ray: RaySpec) -> ([u32; PAYLOAD], usize) {
    let out = h.run(root, &[ray]);
    assert_eq!(out.report.exceptions, 0, "{:?}", out.report);
    (out.payloads[0], out.of(0, Prog::Ah).len())
}

/// §5.4 / J, G11, G23: the any-hit flags of the instance nearest the geometry override those of
/// its ancestors; an ancestor's flags do not reach geometry below an instance without flags.
#[test]
fn g23_nearest_instance_anyhit_flags_override_ancestors() {
    let plain = tri_gas(&[tri_at(0.0, 0.0, 0.0, 0.5)]);
    let opaque = tri_gas_flags(&[tri_at(0.0, 0.0, 0.0, 0.5)], GeometryFlags::DISABLE_ANYHIT);
    let h = recording_harness(1);
    let e = InstanceFlags::empty();
    let (dis, enf) = (InstanceFlags::DISABLE_ANYHIT, InstanceFlags::ENFORCE_ANYHIT);
    // (parent, child, geometry, any-hit expected)
    let cases = [
        (enf, dis, &plain, false),
        (dis, enf, &opaque, true),
        (dis, e, &plain, true),
        (enf, e, &opaque, false),
        (e, dis, &plain, false),
        (e, enf, &opaque, true),
    ];
    for (parent, child, gas, ah) in cases {
        let root = nested(parent, child, gas);
        let (p, calls) = one_ray(&h, &root, RaySpec::down(0.0, 0.0));
        assert_eq!(
            p[0], 0,
            "closest hit of record 0 (parent {parent:?}, child {child:?})"
        );
        assert_eq!(
            calls,
            ah as usize,
            "parent {parent:?}, child {child:?}, geometry {:?}",
            gas.geometry_flags(0)
        );
    }
}

/// §5.4 / §13.7, U.5, G13, G23: FLIP_TRIANGLE_FACING makes the counter-clockwise face the back
/// face, for the reported hit kind and for culling; only the nearest instance's flag counts (a
/// flip on the parent and the child is one flip, not two).
#[test]
fn g13_flip_triangle_facing_flips_hit_kind_and_culling() {
    let gas = tri_gas(&[tri_at(0.0, 0.0, 0.0, 0.5)]);
    let h = recording_harness(1);
    let e = InstanceFlags::empty();
    let flip = InstanceFlags::FLIP_TRIANGLE_FACING;
    let (front, back) = (
        HitKind::TRIANGLE_FRONT_FACE.0 as u32,
        HitKind::TRIANGLE_BACK_FACE.0 as u32,
    );
    // (parent, child, flipped)
    for (parent, child, flipped) in [
        (e, e, false),
        (e, flip, true),
        (flip, e, false),
        (flip, flip, true),
    ] {
        let root = nested(parent, child, &gas);
        let what = format!("parent {parent:?}, child {child:?}");
        let (p, _) = one_ray(&h, &root, RaySpec::down(0.0, 0.0));
        assert_eq!(p[2], if flipped { back } else { front }, "{what}");
        let (p, _) = one_ray(
            &h,
            &root,
            RaySpec::down(0.0, 0.0).flags(RayFlags::CULL_BACK_FACING_TRIANGLES),
        );
        assert_eq!(p[0] == MISS, flipped, "CULL_BACK, {what}");
        let (p, _) = one_ray(
            &h,
            &root,
            RaySpec::down(0.0, 0.0).flags(RayFlags::CULL_FRONT_FACING_TRIANGLES),
        );
        assert_eq!(p[0] == MISS, !flipped, "CULL_FRONT, {what}");
        // From below, the faces swap.
        let up = RaySpec::new(Vec3::new(0.0, 0.0, -10.0), Vec3::Z);
        let (p, _) = one_ray(&h, &root, up);
        assert_eq!(
            p[2],
            if flipped { front } else { back },
            "from below, {what}"
        );
    }
    // The query API reports the same facing.
    for (flags, kind) in [
        (e, HitKind::TRIANGLE_FRONT_FACE),
        (flip, HitKind::TRIANGLE_BACK_FACE),
    ] {
        let one = ias(&[Instance::new(gas.clone().into()).flags(flags)]);
        let hit = one
            .intersect(&oxray::Ray::new(Vec3::new(0.0, 0.0, 5.0), -Vec3::Z))
            .expect("hit");
        assert_eq!(hit.hit_kind, kind, "query API, {flags:?}");
        let two = ias(&[Instance::new(nested(flip, flags, &gas))]);
        let hit = two
            .intersect(&oxray::Ray::new(Vec3::new(0.0, 0.0, 5.0), -Vec3::Z))
            .expect("hit");
        assert_eq!(
            hit.hit_kind, kind,
            "query API, nested under FLIP parent, {flags:?}"
        );
    }
}

/// §5.4 / U.2, G13: the instance flag DISABLE_TRIANGLE_FACE_CULLING overrides the culling ray
/// flags (also together with FLIP_TRIANGLE_FACING); a parent's flag does not reach below a child
/// instance without it.
#[test]
fn g13_instance_disable_face_culling_overrides_cull_ray_flags() {
    let gas = tri_gas(&[tri_at(0.0, 0.0, 0.0, 0.5)]);
    let h = recording_harness(1);
    let e = InstanceFlags::empty();
    let dfc = InstanceFlags::DISABLE_TRIANGLE_FACE_CULLING;
    let flip = InstanceFlags::FLIP_TRIANGLE_FACING;
    let down = RaySpec::down(0.0, 0.0);
    let up = RaySpec::new(Vec3::new(0.0, 0.0, -10.0), Vec3::Z);
    let cull_front = RayFlags::CULL_FRONT_FACING_TRIANGLES;
    let cull_back = RayFlags::CULL_BACK_FACING_TRIANGLES;
    // (parent, child, ray, flags, hit expected)
    let cases = [
        (e, e, &down, cull_front, false),
        (e, dfc, &down, cull_front, true),
        (e, e, &up, cull_back, false),
        (e, dfc, &up, cull_back, true),
        (e, dfc | flip, &down, cull_back, true),
        (e, flip, &down, cull_back, false),
        (dfc, e, &down, cull_front, false),
        (e, dfc, &down, cull_front | cull_back, true),
    ];
    for (parent, child, ray, flags, hit) in cases {
        let root = nested(parent, child, &gas);
        let (p, _) = one_ray(&h, &root, ray.clone().flags(flags));
        assert_eq!(
            p[0] != MISS,
            hit,
            "parent {parent:?}, child {child:?}, ray flags {flags:?} (payload {p:?})"
        );
    }
}

/// U.3 / §5.1, §5.4, §13.2, G11, G14: any-hit enablement: geometry flag, overridden by the
/// instance flag, overridden by the ray flag; CULL_DISABLED_ANYHIT / CULL_ENFORCED_ANYHIT drop
/// primitives by the resulting state.
#[test]
fn u3_instance_anyhit_flags_against_geometry_and_ray_flags() {
    let plain = tri_gas(&[tri_at(0.0, 0.0, 0.0, 0.5)]);
    let opaque = tri_gas_flags(&[tri_at(0.0, 0.0, 0.0, 0.5)], GeometryFlags::DISABLE_ANYHIT);
    let inst_flags = [
        InstanceFlags::empty(),
        InstanceFlags::DISABLE_ANYHIT,
        InstanceFlags::ENFORCE_ANYHIT,
    ];
    // Six instances side by side: geometry g, instance flags f at x = 2 (3 g + f).
    let mut instances = Vec::new();
    for (g, gas) in [&plain, &opaque].into_iter().enumerate() {
        for (f, &flags) in inst_flags.iter().enumerate() {
            let x = 2.0 * (3 * g + f) as f32;
            instances.push(
                Instance::new(gas.clone().into())
                    .transform(Transform::from_translation(Vec3::new(x, 0.0, 0.0)))
                    .flags(flags)
                    .instance_id((3 * g + f) as u32),
            );
        }
    }
    let root = handle_of(&instances);
    let ray_flags = [
        RayFlags::empty(),
        RayFlags::DISABLE_ANYHIT,
        RayFlags::ENFORCE_ANYHIT,
        RayFlags::CULL_DISABLED_ANYHIT,
        RayFlags::CULL_ENFORCED_ANYHIT,
    ];
    let mut rays = Vec::new();
    let mut expect = Vec::new();
    for g in 0..2 {
        for (f, &iflags) in inst_flags.iter().enumerate() {
            for &rflags in &ray_flags {
                let x = 2.0 * (3 * g + f) as f32;
                rays.push(RaySpec::down(x, 0.0).flags(rflags));
                let mut ah = g == 0;
                if iflags.contains(InstanceFlags::DISABLE_ANYHIT) {
                    ah = false;
                } else if iflags.contains(InstanceFlags::ENFORCE_ANYHIT) {
                    ah = true;
                }
                if rflags.contains(RayFlags::DISABLE_ANYHIT) {
                    ah = false;
                } else if rflags.contains(RayFlags::ENFORCE_ANYHIT) {
                    ah = true;
                }
                let culled = (rflags.contains(RayFlags::CULL_DISABLED_ANYHIT) && !ah)
                    || (rflags.contains(RayFlags::CULL_ENFORCED_ANYHIT) && ah);
                expect.push((g, f, iflags, rflags, !culled, ah && !culled));
            }
        }
    }
    let h = recording_harness(1);
    let out = h.run(&root, &rays);
    assert_eq!(out.report.exceptions, 0);
    for (k, &(g, f, iflags, rflags, hit, ah)) in expect.iter().enumerate() {
        let what = format!(
            "geometry {}, instance {iflags:?}, ray {rflags:?}",
            if g == 0 { "plain" } else { "DISABLE_ANYHIT" }
        );
        assert_eq!(out.payloads[k][0] != MISS, hit, "hit: {what}");
        assert_eq!(
            out.of(k as u32, Prog::Ah).len(),
            ah as usize,
            "any hit: {what}"
        );
        if hit {
            assert_eq!(
                out.payloads[k][1],
                (3 * g + f) as u32,
                "instance id: {what}"
            );
        }
    }
}

/// A top IAS of three instances (ids 1..=3, input order = top to bottom) of a mid IAS of three
/// stacked copies (ids 10..=12) of a triangle at the origin: nine triangles on the line x = y = 0
/// at z = 4 - (3 i + j) * 0.25 for top instance i and mid instance j.
fn stack_scene() -> TraversableHandle {
    let gas = tri_gas(&[tri_at(0.0, 0.0, 0.0, 0.5)]);
    let z = |z: f32| Transform::from_translation(Vec3::new(0.0, 0.0, z));
    let mid: Arc<Ias> = Arc::new(ias(&(0..3)
        .map(|j| {
            Instance::new(gas.clone().into())
                .transform(z(-0.25 * j as f32))
                .instance_id(10 + j)
        })
        .collect::<Vec<_>>()));
    handle_of(
        &(0..3)
            .map(|i| {
                Instance::new(mid.clone().into())
                    .transform(z(4.0 - 0.75 * i as f32))
                    .instance_id(1 + i)
            })
            .collect::<Vec<_>>(),
    )
}

/// §13.13 / U.4, G3, G7, G8, G9 across instance levels: an any hit that terminates ends the
/// whole traversal (one any-hit call, the closest hit is that candidate); an any hit that
/// ignores the candidates of one mid-level instance leaves the nearest other one as the closest
/// hit; TERMINATE_ON_FIRST_HIT stops after one accepted hit in any instance.
#[test]
fn u4_terminate_and_ignore_across_instance_levels() {
    let root = stack_scene();
    let m = module()
        .closest_hit("__closesthit__rec", |ctx| {
            ctx.params().push(seen_ch(ctx));
            ctx.set_payload_f32(0, ctx.ray_tmax());
            ctx.set_payload(1, ctx.instance_id());
            Ok(())
        })
        .unwrap()
        .any_hit("__anyhit__terminate", |ctx| {
            ctx.params().push(seen_ah(ctx));
            ctx.terminate_ray()
        })
        .unwrap()
        .any_hit("__anyhit__ignore10", |ctx| {
            ctx.params().push(seen_ah(ctx));
            if ctx.instance_id() == 10 {
                return ctx.ignore_intersection();
            }
            Ok(())
        })
        .unwrap()
        .any_hit("__anyhit__accept", |ctx| {
            ctx.params().push(seen_ah(ctx));
            Ok(())
        })
        .unwrap();
    let with_ah = |ah: &'static str| {
        Harness::new(
            &m,
            None,
            &[(
                HitProgs {
                    ch: Some("__closesthit__rec"),
                    ah: Some(ah),
                    is: None,
                },
                0,
            )],
            TraversableGraphFlags::empty(),
        )
    };
    let ray = RaySpec::down(0.0, 0.0);
    // Terminate: one any hit, and the closest hit is that candidate.
    let out = with_ah("__anyhit__terminate").run(&root, std::slice::from_ref(&ray));
    let ah = out.of(0, Prog::Ah);
    assert_eq!(ah.len(), 1, "{:?}", ah);
    let ch = out.of(0, Prog::Ch);
    assert_eq!(ch.len(), 1);
    assert_eq!(
        (ch[0].tmax, ch[0].instance_id),
        (ah[0].tmax, ah[0].instance_id)
    );
    // Ignore the nearest mid-level copy (id 10) everywhere: the closest hit is id 11 of the
    // top instance nearest the ray (z = 4 - 0.25, t = 6.25).
    let out = with_ah("__anyhit__ignore10").run(&root, std::slice::from_ref(&ray));
    let p = out.payloads[0];
    assert_eq!((f32::from_bits(p[0]), p[1]), (6.25, 11), "{:?}", out.seen);
    // Every candidate the any hit saw lies within the interval left by accepted hits.
    let mut tmax = f32::INFINITY;
    for s in out.of(0, Prog::Ah) {
        assert!(
            s.tmax <= tmax,
            "candidate at {} beyond accepted {tmax}",
            s.tmax
        );
        if s.instance_id != 10 {
            tmax = s.tmax;
        }
    }
    // TERMINATE_ON_FIRST_HIT: one accepted hit ends traversal.
    let first = ray.clone().flags(RayFlags::TERMINATE_ON_FIRST_HIT);
    let out = with_ah("__anyhit__accept").run(&root, &[first]);
    assert_eq!(out.of(0, Prog::Ah).len(), 1, "{:?}", out.seen);
    assert_eq!(out.of(0, Prog::Ch).len(), 1);
    // Without it, the closest of the nine is found: t = 6 (top instance 0, copy 10).
    let out = with_ah("__anyhit__accept").run(&root, std::slice::from_ref(&ray));
    let p = out.payloads[0];
    assert_eq!((f32::from_bits(p[0]), p[1]), (6.0, 10));
}

/// §13.14 / Z2 across instance levels: an exception thrown by an any-hit program two levels
/// down ends the launch index: no closest hit, the trace does not return, and no candidate
/// after the throwing one reaches the any-hit program. The program throws at its first
/// candidate whatever the instance: the order of candidates is the traversal's (unspecified,
/// §13.13), and one farther than an accepted hit may never be offered.
#[test]
fn z2_exception_in_any_hit_below_instances_ends_the_trace() {
    let root = stack_scene();
    let m = module()
        .closest_hit("__closesthit__rec", |ctx| {
            ctx.params().push(seen_ch(ctx));
            Ok(())
        })
        .unwrap()
        .any_hit("__anyhit__throw", |ctx| {
            ctx.params().push(seen_ah(ctx));
            ctx.throw_exception(42, &[ctx.instance_index()])
        })
        .unwrap();
    let h = Harness::new(
        &m,
        None,
        &[(
            HitProgs {
                ch: Some("__closesthit__rec"),
                ah: Some("__anyhit__throw"),
                is: None,
            },
            0,
        )],
        TraversableGraphFlags::empty(),
    );
    let out = h.run(&root, &[RaySpec::down(0.0, 0.0)]);
    assert_eq!(out.exception_codes(), vec![oxray::ExceptionCode(42)]);
    let ah = out.of(0, Prog::Ah);
    assert_eq!(ah.len(), 1, "{:?}", out.seen);
    // A mid-level copy (ids 10-12), two levels down; the details are its instance index.
    assert!((10..13).contains(&ah[0].instance_id), "{:?}", ah[0]);
    assert_eq!(
        out.report.first_exceptions[0].1.details(),
        &[ah[0].instance_index]
    );
    assert!(out.of(0, Prog::Ch).is_empty());
    assert_eq!(out.payloads[0], [UNSET; PAYLOAD]);
}

/// §7.3 / §12, G18: an instance offset sum past the hit-group records raises INVALID_HIT_SBT
/// (with the record index as detail), up to the 28-bit offset limit on two levels.
#[test]
fn g18_instance_offset_past_the_records_raises_invalid_hit_sbt() {
    let gas = tri_gas(&[tri_at(0.0, 0.0, 0.0, 0.5)]);
    let max = oxray::MAX_SBT_OFFSET;
    let h = recording_harness(3);
    for (parent, child, record) in [
        (0, 3, 3u64),
        (2, 1, 3),
        (max, 0, max as u64),
        (max, max, 2 * max as u64),
    ] {
        let mid = ias(&[Instance::new(gas.clone().into()).sbt_offset(child)]);
        let root = handle_of(&[Instance::new(mid.into()).sbt_offset(parent)]);
        let out = h.run(&root, &[RaySpec::down(0.0, 0.0)]);
        assert_eq!(
            out.exception_codes(),
            vec![oxray::ExceptionCode::INVALID_HIT_SBT],
            "offsets {parent} + {child}"
        );
        let detail = out.report.first_exceptions[0].1.details()[0];
        assert_eq!(
            detail as u64,
            record.min(u32::MAX as u64),
            "offsets {parent} + {child}"
        );
    }
    // Within range: 1 + 1 = record 2.
    let mid = ias(&[Instance::new(gas.clone().into()).sbt_offset(1)]);
    let root = handle_of(&[Instance::new(mid.into()).sbt_offset(1)]);
    let out = h.run(&root, &[RaySpec::down(0.0, 0.0)]);
    assert_eq!(out.report.exceptions, 0);
    assert_eq!(out.payloads[0][0], 2);
}

/// §13.7 / U.6 with the query API: an any-hit filter sees the instance fields of each
/// candidate, and ignoring the candidates of one instance reveals the next one along the ray.
#[test]
fn u6_query_filter_sees_instance_fields() {
    let root = stack_scene();
    let top = root.downcast_ref::<oxray::cpu::Ias>().unwrap();
    let ray = oxray::Ray::new(Vec3::new(0.0, 0.0, 10.0), -Vec3::Z);
    let hit = top.intersect(&ray).unwrap();
    assert_eq!((hit.t, hit.instance_id, hit.instance_index), (6.0, 10, 0));
    let mut seen = Vec::new();
    let hit = top
        .intersect_filtered(&ray, &mut oxray::NoCustomPrimitives, |h| {
            seen.push((h.instance_id, h.instance_index));
            if h.instance_index == 0 {
                oxray::CandidateAction::Ignore
            } else {
                oxray::CandidateAction::Accept
            }
        })
        .unwrap();
    assert_eq!((hit.t, hit.instance_id, hit.instance_index), (6.25, 11, 1));
    assert!(seen.iter().all(|&(id, index)| id == 10 + index), "{seen:?}");
    assert!(seen.contains(&(10, 0)));
    let hit = top
        .intersect_filtered(&ray, &mut oxray::NoCustomPrimitives, |h| {
            if h.instance_id == 12 {
                oxray::CandidateAction::Terminate
            } else {
                oxray::CandidateAction::Ignore
            }
        })
        .unwrap();
    assert_eq!((hit.instance_id, hit.instance_index), (12, 2));
}
