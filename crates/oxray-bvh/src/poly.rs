//! Real polynomials of low degree in `f64`, and every real root of one in an interval, for the
//! curve intersectors.
//!
//! The root finder isolates roots by the roots of the derivative (between two consecutive
//! critical points a polynomial is monotonic, so it has at most one root there, found by a
//! safeguarded Newton iteration), recursively down to degree 1. It finds every root of odd
//! multiplicity and every critical point, needs no starting guess and allocates nothing.

/// Coefficients kept per polynomial: degree 10 (the curve tests' highest) plus one.
pub(crate) const MAX_COEFFS: usize = 11;

/// A polynomial `c[0] + c[1] u + … + c[n-1] u^(n-1)` with `n <= MAX_COEFFS`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Poly {
    pub(crate) c: [f64; MAX_COEFFS],
    pub(crate) n: usize,
}

impl Poly {
    /// The polynomial with these coefficients (lowest degree first).
    pub(crate) fn new(coeffs: &[f64]) -> Poly {
        let mut c = [0.0; MAX_COEFFS];
        c[..coeffs.len()].copy_from_slice(coeffs);
        Poly { c, n: coeffs.len() }
    }

    /// Its value at `u` (Horner).
    #[inline]
    pub(crate) fn eval(&self, u: f64) -> f64 {
        self.c[..self.n]
            .iter()
            .rev()
            .fold(0.0, |acc, &k| acc * u + k)
    }

    /// The derivative.
    pub(crate) fn derivative(&self) -> Poly {
        let mut d = Poly::new(&[]);
        for k in 1..self.n {
            d.c[k - 1] = self.c[k] * k as f64;
        }
        d.n = self.n.saturating_sub(1);
        d
    }

    /// The product; the degrees must sum below `MAX_COEFFS`.
    pub(crate) fn mul(&self, o: &Poly) -> Poly {
        let mut p = Poly::new(&[]);
        if self.n == 0 || o.n == 0 {
            return p;
        }
        p.n = self.n + o.n - 1;
        debug_assert!(p.n <= MAX_COEFFS);
        for i in 0..self.n {
            for j in 0..o.n {
                p.c[i + j] += self.c[i] * o.c[j];
            }
        }
        p
    }

    /// `self + s o`.
    pub(crate) fn add_scaled(&self, o: &Poly, s: f64) -> Poly {
        let mut p = *self;
        p.n = self.n.max(o.n);
        for k in 0..o.n {
            p.c[k] += s * o.c[k];
        }
        p
    }

    /// Degree, leading zero coefficients dropped (`None` for the zero polynomial).
    fn degree(&self) -> Option<usize> {
        (0..self.n).rev().find(|&k| self.c[k] != 0.0)
    }

    /// Every root in `[lo, hi]` (ascending, at most `MAX_COEFFS - 1`) into `out`; returns how
    /// many. A root where the polynomial touches zero without crossing it is found when it is
    /// also a root of the derivative and the value there rounds to zero.
    pub(crate) fn roots(&self, lo: f64, hi: f64, out: &mut [f64; MAX_COEFFS]) -> usize {
        let Some(deg) = self.degree() else {
            return 0;
        };
        if deg == 0 {
            return 0;
        }
        if deg == 1 {
            let r = -self.c[0] / self.c[1];
            if r >= lo && r <= hi {
                out[0] = r;
                return 1;
            }
            return 0;
        }
        let mut crit = [0.0; MAX_COEFFS];
        let derivative = self.derivative();
        let nc = derivative.roots(lo, hi, &mut crit);
        let mut count = 0;
        let mut a = lo;
        let mut fa = self.eval(a);
        let scale = self.c[..self.n].iter().fold(0.0f64, |m, &k| m.max(k.abs()));
        let tiny = scale * 1e-13;
        for k in 0..=nc {
            let b = if k < nc { crit[k] } else { hi };
            let fb = self.eval(b);
            if fa == 0.0 {
                push(out, &mut count, a);
            } else if (fa < 0.0) != (fb < 0.0) && fb != 0.0 {
                push(out, &mut count, self.bracketed(&derivative, a, b, fa));
            } else if k < nc && fb.abs() <= tiny {
                // A double root at a critical point: the polynomial touches zero there.
                push(out, &mut count, b);
            }
            a = b;
            fa = fb;
        }
        if fa == 0.0 {
            push(out, &mut count, a);
        }
        count
    }

    /// The root in `[a, b]`, where the polynomial is monotonic and changes sign (`fa` its
    /// value at `a`, `d` its derivative): Newton steps kept inside the bracket, bisection where
    /// they leave it.
    fn bracketed(&self, d: &Poly, mut a: f64, mut b: f64, fa: f64) -> f64 {
        let neg_at_a = fa < 0.0;
        let mut u = 0.5 * (a + b);
        for _ in 0..100 {
            let f = self.eval(u);
            if f == 0.0 {
                return u;
            }
            if (f < 0.0) == neg_at_a {
                a = u;
            } else {
                b = u;
            }
            let df = d.eval(u);
            let newton = u - f / df;
            let next = if newton > a && newton < b {
                newton
            } else {
                0.5 * (a + b)
            };
            if (next - u).abs() <= 1e-15 * (1.0 + u.abs()) || b - a <= 1e-15 * (1.0 + a.abs()) {
                return next;
            }
            u = next;
        }
        u
    }
}

fn push(out: &mut [f64; MAX_COEFFS], count: &mut usize, r: f64) {
    if *count < MAX_COEFFS && (*count == 0 || out[*count - 1] != r) {
        out[*count] = r;
        *count += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roots_of_a_product_of_known_factors_are_found_in_order() {
        // (u - 0.1)(u - 0.35)(u - 0.6)(u - 0.9)(u + 2)
        let mut p = Poly::new(&[1.0]);
        for r in [0.1, 0.35, 0.6, 0.9, -2.0] {
            p = p.mul(&Poly::new(&[-r, 1.0]));
        }
        let mut out = [0.0; MAX_COEFFS];
        let n = p.roots(0.0, 1.0, &mut out);
        assert_eq!(n, 4);
        for (got, want) in out[..n].iter().zip([0.1, 0.35, 0.6, 0.9]) {
            assert!((got - want).abs() < 1e-12, "{got} vs {want}");
        }
    }

    #[test]
    fn a_double_root_and_close_roots_of_degree_ten_are_found_to_rounding() {
        // (u - 0.5)^2 (u - 0.25)(u - 0.2501) times a positive sextic.
        let mut p = Poly::new(&[-0.5, 1.0]).mul(&Poly::new(&[-0.5, 1.0]));
        p = p.mul(&Poly::new(&[-0.25, 1.0]));
        p = p.mul(&Poly::new(&[-0.2501, 1.0]));
        for _ in 0..3 {
            p = p.mul(&Poly::new(&[1.0, 0.0, 1.0]));
        }
        assert_eq!(p.n, 11);
        let mut out = [0.0; MAX_COEFFS];
        let n = p.roots(0.0, 1.0, &mut out);
        // Rounding may split the double root into two very close ones (either is a good
        // candidate for the curve tests, which check what they find), never lose it.
        assert!(n == 3 || n == 4, "{:?}", &out[..n]);
        assert!((out[0] - 0.25).abs() < 1e-9 && (out[1] - 0.2501).abs() < 1e-9);
        assert!(
            out[2..n].iter().all(|r| (r - 0.5).abs() < 1e-6),
            "{:?}",
            &out[..n]
        );
    }
}
