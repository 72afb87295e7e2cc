//! The surface model: the glTF metallic-roughness BRDF (Lambertian diffuse plus a GGX microfacet
//! specular lobe with Smith shadowing and Schlick Fresnel, sampled through the distribution of
//! visible normals) and a smooth dielectric for transmissive materials.
//!
//! The BRDF conserves energy: the GGX lobe is scaled by Turquin's multiple-scattering factor
//! `1 + f0 (1 - E(cos θo)) / E(cos θo)`, with `E` the single-scattering albedo
//! ([`crate::albedo`]), and the diffuse layer receives what the compensated specular coat does
//! not reflect, `1 - E_spec(cos θo)`, so that a white surface reflects all the light it receives
//! (a white furnace returns 1) at every roughness, metal or not. The specular coat's strength is
//! the material's `specular` (glTF `KHR_materials_specular`): 0 leaves a Lambertian surface. The
//! diffuse layer's weight depends on the outgoing direction only, which keeps the albedo exact
//! at the price of reciprocity (the renderer traces from the camera only).

use super::albedo::GgxAlbedo;
use glam::Vec3;
use std::f32::consts::{FRAC_1_PI, PI, TAU};

/// A random number stream: a PCG hash step per draw, seeded per pixel and sample so that images
/// do not depend on the thread count.
#[derive(Clone, Copy, Debug)]
pub struct Rng(pub u32);

impl Rng {
    /// A stream for pixel `pixel`, sample `sample` and a purpose `salt`.
    #[must_use]
    pub fn new(pixel: u32, sample: u32, salt: u32) -> Rng {
        Rng(hash(pixel ^ hash(sample.wrapping_add(hash(salt)))))
    }

    /// A uniform number in [0, 1).
    pub fn uniform(&mut self) -> f32 {
        self.0 = self.0.wrapping_mul(747796405).wrapping_add(2891336453);
        let w = ((self.0 >> ((self.0 >> 28) + 4)) ^ self.0).wrapping_mul(277803737);
        ((w >> 22) ^ w) as f32 * (1.0 / 4294967296.0)
    }
}

/// A 32-bit integer hash (PCG output permutation).
#[must_use]
pub const fn hash(x: u32) -> u32 {
    let s = x.wrapping_mul(747796405).wrapping_add(2891336453);
    let w = ((s >> ((s >> 28) + 4)) ^ s).wrapping_mul(277803737);
    (w >> 22) ^ w
}

/// Luminance of a linear Rec. 709 colour.
#[must_use]
pub fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

/// The material at a surface point, after texturing.
#[derive(Clone, Copy, Debug)]
pub struct Surface {
    /// Linear base colour.
    pub base: Vec3,
    /// Metalness in [0, 1].
    pub metallic: f32,
    /// GGX alpha (perceptual roughness squared, kept above a floor so that the lobe stays
    /// representable in f32).
    pub alpha: f32,
    /// Whether this is a smooth dielectric (transmission).
    pub dielectric: bool,
    /// Index of refraction of a dielectric.
    pub ior: f32,
    /// Strength of the non-metallic part's specular coat in [0, 1] (0: Lambertian).
    pub specular: f32,
}

impl Surface {
    /// Builds the surface from glTF factors; `specular` is `KHR_materials_specular`'s factor.
    #[must_use]
    pub fn new(
        base: Vec3,
        metallic: f32,
        roughness: f32,
        transmission: f32,
        ior: f32,
        specular: f32,
    ) -> Self {
        let r = roughness.clamp(0.0, 1.0);
        Surface {
            base,
            metallic: metallic.clamp(0.0, 1.0),
            alpha: (r * r).max(super::albedo::MIN_ALPHA),
            dielectric: transmission >= 0.5,
            ior: if ior.is_finite() && ior >= 1.0 {
                ior
            } else {
                1.5
            },
            // NaN: glTF's default coat.
            specular: if specular >= 0.0 {
                specular.min(1.0)
            } else if specular < 0.0 {
                0.0
            } else {
                1.0
            },
        }
    }
}

/// The outgoing direction's share of the BRDF ([`Surface::lobes`]).
struct Lobes {
    /// Turquin's multiple-scattering factor on the GGX lobe.
    compensation: Vec3,
    /// The diffuse layer's reflectance: the diffuse colour times what the coat lets through.
    diffuse: Vec3,
    /// Probability of sampling the specular lobe.
    p_spec: f32,
}

