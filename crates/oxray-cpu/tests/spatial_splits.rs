//! Spatial splits (`oxray_bvh::sbvh`): a `PREFER_FAST_TRACE` triangle build may reference a
//! triangle from several leaves. These tests check that such structures find the brute-force
//! reference's hits on every kernel (random scenes, closed meshes hit on their edges and
//! vertices, and the data meshes), that they are built only where the rules allow
//! (`ALLOW_UPDATE`; `REQUIRE_SINGLE_ANYHIT_CALL`, guide §5.1 and §9.2), that they are
//! bit-identical whatever the thread count, and that saving, loading and compaction keep them.

use glam::Vec3;
use oxray_bvh::{GasData, NodeWidth, SpatialSplits, NO_PRIMITIVE};
use oxray_core::{
    BuildFlags, BuildInput, BuildOperation, BuildOptions, CandidateAction, GeometryFlags, Hit,
    IndexBuffer, Ray, TriangleInput, VertexBuffer,
};
use oxray_cpu::{Gas, Isa, NoCustomPrimitives};
use oxray_testkit::mesh::{find_mesh, grid_cube, icosphere, load_obj, random_soup, Mesh};
use oxray_testkit::oracle::check_closest;
use oxray_testkit::rays::{camera_rays, hemisphere_rays, shadow_rays, tricky_rays};
use oxray_testkit::rng::Rng;

mod common;
use common::{kernels, mesh_gas, soup_mesh};

const FAST_TRACE: BuildFlags = BuildFlags::PREFER_FAST_TRACE;

fn input(m: &Mesh) -> BuildInput<'_> {
    TriangleInput::new(VertexBuffer::f32x3(&m.positions))
        .indices(IndexBuffer::u32x3(&m.triangles))
        .into()
}

/// Long thin triangles crossing a box in every direction, among small ones: the case spatial
/// splits are for (an object split's children overlap wherever a long triangle goes).
fn slivers(rng: &mut Rng, n: usize) -> Mesh {
    let mut tris = random_soup(rng, n / 2, 10.0, 0.5);
    for _ in 0..n - n / 2 {
        let a = rng.vec3(-10.0, 10.0);
        let b = rng.vec3(-10.0, 10.0);
        let c = a + rng.vec3(-0.3, 0.3);
        tris.push([a.to_array(), b.to_array(), c.to_array()]);
    }
    soup_mesh(&tris)
}

/// How many leaf slots hold each primitive.
fn references(data: &GasData) -> Vec<u32> {
    let mut count = vec![0u32; data.num_primitives() as usize];
    for (s, &g) in data.slot_prim.iter().enumerate() {
        if g != NO_PRIMITIVE && data.slot_is_active(s) {
            count[g as usize] += 1;
        }
    }
    count
}

fn rays_for(m: &Mesh, rng: &mut Rng) -> Vec<Ray> {
    let mut rays = camera_rays(&m.positions, 40, 40);
    rays.extend(hemisphere_rays(&m.positions, &m.triangles, 1500, 3));
    rays.extend(shadow_rays(&m.positions, &m.triangles, 800, 4));
    let plain = mesh_gas(Isa::Sse, m, BuildFlags::empty());
    rays.extend(tricky_rays(&m.positions, &m.triangles, 1500, 5, |r| {
        plain.intersect(r).map(|h| h.t)
    }));
    let (lo, hi) = m.bounds();
    for _ in 0..800 {
        let o = Vec3::new(
            rng.range(lo[0], hi[0]),
            rng.range(lo[1], hi[1]),
            rng.range(lo[2], hi[2]),
        );
        rays.push(Ray::new(o, rng.dir()));
    }
    rays
}

/// Every kernel's closest hits on the spatial-split structure against brute force (every
/// `step`-th ray), and its occlusion against its own closest hits.
fn check_against_reference(name: &str, m: &Mesh, rays: &[Ray], step: usize) {
    let tris = m.soup();
    for isa in kernels() {
        let g = mesh_gas(isa, m, FAST_TRACE);
        let mut hits = vec![None; rays.len()];
        g.intersect_batch(rays, &mut hits).unwrap();
        let mut occ = vec![false; rays.len()];
        g.occluded_batch(rays, &mut occ).unwrap();
        for (i, ray) in rays.iter().enumerate() {
            assert_eq!(
                hits[i].is_some(),
                occ[i],
                "{name}, {isa}, ray {i}: occlusion"
            );
            if i % step == 0 {
                check_closest(hits[i], &tris, ray)
                    .unwrap_or_else(|e| panic!("{name}, {isa}, ray {i}: {e}"));
            }
        }
    }
}

