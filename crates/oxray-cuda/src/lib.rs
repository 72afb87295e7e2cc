//! # oxray-cuda
//!
//! The CUDA backend of oxray. [`Cuda`] implements the [`AccelBackend`](oxray_core::AccelBackend)
//! boundary for the `oxray` facade's `Device`: a triangle GAS is built on the device by the
//! kernels of [`device_build`] (or, for the presets and layouts they do not build and with
//! [`GasBuilder::Host`], on the host by the builders every backend shares, `oxray-bvh`, and
//! uploaded) in one of the kernels' node layouts ([`CudaGas`]), and batches of rays are traced
//! there by a CUDA C++ kernel with the results of the CPU backend's batched queries (the same
//! distances bit for bit; the same primitives up to ties, and bit for bit on a host-built
//! tree).
//!
//! The CUDA driver and NVRTC are loaded at run time, so this crate builds, and its tests pass,
//! on machines without CUDA: there [`Cuda::new`] and [`CudaContext::new`] return an error for
//! which [`CudaError::is_unavailable`] holds. The kernels are CUDA C++ ([`KERNEL_SOURCE`])
//! compiled by NVRTC for the device's architecture when the context is created.
//!
//! ```no_run
//! use oxray_core::{AccelBackend, BuildOptions, IndexBuffer, Ray, TraversableHandle, TriangleInput, VertexBuffer};
//! use oxray_cuda::Cuda;
//!
//! let vertices = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
//! let triangles = [[0u32, 1, 2], [0, 2, 3]];
//! let input = TriangleInput::new(VertexBuffer::f32x3(&vertices))
//!     .indices(IndexBuffer::u32x3(&triangles));
//! let cuda = Cuda::new(0)?; // fails cleanly where there is no GPU
//! let gas = TraversableHandle::from(cuda.build_gas(&BuildOptions::default(), &[input.into()])?);
//! let rays = vec![Ray::new([0.25, 0.75, 1.0].into(), [0.0, 0.0, -1.0].into()); 4096];
//! let mut hits = vec![None; rays.len()];
//! cuda.intersect_closest(&gas, &rays, &mut hits)?;
//! assert_eq!(hits[0].unwrap().primitive_index, 1);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! For timing, or to keep rays on the device between launches, use [`DeviceRays`],
//! [`DeviceHits`] and [`DeviceOcclusion`] with [`CudaGas::intersect_device`] and
//! [`CudaGas::occluded_device`] (the facade exposes them as resident batches).

#![warn(missing_docs)]

mod backend;
mod context;
pub mod device_build;
mod error;
mod gas;
mod ias;
mod layout;
mod node_buffer;
mod program;
mod random_access;
#[cfg(test)]
mod reference;
mod refit;
mod relocate;
pub mod simulation;
mod transform;

pub use backend::{Cuda, CudaBatch};
pub use context::{trace_kernels_ptx, CudaContext, DeviceInfo, KernelInfo, KERNEL_SOURCE};
pub use device_build::{BuildTimes, DeviceBuildConfig, DeviceBuildError, GasBuilder};
pub use error::CudaError;
pub use gas::{CudaGas, DeviceHits, DeviceOcclusion, DeviceRays, HitRecord};
pub use ias::CudaIas;
pub use layout::{NodeLayout, SlotInfo};
pub use program::{
    compile_pipeline_ptx, launch_size, pack_sbt, pipeline_block, pipeline_cache_entry,
    pipeline_compile_options, pipeline_source, CudaBuffer, CudaHitGroupDesc, CudaModule,
    CudaPipeline, CudaProgramGroup, CudaProgramGroupKind, PackedRegion, PackedSbt,
    DEFAULT_MAX_TRAVERSABLE_GRAPH_DEPTH, DEVICE_HEADER, PIPELINE_BLOCK,
};
pub use transform::{CudaMotionTransform, CudaStaticTransform, MotionTransform};

#[cfg(test)]
#[path = "../tests/common/mod.rs"]
mod common;

#[cfg(test)]
mod host_kernels;

#[cfg(test)]
mod tests {
    use super::common::{
        bench_rays, build_gas_with_tree, find_mesh, icosphere_f32, load_obj, tricky_rays, Mesh,
    };
    use super::layout::DeviceLayout;
    use super::reference::trace;
    use super::*;
    use oxray_bvh::Bvh2;
    use oxray_core::{BuildFlags, Ray};
    use oxray_cpu::Gas;

