//! One conformance suite, two backends (issue: programs on the GPU). Every scenario is a set of
//! CUDA C++ programs (oxray-cuda/tests/programs/suite.cu and conformance/extended.cu) run through
//! the device-neutral API on each device present: the CPU always (its programs compiled by the
//! host's C++ compiler against the CPU device header), and a CUDA device where there is one
//! (`OXRAY_REQUIRE_GPU=1` makes its absence a failure). Each backend must give the expected
//! values, and both backends the same words, bit for bit.
//!
//! Without a GPU, every program of the suite is still compiled to PTX with NVRTC where libnvrtc
//! can be loaded (`OXRAY_REQUIRE_NVRTC=1` makes its absence a failure), so a CUDA program that
//! does not compile fails here too.

mod common;

use common::{devices, name};
use glam::Vec3;
use oxray::programs::{HitGroupDesc, Module, Pipeline, ProgramGroup};
use oxray::{
    Aabb, BuildOptions, CustomPrimitiveInput, Device, ExceptionCode, IndexBuffer, Instance,
    InstanceFlags, LaunchReport, ModuleSource, PipelineCompileOptions, PipelineLinkOptions,
    RayFlags, SbtRegion, ShaderBindingTable, StaticTransform, Transform, TraversableHandle,
    TriangleInput, VertexBuffer,
};

const SUITE: &str = include_str!("../../oxray-cuda/tests/programs/suite.cu");
const EXTENDED: &str = include_str!("conformance/extended.cu");

