//! Programs in CUDA C++ on the CUDA backend.
//!
//! Without a GPU: every test program, and the device header with every function it defines,
//! compiles with NVRTC (skipped with a message where libnvrtc is absent; `OXRAY_REQUIRE_NVRTC=1`
//! makes that a failure). With a GPU (skipped without one; `OXRAY_REQUIRE_GPU=1` makes that a
//! failure): the scenarios run and are compared with the CPU backend's programs.

use bytemuck::{Pod, Zeroable};
use glam::Vec3;
use oxray_core::{
    AccelBackend, BuildOptions, ExceptionCode, IndexBuffer, Instance, PipelineCompileOptions,
    PipelineLinkOptions, SbtRegion, ShaderBindingTable, TraversableHandle, TriangleInput,
    VertexBuffer,
};
use oxray_cuda::{
    compile_pipeline_ptx, Cuda, CudaBuffer, CudaContext, CudaError, CudaHitGroupDesc, CudaModule,
    CudaPipeline, CudaProgramGroup,
};
use std::sync::{Mutex, MutexGuard, OnceLock};

const TRIANGLE: &str = include_str!("../../oxray/examples/programs/triangle.cu");
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
        ptx.contains(".const .align 8 .b8 __oxray_launch[96]"),
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
    // Curves (guide §9.3): the CUDA backend builds none, but programs that read them compile.
    float4 cv[4];
    optixGetLinearCurveVertexData(cv);
    optixGetQuadraticBSplineVertexData(cv);
    optixGetQuadraticBSplineRocapsVertexData(cv);
    optixGetCubicBSplineVertexData(cv);
    optixGetCubicBSplineRocapsVertexData(cv);
    optixGetCatmullRomVertexData(cv);
    optixGetCatmullRomRocapsVertexData(cv);
    optixGetCubicBezierVertexData(cv);
    optixGetCubicBezierRocapsVertexData(cv);
    optixGetRibbonVertexData(cv);
    float2 rp = optixGetRibbonParameters();
    t += optixGetCurveParameter() + rp.y + cv[3].w;
    u += (unsigned int)optixGetPrimitiveType();
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
fn compiled_pipelines_are_kept_in_the_disk_cache() {
    if !nvrtc() {
        return;
    }
    let g = triangle_groups();
    let groups = [g.raygen, g.miss, g.hit];
    let compile = compile_options(3);
    let link = PipelineLinkOptions::default();
    let entry = oxray_cuda::pipeline_cache_entry((9, 0), &compile, &link, &groups).unwrap();
    let first = compile_pipeline_ptx((9, 0), &compile, &link, &groups).unwrap();
    assert_eq!(
        std::fs::read_to_string(&entry).unwrap(),
        first,
        "written to the cache"
    );
    // Served from the cache: a marked copy comes back as it is.
    let marked = format!("{first}\n// from the cache\n");
    std::fs::write(&entry, &marked).unwrap();
    assert_eq!(
        compile_pipeline_ptx((9, 0), &compile, &link, &groups).unwrap(),
        marked
    );
    // A damaged entry is compiled again and replaced.
    std::fs::write(&entry, "garbage").unwrap();
    assert_eq!(
        compile_pipeline_ptx((9, 0), &compile, &link, &groups).unwrap(),
        first
    );
    assert_eq!(std::fs::read_to_string(&entry).unwrap(), first);
    // Other options, another entry.
    let other = oxray_cuda::pipeline_cache_entry((8, 0), &compile, &link, &groups).unwrap();
    assert_ne!(other, entry);
}

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

// The triangle's programs run on both devices, pixel for pixel against the Rust programs, in
// the facade's examples test (`triangle_cpp`).

// The scenarios of suite.cu run on both backends in the facade's conformance suite
// (oxray/tests/conformance.rs), which compares the GPU with the CPU bit for bit.

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

const SUITE2: &str = include_str!("programs/suite2.cu");

/// Output words per launch index of the second suite.
const WORDS: usize = 48;

fn suite2_groups() -> Vec<(&'static str, CudaProgramGroup)> {
    let m = CudaModule::from_source(SUITE2);
    let hit = |is: Option<&'static str>, ch: &'static str, ah: Option<&'static str>| {
        CudaProgramGroup::hit_group(CudaHitGroupDesc {
            closest_hit: Some((&m, ch)),
            any_hit: ah.map(|n| (&m, n)),
            intersection: is.map(|n| (&m, n)),
        })
        .unwrap()
    };
    vec![
        (
            "rg_grid",
            CudaProgramGroup::raygen(&m, "__raygen__grid").unwrap(),
        ),
        (
            "rg_callables",
            CudaProgramGroup::raygen(&m, "__raygen__callables").unwrap(),
        ),
        (
            "ms_none",
            CudaProgramGroup::miss(Some((&m, "__miss__none"))).unwrap(),
        ),
        (
            "hg_sphere",
            hit(
                Some("__intersection__sphere"),
                "__closesthit__custom",
                Some("__anyhit__custom"),
            ),
        ),
        ("hg_tri", hit(None, "__closesthit__custom", None)),
        ("hg_xform", hit(None, "__closesthit__xform", None)),
        (
            "cl_scale",
            CudaProgramGroup::callables(Some((&m, "__direct_callable__scale")), None).unwrap(),
        ),
        (
            "cl_shoot",
            CudaProgramGroup::callables(None, Some((&m, "__continuation_callable__shoot")))
                .unwrap(),
        ),
        (
            "cl_both",
            CudaProgramGroup::callables(
                Some((&m, "__direct_callable__nested")),
                Some((&m, "__continuation_callable__shoot")),
            )
            .unwrap(),
        ),
    ]
}

