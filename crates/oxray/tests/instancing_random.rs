//! Randomized instancing tests (guide §5.4 instance build inputs, §2.5 / §5.9 traversables,
//! §13.7 instance queries; inventory J, O, U.6, Z7 G21):
//!
//! * an IAS over several GASes with random affine transforms answers closest-hit and occlusion
//!   queries like the same geometry flattened into one GAS (one build input per instance);
//! * determinism (§3.2): the IAS built on 1 and 4 threads is identical node for node, and so
//!   are batch results.

mod instancing_common;

use instancing_common::*;
use oxray::cpu::{Gas, Ias};
use oxray::{BuildOptions, Hit, Instance, Ray, Transform};
use proptest::prelude::any;
use proptest::test_runner::{TestCaseError, TestRunner};
use std::sync::Arc;

/// A random instanced scene and its flattened counterpart.
struct Scene {
    leaves: Vec<Leaf>,
    ias: Ias,
    flat: Gas,
}

/// `num_gas` random soups instanced `num_inst` times with random affine transforms and distinct
/// random ids; about one instance in five repeats the previous one's placement (an exact tie
/// between two instances).
fn scene(rng: &mut Rng, num_gas: usize, num_inst: usize) -> Scene {
    let soups: Vec<Vec<Tri>> = (0..num_gas)
        .map(|_| {
            let n = 8 + rng.below(33);
            random_soup(rng, n, 1.0, 0.6)
        })
        .collect();
    let gases: Vec<Arc<Gas>> = soups.iter().map(|s| tri_gas(s)).collect();
    let mut gas_of: Vec<usize> = Vec::new();
    let mut transforms: Vec<Transform> = Vec::new();
    for i in 0..num_inst {
        if i > 0 && rng.below(5) == 0 {
            gas_of.push(gas_of[i - 1]);
            transforms.push(transforms[i - 1]);
        } else {
            gas_of.push(rng.below(num_gas));
            transforms.push(Transform::from_affine(&rng.affine(4.0)));
        }
    }
    // Distinct ids below 2^28.
    let ids: Vec<u32> = (0..num_inst)
        .map(|i| (rng.below(1 << 20) as u32) << 8 | i as u32)
        .collect();
    let instances: Vec<Instance> = (0..num_inst)
        .map(|i| {
            Instance::new(gases[gas_of[i]].clone().into())
                .transform(transforms[i])
                .instance_id(ids[i])
        })
        .collect();
    let ias = Ias::build(&BuildOptions::default(), &[(&instances[..]).into()]).expect("IAS");
    let leaves: Vec<Leaf> = (0..num_inst)
        .map(|i| Leaf {
            world: transform_tris(&transforms[i], &soups[gas_of[i]]),
            instance_id: ids[i],
            instance_index: i as u32,
        })
        .collect();
    let flat = flattened_gas(&leaves.iter().map(|l| l.world.clone()).collect::<Vec<_>>());
    Scene { leaves, ias, flat }
}

/// §5.4 / J, U.6, G21: random instanced scenes (rotation, non-uniform scale, translation)
/// against the same geometry flattened into one GAS with one build input per instance: closest
/// t within 1e-4 relative (near-ties between triangles accepted), hit/miss and occlusion
/// agreement except on grazing rays (at most 0.5%), and instance_index / instance_id naming
/// the instance hit.
#[test]
fn j_random_instanced_scenes_match_flattened_gas() {
    let mut runner = TestRunner::new(proptest_config(64));
    let total = std::cell::RefCell::new(Stats::default());
    let strategy = (any::<u64>(), 2usize..=4, 3usize..=8);
    let result = runner.run(&strategy, |(seed, num_gas, num_inst)| {
        let mut rng = Rng::new(seed);
        let s = scene(&mut rng, num_gas, num_inst);
        let mut st = Stats::default();
        for ray in aimed_rays(&mut rng, &s.leaves, 10.0, 400) {
            compare_ray(&s.ias, &s.flat, &s.leaves, &ray, &mut st).map_err(TestCaseError::fail)?;
        }
        total.borrow_mut().add(&st);
        Ok(())
    });
    if let Err(e) = result {
        panic!("{e}");
    }
    total
        .into_inner()
        .check("one-level instancing vs flattened");
}

