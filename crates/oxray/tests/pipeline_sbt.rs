//! Conformance of the shader binding table (guide §7, inventory T, Z7 G18–G22): which hit-group
//! and miss records a trace uses, what `optixGetSbtGASIndex` / `optixGetPrimitiveIndex` /
//! `optixGetSbtDataPointer` return, the region layout rules of §7.2, and the launch-time checks
//! of record headers.

mod common;
mod pipeline_common;

use oxray::cpu::Gas;
use oxray::{
    BuildOptions, DeviceContext, GeometryFlags, IndexBuffer, LaunchError, Module, OutputBuffer,
    Pipeline, PipelineError, ProgramGroup, SbtIndexOffsets, SbtRegion, ShaderBindingTable,
    TraceRay, TraversableHandle, TriangleInput, VertexBuffer,
};
use pipeline_common::*;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;

/// Launch parameters of the multi-ray SBT tests: launch index `x` traces straight down at
/// `targets[x]`.
#[derive(Clone)]
struct Sp {
    handle: TraversableHandle,
    targets: Vec<Vec3>,
    offset: u32,
    stride: u32,
    miss: u32,
    out: Arc<OutputBuffer<[u32; 4]>>,
    raygen_runs: Arc<AtomicU32>,
}

/// Payload after each ray: `[record data, sbt_gas_index, primitive_index, 1 hit / 2 miss]`.
fn sbt_module() -> Module<Sp> {
    Module::<Sp>::new()
        .raygen("__raygen__rays", |ctx| {
            let p = ctx.params();
            p.raygen_runs.fetch_add(1, Ordering::Relaxed);
            let x = ctx.launch_index()[0] as usize;
            let mut payload = [!0u32; 4];
            let ray = TraceRay::new(&p.handle, p.targets[x] + Vec3::Z * 10.0, -Vec3::Z)
                .sbt(p.offset, p.stride, p.miss);
            ctx.trace(&ray, &mut payload)?;
            p.out.write(x, payload);
            Ok(())
        })
        .unwrap()
        .closest_hit("__closesthit__record", |ctx| {
            let data = ctx.sbt_data::<u32>().unwrap_or(!0);
            let (gas, prim) = (ctx.sbt_gas_index(), ctx.primitive_index());
            ctx.set_payload(0, data);
            ctx.set_payload(1, gas);
            ctx.set_payload(2, prim);
            ctx.set_payload(3, 1);
            Ok(())
        })
        .unwrap()
        .miss("__miss__record", |ctx| {
            let data = ctx.sbt_data::<u32>().unwrap_or(!0);
            ctx.set_payload(0, data);
            ctx.set_payload(3, 2);
            Ok(())
        })
        .unwrap()
}

/// The test scene: `common::three_input_gas` (three triangle inputs with 2, 1 and 3 SBT
/// records, per-primitive SBT index offsets and primitive index offsets 100, 7 and 0; triangle
/// `k` lies around `(3k, 0, 0)`) built on the CPU. Returns the GAS, the targets (one per
/// triangle, plus one empty spot) and the expected `(sbt_gas_index, primitive_index)` of each
/// triangle.
fn three_input_scene() -> (Arc<Gas>, Vec<Vec3>, Vec<(u32, u32)>) {
    let (gas, expected) = common::three_input_gas(&oxray::Device::cpu());
    let gas = Arc::new(gas.as_cpu().expect("built on the CPU").clone());
    let mut targets: Vec<Vec3> = (0..9)
        .map(|k| Vec3::new(3.0 * k as f32, 0.0, 0.0))
        .collect();
    targets.push(Vec3::new(27.0, 0.0, 0.0));
    (gas, targets, expected)
}

fn sbt_pipeline(
    m: &Module<Sp>,
    hit_records: usize,
    miss_records: usize,
) -> (Pipeline<Sp>, ShaderBindingTable) {
    let rg = ProgramGroup::raygen(m, "__raygen__rays").unwrap();
    let hg = ProgramGroup::hit_group(oxray::HitGroupDesc {
        closest_hit: Some((m, "__closesthit__record")),
        ..Default::default()
    })
    .unwrap();
    let ms = ProgramGroup::miss(Some((m, "__miss__record"))).unwrap();
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &compile(4, 2),
        &link(1),
        &[rg.clone(), hg.clone(), ms.clone()],
    )
    .unwrap();
    let hits: Vec<_> = (0..hit_records)
        .map(|i| (hg.pack_header(), 1000 + i as u32))
        .collect();
    let misses: Vec<_> = (0..miss_records)
        .map(|i| (ms.pack_header(), 500 + i as u32))
        .collect();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_records(&misses),
        hitgroup: SbtRegion::from_records(&hits),
        ..Default::default()
    };
    (pipeline, sbt)
}

