//! Built-in spheres through the device-neutral API (guide §5.3): built and traced on the CPU
//! device; refused with a typed `Unsupported` error by the CUDA device, which does not trace
//! them yet, after the same validation as every device (skipped without a GPU; set
//! `OXRAY_REQUIRE_GPU=1` to make a missing GPU a failure).

use glam::Vec3;
use oxray::{
    BuildError, BuildInputKind, BuildOptions, Device, ErrorCode, HitKind, Ray, SphereInput,
};

const CENTRES: [[f32; 3]; 2] = [[0.0, 0.0, 5.0], [2.0, 0.0, 5.0]];
const RADII: [f32; 2] = [1.0, 0.5];

fn input<'a>(c: &'a [&'a [u8]], r: &'a [&'a [u8]]) -> SphereInput<'a> {
    SphereInput::new(c, 2, r)
}

#[test]
fn s5_3_the_cpu_device_builds_and_traces_spheres() {
    let (c, r) = (
        [bytemuck::cast_slice::<_, u8>(&CENTRES)],
        [bytemuck::cast_slice::<_, u8>(&RADII)],
    );
    let device = Device::cpu();
    let gas = device
        .build_gas(&BuildOptions::default(), &[input(&c, &r).into()])
        .unwrap();
    assert_eq!(gas.kind(), BuildInputKind::Spheres);
    let rays = [
        Ray::new(Vec3::ZERO, Vec3::Z),
        Ray::new(Vec3::new(2.0, 0.0, 0.0), Vec3::Z),
        Ray::new(Vec3::new(4.0, 0.0, 0.0), Vec3::Z),
    ];
    let mut hits = [None; 3];
    device
        .intersect_closest(&gas.handle(), &rays, &mut hits)
        .unwrap();
    let h = hits.map(|h| h.map(|h| (h.primitive_index, h.t, h.hit_kind)));
    assert_eq!(
        h,
        [
            Some((0, 4.0, HitKind::SPHERE_FRONT_FACE)),
            Some((1, 4.5, HitKind::SPHERE_FRONT_FACE)),
            None
        ]
    );
}

#[test]
fn s5_3_the_cuda_device_refuses_spheres_with_unsupported() {
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
    let (c, r) = (
        [bytemuck::cast_slice::<_, u8>(&CENTRES)],
        [bytemuck::cast_slice::<_, u8>(&RADII)],
    );
    let err = cuda
        .build_gas(&BuildOptions::default(), &[input(&c, &r).into()])
        .err()
        .unwrap();
    assert!(matches!(err, BuildError::Unsupported(_)), "{err}");
    assert_eq!(err.code(), ErrorCode::NotSupported);
    // Bad input is reported as on the CPU, before the refusal.
    let short = [&r[0][..4]];
    let cpu = Device::cpu()
        .build_gas(&BuildOptions::default(), &[input(&c, &short).into()])
        .err()
        .unwrap();
    let gpu = cuda
        .build_gas(&BuildOptions::default(), &[input(&c, &short).into()])
        .err()
        .unwrap();
    assert_eq!(cpu, gpu);
    assert!(matches!(cpu, BuildError::BufferTooSmall { .. }));
}
