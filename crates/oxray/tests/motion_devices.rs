//! Motion blur (guide §5.10) through pipelines on every device present: the same CUDA C++
//! programs (conformance/motion.cu) trace motion GASes of triangles, custom primitives, spheres
//! and curves, IASes with motion options and matrix and SRT motion transforms, on the CPU (the
//! programs compiled by the host's C++ compiler) and on a CUDA device where there is one
//! (`OXRAY_REQUIRE_GPU=1` makes its absence a failure). Every device must give the same records
//! bit for bit, and the CPU's records the hits of the CPU device's batched queries, which the
//! oxray-cpu motion tests check against brute force at random times.

mod common;

use common::{assert_compiles_with_nvrtc, name, on_every_device, HitSpec, LabelledPipeline};
use common::{PipelineSpec, Rng};
use glam::{Quat, Vec3};
use oxray::{
    Aabb, AabbBuffer, BackendKind, BuildFlags, BuildInput, BuildOptions, CurveInput, CurveType,
    CustomPrimitiveInput, Device, Gas, Ias, Instance, MatrixMotionTransform, MotionFlags,
    MotionOptions, PipelineCompileOptions, PrimitiveTypeFlags, QueryError, Ray, SbtRegion,
    ShaderBindingTable, SphereInput, SrtData, SrtMotionTransform, Transform, TraversableHandle,
    TriangleInput, VertexBuffer,
};

const MOTION: &str = include_str!("conformance/motion.cu");
/// Words of a launch index's record (`MO_WORDS` in motion.cu).
const WORDS: usize = 24;
type Record = [u32; WORDS];

/// A ray of one launch index (`MoRay` in motion.cu).
#[repr(C)]
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct MoRay {
    org: [f32; 3],
    dir: [f32; 3],
    tmin: f32,
    tmax: f32,
    time: f32,
    flags: u32,
    pad: [u32; 2],
}

impl MoRay {
    fn ray(&self) -> Ray {
        Ray::with_interval(self.org.into(), self.dir.into(), self.tmin, self.tmax)
            .with_time(self.time)
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct MoParams {
    out: u64,
    handle: u64,
    rays: u64,
}

const HIT_GROUPS: [HitSpec; 2] = [
    ("hit", Some("__closesthit__mo"), None, None),
    (
        "box",
        Some("__closesthit__mo"),
        None,
        Some("__intersection__mo"),
    ),
];

/// The motion pipeline on `device`; `motion_blur` is `usesMotionBlur`. Graphs up to three
/// levels deep (an IAS, a motion transform, a GAS).
fn pipeline(device: &Device, motion_blur: bool) -> LabelledPipeline {
    let spec = PipelineSpec {
        source: MOTION,
        params: "mo",
        raygens: &[("rg", "__raygen__mo")],
        misses: &[("ms", "__miss__mo")],
        hit_groups: &HIT_GROUPS,
        exception: ("ex", "__exception__mo"),
        compile: PipelineCompileOptions {
            num_payload_values: 2,
            num_attribute_values: 2,
            uses_motion_blur: motion_blur,
            uses_primitive_type_flags: PrimitiveTypeFlags::TRIANGLE
                | PrimitiveTypeFlags::CUSTOM
                | PrimitiveTypeFlags::SPHERE
                | PrimitiveTypeFlags::ROUND_CUBIC_BSPLINE,
            ..Default::default()
        },
        max_trace_depth: 1,
    };
    let mut p = LabelledPipeline::new(device, &spec);
    p.pipeline
        .set_max_traversable_graph_depth(3)
        .unwrap_or_else(|e| panic!("{}: {e}", name(device)));
    p
}

/// Traces `rays` against `handle` with the hit group `group`; no exception may be raised.
fn run(p: &LabelledPipeline, group: &str, handle: u64, rays: &[MoRay]) -> Vec<Record> {
    let d = &p.device;
    let out = d.create_buffer::<Record>(rays.len()).unwrap();
    let ray_buf = d.buffer_from_slice(rays).unwrap();
    let params = MoParams {
        out: out.device_ptr(),
        handle,
        rays: ray_buf.device_ptr(),
    };
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[p.header("rg")]),
        miss: SbtRegion::from_headers(&[p.header("ms")]),
        hitgroup: SbtRegion::from_headers(&[p.header(group)]),
        ..Default::default()
    };
    let report = p
        .pipeline
        .launch_with(&params, &sbt, rays.len() as u32, 1, 1)
        .unwrap_or_else(|e| panic!("{} launch: {e}", name(d)));
    assert_eq!(report.exceptions, 0, "{}: {report:?}", name(d));
    out.download().unwrap()
}

