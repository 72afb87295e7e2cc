//! Built-in curves on the CPU backend (guide §5.2, §9.1, §9.3, §9.6, §9.7, §13.7): hits of every
//! round type against an independent f64 reference on random rays (with the error distribution
//! of t and the silhouette miss rate printed), the BVH against brute force, rays from inside,
//! end caps, ribbons, instancing, update, compaction, save and load, and the pipeline (any-hit,
//! closest-hit, primitive-type flags) with Rust programs and a CUDA C++ program.

use glam::{DVec3, Vec3};
use oxray_bvh::{CurveSegment, GasData};
use oxray_core::{
    BuildError, BuildFlags, BuildOperation, BuildOptions, CurveEndcaps, CurveInput, CurveType,
    DeviceContext, ExceptionCode, HitKind, Instance, PipelineCompileOptions, PipelineLinkOptions,
    PrimitiveType, PrimitiveTypeFlags, Ray, SbtRegion, ShaderBindingTable, Transform,
    TraversableHandle,
};
use oxray_cpu::{
    Gas, HitGroupDesc, Ias, Isa, Module, OutputBuffer, Pipeline, ProgramGroup, TraceRay,
};
use oxray_testkit::oracle::hit_bits;
use oxray_testkit::rng::Rng;

/// Control points, radii and segment starts of a curve input, as its byte buffers.
struct Strands {
    ty: CurveType,
    points: Vec<[f32; 3]>,
    radii: Vec<f32>,
    index: Vec<u32>,
}

impl Strands {
    /// `n` independent one-segment strands of `ty`: gently bent, about one unit long, radii
    /// between `rmin` and `rmax`, in a box of half-size `extent`.
    fn random(rng: &mut Rng, ty: CurveType, n: usize, extent: f32, rmin: f32, rmax: f32) -> Self {
        let k = ty.control_points();
        let mut s = Strands {
            ty,
            points: Vec::new(),
            radii: Vec::new(),
            index: Vec::new(),
        };
        for _ in 0..n {
            s.index.push(s.points.len() as u32);
            let base = rng.vec3(-extent, extent);
            let dir = rng.dir() * 0.4;
            for j in 0..k {
                let p = base + dir * j as f32 + rng.vec3(-0.08, 0.08);
                s.points.push(p.to_array());
                s.radii.push(rng.range(rmin, rmax));
            }
        }
        s
    }

    /// One input over all of it (`keys` must outlive it).
    fn input<'a>(&'a self, keys: &'a ([&'a [u8]; 1], [&'a [u8]; 1])) -> CurveInput<'a> {
        CurveInput::new(
            self.ty,
            &keys.0,
            self.points.len() as u32,
            &keys.1,
            bytemuck::cast_slice(&self.index),
            self.index.len() as u32,
        )
    }

    fn keys(&self) -> ([&[u8]; 1], [&[u8]; 1]) {
        (
            [bytemuck::cast_slice(&self.points)],
            [bytemuck::cast_slice(&self.radii)],
        )
    }

    fn build(&self, flags: BuildFlags) -> Gas {
        let keys = self.keys();
        Gas::build(&BuildOptions::new(flags), &[self.input(&keys).into()]).unwrap()
    }

    /// Centre and radius of segment `i` at `u`, from the basis functions of each type written
    /// out (not the power basis the intersector uses), in f64.
    fn eval(&self, i: usize, u: f64) -> (DVec3, f64) {
        let w: [f64; 4] = match self.ty {
            CurveType::RoundLinear => [1.0 - u, u, 0.0, 0.0],
            CurveType::RoundQuadraticBSpline
            | CurveType::RoundQuadraticBSplineRocaps
            | CurveType::FlatQuadraticBSpline => [
                0.5 * (1.0 - u) * (1.0 - u),
                0.5 * (-2.0 * u * u + 2.0 * u + 1.0),
                0.5 * u * u,
                0.0,
            ],
            CurveType::RoundCubicBSpline | CurveType::RoundCubicBSplineRocaps => [
                (1.0 - u).powi(3) / 6.0,
                (3.0 * u.powi(3) - 6.0 * u * u + 4.0) / 6.0,
                (-3.0 * u.powi(3) + 3.0 * u * u + 3.0 * u + 1.0) / 6.0,
                u.powi(3) / 6.0,
            ],
            CurveType::RoundCatmullRom | CurveType::RoundCatmullRomRocaps => [
                0.5 * (-u.powi(3) + 2.0 * u * u - u),
                0.5 * (3.0 * u.powi(3) - 5.0 * u * u + 2.0),
                0.5 * (-3.0 * u.powi(3) + 4.0 * u * u + u),
                0.5 * (u.powi(3) - u * u),
            ],
            CurveType::RoundCubicBezier | CurveType::RoundCubicBezierRocaps => [
                (1.0 - u).powi(3),
                3.0 * u * (1.0 - u).powi(2),
                3.0 * u * u * (1.0 - u),
                u.powi(3),
            ],
        };
        let start = self.index[i] as usize;
        let mut c = DVec3::ZERO;
        let mut r = 0.0;
        for (k, wk) in w.iter().enumerate().take(self.ty.control_points()) {
            c += Vec3::from(self.points[start + k]).as_dvec3() * *wk;
            r += self.radii[start + k] as f64 * wk;
        }
        (c, r)
    }
}

/// What the reference finds for one segment.
#[derive(Clone, Copy, Debug)]
struct RefHit {
    t: f64,
    u: f64,
}

