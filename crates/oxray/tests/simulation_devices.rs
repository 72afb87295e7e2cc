//! The simulation queries through the device-neutral API, on every device present: the CPU
//! always, and a CUDA device where there is one (skipped without a GPU; `OXRAY_REQUIRE_GPU=1`
//! makes a missing GPU a failure). Every primitive along a ray, hit counts, closest points and
//! signed distances depend on the surface, not on the tree: every device and every build
//! preset must give the CPU's default build's results bit for bit (the signs of signed
//! distances wherever the point is not on the surface), spatial splits (a triangle in several
//! leaves) and device-built trees included. Bad input gets the same typed error everywhere.

mod common;

use common::{devices, grid_cube, icosphere, name, random_soup, Mesh, Rng};
use glam::Vec3;
use oxray::{
    AabbBuffer, AllHits, BuildFlags, BuildOptions, ClosestPoint, CustomPrimitiveInput, Device, Gas,
    IndexBuffer, Instance, InstanceFlags, Ray, SphereInput, SurfaceHit, SurfaceQueryError,
    Transform, TriangleInput, VertexBuffer, VertexNormals,
};
use oxray_testkit::rays::{points_near, rays_around, rays_at_features};

/// The presets whose trees differ: the binned SAH, the fast builder, spatial splits, and the
/// updatable tree (inactive slots kept on the device).
const PRESETS: [BuildFlags; 4] = [
    BuildFlags::empty(),
    BuildFlags::PREFER_FAST_BUILD,
    BuildFlags::PREFER_FAST_TRACE,
    BuildFlags::ALLOW_UPDATE,
];

/// Every device, and every CUDA device again with the host's builder (uploaded trees: spatial
/// splits reach the device only that way).
fn all_devices() -> Vec<(String, Device)> {
    let mut out = Vec::new();
    for d in devices() {
        let n = name(&d).to_string();
        if d.kind() == oxray::BackendKind::Cuda {
            out.push((format!("{n} (host builds)"), d.clone().with_host_builds()));
        }
        out.push((n, d));
    }
    out
}

fn build(device: &Device, mesh: &Mesh, flags: BuildFlags) -> Gas {
    let input = TriangleInput::new(VertexBuffer::f32x3(&mesh.positions))
        .indices(IndexBuffer::u32x3(&mesh.triangles));
    device
        .build_gas(&BuildOptions::new(flags), &[input.into()])
        .unwrap_or_else(|e| panic!("{}: {e}", name(device)))
}

/// The test meshes: a closed sphere, a closed cube of grid faces (axis-aligned, shared edges
/// and vertices on the rays' paths) and an open soup of large overlapping triangles (where
/// spatial splits reference one triangle from several leaves).
fn meshes() -> Vec<(&'static str, Mesh)> {
    let mut rng = Rng::new(0x51a1);
    let soup = random_soup(&mut rng, 80, 4.0, 2.5);
    let positions: Vec<[f32; 3]> = soup.iter().flatten().copied().collect();
    let triangles = (0..soup.len() as u32)
        .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
        .collect();
    vec![
        ("icosphere", icosphere(3)),
        ("grid cube", grid_cube(6)),
        (
            "soup",
            Mesh {
                positions,
                triangles,
            },
        ),
    ]
}

/// Rays around the mesh, and rays aimed exactly at its vertices and edge midpoints (through
/// primitives that share them).
fn rays_for(mesh: &Mesh, seed: u64) -> Vec<Ray> {
    let mut rng = Rng::new(seed);
    let mut rays = rays_around(&mut rng, mesh, 400);
    rays.extend(rays_at_features(&mut rng, mesh, 200));
    rays
}

/// A GAS of spheres on `device`.
fn spheres(device: &Device, centres: &[[f32; 3]], radii: &[f32]) -> Gas {
    let (c, r) = (
        [bytemuck::cast_slice::<_, u8>(centres)],
        [bytemuck::cast_slice::<_, u8>(radii)],
    );
    device
        .build_gas(
            &BuildOptions::default(),
            &[SphereInput::new(&c, centres.len() as u32, &r).into()],
        )
        .unwrap_or_else(|e| panic!("{}: {e}", name(device)))
}

fn all_hits(gas: &Gas, rays: &[Ray], max: usize) -> AllHits {
    let mut out = AllHits::new();
    gas.all_hits_batch(rays, max, &mut out)
        .unwrap_or_else(|e| panic!("{e}"));
    out
}

