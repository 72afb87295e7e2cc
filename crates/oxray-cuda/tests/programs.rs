//! Programs in CUDA C++ on the CUDA backend.
//!
//! Without a GPU: every test program, and the device header with every function it defines,
//! compiles with NVRTC (skipped with a message where libnvrtc is absent; `OXRAY_REQUIRE_NVRTC=1`
//! makes that a failure). With a GPU (skipped without one; `OXRAY_REQUIRE_GPU=1` makes that a
//! failure): the scenarios run and are compared with the CPU backend's programs.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use oxray_core::{
    AccelBackend, BuildOptions, ExceptionCode, IndexBuffer, Instance, InstanceFlags,
    PipelineCompileOptions, PipelineLinkOptions, RayFlags, SbtRegion, ShaderBindingTable,
    TraversableHandle, TriangleInput, VertexBuffer,
};
use oxray_cuda::{
    compile_pipeline_ptx, Cuda, CudaBuffer, CudaContext, CudaError, CudaHitGroupDesc, CudaModule,
    CudaPipeline, CudaProgramGroup,
};
use std::sync::{Mutex, MutexGuard, OnceLock};

const TRIANGLE: &str = include_str!("programs/triangle.cu");
const SUITE: &str = include_str!("programs/suite.cu");

/// Whether NVRTC can be used here (prints why not, or fails under `OXRAY_REQUIRE_NVRTC`).
fn nvrtc() -> bool {
    // SAFETY: only tries to open the library by its usual names (dlopen).
    if unsafe { cudarc::nvrtc::sys::is_culib_present() } {
        return true;
    }
    assert!(
        std::env::var_os("OXRAY_REQUIRE_NVRTC").is_none(),
        "OXRAY_REQUIRE_NVRTC is set but libnvrtc cannot be loaded"
    );
    println!("skipping: libnvrtc not found (set LD_LIBRARY_PATH to compile the programs)");
    false
}

fn gpu() -> Option<(CudaContext, MutexGuard<'static, ()>)> {
    static CTX: OnceLock<Result<CudaContext, CudaError>> = OnceLock::new();
    static LOCK: Mutex<()> = Mutex::new(());
    match CTX.get_or_init(CudaContext::new) {
        Ok(ctx) => Some((ctx.clone(), LOCK.lock().unwrap_or_else(|e| e.into_inner()))),
        Err(e) if e.is_unavailable() && std::env::var_os("OXRAY_REQUIRE_GPU").is_none() => {
            println!("skipping: {e}");
            None
        }
        Err(e) => panic!("CUDA is present but unusable: {e}"),
    }
}

struct TriangleGroups {
    raygen: CudaProgramGroup,
    miss: CudaProgramGroup,
    hit: CudaProgramGroup,
}

fn triangle_groups() -> TriangleGroups {
    let m = CudaModule::from_source(TRIANGLE);
    TriangleGroups {
        raygen: CudaProgramGroup::raygen(&m, "__raygen__rg").unwrap(),
        miss: CudaProgramGroup::miss(Some((&m, "__miss__ms"))).unwrap(),
        hit: CudaProgramGroup::hit_group(CudaHitGroupDesc {
            closest_hit: Some((&m, "__closesthit__ch")),
            ..Default::default()
        })
        .unwrap(),
    }
}

