//! The life of an acceleration structure on every device: updates (guide §5.6), compaction
//! (§5.8) and saving and loading (beyond §5.7's relocation: a structure saved on one device
//! loads on the other). The CPU always runs; CUDA device 0 where there is one
//! (`OXRAY_REQUIRE_GPU=1` makes a missing GPU a failure).

mod common;

use common::{check_closest, devices, grid_cube, icosphere, name, Mesh, Rng};
use glam::{Affine3A, Quat, Vec3};
use oxray::{
    AabbBuffer, AccelProperty, BuildError, BuildFlags, BuildInput, BuildOperation, BuildOptions,
    CustomPrimitiveInput, Device, EmittedProperty, Gas, Hit, IndexBuffer, Instance, LoadError, Ray,
    SphereInput, Transform, TraversableHandle, TriangleInput, UpdateRule, VertexBuffer,
};
use oxray_testkit::mesh::deform;
use oxray_testkit::rays::rays_around as rays;

fn input(m: &Mesh) -> BuildInput<'_> {
    TriangleInput::new(VertexBuffer::f32x3(&m.positions))
        .indices(IndexBuffer::u32x3(&m.triangles))
        .into()
}

fn update(flags: BuildFlags) -> BuildOptions {
    BuildOptions {
        flags,
        operation: BuildOperation::Update,
        ..Default::default()
    }
}

/// `n` rays from random points at distance `from` of the origin towards random points of the
/// cube of half-side `half` around it.
fn rays_into_cube(rng: &mut Rng, n: usize, from: f32, half: f32) -> Vec<Ray> {
    (0..n)
        .map(|_| {
            let o = rng.dir() * from;
            Ray::new(o, (rng.vec3(-half, half) - o).normalize())
        })
        .collect()
}

fn closest(device: &Device, root: &TraversableHandle, rays: &[Ray]) -> Vec<Option<Hit>> {
    let mut hits = vec![None; rays.len()];
    device
        .intersect_closest(root, rays, &mut hits)
        .unwrap_or_else(|e| panic!("{}: {e}", name(device)));
    hits
}

/// The same closest hits: distances bit for bit, and the rest wherever the same primitive was
/// found (two layouts may report either of two primitives at exactly the same distance).
fn assert_same_hits(a: &[Option<Hit>], b: &[Option<Hit>], what: &str) {
    assert_eq!(a.len(), b.len());
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        match (x, y) {
            (None, None) => {}
            (Some(x), Some(y)) => {
                assert_eq!(
                    x.t.to_bits(),
                    y.t.to_bits(),
                    "{what}: ray {i}: {x:?} vs {y:?}"
                );
                if (x.primitive_index, x.instance_id) == (y.primitive_index, y.instance_id) {
                    assert_eq!(
                        (x.u.to_bits(), x.v.to_bits(), x.hit_kind, x.instance_index),
                        (y.u.to_bits(), y.v.to_bits(), y.hit_kind, y.instance_index),
                        "{what}: ray {i}"
                    );
                }
            }
            _ => panic!("{what}: ray {i}: {x:?} vs {y:?}"),
        }
    }
}

fn check_oracle(
    device: &Device,
    gas: &Gas,
    m: &Mesh,
    rays: &[Ray],
    what: &str,
) -> Vec<Option<Hit>> {
    let hits = closest(device, &gas.handle(), rays);
    let soup = m.soup();
    for (ray, hit) in rays.iter().zip(&hits) {
        if let Err(e) = check_closest(*hit, &soup, ray) {
            panic!("{} {what}: {e}", name(device));
        }
    }
    hits
}