#[test]
fn all_hits_and_counts_are_the_same_on_every_device_and_tree() {
    for (mesh_name, mesh) in meshes() {
        let rays = rays_for(&mesh, 7);
        let reference = build(&Device::cpu(), &mesh, BuildFlags::empty());
        let full = all_hits(&reference, &rays, usize::MAX);
        let bounded = all_hits(&reference, &rays, 2);
        assert!(
            (0..rays.len()).any(|i| full.hits(i).len() > 2),
            "{mesh_name}: some ray should cross more than two primitives"
        );
        for (dev_name, device) in all_devices() {
            for flags in PRESETS {
                let gas = build(&device, &mesh, flags);
                let at = format!("{mesh_name}, {dev_name}, {flags:?}");
                assert_eq!(all_hits(&gas, &rays, usize::MAX), full, "{at}: all hits");
                assert_eq!(all_hits(&gas, &rays, 2), bounded, "{at}: two nearest");
                let none = all_hits(&gas, &rays, 0);
                for i in 0..rays.len() {
                    assert!(none.hits(i).is_empty(), "{at}");
                    assert_eq!(none.is_complete(i), full.hits(i).is_empty(), "{at}");
                }
                let mut counts = vec![u32::MAX; rays.len()];
                gas.count_hits_batch(&rays, &mut counts)
                    .unwrap_or_else(|e| panic!("{at}: {e}"));
                for (i, &c) in counts.iter().enumerate() {
                    assert_eq!(c as usize, full.hits(i).len(), "{at}: count of ray {i}");
                }
            }
        }
    }
}

#[test]
fn all_hits_through_instances_are_the_same_on_every_device() {
    let sphere = icosphere(2);
    let cube = grid_cube(3);
    let placements = [
        Transform::IDENTITY,
        Transform::from_translation(Vec3::new(2.5, 0.0, 0.0)),
        Transform::from_affine(&glam::Affine3A::from_scale_rotation_translation(
            Vec3::new(1.0, 2.0, 0.5),
            glam::Quat::from_rotation_y(0.7),
            Vec3::new(-2.0, 1.0, 0.5),
        )),
        // Mirrored: the instance's triangles face the other way.
        Transform::from_affine(&glam::Affine3A::from_scale(Vec3::new(-1.0, 1.0, 1.0))),
    ];
    let mut rng = Rng::new(11);
    let scene = Mesh {
        positions: vec![[-4.0, -3.0, -3.0], [5.0, 4.0, 3.0]],
        triangles: vec![],
    };
    let rays = rays_around(&mut rng, &scene, 600);
    let mut reference: Option<(AllHits, Vec<u32>)> = None;
    for (dev_name, device) in all_devices() {
        let children = [
            build(&device, &sphere, BuildFlags::PREFER_FAST_TRACE),
            build(&device, &cube, BuildFlags::empty()),
        ];
        let instances: Vec<Instance> = placements
            .iter()
            .enumerate()
            .map(|(k, t)| {
                let mut inst = Instance::new(children[k % 2].handle())
                    .transform(*t)
                    .instance_id(100 + k as u32);
                if k == 2 {
                    inst = inst.flags(InstanceFlags::FLIP_TRIANGLE_FACING);
                }
                inst
            })
            .collect();
        let ias = device
            .build_ias(&BuildOptions::default(), &[(&instances[..]).into()])
            .unwrap_or_else(|e| panic!("{dev_name}: {e}"));
        let mut lists = AllHits::new();
        ias.all_hits_batch(&rays, usize::MAX, &mut lists)
            .unwrap_or_else(|e| panic!("{dev_name}: {e}"));
        let mut counts = vec![0u32; rays.len()];
        ias.count_hits_batch(&rays, &mut counts)
            .unwrap_or_else(|e| panic!("{dev_name}: {e}"));
        for (i, &c) in counts.iter().enumerate() {
            assert_eq!(c as usize, lists.hits(i).len(), "{dev_name}: ray {i}");
        }
        match &reference {
            None => {
                let instanced: std::collections::HashSet<u32> =
                    lists.all().iter().map(|h| h.instance_index).collect();
                assert_eq!(instanced.len(), placements.len(), "every instance is hit");
                reference = Some((lists, counts));
            }
            Some((l, c)) => {
                assert_eq!(&lists, l, "{dev_name}: lists");
                assert_eq!(&counts, c, "{dev_name}: counts");
            }
        }
    }
}