/// §5.4: the same GAS instanced at the identity gives exactly the GAS's own hits (apart from
/// the instance fields): no precision is lost through an identity transform.
#[test]
fn j_identity_instance_is_bit_exact() {
    let mut rng = Rng::new(7);
    let tris = random_soup(&mut rng, 200, 2.0, 0.5);
    let gas = tri_gas(&tris);
    let inst = [Instance::new(gas.clone().into()).instance_id(42)];
    let ias = Ias::build(&BuildOptions::default(), &[(&inst[..]).into()]).unwrap();
    for _ in 0..2000 {
        let ray = Ray::new(rng.vec3(-4.0, 4.0), rng.unit());
        let a = ias.intersect(&ray);
        let b = gas.intersect(&ray).map(|h| Hit {
            instance_id: 42,
            instance_index: 0,
            ..h
        });
        assert_eq!(hit_bits(&a), hit_bits(&b), "ray {ray:?}");
        assert_eq!(ias.occluded(&ray), gas.occluded(&ray), "ray {ray:?}");
    }
}

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool")
}

/// §3.2 determinism: an IAS of many instances (enough for the builder's parallel paths) built on
/// 1 and 4 threads has identical nodes, and batch queries give identical hits on 1 and 4
/// threads, equal to single-ray queries.
#[test]
fn determinism_ias_build_and_batch_hits_independent_of_threads() {
    let mut rng = Rng::new(0x5eed);
    let gases: Vec<Arc<Gas>> = (0..4)
        .map(|_| tri_gas(&random_soup(&mut rng, 16, 1.0, 0.5)))
        .collect();
    let instances: Vec<Instance> = (0..6000u32)
        .map(|i| {
            Instance::new(gases[i as usize % 4].clone().into())
                .transform(Transform::from_affine(&rng.affine(60.0)))
                .instance_id(i)
                .sbt_offset(i % 3)
        })
        .collect();
    let build = || Ias::build(&BuildOptions::default(), &[(&instances[..]).into()]).unwrap();
    let one = pool(1).install(build);
    let four = pool(4).install(build);
    assert!(one.bvh().nodes.len() > 1000, "a real tree");
    let bytes = |i: &Ias| bytemuck::cast_slice::<_, u8>(&i.bvh().nodes).to_vec();
    assert_eq!(
        bytes(&one),
        bytes(&four),
        "nodes differ between 1 and 4 threads"
    );
    assert_eq!(one.bounds(), four.bounds());

    let rays: Vec<Ray> = (0..20_000)
        .map(|_| Ray::new(rng.vec3(-70.0, 70.0), rng.unit()))
        .collect();
    let batch = |ias: &Ias, threads: usize| {
        let mut hits = vec![None; rays.len()];
        pool(threads).install(|| ias.intersect_batch(&rays, &mut hits).unwrap());
        let mut occ = vec![false; rays.len()];
        pool(threads).install(|| ias.occluded_batch(&rays, &mut occ).unwrap());
        (hits.iter().map(hit_bits).collect::<Vec<_>>(), occ)
    };
    let (h1, o1) = batch(&one, 1);
    let (h4, o4) = batch(&four, 4);
    let (h4b, o4b) = batch(&one, 4);
    assert_eq!(h1, h4);
    assert_eq!(h1, h4b);
    assert_eq!(o1, o4b);
    assert_eq!(o4, o4b);
    let hit_count = h1.iter().filter(|h| h.is_some()).count();
    assert!(hit_count > 500, "only {hit_count} hits");
    for (i, ray) in rays.iter().enumerate().step_by(7) {
        assert_eq!(hit_bits(&one.intersect(ray)), h1[i], "ray {i}");
        assert_eq!(h1[i].is_some(), o1[i], "ray {i}");
    }
}

/// §5.4: the bounds of an IAS hold every world vertex of every instance (and are finite).
#[test]
fn j_ias_bounds_hold_every_instance() {
    let mut rng = Rng::new(0xB0B);
    for _ in 0..20 {
        let soup = random_soup(&mut rng, 10, 1.0, 0.5);
        let gas = tri_gas(&soup);
        let transforms: Vec<Transform> = (0..5)
            .map(|_| Transform::from_affine(&rng.affine(10.0)))
            .collect();
        let inst: Vec<Instance> = transforms
            .iter()
            .map(|t| Instance::new(gas.clone().into()).transform(*t))
            .collect();
        let ias = Ias::build(&BuildOptions::default(), &[(&inst[..]).into()]).unwrap();
        let b = ias.bounds();
        assert!(b.is_finite_valid());
        for t in &transforms {
            for tri in transform_tris(t, &soup) {
                for p in tri {
                    let p = Vec3::from_array(p);
                    let slack = 1e-5 * p.abs().max_element().max(1.0);
                    assert!(
                        p.cmpge(b.min - slack).all() && p.cmple(b.max + slack).all(),
                        "{p} outside {b:?}"
                    );
                }
            }
        }
    }
}

