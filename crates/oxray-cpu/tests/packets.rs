//! The packet kernel of the batched queries (eight rays from one origin traced together, on
//! processors with AVX2) against the single-ray kernel: the same hits (t, u, v and facing bit
//! for bit; another primitive only at exactly the same distance, one the brute-force reference
//! finds there), the same occlusion, for every mix a batch may hold — whole packets, packets
//! with rays of several octants or dominant axes, invalid rays, zero direction components,
//! bounded and offset intervals, rays through vertices and along edges — and the same answers
//! whatever the number of threads.

use glam::Vec3;
use oxray_core::{BuildFlags, Hit, Ray};
use oxray_cpu::{Gas, Isa};
use oxray_testkit::mesh::{grid_cube, icosphere, load_bunny, random_soup, Mesh};
use oxray_testkit::oracle::{check_closest, reference_hits};
use oxray_testkit::rays::{camera_rays, center_radius};
use oxray_testkit::rng::Rng;

mod common;
use common::{batched, kernels, mesh_gas, soup_mesh};

fn scenes() -> Vec<(String, Mesh)> {
    let mut rng = Rng::new(3);
    let mut out = vec![
        (
            "soup".to_string(),
            soup_mesh(&random_soup(&mut rng, 2000, 10.0, 0.8)),
        ),
        ("grid cube".to_string(), grid_cube(10)),
        ("icosphere".to_string(), icosphere(4)),
    ];
    if let Some(b) = load_bunny("packets") {
        out.push(("bunny".to_string(), b));
    }
    out
}

/// Batches of rays from shared origins, in groups of eight, that exercise the packet kernel
/// and every reason it hands a group back to the single-ray kernel.
fn batch(m: &Mesh, rng: &mut Rng) -> Vec<Ray> {
    let (c, r) = center_radius(&m.positions);

    // A pinhole camera: whole packets, some straddling octants and dominant axes.
    let mut rays = camera_rays(&m.positions, 40, 40);
    // From points around and inside the mesh: towards vertices (edge and vertex hits, the
    // single-ray test's exact fallback) and towards random points near them.
    for k in 0..120 {
        let origin = if k % 4 == 0 {
            c + Vec3::new(
                rng.range(-0.3, 0.3),
                rng.range(-0.3, 0.3),
                rng.range(-0.3, 0.3),
            ) * r
        } else {
            c + rng.dir() * r * rng.range(1.5, 3.0)
        };
        let target = Vec3::from(m.positions[rng.below(m.positions.len())]);
        for l in 0..8 {
            let aim = if l % 3 == 0 {
                Vec3::from(m.positions[rng.below(m.positions.len())])
            } else {
                target + Vec3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), 0.0) * 0.02 * r
            };
            let mut d = aim - origin;
            if k % 11 == 0 && l == 2 {
                d.x = 0.0; // a zero component: not a packet
            }
            let (tmin, tmax) = match k % 5 {
                0 => (0.0, f32::INFINITY),
                1 => (0.0, 1.0), // ends at the target: shadow-ray style
                2 => (0.3, 0.9),
                3 => (0.0, rng.range(0.2, 2.0)),
                _ => (rng.range(0.0, 0.5), f32::INFINITY),
            };
            rays.push(Ray::with_interval(origin, d, tmin, tmax));
        }
        if k % 13 == 0 {
            // An invalid ray inside a group: it hits nothing, its neighbours still do.
            let n = rays.len();
            rays[n - 3] = Ray::with_interval(origin, Vec3::new(f32::NAN, 1.0, 0.0), 0.0, 1.0);
        }
    }
    rays
}

fn single(gas: &Gas, rays: &[Ray]) -> (Vec<Option<Hit>>, Vec<bool>) {
    (
        rays.iter().map(|r| gas.intersect(r)).collect(),
        rays.iter().map(|r| gas.occluded(r)).collect(),
    )
}

#[test]
fn packets_find_the_hits_of_single_rays() {
    let mut rng = Rng::new(5);
    let isas: Vec<Isa> = kernels()
        .into_iter()
        .filter(|i| matches!(i, Isa::Avx2 | Isa::Avx512))
        .collect();
    if isas.is_empty() {
        eprintln!("skipping: no AVX2 on this processor, the batched queries trace single rays");
    }
    for (name, m) in scenes() {
        let tris = m.soup();
        let rays = batch(&m, &mut rng);
        for &isa in &isas {
            for flags in [BuildFlags::empty(), BuildFlags::PREFER_FAST_TRACE] {
                let gas = mesh_gas(isa, &m, flags);
                let (one_hits, one_occ) = single(&gas, &rays);
                let (hits, occ) = batched(&gas, &rays, 1);
                assert!(
                    (hits.clone(), occ.clone()) == batched(&gas, &rays, 2),
                    "{name}, {isa}: the batch depends on the thread count"
                );
                let mut ties = 0;
                for (i, ray) in rays.iter().enumerate() {
                    assert_eq!(
                        occ[i], one_occ[i],
                        "{name}, {isa}, ray {i} {ray:?}: occlusion"
                    );
                    let (a, b) = (&one_hits[i], &hits[i]);
                    assert_eq!(
                        a.is_some(),
                        b.is_some(),
                        "{name}, {isa}, ray {i}: hit or miss"
                    );
                    let (Some(a), Some(b)) = (a, b) else {
                        continue;
                    };
                    assert_eq!(a.t.to_bits(), b.t.to_bits(), "{name}, {isa}, ray {i}: t");
                    if a.primitive_index == b.primitive_index {
                        assert_eq!(
                            (a.u.to_bits(), a.v.to_bits(), a.hit_kind),
                            (b.u.to_bits(), b.v.to_bits(), b.hit_kind),
                            "{name}, {isa}, ray {i}: attributes"
                        );
                    } else {
                        // A tie: the reference hits the packet's primitive at that very t.
                        let at_t = reference_hits(&tris, ray).iter().any(|r| {
                            r.prim == b.primitive_index && r.hit.t.to_bits() == b.t.to_bits()
                        });
                        assert!(
                            at_t,
                            "{name}, {isa}, ray {i}: primitive {} is not a tie",
                            b.primitive_index
                        );
                        ties += 1;
                    }
                    if i % 5 == 0 {
                        check_closest(Some(*b), &tris, ray)
                            .unwrap_or_else(|e| panic!("{name}, {isa}, ray {i}: {e}"));
                    }
                }
                eprintln!("{name} {isa} {flags:?}: {} rays, {ties} ties", rays.len());
            }
        }
    }
}

#[test]
fn packets_of_rays_ending_in_a_shared_point_agree_with_single_rays() {
    // Rays from one light towards points of the surface (what a renderer's light sampling
    // shoots), each ending just short of its point: occluded exactly where a single ray is.
    let m = icosphere(3);
    let (c, r) = center_radius(&m.positions);
    let light = c + Vec3::new(0.3, 2.0, 0.2) * r;
    let mut rng = Rng::new(8);
    let rays: Vec<Ray> = (0..4096)
        .map(|_| {
            let p = Vec3::from(m.positions[rng.below(m.positions.len())]);
            Ray::with_interval(light, p - light, 0.0, 0.999)
        })
        .collect();
    for isa in kernels() {
        let gas = mesh_gas(isa, &m, BuildFlags::empty());
        let (_, one) = single(&gas, &rays);
        let (_, occ) = batched(&gas, &rays, 2);
        assert_eq!(occ, one, "{isa}");
        let blocked = occ.iter().filter(|&&b| b).count();
        assert!(
            blocked > 100 && blocked < rays.len() - 100,
            "{isa}: {blocked} blocked"
        );
    }
}
