//! Every traversal kernel the processor runs ([`Isa`]: 8-wide nodes with AVX2 or AVX-512, the
//! portable 8-wide kernel, 4-wide nodes with SSE) finds the same hits: t, u, v and facing bit
//! for bit, and the same primitive unless two primitives are hit at exactly the same distance
//! (then the one reported must be one of them, and the same for every thread count); the same
//! occlusion; every kernel agrees with the brute-force reference. Kernels the processor lacks
//! are skipped with a message.

use glam::Vec3;
use oxray_core::{
    Aabb, AabbBuffer, BuildFlags, BuildOptions, CustomHit, CustomPrimitive, CustomPrimitiveInput,
    Hit, IndexBuffer, Ray, TriangleInput, VertexBuffer,
};
use oxray_cpu::{Cpu, Gas, Isa};
use oxray_testkit::mesh::{grid_cube, icosphere, load_bunny, random_soup, Mesh};
use oxray_testkit::oracle::{check_closest, reference_hits};
use oxray_testkit::rays::{camera_rays, hemisphere_rays, shadow_rays, tricky_rays};
use oxray_testkit::rng::Rng;
use oxray_testkit::Tri;

mod common;
use common::{kernels, mesh_gas, soup_mesh};

/// The scenes: a random soup, a grid cube (exact ties on shared edges), an icosphere, the
/// bunny where it is found.
fn scenes() -> Vec<(String, Mesh)> {
    let mut rng = Rng::new(17);
    let mut out = vec![
        (
            "soup".to_string(),
            soup_mesh(&random_soup(&mut rng, 3000, 10.0, 0.8)),
        ),
        ("grid cube".to_string(), grid_cube(12)),
        ("icosphere".to_string(), icosphere(4)),
    ];
    if let Some(b) = load_bunny("layouts") {
        out.push(("bunny".to_string(), b));
    }
    out
}

/// Camera, diffuse, shadow and tricky rays (on vertices, edges, planes) over a mesh.
fn rays_for(m: &Mesh, rng: &mut Rng) -> Vec<Ray> {
    let mut rays = camera_rays(&m.positions, 48, 48);
    rays.extend(hemisphere_rays(&m.positions, &m.triangles, 2000, 5));
    rays.extend(shadow_rays(&m.positions, &m.triangles, 1000, 6));
    let four = mesh_gas(Isa::Sse, m, BuildFlags::empty());
    rays.extend(tricky_rays(&m.positions, &m.triangles, 2000, 7, |r| {
        four.intersect(r).map(|h| h.t)
    }));
    // Random rays from inside the bounds, some with a bounded interval.
    let (lo, hi) = m.bounds();
    for i in 0..1000 {
        let o = Vec3::new(
            rng.range(lo[0], hi[0]),
            rng.range(lo[1], hi[1]),
            rng.range(lo[2], hi[2]),
        );
        let tmax = if i % 3 == 0 {
            rng.range(0.0, 2.0)
        } else {
            f32::INFINITY
        };
        rays.push(Ray::with_interval(o, rng.dir(), 0.0, tmax));
    }
    rays
}

/// t, u, v and facing as bits.
fn geometry_bits(h: &Option<Hit>) -> Option<(u32, u32, u32, u8)> {
    h.map(|h| (h.t.to_bits(), h.u.to_bits(), h.v.to_bits(), h.hit_kind.0))
}

/// Whether `a` and `b` are hits of two primitives at exactly the same distance, both of which
/// the reference finds there.
fn is_tie(a: &Hit, b: &Hit, tris: &[Tri], ray: &Ray) -> bool {
    let at_t = |p: u32| {
        reference_hits(tris, ray)
            .iter()
            .any(|r| r.prim == p && r.hit.t.to_bits() == a.t.to_bits())
    };
    a.t.to_bits() == b.t.to_bits() && at_t(a.primitive_index) && at_t(b.primitive_index)
}

fn in_pool<R: Send>(threads: usize, f: impl FnOnce() -> R + Send) -> R {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}

