//! Instance acceleration structure builds (guide §5, §5.4, §5.9, §12; inventory J, O, Z0,
//! Z7 G42): validation of instances, inputs and graph depth; the instance-pointers input;
//! children that are never hit; ownership of children; random instance access (§13.12, K).

mod instancing_common;

use instancing_common::*;
use oxray::cpu::{Gas, Ias};
use oxray::{
    Aabb, AabbBuffer, BuildError, BuildFlags, BuildInput, BuildInputKind, BuildOperation,
    BuildOptions, CustomPrimitiveInput, ErrorCode, Instance, InstanceFlags, Ray, StaticTransform,
    Transform, TraversableGraphFlags, TraversableHandle, TraversableKind, TriangleInput,
    VertexBuffer,
};
use oxray::{MAX_INSTANCE_ID, MAX_SBT_OFFSET, MAX_TRAVERSABLE_GRAPH_DEPTH};
use std::sync::Arc;

fn build(instances: &[Instance]) -> Result<Ias, BuildError> {
    Ias::build(&BuildOptions::default(), &[instances.into()])
}

fn unit_tri() -> Arc<Gas> {
    tri_gas(&[tri_at(0.0, 0.0, 0.0, 0.5)])
}

/// Four valid instances of `gas`, with instance 2 changed by `f`.
fn with_bad_third(gas: &Arc<Gas>, f: impl Fn(Instance) -> Instance) -> Vec<Instance> {
    (0..4)
        .map(|k| {
            let i = Instance::new(gas.clone().into()).instance_id(k);
            if k == 2 {
                f(i)
            } else {
                i
            }
        })
        .collect()
}

fn down() -> Ray {
    Ray::new(Vec3::new(0.0, 0.0, 5.0), -Vec3::Z)
}

// ---------------------------------------------------------------------------------------------
// Validation
// ---------------------------------------------------------------------------------------------

/// §5.4 / §12, J, Z0: instance id and SBT offset have 28 bits and the visibility mask 8; a value
/// with a higher bit set is refused with the instance and field named; the largest values are
/// accepted.
#[test]
fn z0_instance_fields_above_their_bit_limits_are_refused() {
    let gas = unit_tri();
    type Set = fn(Instance, u32) -> Instance;
    let fields: [(&str, Set, u32, u32); 3] = [
        ("instance_id", |i, v| i.instance_id(v), 28, MAX_INSTANCE_ID),
        ("sbt_offset", |i, v| i.sbt_offset(v), 28, MAX_SBT_OFFSET),
        ("visibility_mask", |i, v| i.visibility_mask(v), 8, 0xFF),
    ];
    assert_eq!(MAX_INSTANCE_ID, (1 << 28) - 1);
    assert_eq!(MAX_SBT_OFFSET, (1 << 28) - 1);
    for (field, set, bits, max) in fields {
        let ok = build(&with_bad_third(&gas, |i| set(i, max)));
        assert!(ok.is_ok(), "{field} = {max:#x} refused: {ok:?}");
        for value in [max + 1, 1 << 31, u32::MAX, (max + 1) | 1] {
            let err = build(&with_bad_third(&gas, |i| set(i, value))).unwrap_err();
            assert_eq!(
                err,
                BuildError::InstanceFieldOutOfRange {
                    instance: 2,
                    field,
                    value,
                    bits
                },
                "{field} = {value:#x}"
            );
            assert_eq!(err.code(), ErrorCode::InvalidInput);
        }
    }
}

/// §5.4, J: DISABLE_ANYHIT and ENFORCE_ANYHIT exclude each other on one instance.
#[test]
fn j_conflicting_anyhit_instance_flags_are_refused() {
    let gas = unit_tri();
    let both = InstanceFlags::DISABLE_ANYHIT | InstanceFlags::ENFORCE_ANYHIT;
    let err = build(&with_bad_third(&gas, |i| i.flags(both))).unwrap_err();
    assert_eq!(err, BuildError::ConflictingInstanceFlags { instance: 2 });
    let err = build(&with_bad_third(&gas, |i| {
        i.flags(both | InstanceFlags::FLIP_TRIANGLE_FACING)
    }))
    .unwrap_err();
    assert_eq!(err, BuildError::ConflictingInstanceFlags { instance: 2 });
    // Each alone, and with every other flag, is fine.
    for one in [InstanceFlags::DISABLE_ANYHIT, InstanceFlags::ENFORCE_ANYHIT] {
        let others = InstanceFlags::all() - both;
        assert!(build(&with_bad_third(&gas, |i| i.flags(one | others))).is_ok());
    }
}