/// Rays down -z from z = 5 over `[-extent, extent]²`, tilted a little, at times in
/// `[t0, t1]`.
fn rays(rng: &mut Rng, n: usize, extent: f32, t0: f32, t1: f32) -> Vec<MoRay> {
    (0..n)
        .map(|_| {
            let dir = Vec3::new(rng.range(-0.2, 0.2), rng.range(-0.2, 0.2), -1.0);
            MoRay {
                org: [rng.range(-extent, extent), rng.range(-extent, extent), 5.0],
                dir: dir.to_array(),
                tmin: 0.0,
                tmax: f32::INFINITY,
                time: rng.range(t0, t1),
                flags: 0,
                pad: [0; 2],
            }
        })
        .collect()
}

/// `n` random triangles in `[-1, 1]³` at `keys` motion keys, each moving by its own velocity
/// (up to `speed` per key) and turning.
fn moving_triangles(rng: &mut Rng, n: usize, keys: usize, speed: f32) -> Vec<Vec<[f32; 3]>> {
    let base = common::random_soup(rng, n, 2.0, 0.25);
    let motion: Vec<(Vec3, Quat)> = (0..n)
        .map(|_| {
            let v = rng.vec3(-speed, speed);
            let q = Quat::from_axis_angle(rng.unit(), rng.range(-0.4, 0.4));
            (v, q)
        })
        .collect();
    (0..keys)
        .map(|k| {
            base.iter()
                .zip(&motion)
                .flat_map(|(t, (v, q))| {
                    let c =
                        (Vec3::from(t[0]) + Vec3::from(t[1]) + Vec3::from(t[2])) / 3.0 - Vec3::ONE;
                    let turn = Quat::IDENTITY.slerp(*q, k as f32);
                    t.map(|p| {
                        let local = Vec3::from(p) - Vec3::ONE - c;
                        (c + turn * local + *v * k as f32).to_array()
                    })
                })
                .collect()
        })
        .collect()
}

fn motion_triangle_gas(device: &Device, keys: &[Vec<[f32; 3]>], m: MotionOptions) -> Gas {
    let later: Vec<VertexBuffer<'_>> = keys[1..].iter().map(|k| VertexBuffer::f32x3(k)).collect();
    let input = TriangleInput::new(VertexBuffer::f32x3(&keys[0])).motion_vertices(&later);
    let options =
        BuildOptions::new(BuildFlags::ALLOW_RANDOM_VERTEX_ACCESS | BuildFlags::ALLOW_COMPACTION)
            .with_motion(m);
    device
        .build_gas(&options, &[input.into()])
        .unwrap_or_else(|e| panic!("{}: {e}", name(device)))
}

/// The record fields that the CPU device's batched query also gives: hit, t, primitive,
/// instance id.
fn query_fields(r: &Record) -> Option<(u32, u32, u32)> {
    (r[0] == 1).then_some((r[1], r[2], r[4]))
}

