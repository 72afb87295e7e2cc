//! Built-in curves through the device-neutral API (guide §5.2): built and traced on the CPU
//! device; refused with a typed `Unsupported` error by the CUDA device, which does not trace
//! them yet, after the same validation as every device (skipped without a GPU; set
//! `OXRAY_REQUIRE_GPU=1` to make a missing GPU a failure).

use glam::Vec3;
use oxray::{
    BuildError, BuildInputKind, BuildOptions, CurveInput, CurveType, Device, ErrorCode, HitKind,
    Ray,
};

/// One linear strand of two segments along +x at z = 5, radius 0.5.
const POINTS: [[f32; 3]; 3] = [[0.0, 0.0, 5.0], [2.0, 0.0, 5.0], [4.0, 0.0, 5.0]];
const RADII: [f32; 3] = [0.5; 3];
const INDEX: [u32; 2] = [0, 1];

fn input<'a>(v: &'a [&'a [u8]], r: &'a [&'a [u8]], index: &'a [u8]) -> CurveInput<'a> {
    CurveInput::new(CurveType::RoundLinear, v, 3, r, index, 2)
}

#[test]
fn s5_2_the_cpu_device_builds_and_traces_curves() {
    let (v, r) = (
        [bytemuck::cast_slice::<_, u8>(&POINTS)],
        [bytemuck::cast_slice::<_, u8>(&RADII)],
    );
    let device = Device::cpu();
    let gas = device
        .build_gas(
            &BuildOptions::default(),
            &[input(&v, &r, bytemuck::cast_slice(&INDEX)).into()],
        )
        .unwrap();
    assert_eq!(gas.kind(), BuildInputKind::Curves);
    let rays = [
        Ray::new(Vec3::new(1.0, 0.0, 0.0), Vec3::Z),
        Ray::new(Vec3::new(3.0, 0.0, 0.0), Vec3::Z),
        Ray::new(Vec3::new(1.0, 3.0, 0.0), Vec3::Z),
    ];
    let mut hits = [None; 3];
    device
        .intersect_closest(&gas.handle(), &rays, &mut hits)
        .unwrap();
    let kind = HitKind::curve(CurveType::RoundLinear, false);
    let h = hits.map(|h| h.map(|h| (h.primitive_index, h.t, h.u, h.hit_kind)));
    assert_eq!(
        h,
        [Some((0, 4.5, 0.5, kind)), Some((1, 4.5, 0.5, kind)), None]
    );
}

#[test]
fn s5_2_the_cuda_device_refuses_curves_with_unsupported() {
    let cuda = match Device::cuda(0) {
        Ok(d) => d,
        Err(e) => {
            assert!(
                std::env::var_os("OXRAY_REQUIRE_GPU").is_none(),
                "OXRAY_REQUIRE_GPU is set but CUDA is unavailable: {e}"
            );
            println!("no GPU ({e}): skipped");
            return;
        }
    };
    let (v, r) = (
        [bytemuck::cast_slice::<_, u8>(&POINTS)],
        [bytemuck::cast_slice::<_, u8>(&RADII)],
    );
    let index = bytemuck::cast_slice::<_, u8>(&INDEX);
    let err = cuda
        .build_gas(&BuildOptions::default(), &[input(&v, &r, index).into()])
        .err()
        .unwrap();
    assert!(matches!(err, BuildError::Unsupported(_)), "{err}");
    assert_eq!(err.code(), ErrorCode::NotSupported);
    // Bad input is reported as on the CPU, before the refusal.
    let short = [&r[0][..4]];
    let cpu = Device::cpu()
        .build_gas(&BuildOptions::default(), &[input(&v, &short, index).into()])
        .err()
        .unwrap();
    let gpu = cuda
        .build_gas(&BuildOptions::default(), &[input(&v, &short, index).into()])
        .err()
        .unwrap();
    assert_eq!(cpu, gpu);
    assert!(matches!(cpu, BuildError::BufferTooSmall { .. }));
}