/// A direction drawn from the BSDF.
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    /// The new direction (unit, pointing away from the surface).
    pub wi: Vec3,
    /// BSDF times cosine over pdf.
    pub weight: Vec3,
    /// Solid-angle pdf; 0 for a specular (delta) event.
    pub pdf: f32,
}

/// The sine and cosine of `2 pi u` (`u` in turns), to within about one unit in the last
/// place, in plain arithmetic: no call to the maths library, so the wavefront's lanes compute
/// eight at once ([`crate::wavefront`]) and get the bits the one-path code gets.
///
/// The angle is reduced exactly (`4u` minus its nearest integer: a quarter turn `q` and a
/// remainder in [-1/2, 1/2] of a quarter turn), the remainder's sine and cosine come from
/// their Taylor polynomials on [-pi/4, pi/4] (truncation below 2e-9), and the quarter turn
/// swaps and negates them.
///
/// ```
/// let (s, c) = oxray_render::bsdf::sin_cos_turns(0.125);
/// assert!((s - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-7);
/// assert!((c - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-7);
/// ```
#[inline(always)]
#[must_use]
pub fn sin_cos_turns(u: f32) -> (f32, f32) {
    let four = u * 4.0;
    let q = four.round();
    let x = (four - q) * std::f32::consts::FRAC_PI_2;
    let x2 = x * x;
    let s = x
        * (1.0
            + x2 * (-1.0 / 6.0
                + x2 * (1.0 / 120.0 + x2 * (-1.0 / 5040.0 + x2 * (1.0 / 362_880.0)))));
    let c = 1.0
        + x2 * (-0.5
            + x2 * (1.0 / 24.0
                + x2 * (-1.0 / 720.0 + x2 * (1.0 / 40_320.0 + x2 * (-1.0 / 3_628_800.0)))));
    // Clamped (NaN stays NaN, which the cast maps to 0), as `device_programs.cu` does before its
    // conversion (NaN to the low end, also a multiple of 4); only the last two bits matter.
    // Selects rather than a match, so that eight lanes of it stay vector code.
    let q = q.clamp(-1_048_576.0, 1_048_576.0) as i32;
    let (s, c) = if q & 1 == 0 { (s, c) } else { (c, s) };
    let s = if q & 2 == 0 { s } else { -s };
    let c = if q.wrapping_add(1) & 2 == 0 { c } else { -c };
    (s, c)
}

/// An orthonormal basis around `n`.
#[must_use]
pub fn basis(n: Vec3) -> (Vec3, Vec3) {
    n.any_orthonormal_pair()
}

fn to_local(v: Vec3, n: Vec3, t: Vec3, b: Vec3) -> Vec3 {
    Vec3::new(v.dot(t), v.dot(b), v.dot(n))
}

fn pow5(x: f32) -> f32 {
    let x2 = x * x;
    x2 * x2 * x
}

fn schlick(f0: Vec3, f90: f32, cos: f32) -> Vec3 {
    f0 + (Vec3::splat(f90) - f0) * pow5(1.0 - cos.clamp(0.0, 1.0))
}

fn ggx_d(nh: f32, a2: f32) -> f32 {
    let d = nh * nh * (a2 - 1.0) + 1.0;
    a2 / (PI * d * d)
}

pub(crate) fn smith_g1(nv: f32, a2: f32) -> f32 {
    2.0 * nv / (nv + (a2 + (1.0 - a2) * nv * nv).sqrt())
}

impl Surface {
    /// Reflectance at normal incidence: the coat's 4 % (scaled by `specular`) for the
    /// dielectric part, the base colour for the metallic part.
    fn f0(&self) -> Vec3 {
        Vec3::splat(0.04 * self.specular).lerp(self.base, self.metallic)
    }

    /// Reflectance at grazing incidence.
    fn f90(&self) -> f32 {
        self.specular + (1.0 - self.specular) * self.metallic
    }

    fn diffuse_colour(&self) -> Vec3 {
        self.base * (1.0 - self.metallic)
    }

    /// Whether the surface is Lambertian (no coat, no metal). Its GGX lobe is then exactly
    /// zero (every term is a product with a zero Fresnel factor) and is never sampled, so
    /// [`eval`](Self::eval) and [`sample`](Self::sample) skip it, with the same bits.
    fn lambertian(&self) -> bool {
        !self.dielectric && self.specular == 0.0 && self.metallic == 0.0
    }

