//! One host API over several backends: the same scenario through every `Device` this machine
//! has (the CPU always, CUDA where a driver and a GPU exist), which must agree bit for bit, and
//! the rules of the device boundary (names, foreign structures, resident batches, rays with a
//! time). Set `OXRAY_REQUIRE_GPU=1` to make a missing GPU a failure instead of a skip.

mod common;

use common::{devices, icosphere, Rng};
use glam::Vec3;
use oxray::{
    Aabb, BackendKind, BatchKind, BuildError, BuildFlags, BuildOptions, Device, DeviceError,
    ExceptionCode, Hit, IndexBuffer, Instance, QueryError, Ray, RayRecord, Traversable,
    TraversableHandle, TraversableKind, TriangleInput, VertexBuffer,
};
use std::sync::Arc;

/// Camera-like rays at a unit sphere from outside, plus rays from inside, random rays that miss,
/// and invalid rays (which miss on every device).
fn rays(n: usize) -> Vec<Ray> {
    let mut rng = Rng::new(7);
    let mut rays: Vec<Ray> = (0..n)
        .map(|i| match i % 4 {
            0 | 1 => {
                let o = rng.dir() * 3.0;
                let target = rng.vec3(-0.8, 0.8);
                Ray::new(o, target - o)
            }
            2 => Ray::new(rng.vec3(-0.3, 0.3), rng.dir()),
            _ => Ray::with_interval(rng.dir() * 3.0, rng.dir(), 0.0, rng.range(0.1, 5.0)),
        })
        .collect();
    rays.push(Ray::new(Vec3::NAN, Vec3::Z));
    rays.push(Ray::new(Vec3::ZERO, Vec3::ZERO));
    rays.push(Ray::with_interval(Vec3::splat(3.0), -Vec3::ONE, 2.0, 1.0));
    rays
}

fn sphere_input(mesh: &common::Mesh) -> oxray::BuildInput<'_> {
    TriangleInput::new(VertexBuffer::f32x3(&mesh.positions))
        .indices(IndexBuffer::u32x3(&mesh.triangles))
        .into()
}

#[test]
fn every_device_finds_the_same_hits_bit_for_bit() {
    let mesh = icosphere(4);
    let rays = rays(20_000);
    let mut reference: Option<(Vec<Option<Hit>>, Vec<bool>)> = None;
    for device in devices() {
        for flags in [
            BuildFlags::empty(),
            BuildFlags::PREFER_FAST_TRACE,
            BuildFlags::PREFER_FAST_BUILD,
        ] {
            let gas = device
                .build_gas(&BuildOptions::new(flags), &[sphere_input(&mesh)])
                .unwrap();
            assert_eq!(gas.device_kind(), device.kind());
            assert_eq!(gas.num_primitives(), mesh.triangles.len() as u32);
            let root = gas.handle();
            assert_eq!(root.backend(), Some(device.kind()));
            let mut hits = vec![None; rays.len()];
            device.intersect_closest(&root, &rays, &mut hits).unwrap();
            let mut occluded = vec![false; rays.len()];
            device.intersect_any(&root, &rays, &mut occluded).unwrap();
            // The last three rays are invalid: misses everywhere.
            assert!(hits[rays.len() - 3..].iter().all(Option::is_none));
            assert!(hits.iter().filter(|h| h.is_some()).count() > rays.len() / 3);
            for (h, o) in hits.iter().zip(&occluded) {
                assert_eq!(h.is_some(), *o);
            }
            match &reference {
                None => reference = Some((hits, occluded)),
                Some((want_hits, want_occ)) => {
                    // Distances, barycentrics and facing are bit-identical on every device and
                    // build preset (the presets change which of two tied primitives wins only).
                    for (i, (a, b)) in want_hits.iter().zip(&hits).enumerate() {
                        let bits = |h: &Option<Hit>| h.map(|h| (h.t.to_bits(), h.hit_kind));
                        assert_eq!(bits(a), bits(b), "ray {i} on {device:?} {flags:?}");
                    }
                    assert_eq!(want_occ, &occluded, "{device:?} {flags:?}");
                }
            }
        }
    }
}