fn sp(handle: TraversableHandle, targets: Vec<Vec3>, offset: u32, stride: u32, miss: u32) -> Sp {
    let n = targets.len();
    Sp {
        handle,
        targets,
        offset,
        stride,
        miss,
        out: Arc::new(OutputBuffer::new(n)),
        raygen_runs: Arc::new(AtomicU32::new(0)),
    }
}

/// §7.3 / T / Z7 G18: the hit-group record is `sbtGASIndex * (stride & 0xF) + (offset & 0xF)`
/// (no instance offset with a GAS root), over a GAS of several inputs with several records and
/// per-primitive SBT index offsets; bits of stride and offset above the fourth are ignored (§12).
#[test]
fn hit_group_index_formula_7_3_g18() {
    let m = sbt_module();
    let (gas, targets, expected) = three_input_scene();
    let (pipeline, sbt) = sbt_pipeline(&m, 96, 1);
    let handle = TraversableHandle::from(gas);
    for (stride, offset) in [
        (1, 0),
        (2, 1),
        (0x12, 0x31),
        (3, 2),
        (0, 3),
        (0xF, 0xF),
        (0xF0, 0x2),
    ] {
        let params = sp(handle.clone(), targets.clone(), offset, stride, 0);
        let report = pipeline
            .launch(&params, &sbt, targets.len() as u32, 1, 1)
            .unwrap();
        assert_eq!(
            report.exceptions, 0,
            "stride {stride:#x} offset {offset:#x}: {report:?}"
        );
        let out = params.out.to_vec();
        for (k, &(gas_index, _)) in expected.iter().enumerate() {
            let record = gas_index * (stride & 0xF) + (offset & 0xF);
            assert_eq!(
                out[k][0],
                1000 + record,
                "triangle {k} (sbtGASIndex {gas_index}), stride {stride:#x}, offset {offset:#x}"
            );
            assert_eq!(out[k][3], 1, "triangle {k} was hit");
        }
        assert_eq!(out[9], [500, !0, !0, 2], "the empty spot misses");
    }
}

/// §7.3.2 / Z7 G19: `sbt_gas_index()` is the sum of the records of earlier build inputs plus the
/// primitive's SBT index offset.
#[test]
fn sbt_gas_index_prefix_sum_7_3_2_g19() {
    let m = sbt_module();
    let (gas, targets, expected) = three_input_scene();
    let (pipeline, sbt) = sbt_pipeline(&m, 6, 1);
    let params = sp(TraversableHandle::from(gas), targets.clone(), 0, 1, 0);
    let report = pipeline
        .launch(&params, &sbt, targets.len() as u32, 1, 1)
        .unwrap();
    assert_eq!(report.exceptions, 0, "{:?}", report.first_exceptions);
    let out = params.out.to_vec();
    for (k, &(gas_index, _)) in expected.iter().enumerate() {
        assert_eq!(out[k][1], gas_index, "triangle {k}");
        assert_eq!(
            out[k][0],
            1000 + gas_index,
            "stride 1 offset 0 uses record sbtGASIndex"
        );
    }
}

/// §5.1 / §13.7 / Z7 G20: `primitive_index()` is the index within the build input plus the
/// input's `primitiveIndexOffset`.
#[test]
fn primitive_index_with_offset_13_7_g20() {
    let m = sbt_module();
    let (gas, targets, expected) = three_input_scene();
    let (pipeline, sbt) = sbt_pipeline(&m, 6, 1);
    let params = sp(TraversableHandle::from(gas), targets.clone(), 0, 1, 0);
    let report = pipeline
        .launch(&params, &sbt, targets.len() as u32, 1, 1)
        .unwrap();
    assert_eq!(report.exceptions, 0, "{:?}", report.first_exceptions);
    let out = params.out.to_vec();
    for (k, &(_, prim)) in expected.iter().enumerate() {
        assert_eq!(out[k][2], prim, "triangle {k}");
    }
}