fn suite2_options() -> PipelineCompileOptions {
    PipelineCompileOptions {
        num_payload_values: 16,
        num_attribute_values: 8,
        ..Default::default()
    }
}

#[test]
fn custom_primitives_callables_and_transforms_compile_with_nvrtc() {
    if !nvrtc() {
        return;
    }
    let groups: Vec<_> = suite2_groups().into_iter().map(|(_, g)| g).collect();
    for depth in [1, 2] {
        let link = PipelineLinkOptions {
            max_trace_depth: depth,
        };
        let ptx = compile_pipeline_ptx((9, 0), &suite2_options(), &link, &groups)
            .unwrap_or_else(|e| panic!("depth {depth}: {e}"));
        assert!(ptx.contains(".entry __oxray_pipeline"));
    }
    // Two attribute words (the default) drop the rest; the unit still compiles.
    let options = PipelineCompileOptions {
        num_attribute_values: 2,
        ..suite2_options()
    };
    compile_pipeline_ptx((8, 0), &options, &PipelineLinkOptions::default(), &groups)
        .unwrap_or_else(|e| panic!("{e}"));
}

/// A module calling the device functions the second suite does not.
const API2: &str = r#"
#include <optix.h>
extern "C" __constant__ unsigned long long params[2];
extern "C" __device__ void __direct_callable__nothing() {}
extern "C" __device__ float3 __continuation_callable__three(float a, float3 b, unsigned int c) {
    return make_float3(a + b.x, b.y, b.z + (float)c);
}
extern "C" __global__ void __raygen__all() {
    optixDirectCall<void>(0);
    float3 v = optixContinuationCall<float3, float, float3, unsigned int>(1, 1.0f, make_float3(1.0f, 2.0f, 3.0f), 4u);
    unsigned int u = optixUndefinedValue();
    u += (unsigned int)optixGetPrimitiveType(0xFEu) + optixIsFrontFaceHit(3u) + optixIsBackFaceHit(0xFFu);
    OptixTraversableHandle h = params[0];
    u += (unsigned int)optixGetTransformTypeFromHandle(h) + optixGetInstanceIdFromHandle(h);
    u += (unsigned int)optixGetInstanceChildFromHandle(h);
    const float4* m = optixGetInstanceTransformFromHandle(h);
    const float4* mi = optixGetInstanceInverseTransformFromHandle(h);
    const OptixStaticTransform* st = optixGetStaticTransformFromHandle(h);
    if (m && mi && st) u += __float_as_uint(m[0].x + mi[2].w + st->invTransform[11]) + (unsigned int)st->child;
    *reinterpret_cast<unsigned int*>(params[1]) = u + __float_as_uint(v.x);
}
extern "C" __global__ void __intersection__all() {
    optixSetPayloadTypes(OPTIX_PAYLOAD_TYPE_DEFAULT);
    float3 o = optixGetObjectRayOrigin();
    float3 d = optixGetObjectRayDirection();
    unsigned int k = optixGetPrimitiveIndex() + optixGetSbtGASIndex() + optixGetInstanceId()
        + optixGetInstanceIndex() + optixGetTransformListSize();
    float m[12];
    optixGetWorldToObjectTransformMatrix(m);
    if (optixReportIntersection(optixGetRayTmax() * 0.5f + o.x + d.y + m[3], k)) return;
    if (optixReportIntersection(1.0f, 1u, 1u)) return;
    optixReportIntersection(2.0f, 2u, 1u, 2u, 3u, 4u, 5u, 6u, 7u, 8u);
    (void)optixGetGASTraversableHandle();
    (void)optixGetTransformListHandle(0);
    (void)optixTransformPointFromWorldToObjectSpace(o);
    (void)optixTransformVectorFromWorldToObjectSpace(o);
    (void)optixTransformNormalFromWorldToObjectSpace(o);
}
extern "C" __global__ void __anyhit__all() {
    float3 v[3];
    optixGetTriangleVertexData(v);
    float m[12];
    optixGetObjectToWorldTransformMatrix(m);
    if (v[0].x + m[0] + __uint_as_float(optixGetAttribute_7()) > 1.0f) optixIgnoreIntersection();
}
extern "C" __global__ void __closesthit__all() {
    optixSetPayload_0(optixGetAttribute_2() + optixGetAttribute_3() + optixGetAttribute_4()
        + optixGetAttribute_5() + optixGetAttribute_6() + (unsigned int)optixGetPrimitiveType());
}
extern "C" __global__ void __exception__all() {
    const char* line = optixGetExceptionLineInfo();
    optixSetPayload_0(line == nullptr ? 1u : 0u);
}
"#;

