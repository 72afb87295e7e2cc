//! What motion blur costs a pipeline (guide §5.10), on every device this machine has (the CPU
//! always, CUDA device 0 where there is one): one ray-generation program traces a buffer of
//! rays at their times with a one-hit closest-hit program, against the same mesh as a static
//! GAS and as GASes with two motion keys — motionless (equal keys: the cost of interpolating
//! every triangle tested), small motion (2 % of the mesh's size) and large motion (50 %, where
//! the tree's boxes, the union over both keys, grow) — and through an instance under a static
//! transform, a matrix motion transform and an SRT motion transform (a small turn). Camera rays
//! and incoherent (diffuse) rays, times uniform in the shutter. Prints the median Mrays/s of the
//! launches and the ratio to the static GAS.
//!
//! `cargo bench -p oxray --bench motion [rays] [runs]` (the bunny from `../shared/data/meshes`
//! where present, else an icosphere; numbers depend on the machine and its load: compare the
//! ratios of one run).

use glam::{Quat, Vec3};
use oxray::programs::{HitGroupDesc, ProgramGroup};
use oxray::{
    BackendKind, BuildInput, BuildOptions, Device, Instance, MatrixMotionTransform, ModuleSource,
    MotionOptions, PipelineCompileOptions, PipelineLinkOptions, Ray, SbtRegion, ShaderBindingTable,
    SrtData, SrtMotionTransform, StaticTransform, Transform, TraversableHandle, TriangleInput,
    VertexBuffer,
};
use oxray_testkit::mesh::{find_mesh, icosphere_f32, load_obj, Mesh};
use oxray_testkit::rays::{camera_rays, hemisphere_rays};
use oxray_testkit::rng::Rng;
use std::time::Instant;

const PROGRAMS: &str = r#"
#include <optix.h>
struct BenchParams { float* t; OptixTraversableHandle handle; const float* rays; };
extern "C" __constant__ BenchParams bench;
extern "C" __global__ void __raygen__bench() {
    const unsigned int i = optixGetLaunchIndex().x;
    const float* r = bench.rays + 8 * (size_t)i;
    unsigned int t = __float_as_uint(-1.0f);
    optixTrace(bench.handle, make_float3(r[0], r[1], r[2]), make_float3(r[3], r[4], r[5]), 0.0f,
               1e30f, r[6], 255u, 0u, 0u, 1u, 0u, t);
    bench.t[i] = __uint_as_float(t);
}
extern "C" __global__ void __closesthit__bench() {
    optixSetPayload_0(__float_as_uint(optixGetRayTmax()));
}
extern "C" __global__ void __miss__bench() {}
"#;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct BenchParams {
    t: u64,
    handle: u64,
    rays: u64,
}

fn mesh() -> (String, Mesh) {
    if let Some(m) = find_mesh("stanford-bunny.obj").and_then(|p| load_obj(&p).ok()) {
        return ("bunny".into(), m);
    }
    ("icosphere(6)".into(), icosphere_f32(6))
}

/// The benchmark's pipeline on one device.
struct Bench {
    device: Device,
    pipeline: oxray::programs::Pipeline,
    sbt: ShaderBindingTable,
}

impl Bench {
    fn new(device: &Device) -> Bench {
        let m = device
            .create_module(ModuleSource::CudaCpp(PROGRAMS))
            .unwrap();
        let rg = ProgramGroup::raygen(&m, "__raygen__bench").unwrap();
        let ms = ProgramGroup::miss(&m, "__miss__bench").unwrap();
        let hg = ProgramGroup::hit_group(HitGroupDesc {
            closest_hit: Some((&m, "__closesthit__bench")),
            any_hit: None,
            intersection: None,
        })
        .unwrap();
        let compile = PipelineCompileOptions {
            num_payload_values: 1,
            uses_motion_blur: true,
            ..Default::default()
        };
        let mut pipeline = device
            .create_pipeline(
                &compile,
                &PipelineLinkOptions { max_trace_depth: 1 },
                Some("bench"),
                &[rg.clone(), ms.clone(), hg.clone()],
            )
            .unwrap();
        pipeline.set_max_traversable_graph_depth(3).unwrap();
        let sbt = ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[rg.pack_header()]),
            miss: SbtRegion::from_headers(&[ms.pack_header()]),
            hitgroup: SbtRegion::from_headers(&[hg.pack_header()]),
            ..Default::default()
        };
        Bench {
            device: device.clone(),
            pipeline,
            sbt,
        }
    }

    /// The median Mrays/s of `runs` launches over `rays` (8 floats each) against `handle`,
    /// and the number of hits.
    fn mrays(
        &self,
        handle: u64,
        rays: &oxray::programs::Buffer<f32>,
        n: usize,
        runs: usize,
    ) -> (f64, usize) {
        let out = self.device.create_buffer::<f32>(n).unwrap();
        let params = BenchParams {
            t: out.device_ptr(),
            handle,
            rays: rays.device_ptr(),
        };
        let launch = || {
            let r = self
                .pipeline
                .launch_with(&params, &self.sbt, n as u32, 1, 1)
                .unwrap();
            assert_eq!(r.exceptions, 0);
        };
        launch();
        let mut times: Vec<f64> = (0..runs)
            .map(|_| {
                let t = Instant::now();
                launch();
                t.elapsed().as_secs_f64()
            })
            .collect();
        times.sort_by(f64::total_cmp);
        let hits = out
            .download()
            .unwrap()
            .iter()
            .filter(|&&t| t >= 0.0)
            .count();
        (n as f64 / times[runs / 2] / 1e6, hits)
    }
}