/// §7.2 / §13.2 / Z7 G22: a miss runs the miss record selected by the trace's miss index, and its
/// `sbt_data` is that record's data.
#[test]
fn miss_record_by_miss_index_7_2_g22() {
    let m = sbt_module();
    let (pipeline, sbt) = sbt_pipeline(&m, 1, 4);
    let targets = vec![Vec3::new(50.0, 50.0, 0.0); 3];
    for miss in 0..4 {
        for handle in [
            TraversableHandle::NULL,
            TraversableHandle::from(tri_gas(&[tri_at(0.0, 0.0, 0.0, 1.0)])),
        ] {
            let params = sp(handle, targets.clone(), 0, 1, miss);
            let report = pipeline.launch(&params, &sbt, 3, 1, 1).unwrap();
            assert_eq!(report.exceptions, 0, "{:?}", report.first_exceptions);
            for o in params.out.to_vec() {
                assert_eq!(o, [500 + miss, !0, !0, 2], "miss index {miss}");
            }
        }
    }
}

/// §7.2 / Z7 G22: record `i` of a region lies at `base + i * stride`, and `sbt_data` starts
/// 32 bytes into it, for regions laid out by hand with a stride larger than the records need.
#[test]
fn record_address_base_plus_index_times_stride_7_2_g22() {
    let m = sbt_module();
    let rg = ProgramGroup::raygen(&m, "__raygen__rays").unwrap();
    let hg = ProgramGroup::hit_group(oxray::HitGroupDesc {
        closest_hit: Some((&m, "__closesthit__record")),
        ..Default::default()
    })
    .unwrap();
    let ms = ProgramGroup::miss(Some((&m, "__miss__record"))).unwrap();
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &compile(4, 2),
        &link(1),
        &[rg.clone(), hg.clone(), ms.clone()],
    )
    .unwrap();
    let region = |header: oxray::SbtHeader, stride: usize, count: usize, base: u32| {
        let mut bytes = vec![0xEEu8; stride * count];
        for i in 0..count {
            let r = &mut bytes[i * stride..(i + 1) * stride];
            r[..32].copy_from_slice(&header.0);
            r[32..36].copy_from_slice(&(base + i as u32).to_le_bytes());
        }
        SbtRegion::from_bytes(bytes, stride, count).unwrap()
    };
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: region(ms.pack_header(), 80, 3, 700),
        hitgroup: region(hg.pack_header(), 128, 8, 2000),
        ..Default::default()
    };
    let (gas, targets, expected) = three_input_scene();
    let handle = TraversableHandle::from(gas);
    let params = sp(handle.clone(), targets.clone(), 1, 1, 2);
    let report = pipeline
        .launch(&params, &sbt, targets.len() as u32, 1, 1)
        .unwrap();
    assert_eq!(report.exceptions, 0, "{:?}", report.first_exceptions);
    let out = params.out.to_vec();
    for (k, &(gas_index, _)) in expected.iter().enumerate() {
        assert_eq!(out[k][0], 2000 + gas_index + 1, "triangle {k}");
    }
    assert_eq!(out[9][0], 702, "miss record 2");
}

/// §7.4 / §13.8: `sbt_data` in ray-generation and exception programs is the data of the
/// raygen and exception records; a type longer than the record's data gives `None`;
/// `sbt_data_bytes` is everything after the 32-byte header.
#[test]
fn sbt_data_of_raygen_and_exception_records_7_4() {
    #[derive(Clone)]
    struct P {
        out: Arc<OutputBuffer<[u32; 8]>>,
    }
    let m = Module::<P>::new()
        .raygen("__raygen__data", |ctx| {
            let d = ctx.sbt_data::<[u32; 4]>().unwrap_or([!0; 4]);
            let too_long = ctx.sbt_data::<[u32; 5]>().is_some() as u32;
            let len = ctx.sbt_data_bytes().len() as u32;
            ctx.params()
                .out
                .write(0, [d[0], d[1], d[2], d[3], too_long, len, 0, 0]);
            ctx.throw_exception(1, &[])
        })
        .unwrap()
        .exception("__exception__data", |ctx| {
            let d = ctx.sbt_data::<[u32; 2]>().unwrap_or([!0; 2]);
            let len = ctx.sbt_data_bytes().len() as u32;
            ctx.params().out.write(1, [d[0], d[1], len, 0, 0, 0, 0, 0]);
        })
        .unwrap();
    let rg = ProgramGroup::raygen(&m, "__raygen__data").unwrap();
    let ex = ProgramGroup::exception(&m, "__exception__data").unwrap();
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &compile(2, 2),
        &link(0),
        &[rg.clone(), ex.clone()],
    )
    .unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_records(&[(rg.pack_header(), [11u32, 12, 13, 14])]),
        exception: Some(SbtRegion::from_records(&[(ex.pack_header(), [21u32, 22])])),
        ..Default::default()
    };
    let params = P {
        out: Arc::new(OutputBuffer::new(2)),
    };
    let report = pipeline.launch(&params, &sbt, 1, 1, 1).unwrap();
    assert_eq!(report.exceptions, 1);
    let out = params.out.to_vec();
    assert_eq!(out[0], [11, 12, 13, 14, 0, 16, 0, 0], "raygen record data");
    // 32 + 8 bytes rounded up to 48: 16 bytes of data.
    assert_eq!(out[1], [21, 22, 16, 0, 0, 0, 0, 0], "exception record data");
}