#[test]
fn every_new_device_function_compiles_with_nvrtc() {
    if !nvrtc() {
        return;
    }
    let m = CudaModule::from_source(API2);
    let groups = [
        CudaProgramGroup::raygen(&m, "__raygen__all").unwrap(),
        CudaProgramGroup::hit_group(CudaHitGroupDesc {
            closest_hit: Some((&m, "__closesthit__all")),
            any_hit: Some((&m, "__anyhit__all")),
            intersection: Some((&m, "__intersection__all")),
        })
        .unwrap(),
        CudaProgramGroup::callables(
            Some((&m, "__direct_callable__nothing")),
            Some((&m, "__continuation_callable__three")),
        )
        .unwrap(),
        CudaProgramGroup::exception(&m, "__exception__all").unwrap(),
    ];
    for cc in [(8, 0), (9, 0)] {
        compile_pipeline_ptx(
            cc,
            &suite2_options(),
            &PipelineLinkOptions::default(),
            &groups,
        )
        .unwrap_or_else(|e| panic!("compute_{}{}: {e}", cc.0, cc.1));
    }
    // Entry names keep their prefixes.
    assert!(CudaProgramGroup::callables(None, None).is_err());
    assert!(
        CudaProgramGroup::callables(Some((&m, "__continuation_callable__three")), None).is_err()
    );
    assert!(CudaProgramGroup::hit_group(CudaHitGroupDesc {
        intersection: Some((&m, "__anyhit__all")),
        ..Default::default()
    })
    .is_err());
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Suite2Params {
    out: u64,
    handle: u64,
    width: u32,
    height: u32,
    ray_flags: u32,
    ray_mask: u32,
    z: f32,
    mode: u32,
    dc_index: u32,
    cc_index: u32,
}

struct Suite2 {
    ctx: CudaContext,
    pipeline: CudaPipeline,
    groups: Vec<(&'static str, CudaProgramGroup)>,
}

impl Suite2 {
    fn new(ctx: &CudaContext, depth: u32) -> Suite2 {
        let groups = suite2_groups();
        let list: Vec<_> = groups.iter().map(|(_, g)| g.clone()).collect();
        let pipeline = CudaPipeline::new(
            ctx,
            &suite2_options(),
            &PipelineLinkOptions {
                max_trace_depth: depth,
            },
            Some("params"),
            &list,
        )
        .unwrap();
        Suite2 {
            ctx: ctx.clone(),
            pipeline,
            groups,
        }
    }

    fn header(&self, name: &str) -> oxray_core::SbtHeader {
        self.groups
            .iter()
            .find(|(n, _)| *n == name)
            .unwrap()
            .1
            .pack_header()
    }

    /// Runs a launch of `dims[0] x dims[1]`; the 48 words of every launch index and the report.
    fn run(
        &self,
        handle: u64,
        sbt: &ShaderBindingTable,
        dims: [u32; 2],
        mode: u32,
        calls: [u32; 2],
    ) -> (Vec<Vec<u32>>, oxray_core::LaunchReport) {
        let n = (dims[0] * dims[1]) as usize;
        let out = CudaBuffer::<u32>::zeroed(&self.ctx, n * WORDS).unwrap();
        let params = Suite2Params {
            out: out.device_ptr(),
            handle,
            width: dims[0],
            height: dims[1],
            ray_flags: 0,
            ray_mask: 0xFF,
            z: 1.0,
            mode,
            dc_index: calls[0],
            cc_index: calls[1],
        };
        let report = self
            .pipeline
            .launch_with(&params, sbt, dims[0], dims[1], 1)
            .unwrap();
        let words = out.download().unwrap();
        (words.chunks(WORDS).map(<[u32]>::to_vec).collect(), report)
    }
}

/// A sphere record's data (`SphereData` in suite2.cu).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct SphereData {
    spheres: u64,
    prim_offset: u32,
    kind: u32,
}

/// Eight spheres of radius 0.2 at z = 0: a row at y = -0.5 (build input 0, primitives 0..3) and
/// one at y = 0.5 (input 1, primitive index offset 10).
fn spheres() -> Vec<[f32; 4]> {
    (0..8)
        .map(|k| {
            let (i, j) = (k % 4, k / 4);
            [-0.75 + 0.5 * i as f32, -0.5 + j as f32, 0.0, 0.2]
        })
        .collect()
}

fn sphere_gas(cuda: &Cuda) -> oxray_cuda::CudaGas {
    let boxes: Vec<oxray_core::Aabb> = spheres()
        .iter()
        .map(|s| {
            let c = Vec3::new(s[0], s[1], s[2]);
            oxray_core::Aabb::new(c - Vec3::splat(s[3]), c + Vec3::splat(s[3]))
        })
        .collect();
    let a = oxray_core::CustomPrimitiveInput::new(oxray_core::AabbBuffer::new(&boxes[..4]));
    let b = oxray_core::CustomPrimitiveInput::new(oxray_core::AabbBuffer::new(&boxes[4..]))
        .primitive_index_offset(10);
    let gas = cuda
        .build_gas(&BuildOptions::default(), &[a.into(), b.into()])
        .unwrap();
    assert_eq!(gas.kind(), oxray_bvh::GasKind::CustomPrimitives);
    gas
}

/// The sphere hit a ray from `o` down -z reports, as the intersection program computes it:
/// (sphere, t, normal).
fn expected_sphere(o: [f32; 3]) -> Option<(usize, f32, [f32; 3])> {
    let dir = [0.0f32, 0.0, -1.0];
    spheres().iter().enumerate().find_map(|(k, s)| {
        let (ox, oy, oz) = (o[0] - s[0], o[1] - s[1], o[2] - s[2]);
        let a = dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2];
        let b = ox * dir[0] + oy * dir[1] + oz * dir[2];
        let c = ox * ox + oy * oy + oz * oz - s[3] * s[3];
        let disc = b * b - a * c;
        if disc < 0.0 {
            return None;
        }
        let t = (-b - disc.sqrt()) / a;
        let n = [
            (ox + t * dir[0]) / s[3],
            (oy + t * dir[1]) / s[3],
            (oz + t * dir[2]) / s[3],
        ];
        Some((k, t, n))
    })
}

