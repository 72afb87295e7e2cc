//! GASes built by the device's kernels (`device_build`) against the brute-force oracle and
//! against trees the host built. Runs where a CUDA driver and device exist; elsewhere (CI) each
//! test prints why it skips and passes (`OXRAY_REQUIRE_GPU=1` makes a missing GPU a failure).

mod common;

use common::{bench_rays, find_mesh, icosphere_f32, load_obj, tricky_rays, Mesh};
use oxray_core::{
    AccelBackend, BuildFlags, BuildInput, BuildOptions, GeometryFlags, Hit, IndexBuffer, Ray,
    SbtIndexOffsets, TraversableHandle, TriangleInput, VertexBuffer,
};
use oxray_cuda::device_build::{build_gas, DeviceBuildConfig};
use oxray_cuda::{Cuda, CudaContext, CudaError, CudaGas, DeviceBuildError, GasBuilder};
use oxray_testkit::mesh::{grid_cube, random_soup, soup, Tri};
use oxray_testkit::oracle::{check_closest, reference_hits};
use oxray_testkit::rng::Rng;
use std::sync::{Mutex, MutexGuard, OnceLock};

/// The shared context, with a lock that keeps GPU tests from interleaving; `None` where this
/// machine has no CUDA, unless `OXRAY_REQUIRE_GPU` is set.
fn gpu() -> Option<(CudaContext, MutexGuard<'static, ()>)> {
    static CTX: OnceLock<Result<CudaContext, CudaError>> = OnceLock::new();
    static LOCK: Mutex<()> = Mutex::new(());
    match CTX.get_or_init(CudaContext::new) {
        Ok(ctx) => Some((ctx.clone(), LOCK.lock().unwrap_or_else(|e| e.into_inner()))),
        Err(e) if e.is_unavailable() && std::env::var_os("OXRAY_REQUIRE_GPU").is_none() => {
            println!("skipping: {e}");
            None
        }
        Err(e) => panic!("CUDA is present but unusable: {e}"),
    }
}

const PRESETS: [(&str, BuildFlags, DeviceBuildConfig); 4] = [
    (
        "fast build",
        BuildFlags::PREFER_FAST_BUILD,
        DeviceBuildConfig::FAST_BUILD,
    ),
    (
        "fast build, 30-bit codes",
        BuildFlags::PREFER_FAST_BUILD,
        DeviceBuildConfig {
            morton_bits: 30,
            ..DeviceBuildConfig::FAST_BUILD
        },
    ),
    ("default", BuildFlags::empty(), DeviceBuildConfig::DEFAULT),
    (
        "updatable",
        BuildFlags::ALLOW_UPDATE,
        DeviceBuildConfig {
            keep_inactive: true,
            ..DeviceBuildConfig::DEFAULT
        },
    ),
];

fn update(flags: BuildFlags) -> BuildOptions {
    BuildOptions {
        flags,
        operation: oxray_core::BuildOperation::Update,
        ..Default::default()
    }
}

fn soup_input(vertices: &[[f32; 3]]) -> BuildInput<'_> {
    TriangleInput::new(VertexBuffer::f32x3(vertices)).into()
}

fn mesh_input(mesh: &Mesh) -> BuildInput<'_> {
    TriangleInput::new(VertexBuffer::f32x3(&mesh.positions))
        .indices(IndexBuffer::u32x3(&mesh.triangles))
        .into()
}