#[test]
fn updated_triangle_gases_trace_the_new_geometry_on_every_device() {
    // §5.6: same topology, new vertices; degenerate triangles become inactive, inactive ones
    // come back; the hits are those of the new geometry, the same on every device.
    let base = grid_cube(10);
    let mut per_device: Vec<Vec<Vec<Option<Hit>>>> = Vec::new();
    for device in devices() {
        let mut rng = Rng::new(0x5_6);
        let mut m = base.clone();
        for t in m.triangles.iter().take(40).step_by(7) {
            m.positions[t[1] as usize] = m.positions[t[0] as usize];
        }
        let flags = BuildFlags::ALLOW_UPDATE;
        let mut gas = device
            .build_gas(&BuildOptions::new(flags), &[input(&m)])
            .unwrap();
        let mut rounds = vec![check_oracle(
            &device,
            &gas,
            &m,
            &rays(&mut rng, &m, 300),
            "build",
        )];
        for round in 1..=4 {
            deform(&mut rng, &base, &mut m, round);
            device
                .update_gas(&mut gas, &update(flags), &[input(&m)])
                .unwrap();
            let what = format!("update {round}");
            rounds.push(check_oracle(
                &device,
                &gas,
                &m,
                &rays(&mut rng, &m, 300),
                &what,
            ));
            let fresh = device
                .build_gas(&BuildOptions::new(flags), &[input(&m)])
                .unwrap();
            assert_eq!(gas.bounds(), fresh.bounds(), "{} {what}", name(&device));
        }
        per_device.push(rounds);
    }
    for other in &per_device[1..] {
        for (k, (a, b)) in per_device[0].iter().zip(other).enumerate() {
            assert_same_hits(a, b, &format!("round {k}, cpu vs cuda"));
        }
    }
}

#[test]
fn update_then_trace_equals_rebuild_then_trace() {
    // §5.6: an update gives the hits of a new build over the new data.
    let base = icosphere(3);
    for device in devices() {
        let mut rng = Rng::new(11);
        let mut m = base.clone();
        for flags in [
            BuildFlags::ALLOW_UPDATE,
            BuildFlags::ALLOW_UPDATE | BuildFlags::PREFER_FAST_TRACE,
            BuildFlags::ALLOW_UPDATE | BuildFlags::ALLOW_COMPACTION,
        ] {
            let mut gas = device
                .build_gas(&BuildOptions::new(flags), &[input(&m)])
                .unwrap();
            deform(&mut rng, &base, &mut m, 2);
            device
                .update_gas(&mut gas, &update(flags), &[input(&m)])
                .unwrap();
            let rebuilt = device
                .build_gas(&BuildOptions::default(), &[input(&m)])
                .unwrap();
            let r = rays(&mut rng, &m, 2000);
            let what = format!("{} {flags:?}", name(&device));
            assert_same_hits(
                &closest(&device, &gas.handle(), &r),
                &closest(&device, &rebuilt.handle(), &r),
                &what,
            );
        }
    }
}

#[test]
fn an_update_of_a_shared_structure_leaves_the_sharers_unchanged() {
    // The copy-on-write of `Device::update_gas`: a handle taken before keeps the old geometry.
    let base = icosphere(2);
    for device in devices() {
        let mut m = base.clone();
        let flags = BuildFlags::ALLOW_UPDATE;
        let mut gas = device
            .build_gas(&BuildOptions::new(flags), &[input(&m)])
            .unwrap();
        let old = gas.handle();
        let r = rays(&mut Rng::new(3), &m, 500);
        let before = closest(&device, &old, &r);
        for p in &mut m.positions {
            p[0] += 10.0;
        }
        device
            .update_gas(&mut gas, &update(flags), &[input(&m)])
            .unwrap();
        assert_eq!(closest(&device, &old, &r), before, "{}", name(&device));
        let moved = closest(&device, &gas.handle(), &r);
        assert!(
            moved.iter().filter(|h| h.is_some()).count()
                < before.iter().filter(|h| h.is_some()).count()
        );
        assert_eq!(gas.bounds().min.x, before_min_x(&base) + 10.0);
    }
}

fn before_min_x(m: &Mesh) -> f32 {
    m.bounds().0[0]
}

