//! Property tests: the BVH must return exactly what a brute-force loop over every primitive
//! returns — the same closest distance bit for bit (guide §13.2: the closest hit in the closed
//! interval `[tmin, tmax]`), the same barycentrics and facing (§13.7), and the same occlusion —
//! for triangle soups (§5.1, triangle build input) and custom primitives (§5.1, custom-primitive
//! build input), whatever the build flags (§5.5).

mod common;

use common::{check_closest, reference_closest, reference_hits, Tri};
use glam::Vec3;
use oxray::cpu::Gas;
use oxray::{
    Aabb, AabbBuffer, BuildFlags, BuildOptions, CustomHit, CustomPrimitive, CustomPrimitiveInput,
    HitKind, Ray, TriangleInput, VertexBuffer,
};
use proptest::prelude::*;

// ---------------------------------------------------------------------------------------------
// Strategies
// ---------------------------------------------------------------------------------------------

/// A coordinate: either free, or on a coarse grid so that vertices, edges and planes coincide
/// (shared vertices, axis-aligned and coplanar triangles, exact ties).
fn coord() -> impl Strategy<Value = f32> {
    prop_oneof![-1.0f32..1.0, (-4i32..=4).prop_map(|i| i as f32 * 0.25),]
}

fn triangle() -> impl Strategy<Value = Tri> {
    prop::array::uniform3(prop::array::uniform3(coord()))
}

/// Scales at which the products of the watertight test stay well within `f32` range (their
/// magnitude is the cube of the coordinates' distance to the ray origin), and an offset that
/// moves the scene away from the origin.
fn placement() -> impl Strategy<Value = (f32, f32)> {
    (
        prop_oneof![
            4 => Just(1.0f32),
            1 => Just(1e-7f32),
            1 => Just(2e7f32),
            1 => Just(1e9f32),
        ],
        prop_oneof![3 => Just(0.0f32), 1 => Just(100.0f32)],
    )
}

/// Huge coordinates, about 1e15 (still far from `f32::MAX`).
fn huge_placement() -> impl Strategy<Value = (f32, f32)> {
    (Just(1e15f32), prop_oneof![Just(0.0f32), Just(100.0f32)])
}

/// Tiny coordinates, about 1e-15 (still normal `f32`).
fn tiny_placement() -> impl Strategy<Value = (f32, f32)> {
    (Just(3e-15f32), prop_oneof![Just(0.0f32), Just(100.0f32)])
}

#[derive(Clone, Debug)]
enum OriginSpec {
    /// A point of the scene's bounds (fractions of its extent).
    Inside([f32; 3]),
    /// Exactly a vertex of a triangle.
    Vertex(usize, usize),
    /// On the plane `axis = vertex[axis]` of a triangle's bounding box.
    OnPlane(usize, usize, usize, [f32; 3]),
    /// Anywhere around the scene, often outside.
    Around([f32; 3]),
}

#[derive(Clone, Debug)]
enum DirSpec {
    Random([f32; 3]),
    /// `+e_axis` or `-e_axis`.
    Axis(usize, bool),
    /// One component exactly `+0.0` or `-0.0`.
    OneZero(usize, bool, [f32; 3]),
    /// Two components exactly zero, each `+0.0` or `-0.0`, the third `+1` or `-1`.
    TwoZeros(usize, bool, [bool; 2]),
    /// Towards a triangle's vertex.
    AtVertex(usize, usize),
    /// Towards a triangle's centroid.
    AtCentroid(usize),
}

#[derive(Clone, Debug)]
enum IntervalSpec {
    Full,
    /// `tmin` a fraction of the scene's depth along the ray.
    Tmin(f32),
    /// A finite `tmax` cutting through the scene.
    Tmax(f32),
    Both(f32, f32),
}

#[derive(Clone, Debug)]
struct RaySpec {
    origin: OriginSpec,
    dir: DirSpec,
    interval: IntervalSpec,
}

fn unit3() -> impl Strategy<Value = [f32; 3]> {
    prop::array::uniform3(0.0f32..=1.0)
}