#[test]
fn fast_trace_triangle_builds_split_within_the_budget_and_other_builds_do_not() {
    let mut rng = Rng::new(3);
    let m = slivers(&mut rng, 4000);
    let n = m.triangles.len();
    let split = GasData::build(&BuildOptions::new(FAST_TRACE), &[input(&m)]).unwrap();
    let refs = references(&split);
    let total: u32 = refs.iter().sum();
    assert!(refs.iter().all(|&c| c >= 1), "every triangle is referenced");
    assert!(
        total as usize > n,
        "no spatial split on long slivers ({total} references for {n} triangles)"
    );
    assert!(total as usize <= SpatialSplits::FAST_TRACE.max_references(n));
    assert_eq!(split.num_active_primitives() as usize, n);
    assert_eq!(split.num_references(), total);
    assert_eq!(split.stats().references, total as usize);
    // The spatial splits lower the SAH cost of the same preset without them.
    let binned = GasData::build_with_spatial_splits(
        &BuildOptions::new(FAST_TRACE),
        &[input(&m)],
        NodeWidth::Four,
        None,
    )
    .unwrap();
    assert!(references(&binned).iter().all(|&c| c == 1));
    assert!(
        split.stats().sah_cost < binned.stats().sah_cost,
        "SAH {} with spatial splits, {} without",
        split.stats().sah_cost,
        binned.stats().sah_cost
    );
    // Other presets reference every triangle once.
    for flags in [BuildFlags::empty(), BuildFlags::PREFER_FAST_BUILD] {
        let g = GasData::build(&BuildOptions::new(flags), &[input(&m)]).unwrap();
        assert!(references(&g).iter().all(|&c| c == 1), "{flags:?}");
    }
}

#[test]
fn spatial_split_structures_agree_with_the_reference_on_random_scenes() {
    let mut rng = Rng::new(41);
    for (k, m) in [
        slivers(&mut rng, 3000),
        soup_mesh(&random_soup(&mut rng, 3000, 10.0, 3.0)),
        soup_mesh(&random_soup(&mut rng, 500, 2.0, 4.0)),
    ]
    .iter()
    .enumerate()
    {
        let rays = rays_for(m, &mut rng);
        check_against_reference(&format!("random scene {k}"), m, &rays, 3);
    }
}

#[test]
fn closed_meshes_stay_watertight_on_their_edges_and_vertices() {
    // Rays aimed exactly at vertices and edges of closed meshes (tricky rays), from outside
    // and from inside: a ray that enters a closed mesh must hit it, whatever leaf the part
    // of the triangle it crosses was clipped into.
    let mut rng = Rng::new(8);
    for (name, m) in [("grid cube", grid_cube(16)), ("icosphere", icosphere(4))] {
        let g = mesh_gas(Isa::selected(), &m, FAST_TRACE);
        assert!(
            g.data().num_references() >= g.data().num_active_primitives(),
            "{name}"
        );
        let rays = tricky_rays(&m.positions, &m.triangles, 4000, 9, |r| {
            mesh_gas(Isa::Sse, &m, BuildFlags::empty())
                .intersect(r)
                .map(|h| h.t)
        });
        check_against_reference(name, &m, &rays, 1);
        // From the centre outwards, every ray must leave through the surface.
        let (lo, hi) = m.bounds();
        let c = (Vec3::from(lo) + Vec3::from(hi)) * 0.5;
        for isa in kernels() {
            let g = mesh_gas(isa, &m, FAST_TRACE);
            for i in 0..20_000 {
                let target = m.v(m.triangles[i % m.triangles.len()][i % 3]);
                let d = if i % 2 == 0 {
                    target - c
                } else {
                    // The midpoint of an edge.
                    let t = m.triangles[i % m.triangles.len()];
                    (m.v(t[0]) + m.v(t[1])) * 0.5 - c + rng.vec3(-1e-7, 1e-7)
                };
                assert!(
                    g.intersect(&Ray::new(c, d)).is_some(),
                    "{name}, {isa}: ray {i} from the centre leaks"
                );
            }
        }
    }
}

