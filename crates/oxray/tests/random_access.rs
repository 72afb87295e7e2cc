//! Random access (guide §13.9, §13.12) on every device: a structure built with
//! `ALLOW_RANDOM_VERTEX_ACCESS` gives any primitive's data by the primitive index programs see
//! (with its input's offset) and its SBT-GAS index, from the host and from CUDA C++ programs
//! (`optixGet…VertexDataFromHandle`); an IAS built with `ALLOW_RANDOM_INSTANCE_ACCESS` gives an
//! instance by its index. A primitive the builder left out reads NaN; what OptiX leaves
//! undefined is a typed error on the host and NaN in programs.

mod common;

use common::{name, on_every_device, Scene, ScenePrograms};
use oxray::{
    BuildFlags, BuildOptions, CurveInput, CurveType, Device, Gas, GeometryFlags, Instance,
    PrimitiveTypeFlags, RandomAccessError, SbtIndexOffsets, SphereInput, Transform, TriangleInput,
    VertexBuffer,
};

const RANDOM: BuildFlags = BuildFlags::ALLOW_RANDOM_VERTEX_ACCESS;

/// Two inputs: six triangles (the fourth degenerate) with primitive index offset 0, and four
/// with offset 100 over two SBT records (SBT-GAS indices 1 and 2).
struct Triangles {
    a: Vec<[f32; 3]>,
    b: Vec<[f32; 3]>,
    offsets: Vec<u32>,
}

impl Triangles {
    fn new() -> Triangles {
        let tri = |k: usize| -> [[f32; 3]; 3] {
            let f = k as f32;
            [[f, 0.0, 1.0], [f + 1.0, 0.5 * f, 1.0], [f, 1.0, 2.0 + f]]
        };
        let mut a: Vec<[f32; 3]> = (0..6).flat_map(tri).collect();
        a[3 * 3 + 1] = a[3 * 3]; // triangle 3: two equal vertices
        let b = (6..10).flat_map(tri).collect();
        Triangles {
            a,
            b,
            offsets: vec![0, 1, 1, 0],
        }
    }

    fn gas(&self, device: &Device, flags: BuildFlags) -> Gas {
        let f = [GeometryFlags::empty(); 2];
        let inputs = [
            TriangleInput::new(VertexBuffer::f32x3(&self.a)).into(),
            TriangleInput::new(VertexBuffer::f32x3(&self.b))
                .primitive_index_offset(100)
                .flags(&f)
                .sbt_index_offsets(SbtIndexOffsets::u32(&self.offsets))
                .into(),
        ];
        device
            .build_gas(&BuildOptions::new(flags), &inputs)
            .unwrap()
    }

    /// What primitive `(index, sbt)` should read: its vertices, NaN for the degenerate one.
    fn expected(&self, primitive_index: u32, sbt: u32) -> Option<[[f32; 3]; 3]> {
        let (v, k) = match (primitive_index, sbt) {
            (p @ 0..=5, 0) => (&self.a, p as usize),
            (p @ 100..=103, 1 | 2) => (&self.b, (p - 100) as usize),
            _ => return None,
        };
        if v == &self.a && k == 3 {
            return Some([[f32::NAN; 3]; 3]);
        }
        Some([v[3 * k], v[3 * k + 1], v[3 * k + 2]])
    }
}

fn same_bits(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len()
        && a.iter()
            .zip(b)
            .all(|(x, y)| x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()))
}

#[test]
fn s13_9_triangles_are_read_by_primitive_and_sbt_gas_index_on_every_device() {
    let t = Triangles::new();
    on_every_device(|device| {
        let gas = t.gas(device, RANDOM | BuildFlags::PREFER_FAST_TRACE);
        let mut read = Vec::new();
        for (p, sbt) in [(0, 0), (2, 0), (3, 0), (5, 0), (100, 1), (101, 2), (103, 1)] {
            let got = gas.triangle_vertex_data(p, sbt, 0.0).unwrap();
            let want = t.expected(p, sbt).unwrap();
            let flat: Vec<f32> = got.iter().flat_map(|v| v.to_array()).collect();
            assert!(
                same_bits(&flat, want.as_flattened()),
                "{} ({p}, {sbt}): {got:?} vs {want:?}",
                name(device)
            );
            read.push(flat.iter().map(|f| f.to_bits()).collect::<Vec<_>>());
        }
        // Out of range: a typed error where OptiX leaves it undefined.
        for (p, sbt) in [(6, 0), (99, 1), (104, 1), (0, 3)] {
            assert_eq!(
                gas.triangle_vertex_data(p, sbt, 0.0),
                Err(RandomAccessError::NoSuchPrimitive {
                    primitive_index: p,
                    sbt_gas_index: sbt
                }),
                "{}",
                name(device)
            );
        }
        assert!(matches!(
            gas.sphere_data(0, 0, 0.0),
            Err(RandomAccessError::WrongKind { .. })
        ));
        // Without the flag.
        let plain = t.gas(device, BuildFlags::empty());
        assert!(matches!(
            plain.triangle_vertex_data(0, 0, 0.0),
            Err(RandomAccessError::NotAllowed { .. })
        ));
        read
    });
}

