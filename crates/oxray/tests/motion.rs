//! Motion through the facade (guide §5.10): a motion GAS and a motion transform built on the
//! CPU device, the emitted per-key boxes (§5.8), the memory query's bound, and the same boxes
//! from the CUDA device where one is present.

use glam::Vec3;
use oxray::{
    compute_memory_usage, AccelProperty, BuildOptions, Device, EmittedProperty, Instance,
    MatrixMotionTransform, MotionOptions, Ray, Transform, TraversableHandle, TriangleInput,
    VertexBuffer,
};

const K0: [[f32; 3]; 3] = [[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];

fn moved() -> [[f32; 3]; 3] {
    K0.map(|p| [p[0] + 10.0, p[1], p[2]])
}

#[test]
fn s5_10_2_a_motion_gas_on_the_cpu_device_emits_one_box_per_key() {
    let device = Device::cpu();
    let k1 = moved();
    let later = [VertexBuffer::f32x3(&k1)];
    let input = TriangleInput::new(VertexBuffer::f32x3(&K0)).motion_vertices(&later);
    let options = BuildOptions::default().with_motion(MotionOptions::new(2, 0.0, 1.0));
    let gas = device.build_gas(&options, &[input.into()]).unwrap();
    let EmittedProperty::Aabbs(boxes) = gas.emit_property(AccelProperty::Aabbs).unwrap() else {
        panic!("not boxes")
    };
    assert_eq!(boxes.len(), 2);
    assert_eq!((boxes[0].min.x, boxes[0].max.x), (-1.0, 1.0));
    assert_eq!((boxes[1].min.x, boxes[1].max.x), (9.0, 11.0));
    // The memory query bounds what the build keeps, later keys included.
    let sizes = compute_memory_usage(&options, &[input.into()]).unwrap();
    assert!(gas.memory().output_bytes <= sizes.output_size_in_bytes);
    // Traced through an instance over a matrix motion transform, at the ray's time.
    let keys = [
        Transform::IDENTITY,
        Transform::from_translation(Vec3::new(0.0, 4.0, 0.0)),
    ];
    let t: TraversableHandle =
        MatrixMotionTransform::new(gas.handle(), MotionOptions::new(2, 0.0, 1.0), &keys)
            .unwrap()
            .into();
    let ias = device
        .build_ias(
            &BuildOptions::default(),
            &[(&[Instance::new(t)][..]).into()],
        )
        .unwrap();
    let rays = [
        Ray::new(Vec3::new(5.0, 2.0, -5.0), Vec3::Z).with_time(0.5),
        Ray::new(Vec3::new(5.0, 0.0, -5.0), Vec3::Z).with_time(0.5),
    ];
    let mut hits = [None; 2];
    device
        .intersect_closest(&ias.handle(), &rays, &mut hits)
        .unwrap();
    assert_eq!(hits[0].map(|h| h.t), Some(5.0));
    assert!(hits[1].is_none());
}

#[test]
fn s5_10_2_the_cuda_device_builds_motion_and_emits_the_cpus_boxes_per_key() {
    let Ok(device) = Device::cuda(0) else {
        assert!(
            std::env::var_os("OXRAY_REQUIRE_GPU").is_none(),
            "OXRAY_REQUIRE_GPU is set but there is no CUDA device"
        );
        eprintln!("no CUDA device: the CUDA half is not exercised here");
        return;
    };
    let k1 = moved();
    let later = [VertexBuffer::f32x3(&k1)];
    let input = TriangleInput::new(VertexBuffer::f32x3(&K0)).motion_vertices(&later);
    let options = BuildOptions::default().with_motion(MotionOptions::new(2, 0.0, 1.0));
    let boxes = |d: &Device| {
        let gas = d.build_gas(&options, &[input.into()]).unwrap();
        match gas.emit_property(AccelProperty::Aabbs).unwrap() {
            EmittedProperty::Aabbs(b) => b,
            _ => panic!("not boxes"),
        }
    };
    let cuda = boxes(&device);
    assert_eq!(cuda.len(), 2);
    assert_eq!(cuda, boxes(&Device::cpu()));
    // Motion transforms under instances are built too (pipelines trace them at each ray's
    // time: motion_devices.rs).
    let still = device
        .build_gas(
            &BuildOptions::default(),
            &[TriangleInput::new(VertexBuffer::f32x3(&K0)).into()],
        )
        .unwrap();
    let t: TraversableHandle = MatrixMotionTransform::new(
        still.handle(),
        MotionOptions::new(2, 0.0, 1.0),
        &[Transform::IDENTITY; 2],
    )
    .unwrap()
    .into();
    device
        .build_ias(
            &BuildOptions::default(),
            &[(&[Instance::new(t)][..]).into()],
        )
        .unwrap();
}
