//! Motion in the pipeline (guide §5.10, §13.10, §13.11): the ray time reaches traversal and
//! `optixGetRayTime` only when the pipeline uses motion blur; the transform list holds motion
//! transforms with their matrices at the ray's time; programs read a motion transform's keys
//! and a GAS's motion options; the hit triangle's vertices are those at the ray's time. With
//! Rust programs and with a CUDA C++ program compiled by the host compiler.

use glam::Vec3;
use oxray_core::{
    BuildOptions, DeviceContext, Instance, MotionOptions, PipelineCompileOptions,
    PipelineLinkOptions, SbtRegion, ShaderBindingTable, SrtData, SrtMotionTransform,
    TraversableHandle, TriangleInput, VertexBuffer,
};
use oxray_cpu::{
    Gas, HitGroupDesc, Ias, Module, OutputBuffer, Pipeline, ProgramGroup, TraceRay,
    TransformListKind,
};

/// A triangle facing -z at z = 0 that slides from x = 0 to x = 10 over times [0, 1], under an
/// SRT motion transform that moves it from y = 0 to y = 4 over [0, 2], under an instance: at
/// time t in [0, 1] it is centred on (10 t, 2 t, 0).
fn scene() -> TraversableHandle {
    let k0 = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
    let k1 = k0.map(|p| [p[0] + 10.0, p[1], p[2]]);
    let later = [VertexBuffer::f32x3(&k1)];
    let input = TriangleInput::new(VertexBuffer::f32x3(&k0)).motion_vertices(&later);
    let gas: TraversableHandle = Gas::build(
        &BuildOptions::default().with_motion(MotionOptions::new(2, 0.0, 1.0)),
        &[input.into()],
    )
    .unwrap()
    .into();
    let keys = [
        SrtData::IDENTITY,
        SrtData {
            ty: 4.0,
            ..SrtData::IDENTITY
        },
    ];
    let srt: TraversableHandle =
        SrtMotionTransform::new(gas, MotionOptions::new(2, 0.0, 2.0), &keys)
            .unwrap()
            .into();
    Ias::build(
        &BuildOptions::default(),
        &[(&[Instance::new(srt)][..]).into()],
    )
    .unwrap()
    .into()
}

/// What the closest-hit program saw: t, time, list size, whether entry 1 is an SRT motion
/// transform, that transform's keys, the object-to-world y translation, the hit triangle's
/// apex x, the GAS's keys (as bits of f32 and u32 words).
type Seen = [u32; 8];

#[derive(Clone)]
struct Params {
    handle: TraversableHandle,
    out: std::sync::Arc<OutputBuffer<Seen>>,
}

fn run(uses_motion_blur: bool) -> Vec<Seen> {
    let module = Module::<Params>::new()
        .raygen("__raygen__rg", |ctx| {
            let [x, _, _] = ctx.launch_index();
            let time = x as f32 * 0.25;
            let p = ctx.params();
            let o = Vec3::new(10.0 * time, 2.0 * time, -5.0);
            let mut payload = [0u32; 8];
            ctx.trace(
                &TraceRay::new(&p.handle, o, Vec3::Z).time(time),
                &mut payload,
            )?;
            p.out.write(x as usize, payload);
            Ok(())
        })
        .unwrap()
        .closest_hit("__closesthit__ch", |ctx| {
            let second = ctx.transform_list_entry(1).map(|e| e.kind);
            let srt_keys = ctx
                .srt_motion_transform(1)
                .map_or(0, |m| m.motion_options().num_keys as u32);
            let o2w_y = ctx.object_to_world_transform().0[7];
            let apex_x = ctx.triangle_vertex_data()[2].x;
            let gas_keys = ctx.gas_motion_options().key_count() as u32;
            ctx.set_payload_f32(0, ctx.ray_tmax());
            ctx.set_payload_f32(1, ctx.ray_time());
            ctx.set_payload(2, ctx.transform_list_size());
            ctx.set_payload(
                3,
                (second == Some(TransformListKind::SrtMotionTransform)) as u32,
            );
            ctx.set_payload(4, srt_keys);
            ctx.set_payload_f32(5, o2w_y);
            ctx.set_payload_f32(6, apex_x);
            ctx.set_payload(7, gas_keys);
            Ok(())
        })
        .unwrap()
        .miss("__miss__ms", |ctx| {
            ctx.set_payload(2, MISS);
            Ok(())
        })
        .unwrap();
    let rg = ProgramGroup::raygen(&module, "__raygen__rg").unwrap();
    let ms = ProgramGroup::miss(Some((&module, "__miss__ms"))).unwrap();
    let hg = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__ch")),
        ..Default::default()
    })
    .unwrap();
    let compile = PipelineCompileOptions {
        uses_motion_blur,
        ..Default::default()
    };
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &compile,
        &PipelineLinkOptions { max_trace_depth: 1 },
        &[rg.clone(), ms.clone(), hg.clone()],
    )
    .unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_headers(&[ms.pack_header()]),
        hitgroup: SbtRegion::from_headers(&[hg.pack_header()]),
        ..Default::default()
    };
    let out = std::sync::Arc::new(OutputBuffer::new(5));
    let params = Params {
        handle: scene(),
        out: out.clone(),
    };
    let report = pipeline.launch(&params, &sbt, 5, 1, 1).unwrap();
    assert_eq!(report.exceptions, 0, "{report:?}");
    out.to_vec()
}

