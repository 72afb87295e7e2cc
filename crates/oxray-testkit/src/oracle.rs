//! A brute-force reference for ray queries on triangle soups: every triangle is tested with the
//! engine's watertight triangle test ([`oxray_bvh::triangle::WatertightRay`]), so a correct
//! acceleration structure must agree with it bit for bit.

use crate::mesh::Tri;
use oxray_bvh::triangle::{is_degenerate, TriangleHit, WatertightRay};
use oxray_core::{Hit, HitKind, Ray};

/// One hit of the brute-force reference.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefHit {
    /// Index of the triangle in the soup.
    pub prim: u32,
    /// The watertight test's result.
    pub hit: TriangleHit,
}

/// Every hit of `ray` on the soup within the closed interval `[tmin, tmax]`, in triangle order.
/// Degenerate triangles (non-finite vertex or zero area) are skipped, as the builder makes them
/// inactive; an invalid ray hits nothing.
#[must_use]
pub fn reference_hits(tris: &[Tri], ray: &Ray) -> Vec<RefHit> {
    if ray.validate().is_err() {
        return Vec::new();
    }
    let wr = WatertightRay::new(ray.origin, ray.direction);
    tris.iter()
        .enumerate()
        .filter(|(_, t)| !is_degenerate(t[0].into(), t[1].into(), t[2].into()))
        .filter_map(|(i, t)| {
            wr.intersect(&t[0], &t[1], &t[2], ray.tmin, ray.tmax)
                .map(|hit| RefHit {
                    prim: i as u32,
                    hit,
                })
        })
        .collect()
}

/// The closest reference hit (the lowest triangle index among equal distances).
#[must_use]
pub fn reference_closest(tris: &[Tri], ray: &Ray) -> Option<RefHit> {
    closest_of(&reference_hits(tris, ray))
}

/// The closest of a set of reference hits (the first among equal distances).
#[must_use]
pub fn closest_of(hits: &[RefHit]) -> Option<RefHit> {
    hits.iter()
        .copied()
        .fold(None, |best: Option<RefHit>, h| match best {
            Some(b) if b.hit.t <= h.hit.t => Some(b),
            _ => Some(h),
        })
}

/// Checks a GAS closest hit of a single-input triangle soup against the reference:
/// the distance must equal the reference's closest distance bit for bit, and the primitive
/// reported must itself be hit by the reference at exactly that distance (ties may pick another
/// primitive), with the same barycentrics and facing.
pub fn check_closest(got: Option<Hit>, tris: &[Tri], ray: &Ray) -> Result<(), String> {
    let hits = reference_hits(tris, ray);
    let best = closest_of(&hits);
    match (got, best) {
        (None, None) => Ok(()),
        (Some(g), None) => Err(format!(
            "GAS hit {g:?} but the reference misses; ray {ray:?}"
        )),
        (None, Some(b)) => Err(format!(
            "GAS missed but the reference hits {b:?}; ray {ray:?}"
        )),
        (Some(g), Some(b)) => {
            // Bit for bit, except that +0 and -0 are the same distance (a tie).
            let same = g.t.to_bits() == b.hit.t.to_bits() || (g.t == 0.0 && b.hit.t == 0.0);
            if !same {
                return Err(format!(
                    "closest t differs: GAS {g:?}, reference {b:?}; ray {ray:?}"
                ));
            }
            let Some(r) = hits
                .iter()
                .find(|h| h.prim == g.primitive_index && h.hit.t.to_bits() == g.t.to_bits())
            else {
                return Err(format!(
                    "GAS returned primitive {} at t = {}, which the reference does not hit at that t; \
                     reference hits: {hits:?}; ray {ray:?}",
                    g.primitive_index, g.t
                ));
            };
            if g.u.to_bits() != r.hit.u.to_bits() || g.v.to_bits() != r.hit.v.to_bits() {
                return Err(format!(
                    "barycentrics differ: GAS {g:?}, reference {r:?}; ray {ray:?}"
                ));
            }
            let kind = if r.hit.front_face {
                HitKind::TRIANGLE_FRONT_FACE
            } else {
                HitKind::TRIANGLE_BACK_FACE
            };
            if g.hit_kind != kind {
                return Err(format!("hit kind differs: GAS {g:?}, reference {r:?}"));
            }
            if g.build_input != 0 || g.sbt_gas_index != 0 {
                return Err(format!("single-input GAS reported {g:?}"));
            }
            Ok(())
        }
    }
}

/// Every field of a hit of a GAS as bits: `t`, `u`, `v`, primitive index, SBT-GAS index, build
/// input, hit kind.
pub type HitBits = (u32, u32, u32, u32, u32, u32, u8);