    /// Traces `rays` through the device layout on the CPU and compares with the CPU backend.
    /// With `exact`, hits must be bit-identical (primitive included); otherwise distances must be
    /// bit-identical and the primitive may differ only where another primitive is hit at the
    /// same distance.
    fn check(gas: &Gas, tree: &Bvh2, layout: NodeLayout, rays: &[Ray], exact: bool) {
        let export = gas.export_triangles().unwrap();
        let dl = DeviceLayout::new(&export, tree, layout).unwrap();
        let mut cpu = vec![None; rays.len()];
        gas.intersect_batch(rays, &mut cpu).unwrap();
        let mut occ = vec![false; rays.len()];
        gas.occluded_batch(rays, &mut occ).unwrap();
        let mut ties = 0;
        for (i, r) in rays.iter().enumerate() {
            let rec = trace(&dl, r, false);
            let got = rec.is_hit().then(|| dl.slots[rec.slot_index() as usize]);
            match (&cpu[i], got) {
                (None, None) => assert_eq!(rec.t, f32::INFINITY),
                (Some(h), Some(s)) => {
                    assert_eq!(h.t.to_bits(), rec.t.to_bits(), "ray {i}: {r:?}");
                    if exact || h.primitive_index == s.primitive_index {
                        assert_eq!(h.primitive_index, s.primitive_index, "ray {i}: {r:?}");
                        assert_eq!(
                            (h.u.to_bits(), h.v.to_bits()),
                            (rec.u.to_bits(), rec.v.to_bits())
                        );
                        assert_eq!(h.hit_kind.is_triangle_front_face(), rec.is_front_face());
                        assert_eq!(
                            (h.sbt_gas_index, h.build_input),
                            (s.sbt_gas_index, s.build_input)
                        );
                    } else {
                        ties += 1;
                    }
                }
                (c, g) => panic!("ray {i} {r:?}: cpu {c:?}, layout {g:?}"),
            }
            let any = trace(&dl, r, true);
            assert_eq!(any.is_hit(), occ[i], "ray {i} occlusion: {r:?}");
        }
        // Ties come from the rays aimed exactly at shared vertices and edges.
        assert!(
            ties * 100 <= rays.len(),
            "{ties} ties in {} rays",
            rays.len()
        );
    }

    fn all_rays(mesh: &Mesh, gas: &Gas, side: u32) -> Vec<Ray> {
        let (mut rays, inc) = bench_rays(mesh, side);
        rays.extend(inc);
        rays.extend(tricky_rays(mesh, gas, (side * side) as usize, 11));
        rays
    }

    #[test]
    fn bvh4_layout_traversal_matches_the_cpu_backend_bit_for_bit() {
        for flags in [
            BuildFlags::empty(),
            BuildFlags::PREFER_FAST_TRACE,
            BuildFlags::PREFER_FAST_BUILD,
        ] {
            let mesh = icosphere_f32(4);
            let (gas, tree) = build_gas_with_tree(&mesh, flags).unwrap();
            check(
                &gas,
                &tree,
                NodeLayout::Bvh4,
                &all_rays(&mesh, &gas, 64),
                true,
            );
        }
    }

    #[test]
    fn bvh2_layout_traversal_matches_the_cpu_backend() {
        let mesh = icosphere_f32(4);
        let (gas, tree) = build_gas_with_tree(&mesh, BuildFlags::PREFER_FAST_TRACE).unwrap();
        check(
            &gas,
            &tree,
            NodeLayout::Bvh2,
            &all_rays(&mesh, &gas, 64),
            false,
        );
    }

    #[test]
    fn layouts_match_on_the_bunny() {
        let Some(path) = find_mesh("stanford-bunny.obj") else {
            println!("skipping: stanford-bunny.obj not found (set OXRAY_MESH_DIR)");
            return;
        };
        let mesh = load_obj(&path).unwrap();
        let (gas, tree) = build_gas_with_tree(&mesh, BuildFlags::PREFER_FAST_TRACE).unwrap();
        let rays = all_rays(&mesh, &gas, 96);
        check(&gas, &tree, NodeLayout::Bvh4, &rays, true);
        check(&gas, &tree, NodeLayout::Bvh2, &rays, false);
    }

    #[test]
    fn layouts_of_a_structure_with_spatial_splits_match_the_cpu_backend() {
        // Long slivers among small triangles: PREFER_FAST_TRACE splits some, so that leaves
        // share triangles (each leaf its own slot); the layouts derived from the canonical
        // tree must still find the CPU's hits, and every slot is reached once.
        let mut rng = oxray_testkit::rng::Rng::new(4);
        let mut tris = oxray_testkit::mesh::random_soup(&mut rng, 1500, 10.0, 0.5);
        for _ in 0..1500 {
            let a = rng.vec3(-10.0, 10.0);
            let b = rng.vec3(-10.0, 10.0);
            tris.push([
                a.to_array(),
                b.to_array(),
                (a + rng.vec3(-0.3, 0.3)).to_array(),
            ]);
        }
        let mesh = Mesh {
            positions: tris.iter().flatten().copied().collect(),
            triangles: (0..tris.len() as u32)
                .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
                .collect(),
        };
        let (gas, tree) = build_gas_with_tree(&mesh, BuildFlags::PREFER_FAST_TRACE).unwrap();
        assert!(gas.data().num_references() > gas.data().num_active_primitives());
        let mut rays = all_rays(&mesh, &gas, 48);
        rays.extend((0..3000).map(|_| Ray::new(rng.vec3(-12.0, 12.0), rng.dir())));
        check(&gas, &tree, NodeLayout::Bvh4, &rays, true);
        check(&gas, &tree, NodeLayout::Bvh2, &rays, false);
    }