fn grid_origin(i: usize, dims: [u32; 2], z: f32) -> [f32; 3] {
    let (x, y) = (i as u32 % dims[0], i as u32 / dims[0]);
    [
        2.0 * (x as f32 + 0.5) / dims[0] as f32 - 1.0,
        2.0 * (y as f32 + 0.5) / dims[1] as f32 - 1.0,
        z,
    ]
}

fn close(a: f32, b: f32) -> bool {
    (a - b).abs() <= 1e-5 * (1.0 + b.abs())
}

#[test]
fn custom_primitives_run_their_intersection_and_any_hit_programs() {
    let Some((ctx, _lock)) = gpu() else { return };
    let cuda = Cuda::from_context(ctx.clone());
    let gas = sphere_gas(&cuda);
    let centres = CudaBuffer::<[f32; 4]>::from_slice(&ctx, &spheres()).unwrap();
    let s = Suite2::new(&ctx, 1);
    let data = |input: u64| SphereData {
        spheres: centres.device_ptr() + 64 * input,
        prim_offset: 10 * input as u32,
        kind: 5 + input as u32,
    };
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[s.header("rg_grid")]),
        miss: SbtRegion::from_headers(&[s.header("ms_none")]),
        hitgroup: SbtRegion::from_records(&[
            (s.header("hg_sphere"), data(0)),
            (s.header("hg_sphere"), data(1)),
        ]),
        ..Default::default()
    };
    let dims = [32, 16];
    let handle = gas.optix_handle().unwrap();
    for mode in [0, 1, 2, 3] {
        let (out, report) = s.run(handle, &sbt, dims, mode, [0, 0]);
        assert_eq!(report.exceptions, 0, "mode {mode}: {report:?}");
        let mut hits = 0;
        for (i, o) in out.iter().enumerate() {
            let origin = grid_origin(i, dims, 1.0);
            let expected = expected_sphere(origin);
            let visible = expected.filter(|&(k, _, _)| mode != 1 || k % 2 == 0);
            let Some((k, t, n)) = visible else {
                assert_eq!(o[0], 0, "mode {mode}, launch index {i}: {o:?}");
                if let Some((k, ..)) = expected {
                    assert_eq!(o[15], 2, "two reports of sphere {k} ignored");
                }
                continue;
            };
            hits += 1;
            let input = (k / 4) as u32;
            let prim = (k % 4) as u32 + 10 * input;
            assert_eq!(o[0], 1, "mode {mode}, launch index {i} hits sphere {k}");
            assert_eq!((o[1], o[2], o[3]), (prim, input, 5 + input), "index {i}");
            let t_got = f32::from_bits(o[4]);
            assert!(close(t_got, t), "t {t_got} vs {t}");
            for a in 0..3 {
                assert!(close(f32::from_bits(o[5 + a]), n[a]), "normal {a} of {o:?}");
            }
            assert_eq!((o[8], o[9], o[10]), (0, prim, 0xA5 | 6 << 8 | 7 << 16));
            assert_eq!(
                (o[11], o[12]),
                (u32::MAX, 0x100),
                "GAS root, custom, no facing"
            );
            assert_eq!(o[13], o[4], "any-hit saw the candidate's t as tmax");
            assert_eq!(o[15], 1, "one any-hit call");
            match mode {
                2 => assert_eq!(o[14], 0x200, "a report after terminate does nothing"),
                3 => assert_eq!(o[14], 0x100, "reports outside the interval are false"),
                _ => assert_eq!(o[14], 0),
            }
        }
        assert!(hits > 20, "mode {mode}: {hits} hits");
    }
    // With two attribute words, the others read 0.
    let mut options = suite2_options();
    options.num_attribute_values = 2;
    let list: Vec<_> = s.groups.iter().map(|(_, g)| g.clone()).collect();
    let p2 = CudaPipeline::new(
        &ctx,
        &options,
        &PipelineLinkOptions::default(),
        Some("params"),
        &list,
    )
    .unwrap();
    let out = CudaBuffer::<u32>::zeroed(&ctx, 32 * 16 * WORDS).unwrap();
    let params = Suite2Params {
        out: out.device_ptr(),
        handle,
        width: 32,
        height: 16,
        ray_flags: 0,
        ray_mask: 0xFF,
        z: 1.0,
        mode: 0,
        dc_index: 0,
        cc_index: 0,
    };
    let report = p2.launch_with(&params, &sbt, 32, 16, 1).unwrap();
    assert_eq!(report.exceptions, 0);
    let words = out.download().unwrap();
    let hit = words.chunks(WORDS).find(|o| o[0] == 1).unwrap();
    assert_eq!((hit[7], hit[8], hit[9], hit[10]), (0, 0, 0, 0));
}