/// The reference for segment `i`: the first entry `min_u t₀(u)` into the union of the spheres
/// `S(u)` (the swept-sphere surface), by dense sampling of `u` and golden-section refinement,
/// in f64. `None` when the line misses every sphere; the grazing measure either way.
fn reference(s: &Strands, i: usize, o: Vec3, d: Vec3) -> (Option<RefHit>, f64) {
    let (o, d) = (o.as_dvec3(), d.as_dvec3());
    let dl = d.length();
    let dn = d / dl;
    let t0 = |u: f64| {
        let (c, r) = s.eval(i, u);
        let f = c - o;
        let along = f.dot(dn);
        let perp2 = (f - dn * along).length_squared();
        if perp2 > r * r {
            f64::INFINITY
        } else {
            (along - (r * r - perp2).sqrt()) / dl
        }
    };
    let gap = |u: f64| {
        let (c, r) = s.eval(i, u);
        let f = c - o;
        ((f - dn * f.dot(dn)).length() - r) / r
    };
    const N: usize = 400;
    let argmin = |f: &dyn Fn(f64) -> f64| {
        let mut best = (f64::INFINITY, 0.0);
        for k in 0..=N {
            let u = k as f64 / N as f64;
            let v = f(u);
            if v < best.0 {
                best = (v, u);
            }
        }
        let (mut lo, mut hi) = (
            (best.1 - 1.0 / N as f64).max(0.0),
            (best.1 + 1.0 / N as f64).min(1.0),
        );
        for _ in 0..100 {
            let (a, b) = (lo + (hi - lo) * 0.382, lo + (hi - lo) * 0.618);
            if f(a) <= f(b) {
                hi = b;
            } else {
                lo = a;
            }
        }
        let u = 0.5 * (lo + hi);
        // The ends themselves, where a minimum at the boundary is.
        [(f(u), u), (f(0.0), 0.0), (f(1.0), 1.0), best]
            .into_iter()
            .fold((f64::INFINITY, 0.0), |m, x| if x.0 < m.0 { x } else { m })
    };
    let (g, _) = argmin(&gap);
    let (t, u) = argmin(&t0);
    let hit = t.is_finite().then_some(RefHit { t, u });
    (hit, g)
}

/// §9.3, §9.6, §9.7: every round curve type's hits (through the BVH) against the f64
/// reference on random rays, half of them aimed at silhouettes. Rays whose reference entry is
/// at a segment's open end (where a ray enters an open tube and hits nothing) are left out for
/// the types without round caps. Prints the distribution of the relative t error and the rate
/// of misses and false hits near silhouettes; asserts that away from silhouettes (1e-3 of the
/// radius) every hit matches within 1e-5 relative, and that disagreements stay below 1 %.
#[test]
fn s9_3_round_curves_match_an_f64_reference_on_random_rays() {
    let mut rng = Rng::new(0x93);
    for ty in CurveType::ALL.into_iter().filter(|t| !t.is_ribbon()) {
        let strands = Strands::random(&mut rng, ty, 150, 2.0, 0.02, 0.12);
        let gas = strands.build(BuildFlags::empty());
        let segs: Vec<CurveSegment> = (0..strands.index.len())
            .map(|i| {
                let start = strands.index[i] as usize;
                let pts: Vec<[f32; 4]> = (0..ty.control_points())
                    .map(|k| {
                        let p = strands.points[start + k];
                        [p[0], p[1], p[2], strands.radii[start + k]]
                    })
                    .collect();
                CurveSegment::new(ty, &pts, 0, None)
            })
            .collect();
        let mut errors = Vec::new();
        let (mut near_sil, mut misses, mut false_hits, mut skipped) = (0, 0, 0, 0);
        let rays = 2500;
        for k in 0..rays {
            let o = rng.dir() * 7.0;
            let target = if k % 2 == 0 {
                rng.vec3(-2.2, 2.2)
            } else {
                // Near a silhouette: off the centre line by about the radius.
                let i = rng.below(segs.len());
                let u = rng.range(0.05, 0.95) as f64;
                let (c, r) = strands.eval(i, u);
                let side = (c.as_vec3() - o).cross(rng.unit()).normalize();
                c.as_vec3() + side * (r as f32) * rng.range(0.97, 1.03)
            };
            let d = (target - o) * rng.range(0.5, 2.0);
            let ray = Ray::new(o, d);
            // Brute force over the segments: the reference and the intersector itself.
            let mut want: Option<(RefHit, usize)> = None;
            let mut grazing = f64::INFINITY;
            let mut brute: Option<(f32, usize)> = None;
            for (i, seg) in segs.iter().enumerate() {
                if let Some(h) = seg.intersect(o, d, 0.0, f32::INFINITY) {
                    if brute.is_none_or(|b| h.t < b.0) {
                        brute = Some((h.t, i));
                    }
                }
                if !ray_meets_box(o, d, &seg.bounds()) {
                    continue;
                }
                let (h, g) = reference(&strands, i, o, d);
                grazing = grazing.min(g.abs());
                if let Some(h) = h {
                    if h.t >= 0.0 && want.is_none_or(|w| h.t < w.0.t) {
                        want = Some((h, i));
                    }
                }
            }
            let got = gas.intersect(&ray);
            // The BVH finds what brute force over the same test finds.
            assert_eq!(got.map(|h| h.t), brute.map(|b| b.0), "{ty}: {ray:?}");
            let open_end = want.is_some_and(|(w, _)| {
                ty != CurveType::RoundLinear && (w.u < 1e-4 || w.u > 1.0 - 1e-4)
            });
            if open_end {
                skipped += 1;
                continue;
            }
            let sil = grazing < 1e-3;
            near_sil += sil as usize;
            match (got, want) {
                (Some(h), Some((w, i))) => {
                    assert!(
                        matches!(h.hit_kind.primitive_type(), PrimitiveType::Curve(t) if t == ty)
                    );
                    assert!(h.hit_kind.is_front_face(), "round curves hit front faces");
                    let err = (h.t as f64 - w.t).abs() / w.t;
                    if !sil {
                        assert!(err < 1e-5, "{ty}: t {} vs {} ({ray:?})", h.t, w.t);
                        if h.primitive_index as usize == i {
                            assert!(
                                (h.u as f64 - w.u).abs() < 2e-3,
                                "{ty}: u {} vs {}",
                                h.u,
                                w.u
                            );
                        }
                    }
                    errors.push(err);
                }
                (None, None) => {}
                (Some(h), None) => {
                    assert!(
                        sil,
                        "{ty}: a false hit away from silhouettes: {ray:?} {h:?}"
                    );
                    false_hits += 1;
                }
                (None, Some((w, i))) => {
                    assert!(
                        sil,
                        "{ty}: a miss away from silhouettes: {ray:?} {w:?} {:?}",
                        segs[i]
                    );
                    misses += 1;
                }
            }
        }
        errors.sort_by(f64::total_cmp);
        let q = |p: f64| errors[((errors.len() - 1) as f64 * p) as usize];
        println!(
            "{ty}: {rays} rays, {} hits; relative t error median {:.1e}, p99 {:.1e}, max {:.1e}; \
             {near_sil} rays within 1e-3 r of a silhouette: {misses} misses, {false_hits} false \
             hits; {skipped} rays entering an open end left out",
            errors.len(),
            q(0.5),
            q(0.99),
            q(1.0),
        );
        assert!(errors.len() > 300, "{ty}: {} hits", errors.len());
        assert!(misses + false_hits <= rays / 100, "{ty}");
    }
}