#[test]
fn every_device_traces_one_level_of_instances_alike() {
    use oxray::{InstanceFlags, Transform};
    let sphere = icosphere(3);
    let mut rng = Rng::new(3);
    let rays: Vec<Ray> = (0..20_000)
        .map(|_| {
            let o = rng.vec3(-10.0, 10.0);
            Ray::new(o, rng.vec3(-5.0, 5.0) - o)
        })
        .collect();
    let mut reference: Option<(Vec<Option<Hit>>, Vec<bool>)> = None;
    for device in devices() {
        let gas = device
            .build_gas(&BuildOptions::default(), &[sphere_input(&sphere)])
            .unwrap();
        let mut rng = Rng::new(9);
        let instances: Vec<Instance> = (0..40)
            .map(|i| {
                let t = glam::Affine3A::from_scale_rotation_translation(
                    Vec3::new(
                        rng.range(0.5, 2.0),
                        rng.range(0.5, 2.0),
                        rng.range(0.5, 2.0),
                    ),
                    glam::Quat::from_axis_angle(rng.dir(), rng.range(0.0, 6.0)),
                    rng.vec3(-6.0, 6.0),
                );
                let inst = Instance::new(gas.handle())
                    .transform(Transform::from_affine(&t))
                    .instance_id(7 * i);
                if i % 3 == 0 {
                    inst.flags(InstanceFlags::FLIP_TRIANGLE_FACING)
                } else {
                    inst
                }
            })
            .collect();
        let ias = device
            .build_ias(&BuildOptions::default(), &[(&instances[..]).into()])
            .unwrap();
        assert_eq!(
            (ias.device_kind(), ias.num_instances()),
            (device.kind(), 40)
        );
        // Two levels build on every device (CUDA pipelines trace any graph); the batched
        // queries of the CUDA backend trace one level of instances and refuse deeper graphs.
        let top = [Instance::new(ias.handle())];
        let two = device
            .build_ias(&BuildOptions::default(), &[(&top[..]).into()])
            .unwrap();
        assert_eq!(two.graph_depth(), 3);
        let mut deep = vec![None; 4];
        let r = device.intersect_closest(&two.handle(), &rays[..4], &mut deep);
        match device.kind() {
            BackendKind::Cpu => assert!(r.is_ok()),
            _ => assert!(matches!(r, Err(QueryError::Unsupported(_))), "{r:?}"),
        }
        let mut hits = vec![None; rays.len()];
        device
            .intersect_closest(&ias.handle(), &rays, &mut hits)
            .unwrap();
        let mut occ = vec![false; rays.len()];
        device
            .intersect_any(&ias.handle(), &rays, &mut occ)
            .unwrap();
        assert!(hits.iter().filter(|h| h.is_some()).count() > 2_000);
        // Resident batches agree with the one-call queries.
        let mut batch = device.upload_rays(&rays, BatchKind::Closest).unwrap();
        device.trace_batch(&ias.handle(), &mut batch).unwrap();
        let mut again = vec![None; rays.len()];
        device.download_hits(&batch, &mut again).unwrap();
        assert_eq!(again, hits, "{device:?}");
        match &reference {
            None => reference = Some((hits, occ)),
            Some((want, want_occ)) => {
                assert_eq!(want_occ, &occ, "{device:?}");
                let mut ties = 0;
                for (a, b) in want.iter().zip(&hits) {
                    let (a, b) = (a.unwrap_or(dummy_hit()), b.unwrap_or(dummy_hit()));
                    assert_eq!(a.t.to_bits(), b.t.to_bits(), "{device:?}");
                    if a.instance_index == b.instance_index
                        && a.primitive_index == b.primitive_index
                    {
                        assert_eq!(a, b, "{device:?}");
                    } else {
                        ties += 1;
                    }
                }
                assert!(ties * 100 <= rays.len(), "{ties} ties on {device:?}");
            }
        }
    }
}