#[test]
fn spheres_and_custom_primitives_list_as_on_the_cpu() {
    let mut rng = Rng::new(5);
    let centres: Vec<[f32; 3]> = (0..60).map(|_| rng.vec3(-3.0, 3.0).to_array()).collect();
    let radii: Vec<f32> = (0..60).map(|_| rng.range(0.2, 0.9)).collect();
    let boxes: Vec<oxray::Aabb> = centres
        .iter()
        .zip(&radii)
        .map(|(c, r)| oxray::Aabb::new(Vec3::from(*c) - *r, Vec3::from(*c) + *r))
        .collect();
    let scene = Mesh {
        positions: vec![[-3.0; 3], [3.0; 3]],
        triangles: vec![],
    };
    let rays = rays_around(&mut rng, &scene, 500);
    let mut reference: Option<AllHits> = None;
    for (dev_name, device) in all_devices() {
        let spheres = spheres(&device, &centres, &radii);
        let lists = all_hits(&spheres, &rays, usize::MAX);
        let mut counts = vec![0u32; rays.len()];
        spheres.count_hits_batch(&rays, &mut counts).unwrap();
        for (i, &c) in counts.iter().enumerate() {
            assert_eq!(c as usize, lists.hits(i).len(), "{dev_name}: ray {i}");
        }
        match &reference {
            None => {
                assert!(lists.all().len() > rays.len(), "the cloud is crossed");
                reference = Some(lists);
            }
            Some(l) => assert_eq!(&lists, l, "{dev_name}: spheres"),
        }
        // Custom primitives are never hit by these queries (no intersection program runs).
        let custom = device
            .build_gas(
                &BuildOptions::default(),
                &[CustomPrimitiveInput::new(AabbBuffer::new(&boxes)).into()],
            )
            .unwrap_or_else(|e| panic!("{dev_name}: {e}"));
        let lists = all_hits(&custom, &rays, 4);
        assert!(lists.all().is_empty() && (0..rays.len()).all(|i| lists.is_complete(i)));
        let mut counts = vec![7u32; rays.len()];
        custom.count_hits_batch(&rays, &mut counts).unwrap();
        assert!(counts.iter().all(|&c| c == 0), "{dev_name}");
    }
}

#[test]
fn closest_points_and_signed_distances_are_the_same_on_every_device_and_tree() {
    for (mesh_name, mesh) in meshes() {
        let points = points_near(&mut Rng::new(3), &mesh, 500, 150);
        let reference = build(&Device::cpu(), &mesh, BuildFlags::empty());
        let mut want = vec![None; points.len()];
        reference.closest_point_batch(&points, &mut want).unwrap();
        let mut want_sd = vec![0.0f32; points.len()];
        reference
            .signed_distance_batch(&points, &mut want_sd)
            .unwrap();
        let closed = mesh_name != "soup";
        if closed {
            assert!(want_sd.iter().any(|&d| d < 0.0) && want_sd.iter().any(|&d| d > 0.0));
        }
        for (dev_name, device) in all_devices() {
            for flags in PRESETS {
                let gas = build(&device, &mesh, flags);
                let at = format!("{mesh_name}, {dev_name}, {flags:?}");
                let mut got: Vec<Option<ClosestPoint>> = vec![None; points.len()];
                gas.closest_point_batch(&points, &mut got)
                    .unwrap_or_else(|e| panic!("{at}: {e}"));
                for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                    assert_eq!(g, w, "{at}: point {i} {}", points[i]);
                }
                let mut sd = vec![0.0f32; points.len()];
                gas.signed_distance_batch(&points, &mut sd)
                    .unwrap_or_else(|e| panic!("{at}: {e}"));
                let mut inside = vec![false; points.len()];
                gas.contains_batch(&points, &mut inside)
                    .unwrap_or_else(|e| panic!("{at}: {e}"));
                for (i, (&g, &w)) in sd.iter().zip(&want_sd).enumerate() {
                    assert_eq!(g.abs(), w.abs(), "{at}: |signed distance| of point {i}");
                    // The pseudo-normal's angles may differ in the last bit between devices:
                    // a sign can only differ where the point is on the surface, within
                    // rounding of it.
                    if w.abs() > 1e-5 {
                        assert_eq!(g, w, "{at}: signed distance of point {i} {}", points[i]);
                        assert_eq!(inside[i], w < 0.0, "{at}: inside, point {i}");
                    }
                }
            }
        }
    }
}

