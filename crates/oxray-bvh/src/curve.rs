//! Built-in curves (guide §5.2, §9.3, §9.6, §9.7): the record a GAS keeps per curve segment, its
//! bounds, and the ray/segment tests every backend uses.
//!
//! **Round curves** (every type but the ribbon). A segment's position `c(u)` and radius `r(u)`
//! are cubic (or lower) polynomials of `u ∈ [0, 1]`. oxray intersects the swept-sphere surface,
//! the boundary of the union of the spheres `S(u)` of centre `c(u)` and radius `r(u)`: the
//! ray's entry into that union is `min_u t₀(u)`, where `t₀(u)` is the entry into `S(u)`. This
//! is the Rocaps surface (§9.7) and the phantom (swept-circle) surface wherever the radius is
//! constant; where it varies the two differ slightly, which the guide allows for hair-like
//! curves (§9.7). The minimum is found exactly, without subdivision or a starting guess:
//!
//! 1. In a frame whose z axis is the ray, `c(u) - o = (X, Y, Z)`, and the ray meets `S(u)`
//!    where `D(u) = r² - X² - Y² >= 0` (a polynomial of degree ≤ 6), entering at
//!    `t₀(u) = Z - √D`. The roots of `D` split `[0, 1]` into the intervals where it does.
//! 2. Inside an interval, `t₀` is smallest at a root of `t₀'`, i.e. of
//!    `P = 4 Z'² D - D'²` (degree ≤ 10) where `Z'` and `D'` share a sign, or at `u = 0` or `1`.
//!    Every real root comes from `poly.rs` (isolation by the derivative's roots, then
//!    safeguarded Newton), in `f64`.
//! 3. Ends: linear curves have round caps and elbows (the spheres `S(0)`, `S(1)` are part of
//!    the segment, so a minimum at `u = 0` or `1` is a hit). Other types are open by default:
//!    a first entry through `S(0)` or `S(1)` is not a hit (the ray enters the tube's open end);
//!    with `OPTIX_CURVE_ENDCAP_ON` the ends of strands are flat discs, hit with `u` exactly 0 or
//!    1 (§9.3).
//! 4. Tubes are hollow and back faces culled (§9.6): only entries are hits, and a ray whose
//!    interval starts inside the segment's tube does not hit it.
//!
//! **Ribbons** (flat quadratic B-splines, §5.2, §9.3) are ruled surfaces
//! `c(u) + v r(u) w(u)`, `v ∈ [-1, 1]`. With normals, `w = n(u) × c'(u)` (normalised) for the
//! linearly interpolated normal `n(u)`: the ray meets the line of `u` where
//! `(c(u) - o) · (w × d) = 0` (a quartic). Without normals a ribbon faces the ray
//! (`w ⊥ d`, oxray's reading of "computed automatically", §9.8): the ray meets it at the roots of
//! `X X' + Y Y'` where `D >= 0`. Ribbons have two faces; the front face is the one their normal
//! `c' × w` points out of.

use crate::poly::{Poly, MAX_COEFFS};
use bytemuck::{Pod, Zeroable};
use glam::{DVec3, Vec3};
use oxray_core::{Aabb, CurveType};

/// A flat cap at the start of the segment (`u = 0`: it starts a strand, caps on).
pub const CAP_START: u32 = 1;
/// A flat cap at the end of the segment (`u = 1`: it ends a strand, caps on).
pub const CAP_END: u32 = 2;
/// The segment has ribbon normals.
pub const HAS_NORMALS: u32 = 4;

/// One curve segment as a GAS keeps it: its control points and radii (what
/// `optixGet*VertexData` returns, guide §9.3), its type, and its end caps.
///
/// ```
/// use oxray_bvh::curve::CurveSegment;
/// use oxray_core::CurveType;
/// use glam::Vec3;
/// // A straight linear segment of radius 0.5 along x, from 0 to 4.
/// let s = CurveSegment::new(CurveType::RoundLinear, &[[0.0, 0.0, 0.0, 0.5], [4.0, 0.0, 0.0, 0.5]], 0, None);
/// let hit = s.intersect(Vec3::new(2.0, 0.0, -5.0), Vec3::Z, 0.0, f32::INFINITY).unwrap();
/// assert!((hit.t - 4.5).abs() < 1e-5 && (hit.u - 0.5).abs() < 1e-5);
/// // From inside the tube it is not hit (guide §9.6).
/// assert!(s.intersect(Vec3::new(2.0, 0.0, 0.0), Vec3::Z, 0.0, f32::INFINITY).is_none());
/// ```
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct CurveSegment {
    /// Control points `(x, y, z, radius)`; those past the type's count are zero.
    pub points: [[f32; 4]; 4],
    /// Ribbon normals at `u = 0` and `u = 1` (zero without normals).
    pub normals: [[f32; 3]; 2],
    /// The `OptixPrimitiveType` code of the curve type.
    pub curve_type: u32,
    /// [`CAP_START`], [`CAP_END`], [`HAS_NORMALS`].
    pub flags: u32,
}

