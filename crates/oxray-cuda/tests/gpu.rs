//! GPU hits against CPU hits. Runs where a CUDA driver and device exist; elsewhere (CI) each test
//! prints why it skips and passes.

mod common;

use common::{
    bench_rays, build_gas_with_tree, find_mesh, icosphere_f32, load_obj, tricky_rays, Mesh,
};
use oxray_core::{BuildFlags, Hit, Ray};
use oxray_cpu::Gas;
use oxray_cuda::{
    CudaContext, CudaError, CudaGas, DeviceHits, DeviceOcclusion, DeviceRays, NodeLayout,
};
use std::sync::{Mutex, MutexGuard, OnceLock};

/// The shared context (NVRTC compiles the kernels once), with a lock that keeps GPU tests from
/// interleaving; `None` where this machine has no CUDA, unless `OXRAY_REQUIRE_GPU` is set (on a
/// GPU machine, so that a missing library fails the test instead of skipping it).
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

/// How GPU hits compare with CPU hits.
#[derive(Debug, Default)]
struct Agreement {
    rays: usize,
    /// Same hit, bit for bit (or both miss).
    identical: usize,
    /// Both hit at t within 1e-5 relative, on the same primitive or on another one at the same
    /// distance (a tie).
    agree: usize,
    ties: usize,
    occlusion_agree: usize,
}

impl Agreement {
    fn fraction(&self) -> f64 {
        self.agree as f64 / self.rays.max(1) as f64
    }
}

fn compare(gas: &Gas, gpu: &CudaGas, rays: &[Ray]) -> Agreement {
    let mut cpu = vec![None; rays.len()];
    gas.intersect_batch(rays, &mut cpu).unwrap();
    let mut cpu_occ = vec![false; rays.len()];
    gas.occluded_batch(rays, &mut cpu_occ).unwrap();
    let got = gpu.intersect_batch(rays).unwrap();
    let got_occ = gpu.occluded_batch(rays).unwrap();
    assert_eq!((got.len(), got_occ.len()), (rays.len(), rays.len()));
    let mut a = Agreement {
        rays: rays.len(),
        ..Default::default()
    };
    let mut printed = 0;
    let mut report = |i: usize, c: &Option<Hit>, g: &Option<Hit>| {
        if printed < 10 {
            println!("ray {i} {:?}: cpu {c:?} gpu {g:?}", rays[i]);
            printed += 1;
        }
    };
    for i in 0..rays.len() {
        if bits(&cpu[i]) == bits(&got[i]) {
            a.identical += 1;
        }
        match (&cpu[i], &got[i]) {
            (None, None) => a.agree += 1,
            (Some(c), Some(g)) => {
                if (c.t - g.t).abs() <= 1e-5 * c.t.abs() {
                    a.agree += 1;
                    if c.primitive_index != g.primitive_index {
                        a.ties += 1;
                    }
                } else {
                    report(i, &cpu[i], &got[i]);
                }
            }
            _ => report(i, &cpu[i], &got[i]),
        }
        if cpu_occ[i] == got_occ[i] {
            a.occlusion_agree += 1;
        }
    }
    a
}

fn bits(h: &Option<Hit>) -> Option<(u32, u32, u32, u32, u8)> {
    h.map(|h| {
        (
            h.t.to_bits(),
            h.u.to_bits(),
            h.v.to_bits(),
            h.primitive_index,
            h.hit_kind.0,
        )
    })
}

fn rays_for(mesh: &Mesh, gas: &Gas, side: u32) -> Vec<Ray> {
    let (mut rays, incoherent) = bench_rays(mesh, side);
    rays.extend(incoherent);
    rays.extend(tricky_rays(mesh, gas, (side * side) as usize, 3));
    rays
}

#[test]
fn icosphere_gpu_hits_match_cpu_hits() {
    let Some((ctx, _lock)) = gpu() else { return };
    println!("device: {:?}", ctx.device());
    let mesh = icosphere_f32(5);
    let (gas, tree) = build_gas_with_tree(&mesh, BuildFlags::PREFER_FAST_TRACE).unwrap();
    let rays = rays_for(&mesh, &gas, 256);
    for layout in [NodeLayout::Bvh4, NodeLayout::Bvh2] {
        let gpu = CudaGas::upload_with_layout(&ctx, &gas, &tree, layout).unwrap();
        let a = compare(&gas, &gpu, &rays);
        println!("icosphere {layout:?}: {a:?}");
        assert!(a.fraction() >= 0.9999, "{layout:?}: {a:?}");
        assert_eq!(a.occlusion_agree, a.rays, "{layout:?}: {a:?}");
        if layout == NodeLayout::Bvh4 {
            // Same nodes, same order, same arithmetic: the same hits, ties included.
            assert_eq!(a.identical, a.rays, "{a:?}");
        }
    }
}

