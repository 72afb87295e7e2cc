//! Batches through small triangle structures (at most 64 leaf slots: a room, a box), whose
//! triangles the batched queries test whole, sixteen rays at a time, where the processor has
//! AVX-512: against queries ray by ray (the tree's walk) and against the brute-force reference.
//! Every hit is the walk's bit for bit, except where two primitives lie at exactly the same
//! distance (then either may be reported, at that distance, with its own barycentrics, as
//! the brute-force reference checks); occlusion is the same; rays
//! aimed exactly at vertices and edges of a closed mesh never slip through; invalid rays hit
//! nothing; and the answers do not depend on the number of threads.

use glam::Vec3;
use oxray_core::{BuildFlags, Hit, Ray};
use oxray_cpu::Gas;
use oxray_testkit::mesh::{grid_cube, icosphere, random_soup, Mesh};
use oxray_testkit::oracle::{check_closest, hit_bits};
use oxray_testkit::rays::{rays_around, rays_at_features};
use oxray_testkit::rng::Rng;

mod common;
use common::{batched, invalid_rays, kernels, mesh_gas, soup_mesh};

/// Scattered rays around and at the features of `m`, some with intervals starting past the
/// origin, some from inside, and every kind of invalid ray.
fn rays(m: &Mesh, rng: &mut Rng) -> Vec<Ray> {
    let mut rays = rays_around(rng, m, 1200);
    rays.extend(rays_at_features(rng, m, 800));
    for ray in rays.iter_mut().step_by(5) {
        ray.tmin = (ray.tmax * rng.f32()).min(rng.range(0.0, 4.0));
    }
    // From the centre of the mesh's box, in every direction (each class of the test's axis
    // permutation), some along the axes exactly (zero direction components).
    let (lo, hi) = m.positions.iter().fold(
        (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
        |(lo, hi), &p| (lo.min(Vec3::from(p)), hi.max(Vec3::from(p))),
    );
    let centre = (lo + hi) * 0.5;
    for k in 0..300 {
        let d = if k % 10 == 0 {
            [Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z][k / 10 % 6]
        } else {
            Vec3::new(
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
                rng.range(-1.0, 1.0),
            )
        };
        rays.push(Ray::new(centre, d));
    }
    for (k, bad) in invalid_rays().into_iter().enumerate() {
        rays.insert(41 * k + 3, bad);
    }
    rays
}

/// The batch's hit agrees with the walk's: the same bits, or (a tie) another primitive at
/// exactly the same distance. Returns whether it was a tie.
fn agrees(batch: &Option<Hit>, one: &Option<Hit>) -> Result<bool, String> {
    if hit_bits(batch) == hit_bits(one) {
        return Ok(false);
    }
    match (batch, one) {
        (Some(b), Some(o)) if b.t == o.t && b.primitive_index != o.primitive_index => Ok(true),
        _ => Err(format!("batch {batch:?}, one ray {one:?}")),
    }
}

#[test]
fn small_structures_answer_batches_as_single_queries() {
    let mut rng = Rng::new(29);
    let scenes = [
        ("soup", soup_mesh(&random_soup(&mut rng, 40, 4.0, 1.0))),
        ("cube", grid_cube(1)),
        ("cube 2x2", grid_cube(2)),
        ("icosahedron", icosphere(0)),
    ];
    let mut small_seen = 0;
    for (name, m) in &scenes {
        let tris = m.soup();
        let rays = rays(m, &mut rng);
        for isa in kernels() {
            for flags in [BuildFlags::empty(), BuildFlags::PREFER_FAST_TRACE] {
                let gas: Gas = mesh_gas(isa, m, flags);
                small_seen += usize::from(gas.slot_prim.len() <= 64);
                let (hits, occluded) = batched(&gas, &rays, 1);
                let (hits2, occluded2) = batched(&gas, &rays, 2);
                assert_eq!(
                    occluded, occluded2,
                    "{name}, {isa}: threads change occlusion"
                );
                let (mut hit_count, mut ties) = (0, 0);
                for (i, ray) in rays.iter().enumerate() {
                    let one = gas.intersect(ray);
                    assert_eq!(
                        hit_bits(&hits[i]),
                        hit_bits(&hits2[i]),
                        "{name}, {isa}, ray {i}: threads change the hit"
                    );
                    let tie = agrees(&hits[i], &one)
                        .unwrap_or_else(|e| panic!("{name}, {isa}, ray {i} {ray:?}: {e}"));
                    ties += usize::from(tie);
                    assert_eq!(occluded[i], gas.occluded(ray), "{name}, {isa}, ray {i}");
                    if ray.validate().is_err() {
                        assert!(
                            hits[i].is_none() && !occluded[i],
                            "{name}: invalid ray {i} hit"
                        );
                    }
                    if hits[i].is_some() {
                        hit_count += 1;
                    }
                    // A tie's primitive, too, is hit at that distance with those barycentrics.
                    check_closest(hits[i], &tris, ray)
                        .unwrap_or_else(|e| panic!("{name}, {isa}, ray {i}: {e}"));
                }
                assert!(
                    hit_count > rays.len() / 3,
                    "{name}, {isa}: only {hit_count} of {} rays hit",
                    rays.len()
                );
                // Ties need a ray exactly through a shared edge or vertex (the rays aimed at
                // the mesh's features).
                println!("{name}, {isa}: {hit_count} hits, {ties} ties");
            }
        }
    }
    assert!(small_seen > 0, "no structure was small enough");
}

#[test]
fn rays_from_inside_a_closed_small_mesh_never_escape() {
    // Watertightness: from points inside a closed cube, rays aimed exactly at its vertices and
    // at points on its edges hit it, batched as one by one.
    let m = grid_cube(2);
    let mut rng = Rng::new(5);
    let (lo, hi) = m.positions.iter().fold(
        (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)),
        |(lo, hi), &p| (lo.min(Vec3::from(p)), hi.max(Vec3::from(p))),
    );
    let mut rays = Vec::new();
    for _ in 0..40 {
        let o = lo
            + (hi - lo)
                * Vec3::new(
                    rng.range(0.1, 0.9),
                    rng.range(0.1, 0.9),
                    rng.range(0.1, 0.9),
                );
        for t in &m.triangles {
            let [a, b, c] = t.map(|i| Vec3::from(m.positions[i as usize]));
            let s = rng.f32();
            for target in [a, a + (b - a) * s, b + (c - b) * s, c + (a - c) * s] {
                rays.push(Ray::new(o, target - o));
            }
        }
    }
    for isa in kernels() {
        let gas = mesh_gas(isa, &m, BuildFlags::empty());
        let (hits, occluded) = batched(&gas, &rays, 2);
        for (i, ray) in rays.iter().enumerate() {
            assert!(
                hits[i].is_some() && occluded[i],
                "{isa}: ray {i} {ray:?} escaped"
            );
        }
    }
}
