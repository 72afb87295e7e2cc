//! Built-in spheres through the device-neutral API (guide §5.3, §9.1, §9.4, §9.6, §13.2),
//! on every device present: the CPU always, and a CUDA device where there is one (skipped
//! without a GPU; set `OXRAY_REQUIRE_GPU=1` to make a missing GPU a failure). The batched
//! queries are checked against a brute force over every sphere with the same arithmetic, and
//! the pipeline scenarios run the same CUDA C++ programs (`conformance/spheres.cu`) on both
//! devices; where both exist, their results must agree bit for bit.

mod common;

use common::{name, on_every_device, Scene, ScenePrograms};
use glam::Vec3;
use oxray::{
    BuildInputKind, BuildOptions, Device, ExceptionCode, GeometryFlags, HitKind, Instance,
    LaunchReport, PrimitiveTypeFlags, Ray, RayFlags, SbtIndexOffsets, Sphere, SphereInput,
    Transform,
};
use oxray_testkit::rng::Rng;

const PROGRAMS: &str = include_str!("conformance/spheres.cu");

/// Spheres as the byte buffers of one motion key.
struct Cloud {
    centres: Vec<[f32; 3]>,
    radii: Vec<f32>,
}

impl Cloud {
    fn random(rng: &mut Rng, n: usize) -> Cloud {
        Cloud {
            centres: (0..n).map(|_| rng.vec3(-10.0, 10.0).to_array()).collect(),
            radii: (0..n).map(|_| rng.range(0.05, 0.8)).collect(),
        }
    }

    fn sphere(&self, i: usize) -> Sphere {
        Sphere::new(Vec3::from(self.centres[i]), self.radii[i])
    }

    fn build(&self, device: &Device) -> oxray::Gas {
        let (c, r) = (
            [bytemuck::cast_slice::<_, u8>(&self.centres)],
            [bytemuck::cast_slice::<_, u8>(&self.radii)],
        );
        let input = SphereInput::new(&c, self.centres.len() as u32, &r);
        device
            .build_gas(&BuildOptions::default(), &[input.into()])
            .unwrap_or_else(|e| panic!("{}: {e}", name(device)))
    }

    /// The closest front-face entry over every sphere, with the test every backend uses.
    fn brute_force(&self, ray: &Ray) -> Option<(f32, usize)> {
        let mut best: Option<(f32, usize)> = None;
        for i in 0..self.centres.len() {
            let tmax = best.map_or(ray.tmax, |b| b.0);
            if let Some(t) = self
                .sphere(i)
                .intersect(ray.origin, ray.direction, ray.tmin, tmax)
            {
                if best.is_none_or(|b| t < b.0) {
                    best = Some((t, i));
                }
            }
        }
        best
    }
}

/// Random rays through the cloud, half of them aimed at a silhouette.
fn rays(rng: &mut Rng, cloud: &Cloud, n: usize) -> Vec<Ray> {
    (0..n)
        .map(|k| {
            let o = rng.vec3(-14.0, 14.0);
            let d = if k % 2 == 0 {
                rng.dir()
            } else {
                let s = cloud.sphere(rng.below(cloud.centres.len()));
                let near = if k % 4 == 1 { 1e-5 } else { 2e-2 };
                let target = Vec3::from(s.center)
                    + rng.unit() * s.radius * rng.range(1.0 - near, 1.0 + near);
                (target - o) * rng.range(0.5, 2.0)
            };
            Ray::with_interval(o, d, 0.0, rng.range(5.0, 40.0))
        })
        .collect()
}

/// §9.4, §9.6: the batched closest and any-hit queries find the front-face entry of the
/// nearest sphere, as a brute force over every sphere finds it with the same test, bit for bit;
/// every device gives the same hits.
#[test]
fn s9_4_queries_find_the_nearest_entry_on_every_device() {
    let mut rng = Rng::new(0x9_4);
    let cloud = Cloud::random(&mut rng, 3000);
    let rays = rays(&mut rng, &cloud, 20_000);
    on_every_device(|device| {
        let gas = cloud.build(device);
        assert_eq!(gas.kind(), BuildInputKind::Spheres);
        let mut hits = vec![None; rays.len()];
        device
            .intersect_closest(&gas.handle(), &rays, &mut hits)
            .unwrap();
        let mut occluded = vec![false; rays.len()];
        device
            .intersect_any(&gas.handle(), &rays, &mut occluded)
            .unwrap();
        let mut found = 0;
        for ((ray, hit), occ) in rays.iter().zip(&hits).zip(&occluded) {
            let want = cloud.brute_force(ray);
            assert_eq!(
                hit.map(|h| h.t),
                want.map(|w| w.0),
                "{}: {ray:?}",
                name(device)
            );
            assert_eq!(*occ, want.is_some(), "{}: {ray:?}", name(device));
            if let (Some(h), Some((_, i))) = (hit, want) {
                found += 1;
                assert_eq!(h.hit_kind, HitKind::SPHERE_FRONT_FACE);
                assert_eq!((h.u, h.v), (0.0, 0.0), "spheres have no attributes (§13.4)");
                // Two spheres entered at the same t are a tie either may win.
                if h.primitive_index as usize != i {
                    let other = cloud.sphere(h.primitive_index as usize);
                    assert_eq!(other.entry(ray.origin, ray.direction), h.t);
                }
            }
        }
        assert!(found > 5000, "{found} hits");
        hits.iter()
            .map(|h| h.map(|h| (h.t.to_bits(), h.primitive_index, h.hit_kind)))
            .collect::<Vec<_>>()
    });
}