#[test]
fn s13_9_spheres_and_curves_are_read_on_every_device() {
    let centres = [[0.0f32, 0.0, 0.0], [3.0, 1.0, 0.0], [6.0, 0.0, 2.0]];
    let radii = [0.5f32, -1.0, 0.25]; // the second is left out by the builder
    let points = [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [2.0, 1.0, 0.0],
        [3.0, 1.0, 1.0],
    ];
    let widths = [0.1f32, 0.2, 0.15, 0.05];
    let index = [0u32, 1, 2];
    on_every_device(|device| {
        let (c, r) = (
            [bytemuck::cast_slice::<_, u8>(&centres)],
            [bytemuck::cast_slice::<_, u8>(&radii)],
        );
        let spheres = SphereInput::new(&c, 3, &r).primitive_index_offset(7);
        let gas = device
            .build_gas(&BuildOptions::new(RANDOM), &[spheres.into()])
            .unwrap();
        assert_eq!(gas.sphere_data(7, 0, 0.0).unwrap(), [0.0, 0.0, 0.0, 0.5]);
        assert_eq!(gas.sphere_data(9, 0, 0.0).unwrap(), [6.0, 0.0, 2.0, 0.25]);
        assert!(gas
            .sphere_data(8, 0, 0.0)
            .unwrap()
            .iter()
            .all(|f| f.is_nan()));
        let (v, w) = (
            [bytemuck::cast_slice::<_, u8>(&points)],
            [bytemuck::cast_slice::<_, u8>(&widths)],
        );
        let curves = CurveInput::new(
            CurveType::RoundLinear,
            &v,
            4,
            &w,
            bytemuck::cast_slice(&index),
            3,
        );
        let gas = device
            .build_gas(&BuildOptions::new(RANDOM), &[curves.into()])
            .unwrap();
        let seg = gas.curve_vertex_data(1, 0, 0.0).unwrap();
        assert_eq!(seg[0], [1.0, 0.0, 0.0, 0.2]);
        assert_eq!(seg[1], [2.0, 1.0, 0.0, 0.15]);
        assert_eq!(
            (seg[2], seg[3]),
            ([0.0; 4], [0.0; 4]),
            "a linear segment has two points"
        );
        seg
    });
}

#[test]
fn s13_12_instances_are_read_by_index_on_every_device() {
    let t = Triangles::new();
    on_every_device(|device| {
        let gas = t.gas(device, BuildFlags::empty());
        let list: Vec<Instance> = (0..9)
            .map(|i| {
                Instance::new(gas.handle())
                    .transform(Transform::from_translation(glam::Vec3::new(
                        i as f32 * 20.0,
                        0.0,
                        0.0,
                    )))
                    .instance_id(1000 + i)
                    .sbt_offset(i % 3)
            })
            .collect();
        let opts = BuildOptions::new(BuildFlags::ALLOW_RANDOM_INSTANCE_ACCESS);
        let ias = device.build_ias(&opts, &[(&list[..]).into()]).unwrap();
        for i in 0..9u32 {
            let inst = ias.instance(i).unwrap();
            assert_eq!(
                (inst.instance_id, inst.sbt_offset, inst.index),
                (1000 + i, i % 3, i)
            );
            assert_eq!(inst.object_to_world.0[3], i as f32 * 20.0);
            assert!(inst.child.same_as(&gas.handle()));
        }
        assert_eq!(
            ias.instance(9).unwrap_err(),
            RandomAccessError::NoSuchInstance { index: 9, count: 9 }
        );
        // Saved and loaded, it keeps every instance reachable.
        let loaded = device
            .load_ias(&ias.to_bytes().unwrap(), &vec![gas.handle(); 9])
            .unwrap();
        assert_eq!(loaded.instance(4).unwrap().instance_id, 1004);
        let plain = device
            .build_ias(&BuildOptions::default(), &[(&list[..]).into()])
            .unwrap();
        assert!(matches!(
            plain.instance(0),
            Err(RandomAccessError::NotAllowed { .. })
        ));
        ias.num_instances()
    });
}