/// Checks the CPU records against the CPU device's batched closest-hit query over `root`.
fn assert_matches_the_query(
    device: &Device,
    root: &TraversableHandle,
    rays: &[MoRay],
    recs: &[Record],
) {
    let rs: Vec<Ray> = rays.iter().map(MoRay::ray).collect();
    let mut hits = vec![None; rs.len()];
    device.intersect_closest(root, &rs, &mut hits).unwrap();
    for (i, (h, r)) in hits.iter().zip(recs).enumerate() {
        let want = h.map(|h| (h.t.to_bits(), h.primitive_index, h.instance_id));
        assert_eq!(query_fields(r), want, "ray {i} at time {}", rays[i].time);
    }
}

/// How many of the records are hits and misses.
fn hits_and_misses(recs: &[Record]) -> (usize, usize) {
    let hits = recs.iter().filter(|r| r[0] == 1).count();
    let misses = recs.iter().filter(|r| r[0] == 2).count();
    assert_eq!(hits + misses, recs.len(), "every index hits or misses");
    (hits, misses)
}

#[test]
fn s5_10_2_motion_triangles_are_traced_at_the_ray_time_alike_on_every_device() {
    let mut rng = Rng::new(51);
    let keys = moving_triangles(&mut rng, 300, 3, 0.4);
    let rays = rays(&mut rng, 3000, 1.6, -0.3, 1.3);
    let m = MotionOptions::new(3, 0.0, 1.0);
    on_every_device(|device| {
        let gas = motion_triangle_gas(device, &keys, m);
        let p = pipeline(device, true);
        let recs = run(&p, "hit", gas.optix_handle().unwrap(), &rays);
        let (hits, misses) = hits_and_misses(&recs);
        assert!(hits > 300 && misses > 300, "{hits} hits, {misses} misses");
        for (r, ray) in recs.iter().zip(&rays).filter(|(r, _)| r[0] == 1) {
            // §13.10: the GAS's motion options; §13.5: the ray's time.
            assert_eq!(&r[16..20], &[3, 0, 1.0f32.to_bits(), ray.time.to_bits()]);
            // The vertices at the ray's time, the same from the hit and through the handle
            // (§13.9).
            assert_eq!(r[14], r[15]);
            assert_eq!(r[7], 0, "no transforms");
        }
        if device.kind() == BackendKind::Cpu {
            assert_matches_the_query(device, &gas.handle(), &rays, &recs);
        }
        recs
    });
}

#[test]
fn s5_10_1_vanishing_gases_and_clamped_times_alike_on_every_device() {
    let mut rng = Rng::new(52);
    let keys = moving_triangles(&mut rng, 200, 2, 0.3);
    let rays = rays(&mut rng, 4000, 1.6, -0.5, 1.5);
    let vanish = MotionOptions::new(2, 0.25, 0.75)
        .with_flags(MotionFlags::START_VANISH | MotionFlags::END_VANISH);
    on_every_device(|device| {
        let gas = motion_triangle_gas(device, &keys, vanish);
        let p = pipeline(device, true);
        let recs = run(&p, "hit", gas.optix_handle().unwrap(), &rays);
        for (r, ray) in recs.iter().zip(&rays) {
            if !(0.25..=0.75).contains(&ray.time) {
                assert_eq!(r[0], 2, "time {}: the GAS has vanished", ray.time);
            }
        }
        assert!(hits_and_misses(&recs).0 > 100);
        // Without vanish flags a time outside the range is clamped to it (§5.10.1).
        let clamped = motion_triangle_gas(device, &keys, MotionOptions::new(2, 0.25, 0.75));
        let all = run(&p, "hit", clamped.optix_handle().unwrap(), &rays);
        let at_ends: Vec<MoRay> = rays
            .iter()
            .map(|r| MoRay {
                time: r.time.clamp(0.25, 0.75),
                ..*r
            })
            .collect();
        let ends = run(&p, "hit", clamped.optix_handle().unwrap(), &at_ends);
        for (i, (a, b)) in all.iter().zip(&ends).enumerate() {
            assert_eq!(&a[..19], &b[..19], "ray {i} at time {}", rays[i].time);
        }
        if device.kind() == BackendKind::Cpu {
            assert_matches_the_query(device, &gas.handle(), &rays, &recs);
        }
        (recs, all)
    });
}

