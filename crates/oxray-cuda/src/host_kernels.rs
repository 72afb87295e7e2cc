//! The trace and simulation kernels' own CUDA C++ (`kernels/trace.cu`, `curve.cu`,
//! `simulation.cu`) compiled by the host's C++ compiler over `kernels/host.h` and run one thread
//! at a time on the CPU, against the CPU backend: so that a machine without a GPU (CI) checks
//! what the kernels compute, bit for bit, and the host code that turns their offers into lists.
//! The driver's launches, device memory and the GPU's own compiler are left to the GPU tests.

use crate::context::compile_options;
use crate::gas::{hit_of, sphere_words, HitRecord};
use crate::layout::{ChildRef, DeviceLayout, IasLayout, NodeLayout, SlotInfo};
use crate::simulation::distinct_lists;
use glam::Vec3;
use oxray_bvh::{Bvh2, GasData, IasData, NO_PRIMITIVE};
use oxray_core::{
    AllHits, BuildFlags, BuildInput, BuildOptions, Hit, IndexBuffer, Instance, InstanceFlags, Ray,
    RayRecord, SphereInput, Transform, TriangleInput, VertexBuffer,
};
use oxray_cpu::Gas;
use oxray_testkit::mesh::{grid_cube, icosphere, random_soup, Mesh};
use oxray_testkit::rays::{points_near, rays_around, rays_at_features};
use oxray_testkit::rng::Rng;
use std::sync::OnceLock;

/// The drivers: each runs one kernel over threads `0 .. n`.
const DRIVERS: &str = r#"
extern "C" void host_offers_triangles(const float4* nodes, const float4* tris, const float4* rays,
                                      u32* counts, const unsigned long long* offsets, uint4* out,
                                      u32 n) {
    HOST_LAUNCH(n, oxray_offers_triangles(nodes, tris, rays, counts, offsets, out, n));
}
extern "C" void host_offers_spheres(const float4* nodes, const float4* spheres, const float4* rays,
                                    u32* counts, const unsigned long long* offsets, uint4* out,
                                    u32 n) {
    HOST_LAUNCH(n, oxray_offers_spheres(nodes, spheres, rays, counts, offsets, out, n));
}
extern "C" void host_offers_ias(const float4* top, const float4* insts, const float4* rays,
                                u32* counts, const unsigned long long* offsets, uint4* out,
                                u32* out_inst, u32 n) {
    HOST_LAUNCH(n, oxray_offers_ias(top, insts, rays, counts, offsets, out, out_inst, n));
}
extern "C" void host_closest_points(const float4* nodes, const float4* tris, const u32* ids,
                                    const float4* points, uint4* out, float extent, u32 n) {
    HOST_LAUNCH(n, oxray_closest_points(nodes, tris, ids, points, out, extent, n));
}
extern "C" void host_gather_records(const unsigned long long* addrs, const u32* words, u32* out,
                                    u32 n) {
    HOST_LAUNCH(n, oxray_gather_records(addrs, words, out, n));
}
extern "C" void host_closest_bvh2(const float4* nodes, const float4* tris, const float4* rays,
                                  uint4* hits, u32 n) {
    HOST_LAUNCH(n, oxray_closest_bvh2(nodes, tris, rays, hits, n));
}
extern "C" void host_occluded_bvh2(const float4* nodes, const float4* tris, const float4* rays,
                                   unsigned char* occluded, u32 n) {
    HOST_LAUNCH(n, oxray_occluded_bvh2(nodes, tris, rays, occluded, n));
}
extern "C" void host_closest_bvh4(const float4* nodes, const float4* tris, const float4* rays,
                                  uint4* hits, u32 n) {
    HOST_LAUNCH(n, oxray_closest_bvh4(nodes, tris, rays, hits, n));
}
extern "C" void host_occluded_bvh4(const float4* nodes, const float4* tris, const float4* rays,
                                   unsigned char* occluded, u32 n) {
    HOST_LAUNCH(n, oxray_occluded_bvh4(nodes, tris, rays, occluded, n));
}
extern "C" void host_closest_ias(const float4* top, const float4* insts, const float4* rays,
                                 uint4* hits, u32* inst_out, u32 n) {
    HOST_LAUNCH(n, oxray_closest_ias(top, insts, rays, hits, inst_out, n));
}
extern "C" void host_occluded_ias(const float4* top, const float4* insts, const float4* rays,
                                  unsigned char* occluded, u32 n) {
    HOST_LAUNCH(n, oxray_occluded_ias(top, insts, rays, occluded, n));
}
extern "C" void host_closest_spheres(const float4* nodes, const float4* spheres,
                                     const float4* rays, uint4* hits, u32 n) {
    HOST_LAUNCH(n, oxray_closest_spheres(nodes, spheres, rays, hits, n));
}
extern "C" void host_instance_closest_points(const float4* top, const float4* insts,
                                            const float4* extras, const float4* points,
                                            uint4* out, float extent, u32 n) {
    HOST_LAUNCH(n, oxray_instance_closest_points(top, insts, extras, points, out, extent, n));
}
extern "C" void host_signed_distances(const float4* nodes, const float4* tris, const u32* ids,
                                      const float4* points, float* out, float extent, u32 n) {
    HOST_LAUNCH(n, oxray_signed_distances(nodes, tris, ids, points, out, extent, n));
}
"#;