/// A slab test of the ray's line (t >= 0) against a box.
fn ray_meets_box(o: Vec3, d: Vec3, b: &oxray_core::Aabb) -> bool {
    let inv = d.recip();
    let (t1, t2) = ((b.min - o) * inv, (b.max - o) * inv);
    let lo = t1.min(t2).max_element().max(0.0);
    let hi = t1.max(t2).min_element();
    lo <= hi
}

/// One straight segment of `ty` along +x from 0 to 4 (its centre line, for every basis: the
/// control points are spread along the line so that each type's curve covers [0, 4]) with
/// radius 0.5.
fn straight(ty: CurveType, endcaps: CurveEndcaps) -> Gas {
    let (points, n): (Vec<[f32; 3]>, usize) = match ty.control_points() {
        2 => (vec![[0.0, 0.0, 0.0], [4.0, 0.0, 0.0]], 2),
        3 => (vec![[-2.0, 0.0, 0.0], [2.0, 0.0, 0.0], [6.0, 0.0, 0.0]], 3),
        _ => match ty {
            CurveType::RoundCubicBezier | CurveType::RoundCubicBezierRocaps => (
                vec![
                    [0.0, 0.0, 0.0],
                    [4.0 / 3.0, 0.0, 0.0],
                    [8.0 / 3.0, 0.0, 0.0],
                    [4.0, 0.0, 0.0],
                ],
                4,
            ),
            CurveType::RoundCatmullRom | CurveType::RoundCatmullRomRocaps => (
                vec![
                    [-4.0, 0.0, 0.0],
                    [0.0, 0.0, 0.0],
                    [4.0, 0.0, 0.0],
                    [8.0, 0.0, 0.0],
                ],
                4,
            ),
            _ => (
                vec![
                    [-4.0, 0.0, 0.0],
                    [0.0, 0.0, 0.0],
                    [4.0, 0.0, 0.0],
                    [8.0, 0.0, 0.0],
                ],
                4,
            ),
        },
    };
    let radii = vec![0.5f32; n];
    let index = [0u32];
    let v = [bytemuck::cast_slice::<_, u8>(&points)];
    let r = [bytemuck::cast_slice::<_, u8>(&radii)];
    let input =
        CurveInput::new(ty, &v, n as u32, &r, bytemuck::cast_slice(&index), 1).endcaps(endcaps);
    Gas::build(&BuildOptions::default(), &[input.into()]).unwrap()
}

/// §9.3, §5.2: on a straight tube, a ray across it hits at the radius with `u` where it
/// crosses; along the axis, an open end (the default of non-linear types) lets the ray into the
/// hollow tube (no hit), a flat cap (`OPTIX_CURVE_ENDCAP_ON`) is hit with `u` exactly 0 or 1,
/// and a linear curve's round cap is hit at the sphere's pole with `u` exactly 0 or 1.
#[test]
fn s9_3_end_caps_and_the_curve_parameter_on_a_straight_tube() {
    for ty in CurveType::ALL.into_iter().filter(|t| !t.is_ribbon()) {
        let caps = if ty == CurveType::RoundLinear {
            vec![CurveEndcaps::Default]
        } else {
            vec![CurveEndcaps::Default, CurveEndcaps::On]
        };
        for endcaps in caps {
            let gas = straight(ty, endcaps);
            // Across, at x = 1: t = 10 - 0.5, u = 1/4.
            let h = gas
                .intersect(&Ray::new(Vec3::new(1.0, 0.0, -10.0), Vec3::Z))
                .unwrap_or_else(|| panic!("{ty}"));
            assert!(
                (h.t - 9.5).abs() < 1e-5 && (h.u - 0.25).abs() < 1e-5,
                "{ty}: {h:?}"
            );
            assert_eq!(h.hit_kind, HitKind::curve(ty, false));
            // Along the axis, from either side.
            for (o, d, u, t) in [
                (Vec3::new(-10.0, 0.1, 0.0), Vec3::X, 0.0, 10.0),
                (Vec3::new(14.0, 0.1, 0.0), -Vec3::X, 1.0, 10.0),
            ] {
                let got = gas.intersect(&Ray::new(o, d));
                match (ty, endcaps) {
                    (CurveType::RoundLinear, _) => {
                        let h = got.unwrap();
                        assert_eq!(h.u, u, "{ty}: a round cap's u");
                        // The sphere of radius 0.5 at the end, 0.1 off its axis.
                        let want = t - (0.25f32 - 0.01).sqrt();
                        assert!((h.t - want).abs() < 1e-5, "{ty}: {h:?} vs {want}");
                    }
                    (_, CurveEndcaps::Default) => {
                        assert_eq!(got, None, "{ty}: an open end lets the ray in")
                    }
                    (_, CurveEndcaps::On) => {
                        let h = got.unwrap();
                        assert_eq!(h.u, u, "{ty}: a flat cap's u is exactly 0 or 1 (§9.3)");
                        assert!((h.t - t).abs() < 1e-5, "{ty}: {h:?}");
                    }
                }
            }
        }
    }
}