/// §7.4 / §13.8: `sbt_data` in any-hit, closest-hit and miss programs is the data of the record
/// that selected them (any-hit and closest-hit of one hit see the same record).
#[test]
fn sbt_data_of_hit_and_miss_records_7_4() -> TestResult {
    let m = with_single_raygen(Module::new())
        .closest_hit("__closesthit__log", log_ch)?
        .any_hit("__anyhit__log", log_ah)?
        .miss("__miss__log", log_ms)?;
    let hg = hit_group(&m, Some("__closesthit__log"), Some("__anyhit__log"), None);
    let ms = miss_group(&m, Some("__miss__log"));
    let s = Setup::new(&m)
        .hit(&hg, 40)
        .hit(&hg, 41)
        .hit(&hg, 42)
        .miss(&ms, 90)
        .miss(&ms, 91);
    let handle = TraversableHandle::from(tri_gas(&[tri_at(0.0, 0.0, 0.0, 1.0)]));
    let out = s.run(&handle, RayDesc::down(0.0, 0.0).sbt(2, 1, 1), &[]);
    assert_eq!(
        out.of(Prog::Ah).iter().map(|e| e.data).collect::<Vec<_>>(),
        vec![42]
    );
    assert_eq!(out.ch().data, 42);
    let out = s.run(&handle, RayDesc::down(5.0, 5.0).sbt(2, 1, 1), &[]);
    assert_eq!(
        out.of(Prog::Ms).iter().map(|e| e.data).collect::<Vec<_>>(),
        vec![91]
    );
    // Intersection programs see their hit group's record too.
    let m = with_single_raygen(Module::new())
        .closest_hit("__closesthit__log", log_ch)?
        .intersection("__intersection__data", |ctx| {
            let d = ctx.sbt_data::<u32>().unwrap_or(!0);
            ctx.params().note(format!("IS {d}"));
            ctx.report_intersection(9.5, 0, &[])?;
            Ok(())
        })?;
    let hg = hit_group(
        &m,
        Some("__closesthit__log"),
        None,
        Some("__intersection__data"),
    );
    let s = Setup::new(&m)
        .hit(&hg, 60)
        .hit(&hg, 61)
        .miss(&miss_group(&m, None), 0);
    let boxes = TraversableHandle::from(box_gas(&[cube(Vec3::ZERO, 0.5)]));
    let out = s.run(&boxes, RayDesc::down(0.0, 0.0).sbt(1, 1, 0), &[]);
    assert_eq!(out.notes, vec!["IS 61"]);
    assert_eq!(out.ch().data, 61);
    Ok(())
}