#[test]
fn update_rules_are_refused_alike_on_every_device() {
    // §5.6: the same typed errors on every device, and nothing changes.
    let m = icosphere(2);
    common::on_every_device(|device| {
        let flags = BuildFlags::ALLOW_UPDATE;
        let mut gas = device
            .build_gas(&BuildOptions::new(flags), &[input(&m)])
            .unwrap();
        let mut fixed = device
            .build_gas(&BuildOptions::default(), &[input(&m)])
            .unwrap();
        let fewer = Mesh {
            positions: m.positions.clone(),
            triangles: m.triangles[1..].to_vec(),
        };
        let errors = vec![
            device.update_gas(&mut gas, &BuildOptions::new(flags), &[input(&m)]),
            device.update_gas(&mut fixed, &update(BuildFlags::empty()), &[input(&m)]),
            device.update_gas(
                &mut gas,
                &update(flags | BuildFlags::PREFER_FAST_TRACE),
                &[input(&m)],
            ),
            device.update_gas(&mut gas, &update(flags), &[input(&fewer)]),
            device.update_gas(&mut gas, &update(flags), &[]),
        ];
        let rules: Vec<String> = errors
            .into_iter()
            .map(|e| match e {
                Err(BuildError::InvalidUpdate(rule)) => format!("{rule:?}"),
                other => panic!("{}: {other:?}", name(device)),
            })
            .collect();
        assert!(rules[0].starts_with(&format!("{:?}", UpdateRule::NotAnUpdate)));
        assert!(rules[1].starts_with(&format!("{:?}", UpdateRule::NotAllowed)));
        rules
    });
}

fn sphere_scene(rng: &mut Rng, n: usize) -> (Vec<[f32; 3]>, Vec<f32>) {
    let centers = (0..n).map(|_| rng.vec3(-4.0, 4.0).to_array()).collect();
    let radii = (0..n)
        .map(|i| {
            if i % 17 == 0 {
                -1.0
            } else {
                rng.range(0.05, 0.4)
            }
        })
        .collect();
    (centers, radii)
}

#[test]
fn updated_sphere_gases_agree_across_devices() {
    // §5.6 on built-in spheres: new centres and radii; a sphere without a positive radius is
    // inactive until an update gives it one.
    let mut rng = Rng::new(0x59);
    let (c0, r0) = sphere_scene(&mut rng, 3000);
    let (c1, mut r1) = sphere_scene(&mut rng, 3000);
    r1[0] = 0.3; // an inactive sphere comes back
    let r = rays_into_cube(&mut rng, 4000, 9.0, 4.0);
    let flags = BuildFlags::ALLOW_UPDATE;
    common::on_every_device(|device| {
        let bytes = |v: &[[f32; 3]]| bytemuck::cast_slice::<[f32; 3], u8>(v).to_vec();
        let (cb0, rb0) = (bytes(&c0), bytemuck::cast_slice::<f32, u8>(&r0).to_vec());
        let (vb0, rbs0) = ([&cb0[..]], [&rb0[..]]);
        let built = SphereInput::new(&vb0, c0.len() as u32, &rbs0);
        let mut gas = device
            .build_gas(&BuildOptions::new(flags), &[built.into()])
            .unwrap();
        let before = closest(device, &gas.handle(), &r);
        let (cb1, rb1) = (bytes(&c1), bytemuck::cast_slice::<f32, u8>(&r1).to_vec());
        let (vb1, rbs1) = ([&cb1[..]], [&rb1[..]]);
        let moved = SphereInput::new(&vb1, c1.len() as u32, &rbs1);
        device
            .update_gas(&mut gas, &update(flags), &[moved.into()])
            .unwrap();
        let after = closest(device, &gas.handle(), &r);
        let fresh = device
            .build_gas(&BuildOptions::new(flags), &[moved.into()])
            .unwrap();
        assert_same_hits(
            &after,
            &closest(device, &fresh.handle(), &r),
            "update vs build",
        );
        assert_eq!(gas.bounds(), fresh.bounds());
        (before, after)
    });
}

