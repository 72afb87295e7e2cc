//! Updates (refits) of CPU structures, guide §5.6: after randomized deformations the hits of an
//! updated GAS or IAS equal the brute-force reference's, a deformed closed mesh stays
//! watertight, and every rule on updates is refused with the typed error that names it.

use glam::{Affine3A, Quat, Vec3};
use oxray_core::{
    Aabb, AabbBuffer, BuildError, BuildFlags, BuildInput, BuildOperation, BuildOptions, CustomHit,
    CustomPrimitive, CustomPrimitiveInput, IndexBuffer, Instance, Ray, Transform, TriangleInput,
    UpdateRule, VertexBuffer,
};
use oxray_cpu::{Gas, Ias};
use oxray_testkit::mesh::{grid_cube, icosphere, Mesh};
use oxray_testkit::oracle::{check_closest, reference_hits};
use oxray_testkit::rays::rays_around as rays;
use oxray_testkit::rng::Rng;
use std::sync::Arc;

fn input(m: &Mesh) -> BuildInput<'_> {
    TriangleInput::new(VertexBuffer::f32x3(&m.positions))
        .indices(IndexBuffer::u32x3(&m.triangles))
        .into()
}

fn update_options(flags: BuildFlags) -> BuildOptions {
    BuildOptions {
        flags,
        operation: BuildOperation::Update,
        ..Default::default()
    }
}

fn check_gas_against_reference(gas: &Gas, m: &Mesh, rays: &[Ray]) {
    let soup = m.soup();
    for ray in rays {
        if let Err(e) = check_closest(gas.intersect(ray), &soup, ray) {
            panic!("{e}");
        }
        assert_eq!(
            gas.occluded(ray),
            !reference_hits(&soup, ray).is_empty(),
            "occlusion of {ray:?}"
        );
    }
}

/// The shared deformation, and every third round a NaN vertex (its triangles inactive).
fn deform(rng: &mut Rng, base: &Mesh, m: &mut Mesh, round: u32) {
    oxray_testkit::mesh::deform(rng, base, m, round);
    if round % 3 == 2 {
        let k = rng.below(m.positions.len());
        m.positions[k] = [f32::NAN, 0.0, 0.0];
    }
}

#[test]
fn updated_triangle_gas_hits_equal_the_reference_after_random_deformations() {
    // §5.6: same topology, new vertices; the hits are the new geometry's.
    let mut rng = Rng::new(0x5_6);
    let base = grid_cube(12);
    let mut m = base.clone();
    // Some triangles are degenerate at the build: inactive, but they keep a slot.
    for t in m.triangles.iter().take(40).step_by(7) {
        m.positions[t[1] as usize] = m.positions[t[0] as usize];
    }
    let flags = BuildFlags::ALLOW_UPDATE;
    let mut gas = Gas::build(&BuildOptions::new(flags), &[input(&m)]).unwrap();
    assert!(gas.num_active_primitives() < m.triangles.len() as u32);
    check_gas_against_reference(&gas, &m, &rays(&mut rng, &m, 400));
    let built_sah = gas.stats().sah_cost;
    for round in 1..=6 {
        deform(&mut rng, &base, &mut m, round);
        gas.update(&update_options(flags), &[input(&m)]).unwrap();
        check_gas_against_reference(&gas, &m, &rays(&mut rng, &m, 400));
        // The structure reports the new geometry.
        let fresh = Gas::build(&BuildOptions::new(flags), &[input(&m)]).unwrap();
        assert_eq!(gas.num_active_primitives(), fresh.num_active_primitives());
        assert_eq!(gas.bounds(), fresh.bounds());
    }
    // The refit tree is valid but no better than the one it started from.
    assert!(gas.stats().sah_cost >= built_sah * 0.5);
}

#[test]
fn an_update_with_the_build_data_reproduces_the_built_structure() {
    let m = icosphere(3);
    let flags = BuildFlags::ALLOW_UPDATE | BuildFlags::PREFER_FAST_TRACE;
    let built = Gas::build(&BuildOptions::new(flags), &[input(&m)]).unwrap();
    let mut updated = built.clone();
    updated
        .update(&update_options(flags), &[input(&m)])
        .unwrap();
    assert_eq!(updated.bvh.nodes, built.bvh.nodes);
    assert_eq!(updated.triangles, built.triangles);
    assert_eq!(updated.bounds(), built.bounds());
}