/// Builds on the device, asserting that it did.
fn device_gas(
    ctx: &CudaContext,
    config: &DeviceBuildConfig,
    flags: BuildFlags,
    inputs: &[BuildInput<'_>],
) -> CudaGas {
    let (gas, times) = build_gas(ctx, &BuildOptions::new(flags), inputs, config)
        .unwrap_or_else(|e| panic!("device build failed: {e}"));
    assert_eq!(gas.builder(), GasBuilder::Device);
    assert!(
        times.kernels_ms >= 0.0 && times.total_ms >= times.kernels_ms,
        "{times:?}"
    );
    gas
}

/// Checks every closest hit and occlusion result of `rays` against the oracle over `tris`.
fn check_oracle(gas: &CudaGas, tris: &[Tri], rays: &[Ray], what: &str) {
    let hits = gas.intersect_batch(rays).unwrap();
    let occluded = gas.occluded_batch(rays).unwrap();
    let mut failures = Vec::new();
    for (i, r) in rays.iter().enumerate() {
        if let Err(e) = check_closest(hits[i], tris, r) {
            failures.push(format!("ray {i}: {e}"));
        }
        let any = !reference_hits(tris, r).is_empty();
        if occluded[i] != any {
            failures.push(format!(
                "ray {i}: occluded {} but the oracle says {any}: {r:?}",
                occluded[i]
            ));
        }
    }
    assert!(
        failures.is_empty(),
        "{what}: {} of {} rays disagree with the oracle; first: {:#?}",
        failures.len(),
        rays.len(),
        &failures[..failures.len().min(5)]
    );
}

/// Rays from random points of a box towards random points of it, and some aimed at triangles'
/// centres (so that most hit).
fn random_rays(rng: &mut Rng, tris: &[Tri], n: usize, extent: f32) -> Vec<Ray> {
    (0..n)
        .map(|k| {
            let o = rng.vec3(-0.2 * extent, 1.2 * extent);
            let target = if k % 2 == 0 && !tris.is_empty() {
                let t = tris[rng.below(tris.len())];
                (glam::Vec3::from(t[0]) + glam::Vec3::from(t[1]) + glam::Vec3::from(t[2])) / 3.0
            } else {
                rng.vec3(0.0, extent)
            };
            let d = target - o;
            let d = if d.length_squared() > 0.0 {
                d
            } else {
                glam::Vec3::Z
            };
            let mut r = Ray::new(o, d);
            if k % 5 == 0 {
                r.tmax = rng.range(0.2, 1.0);
            }
            if k % 7 == 0 {
                r.tmin = rng.range(0.0, 0.5);
            }
            r
        })
        .collect()
}

#[test]
fn random_soups_with_inactive_triangles_match_the_oracle() {
    let Some((ctx, _lock)) = gpu() else { return };
    let mut rng = Rng::new(0x6e0b_5eed);
    for n in [0usize, 1, 2, 3, 9, 100, 5000, 60_000] {
        let mut tris = random_soup(&mut rng, n, 10.0, 0.6);
        // Inactive triangles, as the CPU builder makes them: a NaN or infinite coordinate, zero
        // area (a repeated vertex, collinear vertices).
        for (k, t) in tris.iter_mut().enumerate() {
            match k % 17 {
                3 => t[1][2] = f32::NAN,
                5 => t[2] = t[0],
                8 => {
                    t[2] = [
                        2.0 * t[1][0] - t[0][0],
                        2.0 * t[1][1] - t[0][1],
                        2.0 * t[1][2] - t[0][2],
                    ]
                }
                11 if k % 2 == 1 => t[0][0] = f32::INFINITY,
                _ => {}
            }
        }
        // Duplicates: many triangles with one centroid share a Morton code.
        if n >= 100 {
            for k in 0..n / 10 {
                tris[k] = tris[0];
            }
        }
        let vertices = soup(&tris);
        let inputs = [soup_input(&vertices)];
        let rays = random_rays(&mut rng, &tris, 4000, 10.0);
        for (name, flags, config) in &PRESETS {
            let gas = device_gas(&ctx, config, *flags, &inputs);
            let active = tris
                .iter()
                .filter(|t| {
                    !oxray_bvh::triangle::is_degenerate(t[0].into(), t[1].into(), t[2].into())
                })
                .count();
            assert_eq!(
                gas.info().num_active_primitives as usize,
                active,
                "{n} {name}"
            );
            assert_eq!(gas.info().num_primitives as usize, n);
            assert!(
                gas.info().stats.max_depth <= oxray_bvh::MAX_BVH2_DEPTH,
                "{:?}",
                gas.info().stats
            );
            check_oracle(&gas, &tris, &rays, &format!("{n} triangles, {name}"));
        }
    }
}

#[test]
fn grids_are_watertight() {
    let Some((ctx, _lock)) = gpu() else { return };
    // Rays from outside aimed exactly at the grid's shared vertices and edge midpoints inside the
    // cube's faces (not on its edges, where a ray may only graze the solid): a watertight test on
    // a closed surface never lets one through, whatever the tree.
    let mesh = grid_cube(24);
    let tris = mesh.soup();
    let on_face_interior =
        |p: glam::Vec3| p.to_array().iter().filter(|c| c.abs() == 1.0).count() == 1;
    let mut rng = Rng::new(7);
    let mut rays = Vec::new();
    for t in &mesh.triangles {
        let p = |k: usize| glam::Vec3::from(mesh.positions[t[k] as usize]);
        for target in [p(0), (p(0) + p(1)) * 0.5, (p(1) + p(2)) * 0.5] {
            if on_face_interior(target) {
                let o = rng.dir() * 5.0;
                rays.push(Ray::new(o, target - o));
            }
        }
    }
    assert!(rays.len() > 15_000, "{}", rays.len());
    for (name, flags, config) in &PRESETS {
        let gas = device_gas(&ctx, config, *flags, &[mesh_input(&mesh)]);
        let hits = gas.intersect_batch(&rays).unwrap();
        let missed = hits.iter().filter(|h| h.is_none()).count();
        assert_eq!(
            missed,
            0,
            "{name}: {missed} of {} rays slipped through",
            rays.len()
        );
        check_oracle(&gas, &tris, &rays, name);
    }
}

#[test]
fn several_inputs_with_sbt_offsets_resolve_as_on_the_host() {
    let Some((ctx, _lock)) = gpu() else { return };
    // Input 0: f32 vertices with u32 indices (read in place); input 1: u16 indices and two SBT
    // records chosen per triangle (widened on the host); input 2: no indices and a
    // pre-transform (decoded on the host), with a primitive index offset.
    let a = icosphere_f32(3);
    let b_mesh = icosphere_f32(2);
    let b_pos: Vec<[f32; 3]> = b_mesh
        .positions
        .iter()
        .map(|p| [p[0] + 2.5, p[1], p[2]])
        .collect();
    let b_idx: Vec<[u16; 3]> = b_mesh
        .triangles
        .iter()
        .map(|t| t.map(|i| i as u16))
        .collect();
    let b_offsets: Vec<u8> = (0..b_idx.len()).map(|k| (k % 2) as u8).collect();
    let c_tris = soup(&icosphere_f32(2).soup());
    let two = [GeometryFlags::empty(), GeometryFlags::DISABLE_ANYHIT];
    let inputs: Vec<BuildInput<'_>> = vec![
        mesh_input(&a),
        TriangleInput::new(VertexBuffer::f32x3(&b_pos))
            .indices(IndexBuffer::u16x3(&b_idx))
            .flags(&two)
            .sbt_index_offsets(SbtIndexOffsets::u8(&b_offsets))
            .into(),
        TriangleInput::new(VertexBuffer::f32x3(&c_tris))
            .pre_transform([1.0, 0.0, 0.0, -2.5, 0.0, 0.5, 0.0, 0.25, 0.0, 0.0, 1.0, 0.0])
            .primitive_index_offset(1000)
            .into(),
    ];
    let host = oxray_cpu::Gas::build(&BuildOptions::default(), &inputs).unwrap();
    let mut rng = Rng::new(11);
    let rays: Vec<Ray> = (0..20_000)
        .map(|_| {
            let o = rng.dir() * 8.0;
            let target = glam::Vec3::new(
                rng.range(-3.5, 3.5),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
            );
            Ray::new(o, target - o)
        })
        .collect();
    let mut want = vec![None; rays.len()];
    host.intersect_batch(&rays, &mut want).unwrap();
    for (name, flags, config) in &PRESETS {
        let gas = device_gas(&ctx, config, *flags, &inputs);
        assert_eq!(gas.info().num_build_inputs, 3);
        assert_eq!(gas.info().record_flags.len(), 4);
        let got = gas.intersect_batch(&rays).unwrap();
        let (mut hits, mut ties) = (0, 0);
        for i in 0..rays.len() {
            match (want[i], got[i]) {
                (None, None) => {}
                (Some(w), Some(g)) => {
                    hits += 1;
                    assert_eq!(w.t.to_bits(), g.t.to_bits(), "{name} ray {i}: {w:?} {g:?}");
                    if (w.primitive_index, w.build_input) == (g.primitive_index, g.build_input) {
                        assert_eq!(w, g, "{name} ray {i}");
                    } else {
                        ties += 1;
                    }
                }
                (w, g) => panic!("{name} ray {i}: host {w:?}, device {g:?}"),
            }
        }
        println!("{name}: {hits} hits, {ties} ties");
        assert!(
            hits > rays.len() / 4 && ties * 100 <= hits,
            "{hits} hits, {ties} ties"
        );
        // Every input and record was hit somewhere.
        for (input, sbt) in [(0, 0), (1, 1), (1, 2), (2, 3)] {
            assert!(
                got.iter()
                    .flatten()
                    .any(|h| h.build_input == input && h.sbt_gas_index == sbt),
                "{name}: no hit on input {input}, SBT record {sbt}"
            );
        }
        assert!(got.iter().flatten().any(|h| h.primitive_index >= 1000));
    }
}

