//! Built-in curves through the device-neutral API (guide §5.2, §9.1, §9.3, §9.6, §13.2), on
//! every device present: the CPU always, and a CUDA device where there is one (skipped without
//! a GPU; set `OXRAY_REQUIRE_GPU=1` to make a missing GPU a failure). The batched queries are
//! checked against a brute force over every segment with the intersector every backend uses,
//! and the pipeline scenarios run the same CUDA C++ programs (`conformance/curves.cu`) on both
//! devices; where both exist, their results must agree bit for bit.

mod common;

use common::{name, on_every_device, Scene, ScenePrograms};
use glam::Vec3;
use oxray::bvh::GasData;
use oxray::{
    BuildError, BuildInputKind, BuildOptions, CurveEndcaps, CurveInput, CurveType, Device,
    ExceptionCode, HitKind, LaunchReport, PrimitiveTypeFlags, Ray, RayFlags,
};
use oxray_testkit::rng::Rng;

const PROGRAMS: &str = include_str!("conformance/curves.cu");

/// One linear strand of two segments along +x at z = 5, radius 0.5.
const POINTS: [[f32; 3]; 3] = [[0.0, 0.0, 5.0], [2.0, 0.0, 5.0], [4.0, 0.0, 5.0]];
const RADII: [f32; 3] = [0.5; 3];
const INDEX: [u32; 2] = [0, 1];

fn input<'a>(v: &'a [&'a [u8]], r: &'a [&'a [u8]], index: &'a [u8]) -> CurveInput<'a> {
    CurveInput::new(CurveType::RoundLinear, v, 3, r, index, 2)
}

/// §5.2: every device builds and traces a linear strand, with the curve's hit kind and u.
#[test]
fn s5_2_every_device_builds_and_traces_curves() {
    let (v, r) = (
        [bytemuck::cast_slice::<_, u8>(&POINTS)],
        [bytemuck::cast_slice::<_, u8>(&RADII)],
    );
    on_every_device(|device| {
        let gas = device
            .build_gas(
                &BuildOptions::default(),
                &[input(&v, &r, bytemuck::cast_slice(&INDEX)).into()],
            )
            .unwrap_or_else(|e| panic!("{}: {e}", name(device)));
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
            [Some((0, 4.5, 0.5, kind)), Some((1, 4.5, 0.5, kind)), None],
            "{}",
            name(device)
        );
        h
    });
}

/// §5.2: bad curve input is reported alike by every device, before any build work.
#[test]
fn s5_2_bad_curve_input_gets_the_same_error_on_every_device() {
    let v = [bytemuck::cast_slice::<_, u8>(&POINTS)];
    let r = [bytemuck::cast_slice::<_, u8>(&RADII)];
    let short = [&r[0][..4]];
    let index = bytemuck::cast_slice::<_, u8>(&INDEX);
    on_every_device(|device| {
        let err = device
            .build_gas(&BuildOptions::default(), &[input(&v, &short, index).into()])
            .err()
            .unwrap();
        assert!(matches!(err, BuildError::BufferTooSmall { .. }), "{err}");
        err
    });
}

/// Strands of one curve type as byte buffers: one-segment strands, gently bent, in a box.
struct Strands {
    ty: CurveType,
    points: Vec<[f32; 3]>,
    radii: Vec<f32>,
    normals: Vec<[f32; 3]>,
    index: Vec<u32>,
    endcaps: CurveEndcaps,
}

impl Strands {
    /// `n` strands of `ty` in `[-extent, extent]³` (ribbons with normals when `normals`).
    fn random(rng: &mut Rng, ty: CurveType, n: usize, extent: f32, normals: bool) -> Strands {
        let k = ty.control_points();
        let mut s = Strands {
            ty,
            points: Vec::new(),
            radii: Vec::new(),
            normals: Vec::new(),
            index: Vec::new(),
            // Flat caps where the type has them (linear curves always have round ones).
            endcaps: if ty == CurveType::RoundLinear {
                CurveEndcaps::Default
            } else {
                CurveEndcaps::On
            },
        };
        for _ in 0..n {
            s.index.push(s.points.len() as u32);
            let base = rng.vec3(-extent, extent);
            let dir = rng.dir() * 0.5;
            for j in 0..k {
                let p = base + dir * j as f32 + rng.vec3(-0.1, 0.1);
                s.points.push(p.to_array());
                s.radii.push(rng.range(0.03, 0.15));
                if normals {
                    s.normals.push(rng.dir().to_array());
                }
            }
        }
        s
    }