/// A ray-generation program that reads primitive `base + x` of the GAS in the launch
/// parameters through the device functions of §13.9 and writes 8 words: mode 0, a triangle's
/// first eight coordinates; 1, its last; 2, a sphere; 3, a linear curve segment; 4, instance
/// `base + x` of an IAS (§13.12): its id, transform type, translation, whether it has a child
/// and the inverse's translation.
const PROGRAMS: &str = r#"
#include <optix.h>
struct Params {
    unsigned long long out;
    unsigned long long gas;
    unsigned int mode, base, sbt, pad;
};
extern "C" __constant__ Params ra;
extern "C" __global__ void __raygen__read() {
    const unsigned int i = optixGetLaunchIndex().x;
    unsigned int* o = reinterpret_cast<unsigned int*>(ra.out) + 8 * i;
    float f[9] = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
    if (ra.mode <= 1) {
        float3 v[3];
        optixGetTriangleVertexDataFromHandle(ra.gas, ra.base + i, ra.sbt, 0.0f, v);
        const float a[9] = {v[0].x, v[0].y, v[0].z, v[1].x, v[1].y, v[1].z, v[2].x, v[2].y, v[2].z};
        for (int k = 0; k < 8; ++k) f[k] = ra.mode == 0 ? a[k] : (k == 0 ? a[8] : 0.0f);
    } else if (ra.mode == 2) {
        float4 s[1];
        optixGetSphereDataFromHandle(ra.gas, ra.base + i, ra.sbt, 0.0f, s);
        f[0] = s[0].x; f[1] = s[0].y; f[2] = s[0].z; f[3] = s[0].w;
    } else if (ra.mode == 4) {
        const OptixTraversableHandle h = optixGetInstanceTraversableFromIAS(ra.gas, ra.base + i);
        f[0] = (float)optixGetInstanceIdFromHandle(h);
        f[1] = (float)optixGetTransformTypeFromHandle(h);
        f[2] = h != 0ull ? optixGetInstanceTransformFromHandle(h)[0].w : -1.0f;
        f[3] = optixGetInstanceChildFromHandle(h) != 0ull ? 1.0f : 0.0f;
        f[4] = h != 0ull ? optixGetInstanceInverseTransformFromHandle(h)[0].w : -1.0f;
    } else {
        float4 c[2];
        optixGetLinearCurveVertexDataFromHandle(ra.gas, ra.base + i, ra.sbt, 0.0f, c);
        f[0] = c[0].x; f[1] = c[0].y; f[2] = c[0].z; f[3] = c[0].w;
        f[4] = c[1].x; f[5] = c[1].y; f[6] = c[1].z; f[7] = c[1].w;
    }
    for (int k = 0; k < 8; ++k) o[k] = __float_as_uint(f[k]);
}
extern "C" __global__ void __miss__none() {}
extern "C" __global__ void __closesthit__none() {}
"#;

const READER: ScenePrograms = ScenePrograms {
    source: PROGRAMS,
    params: "ra",
    raygen: "__raygen__read",
    miss: "__miss__none",
    hit_groups: &[("hg", "__closesthit__none", None)],
};

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    out: u64,
    gas: u64,
    mode: u32,
    base: u32,
    sbt: u32,
    pad: u32,
}