/// A hit on a curve segment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurveHit {
    /// Distance along the ray, in the units of its direction.
    pub t: f32,
    /// The curve parameter in the segment (exactly 0 or 1 on a flat end cap, §9.3).
    pub u: f32,
    /// A ribbon's `v ∈ [-1, 1]` (0 for round curves).
    pub v: f32,
    /// Whether the hit is on the back face (only ribbons have one).
    pub back_face: bool,
}

/// Segment splitting at build time (guide §9.2): a segment much longer than it is wide is
/// referenced from several leaves of the BVH, each reference bounded by the box of a piece of
/// its parameter interval ([`CurveSegment::bounds_over`]) and each intersecting the whole
/// segment (the same leaf record, the same primitive index), so that hits are those of an
/// unsplit build and a ray may meet a segment in more than one leaf.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurveSplits {
    /// Most pieces per segment.
    pub max_pieces: u32,
    /// A segment is cut into about `length / (width × width_ratio)` pieces
    /// ([`CurveSegment::pieces`]).
    pub width_ratio: f32,
}

impl CurveSplits {
    /// The default splitting factor.
    pub const BALANCED: CurveSplits = CurveSplits {
        max_pieces: 8,
        width_ratio: 2.0,
    };
    /// `PREFER_FAST_TRACE`: a higher splitting factor (§9.2).
    pub const FAST_TRACE: CurveSplits = CurveSplits {
        max_pieces: 16,
        width_ratio: 1.0,
    };
    /// `PREFER_FAST_BUILD`: a lower splitting factor (§9.2).
    pub const FAST_BUILD: CurveSplits = CurveSplits {
        max_pieces: 2,
        width_ratio: 4.0,
    };
}

impl CurveSegment {
    /// The record of an updatable structure's slot whose segment is inactive: NaN control
    /// points, which no ray hits and no bound includes. It keeps its curve type, which a
    /// pipeline's primitive-type check reads.
    #[must_use]
    pub fn deactivated(self) -> CurveSegment {
        CurveSegment {
            points: [[f32::NAN; 4]; 4],
            ..self
        }
    }

    /// A segment of `ty` with control points `points` (`x, y, z, radius`; as many as the type
    /// has), cap `flags` ([`CAP_START`], [`CAP_END`]) and ribbon normals.
    #[must_use]
    pub fn new(
        ty: CurveType,
        points: &[[f32; 4]],
        flags: u32,
        normals: Option<[Vec3; 2]>,
    ) -> CurveSegment {
        let mut p = [[0.0; 4]; 4];
        p[..points.len()].copy_from_slice(points);
        let (normals, has) = match normals {
            Some([a, b]) => ([a.to_array(), b.to_array()], HAS_NORMALS),
            None => ([[0.0; 3]; 2], 0),
        };
        CurveSegment {
            points: p,
            normals,
            curve_type: ty.code(),
            flags: (flags & (CAP_START | CAP_END)) | has,
        }
    }

    /// The curve type (round linear for an inactive record).
    #[must_use]
    pub fn curve_type(&self) -> CurveType {
        CurveType::from_code(self.curve_type).unwrap_or(CurveType::RoundLinear)
    }

    /// The control points as `float4`s, as many as the type has.
    #[must_use]
    pub fn control_points(&self) -> &[[f32; 4]] {
        &self.points[..self.curve_type().control_points()]
    }

    /// Whether a ray can hit it: finite control points, a known type, and a radius that is
    /// positive somewhere (the guide skips negative radii, §9.8).
    #[must_use]
    pub fn is_active(&self) -> bool {
        self.active_type().is_some()
    }

    /// The curve type of an active segment ([`is_active`](Self::is_active)), `None` otherwise:
    /// the type is decoded once.
    #[inline]
    fn active_type(&self) -> Option<CurveType> {
        let ty = CurveType::from_code(self.curve_type)?;
        let points = &self.points[..ty.control_points()];
        // Folds without early exits: a few compares the compiler may pack.
        let finite = points
            .iter()
            .flatten()
            .fold(true, |ok, c| ok & c.is_finite())
            & self
                .normals
                .iter()
                .flatten()
                .fold(true, |ok, c| ok & c.is_finite());
        let radius = points.iter().fold(false, |any, p| any | (p[3] > 0.0));
        (finite && radius).then_some(ty)
    }

    /// Power-basis coefficients of `(x, y, z, r)`: `c(u) = Σ a[k] u^k`.
    fn power_basis(&self) -> [[f64; 4]; 4] {
        self.power_basis_of(self.curve_type())
    }