#[test]
fn an_ias_mixes_triangle_and_custom_gases() {
    let Some((ctx, _lock)) = gpu() else { return };
    let cuda = Cuda::from_context(ctx.clone());
    let tris = TraversableHandle::from(quads(&cuda));
    let balls = TraversableHandle::from(sphere_gas(&cuda));
    use oxray_core::Transform;
    let instances = [
        Instance::new(tris)
            .transform(Transform::from_translation(Vec3::new(0.0, 0.0, -2.0)))
            .instance_id(3),
        Instance::new(balls)
            .transform(Transform::from_translation(Vec3::new(0.0, 0.0, 0.5)))
            .instance_id(4)
            .sbt_offset(2),
    ];
    let ias = cuda
        .build_ias(&BuildOptions::default(), &[(&instances[..]).into()])
        .unwrap();
    // The query kernels do not trace custom primitives.
    let rays = vec![oxray_core::Ray::new(Vec3::Z, -Vec3::Z); 4];
    let mut hits = vec![None; 4];
    assert!(ias.intersect_batch_into(&rays, &mut hits).is_err());
    let centres = CudaBuffer::<[f32; 4]>::from_slice(&ctx, &spheres()).unwrap();
    let s = Suite2::new(&ctx, 1);
    let data = |input: u64| SphereData {
        spheres: centres.device_ptr() + 64 * input,
        prim_offset: 10 * input as u32,
        kind: 5 + input as u32,
    };
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[s.header("rg_grid")]),
        miss: SbtRegion::from_headers(&[s.header("ms_none")]),
        hitgroup: SbtRegion::from_records(&[
            (s.header("hg_tri"), SphereData::default()),
            (s.header("hg_tri"), SphereData::default()),
            (s.header("hg_sphere"), data(0)),
            (s.header("hg_sphere"), data(1)),
        ]),
        ..Default::default()
    };
    let dims = [32, 16];
    let (out, report) = s.run(ias.optix_handle().unwrap(), &sbt, dims, 0, [0, 0]);
    assert_eq!(report.exceptions, 0, "{report:?}");
    let (mut balls, mut triangles) = (0, 0);
    for (i, o) in out.iter().enumerate() {
        let [x, y, _] = grid_origin(i, dims, 1.0);
        assert_eq!(o[0], 1, "launch index {i}");
        // The spheres' object space is the world shifted down by 0.5.
        match expected_sphere([x, y, 0.5]) {
            Some((k, t, _)) => {
                balls += 1;
                let input = (k / 4) as u32;
                assert_eq!(
                    (o[1], o[2], o[3]),
                    ((k % 4) as u32 + 10 * input, input, 5 + input)
                );
                assert!(close(f32::from_bits(o[4]), t));
                assert_eq!((o[11], o[12]), (4, 1 | 0x100));
            }
            None => {
                triangles += 1;
                assert_eq!(o[3], 0xFE, "a front-facing triangle");
                assert_eq!(f32::from_bits(o[4]), 3.0);
                assert_eq!(o[11], 3);
                assert_eq!(o[12], 0x200 | 0x800 | 0x1000, "instance 0, triangle, front");
                assert_eq!(o[2], (x >= 0.0) as u32);
            }
        }
    }
    assert!(
        balls > 20 && triangles > 20,
        "{balls} spheres, {triangles} triangles"
    );
}

/// The callables scenario's SBT: the callables ray-generation program with `raygen_data` in its
/// record, the miss and triangle groups, and three callables records (10, 20 and 30 as data).
fn callables_sbt(s: &Suite2, raygen_data: u32) -> ShaderBindingTable {
    ShaderBindingTable {
        raygen: SbtRegion::from_records(&[(s.header("rg_callables"), raygen_data)]),
        miss: SbtRegion::from_headers(&[s.header("ms_none")]),
        hitgroup: SbtRegion::from_headers(&[s.header("hg_tri"), s.header("hg_tri")]),
        callables: SbtRegion::from_records(&[
            (s.header("cl_scale"), 10.0f32),
            (s.header("cl_shoot"), 20.0),
            (s.header("cl_both"), 30.0),
        ]),
        ..Default::default()
    }
}

/// One pipeline launched again and again: every launch sees its own parameters and SBT (the host
/// skips the copies of what the device already holds) and reports its own exceptions and
/// traces, also after a launch that raised.
#[test]
fn repeated_launches_see_their_own_parameters_sbt_and_counts() {
    let Some((ctx, _lock)) = gpu() else { return };
    let cuda = Cuda::from_context(ctx.clone());
    let gas = quads(&cuda);
    let s = Suite2::new(&ctx, 1);
    let dims = [8, 2];
    let n = u64::from(dims[0] * dims[1]);
    let handle = gas.optix_handle().unwrap();
    // (the raygen record's data, the callables asked for); [5, 1] raises at its direct call,
    // before the continuation callable traces.
    let launches = [
        (0xCAFE, [0, 1]),
        (0xCAFE, [0, 1]),
        (0xBEEF, [0, 1]),
        (0xBEEF, [2, 2]),
        (0xBEEF, [5, 1]),
        (0xBEEF, [5, 1]),
        (0xBEEF, [2, 2]),
        (0xF00D, [0, 1]),
        (0xF00D, [0, 1]),
    ];
    for (k, (data, calls)) in launches.into_iter().enumerate() {
        let (out, report) = s.run(handle, &callables_sbt(&s, data), dims, 0, calls);
        if calls[0] == 5 {
            assert_eq!(report.exceptions, n, "launch {k}");
            assert_eq!(report.traces, 0, "launch {k}: no index reached its trace");
            continue;
        }
        assert_eq!(report.exceptions, 0, "launch {k}: {report:?}");
        assert_eq!(report.traces, n, "launch {k}: one trace per index");
        let base = if calls == [0, 1] { 20 } else { 30 };
        for (i, o) in out.iter().enumerate() {
            let x = (i as u32) % dims[0];
            assert_eq!(o[1], 1 + 100 * x + base, "launch {k}, index {i}");
            assert_eq!(
                (o[2], o[3]),
                (data, 0x600D),
                "launch {k}: this launch's record"
            );
        }
    }
}

