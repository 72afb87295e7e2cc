//! The hit-group SBT layout of optix_util-design.md §1-§2, record by record, and the dirty rules
//! of §2.

use oxray::{
    DeviceContext, HitGroupDesc, Module, OutputBuffer, Pipeline, PipelineCompileOptions,
    PipelineLinkOptions, ProgramGroup, SbtRegion, ShaderBindingTable, TraceRay, TraversableHandle,
};
use oxray_util::{
    GasDesc, GasId, Geometry, GeometryInstance, HitGroupData, Material, MaterialId, Scene,
    UtilError, UtilInstance,
};

type P = ();

fn quad(z: f32) -> Geometry {
    Geometry::Triangles {
        vertices: vec![
            [-1.0, -1.0, z],
            [1.0, -1.0, z],
            [1.0, 1.0, z],
            [-1.0, 1.0, z],
        ],
        indices: vec![[0, 1, 2], [0, 2, 3]],
    }
}

/// A hit group per (material, ray type), told apart by its header.
fn hit_group(module: &Module<P>) -> ProgramGroup<P> {
    ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((module, "__closesthit__ch")),
        ..Default::default()
    })
    .unwrap()
}

/// The design's example: GAS 0 with two material sets (2 and 1 ray types) over inputs with 2, 3
/// and 1 materials; GAS 1 with one set (1 ray type) over one input of 1 material.
struct Example {
    scene: Scene<P>,
    /// `groups[material][ray type]`.
    groups: Vec<Vec<ProgramGroup<P>>>,
    /// `mats[(set, input, material)]`.
    mats: std::collections::BTreeMap<(u32, u32, u32), MaterialId>,
    gas0: GasId,
    gas1: GasId,
}

fn example() -> Example {
    let module = Module::<P>::new()
        .closest_hit("__closesthit__ch", |_| Ok(()))
        .unwrap();
    let mut scene = Scene::new();
    let mut groups = Vec::new();
    let mut mats = std::collections::BTreeMap::new();
    let counts = [2u32, 3, 1];
    let mut geoms = Vec::new();
    for (input, &n) in counts.iter().enumerate() {
        let mut g = GeometryInstance::new(quad(input as f32), n).user_data(100 + input as u32);
        for set in 0..2u32 {
            for m in 0..n {
                let gs = vec![hit_group(&module), hit_group(&module)];
                let id = scene.add_material(Material::new(
                    gs.iter().cloned().map(Some).collect(),
                    1000 * set + 10 * input as u32 + m,
                ));
                groups.push(gs);
                mats.insert((set, input as u32, m), id);
                g = g.material(set, m, id);
            }
        }
        if n > 1 {
            g = g.material_indices(vec![0, n - 1]);
        }
        geoms.push(scene.add_geometry(g));
    }
    let mut gas0 = GasDesc::new(geoms, vec![2, 1]);
    gas0.user_data = 7;
    let gas0 = scene.add_gas(gas0);
    let gs = vec![hit_group(&module)];
    let lone = scene.add_material(Material::new(vec![Some(gs[0].clone())], 5000));
    groups.push(gs);
    mats.insert((9, 9, 9), lone);
    let g = scene.add_geometry(GeometryInstance::new(quad(9.0), 1).material(0, 0, lone));
    let gas1 = scene.add_gas(GasDesc::new(vec![g], vec![1]));
    Example {
        scene,
        groups,
        mats,
        gas0,
        gas1,
    }
}

