//! Determinism: the structure built, and every query result, must not depend on the number of
//! threads (guide §3.2 thread safety; the library promises bit-identical trees whatever the
//! thread count, and batch results identical to single-ray ones).
//!
//! The large cases are above the builder's parallel thresholds (subtrees of more than 4096
//! primitives are built in parallel; nodes of more than 32768 are binned in parallel chunks).

mod common;

use common::{hit_bits, random_soup, Rng, Tri};
use glam::Vec3;
use oxray::cpu::Gas;
use oxray::{
    Aabb, AabbBuffer, BuildFlags, BuildInput, BuildOptions, CustomHit, CustomPrimitive,
    CustomPrimitiveInput, GeometryFlags, Hit, IndexBuffer, Ray, SbtIndexOffsets, TriangleInput,
    VertexBuffer,
};
use rayon::ThreadPool;

fn pool(threads: usize) -> ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool")
}

fn node_bytes(gas: &Gas) -> &[u8] {
    bytemuck::cast_slice(&gas.bvh().nodes)
}

fn soup_input(verts: &[[f32; 3]]) -> BuildInput<'_> {
    TriangleInput::new(VertexBuffer::f32x3(verts)).into()
}

/// Rays into a `[0, extent]^3` scene: from inside and outside, some with finite intervals, some
/// axis-parallel, a few invalid.
fn rays_for(rng: &mut Rng, n: usize, extent: f32) -> Vec<Ray> {
    (0..n)
        .map(|i| {
            let o = rng.vec3(-0.2 * extent, 1.2 * extent);
            let d = match i % 7 {
                0 => Vec3::X,
                1 => Vec3::new(0.0, -0.0, -1.0),
                _ => rng.dir(),
            };
            match i % 11 {
                0 => Ray::with_interval(o, d, 0.1 * extent, 0.5 * extent),
                1 => Ray::new(o, Vec3::ZERO),
                _ => Ray::new(o, d),
            }
        })
        .collect()
}

fn batch_hits(gas: &Gas, rays: &[Ray]) -> Vec<Option<Hit>> {
    let mut hits = vec![None; rays.len()];
    gas.intersect_batch(rays, &mut hits).expect("lengths match");
    hits
}

fn batch_occluded(gas: &Gas, rays: &[Ray]) -> Vec<bool> {
    let mut occ = vec![false; rays.len()];
    gas.occluded_batch(rays, &mut occ).expect("lengths match");
    occ
}

fn bits(hits: &[Option<Hit>]) -> Vec<Option<common::HitBits>> {
    hits.iter().map(hit_bits).collect()
}

