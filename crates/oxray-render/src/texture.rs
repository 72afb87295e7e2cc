//! Texture sampling: bilinear filtering with glTF wrap modes, sRGB decoding through a table.

use glam::{Vec2, Vec4};
use oxray_scene::{Texture, Wrap};
use std::sync::OnceLock;

/// sRGB-encoded byte to linear value: the table [`sample`] decodes colour channels with.
pub fn srgb_table() -> &'static [f32; 256] {
    static TABLE: OnceLock<[f32; 256]> = OnceLock::new();
    TABLE.get_or_init(|| {
        std::array::from_fn(|i| {
            let c = i as f32 / 255.0;
            if c <= 0.04045 {
                c / 12.92
            } else {
                ((c + 0.055) / 1.055).powf(2.4)
            }
        })
    })
}

fn wrap(i: i64, n: u32, mode: Wrap) -> usize {
    let n = n as i64;
    (match mode {
        Wrap::Repeat => i.rem_euclid(n),
        Wrap::ClampToEdge => i.clamp(0, n - 1),
        Wrap::MirroredRepeat => {
            let m = i.rem_euclid(2 * n);
            if m < n {
                m
            } else {
                2 * n - 1 - m
            }
        }
    }) as usize
}

/// Samples `tex` at `uv` (glTF convention: v = 0 is the top row) with bilinear filtering. With
/// `srgb`, the colour channels are decoded to linear first; alpha is always linear.
#[must_use]
pub fn sample(tex: &Texture, uv: Vec2, srgb: bool) -> Vec4 {
    let (w, h) = (tex.width, tex.height);
    if !uv.is_finite() {
        return texel(tex, 0, 0, srgb);
    }
    // Texel centres sit at half-integers; keep the coordinates in a range where the i64
    // conversion is exact whatever the input.
    let x = (uv.x.clamp(-1e6, 1e6) * w as f32 - 0.5) as f64;
    let y = (uv.y.clamp(-1e6, 1e6) * h as f32 - 0.5) as f64;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
    let (x0, y0) = (x0 as i64, y0 as i64);
    let xs = [wrap(x0, w, tex.wrap_u), wrap(x0 + 1, w, tex.wrap_u)];
    let ys = [wrap(y0, h, tex.wrap_v), wrap(y0 + 1, h, tex.wrap_v)];
    let t = |xi: usize, yi: usize| texel(tex, xs[xi], ys[yi], srgb);
    let top = t(0, 0).lerp(t(1, 0), fx);
    let bottom = t(0, 1).lerp(t(1, 1), fx);
    top.lerp(bottom, fy)
}

fn texel(tex: &Texture, x: usize, y: usize, srgb: bool) -> Vec4 {
    let [r, g, b, a] = tex.texels[y * tex.width as usize + x];
    if srgb {
        let lut = srgb_table();
        Vec4::new(
            lut[r as usize],
            lut[g as usize],
            lut[b as usize],
            a as f32 / 255.0,
        )
    } else {
        Vec4::new(r as f32, g as f32, b as f32, a as f32) / 255.0
    }
}

/// The mean linear colour of an sRGB texture (used to weight emissive triangles for light
/// sampling).
#[must_use]
pub fn mean_srgb(tex: &Texture) -> Vec4 {
    let lut = srgb_table();
    let sum = tex.texels.iter().fold(Vec4::ZERO, |s, &[r, g, b, a]| {
        s + Vec4::new(
            lut[r as usize],
            lut[g as usize],
            lut[b as usize],
            a as f32 / 255.0,
        )
    });
    sum / tex.texels.len().max(1) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    fn checker() -> Texture {
        Texture {
            name: "checker".into(),
            width: 2,
            height: 2,
            texels: vec![[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 0], [255; 4]],
            wrap_u: Wrap::Repeat,
            wrap_v: Wrap::ClampToEdge,
        }
    }

    #[test]
    fn texel_centres_are_exact() {
        let t = checker();
        assert_eq!(
            sample(&t, Vec2::new(0.25, 0.25), false),
            Vec4::new(1.0, 0.0, 0.0, 1.0)
        );
        assert_eq!(
            sample(&t, Vec2::new(0.75, 0.25), false),
            Vec4::new(0.0, 1.0, 0.0, 1.0)
        );
        assert_eq!(
            sample(&t, Vec2::new(0.25, 0.75), false),
            Vec4::new(0.0, 0.0, 1.0, 0.0)
        );
    }

    #[test]
    fn wrap_modes() {
        let t = checker();
        // Repeat along u: one texture width further is the same texel.
        assert_eq!(
            sample(&t, Vec2::new(1.25, 0.25), false),
            sample(&t, Vec2::new(0.25, 0.25), false)
        );
        // Clamp along v: far below the texture is the bottom row.
        assert_eq!(
            sample(&t, Vec2::new(0.25, 9.0), false),
            Vec4::new(0.0, 0.0, 1.0, 0.0)
        );
        assert_eq!(wrap(-1, 4, Wrap::MirroredRepeat), 0);
        assert_eq!(wrap(4, 4, Wrap::MirroredRepeat), 3);
        assert_eq!(wrap(-1, 4, Wrap::Repeat), 3);
    }

    #[test]
    fn bilinear_blends_and_srgb_decodes() {
        let t = checker();
        let mid = sample(&t, Vec2::new(0.5, 0.25), false);
        assert!((mid.x - 0.5).abs() < 1e-6 && (mid.y - 0.5).abs() < 1e-6);
        let half = Texture::solid("grey", [188, 188, 188, 255]);
        let lin = sample(&half, Vec2::ZERO, true).x;
        assert!((lin - 0.5).abs() < 0.01, "{lin}");
        assert!(sample(&t, Vec2::new(f32::NAN, 0.0), true).is_finite());
    }
}