/// §9.6: a ray whose interval starts inside a tube does not hit that tube, whatever its
/// direction; from outside the same ray hits.
#[test]
fn s9_6_rays_from_inside_a_tube_do_not_hit_it() {
    for ty in CurveType::ALL.into_iter().filter(|t| !t.is_ribbon()) {
        let gas = straight(ty, CurveEndcaps::Default);
        let mut rng = Rng::new(0x96);
        for _ in 0..200 {
            let inside = Vec3::new(
                rng.range(1.5, 2.5),
                rng.range(-0.3, 0.3),
                rng.range(-0.3, 0.3),
            );
            let d = rng.dir();
            assert_eq!(
                gas.intersect(&Ray::new(inside, d)),
                None,
                "{ty}: {inside} {d}"
            );
            // The same line from outside, behind: it enters the tube (through its side where
            // the line is steep enough to pass the ends well away from the axis).
            let outside = inside - d * 20.0;
            let h = gas.intersect(&Ray::new(outside, d));
            if d.x.abs() < 0.3 {
                assert!(h.is_some(), "{ty}: {outside} {d}");
            }
            // An interval that starts inside (tmin past the entry) does not hit either.
            let h = gas.intersect(&Ray::with_interval(outside, d, 20.0, f32::INFINITY));
            assert_eq!(h, None, "{ty}");
        }
    }
}

/// §9.3: ribbons report (u, v), v ∈ [-1, 1] across the ribbon; with normals the ribbon is the
/// ruled surface spanned by n × c', with a front and a back face; without, it faces the ray.
#[test]
fn s9_3_ribbons_report_u_and_v_and_their_faces() {
    // A straight ribbon along +x from 0 to 4 (quadratic B-spline control points), half-width
    // 0.5, normals +z: it lies in the plane z = 0, spanning y ∈ [-0.5, 0.5].
    let points = [[-2.0f32, 0.0, 0.0], [2.0, 0.0, 0.0], [6.0, 0.0, 0.0]];
    let radii = [0.5f32; 3];
    let normals = [[0.0f32, 0.0, 1.0]; 3];
    let index = [0u32];
    let v = [bytemuck::cast_slice::<_, u8>(&points)];
    let r = [bytemuck::cast_slice::<_, u8>(&radii)];
    let n = [bytemuck::cast_slice::<_, u8>(&normals)];
    let ty = CurveType::FlatQuadraticBSpline;
    let oriented = CurveInput::new(ty, &v, 3, &r, bytemuck::cast_slice(&index), 1).normals(&n, 0);
    let gas = Gas::build(&BuildOptions::default(), &[oriented.into()]).unwrap();
    let from_above = gas
        .intersect(&Ray::new(Vec3::new(1.0, 0.25, 5.0), -Vec3::Z))
        .unwrap();
    assert!((from_above.t - 5.0).abs() < 1e-5, "{from_above:?}");
    assert!((from_above.u - 0.25).abs() < 1e-5 && (from_above.v.abs() - 0.5).abs() < 1e-5);
    let from_below = gas
        .intersect(&Ray::new(Vec3::new(1.0, 0.25, -5.0), Vec3::Z))
        .unwrap();
    assert_eq!(from_below.v, from_above.v, "v is a place on the ribbon");
    // One side is the front face, the other the back face.
    assert_ne!(from_above.hit_kind, from_below.hit_kind);
    assert_eq!(
        from_above.hit_kind.primitive_type(),
        PrimitiveType::Curve(ty)
    );
    assert_eq!(
        from_above.hit_kind.is_front_face(),
        from_below.hit_kind.is_back_face()
    );
    // Past the ribbon's width: no hit; edge-on: no hit either (a ruled surface has no depth).
    assert_eq!(
        gas.intersect(&Ray::new(Vec3::new(1.0, 0.6, 5.0), -Vec3::Z)),
        None
    );
    // Without normals the ribbon turns to face the ray: hit from the side too.
    let facing = CurveInput::new(ty, &v, 3, &r, bytemuck::cast_slice(&index), 1);
    let gas = Gas::build(&BuildOptions::default(), &[facing.into()]).unwrap();
    for d in [Vec3::Z, Vec3::Y, Vec3::new(0.0, 1.0, 1.0).normalize()] {
        let h = gas.intersect(&Ray::new(
            Vec3::new(1.0, 0.0, 0.0) - d * 5.0 + d.cross(Vec3::X) * 0.25,
            d,
        ));
        let h = h.unwrap_or_else(|| panic!("{d}"));
        assert!(
            (h.t - 5.0).abs() < 1e-4 && (h.v.abs() - 0.5).abs() < 1e-4,
            "{d}: {h:?}"
        );
        assert!(
            h.hit_kind.is_front_face(),
            "a ribbon that faces the ray shows its front"
        );
    }
}

/// §9.1: curves in an IAS with non-uniform instance transforms (elliptical cross-sections):
/// each hit equals the hit of the object-space ray on the GAS.
#[test]
fn s9_1_curves_in_an_ias_with_transforms() {
    let mut rng = Rng::new(0x91c);
    let strands = Strands::random(&mut rng, CurveType::RoundCubicBSpline, 200, 1.5, 0.03, 0.1);
    let gas = strands.build(BuildFlags::empty());
    let handle: TraversableHandle = strands.build(BuildFlags::empty()).into();
    let transforms: Vec<Transform> = (0..5)
        .map(|i| {
            Transform::from_affine(&glam::Affine3A::from_scale_rotation_translation(
                Vec3::new(1.0 + 0.3 * i as f32, 0.6, 1.2),
                rng.rotation(),
                Vec3::new(i as f32 * 6.0 - 12.0, 0.0, 0.0),
            ))
        })
        .collect();
    let instances: Vec<Instance> = transforms
        .iter()
        .enumerate()
        .map(|(i, t)| {
            Instance::new(handle.clone())
                .transform(*t)
                .instance_id(i as u32)
        })
        .collect();
    let ias = Ias::build(&BuildOptions::default(), &[(&instances[..]).into()]).unwrap();
    let mut hits = 0;
    for _ in 0..2000 {
        let o = Vec3::new(rng.range(-16.0, 16.0), rng.range(-3.0, 3.0), -10.0);
        let d = Vec3::new(rng.range(-0.2, 0.2), rng.range(-0.2, 0.2), 1.0);
        let got = ias.intersect(&Ray::new(o, d));
        let mut want: Option<(f32, u32, u32)> = None;
        for (k, t) in transforms.iter().enumerate() {
            let w2o = t.inverse().unwrap();
            let ray = Ray::new(w2o.transform_point(o), w2o.transform_vector(d));
            if let Some(h) = gas.intersect(&ray) {
                if want.is_none_or(|w| h.t < w.0) {
                    want = Some((h.t, k as u32, h.primitive_index));
                }
            }
        }
        match (got, want) {
            (Some(h), Some((t, id, prim))) => {
                hits += 1;
                assert!((h.t - t).abs() <= 1e-4 * t, "{h:?} vs {t}");
                if (h.t - t).abs() <= 1e-6 * t {
                    assert_eq!((h.instance_id, h.primitive_index), (id, prim));
                }
            }
            (None, None) => {}
            (g, w) => panic!("{o} {d}: {g:?} vs {w:?}"),
        }
    }
    assert!(hits > 100, "{hits}");
}