fn ray_spec() -> impl Strategy<Value = RaySpec> {
    let origin = prop_oneof![
        unit3().prop_map(OriginSpec::Inside),
        (0..1000usize, 0..3usize).prop_map(|(i, k)| OriginSpec::Vertex(i, k)),
        (0..1000usize, 0..3usize, 0..3usize, unit3())
            .prop_map(|(i, k, a, f)| OriginSpec::OnPlane(i, k, a, f)),
        unit3().prop_map(OriginSpec::Around),
    ];
    let comp = prop_oneof![-1.0f32..1.0, (-2i32..=2).prop_map(|i| i as f32 * 0.5)];
    let dir = prop_oneof![
        prop::array::uniform3(comp.clone()).prop_map(DirSpec::Random),
        (0..3usize, any::<bool>()).prop_map(|(a, n)| DirSpec::Axis(a, n)),
        (0..3usize, any::<bool>(), prop::array::uniform3(comp))
            .prop_map(|(a, n, c)| DirSpec::OneZero(a, n, c)),
        (0..3usize, any::<bool>(), any::<[bool; 2]>())
            .prop_map(|(a, n, z)| DirSpec::TwoZeros(a, n, z)),
        (0..1000usize, 0..3usize).prop_map(|(i, k)| DirSpec::AtVertex(i, k)),
        (0..1000usize).prop_map(DirSpec::AtCentroid),
    ];
    let interval = prop_oneof![
        2 => Just(IntervalSpec::Full),
        1 => (0.0f32..1.0).prop_map(IntervalSpec::Tmin),
        1 => (0.0f32..1.0).prop_map(IntervalSpec::Tmax),
        1 => (0.0f32..1.0, 0.0f32..1.0).prop_map(|(a, b)| IntervalSpec::Both(a.min(b), a.max(b))),
    ];
    (origin, dir, interval).prop_map(|(origin, dir, interval)| RaySpec {
        origin,
        dir,
        interval,
    })
}

// ---------------------------------------------------------------------------------------------
// Scene and ray construction
// ---------------------------------------------------------------------------------------------

fn place(tris: &[Tri], (scale, offset): (f32, f32)) -> Vec<Tri> {
    tris.iter()
        .map(|t| t.map(|v| v.map(|x| (x + offset) * scale)))
        .collect()
}

fn bounds_of(tris: &[Tri]) -> (Vec3, Vec3) {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for v in tris.iter().flatten() {
        lo = lo.min(Vec3::from(*v));
        hi = hi.max(Vec3::from(*v));
    }
    (lo, hi)
}

fn make_ray(spec: &RaySpec, tris: &[Tri]) -> Ray {
    let (lo, hi) = bounds_of(tris);
    let ext = hi - lo;
    let vertex = |i: usize, k: usize| Vec3::from(tris[i % tris.len()][k % 3]);
    let origin = match &spec.origin {
        OriginSpec::Inside(f) => lo + Vec3::from(*f) * ext,
        OriginSpec::Vertex(i, k) => vertex(*i, *k),
        OriginSpec::OnPlane(i, k, a, f) => {
            let mut o = lo + Vec3::from(*f) * ext;
            o[*a] = vertex(*i, *k)[*a];
            o
        }
        OriginSpec::Around(f) => lo - ext + Vec3::from(*f) * ext * 3.0,
    };
    let direction = match &spec.dir {
        DirSpec::Random(c) => Vec3::from(*c),
        DirSpec::Axis(a, neg) => {
            let mut d = Vec3::ZERO;
            d[*a] = if *neg { -1.0 } else { 1.0 };
            d
        }
        DirSpec::OneZero(a, neg, c) => {
            let mut d = Vec3::from(*c);
            d[*a] = if *neg { -0.0 } else { 0.0 };
            d
        }
        DirSpec::TwoZeros(a, neg, z) => {
            let mut d = Vec3::ZERO;
            d[*a] = if *neg { -1.0 } else { 1.0 };
            d[(a + 1) % 3] = if z[0] { -0.0 } else { 0.0 };
            d[(a + 2) % 3] = if z[1] { -0.0 } else { 0.0 };
            d
        }
        DirSpec::AtVertex(i, k) => vertex(*i, *k) - origin,
        DirSpec::AtCentroid(i) => {
            let t = &tris[i % tris.len()];
            let c = (Vec3::from(t[0]) + Vec3::from(t[1]) + Vec3::from(t[2])) / 3.0;
            c - origin
        }
    };
    // The span of t over which the ray crosses the scene, roughly.
    let centre = lo * 0.5 + hi * 0.5;
    let span = (ext.length() * 2.0 + (origin - centre).length()) / direction.length();
    let (tmin, tmax) = match spec.interval {
        IntervalSpec::Full => (0.0, f32::INFINITY),
        IntervalSpec::Tmin(a) => (a * span, f32::INFINITY),
        IntervalSpec::Tmax(b) => (0.0, b * span),
        IntervalSpec::Both(a, b) => (a * span, b * span),
    };
    Ray::with_interval(origin, direction, tmin, tmax)
}