#[test]
fn direct_and_continuation_callables() {
    let Some((ctx, _lock)) = gpu() else { return };
    let cuda = Cuda::from_context(ctx.clone());
    let gas = quads(&cuda);
    let s = Suite2::new(&ctx, 1);
    let sbt = callables_sbt(&s, 0xCAFE);
    let dims = [8, 2];
    let handle = gas.optix_handle().unwrap();
    for (calls, base) in [([0, 1], (0.0f32, 20)), ([2, 2], (30.0, 30))] {
        let (out, report) = s.run(handle, &sbt, dims, 0, calls);
        assert_eq!(report.exceptions, 0, "{calls:?}: {report:?}");
        for (i, o) in out.iter().enumerate() {
            let k = (i as u32) % dims[0];
            // x * k + 10, plus 30 through the nested call.
            let dc = 1.5f32 * k as f32 + 10.0 + base.0;
            assert_eq!(f32::from_bits(o[0]), dc, "{calls:?}, index {i}");
            assert_eq!(
                o[1],
                1 + 100 * k + base.1,
                "{calls:?}: the continuation traced a hit"
            );
            assert_eq!(
                (o[2], o[3]),
                (0xCAFE, 0x600D),
                "the caller's record is back"
            );
        }
    }
    // Bad indices and records without the callable asked for.
    let n = (dims[0] * dims[1]) as u64;
    for (calls, code, detail) in [
        ([5, 1], ExceptionCode::CALLABLE_INVALID_SBT, 5),
        ([1, 1], ExceptionCode::CALLABLE_NO_DC_SBT_RECORD, 1),
        ([0, 0], ExceptionCode::CALLABLE_NO_CC_SBT_RECORD, 0),
        ([0, 3], ExceptionCode::CALLABLE_INVALID_SBT, 3),
    ] {
        let (out, report) = s.run(handle, &sbt, dims, 0, calls);
        assert_eq!(report.exceptions, n, "{calls:?}");
        let e = &report.first_exceptions[0].1;
        assert_eq!((e.code, e.details()), (code, &[detail][..]), "{calls:?}");
        assert!(out.iter().all(|o| o[3] == 0), "the launch indices ended");
    }
    // Without a callables region every index is invalid.
    let empty = ShaderBindingTable {
        callables: SbtRegion::default(),
        ..sbt.clone()
    };
    let (_, report) = s.run(handle, &empty, dims, 0, [0, 0]);
    assert_eq!(
        report.first_exceptions[0].1.code,
        ExceptionCode::CALLABLE_INVALID_SBT
    );
}