/// §5.4, J: a singular or non-finite instance transform is refused (its inverse is needed to
/// carry rays into the instance); so is one for a static transform.
#[test]
fn j_singular_or_non_finite_transforms_are_refused() {
    let gas = unit_tri();
    let id = Transform::IDENTITY.0;
    let with = |k: usize, v: f32| {
        let mut m = id;
        m[k] = v;
        Transform(m)
    };
    let bad = [
        ("zero", Transform([0.0; 12])),
        ("zero scale in y", with(5, 0.0)),
        (
            "two equal rows",
            Transform([1.0, 2.0, 3.0, 0.0, 1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0, 0.0]),
        ),
        ("NaN in the matrix", with(0, f32::NAN)),
        ("NaN in the translation", with(3, f32::NAN)),
        ("infinite translation", with(7, f32::INFINITY)),
        ("infinite matrix element", with(1, f32::NEG_INFINITY)),
    ];
    for (name, t) in bad {
        let err = build(&with_bad_third(&gas, |i| i.transform(t))).unwrap_err();
        assert_eq!(
            err,
            BuildError::InvalidTransform { instance: Some(2) },
            "{name}"
        );
        let err = StaticTransform::new(gas.clone().into(), t).unwrap_err();
        assert_eq!(
            err,
            BuildError::InvalidTransform { instance: None },
            "static, {name}"
        );
    }
    // Small but regular transforms are fine.
    let tiny = Transform::from_affine(&Affine3A::from_scale(Vec3::splat(1e-3)));
    assert!(build(&with_bad_third(&gas, |i| i.transform(tiny))).is_ok());
    assert!(StaticTransform::new(gas.into(), tiny).is_ok());
}

/// §5.4 / G42: an IAS takes exactly one build input, which must hold instances; a GAS takes no
/// instance input; the build-flag and operation rules of §5.5 / §5.6 apply to IASes too.
#[test]
fn g42_ias_build_input_rules() {
    let gas = unit_tri();
    let inst = [Instance::new(gas.clone().into())];
    let inst2 = [Instance::new(gas.clone().into())];
    let opts = BuildOptions::default();
    assert_eq!(
        Ias::build(&opts, &[]).unwrap_err(),
        BuildError::IasInputCount { count: 0 }
    );
    assert_eq!(
        Ias::build(&opts, &[(&inst[..]).into(), (&inst2[..]).into()]).unwrap_err(),
        BuildError::IasInputCount { count: 2 }
    );
    let v = soup(&[tri_at(0.0, 0.0, 0.0, 0.5)]);
    let tri: BuildInput = TriangleInput::new(VertexBuffer::f32x3(&v)).into();
    assert_eq!(
        Ias::build(&opts, &[tri]).unwrap_err(),
        BuildError::NotInstances {
            found: BuildInputKind::Triangles
        }
    );
    let boxes = [Aabb::new(Vec3::ZERO, Vec3::ONE)];
    let custom: BuildInput = CustomPrimitiveInput::new(AabbBuffer::new(&boxes)).into();
    assert_eq!(
        Ias::build(&opts, &[custom]).unwrap_err(),
        BuildError::NotInstances {
            found: BuildInputKind::CustomPrimitives
        }
    );
    let ptrs: Vec<&Instance> = inst.iter().collect();
    for (k, inputs) in [
        vec![(&inst[..]).into()],
        vec![tri, (&inst[..]).into()],
        vec![tri, (&ptrs[..]).into()],
    ]
    .into_iter()
    .enumerate()
    {
        let index = if k == 0 { 0 } else { 1 };
        assert_eq!(
            Gas::build(&opts, &inputs).unwrap_err(),
            BuildError::InstancesInGas { index },
            "GAS inputs {k}"
        );
    }
    let both = BuildOptions::new(BuildFlags::PREFER_FAST_TRACE | BuildFlags::PREFER_FAST_BUILD);
    assert_eq!(
        Ias::build(&both, &[(&inst[..]).into()]).unwrap_err(),
        BuildError::ConflictingBuildFlags
    );
    let update = BuildOptions {
        operation: BuildOperation::Update,
        ..Default::default()
    };
    assert!(matches!(
        Ias::build(&update, &[(&inst[..]).into()]),
        Err(BuildError::InvalidUpdate(oxray::UpdateRule::NoStructure))
    ));
}

