//! Saving structures to bytes and loading them back (serialization, beyond guide §5.7's
//! relocation): round trips give bit-identical hits, and thousands of mutations of saved bytes
//! never panic, hang or allocate more than a small multiple of the input. This file holds a
//! single test, so that its allocation counter sees only the loader.

use glam::Vec3;
use oxray_bvh::serialize::{checksum, FORMAT_VERSION};
use oxray_bvh::{GasData, IasData};
use oxray_core::{
    Aabb, AabbBuffer, BuildFlags, BuildInput, BuildOptions, CurveEndcaps, CurveInput, CurveType,
    CustomHit, CustomPrimitive, CustomPrimitiveInput, GeometryFlags, IndexBuffer, Instance,
    LoadError, Ray, SbtIndexOffsets, SphereInput, Transform, TraversableHandle, TriangleInput,
    VertexBuffer,
};
use oxray_cpu::{Gas, Ias};
use oxray_testkit::mesh::icosphere;
use oxray_testkit::oracle::hit_bits;
use oxray_testkit::rng::Rng;
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

/// Records the largest single allocation.
struct Largest;
static LARGEST: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Largest {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        LARGEST.fetch_max(layout.size(), Ordering::Relaxed);
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        LARGEST.fetch_max(new_size, Ordering::Relaxed);
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOC: Largest = Largest;

fn rays(rng: &mut Rng, n: usize, extent: f32) -> Vec<Ray> {
    (0..n)
        .map(|_| {
            let o = rng.unit() * extent * 2.0;
            Ray::new(o, rng.vec3(-extent, extent) * 0.5 - o)
        })
        .collect()
}

fn sphere_in(p: &CustomPrimitive, ray: &Ray) -> Option<CustomHit> {
    let b = p.aabb;
    let c = (b.min + b.max) * 0.5;
    let r = 0.4 * (b.max - b.min).min_element();
    let oc = ray.origin - c;
    let a = ray.direction.length_squared();
    let hb = oc.dot(ray.direction);
    let disc = hb * hb - a * (oc.length_squared() - r * r);
    if disc.is_nan() || disc < 0.0 {
        return None;
    }
    let t = (-hb - disc.sqrt()) / a;
    (t >= ray.tmin && t <= ray.tmax).then_some(CustomHit {
        t,
        hit_kind: 1,
        u: 0.0,
        v: 0.0,
    })
}

fn same_gas_hits(a: &Gas, b: &Gas, rays: &[Ray]) {
    for ray in rays {
        assert_eq!(
            hit_bits(&a.intersect_with(ray, &mut sphere_in)),
            hit_bits(&b.intersect_with(ray, &mut sphere_in))
        );
    }
}

/// One random mutation of `bytes`; with `fix`, the checksum is recomputed so that the
/// structural checks behind it are reached.
fn mutate(rng: &mut Rng, bytes: &[u8], fix: bool) -> Vec<u8> {
    let mut b = bytes.to_vec();
    match rng.below(6) {
        0 => {
            let i = rng.below(b.len());
            b[i] ^= 1 << rng.below(8);
        }
        1 => {
            for _ in 0..1 + rng.below(8) {
                let i = rng.below(b.len());
                b[i] = rng.next_u64() as u8;
            }
        }
        2 => {
            // A 32- or 64-bit field set to an extreme value.
            let i = rng.below(b.len() - 8) & !3;
            let v: u64 = [u64::MAX, u32::MAX as u64, 1 << 31, 0, 1 << 40, 7][rng.below(6)];
            b[i..i + 8].copy_from_slice(&v.to_le_bytes());
        }
        3 => b.truncate(rng.below(b.len())),
        4 => b.extend((0..1 + rng.below(64)).map(|_| rng.next_u64() as u8)),
        _ => {
            // A copy of one stretch over another (a shuffled node or record).
            let n = 4 * (1 + rng.below(32));
            if b.len() > 2 * n {
                let from = rng.below(b.len() - n);
                let to = rng.below(b.len() - n);
                let chunk = b[from..from + n].to_vec();
                b[to..to + n].copy_from_slice(&chunk);
            }
        }
    }
    if fix && b.len() >= 32 {
        let end = b.len();
        let payload_len = (end - 32) as u64;
        b[16..24].copy_from_slice(&payload_len.to_le_bytes());
        let sum = checksum(&b[32..]);
        b[24..32].copy_from_slice(&sum.to_le_bytes());
    }
    b
}

#[test]
fn saved_structures_load_back_with_identical_hits_and_damaged_bytes_are_refused() {
    let mut rng = Rng::new(0x5_7);
    // A triangle GAS of two inputs with SBT index offsets and a primitive index offset,
    // updatable (so that the input shapes are saved too), with degenerate triangles.
    let mut m = icosphere(3);
    m.positions[5] = m.positions[6];
    let half = m.triangles.len() / 2;
    let offsets: Vec<u8> = (0..m.triangles.len()).map(|i| (i % 3) as u8).collect();
    let flags3 = [
        GeometryFlags::empty(),
        GeometryFlags::DISABLE_ANYHIT,
        GeometryFlags::empty(),
    ];
    let inputs: [BuildInput<'_>; 2] = [
        TriangleInput::new(VertexBuffer::f32x3(&m.positions))
            .indices(IndexBuffer::u32x3(&m.triangles[..half]))
            .into(),
        TriangleInput::new(VertexBuffer::f32x3(&m.positions))
            .indices(IndexBuffer::u32x3(&m.triangles[half..]))
            .flags(&flags3)
            .sbt_index_offsets(SbtIndexOffsets::u8(&offsets[half..]))
            .primitive_index_offset(1000)
            .into(),
    ];
    let options = BuildOptions::new(BuildFlags::ALLOW_UPDATE | BuildFlags::ALLOW_COMPACTION);
    let tri = Gas::build(&options, &inputs).unwrap();
    // A custom-primitive GAS.
    let boxes: Vec<Aabb> = (0..300)
        .map(|_| {
            let c = rng.vec3(-1.0, 1.0);
            Aabb::new(c - Vec3::splat(0.05), c + Vec3::splat(0.05))
        })
        .collect();
    let custom = Gas::build(
        &BuildOptions::default(),
        &[CustomPrimitiveInput::new(AabbBuffer::new(&boxes)).into()],
    )
    .unwrap();

    // A sphere GAS (guide §5.3), updatable, with an inactive sphere and SBT index offsets.
    let centres: Vec<[f32; 3]> = (0..300).map(|_| rng.vec3(-1.0, 1.0).to_array()).collect();
    let mut radii: Vec<f32> = (0..300).map(|_| rng.range(0.02, 0.1)).collect();
    radii[7] = 0.0;
    let sphere_offsets: Vec<u8> = (0..300).map(|i| (i % 2) as u8).collect();
    let (sc, sr) = (
        [bytemuck::cast_slice::<_, u8>(&centres)],
        [bytemuck::cast_slice::<_, u8>(&radii)],
    );
    let sphere_inputs: [BuildInput<'_>; 1] = [SphereInput::new(&sc, 300, &sr)
        .flags(&flags3[..2])
        .sbt_index_offsets(SbtIndexOffsets::u8(&sphere_offsets))
        .into()];
    let spheres = Gas::build(&options, &sphere_inputs).unwrap();

    // A curve GAS (guide §5.2), updatable, with flat caps, one strand of three cubic segments
    // per 6 control points, and an inactive segment (negative radii).
    let cpoints: Vec<[f32; 3]> = (0..600).map(|_| rng.vec3(-1.0, 1.0).to_array()).collect();
    let mut cradii: Vec<f32> = (0..600).map(|_| rng.range(0.01, 0.05)).collect();
    cradii[12..16].fill(-0.1);
    let cindex: Vec<u32> = (0..100)
        .flat_map(|s| [6 * s, 6 * s + 1, 6 * s + 2])
        .collect();
    let (cv, cw) = (
        [bytemuck::cast_slice::<_, u8>(&cpoints)],
        [bytemuck::cast_slice::<_, u8>(&cradii)],
    );
    let curve_inputs: [BuildInput<'_>; 1] = [CurveInput::new(
        CurveType::RoundCubicBSpline,
        &cv,
        600,
        &cw,
        bytemuck::cast_slice(&cindex),
        300,
    )
    .endcaps(CurveEndcaps::On)
    .into()];
    let curves = Gas::build(&options, &curve_inputs).unwrap();
    assert_eq!(curves.num_active_primitives(), 299);

    let test_rays = rays(&mut rng, 2000, 1.5);
    for gas in [&tri, &custom, &spheres, &curves] {
        let bytes = gas.data().to_bytes();
        let loaded = Gas::from(GasData::from_bytes(&bytes).unwrap());
        assert_eq!(loaded.bvh.nodes, gas.bvh.nodes);
        assert_eq!(
            loaded.to_bytes(),
            bytes,
            "a loaded structure saves the same bytes"
        );
        assert_ne!(loaded.lineage, gas.lineage);
        same_gas_hits(gas, &loaded, &test_rays);
    }
    // A compacted structure saves and loads too, and the loaded one can still be updated.
    let compact = GasData::from_bytes(&tri.data().compact().unwrap().to_bytes()).unwrap();
    same_gas_hits(&tri, &Gas::from(compact.clone()), &test_rays);
    let mut updated = Gas::from(compact);
    let up = BuildOptions {
        operation: oxray_core::BuildOperation::Update,
        ..options
    };
    updated.update(&up, &inputs).unwrap();

    // An IAS over both, saved without its children and loaded over copies of them.
    let tri = Arc::new(tri);
    let list: Vec<Instance> = (0..40)
        .map(|i| {
            let child: TraversableHandle = if i % 4 == 3 {
                TraversableHandle::NULL
            } else {
                tri.clone().into()
            };
            Instance::new(child)
                .transform(Transform::from_affine(&rng.affine(3.0)))
                .instance_id(i)
                .sbt_offset(i % 5)
        })
        .collect();
    let ias_options = BuildOptions::new(BuildFlags::ALLOW_UPDATE);
    let ias = Ias::build(&ias_options, &[(&list[..]).into()]).unwrap();
    let ias_bytes = ias.data().to_bytes();
    let copy: TraversableHandle = Arc::new(Gas::from(
        GasData::from_bytes(&tri.data().to_bytes()).unwrap(),
    ))
    .into();
    let children: Vec<TraversableHandle> = list
        .iter()
        .map(|inst| {
            if inst.child.is_null() {
                TraversableHandle::NULL
            } else {
                copy.clone()
            }
        })
        .collect();
    let loaded = Ias::from_data(IasData::from_bytes(&ias_bytes, &children).unwrap()).unwrap();
    // The same instances over the given children: what updates a loaded IAS.
    let relisted: Vec<Instance> = list
        .iter()
        .zip(&children)
        .map(|(inst, c)| Instance {
            child: c.clone(),
            ..inst.clone()
        })
        .collect();
    let ias_up = BuildOptions {
        operation: oxray_core::BuildOperation::Update,
        ..ias_options
    };
    let world_rays = rays(&mut rng, 2000, 6.0);
    for ray in &world_rays {
        assert_eq!(
            hit_bits(&ias.intersect(ray)),
            hit_bits(&loaded.intersect(ray))
        );
    }
    assert_eq!(
        IasData::from_bytes(&ias_bytes, &children[1..]).err(),
        Some(LoadError::ChildCount {
            expected: 40,
            given: 39
        })
    );

    // Typed errors for the header.
    let tri_bytes = tri.data().to_bytes();
    assert_eq!(
        GasData::from_bytes(b"nonsense").err(),
        Some(LoadError::BadMagic)
    );
    let mut v = tri_bytes.clone();
    v[8..12].copy_from_slice(&(FORMAT_VERSION + 1).to_le_bytes());
    assert_eq!(
        GasData::from_bytes(&v).err(),
        Some(LoadError::UnsupportedVersion {
            found: FORMAT_VERSION + 1,
            supported: FORMAT_VERSION
        })
    );
    assert!(matches!(
        GasData::from_bytes(&ias_bytes),
        Err(LoadError::WrongKind { .. })
    ));
    let mut v = tri_bytes.clone();
    let last = v.len() - 1;
    v[last] ^= 1;
    assert!(matches!(
        GasData::from_bytes(&v),
        Err(LoadError::Checksum { .. })
    ));

    // The fuzzer: a few thousand mutations of each, half with a repaired checksum. Loading
    // must give an error or a structure that traces without a panic; no single allocation may
    // exceed a few times the input's size.
    let probe = rays(&mut rng, 16, 1.5);
    // OXRAY_FUZZ_ROUNDS runs a longer campaign.
    let rounds: usize = std::env::var("OXRAY_FUZZ_ROUNDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2500);
    let mut accepted = 0;
    for (name, bytes) in [
        ("triangle GAS", &tri_bytes),
        ("custom GAS", &custom.data().to_bytes()),
        ("sphere GAS", &spheres.data().to_bytes()),
        ("curve GAS", &curves.data().to_bytes()),
        ("IAS", &ias_bytes),
    ] {
        for k in 0..rounds {
            let bad = mutate(&mut rng, bytes, k % 2 == 0);
            LARGEST.store(0, Ordering::Relaxed);
            if name == "IAS" {
                if let Ok(data) = IasData::from_bytes(&bad, &children) {
                    assert!(LARGEST.load(Ordering::Relaxed) <= 8 * bad.len() + 4096);
                    accepted += 1;
                    let mut ias = Ias::from_data(data).unwrap();
                    for ray in &probe {
                        let _ = ias.intersect(ray);
                        let _ = ias.occluded(ray);
                    }
                    let _ = ias.update(&ias_up, &[(&relisted[..]).into()]);
                    let _ = ias.intersect(&probe[0]);
                }
            } else {
                let loaded = GasData::from_bytes(&bad);
                assert!(
                    LARGEST.load(Ordering::Relaxed) <= 8 * bad.len() + 4096,
                    "{name}: an allocation of {} bytes for {} bytes of input",
                    LARGEST.load(Ordering::Relaxed),
                    bad.len()
                );
                if let Ok(data) = loaded {
                    accepted += 1;
                    let mut gas = Gas::from(data);
                    let _ = gas.num_active_primitives();
                    for ray in &probe {
                        let _ = gas.intersect_with(ray, &mut sphere_in);
                        let _ = gas.occluded(ray);
                    }
                    // An update of whatever loaded: refused or done, never a panic.
                    let _ = gas.update(&up, &inputs);
                    let _ = gas.update(&up, &sphere_inputs);
                    let _ = gas.update(&up, &curve_inputs);
                    let _ = gas.intersect(&probe[0]);
                }
            }
        }
    }
    // Mutations of floats (boxes, vertices) with a repaired checksum load: they are data.
    assert!(accepted > 0);
    println!(
        "{accepted} of {} mutations loaded (data changes), the rest refused",
        4 * rounds
    );
}