#[test]
fn nested_instances_and_static_transforms_give_the_transform_list() {
    let Some((ctx, _lock)) = gpu() else { return };
    let cuda = Cuda::from_context(ctx.clone());
    use oxray_core::{StaticTransform, Transform};
    let gas = TraversableHandle::from(quads(&cuda));
    // GAS <- instance A (id 7, SBT offset 1, z - 1) in the inner IAS at index 1 <- static
    // transform S (scale 2 in x and y) <- instance B (id 9, SBT offset 2, a quarter turn about
    // z, x - 0.5, z - 1) in the outer IAS at index 1. Depth 4.
    let a = Transform::from_translation(Vec3::new(0.0, 0.0, -1.0));
    let st = Transform([2.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
    let b = Transform([
        0.0, -1.0, 0.0, -0.5, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, -1.0,
    ]);
    let inner = [
        Instance::new(TraversableHandle::NULL),
        Instance::new(gas.clone())
            .transform(a)
            .instance_id(7)
            .sbt_offset(1),
    ];
    let inner = cuda
        .build_ias(&BuildOptions::default(), &[(&inner[..]).into()])
        .unwrap();
    let s_node = StaticTransform::new(TraversableHandle::from(inner), st).unwrap();
    let outer = [
        Instance::new(TraversableHandle::NULL),
        Instance::new(TraversableHandle::from(s_node))
            .transform(b)
            .instance_id(9)
            .sbt_offset(2),
    ];
    let outer = cuda
        .build_ias(&BuildOptions::default(), &[(&outer[..]).into()])
        .unwrap();
    assert_eq!(oxray_core::Traversable::graph_depth(&outer), 4);
    assert!(!outer.is_queryable());
    let handle = outer.optix_handle().unwrap();
    let mut s = Suite2::new(&ctx, 1);
    let records: Vec<_> = (0..6u32).map(|k| (s.header("hg_xform"), k)).collect();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[s.header("rg_grid")]),
        miss: SbtRegion::from_headers(&[s.header("ms_none")]),
        hitgroup: SbtRegion::from_records(&records),
        ..Default::default()
    };
    let dims = [16, 8];
    // Deeper than the default graph depth (2): every trace raises.
    let (_, report) = s.run(handle, &sbt, dims, 0, [0, 0]);
    assert_eq!(report.exceptions, 128);
    assert_eq!(
        report.first_exceptions[0].1.code,
        ExceptionCode::TRAVERSAL_DEPTH_EXCEEDED
    );
    s.pipeline.set_max_traversable_graph_depth(4).unwrap();
    assert!(s.pipeline.set_max_traversable_graph_depth(32).is_err());
    let (out, report) = s.run(handle, &sbt, dims, 0, [0, 0]);
    assert_eq!(report.exceptions, 0, "{report:?}");
    let o2w = b.then_after(&st).then_after(&a);
    let [ai, si, bi] = [a, st, b].map(|t| t.inverse().unwrap());
    let w2o = ai.then_after(&si).then_after(&bi);
    let normal = Transform::transform_normal_with_inverse(&w2o, Vec3::X);
    let left = [
        [-1.0f32, -1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 1.0, 0.0],
        [-1.0, 1.0, 0.0],
    ];
    let idx = [[0usize, 1, 2], [0, 2, 3]];
    for (i, o) in out.iter().enumerate() {
        let [x, y, _] = grid_origin(i, dims, 1.0);
        assert_eq!(o[0], 3, "hit, and every round trip exact: index {i}");
        let object = w2o.transform_point(Vec3::new(x, y, -2.0));
        let input = (object.x >= 0.0) as u32;
        assert_eq!(o[1], input, "SBT-GAS index at {object:?}");
        let prim = o[2];
        assert!(prim / 2 == input, "primitive {prim} of input {input}");
        assert_eq!(
            [o[3], o[4], o[5]].map(f32::from_bits),
            normal.to_array(),
            "normal"
        );
        // The triangle's vertices in object space, in the input's order.
        for (v, &k) in idx[(prim % 2) as usize].iter().enumerate() {
            let mut p = left[k];
            p[0] += input as f32;
            let got = [o[6 + 3 * v], o[7 + 3 * v], o[8 + 3 * v]].map(f32::from_bits);
            assert_eq!(got, p, "vertex {v} of primitive {prim}");
        }
        assert_eq!(f32::from_bits(o[15]), 3.0, "t");
        let x = &o[16..];
        assert_eq!((x[0], x[1], x[2]), (7, 1, 3), "nearest instance, list size");
        assert_eq!(x[3], 4 | 1 << 4 | 4 << 8, "instance, static, instance");
        assert_eq!((x[4], x[5]), (9, 31), "root instance's id; handle queries");
        assert_eq!(f32::from_bits(x[6]), 2.0, "the static transform's matrix");
        assert_eq!(x[7], 3 + input, "SBT offsets summed: 1 + 2");
        for k in 0..12 {
            assert_eq!(f32::from_bits(x[8 + k]), o2w.0[k], "object to world [{k}]");
            assert_eq!(f32::from_bits(x[20 + k]), w2o.0[k], "world to object [{k}]");
        }
    }
    // One level below the limit still raises.
    s.pipeline.set_max_traversable_graph_depth(3).unwrap();
    let (_, report) = s.run(handle, &sbt, dims, 0, [0, 0]);
    assert_eq!(report.exceptions, 128);
}

/// Programs that read a few of the ray's and the hit's values: each is the closest-hit (and
/// miss) program of its own pipeline, whose fast-path traces store only what the sources name.
const READERS: [&str; 5] = [
    "o[0] = optixGetPrimitiveIndex(); const float2 b = optixGetTriangleBarycentrics(); \
     o[1] = __float_as_uint(b.x); o[2] = __float_as_uint(b.y); o[3] = optixGetAttribute_2();",
    "o[0] = optixGetHitKind(); o[1] = optixIsFrontFaceHit(); o[2] = optixGetSbtGASIndex(); \
     o[3] = optixGetPrimitiveType() ^ optixGetInstanceId();",
    "const float3 a = optixGetWorldRayOrigin(); const float3 d = optixGetObjectRayDirection(); \
     o[0] = __float_as_uint(a.x + 3.0f * a.y); o[1] = __float_as_uint(d.z); \
     o[2] = __float_as_uint(optixGetRayTmin()); o[3] = __float_as_uint(optixGetRayTime()) ^ \
     optixGetRayVisibilityMask();",
    "float3 v[3]; optixGetTriangleVertexData(v); o[0] = __float_as_uint(v[0].x + v[1].y); \
     o[1] = __float_as_uint(v[2].x); o[2] = optixGetGASTraversableHandle() != 0ull; \
     o[3] = optixGetRayFlags();",
    "o[0] = __float_as_uint(optixGetRayTmax());",
];