/// §12 / O, Z0: a traversable graph is at most 31 levels deep, every IAS, GAS and static
/// transform counting one. A chain of 30 IASes over a GAS (31 levels) builds and is hit through
/// every level; one more level is refused, for an IAS and for a static transform.
#[test]
fn z0_graph_deeper_than_31_levels_is_refused() {
    assert_eq!(MAX_TRAVERSABLE_GRAPH_DEPTH, 31);
    let gas = unit_tri();
    let mut h: TraversableHandle = gas.clone().into();
    assert_eq!(h.graph_depth(), 1);
    for level in 1..=30u32 {
        let ias = build(&[Instance::new(h.clone())
            .instance_id(level)
            .transform(Transform::from_translation(Vec3::new(0.01, 0.0, 0.0)))])
        .unwrap_or_else(|e| panic!("level {level}: {e}"));
        assert_eq!(ias.graph_depth(), level + 1);
        h = ias.into();
    }
    assert_eq!(h.graph_depth(), 31);
    let deepest = h.clone();
    // The whole chain is traversed: 30 translations of 0.01 in x.
    let top = deepest.downcast_ref::<oxray::cpu::Ias>().unwrap();
    let hit = top
        .intersect(&Ray::new(Vec3::new(0.3 + 0.2, 0.0, 5.0), -Vec3::Z))
        .expect("a hit through 30 levels");
    assert_eq!((hit.instance_id, hit.instance_index, hit.t), (1, 0, 5.0));
    // At x = -0.2 the untranslated triangle would be hit; the translated one is not.
    assert!(top
        .intersect(&Ray::new(Vec3::new(-0.2, 0.0, 5.0), -Vec3::Z))
        .is_none());
    // One level more.
    let too_deep = BuildError::GraphTooDeep {
        depth: 32,
        limit: 31,
    };
    assert_eq!(
        build(&[Instance::new(deepest.clone())]).unwrap_err(),
        too_deep
    );
    assert_eq!(
        StaticTransform::new(deepest.clone(), Transform::IDENTITY).unwrap_err(),
        too_deep
    );
    // Also when only one instance of many is too deep.
    let shallow = Instance::new(gas.clone().into());
    assert_eq!(
        build(&[shallow.clone(), Instance::new(deepest), shallow]).unwrap_err(),
        too_deep
    );
    // Static transforms count as levels too: 30 over a GAS make 31.
    let mut s: TraversableHandle = gas.into();
    for _ in 0..30 {
        s = StaticTransform::new(s, Transform::IDENTITY).unwrap().into();
    }
    assert_eq!(s.graph_depth(), 31);
    assert_eq!(s.kind(), Some(TraversableKind::StaticTransform));
    assert_eq!(
        StaticTransform::new(s.clone(), Transform::IDENTITY).unwrap_err(),
        too_deep
    );
    assert_eq!(build(&[Instance::new(s)]).unwrap_err(), too_deep);
}

/// §12 / §13.11, O, Z1.8: the deepest allowed graph (30 IASes over a GAS) is traced by the
/// pipeline: the hit reports the innermost instance and a transform list of 30 levels.
#[test]
fn z0_pipeline_traces_a_31_level_graph() {
    let mut h: TraversableHandle = unit_tri().into();
    for level in 1..=30u32 {
        h = build(&[Instance::new(h).instance_id(level).sbt_offset(level % 2)])
            .unwrap()
            .into();
    }
    let m = module()
        .closest_hit("__closesthit__log", |ctx| {
            ctx.params().push(seen_ch(ctx));
            Ok(())
        })
        .unwrap();
    let ch = HitProgs {
        ch: Some("__closesthit__log"),
        ..Default::default()
    };
    // Offsets 1 on the 15 odd levels sum to 15.
    let records: Vec<(HitProgs, u32)> = (0..16).map(|k| (ch, k)).collect();
    let harness = Harness::new(&m, None, &records, TraversableGraphFlags::empty());
    let out = harness.run(&h, &[RaySpec::down(0.0, 0.0)]);
    assert_eq!(out.report.exceptions, 0, "{:?}", out.report);
    let seen = out.of(0, Prog::Ch);
    assert_eq!(seen.len(), 1);
    assert_eq!((seen[0].instance_id, seen[0].instance_index), (1, 0));
    assert_eq!(seen[0].levels, Some(30));
    assert_eq!(seen[0].data, 15, "SBT offsets summed over 30 levels");
}

// ---------------------------------------------------------------------------------------------
// Inputs and children
// ---------------------------------------------------------------------------------------------