type Offers =
    unsafe extern "C" fn(*const u32, *const u32, *const u32, *mut u32, *const u64, *mut u32, u32);
type OffersIas = unsafe extern "C" fn(
    *const u32,
    *const u32,
    *const u32,
    *mut u32,
    *const u64,
    *mut u32,
    *mut u32,
    u32,
);
type Closest = unsafe extern "C" fn(*const u32, *const u32, *const u32, *mut u32, u32);
type Occluded = unsafe extern "C" fn(*const u32, *const u32, *const u32, *mut u8, u32);
type ClosestIas = unsafe extern "C" fn(*const u32, *const u32, *const u32, *mut u32, *mut u32, u32);
type InstancePoints =
    unsafe extern "C" fn(*const u32, *const u32, *const u32, *const f32, *mut u32, f32, u32);
type Gather = unsafe extern "C" fn(*const u64, *const u32, *mut u32, u32);
type Points<T> =
    unsafe extern "C" fn(*const u32, *const u32, *const u32, *const f32, *mut T, f32, u32);

/// The kernels compiled for the host, loaded once.
struct HostKernels {
    _lib: libloading::Library,
    offers_triangles: Offers,
    offers_spheres: Offers,
    offers_ias: OffersIas,
    closest_points: Points<u32>,
    signed_distances: Points<f32>,
    gather_records: Gather,
    closest_bvh2: Closest,
    occluded_bvh2: Occluded,
    closest_bvh4: Closest,
    occluded_bvh4: Occluded,
    closest_ias: ClosestIas,
    occluded_ias: Occluded,
    closest_spheres: Closest,
    instance_closest_points: InstancePoints,
}