/// Every group of the suite, in a fixed order.
fn suite_groups() -> Vec<(&'static str, CudaProgramGroup)> {
    let m = CudaModule::from_source(SUITE);
    let hit = |ch: Option<&'static str>, ah: Option<&'static str>| {
        CudaProgramGroup::hit_group(CudaHitGroupDesc {
            closest_hit: ch.map(|n| (&m, n)),
            any_hit: ah.map(|n| (&m, n)),
            ..Default::default()
        })
        .unwrap()
    };
    vec![
        (
            "rg_grid",
            CudaProgramGroup::raygen(&m, "__raygen__grid").unwrap(),
        ),
        (
            "rg_index",
            CudaProgramGroup::raygen(&m, "__raygen__index").unwrap(),
        ),
        (
            "rg_throw",
            CudaProgramGroup::raygen(&m, "__raygen__throw").unwrap(),
        ),
        (
            "ms_ids",
            CudaProgramGroup::miss(Some((&m, "__miss__ids"))).unwrap(),
        ),
        (
            "ms_payload",
            CudaProgramGroup::miss(Some((&m, "__miss__payload"))).unwrap(),
        ),
        ("ms_none", CudaProgramGroup::miss(None).unwrap()),
        ("hg_ids", hit(Some("__closesthit__ids"), None)),
        ("hg_payload", hit(Some("__closesthit__payload"), None)),
        (
            "hg_skip_odd",
            hit(Some("__closesthit__ids"), Some("__anyhit__skip_odd")),
        ),
        (
            "hg_terminate",
            hit(Some("__closesthit__ids"), Some("__anyhit__terminate")),
        ),
        (
            "ex",
            CudaProgramGroup::exception(&m, "__exception__record").unwrap(),
        ),
    ]
}

fn compile_options(payload: u32) -> PipelineCompileOptions {
    PipelineCompileOptions {
        num_payload_values: payload,
        ..Default::default()
    }
}

#[test]
fn the_test_programs_compile_with_nvrtc() {
    if !nvrtc() {
        return;
    }
    let t = triangle_groups();
    let link = PipelineLinkOptions::default();
    let ptx = compile_pipeline_ptx(
        (9, 0),
        &compile_options(3),
        &link,
        &[t.raygen, t.miss, t.hit],
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert!(
        ptx.contains(".entry __oxray_pipeline"),
        "no pipeline kernel"
    );
    // The host finds these by name (cuModuleGetGlobal): they must not be mangled.
    assert!(ptx.contains(" params["), "no launch parameter variable");
    assert!(
        ptx.contains(".const .align 8 .b8 __oxray_launch[72]"),
        "launch information"
    );
    let groups: Vec<_> = suite_groups().into_iter().map(|(_, g)| g).collect();
    for depth in [1, 2] {
        for payload in [0, 8, 32] {
            let link = PipelineLinkOptions {
                max_trace_depth: depth,
            };
            compile_pipeline_ptx((9, 0), &compile_options(payload), &link, &groups)
                .unwrap_or_else(|e| panic!("payload {payload}, depth {depth}: {e}"));
        }
    }
}

/// A module calling every device function of the header, with every payload count.
const API: &str = r#"
#include <optix.h>
extern "C" __constant__ unsigned long long params[2];
extern "C" __global__ void __raygen__all() {
    uint3 i = optixGetLaunchIndex();
    uint3 d = optixGetLaunchDimensions();
    unsigned int p[32] = {};
    OptixTraversableHandle h = params[0];
    float3 o = make_float3(0.0f, 0.0f, 0.0f), dir = make_float3(0.0f, 0.0f, 1.0f);
    optixTrace(h, o, dir, 0.0f, 1.0f, 0.0f, OptixVisibilityMask(255), OPTIX_RAY_FLAG_NONE, 0, 1, 0);
    optixTrace(h, o, dir, 0.0f, 1.0f, 0.0f, 255u, OPTIX_RAY_FLAG_DISABLE_ANYHIT, 0, 1, 0, p[0]);
    optixTrace(OPTIX_PAYLOAD_TYPE_DEFAULT, h, o, dir, 0.0f, 1.0f, 0.0f, 255u,
               OPTIX_RAY_FLAG_TERMINATE_ON_FIRST_HIT | OPTIX_RAY_FLAG_DISABLE_CLOSESTHIT, 0, 1, 0,
               p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7]);
    optixTrace(h, o, dir, 0.0f, 1.0f, 0.0f, 255u, OPTIX_RAY_FLAG_CULL_BACK_FACING_TRIANGLES, 0, 1,
               0, p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], p[9], p[10], p[11], p[12],
               p[13], p[14], p[15], p[16], p[17], p[18], p[19], p[20], p[21], p[22], p[23], p[24],
               p[25], p[26], p[27], p[28], p[29], p[30], p[31]);
    CUdeviceptr sbt = optixGetSbtDataPointer();
    *reinterpret_cast<unsigned int*>(params[1]) = i.x + d.y + p[31] + (unsigned int)sbt;
    if (i.x == 1000000u) optixThrowException(3);
    if (i.x == 1000001u) optixThrowException(4, 1u, 2u, 3u, 4u, 5u, 6u, 7u, 8u);
}
extern "C" __global__ void __closesthit__all() {
    float3 a = optixGetWorldRayOrigin();
    float3 b = optixGetWorldRayDirection();
    float t = optixGetRayTmin() + optixGetRayTmax() + optixGetRayTime() + a.x + b.y;
    unsigned int u = optixGetRayFlags() + optixGetRayVisibilityMask() + optixGetPrimitiveIndex()
        + optixGetSbtGASIndex() + optixGetInstanceId() + optixGetInstanceIndex()
        + optixGetHitKind() + optixIsTriangleHit() + optixIsFrontFaceHit()
        + optixIsBackFaceHit() + optixIsTriangleFrontFaceHit() + optixIsTriangleBackFaceHit()
        + optixIsFrontFaceHit(optixGetHitKind()) + optixGetAttribute_0() + optixGetAttribute_1();
    float2 bc = optixGetTriangleBarycentrics();
    optixSetPayload_0(optixGetPayload_0() + u + __float_as_uint(t + bc.x));
    optixSetPayload_31(optixGetPayload_31() + optixGetPayload_7());
    optixSetPayload_8(optixGetPayload_15() + optixGetPayload_16() + optixGetPayload_23() + optixGetPayload_24());
}
extern "C" __global__ void __anyhit__all() {
    if (optixGetPrimitiveIndex() == 1u) optixIgnoreIntersection();
    else optixTerminateRay();
}
extern "C" __global__ void __miss__all() { optixSetPayload_1(1u); }
extern "C" __global__ void __exception__all() {
    optixSetPayload_0(0u);
    unsigned int x = (unsigned int)optixGetExceptionCode() + optixGetExceptionDetail_0()
        + optixGetExceptionDetail_7();
    (void)x;
}
"#;