#[test]
fn s5_10_1_motion_aabbs_are_interpolated_alike_on_every_device() {
    let mut rng = Rng::new(53);
    let n = 120;
    // Every box spans z in [-2, 2], so a ray over one enters it before any report (z >= -1.2)
    // and its intersection program runs whatever has been reported before.
    let a: Vec<Aabb> = (0..n)
        .map(|_| {
            let c = rng.vec3(-1.0, 1.0);
            Aabb::new(
                Vec3::new(c.x - 0.15, c.y - 0.15, -2.0),
                Vec3::new(c.x + 0.15, c.y + 0.15, 2.0),
            )
        })
        .collect();
    let b: Vec<Aabb> = a
        .iter()
        .map(|x| {
            let d = rng.vec3(-0.6, 0.6) * Vec3::new(1.0, 1.0, 0.0);
            Aabb::new(x.min + d, x.max + d * 1.5)
        })
        .collect();
    let mut rays = rays(&mut rng, 3000, 1.5, 0.0, 1.0);
    for r in &mut rays {
        r.dir = [0.0, 0.0, -1.0];
    }
    let m = MotionOptions::new(2, 0.0, 1.0);
    on_every_device(|device| {
        let later = [AabbBuffer::new(&b)];
        let input = CustomPrimitiveInput::new(AabbBuffer::new(&a)).motion_aabbs(&later);
        let gas = device
            .build_gas(&BuildOptions::default().with_motion(m), &[input.into()])
            .unwrap();
        let p = pipeline(device, true);
        let recs = run(&p, "box", gas.optix_handle().unwrap(), &rays);
        for (r, ray) in recs.iter().zip(&rays) {
            // The box between the keys (§5.10.1) holds the ray's (x, y): the lowest such
            // primitive index reports the nearest hit (at z = -0.01 index).
            let lerp = |p: f32, q: f32| p + (q - p) * ray.time;
            let inside = (0..n).find(|&i| {
                (0..2).all(|k| {
                    let lo = lerp(a[i].min[k], b[i].min[k]);
                    let hi = lerp(a[i].max[k], b[i].max[k]);
                    ray.org[k] >= lo && ray.org[k] <= hi
                })
            });
            match inside {
                Some(i) => {
                    assert_eq!((r[0], r[2], r[3], r[5]), (1, i as u32, 7, i as u32));
                    assert_eq!(r[6], ray.time.to_bits(), "the time the program saw");
                }
                None => assert_eq!(r[0], 2),
            }
        }
        let (hits, misses) = hits_and_misses(&recs);
        assert!(hits > 300 && misses > 300, "{hits} hits, {misses} misses");
        recs
    });
}