#[test]
fn layout_of_the_design_example_matches_record_by_record() {
    let mut ex = example();
    let layout = ex.scene.sbt_layout().unwrap().clone();
    // Chunk (GAS 0, set 0): 6 materials x 2 ray types; (GAS 0, set 1): 6 x 1; (GAS 1, set 0): 1.
    let c = |g: u32, s: usize| layout.chunk(g as usize, s).unwrap();
    assert_eq!((c(ex.gas0.0, 0).offset, c(ex.gas0.0, 0).len), (0, 12));
    assert_eq!((c(ex.gas0.0, 1).offset, c(ex.gas0.0, 1).len), (12, 6));
    assert_eq!((c(ex.gas1.0, 0).offset, c(ex.gas1.0, 0).len), (18, 1));
    assert_eq!(layout.hit_group_count(), 19);
    assert!(layout.chunk(ex.gas1.0 as usize, 1).is_none());

    let region = ex.scene.hit_group_records().unwrap();
    assert_eq!(region.count(), 19);
    // Expected order: set-major within the GAS, then input, material, ray type.
    let mut expected = Vec::new();
    for (set, rays) in [(0u32, 2u32), (1, 1)] {
        for (input, n) in [(0u32, 2u32), (1, 3), (2, 1)] {
            for m in 0..n {
                let id = ex.mats[&(set, input, m)];
                for r in 0..rays {
                    expected.push((
                        ex.groups[id.0 as usize][r as usize].pack_header(),
                        HitGroupData {
                            material: 1000 * set + 10 * input + m,
                            geometry: 100 + input,
                            gas: 7,
                        },
                    ));
                }
            }
        }
    }
    let lone = ex.mats[&(9, 9, 9)];
    expected.push((
        ex.groups[lone.0 as usize][0].pack_header(),
        HitGroupData {
            material: 5000,
            geometry: 0,
            gas: 0,
        },
    ));
    for (i, (header, data)) in expected.iter().enumerate() {
        let rec = region.record(i).unwrap();
        assert_eq!(&rec[..32], &header.0[..], "record {i}: header");
        let got: HitGroupData = bytemuck::pod_read_unaligned(&rec[32..32 + 12]);
        assert_eq!(&got, data, "record {i}: data");
    }
    // The SBT-GAS index of material 0 of input 1 is 2 (design §1: "Mat 1-0 is 2"); with stride 2
    // and ray type 1 its record in set 0 is 2 * 2 + 1 = 5.
    let id = ex.mats[&(0, 1, 0)];
    assert_eq!(
        &region.record(5).unwrap()[..32],
        &ex.groups[id.0 as usize][1].pack_header().0[..]
    );
}

#[test]
fn dirty_rules_follow_the_design() {
    let mut ex = example();
    // A new GAS is dirty until built; building one does not touch the other.
    assert!(ex.scene.is_gas_dirty(ex.gas0) && ex.scene.is_gas_dirty(ex.gas1));
    ex.scene.build_gas(ex.gas0).unwrap();
    assert!(!ex.scene.is_gas_dirty(ex.gas0) && ex.scene.is_gas_dirty(ex.gas1));
    ex.scene.build_gas(ex.gas1).unwrap();
    let ias = ex.scene.add_ias(
        vec![UtilInstance::new(ex.gas0, 1), UtilInstance::new(ex.gas1, 0)],
        Default::default(),
    );
    assert!(ex.scene.is_ias_dirty(ias));
    // An IAS over a dirty GAS cannot be built: the error names the GAS.
    ex.scene
        .update_gas(ex.gas0, |d| {
            d.build_flags = oxray::BuildFlags::PREFER_FAST_BUILD
        })
        .unwrap();
    match ex.scene.build_ias(ias) {
        Err(UtilError::Dirty { what, .. }) => assert_eq!(what, "GAS 0"),
        other => panic!("expected a dirty GAS, got {other:?}"),
    }
    ex.scene.build_gas(ex.gas0).unwrap();
    ex.scene.build_ias(ias).unwrap();
    ex.scene.hit_group_records().unwrap();
    assert!(ex.scene.check_ready().is_ok() && !ex.scene.is_sbt_dirty());

    // Ray types of a material set: layout dirty, hence IAS and SBT dirty, but the GAS is clean.
    ex.scene
        .update_gas(ex.gas0, |d| d.ray_types_per_set[1] = 2)
        .unwrap();
    assert!(ex.scene.is_layout_dirty() && ex.scene.is_ias_dirty(ias) && ex.scene.is_sbt_dirty());
    assert!(!ex.scene.is_gas_dirty(ex.gas0));
    assert!(matches!(
        ex.scene.check_ready(),
        Err(UtilError::Dirty { .. })
    ));
    // Material user data: only the SBT.
    ex.scene.build_ias(ias).unwrap();
    // Set 1 now has 2 ray types: 12 + 12 + 1 records.
    assert_eq!(ex.scene.hit_group_records().unwrap().count(), 25);
    let id = ex.mats[&(0, 0, 0)];
    ex.scene.set_material_user_data(id, 1).unwrap();
    assert!(ex.scene.is_sbt_dirty() && !ex.scene.is_layout_dirty() && !ex.scene.is_ias_dirty(ias));
    // Geometry changes: every GAS holding it, the layout and the IASes.
    let g = oxray_util::GeomId(0);
    ex.scene.update_geometry(g, |g| g.user_data = 1).unwrap();
    assert!(ex.scene.is_gas_dirty(ex.gas0) && !ex.scene.is_gas_dirty(ex.gas1));
    assert!(ex.scene.is_layout_dirty() && ex.scene.is_ias_dirty(ias));
    // Adding a GAS dirties the layout.
    ex.scene.build_gas(ex.gas0).unwrap();
    ex.scene.build_ias(ias).unwrap();
    assert!(!ex.scene.is_layout_dirty());
    ex.scene.add_gas(GasDesc::new(vec![g], vec![1]));
    assert!(ex.scene.is_layout_dirty() && ex.scene.is_ias_dirty(ias));
}

