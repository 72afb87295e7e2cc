//! CUDA C++ programs on the CPU backend: compile, load, launch, trace; errors for programs
//! that cannot run on a CPU or misbehave; the cache; determinism.
#![cfg(unix)]

use oxray_core::sbt::SbtRegion;
use oxray_core::{
    BuildOptions, DeviceContext, PipelineCompileOptions, PipelineLinkOptions, ShaderBindingTable,
    TraversableHandle, TriangleInput, VertexBuffer,
};
use oxray_cpu::cxx::{
    CxxError, CxxHitGroupDesc, CxxModule, CxxPipeline, CxxProgramGroup, HostBuffer,
};
use oxray_cpu::Gas;

const SRC: &str = r#"
#include <optix.h>
struct Params { unsigned int* out; OptixTraversableHandle handle; };
extern "C" __constant__ Params params;
extern "C" __global__ void __raygen__main() {
    const uint3 i = optixGetLaunchIndex();
    unsigned int p0 = 0, p1 = 0;
    float x = (i.x + 0.5f) / 4.0f - 0.5f;
    optixTrace(params.handle, make_float3(x, 0.25f, 1.0f), make_float3(0.0f, 0.0f, -1.0f),
               0.0f, 10.0f, 0.0f, 255u, 0u, 0u, 1u, 0u, p0, p1);
    params.out[2 * i.x] = p0;
    params.out[2 * i.x + 1] = p1;
}
extern "C" __global__ void __closesthit__ch() {
    optixSetPayload_0(1u + optixGetPrimitiveIndex());
    optixSetPayload_1(__float_as_uint(optixGetRayTmax()));
}
extern "C" __global__ void __miss__ms() { optixSetPayload_0(0xDEADu); }
"#;

#[test]
fn a_cuda_cpp_pipeline_traces_on_the_cpu() {
    let module = CxxModule::from_source(SRC);
    let rg = CxxProgramGroup::raygen(&module, "__raygen__main").unwrap();
    let ms = CxxProgramGroup::miss(Some((&module, "__miss__ms"))).unwrap();
    let hg = CxxProgramGroup::hit_group(CxxHitGroupDesc {
        closest_hit: Some((&module, "__closesthit__ch")),
        ..Default::default()
    })
    .unwrap();
    let pipeline = CxxPipeline::new(
        &DeviceContext::default(),
        &PipelineCompileOptions::default(),
        &PipelineLinkOptions::default(),
        Some("params"),
        &[rg.clone(), ms.clone(), hg.clone()],
    )
    .unwrap();
    let v = [[-1.0f32, -1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
    let gas = Gas::build(
        &BuildOptions::default(),
        &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()],
    )
    .unwrap();
    let handle = TraversableHandle::from(gas);
    let out = HostBuffer::<u32>::zeroed(8);
    #[repr(C)]
    #[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
    struct Params {
        out: u64,
        handle: u64,
    }
    let params = Params {
        out: out.device_ptr(),
        handle: oxray_cpu::cxx::optix_handle(&handle),
    };
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_headers(&[ms.pack_header()]),
        hitgroup: SbtRegion::from_headers(&[hg.pack_header()]),
        ..Default::default()
    };
    let report = pipeline.launch_with(&params, &sbt, 4, 1, 1).unwrap();
    assert_eq!(report.exceptions, 0);
    let o = out.download();
    // x = -0.375, -0.125 hit the triangle (x in [-1, 0] below the edge); 0.125, 0.375 miss.
    assert_eq!(o[0], 1);
    assert_eq!(f32::from_bits(o[1]), 1.0);
    assert_eq!(o[2], 1);
    assert_eq!(o[4], 0xDEAD);
    assert_eq!(o[6], 0xDEAD);
}

fn pipeline_of(groups: &[CxxProgramGroup], params: Option<&str>) -> Result<CxxPipeline, CxxError> {
    CxxPipeline::new(
        &DeviceContext::default(),
        &PipelineCompileOptions::default(),
        &PipelineLinkOptions::default(),
        params,
        groups,
    )
}

