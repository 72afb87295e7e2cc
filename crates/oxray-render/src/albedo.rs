//! The directional albedo of the single-scattering GGX lobe, tabulated once, for energy
//! compensation (`bsdf.rs`).
//!
//! A GGX microfacet lobe with Smith shadowing models a single bounce on the microsurface: the
//! light that would bounce again is lost, up to a third of it at roughness 1. Two numbers per
//! (cos θo, α) recover it: with Schlick's Fresnel `F = f0 + (f90 - f0) (1 - cos θh)^5`, the
//! lobe reflects
//!
//! ```text
//! E_F(cos θo) = f0 A + f90 B,   A = ∫ f/F (1 - (1 - cos θh)^5) cos θi dωi,
//!                               B = ∫ f/F (1 - cos θh)^5 cos θi dωi,
//! ```
//!
//! and `E = A + B` is the albedo with `F = 1`. The surface model scales the lobe by Turquin's
//! factor `1 + f0 (1 - E) / E` (2019), which makes a white conductor reflect everything, and
//! gives the diffuse layer under a dielectric coat what the coat does not reflect,
//! `1 - E_F (1 + f0 (1 - E) / E)`.
//!
//! The table is [`GgxAlbedo::SIZE`]² cells over cos θo (columns, 0 to 1) and √α (rows, 0 to
//! 1), computed by [`GgxAlbedo::compute`] with stratified visible-normal samples (a fixed
//! quadrature, 4 M samples: a sixth of a second, which every render in a fresh process paid
//! when it was computed on first use). The crate embeds the computed table
//! (`ggx_albedo.bin`, written by `cargo run -p oxray-render --example ggx_albedo_table`; a
//! test checks that it is the computation's), and both versions of the path tracer read it
//! with bilinear interpolation (the C++ programs receive it as a buffer).

use super::bsdf::{sample_vndf, smith_g1};
use glam::Vec3;
use std::sync::OnceLock;

/// The tabulated albedo terms `A` and `B` of the GGX lobe (see the module documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct GgxAlbedo {
    /// `[A, B]` per cell, row-major: row `i` is √α = i / (SIZE - 1), column `j` is
    /// cos θo = j / (SIZE - 1).
    pub cells: Vec<[f32; 2]>,
}

/// The computed table, embedded (see the module documentation).
const EMBEDDED: &[u8] = include_bytes!("ggx_albedo.bin");

/// The smallest α the surface model uses (GGX must stay representable in f32).
pub const MIN_ALPHA: f32 = 2e-3;

impl GgxAlbedo {
    /// Cells along each axis.
    pub const SIZE: usize = 32;