#[test]
fn every_device_function_compiles_with_nvrtc() {
    if !nvrtc() {
        return;
    }
    let m = CudaModule::from_source(API);
    let groups = [
        CudaProgramGroup::raygen(&m, "__raygen__all").unwrap(),
        CudaProgramGroup::miss(Some((&m, "__miss__all"))).unwrap(),
        CudaProgramGroup::hit_group(CudaHitGroupDesc {
            closest_hit: Some((&m, "__closesthit__all")),
            any_hit: Some((&m, "__anyhit__all")),
            ..Default::default()
        })
        .unwrap(),
        CudaProgramGroup::exception(&m, "__exception__all").unwrap(),
    ];
    for cc in [(8, 0), (9, 0)] {
        compile_pipeline_ptx(
            cc,
            &compile_options(32),
            &PipelineLinkOptions::default(),
            &groups,
        )
        .unwrap_or_else(|e| panic!("compute_{}{}: {e}", cc.0, cc.1));
    }
}

#[test]
fn a_program_that_does_not_compile_fails_with_the_nvrtc_log() {
    if !nvrtc() {
        return;
    }
    let m = CudaModule::from_source(
        "extern \"C\" __global__ void __raygen__bad() { optixNoSuchFunction(); }",
    );
    let g = CudaProgramGroup::raygen(&m, "__raygen__bad").unwrap();
    match compile_pipeline_ptx(
        (9, 0),
        &compile_options(0),
        &PipelineLinkOptions::default(),
        &[g],
    ) {
        Err(CudaError::Compile { log, .. }) => {
            assert!(log.contains("optixNoSuchFunction"), "{log}");
            assert!(log.contains("module0.cu"), "errors name the module: {log}");
        }
        other => panic!("{other:?}"),
    }
}