#[test]
fn bunny_gpu_hits_match_cpu_hits() {
    let Some((ctx, _lock)) = gpu() else { return };
    let Some(path) = find_mesh("stanford-bunny.obj") else {
        println!("skipping: stanford-bunny.obj not found (set OXRAY_MESH_DIR)");
        return;
    };
    let mesh = load_obj(&path).unwrap();
    for flags in [BuildFlags::PREFER_FAST_TRACE, BuildFlags::PREFER_FAST_BUILD] {
        let (gas, tree) = build_gas_with_tree(&mesh, flags).unwrap();
        let rays = rays_for(&mesh, &gas, 512);
        for layout in [NodeLayout::Bvh4, NodeLayout::Bvh2] {
            let gpu = CudaGas::upload_with_layout(&ctx, &gas, &tree, layout).unwrap();
            let a = compare(&gas, &gpu, &rays);
            println!("bunny {flags:?} {layout:?}: {a:?}");
            assert!(a.fraction() >= 0.9999, "{layout:?}: {a:?}");
            assert_eq!(a.occlusion_agree, a.rays, "{layout:?}: {a:?}");
            if layout == NodeLayout::Bvh4 {
                assert_eq!(a.identical, a.rays, "{a:?}");
            }
        }
    }
}

#[test]
fn device_buffers_and_errors() {
    let Some((ctx, _lock)) = gpu() else { return };
    let mesh = icosphere_f32(2);
    let (gas, tree) = build_gas_with_tree(&mesh, BuildFlags::empty()).unwrap();
    let gpu = CudaGas::upload(&ctx, &gas, &tree).unwrap();
    assert!(gpu.device_bytes() > 0 && gpu.num_nodes() > 0);

    // Empty batches.
    assert!(gpu.intersect_batch(&[]).unwrap().is_empty());
    assert!(gpu.occluded_batch(&[]).unwrap().is_empty());

    // Device-resident rays, reused across launches, match the one-call API.
    let (rays, _) = bench_rays(&mesh, 32);
    let mut d_rays = DeviceRays::upload(&ctx, &rays).unwrap();
    let mut d_hits = DeviceHits::new(&ctx, rays.len()).unwrap();
    let mut d_occ = DeviceOcclusion::new(&ctx, rays.len()).unwrap();
    for _ in 0..2 {
        d_rays.write(&ctx, &rays).unwrap();
        gpu.intersect_device(&d_rays, &mut d_hits).unwrap();
        gpu.occluded_device(&d_rays, &mut d_occ).unwrap();
    }
    let records = d_hits.download(&ctx).unwrap();
    assert_eq!(gpu.resolve(&records), gpu.intersect_batch(&rays).unwrap());
    assert_eq!(
        d_occ.download(&ctx).unwrap(),
        gpu.occluded_batch(&rays).unwrap()
    );
    let mut cpu = vec![None; rays.len()];
    gas.intersect_batch(&rays, &mut cpu).unwrap();
    for (r, c) in records.iter().zip(&cpu) {
        assert_eq!(gpu.primitive_index(r), c.map(|h| h.primitive_index));
    }

    // The reused buffers grow and shrink with the batch.
    let big = bench_rays(&mesh, 200).1;
    for batch in [&rays[..5], &big[..], &rays[..], &big[..7]] {
        let mut cpu = vec![None; batch.len()];
        gas.intersect_batch(batch, &mut cpu).unwrap();
        assert_eq!(gpu.intersect_batch(batch).unwrap(), cpu);
        let mut occ = vec![false; batch.len()];
        gas.occluded_batch(batch, &mut occ).unwrap();
        let mut got = vec![true; batch.len()];
        gpu.occluded_batch_into(batch, &mut got).unwrap();
        assert_eq!(got, occ);
    }

    // Mismatched lengths are typed errors.
    let mut short = DeviceHits::new(&ctx, rays.len() - 1).unwrap();
    assert!(matches!(
        gpu.intersect_device(&d_rays, &mut short),
        Err(CudaError::LengthMismatch { .. })
    ));
    let mut out = vec![None; 3];
    assert!(matches!(
        gpu.intersect_batch_into(&rays, &mut out),
        Err(CudaError::LengthMismatch { .. })
    ));

    // A custom-primitive GAS is uploaded (for pipelines); the batched queries refuse it.
    let boxes = [oxray_core::Aabb::new(glam::Vec3::ZERO, glam::Vec3::ONE)];
    let input = oxray_core::CustomPrimitiveInput::new(oxray_core::AabbBuffer::new(&boxes));
    let (custom, custom_tree) =
        oxray_bvh::GasData::build_with_tree(&oxray_core::BuildOptions::default(), &[input.into()])
            .unwrap();
    let custom = CudaGas::upload(&ctx, &custom, &custom_tree).unwrap();
    assert_eq!(
        custom.intersect_batch(&rays).unwrap_err(),
        CudaError::CustomPrimitives
    );
    assert_eq!(
        custom.occluded_batch(&rays).unwrap_err(),
        CudaError::CustomPrimitives
    );
    assert!(custom.optix_handle().is_ok());
}