    /// [`power_basis`](Self::power_basis) for the segment's type `ty`, decoded by the caller.
    #[inline]
    fn power_basis_of(&self, ty: CurveType) -> [[f64; 4]; 4] {
        let p: [[f64; 4]; 4] = self.points.map(|q| q.map(f64::from));
        // One match per segment; each coefficient is the type's expression, coordinate by
        // coordinate (lanes the compiler may pack).
        macro_rules! per_coordinate {
            (|$q:ident| [$($e:expr),* $(,)?]) => {
                [$(std::array::from_fn(|d| {
                    // Constant coefficients do not read the control points.
                    #[allow(unused_variables)]
                    let $q = |i: usize| p[i][d];
                    $e
                })),*]
            };
        }
        match ty {
            CurveType::RoundLinear => per_coordinate!(|q| [q(0), q(1) - q(0), 0.0, 0.0]),
            CurveType::RoundQuadraticBSpline
            | CurveType::FlatQuadraticBSpline
            | CurveType::RoundQuadraticBSplineRocaps => per_coordinate!(|q| [
                0.5 * (q(0) + q(1)),
                q(1) - q(0),
                0.5 * (q(0) - 2.0 * q(1) + q(2)),
                0.0,
            ]),
            CurveType::RoundCubicBSpline | CurveType::RoundCubicBSplineRocaps => {
                per_coordinate!(|q| [
                    (q(0) + 4.0 * q(1) + q(2)) / 6.0,
                    (q(2) - q(0)) / 2.0,
                    (q(0) - 2.0 * q(1) + q(2)) / 2.0,
                    (-q(0) + 3.0 * q(1) - 3.0 * q(2) + q(3)) / 6.0,
                ])
            }
            CurveType::RoundCatmullRom | CurveType::RoundCatmullRomRocaps => {
                per_coordinate!(|q| [
                    q(1),
                    0.5 * (q(2) - q(0)),
                    0.5 * (2.0 * q(0) - 5.0 * q(1) + 4.0 * q(2) - q(3)),
                    0.5 * (-q(0) + 3.0 * q(1) - 3.0 * q(2) + q(3)),
                ])
            }
            CurveType::RoundCubicBezier | CurveType::RoundCubicBezierRocaps => {
                per_coordinate!(|q| [
                    q(0),
                    3.0 * (q(1) - q(0)),
                    3.0 * (q(0) - 2.0 * q(1) + q(2)),
                    -q(0) + 3.0 * q(1) - 3.0 * q(2) + q(3),
                ])
            }
        }
    }

    /// The centre and radius at `u`, in `f64` (the reference tests use it too).
    #[must_use]
    pub fn eval(&self, u: f64) -> (DVec3, f64) {
        eval_basis(&self.power_basis(), u)
    }

    /// The tangent `c'(u)`, in `f64`.
    #[must_use]
    pub fn tangent(&self, u: f64) -> DVec3 {
        tangent_basis(&self.power_basis(), u)
    }

    /// The box around the segment: the Bézier hull of the centre line grown by the largest
    /// radius coefficient, rounded outwards. Empty for an inactive segment.
    #[must_use]
    pub fn bounds(&self) -> Aabb {
        if !self.is_active() {
            return Aabb::EMPTY;
        }
        hull_box(&bezier_points(&self.power_basis()))
    }

    /// The box around the part of the segment over `u ∈ [u0, u1]` (a piece of a split segment,
    /// guide §9.2): the Bézier hull of the centre line reparametrised over that interval, grown
    /// by the largest radius coefficient of the reparametrised radius, rounded outwards as
    /// [`bounds`](Self::bounds) is. Over `[0, 1]` it is [`bounds`](Self::bounds), bit for bit;
    /// the boxes of `[0, u1]`, `[u1, u2]`, …, `[uₙ, 1]` together hold the whole swept surface
    /// (every sphere `S(u)`, end caps and ribbons included). Empty for an inactive segment.
    ///
    /// ```
    /// use oxray_bvh::curve::CurveSegment;
    /// use oxray_core::CurveType;
    /// // A diagonal straight segment: the halves' boxes are a quarter of the whole's volume.
    /// let s = CurveSegment::new(CurveType::RoundLinear, &[[0.0, 0.0, 0.0, 0.1], [4.0, 4.0, 0.0, 0.1]], 0, None);
    /// assert_eq!(s.bounds_over(0.0, 1.0), s.bounds());
    /// let (a, b) = (s.bounds_over(0.0, 0.5), s.bounds_over(0.5, 1.0));
    /// assert!(a.max.x < 2.2 && b.min.x > 1.8 && s.bounds().contains_box(&a.union(&b)));
    /// ```
    #[must_use]
    pub fn bounds_over(&self, u0: f64, u1: f64) -> Aabb {
        let Some(ty) = self.active_type() else {
            return Aabb::EMPTY;
        };
        let a = self.power_basis_of(ty);
        let a = if (u0, u1) == (0.0, 1.0) {
            a
        } else {
            // c(u0 + h s) in powers of s.
            let h = u1 - u0;
            let mut b = [[0.0; 4]; 4];
            for d in 0..4 {
                let (a0, a1, a2, a3) = (a[0][d], a[1][d], a[2][d], a[3][d]);
                b[0][d] = ((a3 * u0 + a2) * u0 + a1) * u0 + a0;
                b[1][d] = h * ((3.0 * a3 * u0 + 2.0 * a2) * u0 + a1);
                b[2][d] = h * h * (3.0 * a3 * u0 + a2);
                b[3][d] = h * h * h * a3;
            }
            b
        };
        hull_box(&bezier_points(&a))
    }