fn kernels() -> &'static HostKernels {
    static K: OnceLock<HostKernels> = OnceLock::new();
    K.get_or_init(|| {
        let dir = std::env::temp_dir().join(format!("oxray-host-kernels-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let src = dir.join("kernels.cpp");
        let lib = dir.join("kernels.so");
        let source = format!(
            "{}\n{}\n{}",
            include_str!("kernels/host.h"),
            crate::simulation::SIMULATION_SOURCE,
            DRIVERS
        );
        std::fs::write(&src, source).unwrap();
        let cxx = std::env::var("CXX").unwrap_or_else(|_| "c++".into());
        // The kernels' defines (their numeric contract), without the NVRTC-only options; the
        // query kernels' entry points are compiled too.
        let defines: Vec<String> = compile_options((9, 0))
            .into_iter()
            .filter(|o| o.starts_with("-D"))
            .collect();
        let out = std::process::Command::new(&cxx)
            .args(["-std=c++17", "-O2", "-fPIC", "-shared", "-ffp-contract=off"])
            .args(&defines)
            .arg("-o")
            .arg(&lib)
            .arg(&src)
            .output()
            .unwrap_or_else(|e| panic!("the C++ compiler {cxx} cannot run: {e}"));
        assert!(
            out.status.success(),
            "the kernels do not compile for the host:\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        // SAFETY: a library this test just compiled from the kernels and the drivers above; its
        // initialisers only set the host.h globals.
        let lib = unsafe { libloading::Library::new(&lib) }.unwrap();
        // SAFETY: each symbol is one of the drivers above, with the signature of its type; the
        // library stays loaded with the functions (`_lib`).
        unsafe {
            let offers_triangles = *lib.get::<Offers>(b"host_offers_triangles").unwrap();
            let offers_spheres = *lib.get::<Offers>(b"host_offers_spheres").unwrap();
            let offers_ias = *lib.get::<OffersIas>(b"host_offers_ias").unwrap();
            let closest_points = *lib.get::<Points<u32>>(b"host_closest_points").unwrap();
            let signed_distances = *lib.get::<Points<f32>>(b"host_signed_distances").unwrap();
            let gather_records = *lib.get::<Gather>(b"host_gather_records").unwrap();
            let closest_bvh2 = *lib.get::<Closest>(b"host_closest_bvh2").unwrap();
            let occluded_bvh2 = *lib.get::<Occluded>(b"host_occluded_bvh2").unwrap();
            let closest_bvh4 = *lib.get::<Closest>(b"host_closest_bvh4").unwrap();
            let occluded_bvh4 = *lib.get::<Occluded>(b"host_occluded_bvh4").unwrap();
            let closest_ias = *lib.get::<ClosestIas>(b"host_closest_ias").unwrap();
            let occluded_ias = *lib.get::<Occluded>(b"host_occluded_ias").unwrap();
            let closest_spheres = *lib.get::<Closest>(b"host_closest_spheres").unwrap();
            let instance_closest_points = *lib
                .get::<InstancePoints>(b"host_instance_closest_points")
                .unwrap();
            let _ = std::fs::remove_dir_all(&dir);
            HostKernels {
                _lib: lib,
                offers_triangles,
                offers_spheres,
                offers_ias,
                closest_points,
                signed_distances,
                gather_records,
                closest_bvh2,
                occluded_bvh2,
                closest_bvh4,
                occluded_bvh4,
                closest_ias,
                occluded_ias,
                closest_spheres,
                instance_closest_points,
            }
        }
    })
}

/// Rays as the kernels read them.
fn ray_words(rays: &[Ray]) -> Vec<u32> {
    let records: Vec<RayRecord> = rays.iter().map(|&r| RayRecord::from(r)).collect();
    bytemuck::cast_slice(&records).to_vec()
}

/// The count pass and the write pass of an offer kernel, as `trace_offers` runs them (one part):
/// each ray's count, its offers and their instance slots.
fn offers(
    run: impl Fn(*const u32, *mut u32, *const u64, *mut u32, *mut u32, u32),
    rays: &[Ray],
) -> (Vec<u32>, Vec<HitRecord>, Vec<u32>) {
    let words = ray_words(rays);
    let n = rays.len() as u32;
    let mut counts = vec![u32::MAX; rays.len()];
    run(
        words.as_ptr(),
        counts.as_mut_ptr(),
        std::ptr::null(),
        std::ptr::null_mut(),
        std::ptr::null_mut(),
        n,
    );
    let mut offsets = Vec::with_capacity(rays.len());
    let mut at = 0u64;
    for &c in &counts {
        offsets.push(at);
        at += u64::from(c);
    }
    let total = at as usize;
    let mut out = vec![0u32; 4 * total.max(1)];
    let mut insts = vec![u32::MAX; total.max(1)];
    let mut unused = vec![0u32; rays.len()];
    run(
        words.as_ptr(),
        unused.as_mut_ptr(),
        offsets.as_ptr(),
        out.as_mut_ptr(),
        insts.as_mut_ptr(),
        n,
    );
    let records = bytemuck::cast_slice::<u32, HitRecord>(&out[..4 * total]).to_vec();
    insts.truncate(total);
    (counts, records, insts)
}

/// The lists the host makes from offers, as `all_hits` does with no bound.
fn lists(
    resolve: impl Fn(&HitRecord, u32) -> Option<Hit> + Sync,
    counts: &[u32],
    records: &[HitRecord],
    insts: &[u32],
) -> AllHits {
    let mut out = AllHits::new();
    out.append_parts(distinct_lists(resolve, counts, records, insts, usize::MAX));
    out
}

fn mesh_input(mesh: &Mesh) -> BuildInput<'_> {
    TriangleInput::new(VertexBuffer::f32x3(&mesh.positions))
        .indices(IndexBuffer::u32x3(&mesh.triangles))
        .into()
}

/// A triangle GAS built on the host, in the CPU backend and in the device's binary layout.
fn triangle_gas(mesh: &Mesh, flags: BuildFlags) -> (Gas, DeviceLayout) {
    let (data, tree): (GasData, Bvh2) =
        GasData::build_with_tree(&BuildOptions::new(flags), &[mesh_input(mesh)]).unwrap();
    let layout =
        DeviceLayout::new(&data.export_triangles().unwrap(), &tree, NodeLayout::Bvh2).unwrap();
    (Gas::from(data), layout)
}

fn test_meshes() -> Vec<(&'static str, Mesh)> {
    let mut rng = Rng::new(0x51a1);
    let soup = random_soup(&mut rng, 60, 4.0, 2.5);
    vec![
        ("icosphere", icosphere(2)),
        ("grid cube", grid_cube(4)),
        (
            "soup",
            Mesh {
                positions: soup.iter().flatten().copied().collect(),
                triangles: (0..soup.len() as u32)
                    .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
                    .collect(),
            },
        ),
    ]
}

/// Rays around the mesh and rays through its vertices and edge midpoints.
fn test_rays(mesh: &Mesh, seed: u64) -> Vec<Ray> {
    let mut rng = Rng::new(seed);
    let mut rays = rays_around(&mut rng, mesh, 300);
    rays.extend(rays_at_features(&mut rng, mesh, 100));
    // An invalid ray has no offer.
    rays.push(Ray::new(Vec3::NAN, Vec3::Z));
    rays
}

#[test]
fn offers_make_the_cpus_lists_and_counts() {
    let k = kernels();
    for (name, mesh) in test_meshes() {
        let rays = test_rays(&mesh, 3);
        for flags in [BuildFlags::empty(), BuildFlags::PREFER_FAST_TRACE] {
            let (gas, layout) = triangle_gas(&mesh, flags);
            let (counts, records, insts) = offers(
                |r, c, o, out, _, n| {
                    // SAFETY: the layout's nodes and triangles, `n` rays of 8 words, `n` counts,
                    // and in the write pass offsets with room for every offer (the counts').
                    unsafe {
                        (k.offers_triangles)(
                            layout.nodes.as_ptr(),
                            layout.triangles.as_ptr().cast(),
                            r,
                            c,
                            o,
                            out,
                            n,
                        )
                    }
                },
                &rays,
            );
            let got = lists(
                |r, _| {
                    let s = layout.slots.get(r.slot_index() as usize)?;
                    Some(hit_of(r, s, false, !0, 0))
                },
                &counts,
                &records,
                &insts,
            );
            let mut want = AllHits::new();
            gas.all_hits_batch(&rays[..rays.len() - 1], usize::MAX, &mut want)
                .unwrap();
            want.push_ray(&[], true);
            assert_eq!(got, want, "{name}, {flags:?}");
            let mut want_counts = vec![0u32; rays.len() - 1];
            gas.count_hits_batch(&rays[..rays.len() - 1], &mut want_counts)
                .unwrap();
            let repeats = records.len() > want.all().len();
            if flags.is_empty() {
                // No primitive has two leaves: the count pass is the count.
                assert!(!repeats, "{name}");
                assert_eq!(counts[..rays.len() - 1], want_counts[..], "{name}");
            }
            assert_eq!(counts[rays.len() - 1], 0, "{name}: the invalid ray");
        }
    }
}

/// A sphere GAS built on the host, in the CPU backend and in the device's binary layout.
struct Spheres {
    gas: Gas,
    /// The tree's binary nodes.
    nodes: Vec<u32>,
    /// One float4 per sphere slot.
    words: Vec<u32>,
    slots: Vec<SlotInfo>,
}

impl Spheres {
    /// The hit a record on one of the GAS's slots reports.
    fn hit(&self, r: &HitRecord) -> Option<Hit> {
        let s = self.slots.get(r.slot_index() as usize)?;
        let mut h = hit_of(r, s, false, !0, 0);
        h.hit_kind = oxray_core::HitKind::SPHERE_FRONT_FACE;
        Some(h)
    }
}

/// `n` spheres with centres in [-3, 3]^3 and radii in `radii`, and `rays` rays around them.
fn random_spheres(rng: &mut Rng, n: usize, radii: (f32, f32), rays: usize) -> (Spheres, Vec<Ray>) {
    let centres: Vec<[f32; 3]> = (0..n).map(|_| rng.vec3(-3.0, 3.0).to_array()).collect();
    let radii: Vec<f32> = (0..n).map(|_| rng.range(radii.0, radii.1)).collect();
    let (c, r) = (
        [bytemuck::cast_slice::<_, u8>(&centres)],
        [bytemuck::cast_slice::<_, u8>(&radii)],
    );
    let input: BuildInput<'_> = SphereInput::new(&c, n as u32, &r).into();
    let (data, tree) = GasData::build_with_tree(&BuildOptions::default(), &[input]).unwrap();
    let nodes = crate::layout::bvh2_words(&tree).unwrap();
    let (words, slots) = sphere_words(&data);
    let scene = Mesh {
        positions: vec![[-3.0; 3], [3.0; 3]],
        triangles: vec![],
    };
    let rays = rays_around(rng, &scene, rays);
    let spheres = Spheres {
        gas: Gas::from(data),
        nodes,
        words,
        slots,
    };
    (spheres, rays)
}

#[test]
fn sphere_offers_make_the_cpus_lists() {
    let k = kernels();
    let mut rng = Rng::new(5);
    let (s, rays) = random_spheres(&mut rng, 50, (0.2, 0.9), 400);
    let (counts, records, insts) = offers(
        |r, c, o, out, _, n| {
            // SAFETY: the tree's binary nodes and one float4 per sphere slot, as above.
            unsafe { (k.offers_spheres)(s.nodes.as_ptr(), s.words.as_ptr(), r, c, o, out, n) }
        },
        &rays,
    );
    let gas = &s.gas;
    let got = lists(|r, _| s.hit(r), &counts, &records, &insts);
    let mut want = AllHits::new();
    gas.all_hits_batch(&rays, usize::MAX, &mut want).unwrap();
    assert_eq!(got, want);
    assert!(want.all().len() > rays.len());
}

/// One level of `instances` over host-laid-out triangle GASes, the child of the instance of
/// index `i` being `layouts[child_of(i)]`: the IAS data (in slot order) and the kernels' layout
/// of it, the children's host addresses standing for the device's.
fn instance_layout(
    instances: &[Instance],
    layouts: &[&DeviceLayout],
    child_of: impl Fn(u32) -> usize,
) -> (IasData, IasLayout) {
    let (data, tree): (IasData, Bvh2) =
        IasData::build_with_tree(&BuildOptions::default(), &[instances.into()]).unwrap();
    let refs: Vec<Option<ChildRef>> = data
        .instances
        .iter()
        .enumerate()
        .map(|(slot, inst)| {
            let l = layouts[child_of(inst.index)];
            Some(ChildRef {
                index: slot as u32,
                nodes_addr: l.nodes.as_ptr() as u64,
                triangles_addr: l.triangles.as_ptr() as u64,
            })
        })
        .collect();
    let layout = IasLayout::new(&data, &tree, &refs).unwrap();
    (data, layout)
}

#[test]
fn instance_offers_make_the_cpus_lists() {
    let k = kernels();
    let children = [
        triangle_gas(&icosphere(2), BuildFlags::PREFER_FAST_TRACE),
        triangle_gas(&grid_cube(3), BuildFlags::empty()),
    ];
    let placements = [
        Transform::IDENTITY,
        Transform::from_translation(Vec3::new(2.5, 0.0, 0.0)),
        Transform::from_affine(&glam::Affine3A::from_scale_rotation_translation(
            Vec3::new(1.0, 2.0, 0.5),
            glam::Quat::from_rotation_y(0.7),
            Vec3::new(-2.0, 1.0, 0.5),
        )),
        Transform::from_affine(&glam::Affine3A::from_scale(Vec3::new(-1.0, 1.0, 1.0))),
    ];
    let cpu_children: Vec<std::sync::Arc<Gas>> = children
        .iter()
        .map(|(g, _)| std::sync::Arc::new(g.clone()))
        .collect();
    let instances: Vec<Instance> = placements
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let mut inst = Instance::new(cpu_children[i % 2].clone().into())
                .transform(*t)
                .instance_id(100 + i as u32);
            if i == 2 {
                inst = inst.flags(InstanceFlags::FLIP_TRIANGLE_FACING);
            }
            inst
        })
        .collect();
    let (data, layout) = instance_layout(&instances, &[&children[0].1, &children[1].1], |i| {
        i as usize % 2
    });
    let scene = Mesh {
        positions: vec![[-4.0, -3.0, -3.0], [5.0, 4.0, 3.0]],
        triangles: vec![],
    };
    let rays = rays_around(&mut Rng::new(11), &scene, 500);
    let (counts, records, insts) = offers(
        |r, c, o, out, oi, n| {
            // SAFETY: the top-level nodes and instance slots, whose child addresses are the
            // children's layouts above (alive for the call), as the device's.
            unsafe {
                (k.offers_ias)(
                    layout.nodes.as_ptr(),
                    layout.instances.as_ptr(),
                    r,
                    c,
                    o,
                    out,
                    oi,
                    n,
                )
            }
        },
        &rays,
    );
    let got = lists(
        |r, slot| {
            let inst = data.instances.get(slot as usize)?;
            let child = &children[inst.index as usize % 2].1;
            let s = child.slots.get(r.slot_index() as usize)?;
            let flip = inst.flags.contains(InstanceFlags::FLIP_TRIANGLE_FACING);
            Some(hit_of(r, s, flip, inst.instance_id, inst.index))
        },
        &counts,
        &records,
        &insts,
    );
    let cpu = oxray_cpu::Ias::from_data(data.clone()).unwrap();
    let mut want = AllHits::new();
    cpu.all_hits_batch(&rays, usize::MAX, &mut want).unwrap();
    assert_eq!(got, want);
    let hit: std::collections::HashSet<u32> = want.all().iter().map(|h| h.instance_index).collect();
    assert_eq!(hit.len(), placements.len(), "every instance is crossed");
}

