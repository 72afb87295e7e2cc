//! Helpers shared by the integration tests: the brute-force reference for ray queries, the
//! deterministic random-number generator, the mesh generators (icosphere, subdivided cube), the
//! tiny OBJ reader and the Stanford bunny come from `oxray-testkit`; the proptest configuration
//! stays here.
//!
//! The devices of this machine and a runner that checks that every device gives the same
//! result are here too.
//!
//! Each test binary uses a different subset of these helpers.
#![allow(dead_code, unused_imports)]

pub use oxray_testkit::mesh::{
    bunny_path, grid_cube, icosphere, load_bunny, parse_obj, random_soup, Mesh, Tri,
};
pub use oxray_testkit::oracle::{
    check_closest, closest_of, hit_bits, reference_closest, reference_hits, HitBits, RefHit,
};
pub use oxray_testkit::Rng;

use oxray::programs::{HitGroupDesc, Module, Pipeline, ProgramGroup};
use oxray::{
    BackendKind, Device, LaunchReport, ModuleSource, PipelineCompileOptions, PipelineLinkOptions,
    PrimitiveTypeFlags, SbtRegion, ShaderBindingTable,
};

/// A proptest configuration with a fixed seed, so that every run checks the same cases and a
/// failure reproduces, and no regression files are written. `OXRAY_PROPTEST_SEED=<u64>` explores
/// other cases.
pub fn proptest_config(cases: u32) -> proptest::test_runner::Config {
    let seed = std::env::var("OXRAY_PROPTEST_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0x6f78_7261_7939);
    proptest::test_runner::Config {
        cases,
        rng_seed: proptest::test_runner::RngSeed::Fixed(seed),
        failure_persistence: None,
        max_shrink_iters: 2048,
        ..Default::default()
    }
}

/// The CPU traversal kernels this processor runs: the oracle tests run on each. The kernels it
/// lacks are named once, as skipped.
pub fn kernels() -> Vec<oxray::cpu::Isa> {
    static SKIPPED: std::sync::Once = std::sync::Once::new();
    SKIPPED.call_once(|| {
        for isa in oxray::cpu::Isa::ALL {
            if !isa.is_available() {
                eprintln!("skipping the {isa} traversal kernel: this processor lacks it");
            }
        }
    });
    oxray::cpu::Isa::available()
}

/// The devices to run on: the CPU, and CUDA device 0 if there is one (`OXRAY_REQUIRE_GPU=1`
/// makes a missing GPU a failure).
pub fn devices() -> Vec<Device> {
    let mut d = vec![Device::cpu()];
    match Device::cuda(0) {
        Ok(c) => d.push(c),
        Err(e) => {
            assert!(
                std::env::var_os("OXRAY_REQUIRE_GPU").is_none(),
                "OXRAY_REQUIRE_GPU is set but there is no CUDA device: {e}"
            );
            assert!(e.is_unavailable(), "CUDA is there but failed: {e}");
            println!("the CUDA half skips: {e}");
        }
    }
    d
}

/// The device's name in failure messages.
pub fn name(d: &Device) -> &'static str {
    match d.kind() {
        BackendKind::Cuda => "cuda",
        _ => "cpu",
    }
}

/// Runs `scenario` on every device and checks that all give the same result.
pub fn on_every_device<R: PartialEq + std::fmt::Debug>(scenario: impl Fn(&Device) -> R) {
    let results: Vec<(&str, R)> = devices().iter().map(|d| (name(d), scenario(d))).collect();
    for (n, r) in &results[1..] {
        if r != &results[0].1 {
            // Name the first difference rather than print two long results whole.
            let (a, b) = (format!("{r:?}"), format!("{:?}", results[0].1));
            let at = a.bytes().zip(b.bytes()).take_while(|(x, y)| x == y).count();
            let from = at.saturating_sub(200);
            let part = |s: &str| {
                s.get(from..(at + 200).min(s.len()))
                    .unwrap_or("")
                    .to_string()
            };
            panic!(
                "{n} and {} differ on the same scenario, at character {at}:\n  {n}: …{}…\n  {}: …{}…",
                results[0].0,
                part(&a),
                results[0].0,
                part(&b)
            );
        }
    }
}

/// What a [`Scene`] is made of: a module of CUDA C++ programs, the name of its launch-parameter
/// variable, its ray-generation and miss entries, and its hit groups as (label, closest hit,
/// any hit).
pub struct ScenePrograms {
    pub source: &'static str,
    pub params: &'static str,
    pub raygen: &'static str,
    pub miss: &'static str,
    pub hit_groups: &'static [(&'static str, &'static str, Option<&'static str>)],
}