#[test]
fn a_deformed_closed_mesh_stays_watertight_after_updates() {
    // §5.6 with the watertight test: rays from inside a closed, star-shaped deformation of a
    // sphere always hit it, including rays aimed exactly at vertices and edge midpoints.
    let mut rng = Rng::new(7);
    let base = icosphere(4);
    let mut m = base.clone();
    let flags = BuildFlags::ALLOW_UPDATE;
    let mut gas = Gas::build(&BuildOptions::new(flags), &[input(&m)]).unwrap();
    for round in 0..4 {
        let twist = 0.3 * round as f32;
        for (p, b) in m.positions.iter_mut().zip(&base.positions) {
            let b = Vec3::from(*b);
            let r = 1.0 + 0.25 * (3.0 * b.x + round as f32).sin() * (2.0 * b.y).cos();
            *p = (Quat::from_rotation_z(twist * b.z) * (b * r)).to_array();
        }
        gas.update(&update_options(flags), &[input(&m)]).unwrap();
        let origin = Vec3::new(0.01, -0.02, 0.015) * round as f32;
        let mut targets: Vec<Vec3> = m.positions.iter().map(|&p| Vec3::from(p)).collect();
        for t in m.triangles.iter().take(2000) {
            let [a, b, _] = t.map(|k| Vec3::from(m.positions[k as usize]));
            targets.push((a + b) * 0.5);
        }
        for _ in 0..2000 {
            targets.push(origin + rng.unit());
        }
        for target in targets {
            let ray = Ray::new(origin, target - origin);
            assert!(
                gas.intersect(&ray).is_some(),
                "round {round}: the ray towards {target} escaped the closed mesh"
            );
        }
    }
}

/// The custom primitive of a box: the sphere inscribed well inside it, so that the box test
/// before the intersection never decides a hit.
fn sphere_in(b: &Aabb, ray: &Ray) -> Option<f32> {
    let c = (b.min + b.max) * 0.5;
    let r = 0.4 * (b.max - b.min).min_element();
    let oc = ray.origin - c;
    let a = ray.direction.length_squared();
    let hb = oc.dot(ray.direction);
    let disc = hb * hb - a * (oc.length_squared() - r * r);
    if disc.is_nan() || disc < 0.0 {
        return None;
    }
    let t = (-hb - disc.sqrt()) / a;
    (t >= ray.tmin && t <= ray.tmax).then_some(t)
}

#[test]
fn updated_custom_primitive_gas_hits_equal_the_reference() {
    let mut rng = Rng::new(11);
    let mut boxes: Vec<Aabb> = (0..500)
        .map(|_| {
            let c = rng.vec3(0.0, 10.0);
            Aabb::new(c - Vec3::splat(0.3), c + Vec3::splat(0.3))
        })
        .collect();
    boxes[3] = Aabb::EMPTY; // inactive at the build
    let flags = BuildFlags::ALLOW_UPDATE;
    let mut gas = Gas::build(
        &BuildOptions::new(flags),
        &[CustomPrimitiveInput::new(AabbBuffer::new(&boxes)).into()],
    )
    .unwrap();
    for round in 0..5 {
        for (i, b) in boxes.iter_mut().enumerate() {
            let c = if i == 3 && round > 0 {
                Vec3::splat(5.0)
            } else {
                (b.min + b.max) * 0.5 + rng.vec3(-1.0, 1.0) * round as f32
            };
            let h = Vec3::splat(rng.range(0.1, 0.6));
            *b = Aabb::new(c - h, c + h);
        }
        boxes[7] = Aabb::new(Vec3::ONE, Vec3::ZERO); // inverted: inactive now
        gas.update(
            &update_options(flags),
            &[CustomPrimitiveInput::new(AabbBuffer::new(&boxes)).into()],
        )
        .unwrap();
        for _ in 0..300 {
            let o = rng.vec3(-5.0, 15.0);
            let ray = Ray::new(o, rng.vec3(0.0, 10.0) - o);
            let mut isect = |p: &CustomPrimitive, ray: &Ray| {
                sphere_in(&p.aabb, ray).map(|t| CustomHit {
                    t,
                    hit_kind: 0,
                    u: 0.0,
                    v: 0.0,
                })
            };
            let got = gas.intersect_with(&ray, &mut isect).map(|h| h.t);
            let want = boxes
                .iter()
                .filter(|b| b.is_finite_valid())
                .filter_map(|b| sphere_in(b, &ray))
                .min_by(f32::total_cmp);
            assert_eq!(got, want, "round {round}, ray {ray:?}");
        }
    }
}