    /// Whether the surface is Lambertian (no coat, no metal, not a dielectric).
    #[must_use]
    pub fn is_lambertian(&self) -> bool {
        self.lambertian()
    }

    /// What depends on the outgoing direction only: Turquin's factor that scales the GGX lobe,
    /// the compensated lobe's albedo `E_spec`, and the probability of sampling the specular
    /// lobe rather than the diffuse one (in proportion to their albedos, so that a pure metal
    /// never wastes a sample on the empty diffuse lobe, nor a Lambertian surface on the empty
    /// specular one).
    fn lobes(&self, cos_o: f32) -> Lobes {
        let (a, b) = GgxAlbedo::get().lookup(cos_o, self.alpha);
        let f0 = self.f0();
        let e = (a + b).max(1e-4);
        let compensation = Vec3::ONE + f0 * ((1.0 - e) / e);
        let e_spec = ((f0 * a + Vec3::splat(self.f90() * b)) * compensation).min(Vec3::ONE);
        let diffuse = self.diffuse_colour() * (Vec3::ONE - e_spec);
        let s = luminance(e_spec);
        let d = luminance(diffuse);
        let p_spec = if s <= 0.0 {
            0.0
        } else if d <= 0.0 {
            1.0
        } else {
            (s / (s + d)).clamp(0.05, 0.95)
        };
        Lobes {
            compensation,
            diffuse,
            p_spec,
        }
    }

    /// BSDF value times |cos| at `wi` and the pdf with which [`Surface::sample`] would draw
    /// `wi`, for the shading normal `n` (facing `wo`). Dielectrics are pure specular: (0, 0).
    #[must_use]
    pub fn eval(&self, n: Vec3, wo: Vec3, wi: Vec3) -> (Vec3, f32) {
        let (cos_o, cos_i) = (n.dot(wo), n.dot(wi));
        if self.dielectric || cos_o <= 0.0 || cos_i <= 0.0 {
            return (Vec3::ZERO, 0.0);
        }
        if self.lambertian() {
            return (self.base * (FRAC_1_PI * cos_i), cos_i * FRAC_1_PI);
        }
        self.eval_lobes(n, wo, wi, cos_o, cos_i)
    }

    /// [`eval`](Self::eval) with both lobes, for a non-dielectric and directions above the
    /// surface.
    fn eval_lobes(&self, n: Vec3, wo: Vec3, wi: Vec3, cos_o: f32, cos_i: f32) -> (Vec3, f32) {
        let h = (wo + wi).normalize();
        let (nh, oh) = (n.dot(h).max(0.0), wo.dot(h).max(1e-6));
        let a2 = self.alpha * self.alpha;
        let d = ggx_d(nh, a2);
        let g1o = smith_g1(cos_o, a2);
        let lobes = self.lobes(cos_o);
        let f = schlick(self.f0(), self.f90(), oh);
        let spec = f * lobes.compensation * (d * g1o * smith_g1(cos_i, a2) / (4.0 * cos_o));
        let diff = lobes.diffuse * (FRAC_1_PI * cos_i);
        let ps = lobes.p_spec;
        let pdf = ps * d * g1o / (4.0 * cos_o) + (1.0 - ps) * cos_i * FRAC_1_PI;
        (spec + diff, pdf)
    }

    /// Draws a direction. `wo` points away from the surface; `n` is the shading normal facing
    /// `wo`; `entering` says whether the ray arrived from outside a dielectric. `None` when the
    /// path ends (the sample fell below the surface).
    #[must_use]
    pub fn sample(&self, n: Vec3, wo: Vec3, entering: bool, u: [f32; 3]) -> Option<BsdfSample> {
        if self.dielectric {
            return Some(self.sample_dielectric(n, wo, entering, u[0]));
        }
        let cos_o = n.dot(wo);
        if cos_o <= 0.0 {
            return None;
        }
        let (t, b) = basis(n);
        let wi = if !self.lambertian() && u[0] < self.lobes(cos_o).p_spec {
            let wo_l = to_local(wo, n, t, b);
            let h = sample_vndf(wo_l, self.alpha, u[1], u[2]);
            let h = t * h.x + b * h.y + n * h.z;
            2.0 * wo.dot(h) * h - wo
        } else {
            let r = u[1].sqrt();
            let (sin_phi, cos_phi) = sin_cos_turns(u[2]);
            (t * (r * cos_phi) + b * (r * sin_phi) + n * (1.0 - u[1]).max(0.0).sqrt()).normalize()
        };
        let (f, pdf) = self.eval(n, wo, wi);
        if pdf <= 0.0 || !pdf.is_finite() {
            return None;
        }
        Some(BsdfSample {
            wi,
            weight: f / pdf,
            pdf,
        })
    }