    /// The table ([`compute`](Self::compute) with 64² samples per cell, embedded in the
    /// crate).
    pub fn get() -> &'static GgxAlbedo {
        static TABLE: OnceLock<GgxAlbedo> = OnceLock::new();
        TABLE.get_or_init(|| GgxAlbedo::from_bytes(EMBEDDED).unwrap_or_else(|| Self::compute(64)))
    }

    /// The table as little-endian `f32` pairs, row by row (what `ggx_albedo.bin` holds).
    #[must_use]
    pub fn to_bytes(&self) -> Vec<u8> {
        self.cells
            .iter()
            .flatten()
            .flat_map(|x| x.to_le_bytes())
            .collect()
    }

    /// The table from [`to_bytes`](Self::to_bytes)'s layout; `None` if the size is not
    /// [`SIZE`](Self::SIZE)² cells.
    #[must_use]
    pub fn from_bytes(bytes: &[u8]) -> Option<GgxAlbedo> {
        if bytes.len() != Self::SIZE * Self::SIZE * 8 {
            return None;
        }
        let floats: Vec<f32> = bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        Some(GgxAlbedo {
            cells: floats.chunks_exact(2).map(|c| [c[0], c[1]]).collect(),
        })
    }

    /// Computes the table with `strata`² visible-normal samples per cell (stratified, at the
    /// strata's centres): the estimator of `A + B` is `G1(ωi)` per sample, whose variance is
    /// small, so 64² samples give about three correct digits.
    #[must_use]
    pub fn compute(strata: usize) -> GgxAlbedo {
        let n = Self::SIZE;
        let mut cells = Vec::with_capacity(n * n);
        for i in 0..n {
            let r = i as f32 / (n - 1) as f32;
            let alpha = (r * r).max(MIN_ALPHA);
            let a2 = alpha * alpha;
            for j in 0..n {
                // Grazing directions are reached only in the limit; the first column stands
                // for cos θo = 1e-3.
                let mu = (j as f32 / (n - 1) as f32).max(1e-3);
                let wo = Vec3::new((1.0 - mu * mu).sqrt(), 0.0, mu);
                let (mut a, mut b) = (0.0f64, 0.0f64);
                for sy in 0..strata {
                    for sx in 0..strata {
                        let u1 = (sx as f32 + 0.5) / strata as f32;
                        let u2 = (sy as f32 + 0.5) / strata as f32;
                        let h = sample_vndf(wo, alpha, u1, u2);
                        let oh = wo.dot(h);
                        let wi = 2.0 * oh * h - wo;
                        if wi.z <= 0.0 || oh <= 0.0 {
                            continue;
                        }
                        // f cos / pdf of visible-normal sampling: G2 / G1(ωo) = G1(ωi).
                        let w = smith_g1(wi.z, a2) as f64;
                        let s = (1.0 - oh as f64).powi(5);
                        a += w * (1.0 - s);
                        b += w * s;
                    }
                }
                let k = 1.0 / (strata * strata) as f64;
                cells.push([(a * k) as f32, (b * k) as f32]);
            }
        }
        GgxAlbedo { cells }
    }

    /// `(A, B)` at `cos_o` and `alpha`, interpolated bilinearly (the same arithmetic as the
    /// C++ programs' `ggx_albedo`).
    #[must_use]
    pub fn lookup(&self, cos_o: f32, alpha: f32) -> (f32, f32) {
        let last = (Self::SIZE - 1) as f32;
        // NaN reads as 0 (the comparisons fail), so that the index stays in the table.
        let x = if cos_o > 0.0 { cos_o.min(1.0) } else { 0.0 } * last;
        let y = if alpha > 0.0 {
            alpha.sqrt().min(1.0)
        } else {
            0.0
        } * last;
        let (x0, y0) = (
            (x as usize).min(Self::SIZE - 2),
            (y as usize).min(Self::SIZE - 2),
        );
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let c = |yy: usize, xx: usize| self.cells[yy * Self::SIZE + xx];
        let lerp = |p: [f32; 2], q: [f32; 2], t: f32| {
            [p[0] * (1.0 - t) + q[0] * t, p[1] * (1.0 - t) + q[1] * t]
        };
        let top = lerp(c(y0, x0), c(y0, x0 + 1), fx);
        let bottom = lerp(c(y0 + 1, x0), c(y0 + 1, x0 + 1), fx);
        let v = lerp(top, bottom, fy);
        (v[0], v[1])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smooth_lobes_lose_nothing_and_rough_ones_lose_up_to_a_third() {
        let t = GgxAlbedo::get();
        let n = GgxAlbedo::SIZE;
        for &[a, b] in &t.cells {
            assert!(a >= 0.0 && b >= 0.0 && a + b <= 1.0 + 1e-3, "{a} {b}");
        }
        // Near-mirror rows reflect everything at any angle above grazing.
        for j in 4..n {
            let [a, b] = t.cells[j];
            assert!((a + b - 1.0).abs() < 5e-3, "column {j}: {}", a + b);
        }
        // At α = 1 the normals are uniform (D = 1/π) and, at normal incidence, G1(ωo) = 1 and
        // G1(ωi) = 2 cos θi / (cos θi + 1): E = 1/(4π) ∫ G1(ωi) dωi = 1 - ln 2.
        let [a, b] = t.cells[(n - 1) * n + n - 1];
        let exact = 1.0 - std::f32::consts::LN_2;
        assert!((a + b - exact).abs() < 0.01, "{} vs {exact}", a + b);
        // At normal incidence the Fresnel weight (1 - cos θh)^5 is small for smooth lobes.
        let (sa, sb) = t.lookup(1.0, MIN_ALPHA);
        assert!(sb < 1e-3 && sa > 0.99, "{sa} {sb}");
    }

    #[test]
    fn the_embedded_table_is_the_computed_one() {
        let embedded = GgxAlbedo::from_bytes(EMBEDDED).expect("the embedded table's size");
        let computed = GgxAlbedo::compute(64);
        // The same quadrature; the trigonometric functions of another platform's libm may
        // round a last bit differently.
        for (p, q) in embedded.cells.iter().zip(&computed.cells) {
            for k in 0..2 {
                assert!((p[k] - q[k]).abs() <= 1e-6, "{p:?} vs {q:?}");
            }
        }
        assert_eq!(GgxAlbedo::get(), &embedded);
        assert_eq!(GgxAlbedo::from_bytes(&computed.to_bytes()), Some(computed));
        assert_eq!(GgxAlbedo::from_bytes(&[0; 12]), None);
    }

    #[test]
    fn the_table_converges_and_lookups_hit_the_nodes() {
        // A coarser quadrature agrees to about a hundredth: the table is converged.
        let coarse = GgxAlbedo::compute(32);
        let fine = GgxAlbedo::get();
        let worst = coarse
            .cells
            .iter()
            .zip(&fine.cells)
            .map(|(p, q)| (p[0] - q[0]).abs().max((p[1] - q[1]).abs()))
            .fold(0.0f32, f32::max);
        println!("largest difference between 32² and 64² samples per cell: {worst}");
        assert!(worst < 0.02, "{worst}");
        let n = GgxAlbedo::SIZE;
        let (i, j) = (20, 9);
        let r = i as f32 / (n - 1) as f32;
        let (a, b) = fine.lookup(j as f32 / (n - 1) as f32, r * r);
        let [ea, eb] = fine.cells[i * n + j];
        assert!((a - ea).abs() < 1e-5 && (b - eb).abs() < 1e-5);
        // Out-of-range arguments clamp instead of reading outside the table.
        let (a, b) = fine.lookup(7.0, 9.0);
        assert!(a.is_finite() && b.is_finite());
        let (a, b) = fine.lookup(f32::NAN, f32::NAN);
        assert!(a.is_finite() && b.is_finite());
    }
}