/// How a device-built tree's hits compare with a host-built tree's.
fn compare_with_host(mesh: &Mesh, name: &str, ctx: &CudaContext, side: u32) {
    let inputs = [mesh_input(mesh)];
    let (mut rays, incoherent) = bench_rays(mesh, side);
    rays.extend(incoherent);
    for (preset, flags, config) in &PRESETS {
        let host = oxray_cpu::Gas::build(&BuildOptions::new(*flags), &inputs).unwrap();
        let mut all = rays.clone();
        all.extend(tricky_rays(mesh, &host, (side * side) as usize, 3));
        let gas = device_gas(ctx, config, *flags, &inputs);
        let mut want = vec![None; all.len()];
        host.intersect_batch(&all, &mut want).unwrap();
        let mut want_occ = vec![false; all.len()];
        host.occluded_batch(&all, &mut want_occ).unwrap();
        let got = gas.intersect_batch(&all).unwrap();
        let got_occ = gas.occluded_batch(&all).unwrap();
        let mut ties = Vec::new();
        let mut bad: Vec<(usize, Option<Hit>, Option<Hit>)> = Vec::new();
        for i in 0..all.len() {
            match (want[i], got[i]) {
                (None, None) => {}
                (Some(w), Some(g)) if w.t.to_bits() == g.t.to_bits() => {
                    if w.primitive_index != g.primitive_index {
                        ties.push(i);
                    } else if w != g {
                        bad.push((i, want[i], got[i]));
                    }
                }
                _ => bad.push((i, want[i], got[i])),
            }
        }
        // A tie is another primitive at the same distance (rays aimed exactly at shared vertices
        // and edges): the oracle must hit the one the device reports there, with the same
        // barycentrics and facing (a sample of them: each check tests every triangle).
        let tris = mesh.soup();
        let step = (ties.len() / 1000).max(1);
        for &i in ties.iter().step_by(step) {
            if let Err(e) = check_closest(got[i], &tris, &all[i]) {
                panic!("{name} {preset}: ray {i} (a tie with the host's tree): {e}");
            }
        }
        let ties = ties.len();
        let occ_diff = (0..all.len())
            .filter(|&i| want_occ[i] != got_occ[i])
            .count();
        let s = gas.info().stats;
        println!(
            "{name} {preset}: {} rays, {ties} ties, {} differ, {occ_diff} occlusion differences; \
             device tree {} nodes, depth {}, {:.2} triangles a leaf, SAH {:.1}",
            all.len(),
            bad.len(),
            s.nodes,
            s.max_depth,
            s.mean_leaf_size,
            s.sah_cost
        );
        assert!(
            bad.is_empty(),
            "{name} {preset}: first differences {:?}",
            &bad[..bad.len().min(5)]
        );
        assert_eq!(occ_diff, 0, "{name} {preset}");
    }
}