    /// The GAS of these strands on `device`, and the host's structure of the same input (for
    /// the brute force over its segments).
    fn build(&self, device: &Device) -> (oxray::Gas, GasData) {
        let v = [bytemuck::cast_slice::<_, u8>(&self.points)];
        let r = [bytemuck::cast_slice::<_, u8>(&self.radii)];
        let n = [bytemuck::cast_slice::<_, u8>(&self.normals)];
        let mut input = CurveInput::new(
            self.ty,
            &v,
            self.points.len() as u32,
            &r,
            bytemuck::cast_slice(&self.index),
            self.index.len() as u32,
        )
        .endcaps(self.endcaps);
        if !self.normals.is_empty() {
            input = input.normals(&n, 0);
        }
        let options = BuildOptions::default();
        let gas = device
            .build_gas(&options, &[input.into()])
            .unwrap_or_else(|e| panic!("{} {}: {e}", name(device), self.ty));
        let data = GasData::build(&options, &[input.into()]).unwrap();
        (gas, data)
    }
}

/// The nearest hit over every leaf slot of `data` with [`oxray::CurveSegment::intersect`]:
/// (t, primitive index, u, v, back face).
fn brute_force(data: &GasData, ray: &Ray) -> Option<(f32, u32, f32, f32, bool)> {
    let mut best: Option<(f32, u32, f32, f32, bool)> = None;
    for (slot, s) in data.curves.iter().enumerate() {
        let tmax = best.map_or(ray.tmax, |b| b.0);
        if let Some(h) = s.intersect(ray.origin, ray.direction, ray.tmin, tmax) {
            if best.is_none_or(|b| h.t < b.0) {
                let (prim, _, _) = data.resolve(slot as u32);
                best = Some((h.t, prim, h.u, h.v, h.back_face));
            }
        }
    }
    best
}

/// Random rays, half of them aimed at a control point of a random segment.
fn rays(rng: &mut Rng, s: &Strands, n: usize) -> Vec<Ray> {
    (0..n)
        .map(|k| {
            let o = rng.vec3(-4.0, 4.0);
            let d = if k % 2 == 0 {
                rng.dir()
            } else {
                let p = Vec3::from(s.points[rng.below(s.points.len())]);
                (p + rng.vec3(-0.1, 0.1) - o) * rng.range(0.5, 2.0)
            };
            Ray::with_interval(o, d, 0.0, rng.range(3.0, 20.0))
        })
        .collect()
}

/// §9.3, §9.6: for every curve type (round types with end caps, ribbons with and without
/// normals) the batched closest and any-hit queries find what a brute force over every segment
/// finds with the same intersector, bit for bit, with the curve's hit kind and its u (and a
/// ribbon's v); every device gives the same hits.
#[test]
fn s9_3_queries_hit_every_curve_type_alike_on_every_device() {
    let mut rng = Rng::new(0x9_3);
    let mut cases: Vec<(CurveType, bool)> = CurveType::ALL.iter().map(|&t| (t, false)).collect();
    cases.push((CurveType::FlatQuadraticBSpline, true));
    for (ty, normals) in cases {
        let strands = Strands::random(&mut rng, ty, 300, 2.5, normals);
        let rays = rays(&mut rng, &strands, 4000);
        on_every_device(|device| {
            let (gas, data) = strands.build(device);
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
                let want = brute_force(&data, ray);
                let label = format!("{} {ty} normals {normals}: {ray:?}", name(device));
                assert_eq!(hit.map(|h| h.t), want.map(|w| w.0), "{label}");
                assert_eq!(*occ, want.is_some(), "{label}");
                if let (Some(h), Some((_, prim, u, v, back))) = (hit, want) {
                    found += 1;
                    assert_eq!(h.hit_kind, HitKind::curve(ty, back), "{label}");
                    // Two segments entered at the same t are a tie either may win.
                    if h.primitive_index == prim {
                        assert_eq!((h.u, h.v), (u, v), "{label}");
                    }
                }
            }
            assert!(found > 300, "{ty}: {found} hits");
            hits.iter()
                .map(|h| {
                    h.map(|h| {
                        (
                            h.t.to_bits(),
                            h.primitive_index,
                            h.u.to_bits(),
                            h.v.to_bits(),
                            h.hit_kind,
                        )
                    })
                })
                .collect::<Vec<_>>()
        });
    }
}

