//! One test per dirty rule of optix_util-design.md §2, and the util path against the low-level
//! path (identical output).

use oxray::{
    BuildFlags, BuildOptions, DeviceContext, Gas, HitGroupDesc, Ias, IndexBuffer, Instance, Module,
    OutputBuffer, Pipeline, PipelineCompileOptions, PipelineLinkOptions, ProgramGroup, SbtRegion,
    ShaderBindingTable, TraceRay, Transform, TraversableHandle, TriangleInput, VertexBuffer,
};
use oxray_util::{
    Context, GasDesc, GasId, GeomId, Geometry, GeometryInstance, HitGroupData, IasId, MaterialId,
    Scene, UtilError, UtilInstance,
};

fn quad() -> Geometry {
    Geometry::Triangles {
        vertices: vec![
            [-1.0, -1.0, 0.0],
            [1.0, -1.0, 0.0],
            [1.0, 1.0, 0.0],
            [-1.0, 1.0, 0.0],
        ],
        indices: vec![[0, 1, 2], [0, 2, 3]],
    }
}

struct Built {
    scene: Scene<()>,
    mat: MaterialId,
    geom: GeomId,
    gas: GasId,
    ias: IasId,
    hg: ProgramGroup<()>,
}

/// One material, one geometry, one GAS with one set of 1 ray type, one IAS; all clean.
fn built() -> Built {
    let ctx = Context::new(DeviceContext::new());
    let module = Module::<()>::new()
        .closest_hit("__closesthit__ch", |_| Ok(()))
        .unwrap();
    let hg = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__ch")),
        ..Default::default()
    })
    .unwrap();
    let mut scene = ctx.create_scene();
    let mat = scene.add_material(ctx.create_material(vec![Some(hg.clone())], 1));
    let geom = scene.add_geometry(GeometryInstance::new(quad(), 1).material(0, 0, mat));
    let gas = scene.add_gas(GasDesc::new(vec![geom], vec![1]));
    let ias = scene.add_ias(vec![UtilInstance::new(gas, 0)], BuildFlags::empty());
    scene.rebuild_dirty().unwrap();
    scene.hit_group_records().unwrap();
    assert!(scene.check_ready().is_ok() && !scene.is_sbt_dirty() && !scene.is_layout_dirty());
    Built {
        scene,
        mat,
        geom,
        gas,
        ias,
        hg,
    }
}

fn dirty_what(r: Result<(), UtilError>) -> String {
    match r {
        Err(UtilError::Dirty { what, .. }) => what,
        other => panic!("expected a dirty error, got {other:?}"),
    }
}

#[test]
fn gas_build_settings_make_the_gas_dirty_auto() {
    let mut b = built();
    b.scene
        .update_gas(b.gas, |d| d.build_flags = BuildFlags::PREFER_FAST_BUILD)
        .unwrap();
    assert!(b.scene.is_gas_dirty(b.gas));
    assert_eq!(dirty_what(b.scene.check_ready()), "GAS 0");
}

#[test]
fn adding_or_removing_a_geometry_instance_makes_the_gas_dirty_auto() {
    let mut b = built();
    let extra = b
        .scene
        .add_geometry(GeometryInstance::new(quad(), 1).material(0, 0, b.mat));
    b.scene
        .update_gas(b.gas, |d| d.children.push(extra))
        .unwrap();
    assert!(b.scene.is_gas_dirty(b.gas) && b.scene.is_layout_dirty());
    b.scene.rebuild_dirty().unwrap();
    b.scene
        .update_gas(b.gas, |d| {
            d.children.pop();
        })
        .unwrap();
    assert!(b.scene.is_gas_dirty(b.gas));
}

#[test]
fn geometry_changes_make_the_gas_dirty() {
    let mut b = built();
    b.scene
        .update_geometry(b.geom, |g| {
            g.material_flags[0] = oxray::GeometryFlags::DISABLE_ANYHIT
        })
        .unwrap();
    assert!(b.scene.is_gas_dirty(b.gas));
}

#[test]
fn a_dirty_gas_makes_the_layout_and_every_ias_dirty_auto() {
    let mut b = built();
    b.scene
        .update_gas(b.gas, |d| d.build_flags = BuildFlags::empty())
        .unwrap();
    assert!(b.scene.is_layout_dirty() && b.scene.is_ias_dirty(b.ias) && b.scene.is_sbt_dirty());
}