/// §5.4 / §13.7 with the query API: custom primitives below transformed instances are offered
/// to the intersector with the ray in object space (and their object-space box); the t it
/// returns is the world t; single-ray and batch queries agree.
#[test]
fn u6_custom_primitives_under_instances_get_the_object_ray() {
    use oxray::{Aabb, AabbBuffer, BuildInput, CustomHit, CustomPrimitive, CustomPrimitiveInput};
    let boxes = [
        Aabb::new(Vec3::new(-0.5, -0.4, -0.3), Vec3::new(0.5, 0.4, 0.3)),
        Aabb::new(Vec3::new(1.0, -0.2, -0.2), Vec3::new(1.4, 0.2, 0.2)),
    ];
    let input: BuildInput = CustomPrimitiveInput::new(AabbBuffer::new(&boxes)).into();
    let gas = Arc::new(Gas::build(&BuildOptions::default(), &[input]).unwrap());
    let mut rng = Rng::new(0xC057);
    let affines: Vec<_> = (0..6).map(|_| rng.affine(5.0)).collect();
    let inst: Vec<Instance> = affines
        .iter()
        .enumerate()
        .map(|(k, a)| {
            Instance::new(gas.clone().into())
                .transform(Transform::from_affine(a))
                .instance_id(100 + k as u32)
        })
        .collect();
    let ias = Ias::build(&BuildOptions::default(), &[(&inst[..]).into()]).unwrap();
    // Slab entry of the (object-space) ray into the primitive's box.
    let slab = |p: &CustomPrimitive, r: &Ray| -> Option<CustomHit> {
        let inv = r.direction.recip();
        let (t0, t1) = ((p.aabb.min - r.origin) * inv, (p.aabb.max - r.origin) * inv);
        let (tn, tf) = (t0.min(t1).max_element(), t0.max(t1).min_element());
        let t = if tn >= r.tmin { tn } else { tf };
        (tn <= tf && t >= r.tmin && t <= r.tmax).then_some(CustomHit {
            t,
            hit_kind: 3,
            u: 0.0,
            v: 0.0,
        })
    };
    let rays: Vec<Ray> = (0..400)
        .map(|i| {
            let a = &affines[i % affines.len()];
            let target = a.transform_point3(rng.vec3(-0.3, 0.3));
            let o = target + rng.unit() * 8.0;
            Ray::new(o, (target - o) * rng.range(0.3, 3.0))
        })
        .collect();
    let mut singles = Vec::new();
    for ray in &rays {
        let hit = ias.intersect_with(ray, &mut |p: &CustomPrimitive, r: &Ray| slab(p, r));
        let h = hit.expect("aimed inside a box");
        let k = h.instance_index as usize;
        assert_eq!(h.instance_id, 100 + k as u32);
        assert_eq!(h.hit_kind.0, 3);
        // The world point at t is on the surface of the object box.
        let p = affines[k].inverse().transform_point3(ray.at(h.t));
        let b = boxes[h.primitive_index as usize];
        let tol = 1e-4 * p.abs().max_element().max(1.0);
        let inside = p.cmpge(b.min - tol).all() && p.cmple(b.max + tol).all();
        let on_face =
            (0..3).any(|i| (p[i] - b.min[i]).abs() < tol || (p[i] - b.max[i]).abs() < tol);
        assert!(inside && on_face, "object point {p} not on {b:?}");
        assert!(ias.occluded_with(ray, &mut |p: &CustomPrimitive, r: &Ray| slab(p, r)));
        // Without an intersector nothing is hit.
        assert!(ias.intersect(ray).is_none());
        singles.push(hit);
    }
    let mut batch = vec![None; rays.len()];
    ias.intersect_batch_with(&rays, &mut batch, &slab).unwrap();
    assert_eq!(
        singles.iter().map(hit_bits).collect::<Vec<_>>(),
        batch.iter().map(hit_bits).collect::<Vec<_>>()
    );
}