/// §5.2, §9.8: validation errors (motion keys, normals on a round type, caps on linear
/// curves, indices past the vertices) and inactive segments (a non-positive radius: skipped).
#[test]
fn s5_2_curve_inputs_are_validated_and_bad_segments_are_inactive() {
    let points = [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [2.0, 0.0, 0.0],
        [3.0, 0.0, 0.0],
    ];
    let radii = [0.1f32, 0.1, -0.2, -0.2];
    let index = [0u32, 2];
    let v = [bytemuck::cast_slice::<_, u8>(&points)];
    let r = [bytemuck::cast_slice::<_, u8>(&radii)];
    let ix = bytemuck::cast_slice::<_, u8>(&index);
    let linear = CurveInput::new(CurveType::RoundLinear, &v, 4, &r, ix, 2);
    let gas = Gas::build(&BuildOptions::default(), &[linear.into()]).unwrap();
    assert_eq!((gas.num_primitives(), gas.num_active_primitives()), (2, 1));
    let err = Gas::build(
        &BuildOptions::default(),
        &[linear.endcaps(CurveEndcaps::On).into()],
    )
    .unwrap_err();
    assert!(matches!(err, BuildError::InvalidCurveInput { .. }), "{err}");
    let bad = [0u32, 3];
    let err = Gas::build(
        &BuildOptions::default(),
        &[CurveInput::new(
            CurveType::RoundLinear,
            &v,
            4,
            &r,
            bytemuck::cast_slice(&bad),
            2,
        )
        .into()],
    )
    .unwrap_err();
    assert!(
        matches!(
            err,
            BuildError::CurveIndexOutOfRange {
                segment: 1,
                index: 3,
                ..
            }
        ),
        "{err}"
    );
    let two = [v[0], v[0]];
    let err = Gas::build(
        &BuildOptions::default(),
        &[CurveInput::new(CurveType::RoundLinear, &two, 4, &r, ix, 2).into()],
    )
    .unwrap_err();
    assert!(
        matches!(err, BuildError::MotionKeyCount { given: 2, .. }),
        "{err}"
    );
    let err = Gas::build(&BuildOptions::default(), &[linear.normals(&v, 0).into()]).unwrap_err();
    assert!(matches!(err, BuildError::InvalidCurveInput { .. }), "{err}");
}

/// §5.6, §5.8 and the save format: an update moves the curves as a rebuild would; compaction
/// and a save/load round trip keep every hit bit for bit.
#[test]
fn s5_6_update_compaction_and_save_load_of_a_curve_gas() {
    let mut rng = Rng::new(0x56c);
    let a = Strands::random(&mut rng, CurveType::RoundCatmullRom, 300, 2.0, 0.02, 0.1);
    let mut b = Strands::random(&mut rng, CurveType::RoundCatmullRom, 300, 2.0, 0.02, 0.1);
    b.index = a.index.clone();
    let flags = BuildFlags::ALLOW_UPDATE | BuildFlags::ALLOW_COMPACTION;
    let mut gas = a.build(flags);
    let keys = b.keys();
    let mut update = BuildOptions::new(flags);
    update.operation = BuildOperation::Update;
    gas.update(&update, &[b.input(&keys).into()]).unwrap();
    let rebuilt = b.build(BuildFlags::empty());
    let compact = Gas::from(gas.data().compact().unwrap());
    let bytes = gas.data().to_bytes();
    let loaded = Gas::from(GasData::from_bytes(&bytes).unwrap());
    assert_eq!(loaded.data().to_bytes(), bytes);
    assert_eq!(loaded.kind(), oxray_core::BuildInputKind::Curves);
    let mut hits = 0;
    for _ in 0..2000 {
        let o = rng.dir() * 6.0;
        let ray = Ray::new(o, rng.vec3(-2.0, 2.0) - o);
        let h = gas.intersect(&ray);
        hits += h.is_some() as usize;
        assert_eq!(hit_bits(&h), hit_bits(&rebuilt.intersect(&ray)));
        assert_eq!(hit_bits(&h), hit_bits(&compact.intersect(&ray)));
        assert_eq!(hit_bits(&h), hit_bits(&loaded.intersect(&ray)));
    }
    assert!(hits > 100, "{hits}");
    // Damaged bytes are refused, never traversed.
    for cut in [1, bytes.len() / 2, bytes.len() - 8] {
        assert!(GasData::from_bytes(&bytes[..cut]).is_err());
    }
}

/// Per launch index: origin, direction.
#[derive(Clone)]
struct Params {
    handle: TraversableHandle,
    rays: Vec<(Vec3, Vec3)>,
    out: std::sync::Arc<OutputBuffer<[u32; 8]>>,
}

const MISS: u32 = 0xDEAD;