/// The bits of every field of a hit of a GAS, for exact comparisons.
#[must_use]
pub fn hit_bits(h: &Option<Hit>) -> Option<HitBits> {
    h.map(|h| {
        (
            h.t.to_bits(),
            h.u.to_bits(),
            h.v.to_bits(),
            h.primitive_index,
            h.sbt_gas_index,
            h.build_input,
            h.hit_kind.0,
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::tri_at;
    use glam::Vec3;

    /// A GAS-style hit from a reference hit.
    fn as_hit(r: RefHit) -> Hit {
        Hit {
            t: r.hit.t,
            u: r.hit.u,
            v: r.hit.v,
            primitive_index: r.prim,
            sbt_gas_index: 0,
            build_input: 0,
            hit_kind: if r.hit.front_face {
                HitKind::TRIANGLE_FRONT_FACE
            } else {
                HitKind::TRIANGLE_BACK_FACE
            },
            instance_id: !0,
            instance_index: 0,
        }
    }

    #[test]
    fn hits_are_in_triangle_order_and_closest_is_the_nearest() {
        // Three triangles stacked along z, the middle one twice (a tie).
        let tris = [
            tri_at(0.0, 0.0, 0.0, 1.0),
            tri_at(0.0, 0.0, 2.0, 1.0),
            tri_at(0.0, 0.0, 2.0, 1.0),
            tri_at(5.0, 5.0, 1.0, 1.0),
        ];
        let ray = Ray::new(Vec3::new(0.0, 0.0, 5.0), Vec3::NEG_Z);
        let hits = reference_hits(&tris, &ray);
        assert_eq!(hits.iter().map(|h| h.prim).collect::<Vec<_>>(), [0, 1, 2]);
        assert_eq!(
            hits.iter().map(|h| h.hit.t).collect::<Vec<_>>(),
            [5.0, 3.0, 3.0]
        );
        // Seen from +z, going -z: front faces.
        assert!(hits.iter().all(|h| h.hit.front_face));
        let best = reference_closest(&tris, &ray).unwrap();
        assert_eq!((best.prim, best.hit.t), (1, 3.0));
        // The interval is closed: ending exactly at the hit still hits.
        let short = Ray::with_interval(ray.origin, ray.direction, 0.0, 3.0);
        assert_eq!(reference_closest(&tris, &short).unwrap().prim, 1);
        let shorter = Ray::with_interval(ray.origin, ray.direction, 0.0, 2.999);
        assert!(reference_hits(&tris, &shorter).is_empty());
        // From below: back faces.
        let up = Ray::new(Vec3::new(0.0, 0.0, -1.0), Vec3::Z);
        assert!(!reference_closest(&tris, &up).unwrap().hit.front_face);
    }

    #[test]
    fn degenerate_triangles_and_invalid_rays_hit_nothing() {
        let flat = [[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]];
        let nan = [[[f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]];
        let ray = Ray::new(Vec3::new(0.5, 0.0, 1.0), Vec3::NEG_Z);
        assert!(reference_hits(&flat, &ray).is_empty());
        assert!(reference_hits(&nan, &ray).is_empty());
        let tris = [tri_at(0.0, 0.0, 0.0, 1.0)];
        for bad in [
            Ray::new(Vec3::new(0.0, 0.0, 1.0), Vec3::ZERO),
            Ray::with_interval(Vec3::new(0.0, 0.0, 1.0), Vec3::NEG_Z, 2.0, 1.0),
            Ray::new(Vec3::new(f32::NAN, 0.0, 1.0), Vec3::NEG_Z),
        ] {
            assert!(reference_hits(&tris, &bad).is_empty());
        }
        assert_eq!(closest_of(&[]), None);
    }

    #[test]
    fn check_closest_accepts_the_reference_and_ties_and_rejects_the_rest() {
        let tris = [
            tri_at(0.0, 0.0, 0.0, 1.0),
            tri_at(0.0, 0.0, 2.0, 1.0),
            tri_at(0.0, 0.0, 2.0, 1.0),
        ];
        let ray = Ray::new(Vec3::new(0.1, 0.2, 5.0), Vec3::NEG_Z);
        let hits = reference_hits(&tris, &ray);
        let best = as_hit(hits[1]);
        assert_eq!(check_closest(Some(best), &tris, &ray), Ok(()));
        // A tie: the other triangle at the same distance.
        assert_eq!(check_closest(Some(as_hit(hits[2])), &tris, &ray), Ok(()));
        // Farther, missing, spurious, wrong barycentrics, wrong facing, wrong input.
        assert!(check_closest(Some(as_hit(hits[0])), &tris, &ray).is_err());
        assert!(check_closest(None, &tris, &ray).is_err());
        let miss = Ray::new(Vec3::new(9.0, 9.0, 5.0), Vec3::NEG_Z);
        assert!(check_closest(Some(best), &tris, &miss).is_err());
        assert_eq!(check_closest(None, &tris, &miss), Ok(()));
        let mut h = best;
        h.u = f32::from_bits(h.u.to_bits() + 1);
        assert!(check_closest(Some(h), &tris, &ray).is_err());
        let mut h = best;
        h.hit_kind = HitKind::TRIANGLE_BACK_FACE;
        assert!(check_closest(Some(h), &tris, &ray).is_err());
        let mut h = best;
        h.build_input = 1;
        assert!(check_closest(Some(h), &tris, &ray).is_err());
    }

    #[test]
    fn hit_bits_capture_every_gas_field() {
        let tris = [tri_at(0.0, 0.0, 0.0, 1.0)];
        let ray = Ray::new(Vec3::new(0.1, 0.2, 5.0), Vec3::NEG_Z);
        let h = as_hit(reference_closest(&tris, &ray).unwrap());
        let b = hit_bits(&Some(h)).unwrap();
        assert_eq!(b.0, h.t.to_bits());
        assert_eq!(b.6, HitKind::TRIANGLE_FRONT_FACE.0);
        let mut other = h;
        other.sbt_gas_index = 3;
        assert_ne!(hit_bits(&Some(other)), hit_bits(&Some(h)));
        assert_eq!(hit_bits(&None), None);
    }
}