#[test]
fn material_sets_or_ray_types_make_the_layout_dirty_auto() {
    let mut b = built();
    b.scene
        .update_gas(b.gas, |d| d.ray_types_per_set = vec![1, 1])
        .unwrap();
    assert!(b.scene.is_layout_dirty() && !b.scene.is_gas_dirty(b.gas));
    b.scene.rebuild_dirty().unwrap();
    b.scene
        .update_gas(b.gas, |d| d.ray_types_per_set = vec![1, 2])
        .unwrap();
    assert!(b.scene.is_layout_dirty() && b.scene.is_ias_dirty(b.ias));
}

#[test]
fn instances_added_or_removed_make_the_ias_dirty_auto() {
    let mut b = built();
    let gas = b.gas;
    b.scene
        .update_ias(b.ias, |i| i.push(UtilInstance::new(gas, 0)))
        .unwrap();
    assert!(b.scene.is_ias_dirty(b.ias) && !b.scene.is_layout_dirty());
    assert_eq!(dirty_what(b.scene.check_ready()), "IAS 0");
}

#[test]
fn a_rebuilt_gas_makes_the_ias_over_it_dirty() {
    let mut b = built();
    b.scene.build_gas(b.gas).unwrap();
    assert!(b.scene.is_ias_dirty(b.ias));
}

#[test]
fn material_hit_group_or_user_data_make_only_the_sbt_dirty() {
    let mut b = built();
    b.scene.set_material_user_data(b.mat, 2).unwrap();
    assert!(b.scene.is_sbt_dirty() && !b.scene.is_layout_dirty() && !b.scene.is_ias_dirty(b.ias));
    b.scene.hit_group_records().unwrap();
    let hg = b.hg.clone();
    b.scene.set_material_hit_group(b.mat, 0, Some(hg)).unwrap();
    assert!(b.scene.is_sbt_dirty() && !b.scene.is_layout_dirty());
}

#[test]
fn gas_user_data_makes_only_the_sbt_dirty() {
    let mut b = built();
    b.scene.update_gas(b.gas, |d| d.user_data = 9).unwrap();
    assert!(b.scene.is_sbt_dirty() && !b.scene.is_gas_dirty(b.gas) && !b.scene.is_layout_dirty());
}

#[test]
fn a_missing_material_or_hit_group_is_a_clear_error() {
    let mut b = built();
    let g = b.scene.add_geometry(
        GeometryInstance::new(quad(), 2)
            .material(0, 0, b.mat)
            .material_indices(vec![0, 1]),
    );
    b.scene.add_gas(GasDesc::new(vec![g], vec![1]));
    assert!(matches!(
        b.scene.hit_group_records(),
        Err(UtilError::MissingMaterial {
            set: 0,
            index: 1,
            ..
        })
    ));
    let mut b = built();
    b.scene
        .update_gas(b.gas, |d| d.ray_types_per_set = vec![2])
        .unwrap();
    assert!(matches!(
        b.scene.hit_group_records(),
        Err(UtilError::MissingHitGroup { ray_type: 1, .. })
    ));
}