/// A pipeline over the quads whose programs write four words per launch index from `reader`,
/// and a fifth from the ray-generation record's data.
fn reader_source(reader: &str, all_named: bool) -> String {
    let names = if all_named {
        "// Every value is read, as far as the pipeline can tell: optixGetWorldRayOrigin \
         optixGetWorldRayDirection optixGetRayTmin optixGetRayTime optixGetRayVisibilityMask \
         optixGetPrimitiveIndex optixGetSbtGASIndex optixGetHitKind optixGetAttribute_0 \
         optixGetTriangleVertexData\n"
    } else {
        ""
    };
    format!(
        "#include <optix.h>\n{names}\
         struct Params {{ unsigned int* out; OptixTraversableHandle handle; unsigned int w; }};\n\
         extern \"C\" __constant__ Params params;\n\
         static __device__ void write(unsigned int* o) {{ {reader} }}\n\
         extern \"C\" __global__ void __raygen__grid() {{\n\
           const uint3 i = optixGetLaunchIndex();\n\
           const float x = -1.2f + 2.4f * (i.x + 0.5f) / params.w;\n\
           const float y = -1.2f + 2.4f * (i.y + 0.5f) / params.w;\n\
           unsigned int p0 = 7u, p1 = 7u, p2 = 7u, p3 = 7u;\n\
           optixTrace(params.handle, make_float3(x, y, 1.0f), make_float3(0.1f * x, 0.0f, -1.0f),\n\
                      0.25f, 10.0f, 0.5f, OptixVisibilityMask(0x35), 0u, 0u, 1u, 0u,\n\
                      p0, p1, p2, p3);\n\
           unsigned int* o = params.out + 5 * (i.y * params.w + i.x);\n\
           o[0] = p0; o[1] = p1; o[2] = p2; o[3] = p3;\n\
           o[4] = *reinterpret_cast<const unsigned int*>(optixGetSbtDataPointer());\n\
         }}\n\
         static __device__ void put() {{\n\
           unsigned int o[4] = {{0u, 0u, 0u, 0u}}; write(o);\n\
           optixSetPayload_0(o[0]); optixSetPayload_1(o[1]); optixSetPayload_2(o[2]);\n\
           optixSetPayload_3(o[3]);\n\
         }}\n\
         extern \"C\" __global__ void __closesthit__read() {{ put(); }}\n\
         extern \"C\" __global__ void __miss__read() {{ optixSetPayload_0(0xdeadu); }}\n"
    )
}

fn reader_groups(src: &str) -> Vec<CudaProgramGroup> {
    let m = CudaModule::from_source(src);
    vec![
        CudaProgramGroup::raygen(&m, "__raygen__grid").unwrap(),
        CudaProgramGroup::miss(Some((&m, "__miss__read"))).unwrap(),
        CudaProgramGroup::hit_group(CudaHitGroupDesc {
            closest_hit: Some((&m, "__closesthit__read")),
            ..Default::default()
        })
        .unwrap(),
    ]
}

/// A trace on the fast path stores only the values its pipeline's programs name (the reads of
/// `OXRAY_READS`), and what the programs read is the same as when every value is stored: the
/// origin, direction, tmin, time and mask (§13.3), the primitive, SBT-GAS index, instance id,
/// hit kind and facing (§13.7), barycentrics and attributes (§13.4), vertex data and the GAS
/// (§13.9); and the ray-generation program's record after its trace (§7).
#[test]
fn fast_path_traces_store_what_the_programs_read() {
    if !nvrtc() {
        return;
    }
    let link = PipelineLinkOptions::default();
    for reader in READERS {
        for all in [false, true] {
            compile_pipeline_ptx(
                (9, 0),
                &compile_options(4),
                &link,
                &reader_groups(&reader_source(reader, all)),
            )
            .unwrap_or_else(|e| panic!("{reader}: {e}"));
        }
    }
    let Some((ctx, _lock)) = gpu() else { return };
    let cuda = Cuda::from_context(ctx.clone());
    // The quads (two build inputs, so SBT-GAS indices 0 and 1), and the left one alone (one
    // SBT record: its hits need not look the SBT-GAS index up).
    let quads = quads(&cuda);
    let left = [
        [-1.0f32, -1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 1.0, 0.0],
        [-1.0, 1.0, 0.0],
    ];
    let idx = [[0u32, 1, 2], [0, 2, 3]];
    let one = TriangleInput::new(VertexBuffer::f32x3(&left)).indices(IndexBuffer::u32x3(&idx));
    let single = cuda
        .build_gas(&BuildOptions::default(), &[one.into()])
        .unwrap();
    let w = 24u32;
    #[repr(C)]
    #[derive(Clone, Copy, Pod, Zeroable)]
    struct Params {
        out: u64,
        handle: u64,
        w: u32,
        pad: u32,
    }
    for (reader, gas) in READERS.iter().flat_map(|r| [(r, &quads), (r, &single)]) {
        let handle = gas.optix_handle().unwrap();
        let run = |all: bool| {
            let groups = reader_groups(&reader_source(reader, all));
            let pipeline =
                CudaPipeline::new(&ctx, &compile_options(4), &link, Some("params"), &groups)
                    .unwrap();
            let sbt = ShaderBindingTable {
                // After its trace, the ray-generation program sees its own record again.
                raygen: SbtRegion::from_records(&[(groups[0].pack_header(), 0xC0FFEEu32)]),
                miss: SbtRegion::from_headers(&[groups[1].pack_header()]),
                // One record per build input of the quads.
                hitgroup: SbtRegion::from_headers(&[groups[2].pack_header(); 2]),
                ..Default::default()
            };
            let out = CudaBuffer::<u32>::zeroed(&ctx, (5 * w * w) as usize).unwrap();
            let params = Params {
                out: out.device_ptr(),
                handle,
                w,
                pad: 0,
            };
            let report = pipeline.launch_with(&params, &sbt, w, w, 1).unwrap();
            assert_eq!(report.exceptions, 0, "{reader}: {report:?}");
            out.download().unwrap()
        };
        let (some, every) = (run(false), run(true));
        let hits = some.chunks(5).filter(|o| o[0] != 0xdead).count();
        assert!(some.chunks(5).all(|o| o[4] == 0xC0FFEE), "{reader}");
        assert!(
            hits > 100 && hits < (w * w) as usize,
            "{reader}: {hits} hits"
        );
        assert_eq!(some, every, "{reader}");
    }
}