/// Builds in a 1-thread and a 4-thread pool and checks identical nodes; then checks that batch
/// queries in both pools and single-ray queries all agree bit for bit.
fn check_across_pools(inputs: &[BuildInput<'_>], flags: BuildFlags, rays: &[Ray]) -> Gas {
    let (p1, p4) = (pool(1), pool(4));
    let options = BuildOptions::new(flags);
    let g1 = p1.install(|| Gas::build(&options, inputs)).expect("builds");
    let g4 = p4.install(|| Gas::build(&options, inputs)).expect("builds");
    assert_eq!(g1.bvh().nodes.len(), g4.bvh().nodes.len());
    assert!(
        g1.bvh().nodes == g4.bvh().nodes,
        "BVH nodes differ between 1 and 4 threads"
    );
    assert!(node_bytes(&g1) == node_bytes(&g4), "BVH node bytes differ");
    assert_eq!(g1.memory(), g4.memory());
    assert_eq!(g1.stats(), g4.stats());
    assert_eq!(g1.bounds(), g4.bounds());
    assert_eq!(g1.num_active_primitives(), g4.num_active_primitives());

    let h1 = p1.install(|| batch_hits(&g1, rays));
    let h4 = p4.install(|| batch_hits(&g4, rays));
    let single: Vec<Option<Hit>> = rays.iter().map(|r| g1.intersect(r)).collect();
    assert!(
        bits(&h1) == bits(&h4),
        "batch hits differ between 1 and 4 threads"
    );
    assert!(
        bits(&h1) == bits(&single),
        "batch hits differ from single-ray hits"
    );
    let o1 = p1.install(|| batch_occluded(&g1, rays));
    let o4 = p4.install(|| batch_occluded(&g4, rays));
    let single: Vec<bool> = rays.iter().map(|r| g4.occluded(r)).collect();
    assert_eq!(o1, o4);
    assert_eq!(o1, single);
    // Occlusion agrees with the closest hit.
    let closest: Vec<bool> = h1.iter().map(Option::is_some).collect();
    assert_eq!(o1, closest);
    assert!(h1.iter().any(Option::is_some) && h1.iter().any(Option::is_none));
    g4
}

/// Guide §3.2: a small soup (below every parallel threshold) for each build preset.
#[test]
fn small_soup_is_thread_count_independent_3_2() {
    let mut rng = Rng::new(1);
    let tris = random_soup(&mut rng, 3000, 10.0, 0.3);
    let verts: Vec<[f32; 3]> = tris.iter().flatten().copied().collect();
    let rays = rays_for(&mut rng, 4000, 10.0);
    for flags in [
        BuildFlags::empty(),
        BuildFlags::PREFER_FAST_BUILD,
        BuildFlags::PREFER_FAST_TRACE,
    ] {
        check_across_pools(&[soup_input(&verts)], flags, &rays);
    }
}

/// Guide §3.2: a ~200k-triangle soup, so that parallel subtree builds and parallel binning run.
#[test]
fn large_soup_is_thread_count_independent_3_2() {
    let mut rng = Rng::new(2);
    let tris: Vec<Tri> = random_soup(&mut rng, 200_000, 100.0, 0.4);
    let verts: Vec<[f32; 3]> = tris.iter().flatten().copied().collect();
    let rays = rays_for(&mut rng, 30_000, 100.0);
    for flags in [BuildFlags::empty(), BuildFlags::PREFER_FAST_TRACE] {
        let gas = check_across_pools(&[soup_input(&verts)], flags, &rays);
        assert_eq!(gas.num_active_primitives(), 200_000);
        assert!(gas.bvh().nodes.len() > 200_000 / 32);
    }
}

/// Guide §3.2: clustered geometry (many identical centroids, duplicated triangles) above the
/// parallel thresholds, where ties in sorting and binning must still be broken deterministically.
#[test]
fn clustered_soup_with_duplicates_is_thread_count_independent_3_2() {
    let mut rng = Rng::new(3);
    let base = random_soup(&mut rng, 5000, 10.0, 0.5);
    let mut tris: Vec<Tri> = Vec::with_capacity(60_000);
    for k in 0..12 {
        // Duplicates, and copies shifted along one axis only.
        for t in &base {
            tris.push(t.map(|v| [v[0] + (k / 2) as f32 * 0.001, v[1], v[2]]));
        }
    }
    let verts: Vec<[f32; 3]> = tris.iter().flatten().copied().collect();
    let rays = rays_for(&mut rng, 5000, 10.0);
    check_across_pools(&[soup_input(&verts)], BuildFlags::empty(), &rays);
}

/// Guide §3.2 with §7.3.2: several indexed inputs with SBT offsets, primitive index offsets and
/// inactive triangles — the resolved fields (`primitive_index`, `sbt_gas_index`, `build_input`)
/// are the same whatever the thread count.
#[test]
fn multi_input_mesh_is_thread_count_independent_3_2() {
    let mut rng = Rng::new(4);
    let n = 20_000usize;
    let mut verts: Vec<Vec<[f32; 3]>> = Vec::new();
    let mut indices: Vec<Vec<[u32; 3]>> = Vec::new();
    let mut offsets: Vec<Vec<u8>> = Vec::new();
    for input in 0..3 {
        let tris = random_soup(&mut rng, n, 50.0, 0.5);
        let mut v: Vec<[f32; 3]> = tris.iter().flatten().copied().collect();
        // Some inactive triangles: NaN vertices and zero area.
        for k in (0..n).step_by(97) {
            v[3 * k][1] = f32::NAN;
        }
        for k in (5..n).step_by(101) {
            v[3 * k + 2] = v[3 * k + 1];
        }
        verts.push(v);
        indices.push(
            (0..n as u32)
                .map(|k| [3 * k + 2, 3 * k, 3 * k + 1])
                .collect(),
        );
        offsets.push((0..n).map(|k| ((k + input) % 3) as u8).collect());
    }
    let flags = [
        GeometryFlags::empty(),
        GeometryFlags::DISABLE_ANYHIT,
        GeometryFlags::empty(),
    ];
    let inputs: Vec<BuildInput<'_>> = (0..3)
        .map(|i| {
            TriangleInput::new(VertexBuffer::f32x3(&verts[i]))
                .indices(IndexBuffer::u32x3(&indices[i]))
                .flags(&flags)
                .sbt_index_offsets(SbtIndexOffsets::u8(&offsets[i]))
                .primitive_index_offset(1000 * i as u32)
                .into()
        })
        .collect();
    let rays = rays_for(&mut rng, 20_000, 50.0);
    let gas = check_across_pools(&inputs, BuildFlags::empty(), &rays);
    // The resolved fields are those of the primitive hit.
    let hits = batch_hits(&gas, &rays);
    for h in hits.iter().flatten() {
        let input = h.build_input as usize;
        let local = (h.primitive_index - 1000 * input as u32) as usize;
        assert!(local < n);
        assert_eq!(
            h.sbt_gas_index,
            3 * input as u32 + offsets[input][local] as u32
        );
    }
}

/// Guide §3.2: custom primitives above the parallel thresholds; `intersect_batch_with` (the
/// closure called from several threads) agrees with `intersect_with` ray by ray.
#[test]
fn custom_primitives_are_thread_count_independent_3_2() {
    let mut rng = Rng::new(5);
    let boxes: Vec<Aabb> = (0..100_000)
        .map(|_| {
            let c = rng.vec3(0.0, 100.0);
            let h = Vec3::new(
                rng.range(0.05, 0.5),
                rng.range(0.05, 0.5),
                rng.range(0.05, 0.5),
            );
            Aabb::new(c - h, c + h)
        })
        .collect();
    let input: BuildInput<'_> = CustomPrimitiveInput::new(AabbBuffer::new(&boxes)).into();
    let (p1, p4) = (pool(1), pool(4));
    let g1 = p1
        .install(|| Gas::build(&BuildOptions::default(), &[input]))
        .unwrap();
    let g4 = p4
        .install(|| Gas::build(&BuildOptions::default(), &[input]))
        .unwrap();
    assert!(
        node_bytes(&g1) == node_bytes(&g4),
        "BVH nodes differ between 1 and 4 threads"
    );

    // The box itself, entered or (from inside) left.
    let slab = |p: &CustomPrimitive, r: &Ray| -> Option<CustomHit> {
        let inv = r.direction.recip();
        let a = (p.aabb.min - r.origin) * inv;
        let b = (p.aabb.max - r.origin) * inv;
        let tn = a.min(b).max_element();
        let tf = a.max(b).min_element();
        let t = if tn >= r.tmin { tn } else { tf };
        (tn <= tf && t >= r.tmin && t <= r.tmax).then_some(CustomHit {
            t,
            hit_kind: (p.primitive_index % 128) as u8,
            u: tn,
            v: tf,
        })
    };
    let rays = rays_for(&mut rng, 20_000, 100.0);
    let mut h1 = vec![None; rays.len()];
    let mut h4 = vec![None; rays.len()];
    p1.install(|| g1.intersect_batch_with(&rays, &mut h1, &slab))
        .unwrap();
    p4.install(|| g4.intersect_batch_with(&rays, &mut h4, &slab))
        .unwrap();
    let single: Vec<Option<Hit>> = rays
        .iter()
        .map(|r| g4.intersect_with(r, &mut { slab }))
        .collect();
    assert!(
        bits(&h1) == bits(&h4),
        "batch hits differ between 1 and 4 threads"
    );
    assert!(
        bits(&h1) == bits(&single),
        "batch hits differ from single-ray hits"
    );
    assert!(h1.iter().filter(|h| h.is_some()).count() > rays.len() / 10);
    // Without the closure, nothing is hit.
    assert!(batch_hits(&g1, &rays).iter().all(Option::is_none));
}

/// Guide §3.2: building the same input twice gives the same structure (no hidden state).
#[test]
fn rebuilding_gives_identical_structures_3_2() {
    let mut rng = Rng::new(6);
    let tris = random_soup(&mut rng, 50_000, 20.0, 0.3);
    let verts: Vec<[f32; 3]> = tris.iter().flatten().copied().collect();
    let a = Gas::build(&BuildOptions::default(), &[soup_input(&verts)]).unwrap();
    let b = Gas::build(&BuildOptions::default(), &[soup_input(&verts)]).unwrap();
    assert!(node_bytes(&a) == node_bytes(&b));
    let rays = rays_for(&mut rng, 2000, 20.0);
    assert!(bits(&batch_hits(&a, &rays)) == bits(&batch_hits(&b, &rays)));
}