    /// How many pieces [`CurveSplits`] cuts the segment into (at least 1): about its length
    /// (the length of its Bézier control polygon, which bounds the centre line's) over its width
    /// (twice its largest radius coefficient) over `splits.width_ratio`, at most
    /// `splits.max_pieces`. 1 for an inactive segment.
    #[must_use]
    pub fn pieces(&self, splits: &CurveSplits) -> u32 {
        let Some(ty) = self.active_type() else {
            return 1;
        };
        let b = bezier_points(&self.power_basis_of(ty));
        let r = b.iter().fold(0.0f64, |m, p| m.max(p[3]));
        let length: f64 = b
            .windows(2)
            .map(|w| DVec3::new(w[1][0] - w[0][0], w[1][1] - w[0][1], w[1][2] - w[0][2]).length())
            .sum();
        let n = length / (2.0 * r * splits.width_ratio as f64);
        // NaN (no radius, no length) and small ratios: one piece.
        if n >= 2.0 {
            (n as u32).min(splits.max_pieces.max(1))
        } else {
            1
        }
    }

    /// The nearest front-face hit (or ribbon hit) of the ray `org + t dir` in `[tmin, tmax]`;
    /// `dir` need not be normalised.
    #[must_use]
    pub fn intersect(&self, org: Vec3, dir: Vec3, tmin: f32, tmax: f32) -> Option<CurveHit> {
        let len = dir.as_dvec3().length();
        // NaN (a NaN direction) fails the compare: no hit.
        if len.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return None;
        }
        let ty = self.active_type()?;
        let frame = RayFrame::new(org.as_dvec3(), dir.as_dvec3() / len);
        // Distances along the ray in world units.
        let (zmin, zmax) = (tmin as f64 * len, tmax as f64 * len);
        let a = self.power_basis_of(ty);
        let mut x = [0.0; 4];
        let mut y = [0.0; 4];
        let mut z = [0.0; 4];
        let mut r = [0.0; 4];
        for k in 0..4 {
            let q = DVec3::new(a[k][0], a[k][1], a[k][2]);
            let q = if k == 0 { q - frame.o } else { q };
            x[k] = q.dot(frame.e1);
            y[k] = q.dot(frame.e2);
            z[k] = q.dot(frame.d);
            r[k] = a[k][3];
        }
        // Cheap rejection on the Bézier hull in the ray's frame.
        let rmax = bezier_points(&a)
            .iter()
            .fold(0.0f64, |m, p| m.max(p[3].abs()));
        let (bx, by, bz) = (bezier_1d(&x), bezier_1d(&y), bezier_1d(&z));
        let hull = |b: &[f64; 4]| {
            b.iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &v| {
                    (l.min(v), h.max(v))
                })
        };
        let (hx, hy, hz) = (hull(&bx), hull(&by), hull(&bz));
        if hx.0 - rmax > 0.0
            || hx.1 + rmax < 0.0
            || hy.0 - rmax > 0.0
            || hy.1 + rmax < 0.0
            || hz.1 + rmax < zmin
            || hz.0 - rmax > zmax
        {
            return None;
        }
        // The ray's line runs along z through the frame's origin: it misses when the origin
        // is farther than the largest radius from the Bézier hull of the centre line projected
        // on the xy plane (most of the segments whose boxes a ray enters in a head of hair).
        let xy: [[f64; 2]; 4] = std::array::from_fn(|k| [bx[k], by[k]]);
        if hull_distance_2d(&xy) > rmax {
            return None;
        }
        let (px, py, pz, pr) = (Poly::new(&x), Poly::new(&y), Poly::new(&z), Poly::new(&r));
        // D(u) = r² - x² - y²: the ray's line meets S(u) where D >= 0.
        let dd = pr
            .mul(&pr)
            .add_scaled(&px.mul(&px), -1.0)
            .add_scaled(&py.mul(&py), -1.0);
        let (t, hit) = if ty.is_ribbon() {
            self.ribbon(&frame, &a, (&px, &py, &pz, &pr), &dd, zmin, zmax)
        } else {
            let linear = ty == CurveType::RoundLinear;
            self.round(&frame, &a, linear, &pz, &dd, (zmin, zmax), (hz, rmax))
        }?;
        let t = (t / len) as f32;
        // Rounding to f32 must not carry the hit out of the interval.
        (t >= tmin && t <= tmax).then_some(CurveHit { t, ..hit })
    }

    /// The round-curve test in the ray's frame (`a` the power basis, `linear` for
    /// [`CurveType::RoundLinear`]); `t` of the result is in world units.
    #[allow(clippy::too_many_arguments)]
    fn round(
        &self,
        frame: &RayFrame,
        a: &[[f64; 4]; 4],
        linear: bool,
        pz: &Poly,
        dd: &Poly,
        (zmin, zmax): (f64, f64),
        (hz, rmax): ((f64, f64), f64),
    ) -> Option<(f64, CurveHit)> {
        // Intervals of [0, 1] where D >= 0, between D's roots; none: the line misses.
        let mut roots = [0.0; MAX_COEFFS];
        let nr = dd.roots(0.0, 1.0, &mut roots);
        if nr == 0 && dd.eval(0.5) < 0.0 {
            return None;
        }
        // A ray whose interval starts inside the tube does not hit it (§9.6):
        // E(u) = (Z - zmin)² - D(u) < 0 somewhere (at an end only where the end is a sphere).
        // Only a start within the largest radius of the hull can be inside.
        if zmin >= hz.0 - rmax && zmin <= hz.1 + rmax {
            let zs = pz.add_scaled(&Poly::new(&[1.0]), -zmin);
            let e = zs.mul(&zs).add_scaled(dd, -1.0);
            let mut crit = [0.0; MAX_COEFFS];
            let nc = e.derivative().roots(0.0, 1.0, &mut crit);
            if crit[..nc]
                .iter()
                .any(|&u| u > 0.0 && u < 1.0 && e.eval(u) < 0.0)
                || (linear && (e.eval(0.0) < 0.0 || e.eval(1.0) < 0.0))
            {
                return None;
            }
        }

        let t0 = |u: f64| {
            let d = dd.eval(u);
            if d >= 0.0 {
                pz.eval(u) - d.sqrt()
            } else {
                f64::INFINITY
            }
        };
        let mut best: Option<(f64, f64)> = None;
        let mut offer = |t: f64, u: f64| {
            if t >= zmin && t <= zmax && best.is_none_or(|(bt, _)| t < bt) {
                best = Some((t, u));
            }
        };
        let mut bounds = [0.0; MAX_COEFFS + 2];
        bounds[0] = 0.0;
        bounds[1..=nr].copy_from_slice(&roots[..nr]);
        bounds[nr + 1] = 1.0;
        // Critical points of t₀: roots of P = 4 Z'² D - D'² where Z' D' >= 0.
        let dz = pz.derivative();
        let dd1 = dd.derivative();
        let p = dz.mul(&dz).mul(dd).add_scaled(&dd1.mul(&dd1), -0.25);
        let mut cp = [0.0; MAX_COEFFS];
        let ncp = p.roots(0.0, 1.0, &mut cp);
        for w in bounds[..nr + 2].windows(2) {
            let (lo, hi) = (w[0], w[1]);
            if hi <= lo || dd.eval(0.5 * (lo + hi)) < 0.0 {
                continue;
            }
            let mut found = false;
            for &u in cp[..ncp].iter().filter(|&&u| u > lo && u < hi) {
                if dz.eval(u) * dd1.eval(u) < 0.0 {
                    continue;
                }
                // A minimum, not a maximum: t₀' = Z' - D' / (2 √D) goes from negative to
                // positive. Its sign a little way off the root is robust where t₀'s values
                // differ by less than their rounding.
                let slope = |v: f64| dz.eval(v) - dd1.eval(v) / (2.0 * dd.eval(v).max(0.0).sqrt());
                let h = 1e-6 * (hi - lo);
                if slope((u - h).max(lo)) <= 0.0 && slope((u + h).min(hi)) >= 0.0 {
                    found = true;
                    offer(t0(u), u);
                }
            }
            // The ends of [0, 1]: spheres of a linear segment; open or flat otherwise.
            for end in [0.0, 1.0] {
                if (lo == end || hi == end) && linear {
                    found = true;
                    offer(t0(end), end);
                }
            }
            if !found && lo > 0.0 && hi < 1.0 {
                // D >= 0 on a sliver too thin for P's roots to separate (a grazing ray): t₀ has a
                // minimum inside, where D peaks.
                let u = golden_min(&t0, lo, hi);
                offer(t0(u), u);
            }
        }
        // Flat caps at the strand's ends (§5.2): discs facing out of the tube.
        for (flag, u) in [(CAP_START, 0.0), (CAP_END, 1.0)] {
            if self.flags & flag == 0 {
                continue;
            }
            let (c, rad) = eval_basis(a, u);
            let n = tangent_basis(a, u);
            let dn = frame.d.dot(n);
            // Entering the tube: along the tangent at the start, against it at the end.
            if (u == 0.0 && dn <= 0.0) || (u == 1.0 && dn >= 0.0) {
                continue;
            }
            let t = (c - frame.o).dot(n) / dn;
            let p = frame.o + frame.d * t;
            if (p - c).length_squared() <= rad * rad {
                offer(t, u);
            }
        }
        best.map(|(t, u)| {
            let hit = CurveHit {
                t: 0.0,
                u: u as f32,
                v: 0.0,
                back_face: false,
            };
            (t, hit)
        })
    }

    /// The ribbon test in the ray's frame; `t` of the result is in world units.
    fn ribbon(
        &self,
        frame: &RayFrame,
        a: &[[f64; 4]; 4],
        (px, py, pz, pr): (&Poly, &Poly, &Poly, &Poly),
        dd: &Poly,
        zmin: f64,
        zmax: f64,
    ) -> Option<(f64, CurveHit)> {
        let mut best: Option<(f64, CurveHit)> = None;
        let mut roots = [0.0; MAX_COEFFS];
        let tangent_frame = |k: usize| {
            let q = DVec3::new(a[k][0], a[k][1], a[k][2]) * k as f64;
            [q.dot(frame.e1), q.dot(frame.e2), q.dot(frame.d)]
        };
        // c'(u) in the ray's frame: linear for a quadratic.
        let (t1, t2) = (tangent_frame(1), tangent_frame(2));
        let tan = |u: f64| DVec3::new(t1[0] + t2[0] * u, t1[1] + t2[1] * u, t1[2] + t2[2] * u);
        let mut consider = |u: f64, w: DVec3| {
            // The ray meets the line c(u) + s w: solve in the frame's xy plane.
            let (xu, yu, zu, ru) = (px.eval(u), py.eval(u), pz.eval(u), pr.eval(u));
            let ww = w.x * w.x + w.y * w.y;
            // A width direction along the ray (edge-on), or no width: no hit (NaN included).
            if ww.is_nan() || ww <= 0.0 || ru.is_nan() || ru <= 0.0 {
                return;
            }
            let s = -(xu * w.x + yu * w.y) / ww;
            let t = zu + s * w.z;
            let v = s * w.length() / ru;
            if !(-1.0..=1.0).contains(&v) || t < zmin || t > zmax {
                return;
            }
            if best.is_some_and(|(bt, _)| bt <= t) {
                return;
            }
            // The ribbon's normal c' × w; facing the ray is the front face.
            let n = tan(u).cross(w);
            let hit = CurveHit {
                t: 0.0,
                u: u as f32,
                v: v as f32,
                back_face: n.z > 0.0,
            };
            best = Some((t, hit));
        };
        if self.flags & HAS_NORMALS != 0 {
            let n0 = DVec3::from(self.normals[0].map(f64::from));
            let n1 = DVec3::from(self.normals[1].map(f64::from));
            let to_frame = |v: DVec3| DVec3::new(v.dot(frame.e1), v.dot(frame.e2), v.dot(frame.d));
            let (n0, n1) = (to_frame(n0), to_frame(n1));
            // W(u) = n(u) × c'(u) (degree 2); the ray meets the line of u where
            // (c(u) - o) · (W × d) = 0, d = z: (W × z) = (W.y, -W.x, 0), so X W.y - Y W.x = 0.
            let nn = |u: f64| n0 + (n1 - n0) * u;
            // Components of W as polynomials: sample at 3 points and interpolate exactly.
            let wpoly = |f: &dyn Fn(DVec3) -> f64| {
                let (w0, wh, w1) = (
                    f(nn(0.0).cross(tan(0.0))),
                    f(nn(0.5).cross(tan(0.5))),
                    f(nn(1.0).cross(tan(1.0))),
                );
                Poly::new(&[w0, 4.0 * wh - 3.0 * w0 - w1, 2.0 * w0 + 2.0 * w1 - 4.0 * wh])
            };
            let (wx, wy) = (wpoly(&|v| v.x), wpoly(&|v| v.y));
            let g = px.mul(&wy).add_scaled(&py.mul(&wx), -1.0);
            let n = g.roots(0.0, 1.0, &mut roots);
            for &u in &roots[..n] {
                consider(u, nn(u).cross(tan(u)));
            }
        } else {
            // Facing the ray: w ⊥ d and ⊥ c', so the ray's point is at the foot of the
            // projected curve's normal: X X' + Y Y' = 0, within the radius (D >= 0).
            let f = px
                .mul(&px.derivative())
                .add_scaled(&py.mul(&py.derivative()), 1.0);
            let n = f.roots(0.0, 1.0, &mut roots);
            for &u in &roots[..n] {
                if dd.eval(u) >= 0.0 {
                    let tu = tan(u);
                    // Oriented so that its normal c' × w points back at the ray: the front.
                    consider(u, DVec3::new(tu.y, -tu.x, 0.0));
                }
            }
        }
        best
    }
}