#[test]
fn every_kernel_finds_bit_identical_hits_and_agrees_with_the_reference() {
    let isas = kernels();
    let mut rng = Rng::new(99);
    for (name, m) in scenes() {
        let tris = m.soup();
        let rays = rays_for(&m, &mut rng);
        for flags in [BuildFlags::empty(), BuildFlags::PREFER_FAST_TRACE] {
            let gases: Vec<Gas> = isas.iter().map(|&i| mesh_gas(i, &m, flags)).collect();
            // Closest hits on 1 and on 2 threads: per kernel, identical whatever the threads.
            let mut results: Vec<Vec<Option<Hit>>> = Vec::new();
            let mut occlusion: Vec<Vec<bool>> = Vec::new();
            for (gas, isa) in gases.iter().zip(&isas) {
                let mut one = vec![None; rays.len()];
                in_pool(1, || gas.intersect_batch(&rays, &mut one)).unwrap();
                let mut two = vec![None; rays.len()];
                in_pool(2, || gas.intersect_batch(&rays, &mut two)).unwrap();
                assert!(
                    one == two,
                    "{name}: the {isa} kernel's hits depend on the thread count"
                );
                let mut occ = vec![false; rays.len()];
                in_pool(2, || gas.occluded_batch(&rays, &mut occ)).unwrap();
                results.push(one);
                occlusion.push(occ);
            }
            let reference = &results[0];
            let mut ties = 0;
            for (k, isa) in isas.iter().enumerate() {
                assert!(
                    occlusion[k] == occlusion[0],
                    "{name}: {isa} occlusion differs"
                );
                for (i, ray) in rays.iter().enumerate() {
                    let (a, b) = (&reference[i], &results[k][i]);
                    let same_primitive =
                        a.map(|h| h.primitive_index) == b.map(|h| h.primitive_index);
                    if same_primitive {
                        assert_eq!(
                            geometry_bits(a),
                            geometry_bits(b),
                            "{name}, ray {i} {ray:?}: {isa} against {}",
                            isas[0]
                        );
                    }
                    assert_eq!(a.is_some(), occlusion[k][i], "{name}, ray {i}: occlusion");
                    if let (Some(a), Some(b)) = (a, b) {
                        if !same_primitive {
                            // A tie: the same t, each primitive's own u, v and facing (which
                            // the reference checks below).
                            assert!(
                                is_tie(a, b, &tris, ray),
                                "{name}, ray {i}: {isa} reports primitive {} against {}",
                                b.primitive_index,
                                a.primitive_index
                            );
                            check_closest(Some(*b), &tris, ray)
                                .unwrap_or_else(|e| panic!("{name}, {isa}, ray {i}: {e}"));
                            ties += 1;
                        }
                    }
                }
            }
            // Every kernel against brute force, on a sample (the reference is slow).
            for (k, isa) in isas.iter().enumerate() {
                for (i, ray) in rays.iter().enumerate().step_by(7) {
                    check_closest(results[k][i], &tris, ray)
                        .unwrap_or_else(|e| panic!("{name}, {isa}, ray {i}: {e}"));
                }
            }
            eprintln!(
                "{name} ({flags:?}): {} rays, kernels {isas:?}, {ties} ties resolved differently",
                rays.len()
            );
        }
    }
}