#[test]
fn updated_ias_follows_new_transforms_and_updated_children() {
    // §5.6 for an IAS: new transforms over the same children; a child GAS updated by
    // copy-on-write is accepted as the same child, and its new bounds are taken.
    let mut rng = Rng::new(23);
    let base = icosphere(2);
    let mut m = base.clone();
    let flags = BuildFlags::ALLOW_UPDATE;
    let mut gas = Arc::new(Gas::build(&BuildOptions::new(flags), &[input(&m)]).unwrap());
    let mut placements: Vec<Affine3A> = (0..20).map(|_| rng.affine(10.0)).collect();
    let instances = |gas: &Arc<Gas>, placements: &[Affine3A]| -> Vec<Instance> {
        placements
            .iter()
            .enumerate()
            .map(|(i, a)| {
                Instance::new(gas.clone().into())
                    .transform(Transform::from_affine(a))
                    .instance_id(i as u32)
            })
            .collect()
    };
    let list = instances(&gas, &placements);
    let mut ias = Ias::build(&BuildOptions::new(flags), &[(&list[..]).into()]).unwrap();
    let cpu = oxray_cpu::Cpu::new();
    for round in 0..4 {
        for p in m.positions.iter_mut() {
            *p = (Vec3::from(*p) * (1.0 + 0.1 * round as f32) + rng.vec3(-0.05, 0.05)).to_array();
        }
        oxray_core::AccelBackend::update_gas(&cpu, &mut gas, &update_options(flags), &[input(&m)])
            .unwrap();
        for a in placements.iter_mut() {
            *a = Affine3A::from_translation(rng.vec3(-2.0, 2.0)) * *a;
        }
        let list = instances(&gas, &placements);
        ias.update(&update_options(flags), &[(&list[..]).into()])
            .unwrap();
        // The world's triangles, for the reference.
        let world: Vec<[[f32; 3]; 3]> = placements
            .iter()
            .flat_map(|a| {
                m.soup()
                    .into_iter()
                    .map(move |t| t.map(|p| a.transform_point3(Vec3::from(p)).to_array()))
            })
            .collect();
        let rebuilt = Ias::build(&BuildOptions::new(flags), &[(&list[..]).into()]).unwrap();
        for _ in 0..300 {
            let o = rng.vec3(-25.0, 25.0);
            let ray = Ray::new(o, rng.vec3(-10.0, 10.0) - o);
            let got = ias.intersect(&ray);
            let want = rebuilt.intersect(&ray);
            assert_eq!(got.map(|h| h.t.to_bits()), want.map(|h| h.t.to_bits()));
            assert_eq!(ias.occluded(&ray), rebuilt.occluded(&ray));
            // Near the reference (the instance transform is applied to the ray, not the mesh).
            let reference = reference_hits(&world, &ray)
                .iter()
                .map(|h| h.hit.t)
                .min_by(f32::total_cmp);
            match (got, reference) {
                (Some(g), Some(r)) => assert!((g.t - r).abs() <= 1e-3 * r.max(1.0)),
                (None, None) => {}
                (g, r) => {
                    // A graze within rounding of an edge may differ; nothing else.
                    let t = g.map(|h| h.t).or(r).unwrap();
                    assert!(t.is_finite(), "got {g:?}, reference {r:?}");
                }
            }
        }
    }
}

fn assert_rule(r: Result<(), BuildError>, want: UpdateRule) {
    assert_eq!(r, Err(BuildError::InvalidUpdate(want)));
}