/// The centre and radius at `u` of the power basis `a`, in `f64`.
#[inline]
fn eval_basis(a: &[[f64; 4]; 4], u: f64) -> (DVec3, f64) {
    let mut v = [0.0; 4];
    for d in 0..4 {
        v[d] = ((a[3][d] * u + a[2][d]) * u + a[1][d]) * u + a[0][d];
    }
    (DVec3::new(v[0], v[1], v[2]), v[3])
}

/// The tangent `c'(u)` of the power basis `a`, in `f64`.
#[inline]
fn tangent_basis(a: &[[f64; 4]; 4], u: f64) -> DVec3 {
    let mut v = [0.0; 3];
    for d in 0..3 {
        v[d] = (3.0 * a[3][d] * u + 2.0 * a[2][d]) * u + a[1][d];
    }
    DVec3::from_array(v)
}

/// Bézier control points of the power basis `a` (degree 3, elevated where lower): their
/// convex hull holds the centre line and their largest radius bounds the radius.
#[inline]
fn bezier_points(a: &[[f64; 4]; 4]) -> [[f64; 4]; 4] {
    let mut b = [[0.0; 4]; 4];
    for d in 0..4 {
        b[0][d] = a[0][d];
        b[1][d] = a[0][d] + a[1][d] / 3.0;
        b[2][d] = a[0][d] + 2.0 * a[1][d] / 3.0 + a[2][d] / 3.0;
        b[3][d] = a[0][d] + a[1][d] + a[2][d] + a[3][d];
    }
    b
}