#[test]
fn the_device_builds_for_its_kernel_and_loaded_or_compacted_structures_keep_their_hits() {
    let m = icosphere(3);
    let rays = camera_rays(&m.positions, 32, 32);
    let input = TriangleInput::new(VertexBuffer::f32x3(&m.positions))
        .indices(IndexBuffer::u32x3(&m.triangles));
    let options = BuildOptions::new(BuildFlags::ALLOW_COMPACTION | BuildFlags::ALLOW_UPDATE);
    let mut expected: Option<Vec<Option<Hit>>> = None;
    for isa in kernels() {
        use oxray_core::AccelBackend;
        let cpu = Cpu::with_isa(isa);
        assert_eq!(cpu.isa(), isa);
        let gas = cpu.build_gas(&options, &[input.into()]).unwrap();
        assert_eq!(gas.isa(), isa);
        assert_eq!(gas.bvh8.is_some(), isa != Isa::Sse);
        let loaded = Gas::from_data_with_isa(
            oxray_bvh::GasData::from_bytes(&gas.to_bytes()).unwrap(),
            isa,
        );
        let compacted = Gas::from_data_with_isa(gas.compact().unwrap(), isa);
        assert_eq!((loaded.isa(), compacted.isa()), (isa, isa));
        let mut hits = vec![None; rays.len()];
        gas.intersect_batch(&rays, &mut hits).unwrap();
        for other in [&loaded, &compacted] {
            let mut h = vec![None; rays.len()];
            other.intersect_batch(&rays, &mut h).unwrap();
            assert!(h == hits, "{isa}");
        }
        let geo: Vec<_> = hits.iter().map(geometry_bits).collect();
        if let Some(e) = &expected {
            let e: Vec<_> = e.iter().map(geometry_bits).collect();
            assert!(e == geo, "{isa}");
        } else {
            expected = Some(hits);
        }
    }
    // Data without the 8-wide layout falls back to the 4-wide kernel.
    let four = oxray_bvh::GasData::build(&options, &[input.into()]).unwrap();
    assert_eq!(Gas::from_data_with_isa(four, Isa::Avx2).isa(), Isa::Sse);
}

#[test]
fn custom_primitives_and_updates_agree_across_kernels() {
    let mut rng = Rng::new(5);
    let boxes: Vec<Aabb> = (0..500)
        .map(|_| {
            let c = rng.vec3(-10.0, 10.0);
            let r = rng.range(0.05, 0.6);
            Aabb::new(c - Vec3::splat(r), c + Vec3::splat(r))
        })
        .collect();
    let rays: Vec<Ray> = (0..3000)
        .map(|_| Ray::new(rng.vec3(-12.0, 12.0), rng.dir()))
        .collect();
    // The sphere inscribed in each box.
    let mut sphere = |p: &CustomPrimitive, ray: &Ray| -> Option<CustomHit> {
        let c = (p.aabb.min + p.aabb.max) * 0.5;
        let r = (p.aabb.max.x - p.aabb.min.x) * 0.5;
        let oc = ray.origin - c;
        let (a, b, cc) = (
            ray.direction.dot(ray.direction),
            oc.dot(ray.direction),
            oc.dot(oc) - r * r,
        );
        let disc = b * b - a * cc;
        if disc < 0.0 {
            return None;
        }
        let t = (-b - disc.sqrt()) / a;
        (t >= ray.tmin && t <= ray.tmax).then_some(CustomHit {
            t,
            hit_kind: 0,
            u: 0.0,
            v: 0.0,
        })
    };
    let mut expected: Option<Vec<Option<u32>>> = None;
    for isa in kernels() {
        let input = CustomPrimitiveInput::new(AabbBuffer::new(&boxes));
        let gas = Gas::build_with_isa(isa, &BuildOptions::default(), &[input.into()]).unwrap();
        let ts: Vec<Option<u32>> = rays
            .iter()
            .map(|r| gas.intersect_with(r, &mut sphere).map(|h| h.t.to_bits()))
            .collect();
        if let Some(e) = &expected {
            assert!(e == &ts, "{isa}");
        } else {
            assert!(ts.iter().filter(|t| t.is_some()).count() > 100);
            expected = Some(ts);
        }
    }

    // Updates refit the 8-wide layout too.
    let m = icosphere(3);
    let flags = BuildFlags::ALLOW_UPDATE;
    let moved: Vec<[f32; 3]> = m
        .positions
        .iter()
        .map(|p| [p[0] * 1.5 + 0.25, p[1] * 0.75, p[2] + p[0] * 0.5])
        .collect();
    let rays = camera_rays(&moved, 40, 40);
    let moved_mesh = Mesh {
        positions: moved.clone(),
        triangles: m.triangles.clone(),
    };
    let tris = moved_mesh.soup();
    for isa in kernels() {
        let mut gas = mesh_gas(isa, &m, flags);
        let mut options = BuildOptions::new(flags);
        options.operation = oxray_core::BuildOperation::Update;
        let input = TriangleInput::new(VertexBuffer::f32x3(&moved))
            .indices(IndexBuffer::u32x3(&m.triangles));
        gas.update(&options, &[input.into()]).unwrap();
        for ray in &rays {
            check_closest(gas.intersect(ray), &tris, ray).unwrap_or_else(|e| panic!("{isa}: {e}"));
        }
    }
}