/// What a group is made of: (label, kind, entries).
#[derive(Clone, Copy)]
enum G {
    Rg(&'static str),
    Ms(Option<&'static str>),
    Hit(
        Option<&'static str>,
        Option<&'static str>,
        Option<&'static str>,
    ),
    Ex(&'static str),
    Call(Option<&'static str>, Option<&'static str>),
}

/// A pipeline of one module's groups on one device.
struct Suite {
    device: Device,
    pipeline: Pipeline,
    groups: Vec<(&'static str, ProgramGroup)>,
}

impl Suite {
    fn new(
        device: &Device,
        source: &str,
        params: &str,
        depth: u32,
        spec: &[(&'static str, G)],
    ) -> Suite {
        let m: Module = device.create_module(ModuleSource::CudaCpp(source)).unwrap();
        let e = |n: Option<&'static str>| n.map(|n| (&m, n));
        let groups: Vec<(&'static str, ProgramGroup)> = spec
            .iter()
            .map(|&(label, g)| {
                let group = match g {
                    G::Rg(n) => ProgramGroup::raygen(&m, n),
                    G::Ms(Some(n)) => ProgramGroup::miss(&m, n),
                    G::Ms(None) => ProgramGroup::miss_none(device),
                    G::Hit(ch, ah, is) => ProgramGroup::hit_group(HitGroupDesc {
                        closest_hit: e(ch),
                        any_hit: e(ah),
                        intersection: e(is),
                    }),
                    G::Ex(n) => ProgramGroup::exception(&m, n),
                    G::Call(dc, cc) => ProgramGroup::callables(e(dc), e(cc)),
                };
                (label, group.unwrap_or_else(|e| panic!("{label}: {e}")))
            })
            .collect();
        let list: Vec<ProgramGroup> = groups.iter().map(|(_, g)| g.clone()).collect();
        let compile = PipelineCompileOptions {
            num_payload_values: 32,
            num_attribute_values: 3,
            ..Default::default()
        };
        let pipeline = device
            .create_pipeline(
                &compile,
                &PipelineLinkOptions {
                    max_trace_depth: depth,
                },
                Some(params),
                &list,
            )
            .unwrap_or_else(|e| panic!("{} pipeline: {e}", name(device)));
        Suite {
            device: device.clone(),
            pipeline,
            groups,
        }
    }

    fn header(&self, label: &str) -> oxray::SbtHeader {
        self.groups
            .iter()
            .find(|(n, _)| *n == label)
            .unwrap_or_else(|| panic!("no group {label}"))
            .1
            .pack_header()
    }

    fn sbt(
        &self,
        raygen: &str,
        miss: &[&str],
        hits: &[&str],
        exception: Option<&str>,
    ) -> ShaderBindingTable {
        let headers = |l: &[&str]| l.iter().map(|h| self.header(h)).collect::<Vec<_>>();
        ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[self.header(raygen)]),
            miss: SbtRegion::from_headers(&headers(miss)),
            hitgroup: SbtRegion::from_headers(&headers(hits)),
            exception: exception.map(|e| SbtRegion::from_headers(&[self.header(e)])),
            ..Default::default()
        }
    }

    /// Runs a launch with `params` whose first word is the output address; returns the 8 words
    /// of every launch index and the report.
    fn run<P: bytemuck::Pod>(
        &self,
        sbt: &ShaderBindingTable,
        dims: [u32; 3],
        params: impl FnOnce(u64) -> P,
    ) -> (Vec<[u32; 8]>, LaunchReport) {
        let n = (dims[0] * dims[1] * dims[2]) as usize;
        let out = self.device.create_buffer::<[u32; 8]>(n).unwrap();
        let p = params(out.device_ptr());
        let report = self
            .pipeline
            .launch_with(&p, sbt, dims[0], dims[1], dims[2])
            .unwrap_or_else(|e| panic!("{} launch: {e}", name(&self.device)));
        (out.download().unwrap(), report)
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct SuiteParams {
    out: u64,
    handle: u64,
    width: u32,
    height: u32,
    ray_flags: u32,
    ray_mask: u32,
    z: f32,
    pad: u32,
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct ExtParams {
    out: u64,
    handle: u64,
    width: u32,
    height: u32,
    spheres: u64,
    z: f32,
    mode: u32,
}

const SUITE_GROUPS: [(&str, G); 11] = [
    ("rg_grid", G::Rg("__raygen__grid")),
    ("rg_index", G::Rg("__raygen__index")),
    ("rg_throw", G::Rg("__raygen__throw")),
    ("ms_ids", G::Ms(Some("__miss__ids"))),
    ("ms_payload", G::Ms(Some("__miss__payload"))),
    ("ms_none", G::Ms(None)),
    ("hg_ids", G::Hit(Some("__closesthit__ids"), None, None)),
    (
        "hg_payload",
        G::Hit(Some("__closesthit__payload"), None, None),
    ),
    (
        "hg_skip_odd",
        G::Hit(Some("__closesthit__ids"), Some("__anyhit__skip_odd"), None),
    ),
    (
        "hg_terminate",
        G::Hit(Some("__closesthit__ids"), Some("__anyhit__terminate"), None),
    ),
    ("ex", G::Ex("__exception__record")),
];

fn suite(device: &Device, depth: u32) -> Suite {
    Suite::new(device, SUITE, "params", depth, &SUITE_GROUPS)
}

/// Runs `scenario` on every device and checks that all give the same result.
fn on_every_device<R: PartialEq + std::fmt::Debug>(scenario: impl Fn(&Device) -> R) {
    let results: Vec<(&str, R)> = devices().iter().map(|d| (name(d), scenario(d))).collect();
    for (n, r) in &results[1..] {
        assert_eq!(
            r, &results[0].1,
            "{n} and {} differ on the same scenario",
            results[0].0
        );
    }
}

/// Two quads at z = 0 (primitives 0, 1: x < 0; 2, 3: x > 0) in two build inputs, so that the
/// SBT-GAS index is 0 on the left and 1 on the right.
fn quads(device: &Device) -> oxray::Gas {
    let left = [
        [-1.0f32, -1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 1.0, 0.0],
        [-1.0, 1.0, 0.0],
    ];
    let right = left.map(|[x, y, z]| [x + 1.0, y, z]);
    let idx = [[0u32, 1, 2], [0, 2, 3]];
    let a = TriangleInput::new(VertexBuffer::f32x3(&left)).indices(IndexBuffer::u32x3(&idx));
    let b = TriangleInput::new(VertexBuffer::f32x3(&right))
        .indices(IndexBuffer::u32x3(&idx))
        .primitive_index_offset(2);
    device
        .build_gas(&BuildOptions::default(), &[a.into(), b.into()])
        .unwrap()
}

fn grid(out: u64, handle: u64, dims: [u32; 3], flags: RayFlags, mask: u32) -> SuiteParams {
    SuiteParams {
        out,
        handle,
        width: dims[0],
        height: dims[1],
        ray_flags: flags.bits(),
        ray_mask: mask,
        z: 1.0,
        pad: 0,
    }
}

#[test]
fn hits_misses_and_the_hit_group_formula_7_3() {
    on_every_device(|device| {
        let gas = quads(device);
        let handle = gas.optix_handle().unwrap();
        let s = suite(device, 1);
        let dims = [16, 8, 1];
        let sbt = s.sbt("rg_grid", &["ms_ids"], &["hg_ids", "hg_ids"], None);
        let (out, report) = s.run(&sbt, dims, |o| {
            grid(o, handle, dims, RayFlags::empty(), 0xFF)
        });
        assert_eq!(report.exceptions, 0, "{report:?}");
        for (i, o) in out.iter().enumerate() {
            let x = i as u32 % dims[0];
            assert_eq!(o[0], 1, "launch index {i} hits");
            assert_eq!(o[1] >= 2, x >= dims[0] / 2, "primitive {} at x {x}", o[1]);
            assert_eq!(
                (o[2], o[3]),
                (u32::MAX, 0),
                "GAS root: id ~0, index 0 (§13.7)"
            );
            assert_eq!(o[4] >> 16, (x >= dims[0] / 2) as u32, "SBT-GAS index");
            assert_eq!(
                o[4] & 0xFFFF,
                0xFE | 0x100 | 0x200,
                "front-face triangle hit"
            );
            assert_eq!(f32::from_bits(o[5]), 1.0, "t");
        }
        // Too few hit records: SBT-GAS index 1 raises INVALID_HIT_SBT.
        let short = s.sbt("rg_grid", &["ms_ids"], &["hg_ids"], None);
        let (_, bad) = s.run(&short, dims, |o| {
            grid(o, handle, dims, RayFlags::empty(), 0xFF)
        });
        assert_eq!(bad.exceptions, (dims[0] * dims[1] / 2) as u64);
        assert_eq!(
            bad.first_exceptions[0].1.code,
            ExceptionCode::INVALID_HIT_SBT
        );
        // Culling front faces: everything misses; the miss program sees the trace's values.
        let flags = RayFlags::CULL_FRONT_FACING_TRIANGLES;
        let (culled, _) = s.run(&sbt, dims, |o| grid(o, handle, dims, flags, 0x0F));
        for o in &culled {
            assert_eq!(o[0], 0);
            assert_eq!(f32::from_bits(o[5]), 1e16);
            assert_eq!((o[6], o[7]), (flags.bits(), 0x0F));
        }
        // A null handle misses (§13.2).
        let (null, _) = s.run(&sbt, dims, |o| grid(o, 0, dims, RayFlags::empty(), 0xFF));
        assert!(null.iter().all(|o| o[0] == 0));
        (out, bad.exceptions, culled, null)
    });
}

#[test]
fn payload_is_copied_in_and_out_14() {
    on_every_device(|device| {
        let gas = quads(device);
        let handle = gas.optix_handle().unwrap();
        let s = suite(device, 1);
        let sbt = s.sbt(
            "rg_grid",
            &["ms_payload"],
            &["hg_payload", "hg_payload"],
            None,
        );
        let dims = [8, 4, 1];
        let (hit, _) = s.run(&sbt, dims, |o| {
            grid(o, handle, dims, RayFlags::empty(), 0xFF)
        });
        assert!(hit
            .iter()
            .all(|o| *o == [0xAAAA0011, 1, 2, 31, 4, 5, 6, 7 ^ 6]));
        let (miss, _) = s.run(&sbt, dims, |o| grid(o, 0, dims, RayFlags::empty(), 0xFF));
        assert!(miss
            .iter()
            .all(|o| *o == [0xAAAA0022, 1, 102, 3, 4, 5, 6, 7]));
        (hit, miss)
    });
}

/// Four stacked quads along z: layer k at z = -k (triangles 2k, 2k + 1).
fn layers(device: &Device) -> oxray::Gas {
    let mut v = Vec::new();
    let mut t = Vec::new();
    for k in 0..4u32 {
        let z = -(k as f32);
        let b = v.len() as u32;
        v.extend([
            [-1.0f32, -1.0, z],
            [1.0, -1.0, z],
            [1.0, 1.0, z],
            [-1.0, 1.0, z],
        ]);
        t.extend([[b, b + 1, b + 2], [b, b + 2, b + 3]]);
    }
    let input = TriangleInput::new(VertexBuffer::f32x3(&v)).indices(IndexBuffer::u32x3(&t));
    device
        .build_gas(&BuildOptions::default(), &[input.into()])
        .unwrap()
}

#[test]
fn any_hit_ignores_and_terminates_and_ray_flags_override_it_13_2() {
    on_every_device(|device| {
        let gas = layers(device);
        let handle = gas.optix_handle().unwrap();
        let s = suite(device, 1);
        let dims = [16, 16, 1];
        let run = |hits: &str, flags: RayFlags| {
            let sbt = s.sbt("rg_grid", &["ms_ids"], &[hits], None);
            s.run(&sbt, dims, |o| grid(o, handle, dims, flags, 0xFF)).0
        };
        let opaque = run("hg_ids", RayFlags::empty());
        assert!(opaque
            .iter()
            .all(|o| f32::from_bits(o[5]) == 1.0 && o[1] < 2));
        let skip = run("hg_skip_odd", RayFlags::empty());
        assert!(skip
            .iter()
            .all(|o| o[0] == 0 || (o[1] == 0 && f32::from_bits(o[5]) == 1.0)));
        assert!(skip.iter().any(|o| o[0] == 0) && skip.iter().any(|o| o[0] == 1));
        let disabled = run("hg_skip_odd", RayFlags::DISABLE_ANYHIT);
        assert!(disabled.iter().all(|o| f32::from_bits(o[5]) == 1.0));
        let culled = run("hg_skip_odd", RayFlags::CULL_ENFORCED_ANYHIT);
        assert!(culled.iter().all(|o| o[0] == 0));
        let terminated = run("hg_terminate", RayFlags::empty());
        assert!(terminated.iter().all(|o| o[0] == 1));
        let no_ch = run("hg_ids", RayFlags::DISABLE_CLOSESTHIT);
        assert!(no_ch.iter().all(|o| o[0] == 0xAAAA0000 && o[1] == 1));
        // Which layer a terminating any-hit accepts depends on the traversal order, which the
        // guide leaves open: only that each ray hit is compared across devices.
        let terminated: Vec<u32> = terminated.iter().map(|o| o[0]).collect();
        (opaque, skip, disabled, culled, terminated, no_ch)
    });
}

#[test]
fn one_level_of_instances_5_4_and_13_7() {
    on_every_device(|device| {
        let gas = quads(device);
        let h = gas.handle();
        let instances = [
            Instance::new(h.clone())
                .transform(Transform::from_translation(Vec3::new(0.0, 0.0, -1.0)))
                .instance_id(40),
            Instance::new(h.clone())
                .transform(Transform::from_translation(Vec3::new(0.0, 0.0, -3.0)))
                .instance_id(41)
                .sbt_offset(2)
                .flags(InstanceFlags::FLIP_TRIANGLE_FACING),
            Instance::new(h)
                .transform(Transform::from_translation(Vec3::new(0.0, 0.0, -0.5)))
                .instance_id(42)
                .visibility_mask(0x02),
        ];
        let ias = device
            .build_ias(&BuildOptions::default(), &[(&instances[..]).into()])
            .unwrap();
        let handle = ias.optix_handle().unwrap();
        let s = suite(device, 1);
        let dims = [16, 8, 1];
        let sbt = s.sbt("rg_grid", &["ms_ids"], &["hg_ids"; 4], None);
        let (masked, report) = s.run(&sbt, dims, |o| {
            grid(o, handle, dims, RayFlags::empty(), 0x01)
        });
        assert_eq!(report.exceptions, 0, "{report:?}");
        assert!(masked
            .iter()
            .all(|o| (o[0], o[2], o[3], f32::from_bits(o[5])) == (1, 40, 0, 2.0)));
        let (all, _) = s.run(&sbt, dims, |o| {
            grid(o, handle, dims, RayFlags::empty(), 0xFF)
        });
        assert!(all
            .iter()
            .all(|o| (o[2], o[3], f32::from_bits(o[5])) == (42, 2, 1.5)));
        let (flipped, report) = s.run(&sbt, dims, |o| {
            grid(o, handle, dims, RayFlags::CULL_FRONT_FACING_TRIANGLES, 0xFF)
        });
        assert_eq!(report.exceptions, 0);
        for o in &flipped {
            assert_eq!((o[0], o[2], o[3]), (1, 41, 1));
            assert_eq!(o[4] & 0xFFFF, 0xFF | 0x100, "a back-face triangle hit");
            assert_eq!(f32::from_bits(o[5]), 4.0);
        }
        (masked, all, flipped)
    });
}

#[test]
fn launch_indices_in_one_two_and_three_dimensions_13_1() {
    on_every_device(|device| {
        let s = suite(device, 1);
        let sbt = s.sbt("rg_index", &["ms_none"], &[], None);
        let mut all = Vec::new();
        for dims in [[37, 1, 1], [13, 7, 1], [5, 4, 3]] {
            let (out, report) = s.run(&sbt, dims, |o| grid(o, 0, dims, RayFlags::empty(), 0xFF));
            assert_eq!(report.exceptions, 0);
            for z in 0..dims[2] {
                for y in 0..dims[1] {
                    for x in 0..dims[0] {
                        let o = out[((z * dims[1] + y) * dims[0] + x) as usize];
                        assert_eq!(o, [x, y, z, dims[0], dims[1], dims[2], 0x600D, 0]);
                    }
                }
            }
            all.push(out);
        }
        all
    });
}

#[test]
fn user_exceptions_end_the_launch_index_and_run_the_exception_program_13_14() {
    on_every_device(|device| {
        let s = suite(device, 1);
        let dims = [8, 3, 1];
        let sbt = s.sbt("rg_throw", &["ms_none"], &[], Some("ex"));
        let (out, report) = s.run(&sbt, dims, |o| grid(o, 0, dims, RayFlags::empty(), 0xFF));
        assert_eq!(report.exceptions, 3);
        assert_eq!(report.first_exceptions[0].0, [3, 0, 0]);
        assert_eq!(report.first_exceptions[1].1.code, ExceptionCode(7));
        for y in 0..3 {
            for x in 0..8u32 {
                let o = out[(y * 8 + x) as usize];
                if x == 3 {
                    assert_eq!(o[..5], [1, 0, 7, 3, y]);
                } else {
                    assert_eq!(o[..2], [1, 2]);
                }
            }
        }
        (out, report)
    });
}

// ----------------------------------------------------------------------------------------------
// The extended module
// ----------------------------------------------------------------------------------------------

const EXT_GROUPS: [(&str, G); 19] = [
    ("rg_grid", G::Rg("__raygen__ext_grid")),
    ("rg_calls", G::Rg("__raygen__callables")),
    ("rg_faults", G::Rg("__raygen__faults")),
    ("ms", G::Ms(Some("__miss__ext"))),
    (
        "hg_sphere",
        G::Hit(
            Some("__closesthit__custom"),
            None,
            Some("__intersection__sphere"),
        ),
    ),
    (
        "hg_sphere_filtered",
        G::Hit(
            Some("__closesthit__custom"),
            Some("__anyhit__custom_filter"),
            Some("__intersection__sphere"),
        ),
    ),
    ("hg_xform", G::Hit(Some("__closesthit__xform"), None, None)),
    (
        "hg_vertices",
        G::Hit(Some("__closesthit__vertices"), None, None),
    ),
    (
        "hg_recurse",
        G::Hit(Some("__closesthit__recurse"), None, None),
    ),
    ("hg_gas", G::Hit(Some("__closesthit__gas"), None, None)),
    ("rg_sbt", G::Rg("__raygen__sbt")),
    (
        "hg_record",
        G::Hit(Some("__closesthit__record"), None, None),
    ),
    (
        "hg_mark",
        G::Hit(Some("__closesthit__ah_seen"), Some("__anyhit__mark"), None),
    ),
    ("rg_payload32", G::Rg("__raygen__payload32")),
    (
        "hg_payload32",
        G::Hit(Some("__closesthit__payload32"), None, None),
    ),
    ("call_mix", G::Call(Some("__direct_callable__mix"), None)),
    (
        "call_probe",
        G::Call(None, Some("__continuation_callable__probe")),
    ),
    (
        "call_scale",
        G::Call(Some("__direct_callable__scale"), None),
    ),
    ("ex", G::Ex("__exception__ext")),
];

fn extended(device: &Device, depth: u32) -> Suite {
    Suite::new(device, EXTENDED, "ext", depth, &EXT_GROUPS)
}

fn ext(out: u64, handle: u64, dims: [u32; 3], spheres: u64, mode: u32) -> ExtParams {
    ExtParams {
        out,
        handle,
        width: dims[0],
        height: dims[1],
        spheres,
        z: 4.0,
        mode,
    }
}

/// Two spheres of radius 0.75 at x = -1 (primitive 4) and x = 1 (primitive 5), z = 0, as a
/// custom-primitive GAS with primitive index offset 4.
const SPHERES: [[f32; 4]; 2] = [[-1.0, 0.0, 0.0, 0.75], [1.0, 0.0, 0.0, 0.75]];

fn spheres_gas(device: &Device) -> oxray::Gas {
    let boxes: Vec<Aabb> = SPHERES
        .iter()
        .map(|s| {
            let c = Vec3::new(s[0], s[1], s[2]);
            Aabb::new(c - Vec3::splat(s[3]), c + Vec3::splat(s[3]))
        })
        .collect();
    let input = CustomPrimitiveInput::new(oxray::AabbBuffer::new(&boxes)).primitive_index_offset(4);
    device
        .build_gas(&BuildOptions::default(), &[input.into()])
        .unwrap()
}

#[test]
fn intersection_programs_report_custom_hits_13_4() {
    on_every_device(|device| {
        let gas = spheres_gas(device);
        let handle = gas.optix_handle().unwrap();
        // Sphere data indexed by primitive index (4 and 5).
        let mut data = vec![[0.0f32; 4]; 4];
        data.extend(SPHERES);
        let spheres = device.buffer_from_slice(&data).unwrap();
        let s = extended(device, 1);
        let dims = [32, 8, 1];
        let sbt = s.sbt("rg_grid", &["ms"], &["hg_sphere"], None);
        let (out, report) = s.run(&sbt, dims, |o| {
            ext(o, handle, dims, spheres.device_ptr(), 0)
        });
        assert_eq!(report.exceptions, 0, "{report:?}");
        let mut hits = 0;
        for (i, o) in out.iter().enumerate() {
            let (x, y) = (i as u32 % dims[0], i as u32 / dims[0]);
            let px = 4.0 * (x as f32 + 0.5) / dims[0] as f32 - 2.0;
            let py = 2.0 * (y as f32 + 0.5) / dims[1] as f32 - 1.0;
            let c = if px < 0.0 { -1.0 } else { 1.0 };
            let r2 = (px - c) * (px - c) + py * py;
            if r2 < 0.75 * 0.75 - 1e-4 {
                hits += 1;
                assert_eq!(o[0], 1, "ray {i} hits a sphere");
                assert_eq!(o[1], if px < 0.0 { 4 } else { 5 });
                assert_eq!(o[2] & 0xFF, 5, "the near side's hit kind");
                assert_eq!((o[2] >> 8) & 0xFF, 0, "SBT-GAS index");
                assert_eq!(o[2] >> 16, 0xFF, "no instance: id ~0 (low byte)");
                let t = f32::from_bits(o[3]);
                let expect = 4.0 - (0.75f32 * 0.75 - r2).sqrt();
                assert!((t - expect).abs() < 1e-4, "t {t} vs {expect}");
                let nz = f32::from_bits(o[6]);
                assert!(nz > 0.0, "the normal faces the ray's origin");
                assert_eq!(o[7], 1, "closest hit ran once, no any-hit");
            } else if r2 > 0.75 * 0.75 + 1e-4 {
                assert_eq!(o[0], 0, "ray {i} misses");
                assert_eq!(f32::from_bits(o[3]), 1e16);
            }
        }
        assert!(hits > 20);
        // With any-hit: sphere 4 (even) is ignored on both sides; sphere 5's near side (kind 5)
        // is accepted after one any-hit call.
        let sbt = s.sbt("rg_grid", &["ms"], &["hg_sphere_filtered"], None);
        let (filtered, _) = s.run(&sbt, dims, |o| {
            ext(o, handle, dims, spheres.device_ptr(), 0)
        });
        for (a, b) in out.iter().zip(&filtered) {
            if a[0] == 1 && a[1] == 4 {
                assert_eq!(b[0], 0, "sphere 4 ignored");
                assert_eq!(b[7], 0x200, "two any-hit calls, then the miss");
            } else if a[0] == 1 {
                assert_eq!(b[..7], a[..7]);
                assert_eq!(b[7], 0x100 + 1, "one any-hit call, then closest hit");
            }
        }
        (out, filtered)
    });
}

#[test]
fn direct_and_continuation_callables_15() {
    on_every_device(|device| {
        let gas = quads(device);
        let handle = gas.optix_handle().unwrap();
        let s = extended(device, 2);
        let salt = |g: &str, v: u32| (s.header(g), v);
        let sbt = ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[s.header("rg_calls")]),
            miss: SbtRegion::from_headers(&[s.header("ms")]),
            hitgroup: SbtRegion::from_headers(&[s.header("hg_vertices"); 2]),
            callables: SbtRegion::from_records(&[
                salt("call_mix", 1000),
                salt("call_mix", 2000),
                salt("call_probe", 0),
                salt("call_scale", 0),
            ]),
            exception: Some(SbtRegion::from_headers(&[s.header("ex")])),
        };
        let dims = [6, 1, 1];
        let (out, report) = s.run(&sbt, dims, |o| ext(o, handle, dims, 0, 0));
        assert_eq!(report.exceptions, 0, "{report:?}");
        for (x, o) in out.iter().enumerate() {
            let x = x as u32;
            assert_eq!(o[0], 0xCA11);
            assert_eq!(o[1], x * 31 + 7 + 1000, "the callable reads its own record");
            assert_eq!(o[2], (x + 1) * 31 + 100 + 2000);
            assert_eq!(f32::from_bits(o[3]), 1.5 * x as f32);
            assert!(
                o[4] == 1 || o[4] == 2,
                "the continuation traced a hit: {}",
                o[4]
            );
            assert_eq!(o[5], 0, "and a miss");
            assert_eq!(o[6], 0x600D);
        }
        let mut faults = Vec::new();
        for (mode, code) in [
            (1, ExceptionCode::CALLABLE_INVALID_SBT),
            (2, ExceptionCode::CALLABLE_NO_DC_SBT_RECORD),
            (3, ExceptionCode::CALLABLE_NO_CC_SBT_RECORD),
            (4, ExceptionCode::CALLABLE_PARAMETER_MISMATCH),
        ] {
            let (o, report) = s.run(&sbt, dims, |o| ext(o, handle, dims, 0, mode));
            assert_eq!(report.exceptions, dims[0] as u64, "mode {mode}");
            assert_eq!(report.first_exceptions[0].1.code, code, "mode {mode}");
            assert!(o
                .iter()
                .all(|w| w[0] == 0xCA11 && w[3] == 0xE0E0 && w[6] == 0));
            assert!(o.iter().all(|w| w[2] == code.0 as u32));
            faults.push(o);
        }
        (out, faults)
    });
}

#[test]
fn transforms_and_the_transform_list_13_11() {
    on_every_device(|device| {
        let gas = quads(device);
        // World <- IAS instance (id 7, x + 0.25) <- static transform (z - 1) <- GAS.
        let st = StaticTransform::new(
            gas.handle(),
            Transform::from_translation(Vec3::new(0.0, 0.0, -1.0)),
        )
        .unwrap();
        let inner = device
            .build_ias(
                &BuildOptions::default(),
                &[(&[Instance::new(TraversableHandle::from(st))
                    .instance_id(3)
                    .transform(Transform::from_translation(Vec3::new(0.0, 0.5, 0.0)))][..])
                    .into()],
            )
            .unwrap();
        let top = device
            .build_ias(
                &BuildOptions::default(),
                &[(&[Instance::new(inner.handle())
                    .instance_id(7)
                    .transform(Transform::from_translation(Vec3::new(0.25, 0.0, 0.0)))][..])
                    .into()],
            )
            .unwrap();
        let handle = top.optix_handle().unwrap();
        let mut s = extended(device, 1);
        // World, IAS, IAS, static transform, GAS: four levels (CUDA's default is two).
        s.pipeline.set_max_traversable_graph_depth(4).unwrap();
        let dims = [8, 4, 1];
        let sbt = s.sbt("rg_grid", &["ms"], &["hg_xform"; 2], None);
        let (out, report) = s.run(&sbt, dims, |o| ext(o, handle, dims, 0, 0));
        assert_eq!(report.exceptions, 0, "{report:?}");
        let mut hits = 0;
        for o in &out {
            if o[0] == 0 {
                continue;
            }
            hits += 1;
            // Three entries: instance, instance, static transform (types 4, 4, 1).
            assert_eq!(o[0], 1 + 3 + (4 << 8) + (4 << 12) + (1 << 16));
            assert_eq!(o[1], 3, "the nearest instance: id 3, index 0");
            let p = [o[2], o[3], o[4]].map(f32::from_bits);
            assert_eq!(p, [0.25, 0.5, -1.0], "the object origin in world space");
            assert_eq!(f32::from_bits(o[5]), 1.0, "a normal through translations");
            assert_eq!(f32::from_bits(o[6]), -0.25, "world-to-object x translation");
            assert_eq!(f32::from_bits(o[7]), 0.0, "there and back");
        }
        assert!(hits > 0);
        out
    });
}

#[test]
fn triangle_vertex_data_13_9() {
    on_every_device(|device| {
        let gas = quads(device);
        let handle = gas.optix_handle().unwrap();
        let s = extended(device, 1);
        let dims = [8, 4, 1];
        let sbt = s.sbt("rg_grid", &["ms"], &["hg_vertices"; 2], None);
        let (out, _) = s.run(&sbt, dims, |o| ext(o, handle, dims, 0, 0));
        let quad_left = [[-1.0f32, -1.0], [0.0, -1.0], [0.0, 1.0], [-1.0, 1.0]];
        let tri = [[0usize, 1, 2], [0, 2, 3]];
        for o in out.iter().filter(|o| o[0] == 1) {
            let p = o[1] as usize;
            let dx = if p >= 2 { 1.0 } else { 0.0 };
            let t = tri[p % 2];
            let got: Vec<f32> = o[2..8].iter().map(|w| f32::from_bits(*w)).collect();
            let want: Vec<f32> = t
                .iter()
                .flat_map(|&k| [quad_left[k][0] + dx, quad_left[k][1]])
                .collect();
            assert_eq!(got, want, "primitive {p}");
        }
        out
    });
}

#[test]
fn built_in_exceptions_invalid_miss_and_trace_depth_13_14() {
    on_every_device(|device| {
        let gas = quads(device);
        let handle = gas.optix_handle().unwrap();
        let s = extended(device, 2);
        let dims = [4, 1, 1];
        let sbt = s.sbt("rg_faults", &["ms"], &["hg_recurse"; 2], Some("ex"));
        let (miss, report) = s.run(&sbt, dims, |o| ext(o, 0, dims, 0, 1));
        assert_eq!(report.exceptions, 4);
        assert_eq!(
            report.first_exceptions[0].1.code,
            ExceptionCode::INVALID_MISS_SBT
        );
        assert!(miss
            .iter()
            .all(|o| o[0] == 0xFA17 && o[1] == 0 && o[3] == 0xE0E0));
        let (deep, report) = s.run(&sbt, dims, |o| ext(o, handle, dims, 0, 0));
        assert_eq!(report.exceptions, 4);
        assert_eq!(
            report.first_exceptions[0].1.code,
            ExceptionCode::TRACE_DEPTH_EXCEEDED
        );
        assert!(deep
            .iter()
            .all(|o| o[2] == ExceptionCode::TRACE_DEPTH_EXCEEDED.0 as u32));
        (miss, deep)
    });
}

/// Every program of the suite compiles for the GPU with NVRTC, GPU or not.
#[test]
fn the_suite_compiles_with_nvrtc() {
    use oxray::cuda::{CudaHitGroupDesc, CudaModule, CudaProgramGroup};
    if let Err(e) = oxray::cuda::compile_pipeline_ptx(
        (9, 0),
        &PipelineCompileOptions::default(),
        &PipelineLinkOptions::default(),
        &[CudaProgramGroup::raygen(
            &CudaModule::from_source("extern \"C\" __global__ void __raygen__x() {}"),
            "__raygen__x",
        )
        .unwrap()],
    ) {
        assert!(
            std::env::var_os("OXRAY_REQUIRE_NVRTC").is_none(),
            "OXRAY_REQUIRE_NVRTC is set but NVRTC fails: {e}"
        );
        println!("skipping: NVRTC is not available ({e})");
        return;
    }
    for (source, spec) in [(SUITE, &SUITE_GROUPS[..]), (EXTENDED, &EXT_GROUPS[..])] {
        let m = CudaModule::from_source(source);
        let e = |n: Option<&'static str>| n.map(|n| (&m, n));
        let mut groups = Vec::new();
        for &(label, g) in spec {
            let r = match g {
                G::Rg(n) => CudaProgramGroup::raygen(&m, n),
                G::Ms(n) => CudaProgramGroup::miss(e(n)),
                G::Hit(ch, ah, is) => CudaProgramGroup::hit_group(CudaHitGroupDesc {
                    closest_hit: e(ch),
                    any_hit: e(ah),
                    intersection: e(is),
                }),
                G::Ex(n) => CudaProgramGroup::exception(&m, n),
                G::Call(dc, cc) => CudaProgramGroup::callables(e(dc), e(cc)),
            };
            groups.push(r.unwrap_or_else(|e| panic!("{label}: {e}")));
        }
        let compile = PipelineCompileOptions {
            num_payload_values: 32,
            num_attribute_values: 3,
            ..Default::default()
        };
        oxray::cuda::compile_pipeline_ptx(
            (9, 0),
            &compile,
            &PipelineLinkOptions::default(),
            &groups,
        )
        .unwrap_or_else(|e| panic!("the suite does not compile for the GPU: {e}"));
    }
}

#[test]
fn validation_mode_checks_rays_and_fails_the_launch_4_3() {
    on_every_device(|device| {
        let gas = quads(device);
        let handle = gas.optix_handle().unwrap();
        let dims = [4, 1, 1];
        // Without validation a negative tmin is not checked (what the trace finds is undefined,
        // guide §13.2, so only the absence of an exception is compared).
        let s = extended(device, 2);
        let sbt = s.sbt("rg_faults", &["ms"], &["hg_vertices"; 2], None);
        let (plain, report) = s.run(&sbt, dims, |o| ext(o, handle, dims, 0, 3));
        assert_eq!(report.exceptions, 0);
        assert!(plain.iter().all(|o| o[0] == 0xFA17));
        // In validation mode it raises INVALID_RAY with the ray's bits, and the launch fails.
        let strict = device
            .clone()
            .with_context(oxray::DeviceContext::new().validation_mode(true));
        let s = extended(&strict, 2);
        let sbt = s.sbt("rg_faults", &["ms"], &["hg_vertices"; 2], Some("ex"));
        let out = strict.create_buffer::<[u32; 8]>(4).unwrap();
        let params = ext(out.device_ptr(), handle, dims, 0, 3);
        let err = s.pipeline.launch_with(&params, &sbt, 4, 1, 1).unwrap_err();
        let oxray::programs::ProgramError::Launch(oxray::LaunchError::ValidationFailure {
            index,
            exception,
        }) = err
        else {
            panic!("{err:?}");
        };
        assert_eq!(index, [0, 0, 0]);
        assert_eq!(exception.code, ExceptionCode::INVALID_RAY);
        assert_eq!(exception.details()[6], (-1.0f32).to_bits(), "tmin");
        let written = out.download().unwrap();
        assert!(written
            .iter()
            .all(|o| o[2] == ExceptionCode::INVALID_RAY.0 as u32));
        (plain, exception)
    });
}

#[test]
fn the_hit_gas_handle_is_the_traced_handle_13_7() {
    on_every_device(|device| {
        let gas = quads(device);
        let handle = gas.optix_handle().unwrap();
        let s = extended(device, 1);
        let dims = [8, 4, 1];
        let sbt = s.sbt("rg_grid", &["ms"], &["hg_gas"; 2], None);
        let (out, _) = s.run(&sbt, dims, |o| ext(o, handle, dims, 0, 0));
        assert!(out.iter().any(|o| o[0] == 1));
        for o in out.iter().filter(|o| o[0] == 1) {
            assert_eq!((o[1], o[2]), (1, 1), "optixGetGASTraversableHandle");
        }
        out
    });
}

/// Both device headers define the same device functions (a program that compiles for one
/// device compiles for the other, GPU-only intrinsics aside).
#[test]
fn both_device_headers_name_the_same_device_functions() {
    fn names(header: &str) -> std::collections::BTreeSet<String> {
        let mut out = std::collections::BTreeSet::new();
        for (i, _) in header.match_indices("optix") {
            let before = header[..i].chars().next_back();
            if before.is_some_and(|c| c.is_ascii_alphanumeric() || c == '_') {
                continue;
            }
            let name: String = header[i..]
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            if name.len() > 5 && name.as_bytes()[5].is_ascii_uppercase() {
                out.insert(name);
            }
        }
        out
    }
    let gpu = names(oxray::cuda::DEVICE_HEADER);
    let cpu = names(oxray::cpu::cxx::DEVICE_HEADER_CPU);
    assert!(gpu.len() > 50, "{} names", gpu.len());
    assert_eq!(
        gpu.symmetric_difference(&cpu).collect::<Vec<_>>(),
        Vec::<&String>::new(),
        "device functions in one header only"
    );
}

#[test]
fn the_sbt_index_uses_the_low_bits_of_the_trace_offset_and_stride_7_3() {
    on_every_device(|device| {
        let gas = quads(device);
        let handle = gas.optix_handle().unwrap();
        // Both sides through one instance of SBT offset 3, to add the instance's term.
        let inst = [Instance::new(gas.handle()).sbt_offset(3)];
        let ias = device
            .build_ias(&BuildOptions::default(), &[(&inst[..]).into()])
            .unwrap();
        let s = extended(device, 1);
        let records: Vec<_> = (0..24u32).map(|k| (s.header("hg_record"), k)).collect();
        let sbt = ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[s.header("rg_sbt")]),
            miss: SbtRegion::from_headers(&[s.header("ms")]),
            hitgroup: SbtRegion::from_records(&records),
            ..Default::default()
        };
        let dims = [8, 1, 1];
        let mut all = Vec::new();
        for (h, inst_offset) in [(handle, 0), (ias.optix_handle().unwrap(), 3)] {
            // (offset, stride): 0x12 & 0xF = 2; stride 0x13 & 0xF = 3.
            for (offset, stride) in [(0u32, 1u32), (1, 1), (2, 2), (0x12, 0x13), (5, 0)] {
                let mode = offset | (stride << 8);
                let (out, report) = s.run(&sbt, dims, |o| ext(o, h, dims, 0, mode));
                assert_eq!(report.exceptions, 0, "{report:?}");
                for (x, o) in out.iter().enumerate() {
                    let gas_index = (x >= 4) as u32;
                    assert_eq!((o[0], o[2]), (1, gas_index), "x {x}");
                    let expect = inst_offset + gas_index * (stride & 0xF) + (offset & 0xF);
                    assert_eq!(o[1], expect, "record for offset {offset} stride {stride}");
                }
                all.push(out);
            }
        }
        all
    });
}

#[test]
fn any_hit_precedence_geometry_instance_ray_13_2() {
    use oxray::{GeometryFlags, InstanceFlags};
    on_every_device(|device| {
        // The quads, the left input with DISABLE_ANYHIT.
        let left = [
            [-1.0f32, -1.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 1.0, 0.0],
            [-1.0, 1.0, 0.0],
        ];
        let right = left.map(|[x, y, z]| [x + 1.0, y, z]);
        let idx = [[0u32, 1, 2], [0, 2, 3]];
        let off = [GeometryFlags::DISABLE_ANYHIT];
        let on = [GeometryFlags::empty()];
        let a = TriangleInput::new(VertexBuffer::f32x3(&left))
            .indices(IndexBuffer::u32x3(&idx))
            .flags(&off);
        let b = TriangleInput::new(VertexBuffer::f32x3(&right))
            .indices(IndexBuffer::u32x3(&idx))
            .flags(&on);
        let gas = device
            .build_gas(&BuildOptions::default(), &[a.into(), b.into()])
            .unwrap();
        let s = extended(device, 1);
        let sbt = s.sbt("rg_grid", &["ms"], &["hg_mark"; 2], None);
        let dims = [4, 1, 1];
        let mut all = Vec::new();
        for iflags in [
            None,
            Some(InstanceFlags::empty()),
            Some(InstanceFlags::ENFORCE_ANYHIT),
            Some(InstanceFlags::DISABLE_ANYHIT),
        ] {
            let ias = iflags.map(|f| {
                let inst = [Instance::new(gas.handle()).flags(f)];
                device
                    .build_ias(&BuildOptions::default(), &[(&inst[..]).into()])
                    .unwrap()
            });
            let handle = match &ias {
                Some(i) => i.optix_handle().unwrap(),
                None => gas.optix_handle().unwrap(),
            };
            for rflags in [
                RayFlags::empty(),
                RayFlags::ENFORCE_ANYHIT,
                RayFlags::DISABLE_ANYHIT,
            ] {
                let (out, report) = s.run(&sbt, dims, |o| ext(o, handle, dims, 0, rflags.bits()));
                assert_eq!(report.exceptions, 0);
                // Rays 1 and 2 hit the left and the right input.
                for (x, gflag_off) in [(1usize, true), (2, false)] {
                    let o = out[x];
                    assert_eq!((o[0], o[1]), (1, (x == 2) as u32));
                    let mut expect = !gflag_off;
                    match iflags {
                        Some(f) if f.contains(InstanceFlags::DISABLE_ANYHIT) => expect = false,
                        Some(f) if f.contains(InstanceFlags::ENFORCE_ANYHIT) => expect = true,
                        _ => {}
                    }
                    if rflags.contains(RayFlags::DISABLE_ANYHIT) {
                        expect = false;
                    } else if rflags.contains(RayFlags::ENFORCE_ANYHIT) {
                        expect = true;
                    }
                    assert_eq!(
                        o[3] > 0,
                        expect,
                        "instance {iflags:?}, ray {rflags:?}, input {}",
                        (x == 2) as u32
                    );
                }
                all.push(out);
            }
        }
        all
    });
}

#[test]
fn thirty_two_payload_words_are_copied_in_and_out_14() {
    on_every_device(|device| {
        let gas = quads(device);
        let handle = gas.optix_handle().unwrap();
        let s = extended(device, 1);
        let sbt = s.sbt("rg_payload32", &["ms"], &["hg_payload32"; 2], None);
        let dims = [4, 1, 1];
        let (out, report) = s.run(&sbt, dims, |o| ext(o, handle, dims, 0, 0));
        assert_eq!(report.exceptions, 0, "{report:?}");
        let words: Vec<u32> = (0..32).map(|k| 1000 + k).collect();
        let folded = words
            .iter()
            .enumerate()
            .fold(0u32, |f, (k, w)| f ^ (w << (k % 8)));
        let sum = words[..31]
            .iter()
            .zip(0u32..)
            .fold(0u32, |s, (w, k)| s.wrapping_mul(31).wrapping_add(w * 3 + k));
        for o in &out {
            assert_eq!(o[..4], [sum, folded, 3000, 1030 * 3 + 30]);
        }
        out
    });
}