/// The programs of `curves.cu`, for a [`Scene`].
const CURVES: ScenePrograms = ScenePrograms {
    source: PROGRAMS,
    params: "cp",
    raygen: "__raygen__curves",
    miss: "__miss__curves",
    hit_groups: &[
        ("hg", "__closesthit__curve", None),
        (
            "hg_skip_even",
            "__closesthit__curve",
            Some("__anyhit__skip_even"),
        ),
        ("hg_normal", "__closesthit__ribbon_normal", None),
    ],
};

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    out: u64,
    handle: u64,
    width: u32,
    height: u32,
    z: f32,
    ray_flags: u32,
}

const W: u32 = 48;
const H: u32 = 48;

impl Scene {
    /// A W x H launch over `handle` with hit group `hit`: 8 words per launch index.
    fn run(&self, handle: u64, hit: &str, flags: RayFlags) -> (Vec<[u32; 8]>, LaunchReport) {
        self.launch(&self.sbt(hit, 1), W, H, |out| Params {
            out,
            handle,
            width: W,
            height: H,
            z: 5.0,
            ray_flags: flags.bits(),
        })
    }
}

/// The ray of launch index `i`, as the raygen program makes it.
fn pixel_ray(i: usize) -> Ray {
    let (x, y) = ((i as u32 % W) as f32, (i as u32 / W) as f32);
    let px = 4.0 * (x + 0.5) / W as f32 - 2.0;
    let py = 4.0 * (y + 0.5) / H as f32 - 2.0;
    Ray::with_interval(Vec3::new(px, py, 5.0), -Vec3::Z, 0.0, 1e16)
}

/// §9.3, §13.5: for every curve type, a closest-hit program sees what the batched query finds
/// for the same ray (primitive, t, the curve parameter and a ribbon's v, the hit kind and its
/// primitive type, not a triangle) and the segment's control points through its type's
/// vertex-data function; §13.2: an any-hit program that ignores the even segments leaves only
/// odd ones; every device gives the same words.
#[test]
fn s9_3_pipelines_hit_built_in_curves_on_every_device() {
    let mut rng = Rng::new(0x135);
    let all = CurveType::ALL
        .iter()
        .fold(PrimitiveTypeFlags::empty(), |f, t| f | t.type_flag());
    let cases: Vec<Strands> = CurveType::ALL
        .iter()
        .map(|&ty| Strands::random(&mut rng, ty, 120, 1.8, ty.is_ribbon()))
        .collect();
    on_every_device(|device| {
        let scene = Scene::new(device, &CURVES, all);
        let mut results = Vec::new();
        for strands in &cases {
            let ty = strands.ty;
            let (gas, data) = strands.build(device);
            let handle = gas.optix_handle().unwrap();
            let (out, report) = scene.run(handle, "hg", RayFlags::empty());
            assert_eq!(report.exceptions, 0, "{} {ty}: {report:?}", name(device));
            // One trace per launch index, counted in the report.
            assert_eq!(report.traces, u64::from(W * H), "{}", name(device));
            let rays: Vec<Ray> = (0..out.len()).map(pixel_ray).collect();
            let mut hits = vec![None; rays.len()];
            device
                .intersect_closest(&gas.handle(), &rays, &mut hits)
                .unwrap();
            let mut found = 0;
            for (i, (o, hit)) in out.iter().zip(&hits).enumerate() {
                let label = format!("{} {ty} ray {i}", name(device));
                match hit {
                    Some(h) => {
                        found += 1;
                        assert_eq!(o[0], 1, "{label}");
                        assert_eq!(o[1], h.primitive_index, "{label}");
                        let k = h.hit_kind.0 as u32;
                        let back = k & 1;
                        let low = ty.code() & 0xFF;
                        assert_eq!(
                            o[2],
                            k | (1 - back) << 8 | back << 9 | low << 10,
                            "{label}: kind, facing, type"
                        );
                        assert_eq!(f32::from_bits(o[3]), h.t, "{label}");
                        assert_eq!(f32::from_bits(o[4]), h.u, "{label}: curve parameter");
                        assert_eq!(f32::from_bits(o[5]), h.v, "{label}: ribbon v");
                        let s = data.curves[slot_of(&data, h.primitive_index)];
                        let n = ty.control_points();
                        assert_eq!(f32::from_bits(o[6]), s.points[0][0], "{label}: vertex data");
                        assert_eq!(f32::from_bits(o[7]), s.points[n - 1][3], "{label}");
                    }
                    None => {
                        assert_eq!(o[0], 0, "{label}: a miss");
                        assert_eq!(f32::from_bits(o[3]), 1e16, "{label}");
                    }
                }
            }
            assert!(found > 50, "{ty}: {found} hits");
            let (filtered, report) = scene.run(handle, "hg_skip_even", RayFlags::empty());
            assert_eq!(report.exceptions, 0, "{report:?}");
            let mut calls = 0;
            for o in &filtered {
                calls += o[0] >> 4;
                if o[0] & 0xF == 1 {
                    assert_eq!(o[1] & 1, 1, "{ty}: an even segment was ignored");
                }
            }
            assert!(calls as usize >= found, "{ty}: {calls} any-hit calls");
            // How many candidates any-hit sees before the interval shrinks past the others
            // depends on the order of traversal, which differs between devices (§13.2 leaves
            // it open): the devices must agree on the hits, not on the count of calls.
            let filtered: Vec<[u32; 8]> = filtered
                .into_iter()
                .map(|mut o| {
                    o[0] &= 0xF;
                    o
                })
                .collect();
            results.push((ty, out, filtered));
        }
        results
    });
}