#[test]
fn spatial_split_structures_of_the_data_meshes_agree_with_the_reference() {
    let mut rng = Rng::new(77);
    let mut found = 0;
    for file in ["stanford-bunny.obj", "nefertiti.obj", "ogre.obj"] {
        let Some(path) = find_mesh(file) else {
            println!("skipping {file}: absent from ../shared/data/meshes");
            continue;
        };
        found += 1;
        let m = load_obj(&path).unwrap();
        let rays = rays_for(&m, &mut rng);
        check_against_reference(file, &m, &rays, 17);
        let g = GasData::build(&BuildOptions::new(FAST_TRACE), &[input(&m)]).unwrap();
        eprintln!(
            "{file}: {} triangles, {} references ({:+.1} %)",
            m.triangles.len(),
            g.num_references(),
            100.0 * (g.num_references() as f64 / m.triangles.len() as f64 - 1.0)
        );
    }
    if found == 0 {
        println!("skipping the data meshes: none found");
    }
}

#[test]
fn spatial_splits_give_the_same_tree_whatever_the_thread_count() {
    // Large enough for the parallel paths (subtrees over 1,024 references, binning in chunks
    // of 8,192).
    let mut rng = Rng::new(5);
    let m = slivers(&mut rng, 40_000);
    let build = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                GasData::build_with_width(
                    &BuildOptions::new(FAST_TRACE),
                    &[input(&m)],
                    NodeWidth::Eight,
                )
                .unwrap()
            })
    };
    let one = build(1);
    assert!(one.num_references() > one.num_active_primitives());
    for threads in [2, 3, 8] {
        let other = build(threads);
        assert!(
            one.bvh.nodes == other.bvh.nodes,
            "{threads} threads: 4-wide nodes"
        );
        assert!(
            one.bvh8.as_ref().unwrap().nodes == other.bvh8.as_ref().unwrap().nodes,
            "{threads} threads: 8-wide nodes"
        );
        assert_eq!(one.slot_prim, other.slot_prim, "{threads} threads");
        let bytes = |g: &GasData| bytemuck::cast_slice::<_, u8>(&g.triangles).to_vec();
        assert!(bytes(&one) == bytes(&other), "{threads} threads: triangles");
    }
}

/// Filtered closest-hit query that ignores every candidate and counts them per primitive.
fn candidate_counts(g: &Gas, rays: &[Ray], n: usize) -> Vec<u32> {
    let mut most = vec![0u32; n];
    for ray in rays {
        let mut count = vec![0u32; n];
        let hit = g.intersect_filtered(ray, &mut NoCustomPrimitives, |h: &Hit| {
            count[h.primitive_index as usize] += 1;
            CandidateAction::Ignore
        });
        assert!(hit.is_none());
        for (m, c) in most.iter_mut().zip(&count) {
            *m = (*m).max(*c);
        }
    }
    most
}

#[test]
fn require_single_anyhit_call_primitives_are_never_split_5_1_and_9_2() {
    // Guide §5.1: REQUIRE_SINGLE_ANYHIT_CALL "ensures that the any-hit program is called only
    // once for a hit with a primitive"; §9.2: geometry with the flag is not split. Two inputs
    // of slivers, the first with the flag: its triangles keep one reference each and are
    // offered once per ray; the second's are split and may be offered twice.
    let mut rng = Rng::new(19);
    let a = slivers(&mut rng, 2000);
    let b = slivers(&mut rng, 2000);
    let single = [GeometryFlags::REQUIRE_SINGLE_ANYHIT_CALL];
    let none = [GeometryFlags::empty()];
    let inputs = [
        TriangleInput::new(VertexBuffer::f32x3(&a.positions))
            .indices(IndexBuffer::u32x3(&a.triangles))
            .flags(&single)
            .into(),
        TriangleInput::new(VertexBuffer::f32x3(&b.positions))
            .indices(IndexBuffer::u32x3(&b.triangles))
            .flags(&none)
            .primitive_index_offset(a.triangles.len() as u32)
            .into(),
    ];
    let na = a.triangles.len();
    let n = na + b.triangles.len();
    let rays: Vec<Ray> = (0..3000)
        .map(|_| Ray::new(rng.vec3(-12.0, 12.0), rng.dir()))
        .collect();
    for isa in kernels() {
        let g = Gas::build_with_isa(isa, &BuildOptions::new(FAST_TRACE), &inputs).unwrap();
        let refs = references(g.data());
        assert!(
            refs[..na].iter().all(|&c| c == 1),
            "{isa}: flagged input split"
        );
        assert!(refs[na..].iter().any(|&c| c > 1), "{isa}: nothing split");
        let most = candidate_counts(&g, &rays, n);
        assert!(
            most[..na].iter().all(|&c| c <= 1),
            "{isa}: a flagged primitive offered twice"
        );
        assert!(
            most[na..].iter().any(|&c| c > 1),
            "{isa}: no split primitive offered twice (the test would not see a violation)"
        );
    }
    // With every record flagged, nothing is split.
    let inputs = [TriangleInput::new(VertexBuffer::f32x3(&a.positions))
        .indices(IndexBuffer::u32x3(&a.triangles))
        .flags(&single)
        .into()];
    let g = GasData::build(&BuildOptions::new(FAST_TRACE), &inputs).unwrap();
    assert!(references(&g).iter().all(|&c| c == 1));
}

