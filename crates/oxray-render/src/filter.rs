//! Pixel reconstruction filters, applied by filter importance sampling (Ertl et al. 2014): each
//! camera sample's offset from its pixel's centre is drawn from the filter's distribution and
//! the sample counts for that pixel alone, with weight 1 (the filters are non-negative). So a
//! pixel's value is the filter-weighted mean of the radiance around it, no sample touches two
//! pixels, and images stay independent of the thread count.
//!
//! The filters are separable: the horizontal and vertical offsets are drawn independently from
//! the 1-D profile, through its inverse cumulative distribution tabulated at
//! [`TABLE_SIZE`] points ([`Filter::table`]) and interpolated linearly ([`sample_offset`], the
//! same arithmetic as the C++ programs', which receive the table as a buffer).
//!
//! ```
//! use oxray_render::filter::{sample_offset, Filter};
//!
//! let table = Filter::Gaussian.table();
//! // The median offset is the centre; offsets stay within the radius.
//! assert!(sample_offset(&table, 0.5).abs() < 1e-3);
//! assert!(sample_offset(&table, 0.0) >= -Filter::Gaussian.radius());
//! assert_eq!("blackman-harris".parse::<Filter>()?, Filter::BlackmanHarris);
//! # Ok::<(), oxray_render::filter::UnknownFilter>(())
//! ```

use std::f64::consts::TAU;
use std::str::FromStr;
use thiserror::Error;

/// Entries of a filter's inverse-CDF table.
pub const TABLE_SIZE: usize = 256;

/// A pixel reconstruction filter.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Filter {
    /// The pixel's square: radius 0.5 pixel (sharp, aliases the most).
    Box,
    /// A Gaussian of standard deviation 0.5 pixel, truncated at 1.5 pixels (3 sigma) and
    /// shifted to reach 0 there, as pbrt and Mitsuba do.
    #[default]
    Gaussian,
    /// The 4-term Blackman–Harris window over 3 pixels (radius 1.5): about as wide as the
    /// Gaussian, with less leakage from far samples.
    BlackmanHarris,
}

/// A filter name that is none of `box`, `gaussian`, `blackman-harris`.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
#[error("unknown pixel filter {0:?} (expected box, gaussian or blackman-harris)")]
pub struct UnknownFilter(pub String);

impl FromStr for Filter {
    type Err = UnknownFilter;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "box" => Ok(Filter::Box),
            "gaussian" => Ok(Filter::Gaussian),
            "blackman-harris" | "blackmanharris" => Ok(Filter::BlackmanHarris),
            _ => Err(UnknownFilter(s.into())),
        }
    }
}

impl Filter {
    /// How far from the pixel's centre the filter reaches, in pixels.
    #[must_use]
    pub fn radius(self) -> f32 {
        match self {
            Filter::Box => 0.5,
            Filter::Gaussian | Filter::BlackmanHarris => 1.5,
        }
    }

    /// The 1-D profile at offset `x` (pixels), unnormalised; 0 beyond the radius.
    #[must_use]
    pub fn eval(self, x: f32) -> f32 {
        let r = self.radius() as f64;
        let x = x as f64;
        // NaN falls through to 0 as well.
        if x.is_nan() || x.abs() > r {
            return 0.0;
        }
        let v = match self {
            Filter::Box => 1.0,
            Filter::Gaussian => {
                let g = |x: f64| (-x * x / (2.0 * 0.5 * 0.5)).exp();
                g(x) - g(r)
            }
            Filter::BlackmanHarris => {
                let s = x / (2.0 * r) + 0.5;
                0.35875 - 0.48829 * (TAU * s).cos() + 0.14128 * (2.0 * TAU * s).cos()
                    - 0.01168 * (3.0 * TAU * s).cos()
            }
        };
        v.max(0.0) as f32
    }