#[test]
fn updated_custom_primitive_gases_keep_every_box_on_every_device() {
    // §5.6 on custom primitives: new boxes, read back from the device into the CPU's layout.
    let mut rng = Rng::new(0xAB);
    let boxes = |rng: &mut Rng| -> Vec<oxray::Aabb> {
        (0..500)
            .map(|i| {
                let c = rng.vec3(-3.0, 3.0);
                let e = rng.vec3(0.01, 0.2);
                if i % 50 == 0 {
                    oxray::Aabb::new(c + e, c - e) // inverted: inactive
                } else {
                    oxray::Aabb::new(c - e, c + e)
                }
            })
            .collect()
    };
    let (b0, b1) = (boxes(&mut rng), boxes(&mut rng));
    let flags = BuildFlags::ALLOW_UPDATE;
    common::on_every_device(|device| {
        fn input(b: &[oxray::Aabb]) -> BuildInput<'_> {
            CustomPrimitiveInput::new(AabbBuffer::new(b)).into()
        }
        let mut gas = device
            .build_gas(&BuildOptions::new(flags), &[input(&b0)])
            .unwrap();
        device
            .update_gas(&mut gas, &update(flags), &[input(&b1)])
            .unwrap();
        let valid = b1
            .iter()
            .filter(|b| b.is_finite_valid())
            .fold(oxray::Aabb::EMPTY, |a, b| a.union(b));
        assert_eq!(gas.bounds(), valid, "{}", name(device));
        // Read back (on the GPU: from device memory) and loaded on the CPU, it holds the same
        // boxes, so it is the same structure whatever device updated it.
        let on_cpu = Device::cpu().load_gas(&gas.to_bytes().unwrap()).unwrap();
        let EmittedProperty::Aabbs(b) = on_cpu.emit_property(AccelProperty::Aabbs).unwrap() else {
            unreachable!()
        };
        (b, on_cpu.num_primitives())
    });
}

#[test]
fn updated_ias_follows_new_transforms_and_children_on_every_device() {
    // §5.6 on instances: new transforms; a child updated by copy-on-write is taken by the IAS
    // update; the hits are those of an IAS built over the new data.
    let base = icosphere(2);
    let flags = BuildFlags::ALLOW_UPDATE;
    let place = |rng: &mut Rng, n: usize| -> Vec<Affine3A> {
        (0..n)
            .map(|_| {
                Affine3A::from_scale_rotation_translation(
                    Vec3::splat(rng.range(0.3, 1.0)),
                    Quat::from_axis_angle(rng.dir(), rng.range(0.0, 6.0)),
                    rng.vec3(-6.0, 6.0),
                )
            })
            .collect()
    };
    let instances = |gas: &Gas, at: &[Affine3A]| -> Vec<Instance> {
        at.iter()
            .enumerate()
            .map(|(i, a)| {
                Instance::new(gas.handle())
                    .transform(Transform::from_affine(a))
                    .instance_id(i as u32)
            })
            .collect()
    };
    common::on_every_device(|device| {
        let mut rng = Rng::new(21);
        let mut m = base.clone();
        let mut gas = device
            .build_gas(&BuildOptions::new(flags), &[input(&m)])
            .unwrap();
        let a0 = place(&mut rng, 24);
        let insts = instances(&gas, &a0);
        let mut ias = device
            .build_ias(&BuildOptions::new(flags), &[(&insts[..]).into()])
            .unwrap();
        let r = rays_into_cube(&mut rng, 3000, 12.0, 6.0);
        // New transforms.
        let a1 = place(&mut rng, 24);
        let insts = instances(&gas, &a1);
        device
            .update_ias(&mut ias, &update(flags), &[(&insts[..]).into()])
            .unwrap();
        let fresh = device
            .build_ias(&BuildOptions::default(), &[(&insts[..]).into()])
            .unwrap();
        let moved = closest(device, &ias.handle(), &r);
        assert_same_hits(
            &moved,
            &closest(device, &fresh.handle(), &r),
            "new transforms",
        );
        // An updated child (a copy: the IAS shares the old one), then the IAS over it.
        deform(&mut rng, &base, &mut m, 3);
        device
            .update_gas(&mut gas, &update(flags), &[input(&m)])
            .unwrap();
        let insts = instances(&gas, &a1);
        device
            .update_ias(&mut ias, &update(flags), &[(&insts[..]).into()])
            .unwrap();
        let fresh = device
            .build_ias(&BuildOptions::default(), &[(&insts[..]).into()])
            .unwrap();
        let deformed = closest(device, &ias.handle(), &r);
        assert_same_hits(
            &deformed,
            &closest(device, &fresh.handle(), &r),
            "updated child",
        );
        assert_eq!(ias.bounds(), fresh.bounds());
        (moved, deformed)
    });
}