/// The programs of `spheres.cu`, for a [`Scene`].
const SPHERES: ScenePrograms = ScenePrograms {
    source: PROGRAMS,
    params: "sp",
    raygen: "__raygen__spheres",
    miss: "__miss__spheres",
    hit_groups: &[
        ("hg", "__closesthit__sphere", None),
        (
            "hg_skip_even",
            "__closesthit__sphere",
            Some("__anyhit__skip_even"),
        ),
    ],
};

impl Scene {
    /// A 24 x 8 launch over `handle`: the 8 words of every launch index and the report.
    fn run(
        &self,
        handle: u64,
        hit: &str,
        flags: RayFlags,
        mode: u32,
    ) -> (Vec<[u32; 8]>, LaunchReport) {
        let (w, h) = (24u32, 8u32);
        // Two hit-group records: the SBT-GAS indices 0 and 1 of the spheres' input.
        self.launch(&self.sbt(hit, 2), w, h, |out| Params {
            out,
            handle,
            width: w,
            height: h,
            z: 4.0,
            ray_flags: flags.bits(),
            mode,
            pad: 0,
        })
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    out: u64,
    handle: u64,
    width: u32,
    height: u32,
    z: f32,
    ray_flags: u32,
    mode: u32,
    pad: u32,
}

/// Four spheres, primitives 10..13: three in a row on the x axis and a small one inside the
/// third, nearer the rays' origins. Primitives 11 and 13 use the second SBT record, whose
/// geometry flags disable any-hit.
const SCENE: [[f32; 4]; 4] = [
    [-2.0, 0.0, 0.0, 0.8],
    [0.0, 0.0, 0.0, 0.6],
    [2.0, 0.0, 0.0, 0.9],
    [2.0, 0.0, 0.5, 0.3],
];

fn scene_gas(device: &Device) -> oxray::Gas {
    let centres: Vec<[f32; 3]> = SCENE.iter().map(|s| [s[0], s[1], s[2]]).collect();
    let radii: Vec<f32> = SCENE.iter().map(|s| s[3]).collect();
    let (c, r) = (
        [bytemuck::cast_slice::<_, u8>(&centres)],
        [bytemuck::cast_slice::<_, u8>(&radii)],
    );
    let flags = [GeometryFlags::empty(), GeometryFlags::DISABLE_ANYHIT];
    let offsets = [0u8, 1, 0, 1];
    let input = SphereInput::new(&c, 4, &r)
        .flags(&flags)
        .sbt_index_offsets(SbtIndexOffsets::u8(&offsets))
        .primitive_index_offset(10);
    device
        .build_gas(&BuildOptions::default(), &[input.into()])
        .unwrap_or_else(|e| panic!("{}: {e}", name(device)))
}

/// The pixel centre of launch index `i` of the 24 x 8 grid, in the rays' plane.
fn pixel(i: usize) -> (f32, f32) {
    let (x, y) = ((i % 24) as f32, (i / 24) as f32);
    (6.0 * (x + 0.5) / 24.0 - 3.0, 3.0 * (y + 0.5) / 8.0 - 1.5)
}

/// Which of `spheres` (object space, seen through `scale` and `shift` along z) a ray down -z
/// at (x, y) from z = 4 enters first, with its entry t; `skip` leaves spheres out.
fn expected(x: f32, y: f32, skip: impl Fn(usize) -> bool) -> Option<(usize, f32)> {
    let mut best: Option<(usize, f32)> = None;
    for (k, s) in SCENE.iter().enumerate() {
        let d2 = (x - s[0]).powi(2) + (y - s[1]).powi(2);
        if skip(k) || d2 >= s[3] * s[3] {
            continue;
        }
        let t = 4.0 - s[2] - (s[3] * s[3] - d2).sqrt();
        if best.is_none_or(|b| t < b.1) {
            best = Some((k, t));
        }
    }
    best
}

/// Whether a ray at (x, y) passes within `eps` of a silhouette (where f32 and the expectation
/// may disagree).
fn grazes(x: f32, y: f32) -> bool {
    SCENE.iter().any(|s| {
        let d = ((x - s[0]).powi(2) + (y - s[1]).powi(2)).sqrt();
        (d - s[3]).abs() < 1e-3
    })
}

/// §9.4, §13.5, §13.7: closest-hit programs see the sphere's primitive index, SBT-GAS index,
/// its front-face hit kind (0x8C, a sphere, not a triangle, no attributes) and its
/// object-space data; misses keep tmax. §13.2: an any-hit program that ignores a sphere lets
/// the one behind it (here inside it) be found, and geometry flags that disable any-hit skip
/// the program.
#[test]
fn s9_4_pipelines_hit_built_in_spheres_on_every_device() {
    on_every_device(|device| {
        let gas = scene_gas(device);
        let handle = gas.optix_handle().unwrap();
        let s = Scene::new(device, &SPHERES, PrimitiveTypeFlags::SPHERE);
        let (out, report) = s.run(handle, "hg", RayFlags::empty(), 0);
        assert_eq!(report.exceptions, 0, "{report:?}");
        let mut hits = 0;
        for (i, o) in out.iter().enumerate() {
            let (x, y) = pixel(i);
            if grazes(x, y) {
                continue;
            }
            match expected(x, y, |_| false) {
                Some((k, t)) => {
                    hits += 1;
                    assert_eq!(o[0], 1, "{}: ray {i} hits sphere {k}", name(device));
                    assert_eq!(
                        o[1],
                        (10 + k as u32) | ((k as u32 % 2) << 16) | (0xFF << 24)
                    );
                    // 0x8C, front face, a sphere, not a triangle, attribute 0 zero.
                    assert_eq!(o[2], 0x8C | 1 << 8 | 1 << 10, "{}", name(device));
                    assert!((f32::from_bits(o[3]) - t).abs() < 1e-4);
                    let data = [o[4], o[5], o[6], o[7]].map(f32::from_bits);
                    assert_eq!(data, SCENE[k], "optixGetSphereData");
                }
                None => {
                    assert_eq!(o[0], 0, "ray {i} misses");
                    assert_eq!(f32::from_bits(o[3]), 1e16);
                }
            }
        }
        assert!(hits > 20, "{hits}");
        // Any-hit ignores the even primitives (10, 12): the small sphere 13 inside 12 is found
        // through it, 10 is missed; 11 and 13 never call the program (DISABLE_ANYHIT).
        let (filtered, report) = s.run(handle, "hg_skip_even", RayFlags::empty(), 0);
        assert_eq!(report.exceptions, 0, "{report:?}");
        for (i, o) in filtered.iter().enumerate() {
            let (x, y) = pixel(i);
            if grazes(x, y) {
                continue;
            }
            let want = expected(x, y, |k| k % 2 == 0);
            assert_eq!(o[0] & 0xF, want.is_some() as u32, "ray {i}");
            if let Some((k, _)) = want {
                assert_eq!(o[1] & 0xFFFF, 10 + k as u32);
            }
            // One call per even sphere on the ray's line in front of the origin.
            let calls = [0, 2]
                .iter()
                .filter(|&&k| expected(x, y, |j| j != k).is_some())
                .count() as u32;
            assert_eq!(o[0] >> 4, calls, "ray {i}: any-hit calls");
        }
        // The ray flag overrides the program: no calls, the plain result.
        let (disabled, _) = s.run(handle, "hg_skip_even", RayFlags::DISABLE_ANYHIT, 0);
        assert_eq!(disabled, out);
        // CULL_DISABLED_ANYHIT removes the spheres whose any-hit is off (11, 13) altogether;
        // the triangle culling flags do not apply to spheres.
        let (culled, _) = s.run(handle, "hg_skip_even", RayFlags::CULL_DISABLED_ANYHIT, 0);
        for (i, o) in culled.iter().enumerate() {
            let (x, y) = pixel(i);
            if !grazes(x, y) {
                assert_eq!(o[0] & 0xF, 0, "ray {i}: every sphere culled or ignored");
            }
        }
        let (faces, _) = s.run(
            handle,
            "hg",
            RayFlags::CULL_BACK_FACING_TRIANGLES | RayFlags::CULL_FRONT_FACING_TRIANGLES,
            0,
        );
        assert_eq!(faces, out, "triangle culling leaves spheres alone");
        // §9.6: from the centre of a sphere, its surface is not hit (back faces are culled).
        let (inside, _) = s.run(handle, "hg", RayFlags::empty(), 1);
        assert!(inside.iter().all(|o| o[0] == 0), "no hit from inside");
        (out, filtered, culled, inside)
    });
}

/// §13.7, §9.4: under an instance (id 9, scaled by 2 and moved down z by 1), the hit reports
/// the instance id, t along the world ray, and the sphere's object-space data.
#[test]
fn s9_4_instanced_spheres_report_object_space_data() {
    on_every_device(|device| {
        let gas = scene_gas(device);
        let xform = Transform::from_affine(&glam::Affine3A::from_scale_rotation_translation(
            Vec3::splat(0.5),
            glam::Quat::IDENTITY,
            Vec3::new(0.0, 0.0, -1.0),
        ));
        let ias = device
            .build_ias(
                &BuildOptions::default(),
                &[(&[Instance::new(gas.handle()).instance_id(9).transform(xform)][..]).into()],
            )
            .unwrap();
        let s = Scene::new(device, &SPHERES, PrimitiveTypeFlags::SPHERE);
        let (out, report) = s.run(ias.optix_handle().unwrap(), "hg", RayFlags::empty(), 0);
        assert_eq!(report.exceptions, 0, "{report:?}");
        let mut hits = 0;
        for (i, o) in out.iter().enumerate() {
            let (x, y) = pixel(i);
            // World sphere k: centre 0.5 c + (0, 0, -1), radius 0.5 r.
            let (ox, oy) = (2.0 * x, 2.0 * y);
            if grazes(ox, oy) {
                continue;
            }
            match expected(ox, oy, |_| false) {
                Some((k, t_object)) => {
                    hits += 1;
                    assert_eq!(o[0], 1);
                    assert_eq!(o[1] >> 24, 9, "the instance id");
                    // Object-space t from z = 2 * (4 + 1) = 10; world t is half of it.
                    let t = 0.5 * (t_object + 6.0);
                    assert!((f32::from_bits(o[3]) - t).abs() < 1e-4, "{i}");
                    let data = [o[4], o[5], o[6], o[7]].map(f32::from_bits);
                    assert_eq!(data, SCENE[k], "object-space sphere data");
                }
                None => assert_eq!(o[0], 0),
            }
        }
        assert!(hits > 4, "{hits}");
        out
    });
}

/// §9.1: a pipeline whose primitive-type flags leave spheres out (the empty set means
/// triangles and custom primitives) raises UNSUPPORTED_PRIMITIVE_TYPE when a trace enters a
/// sphere GAS.
#[test]
fn s9_1_spheres_need_their_primitive_type_flag() {
    on_every_device(|device| {
        let gas = scene_gas(device);
        let handle = gas.optix_handle().unwrap();
        let mut codes = Vec::new();
        for types in [
            PrimitiveTypeFlags::empty(),
            PrimitiveTypeFlags::TRIANGLE | PrimitiveTypeFlags::CUSTOM,
        ] {
            let s = Scene::new(device, &SPHERES, types);
            let (_, report) = s.run(handle, "hg", RayFlags::empty(), 0);
            assert_eq!(report.exceptions, 24 * 8, "{}: {report:?}", name(device));
            let code = report.first_exceptions[0].1.code;
            assert_eq!(code, ExceptionCode::UNSUPPORTED_PRIMITIVE_TYPE);
            codes.push(code);
        }
        codes
    });
}

/// The sphere programs compile for the GPU with NVRTC, GPU or not (`OXRAY_REQUIRE_NVRTC=1`
/// makes a missing NVRTC a failure): the device header's sphere traversal compiles in CI.
#[test]
fn the_sphere_programs_compile_with_nvrtc() {
    use oxray::cuda::{CudaHitGroupDesc, CudaModule, CudaProgramGroup};
    let m = CudaModule::from_source(PROGRAMS);
    let groups = [
        CudaProgramGroup::raygen(&m, "__raygen__spheres"),
        CudaProgramGroup::miss(Some((&m, "__miss__spheres"))),
        CudaProgramGroup::hit_group(CudaHitGroupDesc {
            closest_hit: Some((&m, "__closesthit__sphere")),
            any_hit: Some((&m, "__anyhit__skip_even")),
            intersection: None,
        }),
    ]
    .map(Result::unwrap);
    common::assert_compiles_with_nvrtc("the sphere programs", &groups, PrimitiveTypeFlags::SPHERE);
}
