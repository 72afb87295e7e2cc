//! CUDA C++ programs on the CPU backend: compile, load, launch, trace.
#![cfg(unix)]

use oxray_core::sbt::SbtRegion;
use oxray_core::{
    BuildOptions, DeviceContext, PipelineCompileOptions, PipelineLinkOptions, ShaderBindingTable,
    TraversableHandle, TriangleInput, VertexBuffer,
};
use oxray_cpu::cxx::{CxxHitGroupDesc, CxxModule, CxxPipeline, CxxProgramGroup, HostBuffer};
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