#[test]
fn updatable_builds_keep_one_reference_per_primitive_5_6() {
    // Guide §5.6: an update refits the structure built with ALLOW_UPDATE, re-reading each
    // primitive into its leaf slot; spatial splits would need the clipping again, so such
    // builds never split, even with PREFER_FAST_TRACE or when asked to.
    let mut rng = Rng::new(23);
    let m = slivers(&mut rng, 3000);
    let options = BuildOptions::new(FAST_TRACE | BuildFlags::ALLOW_UPDATE);
    let g = GasData::build(&options, &[input(&m)]).unwrap();
    assert!(references(&g).iter().all(|&c| c == 1));
    let asked = GasData::build_with_spatial_splits(
        &options,
        &[input(&m)],
        NodeWidth::Four,
        Some(SpatialSplits::FAST_TRACE),
    )
    .unwrap();
    assert!(references(&asked).iter().all(|&c| c == 1));
    // And the structure updates and traces as before.
    let mut cpu = Gas::build(&options, &[input(&m)]).unwrap();
    let moved: Vec<[f32; 3]> = m
        .positions
        .iter()
        .map(|p| [p[0] + 0.5, p[1], p[2]])
        .collect();
    let moved_mesh = Mesh {
        positions: moved,
        triangles: m.triangles.clone(),
    };
    let update = BuildOptions {
        operation: BuildOperation::Update,
        ..options
    };
    cpu.update(&update, &[input(&moved_mesh)]).unwrap();
    let rays = rays_for(&moved_mesh, &mut rng);
    let tris = moved_mesh.soup();
    for (i, ray) in rays.iter().enumerate().step_by(5) {
        check_closest(cpu.intersect(ray), &tris, ray).unwrap_or_else(|e| panic!("ray {i}: {e}"));
    }
}

#[test]
fn split_structures_save_load_and_compact_with_their_hits() {
    let mut rng = Rng::new(31);
    let m = slivers(&mut rng, 3000);
    let options = BuildOptions::new(FAST_TRACE | BuildFlags::ALLOW_COMPACTION);
    let rays = rays_for(&m, &mut rng);
    for isa in kernels() {
        let g = Gas::build_with_isa(isa, &options, &[input(&m)]).unwrap();
        assert!(g.data().num_references() > g.data().num_active_primitives());
        let loaded = Gas::from_data_with_isa(GasData::from_bytes(&g.to_bytes()).unwrap(), isa);
        let compacted = Gas::from_data_with_isa(g.compact().unwrap(), isa);
        let mut hits = vec![None; rays.len()];
        g.intersect_batch(&rays, &mut hits).unwrap();
        for other in [&loaded, &compacted] {
            let mut h = vec![None; rays.len()];
            other.intersect_batch(&rays, &mut h).unwrap();
            assert!(h == hits, "{isa}");
        }
        assert_eq!(loaded.data().num_references(), g.data().num_references());
    }
    // The loader refuses repeated references where the structure must have one per primitive:
    // the same bytes with a record that requires a single any-hit call (guide §5.1).
    let mut data = GasData::build(&options, &[input(&m)]).unwrap();
    data.record_flags[0] = GeometryFlags::REQUIRE_SINGLE_ANYHIT_CALL;
    let err = GasData::from_bytes(&data.to_bytes()).unwrap_err();
    assert!(format!("{err}").contains("referenced"), "{err}");
}

#[test]
fn the_memory_query_bounds_split_structures() {
    let mut rng = Rng::new(37);
    for m in [slivers(&mut rng, 5000), icosphere(5)] {
        for flags in [FAST_TRACE, FAST_TRACE | BuildFlags::ALLOW_COMPACTION] {
            let options = BuildOptions::new(flags);
            let sizes = oxray_bvh::compute_memory_usage(&options, &[input(&m)]).unwrap();
            for width in [NodeWidth::Four, NodeWidth::Eight] {
                let g = GasData::build_with_width(&options, &[input(&m)], width).unwrap();
                assert!(
                    g.memory().output_bytes <= sizes.output_size_in_bytes,
                    "{} > {}",
                    g.memory().output_bytes,
                    sizes.output_size_in_bytes
                );
            }
        }
    }
}