    fn sample_dielectric(&self, n: Vec3, wo: Vec3, entering: bool, u: f32) -> BsdfSample {
        let eta = if entering { 1.0 / self.ior } else { self.ior };
        let cos_o = n.dot(wo).clamp(0.0, 1.0);
        let sin2_t = eta * eta * (1.0 - cos_o * cos_o);
        let reflect = 2.0 * cos_o * n - wo;
        if sin2_t >= 1.0 {
            // Total internal reflection.
            return BsdfSample {
                wi: reflect,
                weight: Vec3::ONE,
                pdf: 0.0,
            };
        }
        let cos_t = (1.0 - sin2_t).sqrt();
        let rs = (eta * cos_o - cos_t) / (eta * cos_o + cos_t);
        let rp = (cos_o - eta * cos_t) / (cos_o + eta * cos_t);
        let fr = 0.5 * (rs * rs + rp * rp);
        if u < fr {
            BsdfSample {
                wi: reflect,
                weight: Vec3::ONE,
                pdf: 0.0,
            }
        } else {
            BsdfSample {
                wi: (-wo * eta + n * (eta * cos_o - cos_t)).normalize(),
                // The base colour tints transmitted light (glTF transmission).
                weight: self.base,
                pdf: 0.0,
            }
        }
    }
}