#[test]
fn compaction_keeps_the_hits_and_reports_its_size_on_every_device() {
    // §5.8: COMPACTED_SIZE is emitted for ALLOW_COMPACTION builds only; the compacted structure
    // has that size and the same hits, and is independent of the source.
    let m = icosphere(4);
    let r = rays(&mut Rng::new(5), &m, 3000);
    common::on_every_device(|device| {
        let plain = device
            .build_gas(&BuildOptions::default(), &[input(&m)])
            .unwrap();
        assert_eq!(
            plain.emit_property(AccelProperty::CompactedSize),
            Err(BuildError::CompactionNotAllowed)
        );
        assert!(device.compact_gas(&plain).is_err());
        let mut sizes = Vec::new();
        for flags in [
            BuildFlags::ALLOW_COMPACTION,
            BuildFlags::ALLOW_COMPACTION | BuildFlags::ALLOW_UPDATE,
            BuildFlags::ALLOW_COMPACTION | BuildFlags::PREFER_FAST_BUILD,
        ] {
            let gas = device
                .build_gas(&BuildOptions::new(flags), &[input(&m)])
                .unwrap();
            let EmittedProperty::CompactedSize(size) =
                gas.emit_property(AccelProperty::CompactedSize).unwrap()
            else {
                unreachable!()
            };
            assert!(size as usize <= gas.memory().output_bytes);
            let compact = device.compact_gas(&gas).unwrap();
            drop(gas);
            assert_eq!(compact.memory().output_bytes as u64, size);
            let per_triangle = size as f64 / m.triangles.len() as f64;
            assert!(
                per_triangle <= 100.0,
                "{} {flags:?}: {per_triangle} B/triangle",
                name(device)
            );
            let hits = closest(device, &compact.handle(), &r);
            let reference = closest(device, &plain.handle(), &r);
            assert_same_hits(&hits, &reference, "compacted");
            sizes.push(per_triangle > 0.0);
        }
        // An IAS too.
        let insts = vec![Instance::new(plain.handle()); 3];
        let opts = BuildOptions::new(BuildFlags::ALLOW_COMPACTION);
        let ias = device.build_ias(&opts, &[(&insts[..]).into()]).unwrap();
        let EmittedProperty::CompactedSize(_) =
            ias.emit_property(AccelProperty::CompactedSize).unwrap()
        else {
            unreachable!()
        };
        let compact = device.compact_ias(&ias).unwrap();
        assert_same_hits(
            &closest(device, &compact.handle(), &r),
            &closest(device, &ias.handle(), &r),
            "compacted IAS",
        );
        sizes
    });
}