#[test]
fn the_sign_is_the_inside_of_a_sphere_on_every_device() {
    // Points well away from the unit icosphere's surface: inside below 0.9, outside past 1.1
    // (the icosphere lies between the inscribed and the unit sphere).
    let mesh = icosphere(3);
    let mut rng = Rng::new(9);
    let points: Vec<Vec3> = (0..2000)
        .map(|_| rng.unit() * rng.range(0.0, 2.0))
        .filter(|p| (p.length() - 1.0).abs() > 0.1)
        .collect();
    for (dev_name, device) in all_devices() {
        let gas = build(&device, &mesh, BuildFlags::empty());
        let mut inside = vec![false; points.len()];
        gas.contains_batch(&points, &mut inside).unwrap();
        for (p, &i) in points.iter().zip(&inside) {
            assert_eq!(i, p.length() < 1.0, "{dev_name}: {p}");
        }
    }
}

#[test]
fn bad_input_gets_the_same_error_on_every_device() {
    let mesh = icosphere(1);
    let mut rays = vec![Ray::new(Vec3::new(0.1, 0.13, -3.0), Vec3::Z); 6];
    rays[4] = Ray::new(Vec3::new(0.0, 0.0, -3.0), Vec3::ZERO);
    rays[5] = Ray::new(Vec3::NAN, Vec3::Z);
    let points = [Vec3::ZERO, Vec3::new(0.0, f32::INFINITY, 0.0), Vec3::NAN];
    for (dev_name, device) in all_devices() {
        let gas = build(&device, &mesh, BuildFlags::empty());
        let mut counts = vec![99u32; rays.len()];
        let e = gas.count_hits_batch(&rays, &mut counts).unwrap_err();
        assert!(
            matches!(e, SurfaceQueryError::InvalidRay { index: 4, .. }),
            "{dev_name}: {e}"
        );
        assert_eq!(
            counts,
            [2, 2, 2, 2, 99, 99],
            "{dev_name}: the valid rays are counted"
        );
        let mut lists = AllHits::new();
        lists.push_ray(&[], true);
        let e = gas.all_hits_batch(&rays, 4, &mut lists).unwrap_err();
        assert!(
            matches!(e, SurfaceQueryError::InvalidRay { index: 4, .. }),
            "{dev_name}: {e}"
        );
        assert!(lists.is_empty(), "{dev_name}: nothing listed");
        let e = gas.count_hits_batch(&rays, &mut [0; 2]).unwrap_err();
        assert!(
            matches!(
                e,
                SurfaceQueryError::LengthMismatch {
                    queries: 6,
                    outputs: 2
                }
            ),
            "{dev_name}: {e}"
        );

        let mut closest = [None; 3];
        let e = gas.closest_point_batch(&points, &mut closest).unwrap_err();
        assert!(
            matches!(e, SurfaceQueryError::NonFinitePoint { index: 1, .. }),
            "{dev_name}: {e}"
        );
        assert!(closest[0].is_some_and(|c| c.distance > 0.9), "{dev_name}");
        let mut sd = [5.0f32; 3];
        let e = gas.signed_distance_batch(&points, &mut sd).unwrap_err();
        assert!(
            matches!(e, SurfaceQueryError::NonFinitePoint { index: 1, .. }),
            "{dev_name}: {e}"
        );
        assert!(
            sd[0] < -0.9 && sd[1] == 5.0 && sd[2] == 5.0,
            "{dev_name}: {sd:?}"
        );

        // Point queries need triangles.
        let e = spheres(&device, &[[0.0; 3]], &[1.0])
            .closest_point_batch(&[Vec3::ZERO], &mut [None])
            .unwrap_err();
        assert!(
            matches!(e, SurfaceQueryError::NotTriangles(_)),
            "{dev_name}: {e}"
        );
    }
}

