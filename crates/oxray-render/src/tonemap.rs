//! Display transforms for 8-bit images: an exposure in stops, then a tone curve from linear
//! Rec. 709 radiance to display-linear values in [0, 1], then the sRGB encoding.
//!
//! - [`ToneMap::Linear`]: the identity clamped to [0, 1] (Cycles' and Mitsuba's "standard"
//!   view): mid-grey 0.18 is 118/255, and everything from 1 up is white.
//! - [`ToneMap::Aces`]: Stephen Hill's fit of the ACES reference rendering and sRGB output
//!   transforms (the input and output matrices around a rational curve), with the usual
//!   exposure convention of that fit (the Khronos glTF Sample Viewer's, after Narkowicz): the
//!   radiance is divided by 0.6 first. Mid-grey maps to about 0.213 (127/255); the curve
//!   saturates hues and reaches white near 16.
//! - [`ToneMap::Neutral`]: the Khronos PBR Neutral curve, which leaves colours below 0.76 as
//!   they are, apart from a 0.04 offset (mid-grey 0.14, 105/255), and compresses brighter ones
//!   towards white while keeping their hue, for base colours shown as authored.
//!
//! ```
//! use oxray_render::tonemap::{Look, ToneMap};
//!
//! let look = Look { tone_map: ToneMap::Linear, exposure: 1.0 };
//! // One stop brighter: 0.25 becomes 0.5.
//! assert_eq!(look.display([0.25, 0.0, 2.0]), [0.5, 0.0, 1.0]);
//! assert_eq!("neutral".parse::<ToneMap>()?, ToneMap::Neutral);
//! # Ok::<(), oxray_render::tonemap::UnknownToneMap>(())
//! ```

use std::str::FromStr;
use thiserror::Error;

/// A tone curve (see the module documentation).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum ToneMap {
    /// Clamp to [0, 1].
    Linear,
    /// ACES, Hill's fit, radiance divided by 0.6 first.
    #[default]
    Aces,
    /// Khronos PBR Neutral.
    Neutral,
}

/// A tone-curve name that is none of `linear`, `aces`, `neutral`.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
#[error("unknown tone curve {0:?} (expected linear, aces or neutral)")]
pub struct UnknownToneMap(pub String);

impl FromStr for ToneMap {
    type Err = UnknownToneMap;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "linear" => Ok(ToneMap::Linear),
            "aces" => Ok(ToneMap::Aces),
            "neutral" | "pbr-neutral" | "khronos-pbr-neutral" => Ok(ToneMap::Neutral),
            _ => Err(UnknownToneMap(s.into())),
        }
    }
}

/// Linear sRGB to the ACES fit's working space (rows).
const ACES_IN: [[f32; 3]; 3] = [
    [0.59719, 0.35458, 0.04823],
    [0.07600, 0.90834, 0.01566],
    [0.02840, 0.13383, 0.83777],
];

/// The fit's working space back to linear sRGB (rows).
const ACES_OUT: [[f32; 3]; 3] = [
    [1.60475, -0.53108, -0.07367],
    [-0.10208, 1.10813, -0.00605],
    [-0.00327, -0.07276, 1.07602],
];

fn mul(m: &[[f32; 3]; 3], v: [f32; 3]) -> [f32; 3] {
    m.map(|r| r[0] * v[0] + r[1] * v[1] + r[2] * v[2])
}

fn aces(c: [f32; 3]) -> [f32; 3] {
    let v = mul(&ACES_IN, c.map(|x| x / 0.6));
    let v = v.map(|x| {
        let a = x * (x + 0.0245786) - 0.000090537;
        let b = x * (0.983729 * x + 0.432951) + 0.238081;
        a / b
    });
    mul(&ACES_OUT, v)
}

fn neutral(c: [f32; 3]) -> [f32; 3] {
    const START: f32 = 0.8 - 0.04;
    const DESATURATION: f32 = 0.15;
    let x = c[0].min(c[1]).min(c[2]);
    let offset = if x < 0.08 { x - 6.25 * x * x } else { 0.04 };
    let c = c.map(|v| v - offset);
    let peak = c[0].max(c[1]).max(c[2]);
    if peak < START {
        return c;
    }
    let d = 1.0 - START;
    let new_peak = 1.0 - d * d / (peak + d - START);
    let c = c.map(|v| v * (new_peak / peak));
    let g = 1.0 - 1.0 / (DESATURATION * (peak - new_peak) + 1.0);
    c.map(|v| v * (1.0 - g) + new_peak * g)
}

impl ToneMap {
    /// Display-linear values in [0, 1] for linear radiance `c` (negative and NaN inputs read
    /// as 0, anything above 10^6, infinity included, as 10^6: white for every curve).
    #[must_use]
    pub fn apply(self, c: [f32; 3]) -> [f32; 3] {
        let c = c.map(|v| if v > 0.0 { v.min(1e6) } else { 0.0 });
        let out = match self {
            ToneMap::Linear => c,
            ToneMap::Aces => aces(c),
            ToneMap::Neutral => neutral(c),
        };
        out.map(|v| if v > 0.0 { v.min(1.0) } else { 0.0 })
    }
}