/// A pipeline of one module's programs on one device (8 payload values, trace depth 1), with
/// its program groups by label: "rg", "ms", then the hit groups'.
pub struct Scene {
    pub device: Device,
    pub pipeline: Pipeline,
    pub groups: Vec<(&'static str, ProgramGroup)>,
}

impl Scene {
    /// The pipeline of `programs` on `device` for the primitive types `types`.
    pub fn new(device: &Device, programs: &ScenePrograms, types: PrimitiveTypeFlags) -> Scene {
        let m: Module = device
            .create_module(ModuleSource::CudaCpp(programs.source))
            .unwrap_or_else(|e| panic!("{}: {e}", name(device)));
        let mut groups = vec![
            ("rg", ProgramGroup::raygen(&m, programs.raygen).unwrap()),
            ("ms", ProgramGroup::miss(&m, programs.miss).unwrap()),
        ];
        for &(label, ch, ah) in programs.hit_groups {
            let g = ProgramGroup::hit_group(HitGroupDesc {
                closest_hit: Some((&m, ch)),
                any_hit: ah.map(|n| (&m, n)),
                intersection: None,
            });
            groups.push((label, g.unwrap()));
        }
        let list: Vec<ProgramGroup> = groups.iter().map(|(_, g)| g.clone()).collect();
        let compile = PipelineCompileOptions {
            num_payload_values: 8,
            uses_primitive_type_flags: types,
            ..Default::default()
        };
        let pipeline = device
            .create_pipeline(
                &compile,
                &PipelineLinkOptions { max_trace_depth: 1 },
                Some(programs.params),
                &list,
            )
            .unwrap_or_else(|e| panic!("{} pipeline: {e}", name(device)));
        Scene {
            device: device.clone(),
            pipeline,
            groups,
        }
    }

    /// The SBT of the raygen and miss groups and `records` hit-group records of group `hit`.
    pub fn sbt(&self, hit: &str, records: usize) -> ShaderBindingTable {
        let h = |l: &str| {
            self.groups
                .iter()
                .find(|(n, _)| *n == l)
                .unwrap()
                .1
                .pack_header()
        };
        ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[h("rg")]),
            miss: SbtRegion::from_headers(&[h("ms")]),
            hitgroup: SbtRegion::from_headers(&vec![h(hit); records]),
            ..Default::default()
        }
    }

    /// A `w` x `h` launch with the SBT `sbt` and the parameters `params` makes of the address
    /// of the output, 8 words per launch index: the output and the report.
    pub fn launch<P: bytemuck::Pod>(
        &self,
        sbt: &ShaderBindingTable,
        w: u32,
        h: u32,
        params: impl FnOnce(u64) -> P,
    ) -> (Vec<[u32; 8]>, LaunchReport) {
        let out = self
            .device
            .create_buffer::<[u32; 8]>((w * h) as usize)
            .unwrap();
        let report = self
            .pipeline
            .launch_with(&params(out.device_ptr()), sbt, w, h, 1)
            .unwrap_or_else(|e| panic!("{} launch: {e}", name(&self.device)));
        (out.download().unwrap(), report)
    }
}

/// Compiles a pipeline of CUDA C++ program groups to PTX with NVRTC for sm_90, GPU or not: a
/// program that does not compile fails the test; a missing NVRTC skips it, unless
/// `OXRAY_REQUIRE_NVRTC` is set (as in CI). `what` names the programs in messages.
pub fn assert_compiles_with_nvrtc(
    what: &str,
    groups: &[oxray::cuda::CudaProgramGroup],
    types: PrimitiveTypeFlags,
) {
    let compile = PipelineCompileOptions {
        num_payload_values: 8,
        uses_primitive_type_flags: types,
        ..Default::default()
    };
    match oxray::cuda::compile_pipeline_ptx(
        (9, 0),
        &compile,
        &PipelineLinkOptions::default(),
        groups,
    ) {
        Ok(ptx) => assert!(ptx.contains(".entry"), "no kernel in the PTX of {what}"),
        Err(e) => {
            let nvrtc_missing = matches!(e, oxray::cuda::CudaError::NoNvrtc(_));
            assert!(nvrtc_missing, "{what} do not compile for the GPU: {e}");
            assert!(
                std::env::var_os("OXRAY_REQUIRE_NVRTC").is_none(),
                "OXRAY_REQUIRE_NVRTC is set but NVRTC fails: {e}"
            );
            println!("skipping: NVRTC is not available ({e})");
        }
    }
}

/// Whether code after `optixIgnoreIntersection`, `optixTerminateRay` or a terminating report
/// runs on `device`: on CUDA they take effect but return (the documented deviation of
/// docs/gpu-backend.md, "Deviations": CUDA C++ has no way out of the calling program short of
/// ending the thread); on the CPU they do not return, as in OptiX. Everything else about them
/// is the same on every device.
pub fn code_after_runs(device: &Device) -> bool {
    device.kind() == BackendKind::Cuda
}

/// A hit group of a [`LabelledPipeline`]: (label, closest hit, any hit, intersection).
pub type HitSpec = (
    &'static str,
    Option<&'static str>,
    Option<&'static str>,
    Option<&'static str>,
);

/// What a [`LabelledPipeline`] is made of: one module of CUDA C++ programs, its
/// launch-parameter variable, its ray-generation, miss and hit groups and exception program by
/// label, and the compile and link options.
pub struct PipelineSpec<'a> {
    pub source: &'static str,
    pub params: &'static str,
    pub raygens: &'a [(&'static str, &'static str)],
    pub misses: &'a [(&'static str, &'static str)],
    pub hit_groups: &'a [HitSpec],
    pub exception: (&'static str, &'static str),
    pub compile: PipelineCompileOptions,
    pub max_trace_depth: u32,
}