#[test]
fn s5_10_2_motion_spheres_and_curves_alike_on_every_device() {
    let mut rng = Rng::new(54);
    let n = 150;
    let c0: Vec<[f32; 3]> = (0..n).map(|_| rng.vec3(-1.2, 1.2).to_array()).collect();
    let c1: Vec<[f32; 3]> = c0
        .iter()
        .map(|c| (Vec3::from(*c) + rng.vec3(-0.5, 0.5)).to_array())
        .collect();
    let r0: Vec<f32> = (0..n).map(|_| rng.range(0.05, 0.2)).collect();
    let r1: Vec<f32> = r0.iter().map(|r| r * rng.range(0.5, 1.5)).collect();
    // Strands of 6 control points each, 3 segments, swaying between the keys.
    let strands = 40;
    let mut p0 = Vec::new();
    let mut idx = Vec::new();
    for s in 0..strands {
        let base = rng.vec3(-1.2, 1.2);
        for k in 0..6 {
            if k < 3 {
                idx.push((6 * s + k) as u32);
            }
            let p = base + Vec3::new(0.1 * k as f32, 0.05 * (k * k) as f32, -0.2 * k as f32);
            p0.push(p.to_array());
        }
    }
    let p1: Vec<[f32; 3]> = p0
        .iter()
        .map(|p| (Vec3::from(*p) + Vec3::new(0.3, -0.2, 0.1)).to_array())
        .collect();
    let w0 = vec![0.04f32; p0.len()];
    let w1 = vec![0.07f32; p0.len()];
    let rays = rays(&mut rng, 3000, 1.6, -0.2, 1.2);
    let m = MotionOptions::new(2, 0.0, 1.0);
    let options = BuildOptions::new(BuildFlags::ALLOW_RANDOM_VERTEX_ACCESS).with_motion(m);
    on_every_device(|device| {
        let centres = [bytemuck::cast_slice(&c0), bytemuck::cast_slice(&c1)];
        let radii = [bytemuck::cast_slice(&r0), bytemuck::cast_slice(&r1)];
        let spheres = SphereInput::new(&centres, n as u32, &radii);
        let sgas = device.build_gas(&options, &[spheres.into()]).unwrap();
        let points = [bytemuck::cast_slice(&p0), bytemuck::cast_slice(&p1)];
        let widths = [bytemuck::cast_slice(&w0), bytemuck::cast_slice(&w1)];
        let curves = CurveInput::new(
            CurveType::RoundCubicBSpline,
            &points,
            p0.len() as u32,
            &widths,
            bytemuck::cast_slice(&idx),
            idx.len() as u32,
        );
        let cgas = device.build_gas(&options, &[curves.into()]).unwrap();
        let p = pipeline(device, true);
        let s = run(&p, "hit", sgas.optix_handle().unwrap(), &rays);
        let c = run(&p, "hit", cgas.optix_handle().unwrap(), &rays);
        for (what, recs) in [("spheres", &s), ("curves", &c)] {
            let (hits, misses) = hits_and_misses(recs);
            assert!(
                hits > 100 && misses > 100,
                "{what}: {hits} hits, {misses} misses"
            );
            for r in recs.iter().filter(|r| r[0] == 1) {
                assert_eq!(
                    r[14], r[15],
                    "{what}: vertex data from the hit and the handle"
                );
                assert_eq!(r[16], 2, "{what}: two motion keys");
            }
        }
        if device.kind() == BackendKind::Cpu {
            assert_matches_the_query(device, &sgas.handle(), &rays, &s);
        }
        (s, c)
    });
}

/// An IAS over a static GAS placed by a matrix motion transform, a motion GAS placed by an SRT
/// motion transform, and a plain instance; built with `ias_motion`.
struct MotionScene {
    ias: Ias,
    _gases: (Gas, Gas),
}

fn motion_scene(device: &Device, ias_motion: MotionOptions) -> MotionScene {
    let mut rng = Rng::new(55);
    let still = common::random_soup(&mut rng, 150, 1.0, 0.2);
    let still: Vec<[f32; 3]> = still.iter().flatten().copied().collect();
    let gas = device
        .build_gas(
            &BuildOptions::default(),
            &[TriangleInput::new(VertexBuffer::f32x3(&still)).into()],
        )
        .unwrap();
    let keys = moving_triangles(&mut rng, 150, 2, 0.2);
    let moving = motion_triangle_gas(device, &keys, MotionOptions::new(2, 0.0, 1.0));
    let matrix = MatrixMotionTransform::new(
        gas.handle(),
        MotionOptions::new(3, 0.0, 1.0),
        &[
            Transform::from_translation(Vec3::new(-1.5, -1.0, 0.0)),
            Transform::from_affine(&glam::Affine3A::from_scale_rotation_translation(
                Vec3::new(1.2, 0.8, 1.0),
                Quat::from_rotation_z(0.3),
                Vec3::new(-1.0, -1.2, 0.2),
            )),
            Transform::from_translation(Vec3::new(-0.5, -1.0, 0.0)),
        ],
    )
    .unwrap();
    let srt_key = |angle: f32, tx: f32| {
        let q = Quat::from_rotation_z(angle);
        SrtData {
            sx: 1.1,
            a: 0.1,
            pvx: 0.2,
            qx: q.x,
            qy: q.y,
            qz: q.z,
            qw: q.w,
            tx,
            ty: 0.5,
            ..SrtData::IDENTITY
        }
    };
    let srt = SrtMotionTransform::new(
        moving.handle(),
        MotionOptions::new(2, 0.0, 1.0).with_flags(MotionFlags::END_VANISH),
        &[srt_key(0.0, 0.2), srt_key(1.2, 0.9)],
    )
    .unwrap();
    let instances = [
        Instance::new(matrix.into()).instance_id(10),
        Instance::new(srt.into()).instance_id(11),
        Instance::new(gas.handle())
            .instance_id(12)
            .transform(Transform::from_translation(Vec3::new(0.3, 1.0, -0.5))),
    ];
    let ias = device
        .build_ias(
            &BuildOptions::default().with_motion(ias_motion),
            &[BuildInput::from(&instances[..])],
        )
        .unwrap_or_else(|e| panic!("{}: {e}", name(device)));
    MotionScene {
        ias,
        _gases: (gas, moving),
    }
}