/// The quantised kernels keep their derived nodes in step with the structure: made when it is
/// built, loaded or compacted, made again by an update (the same as quantising the refit
/// tree), counted in its memory and compacted size, and left out (the float kernel of the
/// same instruction set instead) where the structure has motion.
#[test]
fn quantised_nodes_follow_the_structure_through_updates_and_are_counted() {
    let quantised: Vec<Isa> = kernels().into_iter().filter(|i| i.is_quantized()).collect();
    if quantised.is_empty() {
        eprintln!("skipping: this processor runs no quantised kernel");
        return;
    }
    let m = icosphere(3);
    let moved: Vec<[f32; 3]> = m
        .positions
        .iter()
        .map(|p| [p[0] * 1.5 + 0.25, p[1], p[2] * 0.5])
        .collect();
    let options = BuildOptions::new(BuildFlags::ALLOW_COMPACTION | BuildFlags::ALLOW_UPDATE);
    for isa in quantised {
        fn input<'a>(v: &'a [[f32; 3]], m: &'a Mesh) -> TriangleInput<'a> {
            TriangleInput::new(VertexBuffer::f32x3(v)).indices(IndexBuffer::u32x3(&m.triangles))
        }
        let mut gas =
            Gas::build_with_isa(isa, &options, &[input(&m.positions, &m).into()]).unwrap();
        let q = |g: &Gas| g.quantized_nodes().expect("quantised nodes").nodes.clone();
        let fresh = oxray_bvh::QBvh8::quantize(gas.bvh8.as_ref().unwrap()).unwrap();
        assert_eq!(q(&gas), fresh.nodes, "{isa}");
        let bytes = fresh.memory();
        assert_eq!(
            gas.memory().node_bytes,
            gas.data().memory().node_bytes + bytes
        );
        assert_eq!(
            gas.memory().output_bytes,
            gas.data().memory().output_bytes + bytes
        );
        let compacted = Gas::from_data_with_isa(gas.compact().unwrap(), isa);
        assert_eq!(compacted.isa(), isa);
        assert_eq!(
            Some(compacted.memory().output_bytes),
            gas.compacted_size(),
            "{isa}"
        );

        // An update quantises the refit boxes; the hits are those of a float kernel.
        let mut update = options;
        update.operation = oxray_core::BuildOperation::Update;
        gas.update(&update, &[input(&moved, &m).into()]).unwrap();
        let refit = oxray_bvh::QBvh8::quantize(gas.bvh8.as_ref().unwrap()).unwrap();
        assert_eq!(q(&gas), refit.nodes, "{isa}");
        let float = Gas::from_data_with_isa(gas.data().clone(), isa.unquantized());
        // Ray by ray: batches of camera rays would go through the packet path.
        let rays = camera_rays(&moved, 24, 24);
        let a: Vec<Option<Hit>> = rays.iter().map(|r| gas.intersect(r)).collect();
        let b: Vec<Option<Hit>> = rays.iter().map(|r| float.intersect(r)).collect();
        let geo = |h: &[Option<Hit>]| h.iter().map(geometry_bits).collect::<Vec<_>>();
        assert_eq!(geo(&a), geo(&b), "{isa}");
        assert!(a.iter().filter(|h| h.is_some()).count() > 100);

        // Motion: the float kernel of the same instruction set.
        let later = [VertexBuffer::f32x3(&moved)];
        let motion = input(&m.positions, &m).motion_vertices(&later);
        let gas = Gas::build_with_isa(
            isa,
            &BuildOptions::default().with_motion(oxray_core::MotionOptions::new(2, 0.0, 1.0)),
            &[motion.into()],
        )
        .unwrap();
        assert_eq!(gas.isa(), isa.unquantized());
        assert!(gas.quantized_nodes().is_none());
    }
}