// ---------------------------------------------------------------------------------------------
// On the GPU
// ---------------------------------------------------------------------------------------------

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct TriangleParams {
    image: u64,
    handle: u64,
    width: u32,
    height: u32,
    eye: [f32; 3],
    u: [f32; 3],
    v: [f32; 3],
    w: [f32; 3],
}

const TRI_VERTICES: [[f32; 3]; 3] = [[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0]];

fn camera(width: u32, height: u32) -> [Vec3; 4] {
    [
        Vec3::new(0.0, 0.0, -2.0),
        Vec3::X * (width as f32 / height as f32) * 0.5,
        Vec3::Y * 0.5,
        Vec3::Z,
    ]
}

/// The same programs as `programs/triangle.cu`, as Rust closures on the CPU backend.
fn triangle_on_the_cpu(width: u32, height: u32) -> Vec<[f32; 4]> {
    use oxray_cpu::{Gas, HitGroupDesc, Module, OutputBuffer, Pipeline, ProgramGroup, TraceRay};
    #[derive(Clone)]
    struct P<'a> {
        image: &'a OutputBuffer<[f32; 4]>,
        handle: TraversableHandle,
        cam: [Vec3; 4],
    }
    let image = OutputBuffer::new((width * height) as usize);
    let input = TriangleInput::new(VertexBuffer::f32x3(&TRI_VERTICES))
        .indices(IndexBuffer::u32x3(&[[0u32, 1, 2]]));
    let gas = Gas::build(&BuildOptions::default(), &[input.into()]).unwrap();
    let module = Module::<P>::new()
        .raygen("__raygen__rg", |ctx| {
            let [x, y, _] = ctx.launch_index();
            let [w, h, _] = ctx.launch_dimensions();
            let p = ctx.params();
            let dx = 2.0 * (x as f32 + 0.5) / w as f32 - 1.0;
            let dy = 1.0 - 2.0 * (y as f32 + 0.5) / h as f32;
            let [eye, u, v, wv] = p.cam;
            let dir = Vec3::new(
                u.x * dx + v.x * dy + wv.x,
                u.y * dx + v.y * dy + wv.y,
                u.z * dx + v.z * dy + wv.z,
            );
            let mut payload = [0u32; 3];
            ctx.trace(
                &TraceRay::new(&p.handle, eye, dir).interval(0.0, 1e16),
                &mut payload,
            )?;
            let [r, g, b] = payload.map(f32::from_bits);
            p.image.write((y * w + x) as usize, [r, g, b, 1.0]);
            Ok(())
        })
        .unwrap()
        .miss("__miss__ms", |ctx| {
            let bg = ctx.sbt_data::<[f32; 3]>().unwrap_or_default();
            for (i, c) in bg.into_iter().enumerate() {
                ctx.set_payload_f32(i, c);
            }
            Ok(())
        })
        .unwrap()
        .closest_hit("__closesthit__ch", |ctx| {
            let [b1, b2] = ctx.triangle_barycentrics();
            for (i, c) in [1.0 - b1 - b2, b1, b2].into_iter().enumerate() {
                ctx.set_payload_f32(i, c);
            }
            Ok(())
        })
        .unwrap();
    let raygen = ProgramGroup::raygen(&module, "__raygen__rg").unwrap();
    let miss = ProgramGroup::miss(Some((&module, "__miss__ms"))).unwrap();
    let hit = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__ch")),
        ..Default::default()
    })
    .unwrap();
    let pipeline = Pipeline::new(
        &Default::default(),
        &compile_options(3),
        &PipelineLinkOptions::default(),
        &[raygen.clone(), miss.clone(), hit.clone()],
    )
    .unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[raygen.pack_header()]),
        miss: SbtRegion::from_records(&[(miss.pack_header(), [0.3f32, 0.1, 0.2])]),
        hitgroup: SbtRegion::from_headers(&[hit.pack_header()]),
        ..Default::default()
    };
    let params = P {
        image: &image,
        handle: gas.into(),
        cam: camera(width, height),
    };
    let report = pipeline.launch(&params, &sbt, width, height, 1).unwrap();
    assert_eq!(report.exceptions, 0);
    image.to_vec()
}