fn curve_pipeline(flags: PrimitiveTypeFlags) -> (Pipeline<Params>, ShaderBindingTable) {
    let module = Module::<Params>::new()
        .raygen("__raygen__rg", |ctx| {
            let [x, _, _] = ctx.launch_index();
            let p = ctx.params();
            let (o, d) = p.rays[x as usize];
            let mut payload = [0u32; 8];
            ctx.trace(&TraceRay::new(&p.handle, o, d), &mut payload)?;
            p.out.write(x as usize, payload);
            Ok(())
        })
        .unwrap()
        .any_hit("__anyhit__ah", |ctx| {
            // Counts calls; ignores segment 0 so that a ray through both sees segment 1.
            ctx.set_payload(7, ctx.payload(7) + 1);
            if ctx.primitive_index() == 0 {
                return ctx.ignore_intersection();
            }
            Ok(())
        })
        .unwrap()
        .closest_hit("__closesthit__ch", |ctx| {
            let cp = ctx.curve_vertex_data();
            ctx.set_payload(0, ctx.primitive_index());
            ctx.set_payload_f32(1, ctx.ray_tmax());
            ctx.set_payload(2, ctx.hit_kind().0 as u32);
            ctx.set_payload(3, ctx.primitive_type().code());
            ctx.set_payload_f32(4, ctx.curve_parameter());
            ctx.set_payload_f32(5, cp[1][0]);
            ctx.set_payload_f32(6, cp[1][3]);
            Ok(())
        })
        .unwrap()
        .miss("__miss__ms", |ctx| {
            ctx.set_payload(0, MISS);
            Ok(())
        })
        .unwrap();
    let rg = ProgramGroup::raygen(&module, "__raygen__rg").unwrap();
    let ms = ProgramGroup::miss(Some((&module, "__miss__ms"))).unwrap();
    let hg = ProgramGroup::hit_group(HitGroupDesc {
        closest_hit: Some((&module, "__closesthit__ch")),
        any_hit: Some((&module, "__anyhit__ah")),
        ..Default::default()
    })
    .unwrap();
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &PipelineCompileOptions {
            uses_primitive_type_flags: flags,
            ..Default::default()
        },
        &PipelineLinkOptions { max_trace_depth: 1 },
        &[rg.clone(), ms.clone(), hg.clone()],
    )
    .unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_headers(&[ms.pack_header()]),
        hitgroup: SbtRegion::from_headers(&[hg.pack_header()]),
        ..Default::default()
    };
    (pipeline, sbt)
}

/// Two linear segments along +z, one strand: z ∈ [5, 6] and [6, 7], radius 0.5 at z = 5 and 6,
/// 0.25 at z = 7.
fn two_segments() -> Gas {
    let points = [[0.0f32, 0.0, 5.0], [0.0, 0.0, 6.0], [0.0, 0.0, 7.0]];
    let radii = [0.5f32, 0.5, 0.25];
    let index = [0u32, 1];
    let v = [bytemuck::cast_slice::<_, u8>(&points)];
    let r = [bytemuck::cast_slice::<_, u8>(&radii)];
    let input = CurveInput::new(
        CurveType::RoundLinear,
        &v,
        3,
        &r,
        bytemuck::cast_slice(&index),
        2,
    );
    Gas::build(&BuildOptions::default(), &[input.into()]).unwrap()
}

/// §9.3, §13.2, §13.7: closest-hit and any-hit programs on curves read the hit kind, the
/// primitive type, the curve parameter and the segment's control points; any-hit may ignore a
/// segment. §9.1: without the type's flag the pipeline raises UNSUPPORTED_PRIMITIVE_TYPE.
#[test]
fn s13_7_curve_hits_through_the_pipeline() {
    let gas: TraversableHandle = two_segments().into();
    let (pipeline, sbt) = curve_pipeline(PrimitiveTypeFlags::ROUND_LINEAR);
    let rays = vec![
        // 0: along the axis: segment 0's cap at z = 4.5 is ignored by any-hit; segment 1's
        // round cap (its sphere at z = 6, radius 0.5) is entered at z = 5.5, u = 0.
        (Vec3::ZERO, Vec3::Z),
        // 1: across segment 1 at z = 6.5: the cone tangent to the spheres S(u) is entered
        // where max_s (0.5 - s/4)² - (1/2 - s)² peaks, at s = u = 0.4: t = 10 - √0.15.
        (Vec3::new(0.0, -10.0, 6.5), Vec3::Y),
        // 2: a miss.
        (Vec3::new(3.0, 0.0, 0.0), Vec3::Z),
    ];
    let out = std::sync::Arc::new(OutputBuffer::new(rays.len()));
    let params = Params {
        handle: gas.clone(),
        rays,
        out: out.clone(),
    };
    let report = pipeline.launch(&params, &sbt, 3, 1, 1).unwrap();
    assert_eq!(report.exceptions, 0, "{report:?}");
    let o = out.to_vec();
    let linear = CurveType::RoundLinear;
    let kind = HitKind::curve(linear, false).0 as u32;
    let code = PrimitiveType::Curve(linear).code();
    assert_eq!(o[0][0], 1);
    assert!((f32::from_bits(o[0][1]) - 5.5).abs() < 1e-5);
    assert_eq!(o[0][2..4], [kind, code]);
    assert_eq!(f32::from_bits(o[0][4]), 0.0, "a round cap's u");
    assert_eq!(
        (f32::from_bits(o[0][5]), f32::from_bits(o[0][6])),
        (0.0, 0.25)
    );
    assert!(o[0][7] >= 2, "any-hit ran on both segments");
    assert_eq!(o[1][0], 1);
    assert!((f32::from_bits(o[1][1]) - (10.0 - 0.15f32.sqrt())).abs() < 1e-5);
    assert!((f32::from_bits(o[1][4]) - 0.4).abs() < 1e-5);
    assert_eq!(o[2][0], MISS);

    // §9.1: the flag of another curve type, or none, does not enable linear curves.
    for flags in [
        PrimitiveTypeFlags::empty(),
        PrimitiveTypeFlags::ROUND_CUBIC_BSPLINE | PrimitiveTypeFlags::SPHERE,
    ] {
        let (pipeline, sbt) = curve_pipeline(flags);
        let params = Params {
            handle: gas.clone(),
            rays: vec![(Vec3::ZERO, Vec3::Z)],
            out: std::sync::Arc::new(OutputBuffer::new(1)),
        };
        let report = pipeline.launch(&params, &sbt, 1, 1, 1).unwrap();
        assert_eq!(
            report.first_exceptions[0].1.code,
            ExceptionCode::UNSUPPORTED_PRIMITIVE_TYPE,
            "{flags:?}"
        );
    }
}