#[test]
fn resident_batches_give_the_results_of_the_one_call_queries() {
    let mesh = icosphere(3);
    let rays = rays(5_000);
    for device in devices() {
        let gas = device
            .build_gas(&BuildOptions::default(), &[sphere_input(&mesh)])
            .unwrap();
        let root = gas.handle();
        let mut want = vec![None; rays.len()];
        device.intersect_closest(&root, &rays, &mut want).unwrap();
        let mut batch = device.upload_rays(&rays, BatchKind::Closest).unwrap();
        assert_eq!(
            (batch.len(), batch.kind()),
            (rays.len(), BatchKind::Closest)
        );
        assert_eq!(batch.device_kind(), device.kind());
        device.trace_batch(&root, &mut batch).unwrap();
        device.trace_batch(&root, &mut batch).unwrap();
        let mut got = vec![None; rays.len()];
        device.download_hits(&batch, &mut got).unwrap();
        assert_eq!(got, want, "{device:?}");
        // The results of the other kind are not there.
        let mut occ = vec![false; rays.len()];
        assert!(matches!(
            device.download_occlusion(&batch, &mut occ),
            Err(QueryError::WrongBatchKind(_))
        ));
        let mut any = device.upload_rays(&rays, BatchKind::Any).unwrap();
        device.trace_batch(&root, &mut any).unwrap();
        device.download_occlusion(&any, &mut occ).unwrap();
        assert!(occ.iter().zip(&want).all(|(o, h)| *o == h.is_some()));
        // Outputs of the wrong length are refused.
        let mut short = vec![None; rays.len() - 1];
        assert!(matches!(
            device.download_hits(&batch, &mut short),
            Err(QueryError::LengthMismatch { .. })
        ));
        assert!(matches!(
            device.intersect_closest(&root, &rays, &mut short),
            Err(QueryError::LengthMismatch { .. })
        ));
    }
}

#[test]
fn the_null_handle_misses_on_every_device() {
    let rays = rays(100);
    for device in devices() {
        let mut hits = vec![Some(dummy_hit()); rays.len()];
        device
            .intersect_closest(&TraversableHandle::NULL, &rays, &mut hits)
            .unwrap();
        assert!(hits.iter().all(Option::is_none));
        let mut occ = vec![true; rays.len()];
        device
            .intersect_any(&TraversableHandle::NULL, &rays, &mut occ)
            .unwrap();
        assert!(occ.iter().all(|&o| !o));
    }
}

fn dummy_hit() -> Hit {
    Hit {
        t: 1.0,
        u: 0.0,
        v: 0.0,
        primitive_index: 0,
        sbt_gas_index: 0,
        build_input: 0,
        hit_kind: oxray::HitKind::TRIANGLE_FRONT_FACE,
        instance_id: 0,
        instance_index: 0,
    }
}

#[test]
fn device_names_are_parsed_and_a_missing_gpu_is_an_error_not_a_fallback() {
    assert_eq!(Device::from_name("cpu").unwrap().kind(), BackendKind::Cpu);
    assert_eq!(Device::from_name(" CPU ").unwrap().kind(), BackendKind::Cpu);
    assert_eq!(Device::default().kind(), BackendKind::Cpu);
    for bad in ["bogus", "cuda:x", ""] {
        assert!(matches!(
            Device::from_name(bad),
            Err(DeviceError::UnknownName(_))
        ));
    }
    match Device::from_name("cuda") {
        Ok(d) => assert_eq!(d.kind(), BackendKind::Cuda),
        Err(e) => {
            assert!(e.is_unavailable(), "{e}");
            assert!(e.to_string().contains("CUDA"), "{e}");
        }
    }
    // `auto` is a GPU where there is one, else the CPU; never an error.
    let auto = Device::from_name("auto").unwrap();
    assert!(matches!(auto.kind(), BackendKind::Cpu | BackendKind::Cuda));
    assert!(!auto.describe().is_empty());
}