#[test]
fn s5_10_4_s5_10_5_motion_transforms_under_instances_alike_on_every_device() {
    let mut rng = Rng::new(56);
    let rays = rays(&mut rng, 4000, 2.0, -0.2, 1.2);
    on_every_device(|device| {
        let scene = motion_scene(device, MotionOptions::new(2, 0.0, 1.0));
        let p = pipeline(device, true);
        let recs = run(&p, "hit", scene.ias.optix_handle().unwrap(), &rays);
        let mut seen = [0usize; 3];
        for (r, ray) in recs.iter().zip(&rays).filter(|(r, _)| r[0] == 1) {
            // §13.11: the transform list, the instance first.
            match r[4] {
                10 => {
                    assert_eq!((r[7], r[8], r[9]), (2, 4, 2), "instance, matrix motion");
                    assert_eq!(r[20], 3, "numKeys of the matrix motion transform");
                    seen[0] += 1;
                }
                11 => {
                    assert!(
                        ray.time <= 1.0,
                        "the SRT transform vanishes after its range"
                    );
                    assert_eq!((r[7], r[8], r[9]), (2, 4, 3), "instance, SRT motion");
                    assert_eq!(r[22], 2 | (2 << 16), "numKeys and END_VANISH");
                    assert_eq!(r[16], 2, "the motion GAS under it");
                    seen[1] += 1;
                }
                12 => {
                    assert_eq!((r[7], r[8], r[9]), (1, 4, 0xFF));
                    seen[2] += 1;
                }
                id => panic!("instance id {id}"),
            }
        }
        assert!(seen.iter().all(|&n| n > 50), "hits per instance: {seen:?}");
        if device.kind() == BackendKind::Cpu {
            assert_matches_the_query(device, &scene.ias.handle(), &rays, &recs);
        }
        recs
    });
}

#[test]
fn s5_10_3_an_ias_with_vanish_flags_hides_its_instances_alike_on_every_device() {
    let mut rng = Rng::new(57);
    let rays = rays(&mut rng, 2000, 2.0, -0.5, 1.5);
    let m = MotionOptions::new(2, 0.0, 1.0).with_flags(MotionFlags::START_VANISH);
    on_every_device(|device| {
        let scene = motion_scene(device, m);
        let p = pipeline(device, true);
        let recs = run(&p, "hit", scene.ias.optix_handle().unwrap(), &rays);
        for (r, ray) in recs.iter().zip(&rays) {
            if ray.time < 0.0 {
                assert_eq!(r[0], 2, "time {}: before the IAS's range", ray.time);
            }
        }
        assert!(hits_and_misses(&recs).0 > 200);
        recs
    });
}