const MISS: u32 = 0xDEAD;

#[test]
fn s13_11_rust_programs_see_the_scene_at_the_ray_time() {
    let seen = run(true);
    let f = |w: u32| f32::from_bits(w);
    for (x, s) in seen.iter().enumerate() {
        let time = x as f32 * 0.25;
        assert_ne!(s[2], MISS, "time {time}: no hit");
        assert_eq!((f(s[0]), f(s[1])), (5.0, time));
        assert_eq!(s[2], 2, "the instance and the SRT motion transform");
        assert_eq!(
            (s[3], s[4]),
            (1, 2),
            "entry 1: an SRT motion transform of 2 keys"
        );
        // §13.11: the object-to-world matrix at the ray's time (y = 4 t / 2).
        assert!((f(s[5]) - 2.0 * time).abs() < 1e-6, "{s:?}");
        // §13.9: the vertices at the ray's time (the apex at x = 10 t).
        assert!((f(s[6]) - 10.0 * time).abs() < 1e-5, "{s:?}");
        // §13.10: the GAS's keys.
        assert_eq!(s[7], 2);
    }
}

#[test]
fn s13_5_without_motion_blur_the_ray_time_is_0() {
    // Traversal happens at time 0: only the ray aimed at the triangle's position at time 0 hits.
    let seen = run(false);
    assert_eq!((seen[0][1], seen[0][2]), (0, 2), "a hit at time 0");
    assert!(seen[1..].iter().all(|s| s[2] == MISS), "{seen:?}");
}

/// The same queries from CUDA C++ (both device headers declare them; the GPU's answers that
/// nothing has motion, as the CUDA backend refuses motion).
#[cfg(unix)]
#[test]
fn s13_10_s13_11_a_cuda_cpp_program_reads_motion_transforms_and_gas_motion() {
    use oxray_cpu::cxx::{CxxHitGroupDesc, CxxModule, CxxPipeline, CxxProgramGroup, HostBuffer};
    const SRC: &str = r#"
#include <optix.h>
struct Params { float* out; OptixTraversableHandle handle; };
extern "C" __constant__ Params params;
extern "C" __global__ void __raygen__main() {
    const uint3 i = optixGetLaunchIndex();
    const float time = 0.25f * (float)i.x;
    unsigned int p0 = 0;
    optixTrace(params.handle, make_float3(10.0f * time, 2.0f * time, -5.0f),
               make_float3(0.0f, 0.0f, 1.0f), 0.0f, 100.0f, time, 255u, 0u, 0u, 1u, 0u, p0);
}
extern "C" __global__ void __closesthit__ch() {
    float* o = params.out + 8 * optixGetLaunchIndex().x;
    o[0] = optixGetRayTime();
    o[1] = (float)optixGetTransformListSize();
    const OptixTraversableHandle h = optixGetTransformListHandle(1);
    o[2] = (float)optixGetTransformTypeFromHandle(h);
    const OptixSRTMotionTransform* srt = optixGetSRTMotionTransformFromHandle(h);
    o[3] = srt ? (float)srt->motionOptions.numKeys + srt->srtData[1].ty : -1.0f;
    o[4] = optixGetMatrixMotionTransformFromHandle(h) ? 1.0f : 0.0f;
    const OptixTraversableHandle gas = optixGetGASTraversableHandle();
    o[5] = (float)optixGetGASMotionStepCount(gas);
    o[6] = optixGetGASMotionTimeEnd(gas);
    float m[12];
    optixGetObjectToWorldTransformMatrix(m);
    o[7] = m[7];
}
"#;
    let module = CxxModule::from_source(SRC);
    let rg = CxxProgramGroup::raygen(&module, "__raygen__main").unwrap();
    let ms = CxxProgramGroup::miss(None).unwrap();
    let hg = CxxProgramGroup::hit_group(CxxHitGroupDesc {
        closest_hit: Some((&module, "__closesthit__ch")),
        ..Default::default()
    })
    .unwrap();
    let compile = PipelineCompileOptions {
        uses_motion_blur: true,
        ..Default::default()
    };
    let pipeline = CxxPipeline::new(
        &DeviceContext::default(),
        &compile,
        &PipelineLinkOptions::default(),
        Some("params"),
        &[rg.clone(), ms.clone(), hg.clone()],
    )
    .unwrap();
    let handle = scene();
    let out = HostBuffer::<f32>::zeroed(8 * 5);
    #[repr(C)]
    #[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
    struct CParams {
        out: u64,
        handle: u64,
    }
    let params = CParams {
        out: out.device_ptr(),
        handle: oxray_cpu::cxx::optix_handle(&handle),
    };
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_headers(&[ms.pack_header()]),
        hitgroup: SbtRegion::from_headers(&[hg.pack_header()]),
        ..Default::default()
    };
    let report = pipeline.launch_with(&params, &sbt, 5, 1, 1).unwrap();
    assert_eq!(report.exceptions, 0, "{report:?}");
    let o = out.download();
    for x in 0..5 {
        let time = 0.25 * x as f32;
        let row = &o[8 * x..8 * x + 8];
        assert_eq!(
            &row[..7],
            &[time, 2.0, 3.0, 2.0 + 4.0, 0.0, 2.0, 1.0],
            "x {x}"
        );
        assert!((row[7] - 2.0 * time).abs() < 1e-6, "x {x}: {row:?}");
    }
}