/// A structure that claims to live on another backend: what the CPU device sees of a GPU
/// structure on a machine without one.
struct Elsewhere;

impl Traversable for Elsewhere {
    fn traversable_kind(&self) -> TraversableKind {
        TraversableKind::Gas
    }
    fn bounds(&self) -> Aabb {
        Aabb::new(Vec3::splat(-1.0), Vec3::splat(1.0))
    }
    fn graph_depth(&self) -> u32 {
        1
    }
    fn backend(&self) -> BackendKind {
        BackendKind::Cuda
    }
    fn describe(&self) -> String {
        "a structure on another device".into()
    }
}

#[test]
fn a_structure_of_another_device_is_refused_with_a_typed_error() {
    let foreign = TraversableHandle::from(Arc::new(Elsewhere));
    assert_eq!(foreign.backend(), Some(BackendKind::Cuda));
    let cpu = Device::cpu();
    let rays = [Ray::new(Vec3::Z * 3.0, -Vec3::Z)];
    let mut hits = [None];
    assert_eq!(
        cpu.intersect_closest(&foreign, &rays, &mut hits),
        Err(QueryError::ForeignTraversable {
            device: BackendKind::Cpu,
            found: BackendKind::Cuda
        })
    );
    // An IAS on the CPU cannot instance it.
    let instances = [
        Instance::new(TraversableHandle::NULL),
        Instance::new(foreign.clone()),
    ];
    let err = cpu
        .build_ias(&BuildOptions::default(), &[(&instances[..]).into()])
        .unwrap_err();
    assert_eq!(
        err,
        BuildError::ForeignTraversable {
            instance: 1,
            device: BackendKind::Cpu,
            found: BackendKind::Cuda
        }
    );
    assert!(err.to_string().contains("instance 1"), "{err}");
    // Nor can a static transform over it be traced on the CPU.
    let st = oxray::StaticTransform::new(foreign, oxray::Transform::IDENTITY).unwrap();
    let st = TraversableHandle::from(st);
    assert_eq!(st.backend(), Some(BackendKind::Cuda));
    assert!(matches!(
        cpu.intersect_closest(&st, &rays, &mut hits),
        Err(QueryError::ForeignTraversable { .. })
    ));
}

#[test]
fn s13_14_a_trace_of_another_devices_structure_raises_invalid_traversable() {
    use oxray::{
        DeviceContext, Module, Pipeline, PipelineCompileOptions, PipelineLinkOptions, ProgramGroup,
        SbtRegion, ShaderBindingTable, TraceRay,
    };
    #[derive(Clone)]
    struct Params {
        handle: TraversableHandle,
    }
    let module = Module::<Params>::new()
        .raygen("__raygen__main", |ctx| {
            let mut payload = [0u32; 1];
            let handle = ctx.params().handle.clone();
            ctx.trace(&TraceRay::new(&handle, Vec3::ZERO, Vec3::Z), &mut payload)
        })
        .unwrap()
        .miss("__miss__m", |_| Ok(()))
        .unwrap();
    let raygen = ProgramGroup::raygen(&module, "__raygen__main").unwrap();
    let miss = ProgramGroup::miss(Some((&module, "__miss__m"))).unwrap();
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &PipelineCompileOptions::default(),
        &PipelineLinkOptions::default(),
        &[raygen.clone(), miss.clone()],
    )
    .unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[raygen.pack_header()]),
        miss: SbtRegion::from_headers(&[miss.pack_header()]),
        ..Default::default()
    };
    let params = Params {
        handle: TraversableHandle::from(Arc::new(Elsewhere)),
    };
    let report = pipeline.launch(&params, &sbt, 2, 1, 1).unwrap();
    assert_eq!(report.exceptions, 2);
    assert_eq!(
        report.first_exceptions[0].1.code,
        ExceptionCode::TRAVERSAL_INVALID_TRAVERSABLE
    );
}