#[test]
fn update_rules_of_guide_5_6_are_refused_with_typed_errors() {
    let m = icosphere(1);
    let flags = BuildFlags::ALLOW_UPDATE;
    let up = update_options(flags);
    let mut gas = Gas::build(&BuildOptions::new(flags), &[input(&m)]).unwrap();
    // A build call with operation Update has no structure (§5.6, Listing 5.9).
    assert_eq!(
        Gas::build(&up, &[input(&m)]).err(),
        Some(BuildError::InvalidUpdate(UpdateRule::NoStructure))
    );
    // Operation Build in an update.
    assert_rule(
        gas.update(&BuildOptions::new(flags), &[input(&m)]),
        UpdateRule::NotAnUpdate,
    );
    // Built without ALLOW_UPDATE.
    let mut fixed = Gas::build(&BuildOptions::default(), &[input(&m)]).unwrap();
    assert_rule(
        fixed.update(&update_options(BuildFlags::empty()), &[input(&m)]),
        UpdateRule::NotAllowed,
    );
    // Other flags.
    let other = flags | BuildFlags::PREFER_FAST_BUILD;
    assert_rule(
        gas.update(&update_options(other), &[input(&m)]),
        UpdateRule::Flags {
            built: flags,
            given: other,
        },
    );
    // Another number of inputs.
    assert_rule(
        gas.update(&up, &[input(&m), input(&m)]),
        UpdateRule::InputCount { built: 1, given: 2 },
    );
    // Another input type.
    let boxes = [Aabb::new(Vec3::ZERO, Vec3::ONE)];
    assert!(matches!(
        gas.update(
            &up,
            &[CustomPrimitiveInput::new(AabbBuffer::new(&boxes)).into()]
        ),
        Err(BuildError::InvalidUpdate(UpdateRule::InputKind {
            input: 0,
            ..
        }))
    ));
    // Another vertex count, index count.
    let fewer = &m.positions[..m.positions.len() - 1];
    let tri = &m.triangles[..];
    let r = gas.update(
        &up,
        &[TriangleInput::new(VertexBuffer::f32x3(fewer))
            .indices(IndexBuffer::u32x3(tri))
            .into()],
    );
    assert!(
        matches!(
            r,
            Err(BuildError::InvalidUpdate(UpdateRule::Count {
                what: "vertices",
                ..
            }))
        ) || matches!(r, Err(BuildError::IndexOutOfRange { .. })),
        "{r:?}"
    );
    let r = gas.update(
        &up,
        &[TriangleInput::new(VertexBuffer::f32x3(&m.positions))
            .indices(IndexBuffer::u32x3(&tri[1..]))
            .into()],
    );
    assert!(matches!(
        r,
        Err(BuildError::InvalidUpdate(UpdateRule::Count {
            what: "index triplets",
            ..
        }))
    ));
    // Another index format.
    let t16: Vec<[u16; 3]> = tri.iter().map(|t| t.map(|i| i as u16)).collect();
    let r = gas.update(
        &up,
        &[TriangleInput::new(VertexBuffer::f32x3(&m.positions))
            .indices(IndexBuffer::u16x3(&t16))
            .into()],
    );
    assert_rule(
        r,
        UpdateRule::Description {
            input: 0,
            what: "the index format",
        },
    );
    // A pre-transform that was not there, another primitive index offset, other flags.
    let id = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0];
    let with = |f: &dyn Fn(TriangleInput<'_>) -> TriangleInput<'_>| {
        gas.clone().update(
            &up,
            &[f(TriangleInput::new(VertexBuffer::f32x3(&m.positions))
                .indices(IndexBuffer::u32x3(tri)))
            .into()],
        )
    };
    assert_rule(
        with(&|t| t.pre_transform(id)),
        UpdateRule::Description {
            input: 0,
            what: "the presence of a pre-transform",
        },
    );
    assert_rule(
        with(&|t| t.primitive_index_offset(5)),
        UpdateRule::Description {
            input: 0,
            what: "the primitive index offset",
        },
    );
    static GF: [oxray_core::GeometryFlags; 1] = [oxray_core::GeometryFlags::DISABLE_ANYHIT];
    assert_rule(
        with(&|t| t.flags(&GF)),
        UpdateRule::Description {
            input: 0,
            what: "the geometry flags of its SBT records",
        },
    );
    // A refused update changed nothing.
    let before = gas.bvh.nodes.clone();
    let _ = gas.update(&up, &[input(&m), input(&m)]);
    assert_eq!(gas.bvh.nodes, before);

    // An IAS: another child, another count.
    let g = Arc::new(gas);
    let other = Arc::new(Gas::build(&BuildOptions::new(flags), &[input(&m)]).unwrap());
    let list = [
        Instance::new(g.clone().into()),
        Instance::new(g.clone().into()),
    ];
    let mut ias = Ias::build(&BuildOptions::new(flags), &[(&list[..]).into()]).unwrap();
    let swapped = [Instance::new(g.clone().into()), Instance::new(other.into())];
    assert_rule(
        ias.update(&up, &[(&swapped[..]).into()]),
        UpdateRule::InstanceChild { instance: 1 },
    );
    assert_rule(
        ias.update(&up, &[(&list[..1]).into()]),
        UpdateRule::Count {
            input: 0,
            what: "instances",
            built: 2,
            given: 1,
        },
    );
    let ptrs: Vec<&Instance> = list.iter().collect();
    assert!(matches!(
        ias.update(&up, &[BuildInput::InstancePointers(&ptrs)]),
        Err(BuildError::InvalidUpdate(UpdateRule::InputKind { .. }))
    ));
    assert_eq!(
        ias.update(&up, &[(&list[..]).into()]),
        Ok(()),
        "the same instances update"
    );
}