#[test]
fn the_triangle_renders_as_on_the_cpu_pixel_for_pixel() {
    let Some((ctx, _lock)) = gpu() else { return };
    let (width, height) = (160, 120);
    let cuda = Cuda::from_context(ctx.clone());
    let input = TriangleInput::new(VertexBuffer::f32x3(&TRI_VERTICES))
        .indices(IndexBuffer::u32x3(&[[0u32, 1, 2]]));
    let gas = cuda
        .build_gas(&BuildOptions::default(), &[input.into()])
        .unwrap();
    let t = triangle_groups();
    let pipeline = CudaPipeline::new(
        &ctx,
        &compile_options(3),
        &PipelineLinkOptions::default(),
        Some("params"),
        &[t.raygen.clone(), t.miss.clone(), t.hit.clone()],
    )
    .unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[t.raygen.pack_header()]),
        miss: SbtRegion::from_records(&[(t.miss.pack_header(), [0.3f32, 0.1, 0.2])]),
        hitgroup: SbtRegion::from_headers(&[t.hit.pack_header()]),
        ..Default::default()
    };
    let image = CudaBuffer::<[f32; 4]>::zeroed(&ctx, (width * height) as usize).unwrap();
    let [eye, u, v, w] = camera(width, height);
    let params = TriangleParams {
        image: image.device_ptr(),
        handle: gas.optix_handle().unwrap(),
        width,
        height,
        eye: eye.to_array(),
        u: u.to_array(),
        v: v.to_array(),
        w: w.to_array(),
    };
    let report = pipeline
        .launch_with(&params, &sbt, width, height, 1)
        .unwrap();
    assert_eq!(report.exceptions, 0, "{report:?}");
    let gpu = image.download().unwrap();
    let cpu = triangle_on_the_cpu(width, height);
    let mut hits = 0;
    for (i, (g, c)) in gpu.iter().zip(&cpu).enumerate() {
        assert_eq!(
            g.map(f32::to_bits),
            c.map(f32::to_bits),
            "pixel {i}: {g:?} vs {c:?}"
        );
        hits += (c[0] != 0.3) as usize;
    }
    assert!(
        hits > 1000 && hits < gpu.len() - 1000,
        "{hits} pixels on the triangle"
    );
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
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

/// A suite pipeline over the named groups; the SBT's raygen, miss and hit records name the
/// given groups.
struct Suite {
    ctx: CudaContext,
    pipeline: CudaPipeline,
    groups: Vec<(&'static str, CudaProgramGroup)>,
}

impl Suite {
    fn new(ctx: &CudaContext, depth: u32) -> Suite {
        let groups = suite_groups();
        let list: Vec<_> = groups.iter().map(|(_, g)| g.clone()).collect();
        let pipeline = CudaPipeline::new(
            ctx,
            &compile_options(8),
            &PipelineLinkOptions {
                max_trace_depth: depth,
            },
            Some("params"),
            &list,
        )
        .unwrap();
        Suite {
            ctx: ctx.clone(),
            pipeline,
            groups,
        }
    }

    fn group(&self, name: &str) -> &CudaProgramGroup {
        &self.groups.iter().find(|(n, _)| *n == name).unwrap().1
    }