#[test]
fn the_facade_gas_reports_what_the_backend_built() {
    let mesh = icosphere(2);
    let device = Device::cpu();
    let gas = device
        .build_gas(
            &BuildOptions::new(BuildFlags::PREFER_FAST_TRACE),
            &[sphere_input(&mesh)],
        )
        .unwrap();
    let cpu = gas.as_cpu().expect("built on the CPU");
    assert_eq!(gas.stats(), cpu.stats());
    assert_eq!(gas.memory(), cpu.memory());
    assert_eq!(gas.bounds(), cpu.bounds);
    assert_eq!(gas.build_flags(), BuildFlags::PREFER_FAST_TRACE);
    assert_eq!(gas.num_sbt_records(), 1);
    assert_eq!(gas.num_build_inputs(), 1);
    // A handle refers to the backend's structure, whichever way it was made.
    let from_wrapper = TraversableHandle::from(gas.clone());
    let from_arc = TraversableHandle::from(Arc::new(gas.clone()));
    assert!(from_wrapper.same_as(&gas.handle()));
    assert!(from_arc.same_as(&gas.handle()));
    assert!(from_wrapper.downcast_ref::<oxray::cpu::Gas>().is_some());
    assert_eq!(from_wrapper.kind(), Some(TraversableKind::Gas));
    // Custom primitives build on every device (their intersection programs run in pipelines);
    // the CUDA backend's batched queries, which run no programs, refuse them with a typed error.
    let boxes = [Aabb::new(Vec3::ZERO, Vec3::ONE)];
    let input = oxray::CustomPrimitiveInput::new(oxray::AabbBuffer::new(&boxes));
    for device in devices() {
        let gas = device
            .build_gas(&BuildOptions::default(), &[input.into()])
            .unwrap();
        assert_eq!(gas.num_primitives(), 1);
        if device.kind() != BackendKind::Cpu {
            let mut hits = vec![None; 1];
            let rays = [Ray::new(Vec3::new(0.5, 0.5, 2.0), -Vec3::Z)];
            let r = device.intersect_closest(&gas.handle(), &rays, &mut hits);
            assert!(matches!(r, Err(QueryError::Unsupported(_))), "{r:?}");
        }
    }
}

#[test]
fn rays_carry_a_time_and_the_ray_file_record_keeps_its_32_bytes() {
    let r = Ray::new(Vec3::X, Vec3::Y).with_time(0.25);
    assert_eq!(r.time, 0.25);
    assert_eq!(Ray::new(Vec3::X, Vec3::Y).time, 0.0);
    assert_eq!(std::mem::size_of::<RayRecord>(), 32);
    let rec = RayRecord::from(r);
    assert_eq!(rec.origin, [1.0, 0.0, 0.0]);
    assert_eq!(rec.tmax, f32::INFINITY);
    // The file record has no time: a ray read back is at time 0.
    assert_eq!(Ray::from(rec), Ray::new(Vec3::X, Vec3::Y));
    // A time does not change a static structure's hits.
    let mesh = icosphere(2);
    let gas = Device::cpu()
        .build_gas(&BuildOptions::default(), &[sphere_input(&mesh)])
        .unwrap();
    let rays: Vec<Ray> = rays(1000);
    let timed: Vec<Ray> = rays.iter().map(|r| r.with_time(0.7)).collect();
    let (mut a, mut b) = (vec![None; rays.len()], vec![None; rays.len()]);
    gas.intersect_batch(&rays, &mut a).unwrap();
    gas.intersect_batch(&timed, &mut b).unwrap();
    assert_eq!(a, b);
}