/// Samples a GGX visible normal (Heitz 2018) in the local frame where the normal is +Z.
pub(crate) fn sample_vndf(wo: Vec3, alpha: f32, u1: f32, u2: f32) -> Vec3 {
    let vh = Vec3::new(alpha * wo.x, alpha * wo.y, wo.z).normalize();
    let len2 = vh.x * vh.x + vh.y * vh.y;
    let t1 = if len2 > 0.0 {
        Vec3::new(-vh.y, vh.x, 0.0) / len2.sqrt()
    } else {
        Vec3::X
    };
    let t2 = vh.cross(t1);
    let r = u1.sqrt();
    let phi = TAU * u2;
    let p1 = r * phi.cos();
    let s = 0.5 * (1.0 + vh.z);
    let p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * r * phi.sin();
    let nh = t1 * p1 + t2 * p2 + vh * (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt();
    Vec3::new(alpha * nh.x, alpha * nh.y, nh.z.max(1e-6)).normalize()
}

#[cfg(test)]
mod tests {
    /// The sine and cosine in turns against the f64 library's, over the unit interval and
    /// beyond it (the reduction), and at the quarter turns exactly.
    #[test]
    fn sin_cos_turns_is_within_an_ulp_or_two() {
        let mut worst = 0.0f64;
        let n = 1 << 20;
        for i in 0..=n {
            for u in [i as f32 / n as f32, i as f32 / n as f32 * 3.0 - 1.0] {
                let (s, c) = sin_cos_turns(u);
                let a = std::f64::consts::TAU * f64::from(u);
                worst = worst.max((f64::from(s) - a.sin()).abs());
                worst = worst.max((f64::from(c) - a.cos()).abs());
            }
        }
        assert!(worst < 1.2e-7, "largest error {worst:e}");
        for (u, s, c) in [
            (0.0, 0.0, 1.0),
            (0.25, 1.0, 0.0),
            (0.5, 0.0, -1.0),
            (0.75, -1.0, 0.0),
        ] {
            assert_eq!(sin_cos_turns(u), (s, c), "u = {u}");
        }
    }
    use super::*;

    #[test]
    fn the_lambertian_shortcut_gives_the_bits_of_both_lobes() {
        // Every roughness (the lobe's terms stay finite down to the smallest alpha), coloured
        // bases, directions all over the hemisphere, grazing ones included.
        let mut seed = 0x9e37_79b9_u32;
        let mut next = || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (seed >> 8) as f32 / (1u32 << 24) as f32
        };
        let n = Vec3::new(0.2, 0.9, -0.3).normalize();
        let (t, b) = basis(n);
        let dir = |next: &mut dyn FnMut() -> f32| {
            let (u1, u2) = (next(), next());
            let r = (1.0 - u1 * u1).sqrt();
            let phi = TAU * u2;
            t * (r * phi.cos()) + b * (r * phi.sin()) + n * u1
        };
        for k in 0..2000 {
            let base = Vec3::new(next(), next(), next());
            let roughness = (k % 11) as f32 / 10.0;
            let s = Surface::new(base, 0.0, roughness, 0.0, 1.5, 0.0);
            assert!(s.lambertian());
            let (wo, wi) = (dir(&mut next), dir(&mut next));
            let (cos_o, cos_i) = (n.dot(wo), n.dot(wi));
            if cos_o <= 0.0 || cos_i <= 0.0 {
                continue;
            }
            let (f, pdf) = s.eval(n, wo, wi);
            let (g, gpdf) = s.eval_lobes(n, wo, wi, cos_o, cos_i);
            assert_eq!(
                (f.to_array().map(f32::to_bits), pdf.to_bits()),
                (g.to_array().map(f32::to_bits), gpdf.to_bits()),
                "roughness {roughness}, cos {cos_o} {cos_i}"
            );
        }
        // A coat or a metal is not Lambertian.
        assert!(!Surface::new(Vec3::ONE, 0.0, 1.0, 0.0, 1.5, 1.0).lambertian());
        assert!(!Surface::new(Vec3::ONE, 0.5, 1.0, 0.0, 1.5, 0.0).lambertian());
    }

    fn estimate_albedo(s: &Surface, wo: Vec3, n: usize) -> (Vec3, f32) {
        // Mean of weight (the directional albedo) and the importance-sampling check: the mean of
        // f/pdf over uniform hemisphere samples must match the mean of weight over BSDF samples.
        let mut rng = Rng::new(1, 2, 3);
        let mut sum = Vec3::ZERO;
        let mut uniform = 0.0;
        for _ in 0..n {
            if let Some(smp) = s.sample(
                Vec3::Z,
                wo,
                true,
                [rng.uniform(), rng.uniform(), rng.uniform()],
            ) {
                sum += smp.weight;
            }
            let (u1, u2) = (rng.uniform(), rng.uniform());
            let z = u1;
            let r = (1.0 - z * z).sqrt();
            let wi = Vec3::new(r * (TAU * u2).cos(), r * (TAU * u2).sin(), z);
            uniform += luminance(s.eval(Vec3::Z, wo, wi).0) * TAU;
        }
        (sum / n as f32, uniform / n as f32)
    }

    #[test]
    fn white_lambert_reflects_everything() {
        let s = Surface::new(Vec3::ONE, 0.0, 1.0, 0.0, 1.5, 1.0);
        let (albedo, uniform) = estimate_albedo(&s, Vec3::Z, 200_000);
        // Fresnel takes a few percent for the specular lobe; the total stays at most 1.
        assert!(
            luminance(albedo) > 0.9 && luminance(albedo) <= 1.02,
            "{albedo}"
        );
        assert!(
            (luminance(albedo) - uniform).abs() < 0.03,
            "{albedo} vs {uniform}"
        );
    }

    #[test]
    fn white_furnace_reflects_everything_at_every_roughness() {
        // A white surface in a uniform white environment reflects all the light it receives:
        // its directional albedo (the mean BSDF-sample weight) is 1 for every roughness and
        // direction, metal or dielectric-coated diffuse; without the multiple-scattering
        // compensation a rough metal keeps 0.77 at normal incidence and less at grazing.
        let mut worst = 0.0f32;
        for (kind, metallic) in [("metal", 1.0), ("coated diffuse", 0.0)] {
            for roughness in [0.0, 0.1, 0.25, 0.5, 0.75, 1.0] {
                let s = Surface::new(Vec3::ONE, metallic, roughness, 0.0, 1.5, 1.0);
                let mut row = String::new();
                for cos_o in [0.1f32, 0.3, 0.5, 0.7, 0.9, 1.0] {
                    let wo = Vec3::new((1.0 - cos_o * cos_o).sqrt(), 0.0, cos_o);
                    let (albedo, uniform) = estimate_albedo(&s, wo, 40_000);
                    let a = luminance(albedo);
                    row += &format!(" {a:.4}");
                    worst = worst.max((a - 1.0).abs());
                    assert!(
                        (a - 1.0).abs() < 0.01,
                        "{kind}, roughness {roughness}, cos {cos_o}: albedo {a}"
                    );
                    // Sampling and evaluation agree (the pdf is the sampled density); uniform
                    // directions cannot estimate a near-mirror lobe.
                    if roughness >= 0.25 {
                        assert!((a - uniform).abs() < 0.05, "{a} vs {uniform}");
                    }
                }
                println!("furnace, {kind}, roughness {roughness}: albedo at cos 0.1..1:{row}");
            }
        }
        println!("furnace: largest deviation from 1: {worst:.4}");
    }

    #[test]
    fn lambertian_surfaces_have_no_specular_coat() {
        // specular = 0 (OBJ illum 1, KHR_materials_specular 0): exactly base / pi, sampled by
        // the cosine alone.
        let s = Surface::new(Vec3::new(0.5, 0.25, 0.75), 0.0, 0.2, 0.0, 1.5, 0.0);
        let wo = Vec3::new(0.6, 0.0, 0.8);
        for wi in [
            Vec3::Z,
            Vec3::new(-0.6, 0.0, 0.8),
            Vec3::new(0.0, 0.995, 0.0998),
        ] {
            let wi = wi.normalize();
            let (f, pdf) = s.eval(Vec3::Z, wo, wi);
            let expected = s.base * (FRAC_1_PI * wi.z);
            assert!(
                (f - expected).abs().max_element() < 1e-6,
                "{f} vs {expected}"
            );
            assert!((pdf - wi.z * FRAC_1_PI).abs() < 1e-6);
        }
        let (albedo, _) = estimate_albedo(&s, wo, 20_000);
        assert!((albedo - s.base).abs().max_element() < 1e-4, "{albedo}");
    }

    #[test]
    fn sampling_matches_evaluation_for_rough_metal() {
        let s = Surface::new(Vec3::new(0.9, 0.6, 0.3), 1.0, 0.5, 0.0, 1.5, 1.0);
        let wo = Vec3::new(0.6, 0.0, 0.8);
        let (albedo, uniform) = estimate_albedo(&s, wo, 400_000);
        assert!(
            (luminance(albedo) - uniform).abs() < 0.03,
            "{albedo} vs {uniform}"
        );
        assert!(luminance(albedo) < 1.0);
    }

    #[test]
    fn smooth_metal_is_a_mirror() {
        let s = Surface::new(Vec3::ONE, 1.0, 0.0, 0.0, 1.5, 1.0);
        let wo = Vec3::new(0.6, 0.0, 0.8);
        let mut rng = Rng::new(4, 5, 6);
        // GGX has long tails even at the roughness floor: most samples, not all, are within a
        // hair of the mirror direction.
        let close = (0..1000)
            .filter(|_| {
                let smp = s
                    .sample(
                        Vec3::Z,
                        wo,
                        true,
                        [rng.uniform(), rng.uniform(), rng.uniform()],
                    )
                    .unwrap();
                smp.wi.distance(Vec3::new(-0.6, 0.0, 0.8)) < 0.02
            })
            .count();
        assert!(close > 900, "{close}");
    }

    #[test]
    fn dielectric_refracts_by_snell_and_reflects_totally() {
        let glass = Surface::new(Vec3::ONE, 0.0, 0.0, 1.0, 1.5, 1.0);
        let wo = Vec3::new(0.5, 0.0, 0.75f32.sqrt());
        // u = 0.99 is above the Fresnel reflectance: refraction.
        let t = glass.sample(Vec3::Z, wo, true, [0.99, 0.0, 0.0]).unwrap();
        let sin_t = (t.wi.x * t.wi.x + t.wi.y * t.wi.y).sqrt();
        assert!((sin_t - 0.5 / 1.5).abs() < 1e-5 && t.wi.z < 0.0, "{}", t.wi);
        // From inside at a grazing angle: total internal reflection whatever u.
        let graze = Vec3::new(0.9, 0.0, 0.19f32.sqrt());
        let r = glass
            .sample(Vec3::Z, graze, false, [0.99, 0.0, 0.0])
            .unwrap();
        assert!(r.wi.z > 0.0 && r.pdf == 0.0);
    }

    #[test]
    fn rng_is_uniform_and_in_range() {
        let mut r = Rng::new(7, 0, 0);
        let n = 100_000;
        let mut sum = 0.0;
        for _ in 0..n {
            let x = r.uniform();
            assert!((0.0..1.0).contains(&x));
            sum += x as f64;
        }
        assert!((sum / n as f64 - 0.5).abs() < 0.01);
    }
}