#[test]
fn gpu_only_intrinsics_fail_to_compile_with_a_message_naming_them() {
    let m = CxxModule::from_source(
        "#include <optix.h>\nextern \"C\" __global__ void __raygen__sync() { __syncthreads(); }\n",
    );
    let rg = CxxProgramGroup::raygen(&m, "__raygen__sync").unwrap();
    match pipeline_of(&[rg], None) {
        Err(e @ CxxError::Compile { .. }) => {
            let CxxError::Compile { gpu_only, .. } = &e else {
                unreachable!()
            };
            assert_eq!(gpu_only, &["__syncthreads"]);
            assert!(
                e.to_string()
                    .contains("GPU-only intrinsics (__syncthreads)"),
                "{e}"
            );
        }
        other => panic!("{other:?}"),
    }
    // A plain syntax error is a compile error without GPU-only names.
    let m = CxxModule::from_source("extern \"C\" __global__ void __raygen__bad() { oops }\n");
    let rg = CxxProgramGroup::raygen(&m, "__raygen__bad").unwrap();
    match pipeline_of(&[rg], None) {
        Err(CxxError::Compile { gpu_only, log }) => {
            assert!(gpu_only.is_empty());
            assert!(log.contains("oops"), "{log}");
        }
        other => panic!("{other:?}"),
    }
}

const MISUSE: &str = r#"
#include <optix.h>
struct Params { unsigned int* out; OptixTraversableHandle handle; unsigned int mode; unsigned int pad; };
extern "C" __constant__ Params params;
extern "C" __global__ void __raygen__main() {
    const unsigned int i = optixGetLaunchIndex().x;
    params.out[i] = 1u;
    if (params.mode == 1u) throw 42;            // a C++ exception of the program's own
    if (params.mode == 2u) optixGetPayload_0(); // no payload in ray generation
    if (params.mode == 3u) optixThrowException(5, i, 9u);
    params.out[i] = 2u;
}
"#;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct MisuseParams {
    out: u64,
    handle: u64,
    mode: u32,
    pad: u32,
}

#[test]
fn misbehaving_programs_end_their_launch_index_with_an_exception() {
    let m = CxxModule::from_source(MISUSE);
    let rg = CxxProgramGroup::raygen(&m, "__raygen__main").unwrap();
    let p = pipeline_of(std::slice::from_ref(&rg), Some("params")).unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        ..Default::default()
    };
    let out = HostBuffer::<u32>::zeroed(4);
    let run = |mode| {
        let params = MisuseParams {
            out: out.device_ptr(),
            handle: 0,
            mode,
            pad: 0,
        };
        let r = p.launch_with(&params, &sbt, 4, 1, 1).unwrap();
        (r, out.download())
    };
    let (r, o) = run(0);
    assert_eq!((r.exceptions, o), (0, vec![2; 4]));
    let (r, o) = run(1);
    assert_eq!(r.exceptions, 4);
    let e = &r.first_exceptions[0].1;
    assert_eq!(e.code.0, oxray_cpu::cxx::PROGRAM_ERROR_CODE);
    assert_eq!(e.details(), &[1]);
    assert_eq!(o, vec![1; 4], "nothing after the throw ran");
    let (r, _) = run(2);
    let e = &r.first_exceptions[0].1;
    assert_eq!(e.details()[0], 2);
    assert_eq!(
        oxray_cpu::cxx::MISUSED_FUNCTIONS[e.details()[1] as usize],
        "optixGetPayload"
    );
    let (r, o) = run(3);
    assert_eq!(r.exceptions, 4);
    assert_eq!(r.first_exceptions[2].1.code.0, 5);
    assert_eq!(r.first_exceptions[2].1.details(), &[2, 9]);
    assert_eq!(o, vec![1; 4]);
    // Launch parameters of the wrong size are refused (guide §10).
    assert!(matches!(
        p.launch(&[0u8; 8], &sbt, 1, 1, 1),
        Err(CxxError::ParamsSize {
            given: 8,
            declared: 24,
            ..
        })
    ));
}