/// §7.2: strides are multiples of 16 (`OPTIX_SBT_RECORD_ALIGNMENT`) holding at least the 32-byte
/// header; the bytes must hold `count` records.
#[test]
fn sbt_region_from_bytes_stride_rules_7_2() {
    for stride in [0usize, 16, 8, 40, 33, 47, 100] {
        assert_eq!(
            SbtRegion::from_bytes(vec![0; 1024], stride, 1).unwrap_err(),
            PipelineError::InvalidSbtStride { stride },
            "stride {stride}"
        );
    }
    for stride in [32usize, 48, 64, 256] {
        let r = SbtRegion::from_bytes(vec![0; stride * 3], stride, 3).unwrap();
        assert_eq!((r.stride(), r.count()), (stride, 3));
        assert_eq!(r.record(2).map(<[u8]>::len), Some(stride));
        assert!(r.record(3).is_none());
    }
    assert_eq!(
        SbtRegion::from_bytes(vec![0; 95], 32, 3).unwrap_err(),
        PipelineError::SbtRegionTooSmall {
            needed: 96,
            len: 95
        }
    );
    assert!(
        SbtRegion::from_bytes(vec![0; 200], 32, 3).is_ok(),
        "extra bytes are fine"
    );
    assert!(
        SbtRegion::from_bytes(Vec::new(), 32, 0).is_ok(),
        "an empty region"
    );
    // Typed records: 32 + data rounded up to 16.
    let h = oxray::SbtHeader([0; 32]);
    assert_eq!(SbtRegion::from_records(&[(h, 0u8)]).stride(), 48);
    assert_eq!(SbtRegion::from_records(&[(h, [0u32; 4])]).stride(), 48);
    assert_eq!(SbtRegion::from_records(&[(h, [0u32; 5])]).stride(), 64);
    assert_eq!(SbtRegion::from_headers(&[h, h]).stride(), 32);
}

fn rejected(result: Result<oxray::LaunchReport, LaunchError>, region: &str, index: usize) {
    match result {
        Err(LaunchError::InvalidSbtRecord {
            region: r,
            index: i,
            ..
        }) => {
            assert_eq!((r, i), (region, index));
        }
        other => panic!("expected InvalidSbtRecord in {region} record {index}, got {other:?}"),
    }
}

/// §7.1 / §10: a launch whose SBT holds a record header packed from a group that is not in the
/// pipeline, from a group of the wrong kind for its region, or no header at all, is refused
/// with `LaunchError::InvalidSbtRecord` and runs nothing.
#[test]
fn invalid_sbt_record_headers_refused_at_launch_7_1() {
    let m = sbt_module();
    let rg = ProgramGroup::raygen(&m, "__raygen__rays").unwrap();
    let hg = ProgramGroup::hit_group(oxray::HitGroupDesc {
        closest_hit: Some((&m, "__closesthit__record")),
        ..Default::default()
    })
    .unwrap();
    let ms = ProgramGroup::miss(Some((&m, "__miss__record"))).unwrap();
    // Same programs, but a group the pipeline does not hold.
    let stranger = ProgramGroup::hit_group(oxray::HitGroupDesc {
        closest_hit: Some((&m, "__closesthit__record")),
        ..Default::default()
    })
    .unwrap();
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &compile(4, 2),
        &link(1),
        &[rg.clone(), hg.clone(), ms.clone()],
    )
    .unwrap();
    let good = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_headers(&[ms.pack_header()]),
        hitgroup: SbtRegion::from_headers(&[hg.pack_header(), hg.pack_header()]),
        ..Default::default()
    };
    let params = sp(TraversableHandle::NULL, vec![Vec3::ZERO], 0, 1, 0);
    assert!(pipeline.launch(&params, &good, 1, 1, 1).is_ok());
    assert_eq!(params.raygen_runs.load(Ordering::Relaxed), 1);

    let params = sp(TraversableHandle::NULL, vec![Vec3::ZERO], 0, 1, 0);
    let with = |f: &dyn Fn(&mut ShaderBindingTable)| {
        let mut sbt = good.clone();
        f(&mut sbt);
        pipeline.launch(&params, &sbt, 1, 1, 1)
    };
    // Not in the pipeline.
    rejected(
        with(&|s| {
            s.hitgroup = SbtRegion::from_headers(&[hg.pack_header(), stranger.pack_header()])
        }),
        "hitgroup",
        1,
    );
    // Wrong kind for the region.
    rejected(
        with(&|s| s.miss = SbtRegion::from_headers(&[hg.pack_header()])),
        "miss",
        0,
    );
    rejected(
        with(&|s| s.hitgroup = SbtRegion::from_headers(&[ms.pack_header()])),
        "hitgroup",
        0,
    );
    rejected(
        with(&|s| s.raygen = SbtRegion::from_headers(&[ms.pack_header()])),
        "raygen",
        0,
    );
    rejected(
        with(&|s| s.exception = Some(SbtRegion::from_headers(&[rg.pack_header()]))),
        "exception",
        0,
    );
    // Not a header at all.
    rejected(
        with(&|s| s.hitgroup = SbtRegion::from_bytes(vec![0; 64], 32, 2).unwrap()),
        "hitgroup",
        0,
    );
    // No raygen record.
    assert!(matches!(
        with(&|s| s.raygen = SbtRegion::default()),
        Err(LaunchError::NoRaygenRecord)
    ));
    assert_eq!(
        params.raygen_runs.load(Ordering::Relaxed),
        0,
        "a refused launch runs nothing"
    );
    assert_eq!(
        LaunchError::NoRaygenRecord.code(),
        oxray::ErrorCode::InvalidLaunchParameter
    );
}