/// The kernels of this processor agree bit for bit on curves (the BVH width does not change a
/// hit).
#[test]
fn every_kernel_finds_the_same_curve_hits() {
    let mut rng = Rng::new(0xc4);
    let s = Strands::random(&mut rng, CurveType::RoundCubicBezier, 400, 2.0, 0.02, 0.1);
    let keys = s.keys();
    let gases: Vec<Gas> = Isa::available()
        .into_iter()
        .map(|isa| {
            Gas::build_with_isa(isa, &BuildOptions::default(), &[s.input(&keys).into()]).unwrap()
        })
        .collect();
    for _ in 0..1000 {
        let o = rng.dir() * 6.0;
        let ray = Ray::new(o, rng.vec3(-2.0, 2.0) - o);
        let first = hit_bits(&gases[0].intersect(&ray));
        for g in &gases[1..] {
            assert_eq!(hit_bits(&g.intersect(&ray)), first);
        }
    }
}

/// §9.3, §13.7 with a CUDA C++ program run on the CPU backend: `optixGetCurveParameter`,
/// `optixGetLinearCurveVertexData`, `optixGetPrimitiveType`, `optixIsFrontFaceHit`.
#[cfg(unix)]
#[test]
fn s9_3_a_cuda_cpp_program_reads_the_curve() {
    use oxray_cpu::cxx::{CxxHitGroupDesc, CxxModule, CxxPipeline, CxxProgramGroup, HostBuffer};
    const SRC: &str = r#"
#include <optix.h>
struct Params { float* out; OptixTraversableHandle handle; };
extern "C" __constant__ Params params;
extern "C" __global__ void __raygen__main() {
    unsigned int p[8] = {0, 0, 0, 0, 0, 0, 0, 0};
    optixTrace(params.handle, make_float3(0.0f, -10.0f, 6.5f), make_float3(0.0f, 1.0f, 0.0f),
               0.0f, 100.0f, 0.0f, 255u, 0u, 0u, 1u, 0u,
               p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7]);
    for (int k = 0; k < 8; ++k) params.out[k] = __uint_as_float(p[k]);
}
extern "C" __global__ void __closesthit__ch() {
    float4 v[2];
    optixGetLinearCurveVertexData(v);
    optixSetPayload_0(__float_as_uint(optixGetCurveParameter()));
    optixSetPayload_1(optixGetPrimitiveType() == OPTIX_PRIMITIVE_TYPE_ROUND_LINEAR ? 1u : 0u);
    optixSetPayload_2(optixIsFrontFaceHit() ? 1u : 0u);
    optixSetPayload_3(__float_as_uint(v[0].z));
    optixSetPayload_4(__float_as_uint(v[1].w));
    optixSetPayload_5(optixGetPrimitiveIndex());
    optixSetPayload_6(__float_as_uint(optixGetRayTmax()));
}
extern "C" __global__ void __miss__ms() { optixSetPayload_0(0xDEADu); }
"#;
    let module = CxxModule::from_source(SRC);
    let rg = CxxProgramGroup::raygen(&module, "__raygen__main").unwrap();
    let ms = CxxProgramGroup::miss(Some((&module, "__miss__ms"))).unwrap();
    let hg = CxxProgramGroup::hit_group(CxxHitGroupDesc {
        closest_hit: Some((&module, "__closesthit__ch")),
        ..Default::default()
    })
    .unwrap();
    let pipeline = CxxPipeline::new(
        &DeviceContext::default(),
        &PipelineCompileOptions {
            uses_primitive_type_flags: PrimitiveTypeFlags::ROUND_LINEAR,
            ..Default::default()
        },
        &PipelineLinkOptions::default(),
        Some("params"),
        &[rg.clone(), ms.clone(), hg.clone()],
    )
    .unwrap();
    let gas: TraversableHandle = two_segments().into();
    let out = HostBuffer::<f32>::zeroed(8);
    #[repr(C)]
    #[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
    struct CParams {
        out: u64,
        handle: u64,
    }
    let params = CParams {
        out: out.device_ptr(),
        handle: oxray_cpu::cxx::optix_handle(&gas),
    };
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_headers(&[ms.pack_header()]),
        hitgroup: SbtRegion::from_headers(&[hg.pack_header()]),
        ..Default::default()
    };
    let report = pipeline.launch_with(&params, &sbt, 1, 1, 1).unwrap();
    assert_eq!(report.exceptions, 0, "{report:?}");
    let o: Vec<u32> = out.download().iter().map(|f| f.to_bits()).collect();
    assert!((f32::from_bits(o[0]) - 0.4).abs() < 1e-5, "u");
    assert_eq!(o[1..3], [1, 1]);
    assert_eq!((f32::from_bits(o[3]), f32::from_bits(o[4])), (6.0, 0.25));
    assert_eq!(o[5], 1);
    assert!((f32::from_bits(o[6]) - (10.0 - 0.15f32.sqrt())).abs() < 1e-5);
}

/// §9.2 (splitting curve segments): a build may reference a long segment from several leaves,
/// each bounded by a piece of its parameter interval; every reference intersects the whole
/// segment, so the closest hits of split builds (the default, `PREFER_FAST_TRACE`'s higher and
/// `PREFER_FAST_BUILD`'s lower splitting factor) are those of an unsplit build, bit for bit, on
/// random rays, for every curve type; and a split structure saves and loads.
#[test]
fn s9_2_split_and_unsplit_builds_give_identical_closest_hits() {
    let mut rng = Rng::new(0x92);
    for ty in CurveType::ALL {
        // Thin segments (radius 0.004 to 0.03, about 0.4 to 1.2 long) are split.
        let s = Strands::random(&mut rng, ty, 300, 1.5, 0.004, 0.03);
        let keys = s.keys();
        let inputs = [s.input(&keys).into()];
        let plain = BuildOptions::default();
        let unsplit = GasData::build_with_curve_splits(&plain, &inputs, None).unwrap();
        assert_eq!(unsplit.num_references(), unsplit.num_active_primitives());
        let unsplit = Gas::from(unsplit);
        let mut split = Vec::new();
        for flags in [
            BuildFlags::empty(),
            BuildFlags::PREFER_FAST_TRACE,
            BuildFlags::PREFER_FAST_BUILD,
        ] {
            let gas = Gas::build(&BuildOptions::new(flags), &inputs).unwrap();
            let d = gas.data();
            assert_eq!(d.num_active_primitives(), unsplit.num_active_primitives());
            assert!(
                d.num_references() > d.num_active_primitives(),
                "{ty} {flags:?}: {} references",
                d.num_references()
            );
            // §9.2: splitting costs memory; the memory query (§5) still bounds it.
            let sizes =
                oxray_bvh::compute_memory_usage(&BuildOptions::new(flags), &inputs).unwrap();
            assert!(
                d.memory().output_bytes <= sizes.output_size_in_bytes,
                "{ty} {flags:?}: {} > {}",
                d.memory().output_bytes,
                sizes.output_size_in_bytes
            );
            split.push(gas);
        }
        let (fast_trace, fast_build) = (split[1].data(), split[2].data());
        assert!(fast_trace.num_references() > fast_build.num_references());
        let loaded = Gas::from(GasData::from_bytes(&split[0].data().to_bytes()).unwrap());
        split.push(loaded);
        let mut hits = 0;
        for _ in 0..3000 {
            let o = rng.dir() * 5.0;
            let ray = Ray::new(o, rng.vec3(-1.5, 1.5) - o);
            let h = unsplit.intersect(&ray);
            hits += h.is_some() as usize;
            for g in &split {
                assert_eq!(hit_bits(&g.intersect(&ray)), hit_bits(&h), "{ty}");
            }
        }
        assert!(hits > 150, "{ty}: {hits}");
    }
}