#[test]
fn icosphere_hits_equal_a_host_built_trees() {
    let Some((ctx, _lock)) = gpu() else { return };
    compare_with_host(&icosphere_f32(6), "icosphere-6", &ctx, 256);
}

#[test]
fn real_meshes_hit_as_host_built_trees_do() {
    let Some((ctx, _lock)) = gpu() else { return };
    let mut found = 0;
    for file in [
        "stanford-bunny.obj",
        "teapot.obj",
        "spot.obj",
        "nefertiti.obj",
    ] {
        let Some(path) = find_mesh(file) else {
            println!("skipping {file}: not found (set OXRAY_MESH_DIR)");
            continue;
        };
        let mesh = load_obj(&path).unwrap();
        compare_with_host(&mesh, file, &ctx, 256);
        found += 1;
    }
    println!("{found} meshes compared");
}

#[test]
fn a_tree_deeper_than_allowed_is_refused_and_the_backend_builds_on_the_host() {
    let Some((ctx, _lock)) = gpu() else { return };
    let mesh = icosphere_f32(3);
    let inputs = [mesh_input(&mesh)];
    let shallow = DeviceBuildConfig {
        max_depth: 3,
        ..DeviceBuildConfig::FAST_BUILD
    };
    match build_gas(&ctx, &BuildOptions::default(), &inputs, &shallow) {
        Err(DeviceBuildError::Device(CudaError::TreeTooDeep { depth, max: 3 })) => {
            assert!(depth > 3 && depth as usize <= oxray_bvh::MAX_BVH2_DEPTH)
        }
        other => panic!(
            "expected TreeTooDeep, got {:?}",
            other.map(|(g, _)| g.info().clone())
        ),
    }
    // Validation errors are the host builder's, before anything reaches the device.
    let bad = [TriangleInput::new(VertexBuffer::f32x3(&mesh.positions))
        .indices(IndexBuffer::u32x3(&[[0, 1, 1_000_000]]))
        .into()];
    let e = build_gas(
        &ctx,
        &BuildOptions::default(),
        &bad,
        &DeviceBuildConfig::DEFAULT,
    )
    .map(|_| ())
    .unwrap_err();
    assert_eq!(
        e,
        DeviceBuildError::Invalid(
            oxray_bvh::GasData::build(&BuildOptions::default(), &bad).unwrap_err()
        )
    );
}