fn ray_words(rays: &[Ray], rng: &mut Rng) -> Vec<f32> {
    rays.iter()
        .flat_map(|r| {
            let (o, d) = (r.origin, r.direction);
            [o.x, o.y, o.z, d.x, d.y, d.z, rng.f32(), 0.0]
        })
        .collect()
}

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .filter_map(|a| a.parse().ok())
        .collect();
    let side = (args.first().copied().unwrap_or(1 << 18) as f64).sqrt() as u32;
    let runs = args.get(1).copied().unwrap_or(7).max(1);
    let (name, m) = mesh();
    let (lo, hi) = oxray_testkit::mesh::bounds(&m.positions);
    let size = (Vec3::from(hi) - Vec3::from(lo)).max_element();
    let centre = (Vec3::from(lo) + Vec3::from(hi)) * 0.5;
    let mut rng = Rng::new(7);
    let camera = ray_words(&camera_rays(&m.positions, side, side), &mut rng);
    let n = camera.len() / 8;
    let diffuse = ray_words(
        &hemisphere_rays(&m.positions, &m.triangles, n, 11),
        &mut rng,
    );
    let shifted = |d: f32| -> Vec<[f32; 3]> {
        m.positions
            .iter()
            .map(|p| [p[0] + d * size, p[1], p[2]])
            .collect()
    };
    let keys = [shifted(0.0), shifted(0.02), shifted(0.5)];
    let mut devices = vec![Device::cpu()];
    match Device::cuda(0) {
        Ok(d) => devices.push(d),
        Err(e) => println!("(no CUDA device: {e})"),
    }
    for device in &devices {
        let kind = match device.kind() {
            BackendKind::Cuda => "cuda",
            _ => "cpu",
        };
        println!(
            "{kind}, {name}: {} triangles, {n} rays a launch; Mrays/s (ratio to the static GAS), hits",
            m.triangles.len()
        );
        println!("{:<28} {:>24} {:>24}", "", "camera", "diffuse");
        let bench = Bench::new(device);
        let input = || {
            TriangleInput::new(VertexBuffer::f32x3(&m.positions))
                .indices(oxray::IndexBuffer::u32x3(&m.triangles))
        };
        let gas = device
            .build_gas(&BuildOptions::default(), &[input().into()])
            .unwrap();
        let two_keys = BuildOptions::default().with_motion(MotionOptions::new(2, 0.0, 1.0));
        let moving: Vec<oxray::Gas> = keys
            .iter()
            .map(|k| {
                let later = [VertexBuffer::f32x3(k)];
                device
                    .build_gas(&two_keys, &[input().motion_vertices(&later).into()])
                    .unwrap()
            })
            .collect();
        let ias = |child: TraversableHandle| {
            device
                .build_ias(
                    &BuildOptions::default(),
                    &[BuildInput::from(&[Instance::new(child)][..])],
                )
                .unwrap()
        };
        let pivot = Transform::from_translation(-centre);
        let static_t: TraversableHandle = StaticTransform::new(gas.handle(), Transform::IDENTITY)
            .unwrap()
            .into();
        let turn = |a: f32| {
            let q = Quat::from_rotation_y(a);
            let t = Transform::from_affine(&glam::Affine3A::from_rotation_translation(q, centre));
            t.then_after(&pivot)
        };
        let matrix: TraversableHandle = MatrixMotionTransform::new(
            gas.handle(),
            MotionOptions::new(2, 0.0, 1.0),
            &[turn(0.0), turn(0.1)],
        )
        .unwrap()
        .into();
        let srt_key = |a: f32| {
            let q = Quat::from_rotation_y(a);
            SrtData {
                pvx: -centre.x,
                pvy: -centre.y,
                pvz: -centre.z,
                qx: q.x,
                qy: q.y,
                qz: q.z,
                qw: q.w,
                tx: centre.x,
                ty: centre.y,
                tz: centre.z,
                ..SrtData::IDENTITY
            }
        };
        let srt: TraversableHandle = SrtMotionTransform::new(
            gas.handle(),
            MotionOptions::new(2, 0.0, 1.0),
            &[srt_key(0.0), srt_key(0.1)],
        )
        .unwrap()
        .into();
        let tops = [
            ("instance, static transform", ias(static_t)),
            ("instance, matrix motion", ias(matrix)),
            ("instance, SRT motion", ias(srt)),
        ];
        let mut rows: Vec<(&str, u64)> = vec![
            ("static GAS", gas.optix_handle().unwrap()),
            ("motionless 2 keys", moving[0].optix_handle().unwrap()),
            ("small motion (2 %)", moving[1].optix_handle().unwrap()),
            ("large motion (50 %)", moving[2].optix_handle().unwrap()),
        ];
        for (label, i) in &tops {
            rows.push((label, i.optix_handle().unwrap()));
        }
        let cam = device.buffer_from_slice(&camera).unwrap();
        let dif = device.buffer_from_slice(&diffuse).unwrap();
        let mut base = (0.0, 0.0);
        for (label, handle) in rows {
            let (c, ch) = bench.mrays(handle, &cam, n, runs);
            let (d, dh) = bench.mrays(handle, &dif, n, runs);
            if base.0 == 0.0 {
                base = (c, d);
            }
            println!(
                "{label:<28} {c:>9.2} ({:>4.2}) {ch:>7} {d:>9.2} ({:>4.2}) {dh:>7}",
                c / base.0,
                d / base.1
            );
        }
    }
}