/// One structure per CPU traversal kernel the processor runs ([`common::kernels`]): the checks
/// run on each, and every query asks each of them and checks that they agree (t, u, v and
/// facing bit for bit; the primitive unless two are hit at the same t).
struct Gases(Vec<Gas>);

impl Gases {
    fn build(options: &BuildOptions, inputs: &[oxray::BuildInput<'_>]) -> Gases {
        Gases(
            common::kernels()
                .into_iter()
                .map(|isa| Gas::build_with_isa(isa, options, inputs).expect("a valid input builds"))
                .collect(),
        )
    }

    fn each(&self) -> &[Gas] {
        &self.0
    }

    fn num_primitives(&self) -> u32 {
        self.0[0].num_primitives()
    }

    fn num_active_primitives(&self) -> u32 {
        self.0[0].num_active_primitives()
    }

    /// The first kernel's hit, once every kernel agrees with it.
    fn agree(
        &self,
        ray: &Ray,
        mut hit: impl FnMut(&Gas) -> Option<oxray::Hit>,
    ) -> Option<oxray::Hit> {
        let first = hit(&self.0[0]);
        for g in &self.0[1..] {
            let h = hit(g);
            let t = |h: &Option<oxray::Hit>| h.map(|h| h.t.to_bits());
            assert_eq!(
                t(&h),
                t(&first),
                "kernel {} against {}; ray {ray:?}",
                g.isa(),
                self.0[0].isa()
            );
            if h.map(|h| h.primitive_index) == first.map(|h| h.primitive_index) {
                assert_eq!(
                    h,
                    first,
                    "kernel {} against {}; ray {ray:?}",
                    g.isa(),
                    self.0[0].isa()
                );
            }
        }
        first
    }

    fn intersect(&self, ray: &Ray) -> Option<oxray::Hit> {
        self.agree(ray, |g| g.intersect(ray))
    }

    fn intersect_with<C: oxray::cpu::CustomIntersector>(
        &self,
        ray: &Ray,
        c: &mut C,
    ) -> Option<oxray::Hit> {
        self.agree(ray, |g| g.intersect_with(ray, c))
    }

    fn occluded(&self, ray: &Ray) -> bool {
        self.occluded_by(ray, |g| g.occluded(ray))
    }

    fn occluded_with<C: oxray::cpu::CustomIntersector>(&self, ray: &Ray, c: &mut C) -> bool {
        self.occluded_by(ray, |g| g.occluded_with(ray, c))
    }

    fn occluded_by(&self, ray: &Ray, mut f: impl FnMut(&Gas) -> bool) -> bool {
        let first = f(&self.0[0]);
        for g in &self.0[1..] {
            assert_eq!(f(g), first, "kernel {} occlusion; ray {ray:?}", g.isa());
        }
        first
    }
}

fn soup_gas(tris: &[Tri], flags: BuildFlags) -> Gases {
    let verts: Vec<[f32; 3]> = tris.iter().flatten().copied().collect();
    Gases::build(
        &BuildOptions::new(flags),
        &[TriangleInput::new(VertexBuffer::f32x3(&verts)).into()],
    )
}

/// Checks closest hit and occlusion of `ray` against the brute-force reference, on every
/// kernel.
fn check_ray(gases: &Gases, tris: &[Tri], ray: &Ray) -> Result<(), String> {
    let any = !reference_hits(tris, ray).is_empty();
    for gas in gases.each() {
        let kernel = gas.isa();
        check_closest(gas.intersect(ray), tris, ray)
            .map_err(|e| format!("{kernel} kernel: {e}"))?;
        if gas.occluded(ray) != any {
            return Err(format!(
                "{kernel} kernel: occluded = {} but the reference says {any}; ray {ray:?}",
                !any
            ));
        }
    }
    gases.intersect(ray);
    Ok(())
}

/// Checks the same ray with its interval closed exactly on the reference's closest hit t*:
/// `[tmin, t*]` and `[t*, t*]` must both report a hit at t* (§13.2: the interval is closed).
/// Skipped when t* is not finite.
fn check_interval_closed_on_hit(gases: &Gases, tris: &[Tri], ray: &Ray) -> Result<(), String> {
    let Some(best) = reference_closest(tris, ray) else {
        return Ok(());
    };
    let t = best.hit.t;
    if !t.is_finite() {
        return Ok(());
    }
    for r in [
        Ray { tmax: t, ..*ray },
        Ray {
            tmin: t,
            tmax: t,
            ..*ray
        },
    ] {
        for gas in gases.each() {
            let kernel = gas.isa();
            check_closest(gas.intersect(&r), tris, &r)
                .map_err(|e| format!("{kernel} kernel, interval closed on t* = {t}: {e}"))?;
            if !gas.occluded(&r) {
                return Err(format!(
                    "{kernel} kernel: not occluded with the interval closed on t* = {t}; ray {r:?}"
                ));
            }
        }
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Triangle soups
// ---------------------------------------------------------------------------------------------

fn check_soup(tris: &[Tri], placement: (f32, f32), rays: &[RaySpec]) -> Result<(), TestCaseError> {
    let tris = place(tris, placement);
    let gas = soup_gas(&tris, BuildFlags::empty());
    for spec in rays {
        let ray = make_ray(spec, &tris);
        if let Err(e) = check_ray(&gas, &tris, &ray) {
            return Err(TestCaseError::fail(format!(
                "{e}\nspec {spec:?}, placement {placement:?}"
            )));
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(common::proptest_config(256))]

    /// Guide §13.2 and §5.1: closest hit and occlusion of random rays on small random soups
    /// (shallow trees, many exact coincidences), at moderate coordinate scales.
    #[test]
    fn small_soups_match_bruteforce_13_2(
        tris in prop::collection::vec(triangle(), 1..48),
        placement in placement(),
        rays in prop::collection::vec(ray_spec(), 24),
    ) {
        check_soup(&tris, placement, &rays)?;
    }
}

proptest! {
    #![proptest_config(common::proptest_config(128))]

    /// Guide §13.2: the same with coordinates around 1e15.
    #[test]
    fn huge_coordinate_soups_match_bruteforce_13_2(
        tris in prop::collection::vec(triangle(), 1..48),
        placement in huge_placement(),
        rays in prop::collection::vec(ray_spec(), 24),
    ) {
        check_soup(&tris, placement, &rays)?;
    }

    /// Guide §13.2: the same with coordinates around 1e-15.
    #[test]
    fn tiny_coordinate_soups_match_bruteforce_13_2(
        tris in prop::collection::vec(triangle(), 1..48),
        placement in tiny_placement(),
        rays in prop::collection::vec(ray_spec(), 24),
    ) {
        check_soup(&tris, placement, &rays)?;
    }
}

proptest! {
    #![proptest_config(common::proptest_config(64))]

    /// Guide §13.2: the same on larger soups (deeper trees, 4-wide nodes with inner children).
    #[test]
    fn larger_soups_match_bruteforce_13_2(
        tris in prop::collection::vec(triangle(), 100..400),
        placement in placement(),
        rays in prop::collection::vec(ray_spec(), 32),
    ) {
        let tris = place(&tris, placement);
        let gas = soup_gas(&tris, BuildFlags::empty());
        prop_assert_eq!(gas.num_primitives() as usize, tris.len());
        for spec in &rays {
            let ray = make_ray(spec, &tris);
            if let Err(e) = check_ray(&gas, &tris, &ray) {
                return Err(TestCaseError::fail(format!("{e}\nspec {spec:?}, placement {placement:?}")));
            }
        }
    }

    /// Guide §5.5: the build flags are trade-off hints only; every preset returns the same closest
    /// distance (and the brute-force one).
    #[test]
    fn every_build_preset_gives_the_same_closest_t_5_5(
        tris in prop::collection::vec(triangle(), 200..700),
        placement in placement(),
        rays in prop::collection::vec(ray_spec(), 32),
    ) {
        let tris = place(&tris, placement);
        let presets = [BuildFlags::empty(), BuildFlags::PREFER_FAST_BUILD, BuildFlags::PREFER_FAST_TRACE];
        let gases: Vec<Gases> = presets.iter().map(|&f| soup_gas(&tris, f)).collect();
        for spec in &rays {
            let ray = make_ray(spec, &tris);
            // Bit patterns, with -0 folded into +0 (the same distance).
            let ts: Vec<Option<u32>> = gases.iter().map(|g| g.intersect(&ray).map(|h| (h.t + 0.0).to_bits())).collect();
            prop_assert!(ts.iter().all(|t| *t == ts[0]), "presets disagree: {:?} for {:?}", ts, ray);
            let occ: Vec<bool> = gases.iter().map(|g| g.occluded(&ray)).collect();
            prop_assert!(occ.iter().all(|o| *o == occ[0]), "presets disagree on occlusion: {:?}", occ);
            for (g, f) in gases.iter().zip(presets) {
                if let Err(e) = check_ray(g, &tris, &ray) {
                    return Err(TestCaseError::fail(format!("{f:?}: {e}")));
                }
            }
        }
    }
}

proptest! {
    #![proptest_config(common::proptest_config(1024))]

    /// Guide §13.2: the interval is closed — a hit exactly at `tmin` or exactly at `tmax` is
    /// reported. The same random rays as above, re-cast with `tmax = t*` and with
    /// `tmin = tmax = t*`, where t* is the brute-force closest distance.
    #[test]
    fn interval_closed_on_the_closest_hit_is_reported_13_2(
        tris in prop::collection::vec(triangle(), 1..48),
        placement in placement(),
        rays in prop::collection::vec(ray_spec(), 24),
    ) {
        let tris = place(&tris, placement);
        let gas = soup_gas(&tris, BuildFlags::empty());
        for spec in &rays {
            let ray = make_ray(spec, &tris);
            if let Err(e) = check_interval_closed_on_hit(&gas, &tris, &ray) {
                return Err(TestCaseError::fail(format!("{e}\nspec {spec:?}, placement {placement:?}")));
            }
        }
    }

}

proptest! {
    #![proptest_config(common::proptest_config(256))]

    /// Guide §13.5 (`optixGetRayTmax` in closest-hit is the hit distance): at moderate
    /// coordinate scales the reported t of a non-grazing hit is close to the exact distance to
    /// the triangle's plane (computed in `f64`).
    #[test]
    fn hit_distance_is_accurate_13_5(
        tris in prop::collection::vec(triangle(), 1..16),
        placement in placement(),
        rays in prop::collection::vec(ray_spec(), 24),
    ) {
        check_accuracy(&tris, placement, &rays)?;
    }

    /// Guide §13.5: the same with coordinates around 1e15: the distance must stay finite.
    #[test]
    fn hit_distance_is_accurate_at_huge_coordinates_13_5(
        tris in prop::collection::vec(triangle(), 1..16),
        placement in huge_placement(),
        rays in prop::collection::vec(ray_spec(), 24),
    ) {
        check_accuracy(&tris, placement, &rays)?;
    }

    /// Guide §13.5: the same with coordinates around 1e-15.
    #[test]
    fn hit_distance_is_accurate_at_tiny_coordinates_13_5(
        tris in prop::collection::vec(triangle(), 1..16),
        placement in tiny_placement(),
        rays in prop::collection::vec(ray_spec(), 24),
    ) {
        check_accuracy(&tris, placement, &rays)?;
    }
}

fn check_accuracy(
    tris: &[Tri],
    placement: (f32, f32),
    rays: &[RaySpec],
) -> Result<(), TestCaseError> {
    let tris = place(tris, placement);
    let gas = soup_gas(&tris, BuildFlags::empty());
    for spec in rays {
        let ray = make_ray(spec, &tris);
        let Some(h) = gas.intersect(&ray) else {
            continue;
        };
        let t = tris[h.primitive_index as usize].map(|v| Vec3::from(v).as_dvec3());
        let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
        let (o, d) = (ray.origin.as_dvec3(), ray.direction.as_dvec3());
        if (n.dot(d) / d.length()).abs() < 0.05 {
            continue;
        }
        let exact = n.dot(t[0] - o) / n.dot(d);
        let err = (h.t as f64 - exact).abs();
        // Relative error, plus an absolute one at the scale of the triangle seen from the origin.
        let reach = t.iter().map(|v| (*v - o).length()).fold(0.0, f64::max) / d.length();
        prop_assert!(
            h.t.is_finite() && err <= 1e-3 * exact.abs() + 1e-5 * reach,
            "t = {} but the exact distance is {}; hit {:?}, ray {:?}, placement {:?}",
            h.t,
            exact,
            h,
            ray,
            placement
        );
    }
    Ok(())
}

/// Guide §13.5: a minimal case of the above at coordinates around 1e15 (well within `f32`):
/// the distance must be finite, about 1e15, and a `tmax` of 1e16 must not lose the hit.
#[test]
fn huge_coordinates_give_a_finite_distance_13_5() {
    let s = 1e15f32;
    let v = [[0.0f32, -s, -s], [0.0, s, -s], [0.0, 0.0, s]];
    let tris = [v];
    let gas = soup_gas(&tris, BuildFlags::empty());
    let ray = Ray::new(Vec3::new(-s, 0.0, 0.0), Vec3::X);
    let h = gas.intersect(&ray).expect("the ray hits the triangle");
    assert!(
        (h.t / s - 1.0).abs() < 1e-5,
        "t = {} for a triangle at distance {s}",
        h.t
    );
    let cut = Ray::with_interval(ray.origin, ray.direction, 0.0, 1e16);
    assert!(
        gas.intersect(&cut).is_some(),
        "tmax = 1e16 loses the hit at 1e15"
    );
    assert!(gas.occluded(&cut));
}

/// Guide §13.2: a deterministic stress case — a regular grid of coplanar, axis-aligned triangles
/// with shared vertices, queried by rays through every vertex and edge midpoint along each axis
/// direction and with the interval closed exactly on the hit.
#[test]
fn grid_of_coplanar_triangles_matches_bruteforce_13_2() {
    let n = 12;
    let mut tris: Vec<Tri> = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let p = |a: i32, b: i32| [(i + a) as f32 * 0.5, (j + b) as f32 * 0.5, 1.5];
            tris.push([p(0, 0), p(1, 0), p(1, 1)]);
            tris.push([p(0, 0), p(1, 1), p(0, 1)]);
        }
    }
    let gas = soup_gas(&tris, BuildFlags::PREFER_FAST_TRACE);
    let mut rays = 0;
    for i in 0..=2 * n {
        for j in 0..=2 * n {
            let (x, y) = (i as f32 * 0.25, j as f32 * 0.25);
            for (o, d) in [
                (Vec3::new(x, y, 4.0), -Vec3::Z),
                (Vec3::new(x, y, -4.0), Vec3::Z),
                (Vec3::new(x, y, 1.5), Vec3::Z),
                (Vec3::new(x, y, -1.0), Vec3::new(0.0, -0.0, 2.5)),
                (Vec3::new(x, y, 5.0), Vec3::new(0.01, -0.02, -1.0)),
            ] {
                let ray = Ray::new(o, d);
                check_ray(&gas, &tris, &ray).unwrap();
                check_interval_closed_on_hit(&gas, &tris, &ray).unwrap();
                rays += 1;
            }
        }
    }
    assert_eq!(rays, 625 * 5);
    // Rays in the plane of the grid hit nothing.
    for k in 0..20 {
        let ray = Ray::new(
            Vec3::new(-1.0, k as f32 * 0.3, 1.5),
            Vec3::new(1.0, 0.1, 0.0),
        );
        assert_eq!(gas.intersect(&ray), None);
        assert!(!gas.occluded(&ray));
    }
}

// ---------------------------------------------------------------------------------------------
// Custom primitives
// ---------------------------------------------------------------------------------------------

#[derive(Clone, Copy, Debug)]
enum Shape {
    /// The sphere inscribed in the box, shrunk by 10%.
    Sphere,
    /// The box itself, shrunk by 5% towards its centre.
    Box,
}

/// The closest intersection of `ray` with the shape inside `aabb` within `[ray.tmin, ray.tmax]`:
/// an intersection program in closure form.
fn shape_hit(shape: Shape, p: &CustomPrimitive, ray: &Ray) -> Option<CustomHit> {
    let c = p.aabb.center().as_dvec3();
    let half = (p.aabb.extent() * 0.5).as_dvec3();
    let o = ray.origin.as_dvec3();
    let d = ray.direction.as_dvec3();
    let (t0, t1) = match shape {
        Shape::Sphere => {
            let r = 0.9 * half.min_element();
            let oc = o - c;
            let a = d.dot(d);
            let b = oc.dot(d);
            let cc = oc.dot(oc) - r * r;
            let disc = b * b - a * cc;
            if disc < 0.0 {
                return None;
            }
            let s = disc.sqrt();
            ((-b - s) / a, (-b + s) / a)
        }
        Shape::Box => {
            let lo = c - half * 0.95;
            let hi = c + half * 0.95;
            let (mut tn, mut tf) = (f64::NEG_INFINITY, f64::INFINITY);
            for a in 0..3 {
                if d[a] == 0.0 {
                    if o[a] < lo[a] || o[a] > hi[a] {
                        return None;
                    }
                    continue;
                }
                let (x, y) = ((lo[a] - o[a]) / d[a], (hi[a] - o[a]) / d[a]);
                tn = tn.max(x.min(y));
                tf = tf.min(x.max(y));
            }
            if tn > tf {
                return None;
            }
            (tn, tf)
        }
    };
    let (tmin, tmax) = (ray.tmin as f64, ray.tmax as f64);
    let t = [t0, t1]
        .into_iter()
        .map(|t| t as f32)
        .find(|&t| (t as f64) >= tmin && (t as f64) <= tmax)?;
    Some(CustomHit {
        t,
        // All 8 bits: the query must keep only the low 7 (§12, §13.4).
        hit_kind: (p.primitive_index as u8).wrapping_mul(37) | 0x80,
        u: p.primitive_index as f32,
        v: t * 0.5,
    })
}

fn aabb_strategy() -> impl Strategy<Value = Aabb> {
    let valid = (
        prop::array::uniform3(coord()),
        prop::array::uniform3(0.01f32..0.4),
    )
        .prop_map(|(c, h)| {
            let (c, h) = (Vec3::from(c), Vec3::from(h));
            Aabb::new(c - h, c + h)
        });
    prop_oneof![
        10 => valid,
        // Inverted: min > max on one axis.
        1 => (prop::array::uniform3(coord()), 0..3usize).prop_map(|(c, a)| {
            let mut max = Vec3::from(c);
            max[a] -= 0.5;
            Aabb::new(Vec3::from(c), max)
        }),
        // NaN or infinite coordinates.
        1 => (prop::array::uniform3(coord()), any::<bool>()).prop_map(|(c, nan)| {
            let mut max = Vec3::from(c) + 0.3;
            max.y = if nan { f32::NAN } else { f32::INFINITY };
            Aabb::new(Vec3::from(c), max)
        }),
    ]
}

fn custom_ray() -> impl Strategy<Value = (RaySpec, usize, usize)> {
    // (spec, box for a corner origin, corner)
    (ray_spec(), 0..1000usize, 0..8usize)
}

proptest! {
    #![proptest_config(common::proptest_config(128))]

    /// Guide §5.1 (custom primitives) and §13.4: `intersect_with` returns the closest hit that
    /// the intersection closure reports over all active boxes, and `occluded_with` whether there
    /// is one; inactive boxes (inverted, NaN, infinite) are never handed to the closure.
    #[test]
    fn custom_primitives_match_bruteforce_5_1(
        boxes in prop::collection::vec(aabb_strategy(), 1..120),
        sphere in any::<bool>(),
        rays in prop::collection::vec(custom_ray(), 24),
    ) {
        let shape = if sphere { Shape::Sphere } else { Shape::Box };
        let gas = Gases::build(
            &BuildOptions::default(),
            &[CustomPrimitiveInput::new(AabbBuffer::new(&boxes)).into()],
        );
        let active: Vec<usize> = (0..boxes.len()).filter(|&i| boxes[i].is_finite_valid()).collect();
        prop_assert_eq!(gas.num_active_primitives() as usize, active.len());
        let valid_tris: Vec<Tri> = active.iter().map(|&i| {
            let b = boxes[i];
            [b.min.to_array(), b.max.to_array(), b.center().to_array()]
        }).collect();
        for (spec, bi, corner) in &rays {
            let mut ray = if valid_tris.is_empty() {
                Ray::new(Vec3::ZERO, Vec3::X)
            } else {
                make_ray(spec, &valid_tris)
            };
            if let (OriginSpec::Vertex(..), false) = (&spec.origin, active.is_empty()) {
                // Exactly on a box corner instead.
                let b = boxes[active[bi % active.len()]];
                ray.origin = Vec3::new(
                    if corner & 1 == 0 { b.min.x } else { b.max.x },
                    if corner & 2 == 0 { b.min.y } else { b.max.y },
                    if corner & 4 == 0 { b.min.z } else { b.max.z },
                );
            }
            // Brute force over every active box with the full interval.
            let mut expected: Vec<(u32, CustomHit)> = Vec::new();
            if ray.validate().is_ok() {
                for &i in &active {
                    let p = CustomPrimitive { primitive_index: i as u32, sbt_gas_index: 0, build_input: 0, aabb: boxes[i] };
                    if let Some(h) = shape_hit(shape, &p, &ray) {
                        expected.push((i as u32, h));
                    }
                }
            }
            let best = expected.iter().map(|(_, h)| h.t).fold(None, |m: Option<f32>, t| Some(m.map_or(t, |m| m.min(t))));

            let mut bad_call = None;
            let mut closure = |p: &CustomPrimitive, r: &Ray| {
                let i = p.primitive_index as usize;
                if i >= boxes.len() || !boxes[i].is_finite_valid() || p.aabb != boxes[i]
                    || p.build_input != 0 || p.sbt_gas_index != 0 || r.origin != ray.origin
                    || r.direction != ray.direction || r.tmin != ray.tmin || r.tmax > ray.tmax {
                    bad_call = Some((*p, *r));
                }
                shape_hit(shape, p, r)
            };
            let got = gas.intersect_with(&ray, &mut closure);
            let occluded = gas.occluded_with(&ray, &mut closure);
            prop_assert!(bad_call.is_none(), "closure called with {:?}", bad_call);
            prop_assert_eq!(got.map(|h| h.t.to_bits()), best.map(f32::to_bits), "ray {:?}: got {:?}, expected {:?}", ray, got, expected);
            prop_assert_eq!(occluded, best.is_some());
            if let Some(g) = got {
                let e = expected.iter().find(|(i, h)| *i == g.primitive_index && h.t.to_bits() == g.t.to_bits());
                prop_assert!(e.is_some(), "primitive {} is not hit at t = {}: {:?}", g.primitive_index, g.t, expected);
                let (_, e) = e.unwrap();
                prop_assert_eq!(g.hit_kind, HitKind::custom(e.hit_kind));
                prop_assert!(g.hit_kind.0 < 128);
                prop_assert_eq!((g.u.to_bits(), g.v.to_bits()), (e.u.to_bits(), e.v.to_bits()));
                prop_assert_eq!((g.build_input, g.sbt_gas_index), (0, 0));
            }
            // Without an intersector, custom primitives are never hit (§13.4: no IS program).
            prop_assert_eq!(gas.intersect(&ray), None);
            prop_assert!(!gas.occluded(&ray));
        }
    }
}
