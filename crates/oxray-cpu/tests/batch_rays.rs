//! The batched queries' path for rays that do not go as packets (each ray's set-up, walk and
//! answer compiled with the kernel, for a triangle GAS without motion) against queries ray by
//! ray: the same hit, every field bit for bit (the same walk, so even which of two primitives
//! at one distance is reported), the same occlusion, for every kernel, with invalid rays mixed
//! in, with several build inputs, and whatever the number of threads.

use oxray_core::{BuildFlags, BuildOptions, IndexBuffer, Ray, TriangleInput, VertexBuffer};
use oxray_cpu::{Gas, Isa};
use oxray_testkit::mesh::{grid_cube, icosphere, random_soup, Mesh};
use oxray_testkit::oracle::{check_closest, hit_bits};
use oxray_testkit::rays::{rays_around, rays_at_features};
use oxray_testkit::rng::Rng;

mod common;
use common::{batched, invalid_rays, kernels, mesh_gas, soup_mesh};

/// A GAS with the mesh's triangles split over two build inputs (the second half's hits carry
/// build input 1 and their own primitive indices).
fn two_input_gas(isa: Isa, m: &Mesh, flags: BuildFlags) -> Gas {
    let half = m.triangles.len() / 2;
    let (a, b) = m.triangles.split_at(half);
    let inputs = [a, b].map(|t| {
        TriangleInput::new(VertexBuffer::f32x3(&m.positions))
            .indices(IndexBuffer::u32x3(t))
            .into()
    });
    Gas::build_with_isa(isa, &BuildOptions::new(flags), &inputs).unwrap()
}

/// Rays from many origins (no two consecutive share one, so no group of eight is a packet):
/// around the mesh, exactly at its vertices and edges, and every kind of invalid ray.
fn rays(m: &Mesh, rng: &mut Rng) -> Vec<Ray> {
    let mut rays = rays_around(rng, m, 1500);
    rays.extend(rays_at_features(rng, m, 700));
    // Intervals that start past the origin (the first surfaces skipped).
    for ray in rays.iter_mut().step_by(5) {
        ray.tmin = (ray.tmax * rng.f32()).min(rng.range(0.0, 8.0));
    }
    for (k, bad) in invalid_rays().into_iter().enumerate() {
        rays.insert(37 * k + 5, bad);
    }
    rays
}

#[test]
fn batches_of_scattered_rays_answer_as_single_queries_bit_for_bit() {
    let mut rng = Rng::new(17);
    let scenes = [
        ("soup", soup_mesh(&random_soup(&mut rng, 3000, 10.0, 0.8))),
        ("grid cube", grid_cube(12)),
        ("icosphere", icosphere(4)),
    ];
    for (name, m) in &scenes {
        let tris = m.soup();
        let rays = rays(m, &mut rng);
        for isa in kernels() {
            for flags in [BuildFlags::empty(), BuildFlags::PREFER_FAST_TRACE] {
                for (inputs, gas) in [
                    (1, mesh_gas(isa, m, flags)),
                    (2, two_input_gas(isa, m, flags)),
                ] {
                    let (hits, occluded) = batched(&gas, &rays, 1);
                    let (hits2, occluded2) = batched(&gas, &rays, 2);
                    assert_eq!(
                        occluded, occluded2,
                        "{name}, {isa}: threads change occlusion"
                    );
                    let (mut hit_count, mut second_input) = (0, 0);
                    for (i, ray) in rays.iter().enumerate() {
                        let one = gas.intersect(ray);
                        assert_eq!(
                            hit_bits(&hits[i]),
                            hit_bits(&one),
                            "{name}, {isa}, ray {i} {ray:?}"
                        );
                        assert_eq!(
                            hit_bits(&hits2[i]),
                            hit_bits(&one),
                            "{name}, {isa}, ray {i}, 2 threads"
                        );
                        assert_eq!(occluded[i], gas.occluded(ray), "{name}, {isa}, ray {i}");
                        if ray.validate().is_err() {
                            assert!(one.is_none() && !occluded[i], "{name}: invalid ray {i} hit");
                        }
                        let Some(h) = one else { continue };
                        hit_count += 1;
                        second_input += usize::from(h.build_input == 1);
                        if i % 7 == 0 {
                            // Back to the one-input soup the reference knows.
                            let mut h = h;
                            h.primitive_index += h.build_input * (m.triangles.len() / 2) as u32;
                            (h.build_input, h.sbt_gas_index) = (0, 0);
                            check_closest(Some(h), &tris, ray)
                                .unwrap_or_else(|e| panic!("{name}, {isa}, ray {i}: {e}"));
                        }
                    }
                    assert!(
                        hit_count > rays.len() / 3 && (inputs == 1 || second_input > 0),
                        "{name}, {isa}: {hit_count} hits, {second_input} on the second input"
                    );
                }
            }
        }
    }
}