    #[test]
    fn tiny_and_empty_gases_lay_out() {
        // One triangle: the root is a leaf lane.
        let mesh = Mesh {
            positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            triangles: vec![[0, 1, 2]],
        };
        let (gas, tree) = build_gas_with_tree(&mesh, BuildFlags::empty()).unwrap();
        let rays: Vec<Ray> = (0..64)
            .map(|i| {
                let x = (i % 8) as f32 / 7.0;
                let y = (i / 8) as f32 / 7.0;
                Ray::new([x, y, 1.0].into(), [0.0, 0.0, -1.0].into())
            })
            .collect();
        check(&gas, &tree, NodeLayout::Bvh4, &rays, true);
        check(&gas, &tree, NodeLayout::Bvh2, &rays, true);

        // Only degenerate triangles: nothing to hit.
        let flat = Mesh {
            positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]],
            triangles: vec![[0, 1, 2]],
        };
        let (gas, tree) = build_gas_with_tree(&flat, BuildFlags::empty()).unwrap();
        for layout in [NodeLayout::Bvh4, NodeLayout::Bvh2] {
            let dl = DeviceLayout::new(&gas.export_triangles().unwrap(), &tree, layout).unwrap();
            assert!(!trace(&dl, &rays[0], false).is_hit());
            assert!(dl.slots.is_empty());
        }
    }

    #[test]
    fn bvh2_nodes_are_half_the_size_and_cover_every_slot() {
        let mesh = icosphere_f32(3);
        let (gas, tree) = build_gas_with_tree(&mesh, BuildFlags::empty()).unwrap();
        let export = gas.export_triangles().unwrap();
        let b4 = DeviceLayout::new(&export, &tree, NodeLayout::Bvh4).unwrap();
        let b2 = DeviceLayout::new(&export, &tree, NodeLayout::Bvh2).unwrap();
        assert_eq!(b4.nodes.len(), 32 * export.nodes.len());
        assert_eq!(b2.nodes.len() % 16, 0);
        // Every active slot is reached exactly once from the binary root.
        let mut seen = vec![0u32; b2.slots.len()];
        let mut stack = vec![0usize];
        while let Some(n) = stack.pop() {
            let w = &b2.nodes[16 * n..][..16];
            for c in 0..2 {
                let lo_x = f32::from_bits(w[4 * c]);
                let hi_x = f32::from_bits(w[4 * c + 1]);
                if lo_x > hi_x {
                    continue; // unused child
                }
                let (child, count) = (w[12 + c] as usize, w[14 + c] as usize);
                if count == 0 {
                    stack.push(child);
                } else {
                    for n in &mut seen[child..child + count] {
                        *n += 1;
                    }
                }
            }
        }
        for (s, info) in b2.slots.iter().enumerate() {
            let active = info.primitive_index != u32::MAX;
            assert_eq!(seen[s], active as u32, "slot {s}");
        }
        assert_eq!(b2.triangles.len(), 12 * b2.slots.len());
    }

    #[test]
    fn custom_primitive_gas_is_refused_before_any_device_call() {
        // Without a device a context cannot be made; the refusal is checked on the export.
        let boxes = [oxray_core::Aabb::new(glam::Vec3::ZERO, glam::Vec3::ONE)];
        let input = oxray_core::CustomPrimitiveInput::new(oxray_core::AabbBuffer::new(&boxes));
        let gas = Gas::build(&oxray_core::BuildOptions::default(), &[input.into()]).unwrap();
        assert!(gas.export_triangles().is_none());
        assert!(CudaError::CustomPrimitives.to_string().contains("triangle"));
    }

    /// One level of instances over two meshes, with random transforms (non-uniform scales,
    /// mirrors), a flipped-facing instance, a zero-mask instance, a null one and an empty GAS.
    fn instanced_scene() -> (
        oxray_cpu::Ias,
        crate::layout::IasLayout,
        Vec<Option<DeviceLayout>>,
        Vec<Ray>,
    ) {
        use oxray_core::{Instance, InstanceFlags, Transform, TraversableHandle};
        use oxray_testkit::rng::Rng;
        let sphere = icosphere_f32(3);
        let plane = Mesh {
            positions: vec![
                [-1.0, -1.0, 0.0],
                [1.0, -1.0, 0.0],
                [1.0, 1.0, 0.0],
                [-1.0, 1.0, 0.0],
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        };
        let flat = Mesh {
            positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]],
            triangles: vec![[0, 1, 2]],
        };
        let built: Vec<(Gas, Bvh2)> = [&sphere, &plane, &flat]
            .iter()
            .map(|m| build_gas_with_tree(m, BuildFlags::empty()).unwrap())
            .collect();
        let layouts: Vec<DeviceLayout> = built
            .iter()
            .map(|(g, t)| {
                let e = g.export_triangles().unwrap();
                DeviceLayout::new(&e, t, NodeLayout::Bvh2).unwrap()
            })
            .collect();
        let handles: Vec<TraversableHandle> = built
            .iter()
            .map(|(g, _)| TraversableHandle::from(g.clone()))
            .collect();
        let mut rng = Rng::new(5);
        let mut instances: Vec<Instance> = (0..60)
            .map(|i| {
                let mut a = rng.affine(6.0);
                if i % 7 == 0 {
                    a.matrix3.x_axis = -a.matrix3.x_axis; // a mirror
                }
                let mut inst = Instance::new(handles[i % 3].clone())
                    .transform(Transform::from_affine(&a))
                    .instance_id(100 + i as u32);
                if i % 5 == 1 {
                    inst = inst.flags(InstanceFlags::FLIP_TRIANGLE_FACING);
                }
                if i == 9 {
                    inst = inst.visibility_mask(0);
                }
                inst
            })
            .collect();
        instances.push(Instance::new(TraversableHandle::NULL));
        let input = [oxray_core::BuildInput::from(&instances[..])];
        let options = oxray_core::BuildOptions::default();
        let cpu = oxray_cpu::Ias::build(&options, &input).unwrap();
        let (data, tree) = oxray_bvh::IasData::build_with_tree(&options, &input).unwrap();
        // The children of the device table, by slot, as `CudaIas::upload` makes them.
        let mut children = Vec::new();
        let refs: Vec<Option<crate::layout::ChildRef>> = data
            .instances
            .iter()
            .enumerate()
            .map(|(slot, inst)| {
                let which = handles.iter().position(|h| h.same_as(&inst.child));
                children.push(which.map(|w| layouts[w].clone()));
                (which.is_some() && inst.mask != 0).then_some(crate::layout::ChildRef {
                    index: slot as u32,
                    nodes_addr: 1,
                    triangles_addr: 1,
                })
            })
            .collect();
        let top = crate::layout::IasLayout::new(&data, &tree, &refs).unwrap();
        let mut rays: Vec<Ray> = (0..20_000)
            .map(|_| {
                let o = rng.vec3(-12.0, 12.0);
                Ray::new(o, rng.vec3(-6.0, 6.0) - o)
            })
            .collect();
        rays.push(Ray::new(glam::Vec3::NAN, glam::Vec3::Z));
        (cpu, top, children, rays)
    }

    #[test]
    fn ias_layout_traversal_matches_the_cpu_backend() {
        use super::reference::trace_ias;
        let (cpu, top, children, rays) = instanced_scene();
        let mut ties = 0;
        let mut hits = 0;
        for (i, r) in rays.iter().enumerate() {
            let want = cpu.intersect(r);
            let (rec, slot) = trace_ias(&top, &children, r, false);
            match (want, rec.is_hit()) {
                (None, false) => {}
                (Some(h), true) => {
                    hits += 1;
                    assert_eq!(h.t.to_bits(), rec.t.to_bits(), "ray {i}: {r:?}");
                    let inst = &cpu.instances[slot as usize];
                    if h.instance_index == inst.index {
                        assert_eq!(
                            (h.u.to_bits(), h.v.to_bits()),
                            (rec.u.to_bits(), rec.v.to_bits())
                        );
                        let flip = inst
                            .flags
                            .contains(oxray_core::InstanceFlags::FLIP_TRIANGLE_FACING);
                        assert_eq!(
                            h.hit_kind.is_triangle_front_face(),
                            rec.is_front_face() != flip
                        );
                        assert_eq!(h.instance_id, inst.instance_id);
                    } else {
                        ties += 1;
                    }
                }
                (w, _) => panic!("ray {i} {r:?}: cpu {w:?}, layout {rec:?}"),
            }
            let (any, _) = trace_ias(&top, &children, r, true);
            assert_eq!(any.is_hit(), cpu.occluded(r), "ray {i} occlusion");
        }
        assert!(hits > 2_000, "{hits} hits");
        assert!(ties * 100 <= rays.len(), "{ties} ties");
    }
}