/// How an image is shown: an exposure and a tone curve.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Look {
    /// The tone curve.
    pub tone_map: ToneMap,
    /// Exposure in stops: radiance is multiplied by 2^exposure before the curve.
    pub exposure: f32,
}

impl Look {
    /// Display-linear values in [0, 1] for linear radiance `c`.
    #[must_use]
    pub fn display(&self, c: [f32; 3]) -> [f32; 3] {
        let k = self.exposure.exp2();
        self.tone_map.apply(c.map(|v| v * k))
    }

    /// 8-bit sRGB for linear radiance `c`.
    pub fn srgb8(&self, c: [f32; 3]) -> [u8; 3] {
        self.display(c).map(srgb_encode)
    }
}

/// The sRGB transfer function of a display-linear value in [0, 1], as an 8-bit code.
#[must_use]
pub fn srgb_encode(x: f32) -> u8 {
    let s = if x <= 0.0031308 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    };
    (s.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    const ALL: [ToneMap; 3] = [ToneMap::Linear, ToneMap::Aces, ToneMap::Neutral];

    fn grey(t: ToneMap, x: f32) -> f32 {
        t.apply([x; 3])[0]
    }

    #[test]
    fn mid_grey_maps_where_each_curve_is_documented_to() {
        let look = |t| Look {
            tone_map: t,
            exposure: 0.0,
        };
        assert_eq!(look(ToneMap::Linear).srgb8([0.18; 3]), [118; 3]);
        // Neutral: below its compression, only the 0.04 offset.
        assert!((grey(ToneMap::Neutral, 0.18) - 0.14).abs() < 1e-6);
        assert_eq!(look(ToneMap::Neutral).srgb8([0.18; 3]), [105; 3]);
        // Hill's fit at 0.18 / 0.6: (0.3 (0.3 + 0.0245786) - 0.000090537)
        // / (0.3 (0.983729 0.3 + 0.432951) + 0.238081) = 0.2131; grey stays grey (every
        // matrix row sums to 1).
        let a = ToneMap::Aces.apply([0.18; 3]);
        assert!(a.iter().all(|&v| (v - 0.2131).abs() < 2e-3), "{a:?}");
        assert_eq!(look(ToneMap::Aces).srgb8([0.18; 3]), [127; 3]);
        // One stop of exposure is a factor of 2.
        let brighter = Look {
            tone_map: ToneMap::Linear,
            exposure: 1.0,
        };
        assert_eq!(brighter.display([0.09; 3]), [0.18; 3]);
    }

    #[test]
    fn curves_are_monotonic_black_at_zero_and_white_at_their_white_point() {
        for t in ALL {
            assert_eq!(t.apply([0.0; 3]), [0.0; 3], "{t:?}");
            assert_eq!(
                t.apply([-1.0, f32::NAN, f32::NEG_INFINITY]),
                [0.0; 3],
                "{t:?}"
            );
            let mut last = 0.0;
            for i in 1..4000 {
                let y = grey(t, i as f32 * 0.01);
                assert!(y >= last && y <= 1.0, "{t:?} at {}", i as f32 * 0.01);
                last = y;
            }
            // Far above the white point: white, also for infinite radiance.
            assert_eq!(
                Look {
                    tone_map: t,
                    exposure: 0.0
                }
                .srgb8([1e4; 3]),
                [255; 3]
            );
            let inf = t.apply([f32::INFINITY; 3]);
            assert!(inf.iter().all(|&v| v >= 1.0 - 1e-6), "{t:?}: {inf:?}");
        }
        // Linear is white from 1 up; the others still below white at 1 (they compress).
        assert_eq!(grey(ToneMap::Linear, 1.0), 1.0);
        assert!(grey(ToneMap::Aces, 1.0) < 0.8 && grey(ToneMap::Neutral, 1.0) < 0.9);
        // Neutral keeps a bright colour's hue order and does not clip it to white.
        let warm = ToneMap::Neutral.apply([2.0, 1.4, 0.5]);
        assert!(
            warm[0] > warm[1] && warm[1] > warm[2] && warm[2] < 0.99,
            "{warm:?}"
        );
    }

    #[test]
    fn names_parse() {
        for (s, t) in [
            ("linear", ToneMap::Linear),
            ("ACES", ToneMap::Aces),
            ("pbr-neutral", ToneMap::Neutral),
        ] {
            assert_eq!(s.parse::<ToneMap>(), Ok(t));
        }
        let e = "filmic".parse::<ToneMap>().unwrap_err().to_string();
        assert!(e.contains("filmic") && e.contains("neutral"), "{e}");
    }
}