#[test]
fn hit_surfaces_are_the_same_on_every_device() {
    let mesh = icosphere(3);
    // Vertex normals of the sphere (its positions), for the shading normal.
    let normals = mesh.positions.clone();
    let rays = rays_for(&mesh, 13);
    let mut reference: Option<Vec<Option<SurfaceHit>>> = None;
    for (dev_name, device) in all_devices() {
        for flags in [BuildFlags::empty(), BuildFlags::PREFER_FAST_TRACE] {
            let gas = build(&device, &mesh, flags);
            let mut hits = vec![None; rays.len()];
            gas.intersect_batch(&rays, &mut hits).unwrap();
            let shading = VertexNormals::new(&normals, &mesh.triangles).unwrap();
            let mut got = vec![None; rays.len()];
            gas.hit_surface_batch_shaded(&rays, &hits, &shading, &mut got)
                .unwrap_or_else(|e| panic!("{dev_name}: {e}"));
            for (i, (s, h)) in got.iter().zip(&hits).enumerate() {
                assert_eq!(s.is_some(), h.is_some(), "{dev_name}: ray {i}");
                if let (Some(s), Some(h)) = (s, h) {
                    assert!((s.point.length() - 1.0).abs() < 1e-2, "{dev_name}: {s:?}");
                    assert_eq!(
                        s.front_face,
                        s.geometric_normal.dot(rays[i].direction) < 0.0
                    );
                    assert_eq!(s.front_face, h.hit_kind.is_triangle_front_face());
                }
            }
            // Which of two primitives at one distance a tree reports differs (rays through
            // shared edges): compare where the hits are the same.
            match &reference {
                None => reference = Some(got),
                Some(want) => {
                    let mut cpu_hits = vec![None; rays.len()];
                    build(&Device::cpu(), &mesh, BuildFlags::empty())
                        .intersect_batch(&rays, &mut cpu_hits)
                        .unwrap();
                    for i in 0..rays.len() {
                        if hits[i] == cpu_hits[i] {
                            assert_eq!(got[i], want[i], "{dev_name}, {flags:?}: ray {i}");
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn hit_surfaces_through_instances_and_on_spheres_are_the_same_on_every_device() {
    let mesh = icosphere(2);
    let placements = [
        Transform::from_translation(Vec3::new(-1.5, 0.0, 0.0)),
        Transform::from_affine(&glam::Affine3A::from_scale_rotation_translation(
            Vec3::new(0.5, 1.5, 1.0),
            glam::Quat::from_rotation_z(0.4),
            Vec3::new(1.5, 0.0, 0.0),
        )),
    ];
    let scene = Mesh {
        positions: vec![[-3.0, -2.0, -2.0], [3.0, 2.0, 2.0]],
        triangles: vec![],
    };
    let rays = rays_around(&mut Rng::new(17), &scene, 400);
    let centres: Vec<[f32; 3]> = vec![[0.0, 0.0, 0.0], [1.0, 0.5, 0.0], [-1.0, 0.0, 0.5]];
    let radii = vec![0.6f32, 0.4, 0.5];
    type Surfaces = Vec<Option<SurfaceHit>>;
    let mut reference: Option<(Surfaces, Surfaces)> = None;
    for (dev_name, device) in all_devices() {
        let gas = build(&device, &mesh, BuildFlags::empty());
        let instances: Vec<Instance> = placements
            .iter()
            .enumerate()
            .map(|(k, t)| {
                Instance::new(gas.handle())
                    .transform(*t)
                    .instance_id(7 + k as u32)
            })
            .collect();
        let ias = device
            .build_ias(&BuildOptions::default(), &[(&instances[..]).into()])
            .unwrap();
        let mut hits = vec![None; rays.len()];
        ias.intersect_batch(&rays, &mut hits).unwrap();
        let mut through = vec![None; rays.len()];
        ias.hit_surface_batch(&rays, &hits, &mut through)
            .unwrap_or_else(|e| panic!("{dev_name}: {e}"));
        assert!(through.iter().flatten().count() > 50, "{dev_name}");

        let spheres = spheres(&device, &centres, &radii);
        let mut sphere_hits = vec![None; rays.len()];
        spheres.intersect_batch(&rays, &mut sphere_hits).unwrap();
        let mut on_spheres = vec![None; rays.len()];
        spheres
            .hit_surface_batch(&rays, &sphere_hits, &mut on_spheres)
            .unwrap_or_else(|e| panic!("{dev_name}: {e}"));
        for s in on_spheres.iter().flatten() {
            let d = centres
                .iter()
                .zip(&radii)
                .map(|(c, r)| ((s.point - Vec3::from(*c)).length() - r).abs())
                .fold(f32::INFINITY, f32::min);
            assert!(d < 1e-5, "{dev_name}: {s:?} is on no sphere");
        }
        match &reference {
            None => reference = Some((through, on_spheres)),
            Some((t, s)) => {
                assert_eq!(&through, t, "{dev_name}: through instances");
                assert_eq!(&on_spheres, s, "{dev_name}: on spheres");
            }
        }
    }
}

#[test]
fn a_hit_that_is_not_on_its_ray_is_not_found_on_every_device() {
    let mesh = icosphere(1);
    let ray = Ray::new(Vec3::new(0.1, 0.13, -3.0), Vec3::Z);
    for (dev_name, device) in all_devices() {
        let gas = build(&device, &mesh, BuildFlags::empty());
        let mut hits = vec![None; 3];
        let rays = [ray; 3];
        gas.intersect_batch(&rays, &mut hits).unwrap();
        let real = hits[0].unwrap();
        // Another primitive, and the right one at another distance.
        hits[1] = Some(oxray::Hit {
            primitive_index: (real.primitive_index + 1) % 80,
            ..real
        });
        hits[2] = Some(oxray::Hit {
            t: real.t * 0.5,
            ..real
        });
        let mut out = vec![None; 3];
        let e = gas.hit_surface_batch(&rays, &hits, &mut out).unwrap_err();
        assert!(
            matches!(e, SurfaceQueryError::HitNotFound { index: 1, .. }),
            "{dev_name}: {e}"
        );
        assert!(
            out[0].is_some() && out[1].is_none() && out[2].is_none(),
            "{dev_name}"
        );
        let e = gas
            .hit_surface_batch(&rays[..2], &hits, &mut out)
            .unwrap_err();
        assert!(
            matches!(
                e,
                SurfaceQueryError::LengthMismatch {
                    queries: 2,
                    outputs: 3
                }
            ),
            "{dev_name}: {e}"
        );
    }
}

#[test]
fn closest_points_through_instances_are_the_same_on_every_device() {
    let sphere = icosphere(2);
    let cube = grid_cube(3);
    let mut placements: Vec<Transform> = (0..6)
        .map(|i| {
            Transform::from_affine(&glam::Affine3A::from_scale_rotation_translation(
                Vec3::splat(0.5 + 0.3 * i as f32),
                glam::Quat::from_rotation_z(0.5 * i as f32),
                Vec3::new(3.0 * i as f32 - 7.0, (i % 2) as f32, 0.0),
            ))
        })
        .collect();
    // Two copies of one placement: equally close, the lower slot wins on every device.
    placements.extend([Transform::from_translation(Vec3::new(0.0, 4.0, 0.0)); 2]);
    let mut rng = Rng::new(23);
    let mut points: Vec<Vec3> = (0..300).map(|_| rng.vec3(-9.0, 9.0)).collect();
    points.push(Vec3::new(0.0, 4.0, 0.0));
    let mut reference: Option<Vec<Option<oxray::InstanceClosestPoint>>> = None;
    for (dev_name, device) in all_devices() {
        let children = [
            build(&device, &sphere, BuildFlags::empty()),
            build(&device, &cube, BuildFlags::PREFER_FAST_TRACE),
        ];
        let instances: Vec<Instance> = placements
            .iter()
            .enumerate()
            .map(|(k, t)| {
                Instance::new(children[if k >= 6 { 0 } else { k % 2 }].handle())
                    .transform(*t)
                    .instance_id(30 + k as u32)
            })
            .collect();
        let ias = device
            .build_ias(&BuildOptions::default(), &[(&instances[..]).into()])
            .unwrap();
        let mut got = vec![None; points.len()];
        ias.closest_point_batch(&points, &mut got)
            .unwrap_or_else(|e| panic!("{dev_name}: {e}"));
        assert!(got.iter().all(Option::is_some), "{dev_name}");
        match &reference {
            None => reference = Some(got),
            Some(want) => {
                for (i, (g, w)) in got.iter().zip(want).enumerate() {
                    assert_eq!(g, w, "{dev_name}: point {i} {}", points[i]);
                }
            }
        }
        // A stretched instance anywhere: refused whatever the point, on every device.
        let mut stretched = instances.clone();
        stretched.push(
            Instance::new(children[0].handle()).transform(Transform::from_affine(
                &glam::Affine3A::from_scale(Vec3::new(1.0, 3.0, 1.0)),
            )),
        );
        let ias = device
            .build_ias(&BuildOptions::default(), &[(&stretched[..]).into()])
            .unwrap();
        let e = ias
            .closest_point_batch(&points[..1], &mut [None])
            .unwrap_err();
        assert!(
            matches!(e, SurfaceQueryError::Unsupported(_)),
            "{dev_name}: {e}"
        );
    }
}