#[test]
fn the_backend_builds_on_the_device_by_default_and_on_the_host_when_asked() {
    let Some((ctx, _lock)) = gpu() else { return };
    let mesh = icosphere_f32(4);
    let inputs = [mesh_input(&mesh)];
    let cuda = Cuda::from_context(ctx.clone());
    let rays = bench_rays(&mesh, 64).1;
    let mut results = Vec::new();
    for (flags, builder) in [
        (BuildFlags::empty(), GasBuilder::Device),
        (BuildFlags::PREFER_FAST_BUILD, GasBuilder::Device),
        (BuildFlags::ALLOW_COMPACTION, GasBuilder::Device),
        (BuildFlags::PREFER_FAST_TRACE, GasBuilder::Device),
        (BuildFlags::ALLOW_UPDATE, GasBuilder::Device),
        (
            BuildFlags::ALLOW_UPDATE | BuildFlags::PREFER_FAST_BUILD,
            GasBuilder::Device,
        ),
    ] {
        let options = BuildOptions::new(flags);
        let gas = cuda.build_gas(&options, &inputs).unwrap();
        assert_eq!(gas.builder(), builder, "{flags:?}");
        // The memory query bounds what the build keeps on the device.
        let sizes = cuda.compute_memory_usage(&options, &inputs).unwrap();
        assert!(
            gas.device_bytes() <= sizes.output_size_in_bytes,
            "{flags:?}: {sizes:?}"
        );
        let handle = TraversableHandle::from(gas);
        let mut hits = vec![None; rays.len()];
        cuda.intersect_closest(&handle, &rays, &mut hits).unwrap();
        results.push(
            hits.iter()
                .map(|h| h.map(|h| h.t.to_bits()))
                .collect::<Vec<_>>(),
        );
    }
    assert!(
        results.windows(2).all(|w| w[0] == w[1]),
        "every build finds the same distances"
    );
    let host = Cuda::from_context(ctx).with_builder(GasBuilder::Host);
    assert_eq!(
        host.build_gas(&BuildOptions::default(), &inputs)
            .unwrap()
            .builder(),
        GasBuilder::Host
    );
    // Pipelines trace a device-built GAS through its handle.
    let gas = cuda.build_gas(&BuildOptions::default(), &inputs).unwrap();
    assert_ne!(gas.optix_handle().unwrap(), 0);
}

/// Custom primitives (guide §5.3) built by the device: every valid box in a leaf slot once,
/// invalid ones (inverted, NaN, infinite) left out as the host's builder leaves them, the
/// structure's bounds the host's, and a leaf box around each of its boxes (checked by the
/// assembled CPU layout read back from device memory).
#[test]
fn custom_primitive_gases_build_on_the_device() {
    let Some((ctx, _lock)) = gpu() else {
        return;
    };
    let mut rng = Rng::new(0xAAB);
    let boxes: Vec<oxray_core::Aabb> = (0..20_000)
        .map(|i| {
            let c = rng.vec3(-10.0, 10.0);
            let e = rng.vec3(0.001, 0.3);
            match i % 97 {
                0 => oxray_core::Aabb::new(c + e, c - e),
                1 => oxray_core::Aabb::new(c - e, glam::Vec3::new(f32::NAN, c.y, c.z)),
                2 => oxray_core::Aabb::new(c - e, glam::Vec3::INFINITY),
                _ => oxray_core::Aabb::new(c - e, c + e),
            }
        })
        .collect();
    let f = [GeometryFlags::empty(); 2];
    let offsets: Vec<u32> = (0..boxes.len() as u32 / 2).map(|i| i % 2).collect();
    let (a, b) = boxes.split_at(boxes.len() / 2);
    let inputs = [
        oxray_core::CustomPrimitiveInput::new(oxray_core::AabbBuffer::new(a)).into(),
        oxray_core::CustomPrimitiveInput::new(oxray_core::AabbBuffer::new(b))
            .flags(&f)
            .sbt_index_offsets(SbtIndexOffsets::u32(&offsets))
            .primitive_index_offset(1000)
            .into(),
    ];
    for (name, flags, config) in PRESETS {
        let gas = device_gas(&ctx, &config, flags, &inputs);
        let host = oxray_bvh::GasData::build(&BuildOptions::new(flags), &inputs).unwrap();
        assert_eq!(gas.info().bounds, host.bounds, "{name}");
        assert_eq!(
            gas.info().num_active_primitives,
            host.num_active_primitives(),
            "{name}"
        );
        let back = gas.to_data().unwrap();
        let (got, _) = slotted_boxes(&gas);
        let mut want: Vec<(u32, [u32; 6])> = host
            .slot_prim
            .iter()
            .zip(&host.aabbs)
            .map(|(&g, b)| (g, bits(b)))
            .collect();
        want.sort_unstable();
        assert_eq!(
            got, want,
            "{name}: every valid box once, invalid ones left out"
        );
        // The resolution of a slot: input, primitive index with its offset, SBT-GAS index.
        let s = back.slot_prim.iter().position(|&g| g == 10_001).unwrap();
        assert_eq!(back.resolve(s as u32), (1001, 2, 1));
    }
}

/// The boxes of a custom-primitive GAS read back from the device, by primitive (slots that
/// hold one), as bits, and the structure's bounds.
fn slotted_boxes(gas: &CudaGas) -> (Vec<(u32, [u32; 6])>, oxray_core::Aabb) {
    let back = gas.to_data().unwrap();
    let mut got: Vec<(u32, [u32; 6])> = back
        .slot_prim
        .iter()
        .zip(&back.aabbs)
        .filter(|(&g, _)| g != oxray_bvh::NO_PRIMITIVE)
        .map(|(&g, b)| (g, bits(b)))
        .collect();
    got.sort_unstable();
    (got, back.bounds)
}