    fn sbt(
        &self,
        raygen: &str,
        miss: &str,
        hits: &[&str],
        exception: Option<&str>,
    ) -> ShaderBindingTable {
        ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[self.group(raygen).pack_header()]),
            miss: SbtRegion::from_headers(&[self.group(miss).pack_header()]),
            hitgroup: SbtRegion::from_headers(
                &hits
                    .iter()
                    .map(|h| self.group(h).pack_header())
                    .collect::<Vec<_>>(),
            ),
            exception: exception.map(|e| SbtRegion::from_headers(&[self.group(e).pack_header()])),
            ..Default::default()
        }
    }

    /// Runs a launch; returns the 8 words of every launch index and the report.
    fn run(
        &self,
        handle: u64,
        sbt: &ShaderBindingTable,
        dims: [u32; 3],
        flags: RayFlags,
        mask: u32,
    ) -> (Vec<[u32; 8]>, oxray_core::LaunchReport) {
        let n = (dims[0] * dims[1] * dims[2]) as usize;
        let out = CudaBuffer::<[u32; 8]>::zeroed(&self.ctx, n).unwrap();
        let params = SuiteParams {
            out: out.device_ptr(),
            handle,
            width: dims[0],
            height: dims[1],
            ray_flags: flags.bits(),
            ray_mask: mask,
            z: 1.0,
            pad: 0,
        };
        let report = self
            .pipeline
            .launch_with(&params, sbt, dims[0], dims[1], dims[2])
            .unwrap();
        (out.download().unwrap(), report)
    }
}

/// Two quads at z = 0 (primitives 0, 1: x < 0; 2, 3: x > 0) in two build inputs, so that the
/// SBT-GAS index is 0 on the left and 1 on the right.
fn quads(cuda: &Cuda) -> oxray_cuda::CudaGas {
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
    cuda.build_gas(&BuildOptions::default(), &[a.into(), b.into()])
        .unwrap()
}

#[test]
fn hits_misses_and_the_hit_group_formula() {
    let Some((ctx, _lock)) = gpu() else { return };
    let cuda = Cuda::from_context(ctx.clone());
    let gas = quads(&cuda);
    let s = Suite::new(&ctx, 1);
    let dims = [16, 8, 1];
    // One record per SBT-GAS index: both run the ids closest-hit.
    let sbt = s.sbt("rg_grid", "ms_ids", &["hg_ids", "hg_ids"], None);
    let (out, report) = s.run(
        gas.optix_handle().unwrap(),
        &sbt,
        dims,
        RayFlags::empty(),
        0xFF,
    );
    assert_eq!(report.exceptions, 0, "{report:?}");
    for (i, o) in out.iter().enumerate() {
        let x = i as u32 % dims[0];
        assert_eq!(o[0], 1, "launch index {i} hits");
        assert_eq!(o[1] >= 2, x >= dims[0] / 2, "primitive {} at x {x}", o[1]);
        assert_eq!(
            (o[2], o[3]),
            (u32::MAX, 0),
            "GAS root: instance id ~0, index 0"
        );
        let sbt_gas_index = o[4] >> 16;
        assert_eq!(sbt_gas_index, (x >= dims[0] / 2) as u32);
        // Rays go down -z onto counter-clockwise quads seen from +z: front faces.
        assert_eq!(o[4] & 0xFFFF, 0xFE | 0x100 | 0x200);
        assert_eq!(f32::from_bits(o[5]), 1.0, "t");
    }
    // Too few hit records: SBT-GAS index 1 raises INVALID_HIT_SBT.
    let sbt = s.sbt("rg_grid", "ms_ids", &["hg_ids"], None);
    let (_, report) = s.run(
        gas.optix_handle().unwrap(),
        &sbt,
        dims,
        RayFlags::empty(),
        0xFF,
    );
    assert_eq!(report.exceptions, (dims[0] * dims[1] / 2) as u64);
    assert_eq!(
        report.first_exceptions[0].1.code,
        ExceptionCode::INVALID_HIT_SBT
    );
    // Culling front faces: everything misses; the miss program sees the trace's flags.
    let sbt = s.sbt("rg_grid", "ms_ids", &["hg_ids", "hg_ids"], None);
    let flags = RayFlags::CULL_FRONT_FACING_TRIANGLES;
    let (out, _) = s.run(gas.optix_handle().unwrap(), &sbt, dims, flags, 0x0F);
    for o in &out {
        assert_eq!(o[0], 0);
        assert_eq!(f32::from_bits(o[5]), 1e16);
        assert_eq!((o[6], o[7]), (flags.bits(), 0x0F));
    }
    // A null handle misses.
    let (out, _) = s.run(0, &sbt, dims, RayFlags::empty(), 0xFF);
    assert!(out.iter().all(|o| o[0] == 0));
}