/// §9.3: `optixGetRibbonNormal` at a ribbon hit's parameters is the unit normal of the ribbon
/// there, as `CurveSegment::ribbon_normal` computes it (bit for bit), for ribbons with normals
/// and ribbons that face the ray; every device gives the same words.
#[test]
fn s9_3_ribbon_normals_on_every_device() {
    let mut rng = Rng::new(0x9_3_1);
    let cases: Vec<Strands> = [true, false]
        .map(|normals| {
            Strands::random(&mut rng, CurveType::FlatQuadraticBSpline, 150, 1.8, normals)
        })
        .into();
    on_every_device(|device| {
        let scene = Scene::new(device, &CURVES, CurveType::FlatQuadraticBSpline.type_flag());
        let mut results = Vec::new();
        for strands in &cases {
            let (gas, data) = strands.build(device);
            let (out, report) =
                scene.run(gas.optix_handle().unwrap(), "hg_normal", RayFlags::empty());
            assert_eq!(report.exceptions, 0, "{report:?}");
            let mut found = 0;
            for (i, o) in out.iter().enumerate() {
                if o[0] & 0xF == 0 {
                    continue;
                }
                let ray = pixel_ray(i);
                let s = data.curves[slot_of(&data, o[1])];
                let h = s
                    .intersect(ray.origin, ray.direction, ray.tmin, ray.tmax)
                    .unwrap();
                let n = [o[4], o[5], o[6]].map(f32::from_bits);
                let want = s.ribbon_normal(h.u, f32::from_bits(o[7]), ray.direction);
                assert_eq!(n, want.to_array(), "{} ray {i}", name(device));
                assert!((want.length() - 1.0).abs() < 1e-5, "{want}");
                found += 1;
            }
            assert!(found > 50, "{found} ribbon hits");
            results.push(out);
        }
        results
    });
}

/// §9.1, §13.7: curves under an instance (scaled by 2, moved along z): the closest-hit
/// program sees t along the world ray, the segment's object-space control points and its u,
/// as the CPU's query through the same instance finds them; every device gives the same words.
#[test]
fn s9_1_instanced_curves_on_every_device() {
    let mut rng = Rng::new(0x9_1_7);
    let strands = Strands::random(&mut rng, CurveType::RoundCubicBSpline, 120, 0.9, false);
    let xform = oxray::Transform::from_affine(&glam::Affine3A::from_scale_rotation_translation(
        Vec3::splat(2.0),
        glam::Quat::from_rotation_z(0.3),
        Vec3::new(0.0, 0.0, -1.0),
    ));
    on_every_device(|device| {
        let (gas, data) = strands.build(device);
        let ias = device
            .build_ias(
                &BuildOptions::default(),
                &[(&[oxray::Instance::new(gas.handle()).transform(xform)][..]).into()],
            )
            .unwrap();
        let scene = Scene::new(device, &CURVES, CurveType::RoundCubicBSpline.type_flag());
        let (out, report) = scene.run(ias.optix_handle().unwrap(), "hg", RayFlags::empty());
        assert_eq!(report.exceptions, 0, "{report:?}");
        // The reference: the CPU device's query through the same instance.
        let cpu = Device::cpu();
        let (cpu_gas, _) = strands.build(&cpu);
        let cpu_ias = cpu
            .build_ias(
                &BuildOptions::default(),
                &[(&[oxray::Instance::new(cpu_gas.handle()).transform(xform)][..]).into()],
            )
            .unwrap();
        let rays: Vec<Ray> = (0..out.len()).map(pixel_ray).collect();
        let mut hits = vec![None; rays.len()];
        cpu.intersect_closest(&cpu_ias.handle(), &rays, &mut hits)
            .unwrap();
        let mut found = 0;
        for (i, (o, h)) in out.iter().zip(&hits).enumerate() {
            assert_eq!(o[0] & 0xF, h.is_some() as u32, "{} ray {i}", name(device));
            if let Some(h) = h {
                found += 1;
                assert_eq!(o[1] & 0xFFFF, h.primitive_index);
                assert_eq!(
                    f32::from_bits(o[3]),
                    h.t,
                    "{} ray {i}: world t",
                    name(device)
                );
                assert_eq!(f32::from_bits(o[4]), h.u);
                let s = data.curves[slot_of(&data, h.primitive_index)];
                assert_eq!(
                    f32::from_bits(o[6]),
                    s.points[0][0],
                    "object-space vertex data"
                );
            }
        }
        assert!(found > 50, "{found} hits");
        out
    });
}

