//! The transform list of a hit (guide §13.11, inventory Z1.8): entries from the root (index 0)
//! to the geometry, with their kind, ids and matrices, in any-hit and closest-hit programs.

use glam::Vec3;
use oxray::cpu::{Gas, Ias};
use oxray::{
    BuildOptions, DeviceContext, HitGroupDesc, Instance, Module, OutputBuffer, Pipeline,
    PipelineCompileOptions, PipelineLinkOptions, ProgramGroup, SbtRegion, ShaderBindingTable,
    StaticTransform, TraceRay, Transform, TransformListEntry, TransformListKind, TraversableHandle,
    TriangleInput, VertexBuffer,
};
use std::sync::Mutex;

#[derive(Clone)]
struct Params<'a> {
    handle: TraversableHandle,
    seen: &'a Mutex<Vec<(&'static str, Vec<TransformListEntry>)>>,
    out: &'a OutputBuffer<u32>,
}

fn collect(n: u32, entry: impl Fn(u32) -> Option<TransformListEntry>) -> Vec<TransformListEntry> {
    assert!(entry(n).is_none(), "an entry past the list");
    (0..n)
        .map(|i| entry(i).expect("entry inside the list"))
        .collect()
}

fn trace(handle: TraversableHandle) -> Vec<(&'static str, Vec<TransformListEntry>)> {
    let seen = Mutex::new(Vec::new());
    let out = OutputBuffer::new(1);
    let module = Module::<Params>::new()
        .raygen("__raygen__rg", |ctx| {
            let p = ctx.params();
            let mut payload = [0u32; 1];
            ctx.trace(
                &TraceRay::new(&p.handle, Vec3::new(0.1, 0.1, -10.0), Vec3::Z),
                &mut payload,
            )?;
            p.out.write(0, payload[0]);
            Ok(())
        })
        .unwrap()
        .any_hit("__anyhit__ah", |ctx| {
            let list = collect(ctx.transform_list_size(), |i| ctx.transform_list_entry(i));
            ctx.params().seen.lock().unwrap().push(("AH", list));
            Ok(())
        })
        .unwrap()
        .closest_hit("__closesthit__ch", |ctx| {
            let list = collect(ctx.transform_list_size(), |i| ctx.transform_list_entry(i));
            ctx.params().seen.lock().unwrap().push(("CH", list));
            ctx.set_payload(0, 1);
            Ok(())
        })
        .unwrap();
    let rg = ProgramGroup::raygen(&module, "__raygen__rg").unwrap();
    let ms = ProgramGroup::miss(None).unwrap();
    let hg = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__ch")),
        any_hit: Some((&module, "__anyhit__ah")),
        ..Default::default()
    })
    .unwrap();
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &PipelineCompileOptions {
            num_payload_values: 1,
            ..Default::default()
        },
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
    let report = pipeline
        .launch(
            &Params {
                handle,
                seen: &seen,
                out: &out,
            },
            &sbt,
            1,
            1,
            1,
        )
        .unwrap();
    assert_eq!(report.exceptions, 0, "{:?}", report.first_exceptions);
    assert_eq!(out.read(0), Some(1), "the ray must hit");
    let result = seen.lock().unwrap().clone();
    result
}

fn triangle() -> Gas {
    let v = [[-1.0f32, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]];
    Gas::build(
        &BuildOptions::default(),
        &[TriangleInput::new(VertexBuffer::f32x3(&v)).into()],
    )
    .unwrap()
}

#[test]
fn gas_root_has_an_empty_transform_list_13_11() {
    let seen = trace(triangle().into());
    assert_eq!(seen.len(), 2);
    assert!(seen.iter().all(|(_, l)| l.is_empty()));
}