fn bits(b: &oxray_core::Aabb) -> [u32; 6] {
    [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z].map(f32::to_bits)
}

/// §5.6 on a structure the device built with `ALLOW_UPDATE`: inactive triangles keep slots
/// (found in the slot table read back), an update makes them active and others inactive, and
/// every state traces the oracle's hits and the distances of the CPU's update of the same
/// geometry.
#[test]
fn device_built_updatable_gases_refit_inactive_triangles_into_hits() {
    let Some((ctx, _lock)) = gpu() else { return };
    let mut rng = Rng::new(0x0BD7);
    for n in [1usize, 2, 7, 300, 20_000] {
        let base = random_soup(&mut rng, n, 10.0, 0.6);
        let mut tris = base.clone();
        // Every fifth triangle starts inactive (collapsed, or with a NaN).
        for (k, t) in tris.iter_mut().enumerate() {
            match k % 10 {
                0 => t[1] = t[0],
                5 => t[2][1] = f32::NAN,
                _ => {}
            }
        }
        let flags = BuildFlags::ALLOW_UPDATE | BuildFlags::ALLOW_COMPACTION;
        let config = DeviceBuildConfig::for_options(&BuildOptions::new(flags), n as u32);
        assert!(config.keep_inactive);
        let vertices = soup(&tris);
        let mut gas = device_gas(&ctx, &config, flags, &[soup_input(&vertices)]);
        let active = |tris: &[Tri]| {
            tris.iter()
                .filter(|t| {
                    !oxray_bvh::triangle::is_degenerate(t[0].into(), t[1].into(), t[2].into())
                })
                .count()
        };
        assert_eq!(gas.info().num_active_primitives as usize, active(&tris));
        let back = gas.to_data().unwrap();
        let mut kept: Vec<u32> = back
            .slot_prim
            .iter()
            .copied()
            .filter(|&g| g != oxray_bvh::NO_PRIMITIVE)
            .collect();
        kept.sort_unstable();
        assert_eq!(
            kept,
            (0..n as u32).collect::<Vec<_>>(),
            "{n}: a slot for every triangle"
        );
        let rays = random_rays(&mut rng, &base, 3000, 10.0);
        check_oracle(&gas, &tris, &rays, &format!("{n}: as built"));
        let mut cpu =
            oxray_cpu::Gas::build(&BuildOptions::new(flags), &[soup_input(&vertices)]).unwrap();
        // Round 1: every triangle active, moved a little; round 2: others inactive.
        for round in 1..=2 {
            tris = base.clone();
            for (k, t) in tris.iter_mut().enumerate() {
                for p in t.iter_mut() {
                    p[2] += 0.01 * round as f32 * (k % 3) as f32;
                }
                if round == 2 && k % 10 == 3 {
                    t[2] = t[1];
                }
            }
            let vertices = soup(&tris);
            let inputs = [soup_input(&vertices)];
            gas.update(&update(flags), &inputs).unwrap();
            cpu.update(&update(flags), &inputs).unwrap();
            let what = format!("{n}: update {round}");
            check_oracle(&gas, &tris, &rays, &what);
            let hits = gas.intersect_batch(&rays).unwrap();
            for (i, r) in rays.iter().enumerate() {
                let want = cpu.intersect(r).map(|h| h.t.to_bits());
                assert_eq!(hits[i].map(|h| h.t.to_bits()), want, "{what}: ray {i}");
            }
        }
        // Compaction keeps what an update needs.
        let mut compacted = gas.compact().unwrap();
        let vertices = soup(&base);
        compacted
            .update(&update(flags), &[soup_input(&vertices)])
            .unwrap();
        check_oracle(
            &compacted,
            &base,
            &rays,
            &format!("{n}: compacted, updated"),
        );
    }
}

fn box_input(b: &[oxray_core::Aabb]) -> BuildInput<'_> {
    oxray_core::CustomPrimitiveInput::new(oxray_core::AabbBuffer::new(b)).into()
}