#[test]
fn s13_9_programs_read_primitives_from_handles_on_every_device() {
    let t = Triangles::new();
    let centres = [[1.0f32, 2.0, 3.0], [4.0, 5.0, 6.0]];
    let radii = [0.5f32, 0.0]; // the second is left out
    let points = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 1.0, 0.0]];
    let widths = [0.1f32, 0.2, 0.15];
    let index = [0u32, 1];
    on_every_device(|device| {
        let types = PrimitiveTypeFlags::TRIANGLE
            | PrimitiveTypeFlags::SPHERE
            | PrimitiveTypeFlags::ROUND_LINEAR;
        let scene = Scene::new(device, &READER, types);
        let sbt = scene.sbt("hg", 3);
        let run = |gas: &Gas, mode: u32, base: u32, sbt_index: u32, n: u32| {
            let handle = gas.optix_handle().unwrap();
            let (out, report) = scene.launch(&sbt, n, 1, |out| Params {
                out,
                gas: handle,
                mode,
                base,
                sbt: sbt_index,
                pad: 0,
            });
            assert_eq!(report.exceptions, 0, "{}", name(device));
            out.iter()
                .map(|w| w.map(f32::from_bits))
                .collect::<Vec<[f32; 8]>>()
        };
        let mut all = Vec::new();
        let gas = t.gas(device, RANDOM);
        for (base, sbt_index, n) in [(0u32, 0u32, 6u32), (100, 1, 4)] {
            let first = run(&gas, 0, base, sbt_index, n);
            let last = run(&gas, 1, base, sbt_index, n);
            for i in 0..n {
                let want = t.expected(base + i, sbt_index).unwrap();
                let mut got = first[i as usize].to_vec();
                got.push(last[i as usize][0]);
                assert!(
                    same_bits(&got, want.as_flattened()),
                    "{} primitive {}: {got:?}",
                    name(device),
                    base + i
                );
                all.push(got.iter().map(|f| f.to_bits()).collect::<Vec<_>>());
            }
        }
        // An index out of range and a GAS without the flag read NaN.
        let bad = run(&gas, 0, 6, 0, 1);
        assert!(bad[0].iter().all(|f| f.is_nan()));
        let plain = t.gas(device, BuildFlags::empty());
        assert!(run(&plain, 0, 0, 0, 1)[0].iter().all(|f| f.is_nan()));
        // Spheres and curves.
        let (c, r) = (
            [bytemuck::cast_slice::<_, u8>(&centres)],
            [bytemuck::cast_slice::<_, u8>(&radii)],
        );
        let spheres = device
            .build_gas(
                &BuildOptions::new(RANDOM),
                &[SphereInput::new(&c, 2, &r).into()],
            )
            .unwrap();
        let s = run(&spheres, 2, 0, 0, 2);
        assert_eq!(s[0][..4], [1.0, 2.0, 3.0, 0.5]);
        assert!(s[1][..4].iter().all(|f| f.is_nan()));
        let (v, w) = (
            [bytemuck::cast_slice::<_, u8>(&points)],
            [bytemuck::cast_slice::<_, u8>(&widths)],
        );
        let curve = CurveInput::new(
            CurveType::RoundLinear,
            &v,
            3,
            &w,
            bytemuck::cast_slice(&index),
            2,
        );
        let curves = device
            .build_gas(&BuildOptions::new(RANDOM), &[curve.into()])
            .unwrap();
        let k = run(&curves, 3, 0, 0, 2);
        assert_eq!(k[1], [1.0, 0.0, 0.0, 0.2, 2.0, 1.0, 0.0, 0.15]);
        all.push(k[0].map(f32::to_bits).to_vec());
        // Instances by index (§13.12).
        let list: Vec<Instance> = (0..5)
            .map(|i| {
                Instance::new(gas.handle())
                    .transform(Transform::from_translation(glam::Vec3::new(
                        2.0 * i as f32,
                        0.0,
                        0.0,
                    )))
                    .instance_id(50 + i)
            })
            .collect();
        let _ = gas.optix_handle().unwrap(); // the child's handle, given before the launch
        let opts = BuildOptions::new(BuildFlags::ALLOW_RANDOM_INSTANCE_ACCESS);
        let ias = device.build_ias(&opts, &[(&list[..]).into()]).unwrap();
        let handle = ias.optix_handle().unwrap();
        let (out, report) = scene.launch(&sbt, 6, 1, |out| Params {
            out,
            gas: handle,
            mode: 4,
            base: 0,
            sbt: 0,
            pad: 0,
        });
        assert_eq!(report.exceptions, 0);
        for (i, o) in out.iter().take(5).enumerate() {
            let f = o.map(f32::from_bits);
            assert_eq!(
                f[..5],
                [50.0 + i as f32, 4.0, 2.0 * i as f32, 1.0, -2.0 * i as f32],
                "{} instance {i}",
                name(device)
            );
        }
        // Past the instances: a null handle.
        assert_eq!(out[5].map(f32::from_bits)[..4], [0.0, 0.0, -1.0, 0.0]);
        all.push(out.iter().flatten().copied().collect());
        all
    });
}

/// The reading programs compile for the GPU with NVRTC, GPU or not: the device header's random
/// access functions compile in CI.
#[test]
fn the_random_access_programs_compile_with_nvrtc() {
    use oxray::cuda::{CudaHitGroupDesc, CudaModule, CudaProgramGroup};
    let m = CudaModule::from_source(PROGRAMS);
    let groups = [
        CudaProgramGroup::raygen(&m, "__raygen__read"),
        CudaProgramGroup::miss(Some((&m, "__miss__none"))),
        CudaProgramGroup::hit_group(CudaHitGroupDesc {
            closest_hit: Some((&m, "__closesthit__none")),
            any_hit: None,
            intersection: None,
        }),
    ]
    .map(Result::unwrap);
    let types = PrimitiveTypeFlags::TRIANGLE
        | PrimitiveTypeFlags::SPHERE
        | PrimitiveTypeFlags::ROUND_LINEAR;
    common::assert_compiles_with_nvrtc("the random access programs", &groups, types);
}