/// §5.4, J: an instance-pointers input builds the same structure as the array of the same
/// instances (same nodes, bounds and hits).
#[test]
fn j_instance_pointers_build_the_same_structure() {
    let mut rng = Rng::new(0x9e7);
    let gases: Vec<Arc<Gas>> = (0..3)
        .map(|_| tri_gas(&random_soup(&mut rng, 20, 1.0, 0.5)))
        .collect();
    let instances: Vec<Instance> = (0..200u32)
        .map(|i| {
            Instance::new(gases[i as usize % 3].clone().into())
                .transform(Transform::from_affine(&rng.affine(20.0)))
                .instance_id(i * 3)
                .sbt_offset(i % 5)
        })
        .collect();
    let ptrs: Vec<&Instance> = instances.iter().collect();
    let opts = BuildOptions::default();
    let a = Ias::build(&opts, &[(&instances[..]).into()]).unwrap();
    let b = Ias::build(&opts, &[BuildInput::InstancePointers(&ptrs)]).unwrap();
    let c = Ias::build(&opts, &[(&ptrs[..]).into()]).unwrap();
    for other in [&b, &c] {
        assert_eq!(
            bytemuck::cast_slice::<_, u8>(&a.bvh().nodes),
            bytemuck::cast_slice::<_, u8>(&other.bvh().nodes)
        );
        assert_eq!(a.bounds(), other.bounds());
        assert_eq!(a.num_instances(), other.num_instances());
        assert_eq!(a.graph_depth(), other.graph_depth());
    }
    let rays: Vec<Ray> = (0..3000)
        .map(|_| Ray::new(rng.vec3(-25.0, 25.0), rng.unit()))
        .collect();
    let mut hits = 0;
    for r in &rays {
        let h = a.intersect(r);
        hits += h.is_some() as usize;
        assert_eq!(hit_bits(&h), hit_bits(&b.intersect(r)));
        assert_eq!(a.occluded(r), b.occluded(r));
    }
    assert!(hits > 100, "only {hits} hits");
    // Pointers may repeat an instance: both copies are in the structure.
    let twice = [&instances[0], &instances[0]];
    let d = Ias::build(&opts, &[(&twice[..]).into()]).unwrap();
    assert_eq!(d.num_instances(), 2);
}

/// An empty GAS: a triangle input without triangles.
fn empty_gas() -> Arc<Gas> {
    let v: [[f32; 3]; 0] = [];
    Arc::new(
        Gas::build(
            &BuildOptions::default(),
            &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()],
        )
        .expect("an empty GAS builds"),
    )
}