/// §6.6 / §7.1: a program group may serve several records and several pipelines; the same SBT
/// (same headers) works with every pipeline that holds the groups.
#[test]
fn program_group_reused_across_pipelines_6_6() {
    let m = sbt_module();
    let rg = ProgramGroup::raygen(&m, "__raygen__rays").unwrap();
    let hg = ProgramGroup::hit_group(oxray::HitGroupDesc {
        closest_hit: Some((&m, "__closesthit__record")),
        ..Default::default()
    })
    .unwrap();
    let ms = ProgramGroup::miss(Some((&m, "__miss__record"))).unwrap();
    let p1 = Pipeline::new(
        &DeviceContext::new(),
        &compile(4, 2),
        &link(1),
        &[rg.clone(), hg.clone(), ms.clone()],
    )
    .unwrap();
    let p2 = Pipeline::new(
        &DeviceContext::new(),
        &compile(4, 2),
        &link(2),
        &[ms.clone(), hg.clone(), rg.clone()],
    )
    .unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_records(&[(ms.pack_header(), 500u32)]),
        hitgroup: SbtRegion::from_records(&[
            (hg.pack_header(), 1000u32),
            (hg.pack_header(), 1001u32),
        ]),
        ..Default::default()
    };
    let handle = TraversableHandle::from(tri_gas(&[tri_at(0.0, 0.0, 0.0, 1.0)]));
    for p in [&p1, &p2] {
        let params = sp(
            handle.clone(),
            vec![Vec3::ZERO, Vec3::new(9.0, 0.0, 0.0)],
            1,
            1,
            0,
        );
        let report = p.launch(&params, &sbt, 2, 1, 1).unwrap();
        assert_eq!(report.exceptions, 0, "{:?}", report.first_exceptions);
        assert_eq!(params.out.to_vec(), vec![[1001, 0, 0, 1], [500, !0, !0, 2]]);
    }
}

/// §5.1 / §7.3.2: a triangle input with an index buffer and a `u32` SBT index offset buffer
/// selects records the same way as a soup.
#[test]
fn indexed_input_with_u32_offsets_selects_records_7_3_2() {
    let m = sbt_module();
    let v = [
        [0.0f32, -1.0, 0.0],
        [2.0, -1.0, 0.0],
        [1.0, 1.0, 0.0],
        [4.0, 1.0, 0.0],
        [3.0, -1.0, 0.0],
    ];
    // Triangles 0 (around x=1) and 1 (around x=3, counter-clockwise from +z).
    let idx = [[0u32, 1, 2], [2, 4, 3]];
    let offs = [3u32, 1];
    let flags = [GeometryFlags::empty(); 4];
    let input = TriangleInput::new(VertexBuffer::f32x3(&v))
        .indices(IndexBuffer::u32x3(&idx))
        .flags(&flags)
        .sbt_index_offsets(SbtIndexOffsets::u32(&offs))
        .primitive_index_offset(5);
    let gas = Gas::build(&BuildOptions::default(), &[input.into()]).unwrap();
    let (pipeline, sbt) = sbt_pipeline(&m, 8, 1);
    let params = sp(
        TraversableHandle::from(gas),
        vec![Vec3::new(1.0, -0.5, 0.0), Vec3::new(3.0, 0.5, 0.0)],
        0,
        2,
        0,
    );
    let report = pipeline.launch(&params, &sbt, 2, 1, 1).unwrap();
    assert_eq!(report.exceptions, 0, "{:?}", report.first_exceptions);
    assert_eq!(params.out.to_vec(), vec![[1006, 3, 5, 1], [1002, 1, 6, 1]]);
}