/// The same scene through the util layer and through the low-level API gives the same output.
#[test]
fn util_and_low_level_paths_render_identically() {
    #[derive(Clone)]
    struct Params<'a> {
        handle: TraversableHandle,
        out: &'a OutputBuffer<u32>,
    }
    let outs = [OutputBuffer::new(64), OutputBuffer::new(64)];
    let module = Module::<Params>::new()
        .raygen("__raygen__rg", |ctx| {
            let [x, _, _] = ctx.launch_index();
            let p = ctx.params();
            let mut payload = [0u32];
            let o = glam::Vec3::new(x as f32 * 0.25 - 4.0, 0.3, -5.0);
            ctx.trace(
                &TraceRay::new(&p.handle, o, glam::Vec3::Z).sbt(0, 1, 0),
                &mut payload,
            )?;
            p.out.write(x as usize, payload[0]);
            Ok(())
        })
        .unwrap()
        .closest_hit("__closesthit__ch", |ctx| {
            let d = ctx.sbt_data::<HitGroupData>().unwrap();
            ctx.set_payload(
                0,
                d.material * 1000 + ctx.primitive_index() * 10 + ctx.instance_id(),
            );
            Ok(())
        })
        .unwrap();
    let hg = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__ch")),
        ..Default::default()
    })
    .unwrap();
    let rg = ProgramGroup::raygen(&module, "__raygen__rg").unwrap();
    let ms = ProgramGroup::miss(None).unwrap();
    let shift = |x: f32| Transform::from_translation(glam::Vec3::new(x, 0.0, 0.0));

    // Util path: two instances of one GAS with material sets 0 and 1.
    let mut scene: Scene<Params> = Scene::new();
    let a = scene.add_material(oxray_util::Material::new(vec![Some(hg.clone())], 1));
    let b = scene.add_material(oxray_util::Material::new(vec![Some(hg.clone())], 2));
    let g = scene.add_geometry(
        GeometryInstance::new(quad(), 1)
            .material(0, 0, a)
            .material(1, 0, b),
    );
    let gas = scene.add_gas(GasDesc::new(vec![g], vec![1, 1]));
    let mut i0 = UtilInstance::new(gas, 0);
    i0.transform = shift(-2.0);
    i0.instance_id = 3;
    let mut i1 = UtilInstance::new(gas, 1);
    i1.transform = shift(2.0);
    i1.instance_id = 4;
    let ias = scene.add_ias(vec![i0, i1], BuildFlags::empty());
    scene.rebuild_dirty().unwrap();
    let handle = scene.ias_handle(ias).unwrap();
    let pipeline = oxray_util::ScenePipeline::new(
        &DeviceContext::new(),
        PipelineCompileOptions {
            num_payload_values: 1,
            ..Default::default()
        },
        PipelineLinkOptions { max_trace_depth: 1 },
        rg.clone(),
        vec![ms.clone()],
    );
    let report = pipeline
        .launch(
            &mut scene,
            &Params {
                handle,
                out: &outs[0],
            },
            64,
            1,
            1,
        )
        .unwrap();
    assert_eq!(report.exceptions, 0, "{:?}", report.first_exceptions);

    // Low-level path: the same structures and SBT written by hand.
    let Geometry::Triangles { vertices, indices } = quad() else {
        unreachable!()
    };
    let input =
        TriangleInput::new(VertexBuffer::f32x3(&vertices)).indices(IndexBuffer::u32x3(&indices));
    let gas = std::sync::Arc::new(
        Gas::build(
            &BuildOptions::new(BuildFlags::PREFER_FAST_TRACE),
            &[input.into()],
        )
        .unwrap(),
    );
    let instances = [
        Instance::new(gas.clone().into())
            .transform(shift(-2.0))
            .instance_id(3)
            .sbt_offset(0),
        Instance::new(gas.into())
            .transform(shift(2.0))
            .instance_id(4)
            .sbt_offset(1),
    ];
    let handle: TraversableHandle =
        Ias::build(&BuildOptions::default(), &[(&instances[..]).into()])
            .unwrap()
            .into();
    let data = |m| HitGroupData {
        material: m,
        geometry: 0,
        gas: 0,
    };
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_headers(&[ms.pack_header()]),
        hitgroup: SbtRegion::from_records(&[
            (hg.pack_header(), data(1)),
            (hg.pack_header(), data(2)),
        ]),
        ..Default::default()
    };
    let low = Pipeline::new(
        &DeviceContext::new(),
        &PipelineCompileOptions {
            num_payload_values: 1,
            ..Default::default()
        },
        &PipelineLinkOptions { max_trace_depth: 1 },
        &[rg, ms, hg],
    )
    .unwrap();
    let report = low
        .launch(
            &Params {
                handle,
                out: &outs[1],
            },
            &sbt,
            64,
            1,
            1,
        )
        .unwrap();
    assert_eq!(report.exceptions, 0, "{:?}", report.first_exceptions);

    let (u, l) = (outs[0].to_vec(), outs[1].to_vec());
    assert_eq!(u, l);
    assert!(
        u.contains(&1003) && u.contains(&2004),
        "both material sets show: {u:?}"
    );
}