#[test]
fn point_kernels_find_the_cpus_closest_points_and_signs() {
    let k = kernels();
    for (name, mesh) in test_meshes() {
        let points = points_near(&mut Rng::new(4), &mesh, 300, 100);
        let words: Vec<f32> = points
            .iter()
            .flat_map(|p| [p.x, p.y, p.z, f32::INFINITY])
            .collect();
        for flags in [BuildFlags::empty(), BuildFlags::PREFER_FAST_TRACE] {
            let (gas, layout) = triangle_gas(&mesh, flags);
            // One input: a slot's global id is its primitive index.
            let ids: Vec<u32> = layout
                .slots
                .iter()
                .map(|s| {
                    if s.primitive_index == u32::MAX {
                        NO_PRIMITIVE
                    } else {
                        s.primitive_index
                    }
                })
                .collect();
            let b = gas.data().bounds;
            let extent = b.min.abs().max(b.max.abs()).max_element();
            let n = points.len() as u32;
            let mut out = vec![0u32; 8 * points.len()];
            let mut sd = vec![0.0f32; points.len()];
            // SAFETY: the layout's nodes and triangles, an id per slot, `n` points of 4 floats
            // and 8 words (closest points) or one float (signed distances) per point.
            unsafe {
                (k.closest_points)(
                    layout.nodes.as_ptr(),
                    layout.triangles.as_ptr().cast(),
                    ids.as_ptr(),
                    words.as_ptr(),
                    out.as_mut_ptr(),
                    extent,
                    n,
                );
                (k.signed_distances)(
                    layout.nodes.as_ptr(),
                    layout.triangles.as_ptr().cast(),
                    ids.as_ptr(),
                    words.as_ptr(),
                    sd.as_mut_ptr(),
                    extent,
                    n,
                );
            }
            for (i, p) in points.iter().enumerate() {
                let at = format!("{name}, {flags:?}, point {i} {p}");
                let want = gas.closest_point(*p).unwrap().unwrap();
                let w = &out[8 * i..8 * i + 8];
                let slot = layout.slots[w[6] as usize];
                assert_eq!(
                    (
                        Vec3::new(
                            f32::from_bits(w[0]),
                            f32::from_bits(w[1]),
                            f32::from_bits(w[2])
                        ),
                        f32::from_bits(w[3]).sqrt(),
                        slot.primitive_index,
                        f32::from_bits(w[4]),
                        f32::from_bits(w[5]),
                    ),
                    (
                        want.point,
                        want.distance,
                        want.primitive_index,
                        want.u,
                        want.v
                    ),
                    "{at}"
                );
                assert_eq!(
                    sd[i].to_bits(),
                    gas.signed_distance(*p).unwrap().to_bits(),
                    "{at}: signed distance"
                );
            }
        }
    }
}