/// The box of the Bézier control points `b` of a segment's centre line grown by their largest
/// radius, rounded outwards.
fn hull_box(b: &[[f64; 4]; 4]) -> Aabb {
    let r = b.iter().fold(0.0f64, |m, p| m.max(p[3]));
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for p in b {
        let c = DVec3::new(p[0], p[1], p[2]);
        lo = lo.min(c - r);
        hi = hi.max(c + r);
    }
    let pad = |v: DVec3| v.abs() * 1e-6 + DVec3::splat(r * 1e-6);
    let (lo, hi) = (lo - pad(lo), hi + pad(hi));
    Aabb::new(lo.as_vec3(), hi.as_vec3())
}

/// The Bézier control points of one coordinate's power-basis coefficients `c`.
#[inline]
fn bezier_1d(c: &[f64; 4]) -> [f64; 4] {
    [
        c[0],
        c[0] + c[1] / 3.0,
        c[0] + 2.0 * c[1] / 3.0 + c[2] / 3.0,
        c[0] + c[1] + c[2] + c[3],
    ]
}

/// The distance from the origin to the convex hull of four points in the plane: 0 inside
/// (inside one of the triangles of three of them), else the distance to the nearest of the six
/// segments between them (the hull's edges are among them, and all lie in the hull).
fn hull_distance_2d(p: &[[f64; 2]; 4]) -> f64 {
    let cross = |a: [f64; 2], b: [f64; 2]| a[0] * b[1] - a[1] * b[0];
    let inside = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| {
        let (s1, s2, s3) = (cross(a, b), cross(b, c), cross(c, a));
        (s1 >= 0.0 && s2 >= 0.0 && s3 >= 0.0) || (s1 <= 0.0 && s2 <= 0.0 && s3 <= 0.0)
    };
    if inside(p[0], p[1], p[2])
        || inside(p[0], p[1], p[3])
        || inside(p[0], p[2], p[3])
        || inside(p[1], p[2], p[3])
    {
        return 0.0;
    }
    let seg = |a: [f64; 2], b: [f64; 2]| {
        let ab = [b[0] - a[0], b[1] - a[1]];
        let len2 = ab[0] * ab[0] + ab[1] * ab[1];
        let t = if len2 > 0.0 {
            (-(a[0] * ab[0] + a[1] * ab[1]) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let q = [a[0] + ab[0] * t, a[1] + ab[1] * t];
        (q[0] * q[0] + q[1] * q[1]).sqrt()
    };
    let mut d = f64::INFINITY;
    for i in 0..4 {
        for j in i + 1..4 {
            d = d.min(seg(p[i], p[j]));
        }
    }
    d
}

/// An orthonormal frame whose z axis is the ray's direction.
struct RayFrame {
    o: DVec3,
    d: DVec3,
    e1: DVec3,
    e2: DVec3,
}

impl RayFrame {
    fn new(o: DVec3, d: DVec3) -> RayFrame {
        let (e1, e2) = d.any_orthonormal_pair();
        RayFrame { o, d, e1, e2 }
    }
}

/// The minimum of a unimodal `f` on `[lo, hi]` (golden-section search).
fn golden_min(f: &dyn Fn(f64) -> f64, mut lo: f64, mut hi: f64) -> f64 {
    const G: f64 = 0.618_033_988_749_894_8;
    let mut a = hi - G * (hi - lo);
    let mut b = lo + G * (hi - lo);
    let (mut fa, mut fb) = (f(a), f(b));
    for _ in 0..80 {
        if fa < fb {
            hi = b;
            b = a;
            fb = fa;
            a = hi - G * (hi - lo);
            fa = f(a);
        } else {
            lo = a;
            a = b;
            fa = fb;
            b = lo + G * (hi - lo);
            fb = f(b);
        }
        if hi - lo < 1e-15 {
            break;
        }
    }
    0.5 * (lo + hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random_segment(seed: &mut u64, ty: CurveType) -> CurveSegment {
        let mut next = || {
            *seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((*seed >> 40) as f32) / (1u64 << 24) as f32
        };
        let pts: Vec<[f32; 4]> = (0..ty.control_points())
            .map(|_| {
                [
                    next() * 2.0 - 1.0,
                    next() * 2.0 - 1.0,
                    next() * 2.0 - 1.0,
                    0.01 + next() * 0.2,
                ]
            })
            .collect();
        CurveSegment::new(ty, &pts, 0, None)
    }

    /// §5.2, §9.2: the box of a segment, and of each piece of a split segment, holds every
    /// sphere S(u) of its swept surface (of its part), for every curve type (the BVH may then
    /// never cull a hit).
    #[test]
    fn s5_2_bounds_hold_the_swept_surface() {
        let mut seed = 7u64;
        for ty in CurveType::ALL {
            for _ in 0..50 {
                let s = random_segment(&mut seed, ty);
                let b = s.bounds();
                // §9.2: so do the boxes of the pieces of a split segment, each over its part.
                let n = 1 + (s.points[0][0].to_bits() % 7) as usize;
                let pieces: Vec<Aabb> = (0..n)
                    .map(|j| s.bounds_over(j as f64 / n as f64, (j + 1) as f64 / n as f64))
                    .collect();
                for k in 0..=200 {
                    let u = k as f64 / 200.0;
                    let (c, r) = s.eval(u);
                    let (lo, hi) = ((c - r).as_vec3(), (c + r).as_vec3());
                    assert!(
                        b.min.cmple(lo).all() && b.max.cmpge(hi).all(),
                        "{ty}: {b:?} {c} {r}"
                    );
                    let p = pieces[((u * n as f64) as usize).min(n - 1)];
                    assert!(
                        p.min.cmple(lo).all() && p.max.cmpge(hi).all(),
                        "{ty}, {n} pieces: {p:?} {c} {r}"
                    );
                }
            }
        }
    }

    /// The Bézier-hull bounds against the box of the raw control points (valid for uniform
    /// B-splines, whose segments lie in their control points' hull) on curved B-spline
    /// strands: the SAH cost of the BVH over each (printed), the tight one lower.
    #[test]
    fn tight_bounds_lower_the_sah_cost_of_b_spline_strands() {
        use crate::build::{build_bvh2, BuildConfig};
        let mut seed = 11u64;
        let mut next = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 40) as f32) / (1u64 << 24) as f32
        };
        let (mut tight, mut loose) = (Vec::new(), Vec::new());
        for _ in 0..4000 {
            let mut p = Vec3::new(next(), next(), next()) * 10.0;
            let mut h = (Vec3::new(next(), next(), next()) - 0.5).normalize();
            let mut pts = Vec::new();
            for _ in 0..8 {
                pts.push([p.x, p.y, p.z, 0.01]);
                h = (h + (Vec3::new(next(), next(), next()) - 0.5) * 0.6).normalize();
                p += h * 0.2;
            }
            for w in pts.windows(4) {
                let s = CurveSegment::new(CurveType::RoundCubicBSpline, w, 0, None);
                tight.push(s.bounds());
                let b = w.iter().fold(Aabb::EMPTY, |b, q| {
                    let c = Vec3::new(q[0], q[1], q[2]);
                    b.union(&Aabb::new(c - q[3], c + q[3]))
                });
                loose.push(b);
            }
        }
        let sah = |boxes: &[Aabb]| {
            crate::Bvh4::from(&build_bvh2(boxes, &BuildConfig::BALANCED))
                .stats()
                .sah_cost
        };
        let (t, l) = (sah(&tight), sah(&loose));
        println!(
            "SAH cost over {} segments: Bézier hull {t:.2}, control points {l:.2}",
            tight.len()
        );
        assert!(t < l, "{t} vs {l}");
    }

    /// §9.3: across a straight constant-radius segment of every round type, the hit is at the
    /// radius and u where the ray crosses; a ray that passes by misses.
    #[test]
    fn s9_3_a_ray_across_a_straight_segment_hits_at_its_radius() {
        // Each type's control points for the centre line x ∈ [0, 4] (u = x / 4), radius 0.25.
        for ty in CurveType::ALL.into_iter().filter(|t| !t.is_ribbon()) {
            let xs: &[f32] = match ty.control_points() {
                2 => &[0.0, 4.0],
                3 => &[-2.0, 2.0, 6.0],
                _ if matches!(
                    ty,
                    CurveType::RoundCubicBezier | CurveType::RoundCubicBezierRocaps
                ) =>
                {
                    &[0.0, 4.0 / 3.0, 8.0 / 3.0, 4.0]
                }
                _ => &[-4.0, 0.0, 4.0, 8.0],
            };
            let pts: Vec<[f32; 4]> = xs.iter().map(|&x| [x, 0.0, 0.0, 0.25]).collect();
            let s = CurveSegment::new(ty, &pts, 0, None);
            for x in [0.5f32, 1.0, 2.0, 3.5] {
                let h = s
                    .intersect(Vec3::new(x, 0.0, 3.0), -Vec3::Z, 0.0, 10.0)
                    .unwrap();
                assert!(
                    (h.t - 2.75).abs() < 1e-5 && (h.u - x / 4.0).abs() < 1e-5,
                    "{ty}: {h:?}"
                );
                assert!(!h.back_face);
                assert!(s
                    .intersect(Vec3::new(x, 0.3, 3.0), -Vec3::Z, 0.0, 10.0)
                    .is_none());
                // The interval ends before the tube: no hit.
                assert!(s
                    .intersect(Vec3::new(x, 0.0, 3.0), -Vec3::Z, 0.0, 2.7)
                    .is_none());
            }
        }
    }
}