/// The same for custom primitives: invalid boxes keep slots in an updatable device build and
/// an update makes them valid; the slots read back hold the new boxes.
#[test]
fn device_built_updatable_custom_primitives_take_new_boxes() {
    let Some((ctx, _lock)) = gpu() else { return };
    let mut rng = Rng::new(0xB0C5);
    let valid: Vec<oxray_core::Aabb> = (0..5000)
        .map(|_| {
            let c = rng.vec3(-10.0, 10.0);
            let e = rng.vec3(0.01, 0.3);
            oxray_core::Aabb::new(c - e, c + e)
        })
        .collect();
    let mut boxes = valid.clone();
    for b in boxes.iter_mut().step_by(7) {
        *b = oxray_core::Aabb::new(b.max, b.min);
    }
    let flags = BuildFlags::ALLOW_UPDATE;
    let config = DeviceBuildConfig::for_options(&BuildOptions::new(flags), 5000);
    let mut gas = device_gas(&ctx, &config, flags, &[box_input(&boxes)]);
    assert_eq!(gas.info().num_active_primitives, 5000 - 5000u32.div_ceil(7));
    let slots_of = slotted_boxes;
    let (got, _) = slots_of(&gas);
    assert_eq!(
        got.len(),
        5000,
        "a slot for every box, inactive ones included"
    );
    for (g, b) in &got {
        if g % 7 == 0 {
            assert_eq!(*b, bits(&oxray_core::Aabb::EMPTY), "box {g} is inactive");
        } else {
            assert_eq!(*b, bits(&valid[*g as usize]));
        }
    }
    gas.update(&update(flags), &[box_input(&valid)]).unwrap();
    let (got, bounds) = slots_of(&gas);
    let want: Vec<(u32, [u32; 6])> = (0..5000u32)
        .map(|g| (g, bits(&valid[g as usize])))
        .collect();
    assert_eq!(got, want, "every box active and updated");
    let host = oxray_bvh::GasData::build(&BuildOptions::default(), &[box_input(&valid)]).unwrap();
    assert_eq!(bounds, host.bounds);
}

/// §5.6 in the BVH4 node layout (the CPU's 4-wide nodes, byte for byte, built on the host):
/// refit on the device by its own node kernel, the updated structure traces the hits of the
/// CPU's update of the same build, ties included (both walk the same 4-wide tree in the same
/// order), through collapsed triangles becoming active and active ones collapsing.
#[test]
fn bvh4_layout_gases_refit_on_the_device_as_the_cpu_updates() {
    let Some((ctx, _lock)) = gpu() else { return };
    let cuda = Cuda::from_context(ctx).with_layout(oxray_cuda::NodeLayout::Bvh4);
    let base = grid_cube(12);
    let mut mesh = base.clone();
    for t in mesh.triangles.iter().step_by(9) {
        mesh.positions[t[1] as usize] = mesh.positions[t[0] as usize];
    }
    let flags = BuildFlags::ALLOW_UPDATE;
    let options = BuildOptions::new(flags);
    let input = |m: &Mesh| -> Vec<[f32; 3]> { m.positions.clone() };
    let positions = input(&mesh);
    let inputs = [TriangleInput::new(VertexBuffer::f32x3(&positions))
        .indices(IndexBuffer::u32x3(&mesh.triangles))
        .into()];
    let mut gas = cuda.build_gas(&options, &inputs).unwrap();
    assert_eq!(
        gas.builder(),
        GasBuilder::Host,
        "the BVH4 layout is built on the host"
    );
    let mut cpu = oxray_cpu::Gas::build_with_isa(oxray_cpu::Isa::Sse, &options, &inputs).unwrap();
    let mut rng = Rng::new(0xB4);
    let rays = random_rays(&mut rng, &base.soup(), 4000, 2.0);
    for round in 0..3 {
        if round > 0 {
            mesh.positions = base
                .positions
                .iter()
                .map(|p| {
                    let s = 1.0 + 0.05 * round as f32 * (p[0] * 3.0).sin();
                    [p[0] * s, p[1] * s, p[2] + 0.02 * round as f32]
                })
                .collect();
            // The other half of the collapsed triangles this time.
            for t in mesh.triangles.iter().skip(round).step_by(9) {
                mesh.positions[t[2] as usize] = mesh.positions[t[0] as usize];
            }
            let positions = input(&mesh);
            let inputs = [TriangleInput::new(VertexBuffer::f32x3(&positions))
                .indices(IndexBuffer::u32x3(&mesh.triangles))
                .into()];
            gas.update(&update(flags), &inputs).unwrap();
            cpu.update(&update(flags), &inputs).unwrap();
        }
        assert_eq!(gas.info().bounds, cpu.data().bounds, "round {round}");
        let hits = gas.intersect_batch(&rays).unwrap();
        let want: Vec<Option<Hit>> = rays.iter().map(|r| cpu.intersect(r)).collect();
        assert_eq!(hits, want, "round {round}: the CPU's update, ties included");
        check_oracle(&gas, &mesh.soup(), &rays, &format!("BVH4 round {round}"));
    }
}