#[test]
fn saved_structures_load_on_every_device_with_the_same_hits() {
    // Beyond §5.7: a GAS or IAS saved on any device loads on any device and traces the same
    // hits; a loaded updatable structure updates on the device it was loaded on.
    let base = icosphere(4);
    let r = rays(&mut Rng::new(9), &base, 4000);
    let devices = devices();
    for src in &devices {
        for flags in [
            BuildFlags::empty(),
            BuildFlags::PREFER_FAST_TRACE,
            BuildFlags::PREFER_FAST_BUILD,
            BuildFlags::ALLOW_UPDATE,
        ] {
            let gas = src
                .build_gas(&BuildOptions::new(flags), &[input(&base)])
                .unwrap();
            let hits = closest(src, &gas.handle(), &r);
            let bytes = gas.to_bytes().unwrap();
            let insts: Vec<Instance> = (0..5)
                .map(|i| {
                    Instance::new(gas.handle())
                        .transform(Transform::from_translation(Vec3::new(
                            3.0 * i as f32,
                            0.0,
                            0.0,
                        )))
                        .instance_id(i)
                })
                .collect();
            let ias = src
                .build_ias(&BuildOptions::default(), &[(&insts[..]).into()])
                .unwrap();
            let ias_hits = closest(src, &ias.handle(), &r);
            let ias_bytes = ias.to_bytes().unwrap();
            for dst in &devices {
                let what = format!("{flags:?} saved on {} loaded on {}", name(src), name(dst));
                let mut loaded = dst
                    .load_gas(&bytes)
                    .unwrap_or_else(|e| panic!("{what}: {e}"));
                assert_eq!(loaded.device_kind(), dst.kind());
                assert_eq!(loaded.bounds(), gas.bounds(), "{what}");
                assert_same_hits(&hits, &closest(dst, &loaded.handle(), &r), &what);
                let children = vec![loaded.handle(); 5];
                let lias = dst.load_ias(&ias_bytes, &children).unwrap();
                assert_same_hits(&ias_hits, &closest(dst, &lias.handle(), &r), &what);
                if flags.contains(BuildFlags::ALLOW_UPDATE) {
                    let mut m = base.clone();
                    deform(&mut Rng::new(4), &base, &mut m, 2);
                    dst.update_gas(&mut loaded, &update(flags), &[input(&m)])
                        .unwrap();
                    check_oracle(dst, &loaded, &m, &r[..500], &what);
                }
            }
        }
    }
}

#[test]
fn saved_spheres_and_boxes_load_on_every_device() {
    let mut rng = Rng::new(77);
    let (c, rad) = sphere_scene(&mut rng, 800);
    let cb = bytemuck::cast_slice::<[f32; 3], u8>(&c).to_vec();
    let rb = bytemuck::cast_slice::<f32, u8>(&rad).to_vec();
    let (vb, rbs) = ([&cb[..]], [&rb[..]]);
    let r = rays_into_cube(&mut rng, 3000, 9.0, 4.0);
    let devices = devices();
    for src in &devices {
        let spheres = SphereInput::new(&vb, c.len() as u32, &rbs);
        let gas = src
            .build_gas(&BuildOptions::default(), &[spheres.into()])
            .unwrap();
        let hits = closest(src, &gas.handle(), &r);
        let bytes = gas.to_bytes().unwrap();
        for dst in &devices {
            let loaded = dst.load_gas(&bytes).unwrap();
            let what = format!("spheres from {} on {}", name(src), name(dst));
            assert_same_hits(&hits, &closest(dst, &loaded.handle(), &r), &what);
        }
        let boxes: Vec<oxray::Aabb> = c
            .iter()
            .map(|p| oxray::Aabb::new(Vec3::from(*p) - 0.1, Vec3::from(*p) + 0.1))
            .collect();
        let custom = CustomPrimitiveInput::new(AabbBuffer::new(&boxes));
        let gas = src
            .build_gas(&BuildOptions::default(), &[custom.into()])
            .unwrap();
        let bytes = gas.to_bytes().unwrap();
        for dst in &devices {
            let loaded = dst.load_gas(&bytes).unwrap();
            assert_eq!(loaded.bounds(), gas.bounds());
            assert_eq!(loaded.num_primitives(), gas.num_primitives());
        }
    }
}

#[test]
fn damaged_saved_bytes_are_refused_on_every_device() {
    let m = icosphere(2);
    let bytes = Device::cpu()
        .build_gas(&BuildOptions::default(), &[input(&m)])
        .unwrap()
        .to_bytes()
        .unwrap();
    for device in devices() {
        let mut bad = bytes.clone();
        let at = bad.len() / 2;
        bad[at] ^= 0x40;
        assert!(
            matches!(device.load_gas(&bad), Err(LoadError::Checksum { .. })),
            "{}",
            name(&device)
        );
        assert!(device.load_gas(&bytes[..bytes.len() - 7]).is_err());
        assert!(device.load_gas(&[]).is_err());
    }
}