#[test]
fn the_gather_reads_each_record_at_its_address_up_to_its_size() {
    let k = kernels();
    let triangles: Vec<u32> = (0..120).collect();
    let spheres: Vec<u32> = (1000..1040).collect();
    let addrs = [
        triangles.as_ptr() as u64 + 4 * 12 * 3,
        spheres.as_ptr() as u64 + 4 * 4 * 9,
        triangles.as_ptr() as u64,
    ];
    let words = [12u32, 4, 12];
    let mut out = vec![u32::MAX; 12 * addrs.len()];
    // SAFETY: each address starts a record of its size within `triangles` or `spheres` (slot 3
    // of ten 12-word slots, slot 9 of ten 4-word slots, slot 0), and 12 output words each.
    unsafe { (k.gather_records)(addrs.as_ptr(), words.as_ptr(), out.as_mut_ptr(), 3) };
    assert_eq!(out[..12], triangles[36..48]);
    assert_eq!(out[12..16], spheres[36..40]);
    assert!(
        out[16..24].iter().all(|&w| w == u32::MAX),
        "a sphere's record is 4 words"
    );
    assert_eq!(out[24..], triangles[..12]);
}

/// Closest-hit records and occlusion bytes of a query kernel pair over `rays`.
fn trace_records(
    closest: impl Fn(*const u32, *mut u32, u32),
    occluded: impl Fn(*const u32, *mut u8, u32),
    rays: &[Ray],
) -> (Vec<HitRecord>, Vec<bool>) {
    let words = ray_words(rays);
    let n = rays.len() as u32;
    let mut hits = vec![0u32; 4 * rays.len()];
    let mut occ = vec![7u8; rays.len()];
    closest(words.as_ptr(), hits.as_mut_ptr(), n);
    occluded(words.as_ptr(), occ.as_mut_ptr(), n);
    (
        bytemuck::cast_slice::<u32, HitRecord>(&hits).to_vec(),
        occ.iter().map(|&o| o == 1).collect(),
    )
}