#[test]
fn payload_is_copied_in_and_out() {
    let Some((ctx, _lock)) = gpu() else { return };
    let cuda = Cuda::from_context(ctx.clone());
    let gas = quads(&cuda);
    let s = Suite::new(&ctx, 1);
    let sbt = s.sbt("rg_grid", "ms_payload", &["hg_payload", "hg_payload"], None);
    let (out, report) = s.run(
        gas.optix_handle().unwrap(),
        &sbt,
        [8, 4, 1],
        RayFlags::empty(),
        0xFF,
    );
    assert_eq!(report.exceptions, 0);
    for o in &out {
        assert_eq!(*o, [0xAAAA0011, 1, 2, 31, 4, 5, 6, 7 ^ 6]);
    }
    let (out, _) = s.run(0, &sbt, [8, 4, 1], RayFlags::empty(), 0xFF);
    for o in &out {
        assert_eq!(*o, [0xAAAA0022, 1, 102, 3, 4, 5, 6, 7]);
    }
}

#[test]
fn any_hit_ignores_and_terminates_and_ray_flags_override_it() {
    let Some((ctx, _lock)) = gpu() else { return };
    let cuda = Cuda::from_context(ctx.clone());
    // Four stacked quads along z: primitive k at z = -k (two triangles each: 2k, 2k + 1).
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
    let gas = cuda
        .build_gas(&BuildOptions::default(), &[input.into()])
        .unwrap();
    let handle = gas.optix_handle().unwrap();
    let s = Suite::new(&ctx, 1);
    let dims = [16, 16, 1];
    // No any-hit: the nearest layer (t = 1) is hit.
    let sbt = s.sbt("rg_grid", "ms_ids", &["hg_ids"], None);
    let (out, _) = s.run(handle, &sbt, dims, RayFlags::empty(), 0xFF);
    assert!(out.iter().all(|o| f32::from_bits(o[5]) == 1.0 && o[1] < 2));
    // Odd primitives ignored: the layers are the same quad, so a ray through an odd triangle
    // crosses only odd ones and misses; the others hit the even triangle of layer 0.
    let sbt = s.sbt("rg_grid", "ms_ids", &["hg_skip_odd"], None);
    let (out, _) = s.run(handle, &sbt, dims, RayFlags::empty(), 0xFF);
    assert!(
        out.iter()
            .all(|o| o[0] == 0 || (o[1] == 0 && f32::from_bits(o[5]) == 1.0)),
        "{out:?}"
    );
    assert!(out.iter().any(|o| o[0] == 0) && out.iter().any(|o| o[0] == 1));
    // DISABLE_ANYHIT makes it opaque again.
    let (out, _) = s.run(handle, &sbt, dims, RayFlags::DISABLE_ANYHIT, 0xFF);
    assert!(out.iter().all(|o| f32::from_bits(o[5]) == 1.0));
    // CULL_ENFORCED_ANYHIT removes every primitive whose any-hit is on.
    let (out, _) = s.run(handle, &sbt, dims, RayFlags::CULL_ENFORCED_ANYHIT, 0xFF);
    assert!(out.iter().all(|o| o[0] == 0));
    // An any-hit that terminates: the candidate becomes the closest hit, whichever layer it is.
    let sbt = s.sbt("rg_grid", "ms_ids", &["hg_terminate"], None);
    let (out, _) = s.run(handle, &sbt, dims, RayFlags::empty(), 0xFF);
    assert!(out.iter().all(|o| o[0] == 1));
    // DISABLE_CLOSESTHIT: a hit runs nothing; the payload comes back as sent.
    let sbt = s.sbt("rg_grid", "ms_ids", &["hg_ids"], None);
    let (out, _) = s.run(handle, &sbt, dims, RayFlags::DISABLE_CLOSESTHIT, 0xFF);
    assert!(out.iter().all(|o| o[0] == 0xAAAA0000 && o[1] == 1));
}