    /// The inverse cumulative distribution of the profile at `u = i / (TABLE_SIZE - 1)`: from
    /// `-radius` to `radius`, found by integrating the profile over 4,096 bins.
    #[must_use]
    pub fn table(self) -> Vec<f32> {
        const BINS: usize = 4096;
        let r = self.radius() as f64;
        let width = 2.0 * r / BINS as f64;
        let mut cdf = Vec::with_capacity(BINS + 1);
        let mut acc = 0.0f64;
        cdf.push(0.0);
        for i in 0..BINS {
            let x = -r + (i as f64 + 0.5) * width;
            acc += self.eval(x as f32) as f64;
            cdf.push(acc);
        }
        let mut table = Vec::with_capacity(TABLE_SIZE);
        let mut bin = 0;
        for k in 0..TABLE_SIZE {
            let target = acc * k as f64 / (TABLE_SIZE - 1) as f64;
            while bin < BINS - 1 && cdf[bin + 1] < target {
                bin += 1;
            }
            let (lo, hi) = (cdf[bin], cdf[bin + 1]);
            let t = if hi > lo {
                ((target - lo) / (hi - lo)).clamp(0.0, 1.0)
            } else {
                0.5
            };
            table.push((-r + (bin as f64 + t) * width) as f32);
        }
        table
    }
}

/// An offset from a pixel's centre drawn from a filter's `table` ([`Filter::table`]) by the
/// uniform number `u` in [0, 1).
#[must_use]
pub fn sample_offset(table: &[f32], u: f32) -> f32 {
    let n = table.len();
    if n < 2 {
        return u - 0.5;
    }
    let x = u.clamp(0.0, 1.0) * (n - 1) as f32;
    let i = (x as usize).min(n - 2);
    let t = x - i as f32;
    table[i] * (1.0 - t) + table[i + 1] * t
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sampled_offsets_follow_each_profile() {
        // A histogram of offsets drawn at stratified u against the profile's integral per bin.
        for f in [Filter::Box, Filter::Gaussian, Filter::BlackmanHarris] {
            let table = f.table();
            assert_eq!(table.len(), TABLE_SIZE);
            assert!(
                table.windows(2).all(|w| w[0] <= w[1]),
                "{f:?}: not monotonic"
            );
            let r = f.radius();
            assert!((table[0] + r).abs() < 1e-3 && (table[TABLE_SIZE - 1] - r).abs() < 1e-3);
            let bins = 24;
            let mut hist = vec![0.0f64; bins];
            let n = 200_000;
            for k in 0..n {
                let x = sample_offset(&table, (k as f32 + 0.5) / n as f32);
                let b = (((x + r) / (2.0 * r)) * bins as f32) as usize;
                hist[b.min(bins - 1)] += 1.0 / n as f64;
            }
            let mut expected = vec![0.0f64; bins];
            let fine = 100;
            for (b, e) in expected.iter_mut().enumerate() {
                for j in 0..fine {
                    let x =
                        -r + 2.0 * r * (b as f32 + (j as f32 + 0.5) / fine as f32) / bins as f32;
                    *e += f.eval(x) as f64;
                }
            }
            let total: f64 = expected.iter().sum();
            let worst = hist
                .iter()
                .zip(&expected)
                .map(|(h, e)| (h - e / total).abs())
                .fold(0.0, f64::max);
            assert!(worst < 2e-3, "{f:?}: histogram off by {worst}");
        }
        // The box filter is the uniform jitter over the pixel.
        let table = Filter::Box.table();
        for u in [0.0, 0.1, 0.37, 0.5, 0.99] {
            assert!((sample_offset(&table, u) - (u - 0.5)).abs() < 1e-4);
        }
    }

    #[test]
    fn profiles_peak_at_the_centre_and_vanish_beyond_the_radius() {
        for f in [Filter::Gaussian, Filter::BlackmanHarris] {
            assert!(f.eval(0.0) > f.eval(0.5) && f.eval(0.5) > f.eval(1.0));
            assert!(f.eval(1.5) < 1e-3 && f.eval(1.6) == 0.0 && f.eval(f32::NAN) == 0.0);
            assert_eq!(f.eval(0.7), f.eval(-0.7));
        }
        assert!("lanczos".parse::<Filter>().is_err());
        assert_eq!("Gaussian".parse::<Filter>(), Ok(Filter::Gaussian));
    }
}