/// A pipeline of one module's programs on one device with its program groups by label: the
/// spec's, and "ms_none", a miss group without a program.
pub struct LabelledPipeline {
    pub device: Device,
    pub pipeline: Pipeline,
    pub groups: Vec<(&'static str, ProgramGroup)>,
}

impl LabelledPipeline {
    pub fn new(device: &Device, spec: &PipelineSpec<'_>) -> LabelledPipeline {
        let m: Module = device
            .create_module(ModuleSource::CudaCpp(spec.source))
            .unwrap_or_else(|e| panic!("{}: {e}", name(device)));
        let e = |n: Option<&'static str>| n.map(|n| (&m, n));
        let mut groups = Vec::new();
        for &(label, entry) in spec.raygens {
            groups.push((label, ProgramGroup::raygen(&m, entry).unwrap()));
        }
        for &(label, entry) in spec.misses {
            groups.push((label, ProgramGroup::miss(&m, entry).unwrap()));
        }
        groups.push(("ms_none", ProgramGroup::miss_none(device).unwrap()));
        for &(label, ch, ah, is) in spec.hit_groups {
            let g = ProgramGroup::hit_group(HitGroupDesc {
                closest_hit: e(ch),
                any_hit: e(ah),
                intersection: e(is),
            });
            groups.push((label, g.unwrap_or_else(|e| panic!("{label}: {e}"))));
        }
        let (label, entry) = spec.exception;
        groups.push((label, ProgramGroup::exception(&m, entry).unwrap()));
        let list: Vec<ProgramGroup> = groups.iter().map(|(_, g)| g.clone()).collect();
        let pipeline = device
            .create_pipeline(
                &spec.compile,
                &PipelineLinkOptions {
                    max_trace_depth: spec.max_trace_depth,
                },
                Some(spec.params),
                &list,
            )
            .unwrap_or_else(|e| panic!("{} pipeline: {e}", name(device)));
        LabelledPipeline {
            device: device.clone(),
            pipeline,
            groups,
        }
    }

    /// The SBT header of the group labelled `label`.
    pub fn header(&self, label: &str) -> oxray::SbtHeader {
        self.groups
            .iter()
            .find(|(n, _)| *n == label)
            .unwrap_or_else(|| panic!("no group {label}"))
            .1
            .pack_header()
    }
}

/// The SBT scene of pipeline_sbt.rs and its CUDA C++ twins: three triangle inputs with 2, 1 and
/// 3 SBT records, per-primitive SBT index offsets (1, 0, 1, 0 and 2, 0, 1) and primitive index
/// offsets 100, 7 and 0; triangle `k` (over all inputs) lies around `(3k, 0, 0)`, nothing
/// around `(27, 0, 0)`. The GAS on `device`, and the `(sbtGASIndex, primitive index)` a hit on
/// each triangle reports (input 0: records 0..2; input 1: record 2; input 2: records 3..6).
pub fn three_input_gas(device: &Device) -> (oxray::Gas, Vec<(u32, u32)>) {
    use oxray::{BuildInput, BuildOptions, GeometryFlags, SbtIndexOffsets, TriangleInput};
    use oxray_testkit::mesh::{soup, tri_at};
    let tris: Vec<Tri> = (0..9)
        .map(|k| tri_at(3.0 * k as f32, 0.0, 0.0, 1.0))
        .collect();
    let v0 = soup(&tris[0..4]);
    let v1 = soup(&tris[4..6]);
    let v2 = soup(&tris[6..9]);
    let f2 = [GeometryFlags::empty(); 2];
    let f1 = [GeometryFlags::empty(); 1];
    let f3 = [GeometryFlags::empty(); 3];
    let o0 = [1u8, 0, 1, 0];
    let o2 = [2u16, 0, 1];
    let inputs: [BuildInput; 3] = [
        TriangleInput::new(oxray::VertexBuffer::f32x3(&v0))
            .flags(&f2)
            .sbt_index_offsets(SbtIndexOffsets::u8(&o0))
            .primitive_index_offset(100)
            .into(),
        TriangleInput::new(oxray::VertexBuffer::f32x3(&v1))
            .flags(&f1)
            .primitive_index_offset(7)
            .into(),
        TriangleInput::new(oxray::VertexBuffer::f32x3(&v2))
            .flags(&f3)
            .sbt_index_offsets(SbtIndexOffsets::u16(&o2))
            .into(),
    ];
    let gas = device
        .build_gas(&BuildOptions::default(), &inputs)
        .unwrap_or_else(|e| panic!("{}: {e}", name(device)));
    let expected = vec![
        (1, 100),
        (0, 101),
        (1, 102),
        (0, 103),
        (2, 7),
        (2, 8),
        (5, 0),
        (3, 1),
        (4, 2),
    ];
    (gas, expected)
}