/// The leaf slot holding primitive `prim` (the first, where a segment has several).
fn slot_of(data: &GasData, prim: u32) -> usize {
    (0..data.curves.len())
        .find(|&s| data.resolve(s as u32).0 == prim)
        .unwrap()
}

/// §9.1: a pipeline whose primitive-type flags leave out a curve type of the structure (the
/// empty set means triangles and custom primitives) raises UNSUPPORTED_PRIMITIVE_TYPE when a
/// trace enters the curve GAS; with the type's flag it does not.
#[test]
fn s9_1_curves_need_their_primitive_type_flag() {
    let mut rng = Rng::new(0x9_1);
    let strands = Strands::random(&mut rng, CurveType::RoundCubicBSpline, 60, 1.5, false);
    on_every_device(|device| {
        let (gas, _) = strands.build(device);
        let handle = gas.optix_handle().unwrap();
        let mut codes = Vec::new();
        for types in [
            PrimitiveTypeFlags::empty(),
            PrimitiveTypeFlags::TRIANGLE | PrimitiveTypeFlags::ROUND_LINEAR,
        ] {
            let (_, report) =
                Scene::new(device, &CURVES, types).run(handle, "hg", RayFlags::empty());
            assert_eq!(
                report.exceptions,
                u64::from(W * H),
                "{}: {report:?}",
                name(device)
            );
            // The trace that raised is counted too.
            assert_eq!(report.traces, u64::from(W * H), "{}", name(device));
            let code = report.first_exceptions[0].1.code;
            assert_eq!(code, ExceptionCode::UNSUPPORTED_PRIMITIVE_TYPE);
            codes.push(code);
        }
        let (_, report) = Scene::new(device, &CURVES, PrimitiveTypeFlags::ROUND_CUBIC_BSPLINE).run(
            handle,
            "hg",
            RayFlags::empty(),
        );
        assert_eq!(report.exceptions, 0, "{}: {report:?}", name(device));
        codes
    });
}

/// The curve programs compile for the GPU with NVRTC, GPU or not (`OXRAY_REQUIRE_NVRTC=1`
/// makes a missing NVRTC a failure): the device header's curve traversal compiles in CI.
#[test]
fn the_curve_programs_compile_with_nvrtc() {
    use oxray::cuda::{CudaHitGroupDesc, CudaModule, CudaProgramGroup};
    let m = CudaModule::from_source(PROGRAMS);
    let groups = [
        CudaProgramGroup::raygen(&m, "__raygen__curves"),
        CudaProgramGroup::miss(Some((&m, "__miss__curves"))),
        CudaProgramGroup::hit_group(CudaHitGroupDesc {
            closest_hit: Some((&m, "__closesthit__curve")),
            any_hit: Some((&m, "__anyhit__skip_even")),
            intersection: None,
        }),
        CudaProgramGroup::hit_group(CudaHitGroupDesc {
            closest_hit: Some((&m, "__closesthit__ribbon_normal")),
            any_hit: None,
            intersection: None,
        }),
    ]
    .map(Result::unwrap);
    common::assert_compiles_with_nvrtc(
        "the curve programs",
        &groups,
        PrimitiveTypeFlags::ROUND_CUBIC_BSPLINE,
    );
}