#[test]
fn one_level_of_instances() {
    let Some((ctx, _lock)) = gpu() else { return };
    let cuda = Cuda::from_context(ctx.clone());
    let gas = quads(&cuda);
    let h = TraversableHandle::from(gas);
    use oxray_core::Transform;
    // Instance 0 (id 40): the quads shifted to z = -1; instance 1 (id 41): at z = -3, flipped
    // facing, SBT offset 2; instance 2: mask 0x02 at z = -0.5.
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
    let ias = cuda
        .build_ias(&BuildOptions::default(), &[(&instances[..]).into()])
        .unwrap();
    let handle = ias.optix_handle().unwrap();
    let s = Suite::new(&ctx, 1);
    let dims = [16, 8, 1];
    let sbt = s.sbt("rg_grid", "ms_ids", &["hg_ids"; 4], None);
    // Mask 0x01: instance 2 is invisible; instance 0 is nearest (t = 2).
    let (out, report) = s.run(handle, &sbt, dims, RayFlags::empty(), 0x01);
    assert_eq!(report.exceptions, 0, "{report:?}");
    for o in &out {
        assert_eq!((o[0], o[2], o[3]), (1, 40, 0));
        assert_eq!(f32::from_bits(o[5]), 2.0);
    }
    // Mask 0xFF: instance 2 (t = 1.5).
    let (out, _) = s.run(handle, &sbt, dims, RayFlags::empty(), 0xFF);
    assert!(out
        .iter()
        .all(|o| (o[2], o[3], f32::from_bits(o[5])) == (42, 2, 1.5)));
    // Culling front faces: instances 0 and 2 are culled; instance 1 is flipped, so its
    // faces are back faces, hit through hit-group records 2 + SBT-GAS index.
    let (out, report) = s.run(
        handle,
        &sbt,
        dims,
        RayFlags::CULL_FRONT_FACING_TRIANGLES,
        0xFF,
    );
    assert_eq!(report.exceptions, 0);
    for o in &out {
        assert_eq!((o[0], o[2], o[3]), (1, 41, 1));
        assert_eq!(o[4] & 0xFFFF, 0xFF | 0x100, "a back-face triangle hit");
        assert_eq!(f32::from_bits(o[5]), 4.0);
    }
}

#[test]
fn launch_indices_in_one_two_and_three_dimensions() {
    let Some((ctx, _lock)) = gpu() else { return };
    let s = Suite::new(&ctx, 1);
    let sbt = s.sbt("rg_index", "ms_none", &[], None);
    for dims in [[37, 1, 1], [13, 7, 1], [5, 4, 3]] {
        let (out, report) = s.run(0, &sbt, dims, RayFlags::empty(), 0xFF);
        assert_eq!(report.exceptions, 0);
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let o = out[((z * dims[1] + y) * dims[0] + x) as usize];
                    assert_eq!(o, [x, y, z, dims[0], dims[1], dims[2], 0x600D, 0]);
                }
            }
        }
    }
}

#[test]
fn user_exceptions_end_the_launch_index_and_run_the_exception_program() {
    let Some((ctx, _lock)) = gpu() else { return };
    let s = Suite::new(&ctx, 1);
    let dims = [8, 3, 1];
    let sbt = s.sbt("rg_throw", "ms_none", &[], Some("ex"));
    let (out, report) = s.run(0, &sbt, dims, RayFlags::empty(), 0xFF);
    assert_eq!(report.exceptions, 3);
    assert_eq!(report.first_exceptions.len(), 3);
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
}