#[test]
fn one_gas_serves_two_pipelines_and_instances_pick_their_material_set() {
    // Two materials on one quad: set 0 writes 10 + user data, set 1 writes 20 + user data.
    #[derive(Clone)]
    struct Params<'a> {
        handle: TraversableHandle,
        out: &'a OutputBuffer<u32>,
    }
    // The outputs outlive the scene and pipelines, whose parameter type borrows them.
    let outs = [OutputBuffer::new(2), OutputBuffer::new(2)];
    let module = Module::<Params>::new()
        .raygen("__raygen__rg", |ctx| {
            let [x, _, _] = ctx.launch_index();
            let p = ctx.params();
            let mut payload = [0u32];
            let o = glam::Vec3::new(x as f32 * 10.0, 0.0, -5.0);
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
            ctx.set_payload(0, d.material);
            Ok(())
        })
        .unwrap();
    let hg = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__ch")),
        ..Default::default()
    })
    .unwrap();
    let mut scene: Scene<Params> = Scene::new();
    let a = scene.add_material(Material::new(vec![Some(hg.clone())], 11));
    let b = scene.add_material(Material::new(vec![Some(hg.clone())], 22));
    let g = scene.add_geometry(
        GeometryInstance::new(quad(0.0), 1)
            .material(0, 0, a)
            .material(1, 0, b),
    );
    let gas = scene.add_gas(GasDesc::new(vec![g], vec![1, 1]));
    scene.build_gas(gas).unwrap();
    let mut left = UtilInstance::new(gas, 0);
    let mut right = UtilInstance::new(gas, 1);
    left.transform = oxray::Transform::from_translation(glam::Vec3::ZERO);
    right.transform = oxray::Transform::from_translation(glam::Vec3::new(10.0, 0.0, 0.0));
    let ias = scene.add_ias(vec![left, right], Default::default());
    let handle = scene.build_ias(ias).unwrap();
    let hitgroup = scene.hit_group_records().unwrap();
    scene.check_ready().unwrap();

    let rg = ProgramGroup::raygen(&module, "__raygen__rg").unwrap();
    let ms = ProgramGroup::miss(None).unwrap();
    let mut results = Vec::new();
    for out in &outs {
        let mut groups = vec![rg.clone(), ms.clone()];
        groups.extend(scene.hit_groups());
        let pipeline = Pipeline::new(
            &DeviceContext::new(),
            &PipelineCompileOptions {
                num_payload_values: 1,
                ..Default::default()
            },
            &PipelineLinkOptions { max_trace_depth: 1 },
            &groups,
        )
        .unwrap();
        let sbt = ShaderBindingTable {
            raygen: SbtRegion::from_headers(&[rg.pack_header()]),
            miss: SbtRegion::from_headers(&[ms.pack_header()]),
            hitgroup: hitgroup.clone(),
            ..Default::default()
        };
        let report = pipeline
            .launch(
                &Params {
                    handle: handle.clone(),
                    out,
                },
                &sbt,
                2,
                1,
                1,
            )
            .unwrap();
        assert_eq!(report.exceptions, 0, "{:?}", report.first_exceptions);
        results.push(out.to_vec());
    }
    assert_eq!(results[0], vec![11, 22]);
    assert_eq!(results[0], results[1]);
}