/// Compares the kernels' hits (resolved) with the CPU's: distances, barycentrics and facing bit
/// for bit; with `exact` the primitive too, else a different primitive only at the same
/// distance (a tie that another tree breaks otherwise: rays aimed at shared vertices and
/// edges), in at most a quarter of the rays.
fn compare_hits(got: &[Option<Hit>], want: &[Option<Hit>], occ: &[bool], at: &str, exact: bool) {
    let mut ties = 0;
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert_eq!(occ[i], w.is_some(), "{at}: occlusion of ray {i}");
        match (g, w) {
            (None, None) => {}
            (Some(g), Some(w))
                if g.t == w.t && !exact && g.primitive_index != w.primitive_index =>
            {
                ties += 1;
            }
            (g, w) => assert_eq!(g, w, "{at}: ray {i}"),
        }
    }
    assert!(ties * 4 <= got.len(), "{at}: {ties} ties");
}

#[test]
fn query_kernels_trace_the_cpus_hits_in_both_layouts() {
    let k = kernels();
    for (name, mesh) in test_meshes() {
        let mut rays = test_rays(&mesh, 8);
        // Bounded and shortened rays: the interval's rules.
        let mut rng = Rng::new(81);
        for r in rays.iter_mut().step_by(5) {
            r.tmin = rng.range(0.0, 1.0);
        }
        for flags in [BuildFlags::empty(), BuildFlags::PREFER_FAST_TRACE] {
            let (gas, _) = triangle_gas(&mesh, flags);
            let (data, tree) =
                GasData::build_with_tree(&BuildOptions::new(flags), &[mesh_input(&mesh)]).unwrap();
            let export = data.export_triangles().unwrap();
            let mut want = vec![None; rays.len()];
            gas.intersect_batch(&rays, &mut want).unwrap();
            for layout in [NodeLayout::Bvh2, NodeLayout::Bvh4] {
                let dl = DeviceLayout::new(&export, &tree, layout).unwrap();
                let (nodes, tris) = (dl.nodes.as_ptr(), dl.triangles.as_ptr().cast::<u32>());
                let (closest, occluded) = match layout {
                    NodeLayout::Bvh2 => (k.closest_bvh2, k.occluded_bvh2),
                    NodeLayout::Bvh4 => (k.closest_bvh4, k.occluded_bvh4),
                };
                let (records, occ) = trace_records(
                    // SAFETY: the layout's nodes and triangles, `n` rays of 8 words and 4
                    // words (or one byte) of results per ray.
                    |r, h, n| unsafe { closest(nodes, tris, r, h, n) },
                    |r, o, n| unsafe { occluded(nodes, tris, r, o, n) },
                    &rays,
                );
                let got: Vec<Option<Hit>> = records
                    .iter()
                    .map(|r| {
                        r.is_hit()
                            .then(|| hit_of(r, &dl.slots[r.slot_index() as usize], false, !0, 0))
                    })
                    .collect();
                let at = format!("{name}, {flags:?}, {layout:?}");
                compare_hits(&got, &want, &occ, &at, layout == NodeLayout::Bvh4);
            }
        }
    }
}