#[test]
fn pipelines_of_one_unit_share_the_cached_library_and_launch_one_at_a_time() {
    let m = CxxModule::from_source(MISUSE);
    let rg = CxxProgramGroup::raygen(&m, "__raygen__main").unwrap();
    let a = pipeline_of(std::slice::from_ref(&rg), Some("params")).unwrap();
    let dir = oxray_cpu::cxx::cache_dir();
    let count = || std::fs::read_dir(&dir).unwrap().count();
    let before = count();
    // Another module object of the same source: the same unit, found in the cache.
    let m2 = CxxModule::from_source(MISUSE);
    let rg2 = CxxProgramGroup::raygen(&m2, "__raygen__main").unwrap();
    let b = pipeline_of(std::slice::from_ref(&rg2), Some("params")).unwrap();
    assert_eq!(count(), before, "no new library");
    let sbt_a = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        ..Default::default()
    };
    let sbt_b = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg2.pack_header()]),
        ..Default::default()
    };
    // Both share the library's parameter variable: concurrent launches must not mix them.
    let out_a = HostBuffer::<u32>::zeroed(4096);
    let out_b = HostBuffer::<u32>::zeroed(4096);
    std::thread::scope(|s| {
        for _ in 0..8 {
            s.spawn(|| {
                let pa = MisuseParams {
                    out: out_a.device_ptr(),
                    handle: 0,
                    mode: 0,
                    pad: 0,
                };
                let r = a.launch_with(&pa, &sbt_a, 4096, 1, 1).unwrap();
                assert_eq!(r.exceptions, 0);
            });
            s.spawn(|| {
                let pb = MisuseParams {
                    out: out_b.device_ptr(),
                    handle: 0,
                    mode: 3,
                    pad: 0,
                };
                let r = b.launch_with(&pb, &sbt_b, 4096, 1, 1).unwrap();
                assert_eq!(r.exceptions, 4096);
            });
        }
    });
    assert!(out_a.download().iter().all(|&w| w == 2));
    assert!(out_b.download().iter().all(|&w| w == 1));
}

#[test]
fn results_are_the_same_whatever_the_thread_count() {
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let module = CxxModule::from_source(SRC);
                let rg = CxxProgramGroup::raygen(&module, "__raygen__main").unwrap();
                let ms = CxxProgramGroup::miss(Some((&module, "__miss__ms"))).unwrap();
                let hg = CxxProgramGroup::hit_group(CxxHitGroupDesc {
                    closest_hit: Some((&module, "__closesthit__ch")),
                    ..Default::default()
                })
                .unwrap();
                let p = pipeline_of(&[rg.clone(), ms.clone(), hg.clone()], Some("params")).unwrap();
                let v = [[-1.0f32, -1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
                let gas = Gas::build(
                    &BuildOptions::default(),
                    &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()],
                )
                .unwrap();
                let handle = TraversableHandle::from(gas);
                let out = HostBuffer::<u32>::zeroed(2 * 4);
                let sbt = ShaderBindingTable {
                    raygen: SbtRegion::from_headers(&[rg.pack_header()]),
                    miss: SbtRegion::from_headers(&[ms.pack_header()]),
                    hitgroup: SbtRegion::from_headers(&[hg.pack_header()]),
                    ..Default::default()
                };
                let params = [out.device_ptr(), oxray_cpu::cxx::optix_handle(&handle)];
                let r = p.launch_with(&params, &sbt, 4, 1, 1).unwrap();
                assert_eq!(r.exceptions, 0);
                out.download()
            })
    };
    assert_eq!(run(1), run(4));
}