/// Instances placed at random: translated, rotated, scaled (mirrored too), some of the null
/// handle (never hit).
fn random_instances(
    rng: &mut Rng,
    children: &[oxray_core::TraversableHandle],
    n: usize,
) -> Vec<oxray_core::Instance> {
    (0..n)
        .map(|k| {
            let child = if k % 23 == 5 {
                TraversableHandle::NULL
            } else {
                children[k % children.len()].clone()
            };
            let axis = rng.dir();
            let scale = rng.range(0.2, 1.5) * if k % 7 == 0 { -1.0 } else { 1.0 };
            let a = glam::Affine3A::from_scale_rotation_translation(
                glam::Vec3::splat(scale),
                glam::Quat::from_axis_angle(axis, rng.range(0.0, 6.0)),
                rng.vec3(-40.0, 40.0),
            );
            oxray_core::Instance::new(child)
                .transform(oxray_core::Transform::from_affine(&a))
                .instance_id(k as u32)
        })
        .collect()
}

/// IAS top-level trees built by the device's kernels (guide §5.4 builds, §5.6 updates): every
/// preset and flag, against the same instances built by the host's builder: the same
/// distances and instances for every ray, random instance access reaching every instance,
/// and an update and a compaction of the device-built IAS tracing as a new host build does.
#[test]
fn ias_trees_build_on_the_device_and_trace_as_host_built_ones() {
    let Some((ctx, _lock)) = gpu() else { return };
    let device = Cuda::from_context(ctx.clone());
    let host = Cuda::from_context(ctx).with_builder(GasBuilder::Host);
    let sphere = icosphere_f32(2);
    let cube = grid_cube(3);
    let gases: Vec<TraversableHandle> = [&sphere, &cube]
        .iter()
        .map(|m| {
            TraversableHandle::from(
                device
                    .build_gas(&BuildOptions::default(), &[mesh_input(m)])
                    .unwrap(),
            )
        })
        .collect();
    let mut rng = Rng::new(0x1A5);
    let closest = |cuda: &Cuda, ias: oxray_cuda::CudaIas, rays: &[Ray]| {
        let handle = TraversableHandle::from(ias);
        let mut hits = vec![None; rays.len()];
        cuda.intersect_closest(&handle, rays, &mut hits).unwrap();
        hits.iter()
            .map(|h| h.map(|h| (h.t.to_bits(), h.instance_index)))
            .collect::<Vec<_>>()
    };
    for n in [1usize, 2, 5, 300, 20_000] {
        let instances = random_instances(&mut rng, &gases, n);
        let input = [(&instances[..]).into()];
        let rays: Vec<Ray> = (0..4000)
            .map(|k| {
                let o = rng.vec3(-60.0, 60.0);
                let target = if k % 2 == 0 {
                    instances[rng.below(n)]
                        .transform
                        .transform_point(glam::Vec3::ZERO)
                } else {
                    rng.vec3(-40.0, 40.0)
                };
                Ray::new(o, target - o)
            })
            .collect();
        for flags in [
            BuildFlags::empty(),
            BuildFlags::PREFER_FAST_BUILD,
            BuildFlags::PREFER_FAST_TRACE | BuildFlags::ALLOW_COMPACTION,
            BuildFlags::ALLOW_UPDATE,
            BuildFlags::ALLOW_RANDOM_INSTANCE_ACCESS,
        ] {
            let options = BuildOptions::new(flags);
            let ias = device.build_ias(&options, &input).unwrap();
            assert_eq!(ias.builder(), GasBuilder::Device, "{n} {flags:?}");
            let reference = host.build_ias(&options, &input).unwrap();
            assert_eq!(reference.builder(), GasBuilder::Host);
            assert_eq!(ias.data().bounds, reference.data().bounds, "{n} {flags:?}");
            let mut slots = ias.data().slot_of.clone();
            slots.sort_unstable();
            slots.dedup();
            let kept = if flags
                .intersects(BuildFlags::ALLOW_UPDATE | BuildFlags::ALLOW_RANDOM_INSTANCE_ACCESS)
            {
                n
            } else {
                instances.iter().filter(|i| !i.child.is_null()).count()
            };
            assert_eq!(
                slots.iter().filter(|&&s| s != u32::MAX).count(),
                kept,
                "{n} {flags:?}: a slot for every instance that needs one"
            );
            let want = closest(&host, reference, &rays);
            if flags.contains(BuildFlags::ALLOW_COMPACTION) {
                let compacted = ias.compact().unwrap();
                assert_eq!(compacted.builder(), GasBuilder::Device);
                assert_eq!(closest(&device, compacted, &rays), want, "{n} compacted");
            }
            if flags.contains(BuildFlags::ALLOW_UPDATE) {
                let moved = random_instances(&mut rng, &gases, n);
                let moved_input = [(&moved[..]).into()];
                let mut ias = ias;
                ias.update(&update(flags), &moved_input).unwrap();
                let rebuilt = host.build_ias(&options, &moved_input).unwrap();
                assert_eq!(
                    closest(&device, ias, &rays),
                    closest(&host, rebuilt, &rays),
                    "{n}: the device-built IAS updated"
                );
            } else {
                assert_eq!(closest(&device, ias, &rays), want, "{n} {flags:?}");
            }
        }
    }
}