/// §9.2, §5.1: segments of a `REQUIRE_SINGLE_ANYHIT_CALL` record, and every segment of an
/// `ALLOW_UPDATE` build, are not split: one leaf slot per segment, and an any-hit program that
/// ignores every hit runs exactly once per segment the ray crosses (counted by brute force).
/// A split build may run it more than once per segment, as the guide allows.
#[test]
fn s9_2_single_anyhit_and_updatable_builds_are_not_split() {
    let mut rng = Rng::new(0x921);
    let s = Strands::random(
        &mut rng,
        CurveType::RoundCubicBSpline,
        200,
        1.0,
        0.005,
        0.02,
    );
    let keys = s.keys();
    let single = s
        .input(&keys)
        .flag(oxray_core::GeometryFlags::REQUIRE_SINGLE_ANYHIT_CALL);
    let builds = [
        (BuildFlags::PREFER_FAST_TRACE, single.into(), true),
        (BuildFlags::ALLOW_UPDATE, s.input(&keys).into(), true),
        (BuildFlags::empty(), s.input(&keys).into(), false),
    ];
    let module = Module::<Params>::new()
        .raygen("__raygen__rg", |ctx| {
            let [x, _, _] = ctx.launch_index();
            let p = ctx.params();
            let (o, d) = p.rays[x as usize];
            let mut payload = [0u32; 8];
            ctx.trace(&TraceRay::new(&p.handle, o, d), &mut payload)?;
            p.out.write(x as usize, payload);
            Ok(())
        })
        .unwrap()
        .any_hit("__anyhit__count", |ctx| {
            ctx.set_payload(0, ctx.payload(0) + 1);
            ctx.ignore_intersection()
        })
        .unwrap()
        .miss("__miss__ms", |_| Ok(()))
        .unwrap();
    let rg = ProgramGroup::raygen(&module, "__raygen__rg").unwrap();
    let ms = ProgramGroup::miss(Some((&module, "__miss__ms"))).unwrap();
    let hg = ProgramGroup::hit_group(HitGroupDesc {
        any_hit: Some((&module, "__anyhit__count")),
        ..Default::default()
    })
    .unwrap();
    let pipeline = Pipeline::new(
        &DeviceContext::new(),
        &PipelineCompileOptions {
            uses_primitive_type_flags: PrimitiveTypeFlags::ROUND_CUBIC_BSPLINE,
            ..Default::default()
        },
        &PipelineLinkOptions { max_trace_depth: 1 },
        &[rg.clone(), ms.clone(), hg.clone()],
    )
    .unwrap();
    let sbt = ShaderBindingTable {
        raygen: SbtRegion::from_headers(&[rg.pack_header()]),
        miss: SbtRegion::from_headers(&[ms.pack_header()]),
        hitgroup: SbtRegion::from_headers(&[hg.pack_header()]),
        ..Default::default()
    };
    let rays: Vec<(Vec3, Vec3)> = (0..2000)
        .map(|_| {
            let o = rng.dir() * 4.0;
            (o, rng.vec3(-1.0, 1.0) - o)
        })
        .collect();
    for (flags, input, whole) in builds {
        let gas = Gas::build(&BuildOptions::new(flags), &[input]).unwrap();
        let d = gas.data();
        assert_eq!(
            d.num_references() == d.num_active_primitives(),
            whole,
            "{flags:?}"
        );
        // Brute force over the distinct segments: those the ray crosses.
        let mut segments: Vec<(u32, CurveSegment)> = d
            .slot_prim
            .iter()
            .zip(&d.curves)
            .map(|(&g, &c)| (g, c))
            .collect();
        segments.sort_by_key(|&(g, _)| g);
        segments.dedup_by_key(|&mut (g, _)| g);
        let out = std::sync::Arc::new(OutputBuffer::new(rays.len()));
        let params = Params {
            handle: TraversableHandle::from(gas),
            rays: rays.clone(),
            out: out.clone(),
        };
        let report = pipeline
            .launch(&params, &sbt, rays.len() as u32, 1, 1)
            .unwrap();
        assert_eq!(report.exceptions, 0, "{report:?}");
        let (mut crossed, mut repeated) = (0, 0);
        for ((o, dir), payload) in rays.iter().zip(out.to_vec()) {
            let n = segments
                .iter()
                .filter(|(_, c)| c.intersect(*o, *dir, 0.0, f32::INFINITY).is_some())
                .count() as u32;
            crossed += n;
            if whole {
                assert_eq!(payload[0], n, "{flags:?}: any-hit once per segment");
            } else {
                assert!(payload[0] >= n, "{flags:?}");
                repeated += payload[0] - n;
            }
        }
        assert!(crossed > 200, "{crossed}");
        if !whole {
            assert!(repeated > 0, "a split build meets some segments twice");
        }
    }
}