#[test]
fn instance_and_sphere_query_kernels_trace_the_cpus_hits() {
    let k = kernels();
    // One level of instances, with the placements of the offer test.
    let children = [
        triangle_gas(&icosphere(2), BuildFlags::empty()),
        triangle_gas(&grid_cube(3), BuildFlags::empty()),
    ];
    let cpu_children: Vec<std::sync::Arc<Gas>> = children
        .iter()
        .map(|(g, _)| std::sync::Arc::new(g.clone()))
        .collect();
    let instances: Vec<Instance> = (0..6)
        .map(|i| {
            let t = Transform::from_affine(&glam::Affine3A::from_scale_rotation_translation(
                Vec3::splat(0.5 + 0.2 * i as f32),
                glam::Quat::from_rotation_y(0.5 * i as f32),
                Vec3::new(2.0 * i as f32 - 5.0, 0.3 * i as f32, 0.0),
            ));
            let inst = Instance::new(cpu_children[i % 2].clone().into())
                .transform(t)
                .instance_id(10 + i as u32);
            if i == 3 {
                inst.flags(InstanceFlags::FLIP_TRIANGLE_FACING)
            } else {
                inst
            }
        })
        .collect();
    let (data, layout) = instance_layout(&instances, &[&children[0].1, &children[1].1], |i| {
        i as usize % 2
    });
    let scene = Mesh {
        positions: vec![[-7.0, -2.0, -2.0], [7.0, 3.0, 2.0]],
        triangles: vec![],
    };
    let rays = rays_around(&mut Rng::new(12), &scene, 600);
    let words = ray_words(&rays);
    let n = rays.len() as u32;
    let mut hits = vec![0u32; 4 * rays.len()];
    let mut slots = vec![0u32; rays.len()];
    let mut occ = vec![7u8; rays.len()];
    // SAFETY: the top-level nodes and instance slots (child addresses of the layouts above,
    // alive for the calls), `n` rays and their results.
    unsafe {
        (k.closest_ias)(
            layout.nodes.as_ptr(),
            layout.instances.as_ptr(),
            words.as_ptr(),
            hits.as_mut_ptr(),
            slots.as_mut_ptr(),
            n,
        );
        (k.occluded_ias)(
            layout.nodes.as_ptr(),
            layout.instances.as_ptr(),
            words.as_ptr(),
            occ.as_mut_ptr(),
            n,
        );
    }
    let records = bytemuck::cast_slice::<u32, HitRecord>(&hits);
    let got: Vec<Option<Hit>> = records
        .iter()
        .zip(&slots)
        .map(|(r, &slot)| {
            r.is_hit().then(|| {
                let inst = &data.instances[slot as usize];
                let child = &children[inst.index as usize % 2].1;
                let flip = inst.flags.contains(InstanceFlags::FLIP_TRIANGLE_FACING);
                hit_of(
                    r,
                    &child.slots[r.slot_index() as usize],
                    flip,
                    inst.instance_id,
                    inst.index,
                )
            })
        })
        .collect();
    let cpu = oxray_cpu::Ias::from_data(data.clone()).unwrap();
    let mut want = vec![None; rays.len()];
    cpu.intersect_batch(&rays, &mut want).unwrap();
    let occ: Vec<bool> = occ.iter().map(|&o| o == 1).collect();
    compare_hits(&got, &want, &occ, "instances", false);
    assert!(want.iter().flatten().count() > 100, "the instances are hit");

    // Spheres.
    let mut rng = Rng::new(6);
    let (s, rays) = random_spheres(&mut rng, 80, (0.1, 0.6), 500);
    let words = ray_words(&rays);
    let mut hits = vec![0u32; 4 * rays.len()];
    // SAFETY: the binary nodes and one float4 per sphere slot, `n` rays and 4 words each.
    unsafe {
        (k.closest_spheres)(
            s.nodes.as_ptr(),
            s.words.as_ptr(),
            words.as_ptr(),
            hits.as_mut_ptr(),
            rays.len() as u32,
        )
    };
    let got: Vec<Option<Hit>> = bytemuck::cast_slice::<u32, HitRecord>(&hits)
        .iter()
        .map(|r| r.is_hit().then(|| s.hit(r)).flatten())
        .collect();
    let mut want = vec![None; rays.len()];
    s.gas.intersect_batch(&rays, &mut want).unwrap();
    let occ: Vec<bool> = want.iter().map(Option::is_some).collect();
    compare_hits(&got, &want, &occ, "spheres", true);
}

