//! Compaction (guide §5.8) and the emitted compacted size: a compacted GAS or IAS is smaller,
//! exactly its announced size, and gives bit-identical hits; it can still be updated (§5.8:
//! "it is possible to traverse, update, or relocate a compacted acceleration structure").

use glam::Vec3;
use oxray_core::{
    BuildError, BuildFlags, BuildInput, BuildOperation, BuildOptions, IndexBuffer, Instance, Ray,
    Transform, TriangleInput, VertexBuffer,
};
use oxray_cpu::{Gas, Ias};
use oxray_testkit::mesh::{icosphere, load_bunny, Mesh};
use oxray_testkit::oracle::hit_bits;
use oxray_testkit::rays::{camera_rays, hemisphere_rays};
use std::sync::Arc;

fn input(m: &Mesh) -> BuildInput<'_> {
    TriangleInput::new(VertexBuffer::f32x3(&m.positions))
        .indices(IndexBuffer::u32x3(&m.triangles))
        .into()
}

fn rays(m: &Mesh) -> Vec<Ray> {
    let mut r = camera_rays(&m.positions, 48, 48);
    r.extend(hemisphere_rays(&m.positions, &m.triangles, 2000, 5));
    r
}

fn same_hits(a: &Gas, b: &Gas, rays: &[Ray]) {
    for ray in rays {
        assert_eq!(hit_bits(&a.intersect(ray)), hit_bits(&b.intersect(ray)));
        assert_eq!(a.occluded(ray), b.occluded(ray));
    }
}

#[test]
fn compaction_shrinks_to_the_emitted_size_with_identical_hits_5_8() {
    let m = load_bunny("compaction").unwrap_or_else(|| icosphere(5));
    for extra in [BuildFlags::empty(), BuildFlags::ALLOW_UPDATE] {
        let flags = BuildFlags::ALLOW_COMPACTION | BuildFlags::PREFER_FAST_TRACE | extra;
        let gas = Gas::build(&BuildOptions::new(flags), &[input(&m)]).unwrap();
        let size = gas
            .compacted_size()
            .expect("ALLOW_COMPACTION emits the size");
        let before = gas.memory().output_bytes;
        // The CPU build is exact but for the builder's slack, which compaction trims.
        assert!(size <= before, "{size} > {before}");
        let compact = Gas::from(gas.data().compact().unwrap());
        assert_eq!(compact.memory().output_bytes, size);
        assert_eq!(compact.compacted_size(), Some(size));
        assert_eq!(compact.lineage, gas.lineage);
        same_hits(&gas, &compact, &rays(&m));
        // Without the flag a build is exact from the start: as small as a compacted one.
        let plain = Gas::build(
            &BuildOptions::new(flags - BuildFlags::ALLOW_COMPACTION),
            &[input(&m)],
        )
        .unwrap();
        assert_eq!(plain.memory().output_bytes, size);
        assert_eq!(plain.compacted_size(), None);
        println!(
            "{} triangles, {extra:?}: {:.1} B/triangle as built, {:.1} B/triangle compacted",
            m.triangles.len(),
            before as f64 / m.triangles.len() as f64,
            size as f64 / m.triangles.len() as f64
        );
    }
}

#[test]
fn compaction_needs_allow_compaction_5_8() {
    let m = icosphere(1);
    let gas = Gas::build(&BuildOptions::default(), &[input(&m)]).unwrap();
    assert_eq!(
        gas.data().compact().err(),
        Some(BuildError::CompactionNotAllowed)
    );
    assert_eq!(
        BuildError::CompactionNotAllowed.code(),
        oxray_core::ErrorCode::InvalidValue
    );
}

#[test]
fn a_compacted_structure_can_be_updated_like_its_source_5_8() {
    let mut m = icosphere(3);
    let flags = BuildFlags::ALLOW_COMPACTION | BuildFlags::ALLOW_UPDATE;
    let mut gas = Gas::build(&BuildOptions::new(flags), &[input(&m)]).unwrap();
    let mut compact = Gas::from(gas.data().compact().unwrap());
    for p in &mut m.positions {
        *p = (Vec3::from(*p) * Vec3::new(1.5, 0.7, 1.0)).to_array();
    }
    let up = BuildOptions {
        flags,
        operation: BuildOperation::Update,
        ..Default::default()
    };
    gas.update(&up, &[input(&m)]).unwrap();
    compact.update(&up, &[input(&m)]).unwrap();
    assert_eq!(gas.bvh.nodes, compact.bvh.nodes);
    same_hits(&gas, &compact, &rays(&m));
}

#[test]
fn compacted_ias_gives_the_same_hits_5_8() {
    let m = icosphere(2);
    let gas = Arc::new(Gas::build(&BuildOptions::default(), &[input(&m)]).unwrap());
    let list: Vec<Instance> = (0..50)
        .map(|i| {
            Instance::new(gas.clone().into()).transform(Transform::from_translation(Vec3::new(
                i as f32 * 2.5,
                0.0,
                0.0,
            )))
        })
        .collect();
    let ias = Ias::build(
        &BuildOptions::new(BuildFlags::ALLOW_COMPACTION),
        &[(&list[..]).into()],
    )
    .unwrap();
    let size = ias.compacted_size().unwrap();
    let compact = Ias::from_data(ias.data().compact().unwrap()).unwrap();
    assert_eq!(compact.memory_bytes(), size);
    for i in 0..500 {
        let ray = Ray::new(
            Vec3::new(i as f32 * 0.25 - 2.0, 0.3, 5.0),
            Vec3::new(0.01, -0.05, -1.0),
        );
        assert_eq!(
            hit_bits(&ias.intersect(&ray)),
            hit_bits(&compact.intersect(&ray))
        );
    }
}