#[test]
fn nested_instances_and_static_transforms_are_listed_root_first_13_11() {
    let t_inner = Transform::from_translation(Vec3::new(0.0, 0.0, 1.0));
    let t_static = Transform::from_translation(Vec3::new(0.0, 0.0, 2.0));
    let t_outer = Transform::from_translation(Vec3::new(0.0, 0.0, 3.0));
    let inner = Ias::build(
        &BuildOptions::default(),
        &[(&[Instance::new(triangle().into())
            .transform(t_inner)
            .instance_id(7)][..])
            .into()],
    )
    .unwrap();
    let st = StaticTransform::new(inner.into(), t_static).unwrap();
    let outer = Ias::build(
        &BuildOptions::default(),
        &[(&[
            Instance::new(TraversableHandle::NULL),
            Instance::new(st.into()).transform(t_outer).instance_id(5),
        ][..])
            .into()],
    )
    .unwrap();
    let seen = trace(outer.into());
    assert_eq!(
        seen.iter().map(|(k, _)| *k).collect::<Vec<_>>(),
        ["AH", "CH"]
    );
    for (_, list) in &seen {
        let kinds: Vec<_> = list.iter().map(|e| e.kind).collect();
        assert_eq!(
            kinds,
            [
                TransformListKind::Instance {
                    instance_id: 5,
                    instance_index: 1
                },
                TransformListKind::StaticTransform,
                TransformListKind::Instance {
                    instance_id: 7,
                    instance_index: 0
                },
            ]
        );
        let o2w: Vec<_> = list.iter().map(|e| e.object_to_world).collect();
        assert_eq!(o2w, [t_outer, t_static, t_inner]);
        for e in list {
            let p = Vec3::new(0.3, -0.2, 0.7);
            let back = e
                .world_to_object
                .transform_point(e.object_to_world.transform_point(p));
            assert!((back - p).length() < 1e-6);
        }
    }
}

/// §6.8 / §12: a trace of a graph deeper than the pipeline's `max_traversable_graph_depth`
/// raises `TRAVERSAL_DEPTH_EXCEEDED`; the depth must be in 1..=31.
#[test]
fn max_traversable_graph_depth_is_enforced_6_8() {
    use oxray::ExceptionCode;
    let module = Module::<TraversableHandle>::new()
        .raygen("__raygen__rg", |ctx| {
            let mut payload = [0u32; 1];
            ctx.trace(
                &TraceRay::new(ctx.params(), Vec3::new(0.1, 0.1, -10.0), Vec3::Z),
                &mut payload,
            )
        })
        .unwrap();
    let rg = ProgramGroup::raygen(&module, "__raygen__rg").unwrap();
    let ms = ProgramGroup::miss(None).unwrap();
    let mut pipeline = Pipeline::new(
        &DeviceContext::new(),
        &PipelineCompileOptions::default(),
        &PipelineLinkOptions { max_trace_depth: 1 },
        &[rg.clone(), ms.clone()],
    )
    .unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_headers(&[ms.pack_header()]),
        ..Default::default()
    };
    // IAS -> GAS: two levels.
    let ias: TraversableHandle = Ias::build(
        &BuildOptions::default(),
        &[(&[Instance::new(triangle().into())][..]).into()],
    )
    .unwrap()
    .into();
    assert_eq!(
        pipeline.launch(&ias, &sbt, 1, 1, 1).unwrap().exceptions,
        1,
        "no hit group: an exception"
    );
    pipeline.set_max_traversable_graph_depth(1).unwrap();
    let report = pipeline.launch(&ias, &sbt, 1, 1, 1).unwrap();
    assert_eq!(
        report.first_exceptions[0].1.code,
        ExceptionCode::TRAVERSAL_DEPTH_EXCEEDED
    );
    // A GAS (one level) is within the limit: traversal runs and finds no hit-group record.
    let gas: TraversableHandle = triangle().into();
    let report = pipeline.launch(&gas, &sbt, 1, 1, 1).unwrap();
    assert_eq!(
        report.first_exceptions.first().map(|e| e.1.code),
        Some(ExceptionCode::INVALID_HIT_SBT)
    );
    assert!(pipeline.set_max_traversable_graph_depth(0).is_err());
    assert!(pipeline.set_max_traversable_graph_depth(32).is_err());
}