#[test]
fn the_instance_closest_point_kernel_finds_the_cpus_points_and_instances() {
    let k = kernels();
    let children = [
        triangle_gas(&icosphere(2), BuildFlags::empty()),
        triangle_gas(&grid_cube(3), BuildFlags::PREFER_FAST_TRACE),
    ];
    let cpu_children: Vec<std::sync::Arc<Gas>> = children
        .iter()
        .map(|(g, _)| std::sync::Arc::new(g.clone()))
        .collect();
    // Similarities: translations, rotations, uniform scales, a mirror; and three copies of one
    // placement (ties between instances: the lower slot wins).
    let mut placements: Vec<Transform> = (0..8)
        .map(|i| {
            Transform::from_affine(&glam::Affine3A::from_scale_rotation_translation(
                Vec3::splat(0.5 + 0.25 * i as f32),
                glam::Quat::from_rotation_y(0.4 * i as f32) * glam::Quat::from_rotation_x(0.3),
                Vec3::new(3.0 * i as f32 - 10.0, (i % 3) as f32, 0.5 * i as f32),
            ))
        })
        .collect();
    placements.push(Transform::from_affine(&glam::Affine3A::from_scale(
        Vec3::new(-1.0, 1.0, 1.0),
    )));
    placements.extend([Transform::from_translation(Vec3::new(0.0, 5.0, 0.0)); 3]);
    // The instance of index `i`'s child: the last three are copies of the sphere.
    let child_of = |i: u32| if i >= 9 { 0 } else { i as usize % 2 };
    let instances: Vec<Instance> = placements
        .iter()
        .enumerate()
        .map(|(i, t)| {
            Instance::new(cpu_children[child_of(i as u32)].clone().into())
                .transform(*t)
                .instance_id(50 + i as u32)
        })
        .collect();
    let (data, layout) = instance_layout(&instances, &[&children[0].1, &children[1].1], child_of);
    // Slot ids (one input each: the primitive index) and the extras, as the host makes them.
    let ids: Vec<Vec<u32>> = children
        .iter()
        .map(|(_, l)| {
            l.slots
                .iter()
                .map(|s| {
                    if s.primitive_index == u32::MAX {
                        NO_PRIMITIVE
                    } else {
                        s.primitive_index
                    }
                })
                .collect()
        })
        .collect();
    let mut extras = vec![0u32; 16 * data.instances.len()];
    for (slot, inst) in data.instances.iter().enumerate() {
        let c = child_of(inst.index);
        let b = children[c].0.data().bounds;
        let e = &mut extras[16 * slot..16 * slot + 16];
        for (k, f) in inst.object_to_world.0.iter().enumerate() {
            e[k] = f.to_bits();
        }
        let addr = ids[c].as_ptr() as u64;
        e[12] = addr as u32;
        e[13] = (addr >> 32) as u32;
        e[14] = inst.object_to_world.similarity_scale().unwrap().to_bits();
        e[15] = b.min.abs().max(b.max.abs()).max_element().to_bits();
    }
    let cpu = oxray_cpu::Ias::from_data(data.clone()).unwrap();
    let mut rng = Rng::new(31);
    let mut points: Vec<Vec3> = (0..400).map(|_| rng.vec3(-12.0, 12.0)).collect();
    // Points equally far from the three copies, and on their surface.
    points.extend([
        Vec3::new(0.0, 5.0, 0.0),
        Vec3::new(0.0, 6.0, 0.0),
        Vec3::new(0.3, 7.5, -0.2),
    ]);
    let words: Vec<f32> = points.iter().flat_map(|p| [p.x, p.y, p.z, 0.0]).collect();
    let b = data.bounds;
    let top_extent = b.min.abs().max(b.max.abs()).max_element();
    let mut out = vec![0u32; 8 * points.len()];
    // SAFETY: the top-level nodes and instance slots (child addresses of the layouts above),
    // 16 extra words per slot whose id address is a table above, 4 floats per point and 8
    // output words per point; everything alive through the call.
    unsafe {
        (k.instance_closest_points)(
            layout.nodes.as_ptr(),
            layout.instances.as_ptr(),
            extras.as_ptr(),
            words.as_ptr(),
            out.as_mut_ptr(),
            top_extent,
            points.len() as u32,
        )
    };
    for (i, p) in points.iter().enumerate() {
        let want = cpu.closest_point(*p).unwrap().unwrap();
        let w = &out[8 * i..8 * i + 8];
        let inst = &data.instances[w[7] as usize];
        let slot = children[child_of(inst.index)].1.slots[w[6] as usize];
        assert_eq!(
            (
                Vec3::new(
                    f32::from_bits(w[0]),
                    f32::from_bits(w[1]),
                    f32::from_bits(w[2])
                ),
                f32::from_bits(w[3]),
                slot.primitive_index,
                f32::from_bits(w[4]),
                f32::from_bits(w[5]),
                inst.instance_id,
            ),
            (
                want.closest.point,
                want.closest.distance,
                want.closest.primitive_index,
                want.closest.u,
                want.closest.v,
                want.instance_id,
            ),
            "point {i} {p}"
        );
    }
}