#[test]
fn s13_5_without_motion_blur_every_ray_is_traced_at_time_0_on_every_device() {
    let mut rng = Rng::new(58);
    let rays = rays(&mut rng, 2000, 2.0, 0.2, 1.0);
    let at_zero: Vec<MoRay> = rays.iter().map(|r| MoRay { time: 0.0, ..*r }).collect();
    on_every_device(|device| {
        let scene = motion_scene(device, MotionOptions::new(2, 0.0, 1.0));
        let handle = scene.ias.optix_handle().unwrap();
        let still = run(&pipeline(device, false), "hit", handle, &rays);
        let zero = run(&pipeline(device, true), "hit", handle, &at_zero);
        assert_eq!(still, zero, "{}", name(device));
        assert!(hits_and_misses(&still).0 > 200);
        still
    });
}

#[test]
fn s5_8_s5_7_motion_gases_compact_and_load_across_devices_with_the_same_records() {
    let mut rng = Rng::new(59);
    let keys = moving_triangles(&mut rng, 200, 3, 0.3);
    let rays = rays(&mut rng, 2000, 1.6, 0.0, 1.0);
    let m = MotionOptions::new(3, 0.0, 1.0);
    // Saved by the CPU device, loaded on each.
    let bytes = motion_triangle_gas(&Device::cpu(), &keys, m)
        .to_bytes()
        .unwrap();
    on_every_device(|device| {
        let gas = motion_triangle_gas(device, &keys, m);
        let p = pipeline(device, true);
        let built = run(&p, "hit", gas.optix_handle().unwrap(), &rays);
        let compact = device.compact_gas(&gas).unwrap();
        assert_eq!(
            run(&p, "hit", compact.optix_handle().unwrap(), &rays),
            built
        );
        let loaded = device.load_gas(&bytes).unwrap();
        assert_eq!(run(&p, "hit", loaded.optix_handle().unwrap(), &rays), built);
        built
    });
}

#[test]
fn the_cuda_device_refuses_batched_queries_of_motion_structures() {
    let mut rng = Rng::new(60);
    let keys = moving_triangles(&mut rng, 20, 2, 0.3);
    for device in common::devices() {
        let gas = motion_triangle_gas(&device, &keys, MotionOptions::new(2, 0.0, 1.0));
        let rays = [Ray::new(Vec3::new(0.0, 0.0, 5.0), -Vec3::Z).with_time(0.5)];
        let mut hits = [None];
        let query = device.intersect_closest(&gas.handle(), &rays, &mut hits);
        match device.kind() {
            // The query kernels' rays carry no time: pipelines trace motion on the GPU.
            BackendKind::Cuda => {
                assert!(
                    matches!(query, Err(QueryError::Unsupported(_))),
                    "{query:?}"
                )
            }
            _ => query.unwrap(),
        }
    }
}

#[test]
fn the_motion_programs_compile_with_nvrtc() {
    let m = oxray::cuda::CudaModule::from_source(MOTION);
    let g = |kind: &str| {
        use oxray::cuda::CudaProgramGroup as G;
        match kind {
            "rg" => G::raygen(&m, "__raygen__mo"),
            "ms" => G::miss(Some((&m, "__miss__mo"))),
            "ex" => G::exception(&m, "__exception__mo"),
            _ => G::hit_group(oxray::cuda::CudaHitGroupDesc {
                closest_hit: Some((&m, "__closesthit__mo")),
                any_hit: None,
                intersection: Some((&m, "__intersection__mo")),
            }),
        }
        .unwrap()
    };
    let groups = [g("rg"), g("ms"), g("ex"), g("hit")];
    assert_compiles_with_nvrtc(
        "the motion programs",
        &groups,
        PrimitiveTypeFlags::TRIANGLE
            | PrimitiveTypeFlags::CUSTOM
            | PrimitiveTypeFlags::SPHERE
            | PrimitiveTypeFlags::ROUND_CUBIC_BSPLINE,
    );
}