/// §5.4 / §5.9, O, G1: instances of the null handle, of an empty GAS, of an empty IAS or of a
/// GAS whose triangles are all degenerate are never hit, by queries or by the pipeline; the
/// instances after them keep their input index.
#[test]
fn o_null_and_empty_children_are_never_hit() {
    let empty = empty_gas();
    assert_eq!(empty.num_primitives(), 0);
    let degenerate = tri_gas(&[[[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]]);
    let no_instances = build(&[]).expect("an IAS of no instances builds");
    assert_eq!(no_instances.num_instances(), 0);
    assert!(no_instances.intersect(&down()).is_none());
    let never: Vec<TraversableHandle> = vec![
        TraversableHandle::NULL,
        empty.clone().into(),
        no_instances.into(),
        degenerate.into(),
        StaticTransform::new(TraversableHandle::NULL, Transform::IDENTITY)
            .unwrap()
            .into(),
    ];
    // Only the never-hit children.
    let only: Vec<Instance> = never.iter().map(|h| Instance::new(h.clone())).collect();
    let s = build(&only).unwrap();
    assert_eq!(s.num_instances(), never.len() as u32);
    for r in [down(), Ray::new(Vec3::new(0.5, 0.0, 5.0), -Vec3::Z)] {
        assert!(s.intersect(&r).is_none());
        assert!(!s.occluded(&r));
    }
    // ...followed by a real one at the same place.
    let mut all = only.clone();
    all.push(Instance::new(unit_tri().into()).instance_id(77));
    let s: TraversableHandle = build(&all).unwrap().into();
    let hit = s
        .downcast_ref::<oxray::cpu::Ias>()
        .unwrap()
        .intersect(&down())
        .expect("the real instance");
    assert_eq!(
        (hit.instance_id, hit.instance_index),
        (77, never.len() as u32)
    );
    // In the pipeline: any hit and closest hit only for the real one.
    let m = module()
        .closest_hit("__closesthit__log", |ctx| {
            ctx.params().push(seen_ch(ctx));
            Ok(())
        })
        .unwrap()
        .any_hit("__anyhit__log", |ctx| {
            ctx.params().push(seen_ah(ctx));
            Ok(())
        })
        .unwrap();
    let progs = HitProgs {
        ch: Some("__closesthit__log"),
        ah: Some("__anyhit__log"),
        is: None,
    };
    let h = Harness::new(&m, None, &[(progs, 0)], TraversableGraphFlags::empty());
    let only: TraversableHandle = build(&only).unwrap().into();
    let out = h.run(&only, &[RaySpec::down(0.0, 0.0)]);
    assert_eq!(out.report.exceptions, 0);
    assert!(out.seen.is_empty(), "{:?}", out.seen);
    let out = h.run(&s, &[RaySpec::down(0.0, 0.0)]);
    assert_eq!(out.seen.len(), 2, "{:?}", out.seen);
    assert!(out
        .seen
        .iter()
        .all(|x| x.instance_index == never.len() as u32));
    // Tracing the null handle itself runs only the miss program (G1).
    let out = h.run(&TraversableHandle::NULL, &[RaySpec::down(0.0, 0.0)]);
    assert!(out.seen.is_empty());
    assert_eq!(out.report.exceptions, 0);
}

// ---------------------------------------------------------------------------------------------
// Ownership and random instance access
// ---------------------------------------------------------------------------------------------

/// §5.9, O: an IAS keeps its children alive: dropping the caller's `Arc<Gas>` (and the instance
/// array) after the build leaves it working; the GAS is freed with the last IAS referring to it.
#[test]
fn o_ias_keeps_its_children_alive() {
    let gas = unit_tri();
    let weak = Arc::downgrade(&gas);
    let instances = vec![Instance::new(gas.clone().into()).instance_id(5)];
    let ias = Arc::new(build(&instances).unwrap());
    drop(instances);
    drop(gas);
    assert!(weak.upgrade().is_some(), "the IAS lost its GAS");
    let hit = ias.intersect(&down()).expect("still hit");
    assert_eq!(hit.instance_id, 5);
    // Two levels: the top IAS keeps the mid IAS, which keeps the GAS.
    let mid_weak = Arc::downgrade(&ias);
    let top =
        build(&[Instance::new(ias.clone().into()).transform(Transform::from_translation(Vec3::Y))])
            .unwrap();
    drop(ias);
    assert!(mid_weak.upgrade().is_some() && weak.upgrade().is_some());
    let hit = top
        .intersect(&Ray::new(Vec3::new(0.0, 1.0, 5.0), -Vec3::Z))
        .expect("still hit through two levels");
    assert_eq!((hit.instance_id, hit.t), (5, 5.0));
    // Through a static transform as well.
    let st: TraversableHandle = StaticTransform::new(top.into(), Transform::IDENTITY)
        .unwrap()
        .into();
    let outer = build(&[Instance::new(st.clone())]).unwrap();
    drop(st);
    assert!(outer
        .intersect(&Ray::new(Vec3::new(0.0, 1.0, 5.0), -Vec3::Z))
        .is_some());
    drop(outer);
    assert!(
        mid_weak.upgrade().is_none(),
        "the mid IAS outlived every referrer"
    );
    assert!(weak.upgrade().is_none(), "the GAS outlived every referrer");
}

/// §13.12 / K: `instance_child(i)` (`optixGetInstanceTraversableFromIAS`) returns instance i's
/// child, by input index, only for an IAS built with ALLOW_RANDOM_INSTANCE_ACCESS; `None` past
/// the end and for a null child.
#[test]
fn k_instance_child_needs_allow_random_instance_access() {
    let mut rng = Rng::new(3);
    let gases: Vec<TraversableHandle> = (0..3).map(|_| unit_tri().into()).collect();
    let mut instances: Vec<Instance> = (0..40)
        .map(|k| {
            Instance::new(gases[k % 3].clone()).transform(Transform::from_affine(&rng.affine(30.0)))
        })
        .collect();
    instances[7] = Instance::new(TraversableHandle::NULL);
    let with = Ias::build(
        &BuildOptions::new(BuildFlags::ALLOW_RANDOM_INSTANCE_ACCESS),
        &[(&instances[..]).into()],
    )
    .unwrap();
    let without = build(&instances).unwrap();
    for (k, inst) in instances.iter().enumerate() {
        let k32 = k as u32;
        assert!(
            without.instance_child(k32).is_none(),
            "without the flag, instance {k}"
        );
        if k == 7 {
            assert!(with.instance_child(k32).is_none(), "null child");
            continue;
        }
        let child = with.instance_child(k32).expect("child with the flag");
        assert!(child.same_as(&inst.child), "instance {k}: another child");
        assert!(child.same_as(&gases[k % 3]));
    }
    assert!(with.instance_child(40).is_none());
    assert!(with.instance_child(u32::MAX).is_none());
}
