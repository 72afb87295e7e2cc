//! Light sources for next-event estimation: emissive triangles, picked in proportion to their
//! power, and an environment (an equirectangular radiance map, procedural sky or loaded from a
//! file), picked by importance over its texels.

use super::bsdf::luminance;
use super::texture;
use glam::{Vec2, Vec3};
use oxray_scene::SceneDesc;
use std::f32::consts::{PI, TAU};
use std::path::Path;

/// One emissive triangle in world space.
#[derive(Clone, Copy, Debug)]
pub struct LightTriangle {
    /// First vertex.
    pub p0: Vec3,
    /// Edges from `p0`.
    pub e1: Vec3,
    /// Second edge.
    pub e2: Vec3,
    /// Unit normal out of the front face.
    pub normal: Vec3,
    /// Texture coordinates of the vertices in the set of the material's emissive texture (zero
    /// without that set).
    pub uv: [Vec2; 3],
    /// Material index.
    pub material: u32,
    /// Whether it emits from both faces (else from the front face, `e1 x e2`, only).
    pub two_sided: bool,
}

/// The emissive triangles of a scene.
#[derive(Clone, Debug, Default)]
pub struct TriangleLights {
    /// The triangles.
    pub triangles: Vec<LightTriangle>,
    /// Cumulative power, normalised so that the last entry is 1.
    cdf: Vec<f32>,
    /// Total power (area times mean emitted luminance).
    pub total_power: f32,
    /// Per material, its mean emitted luminance (0 for non-emitters): a triangle's selection
    /// probability per unit area is `weight / total_power`.
    pub material_weight: Vec<f32>,
}

impl TriangleLights {
    /// Collects every emissive triangle of every instance.
    #[must_use]
    pub fn new(scene: &SceneDesc) -> TriangleLights {
        Self::placed(scene, |i| scene.instances.get(i).map(|inst| inst.transform))
    }

    /// Collects the emissive triangles of every instance that `placement` places (by instance
    /// index; `None` leaves an instance's triangles out: a moving emitter, which next-event
    /// estimation cannot sample at a ray's time).
    pub fn placed(
        scene: &SceneDesc,
        placement: impl Fn(usize) -> Option<glam::Mat4>,
    ) -> TriangleLights {
        let tex_mean: Vec<Vec3> = scene
            .textures
            .iter()
            .map(|t| texture::mean_srgb(t).truncate())
            .collect();
        let material_weight: Vec<f32> = scene
            .materials
            .iter()
            .map(|m| {
                let mut e = Vec3::from(m.emissive);
                if let Some(t) = m.emissive_texture {
                    e *= tex_mean
                        .get(t.texture as usize)
                        .copied()
                        .unwrap_or(Vec3::ONE);
                }
                let w = luminance(e);
                if w.is_finite() && w > 0.0 {
                    w
                } else {
                    0.0
                }
            })
            .collect();
        let mut triangles = Vec::new();
        let mut power = Vec::new();
        for (index, inst) in scene.instances.iter().enumerate() {
            let Some(mesh) = scene.meshes.get(inst.mesh as usize) else {
                continue;
            };
            let Some(transform) = placement(index) else {
                continue;
            };
            for prim in &mesh.primitives {
                let w = material_weight
                    .get(prim.material as usize)
                    .copied()
                    .unwrap_or(0.0);
                if w <= 0.0 {
                    continue;
                }
                let emissive_set = scene
                    .materials
                    .get(prim.material as usize)
                    .and_then(|m| m.emissive_texture)
                    .map_or(0, |t| t.tex_coord);
                let set = if emissive_set == 1 {
                    &prim.uvs1
                } else {
                    &prim.uvs
                };
                for t in &prim.triangles {
                    let p =
                        t.map(|i| transform.transform_point3(prim.positions[i as usize].into()));
                    let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
                    let area = 0.5 * e1.cross(e2).length();
                    // A mirroring placement turns the winding order around.
                    let normal =
                        e1.cross(e2).normalize_or_zero() * transform.determinant().signum();
                    if !(area > 0.0 && area.is_finite()) {
                        continue;
                    }
                    let uv = t.map(|i| set.get(i as usize).map_or(Vec2::ZERO, |&u| u.into()));
                    triangles.push(LightTriangle {
                        p0: p[0],
                        normal,
                        e1,
                        e2,
                        uv,
                        material: prim.material,
                        two_sided: scene.materials[prim.material as usize].double_sided,
                    });
                    power.push(area * w);
                }
            }
        }
        let mut cdf = Vec::with_capacity(power.len());
        let mut acc = 0.0f64;
        for p in &power {
            acc += *p as f64;
            cdf.push(acc as f32);
        }
        let total_power = acc as f32;
        for c in &mut cdf {
            *c /= total_power;
        }
        TriangleLights {
            triangles,
            cdf,
            total_power,
            material_weight,
        }
    }

    /// Whether there is any emissive triangle.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }

    /// Picks a triangle in proportion to its power and a uniform point on it: the triangle, the
    /// point, its barycentrics (for texture lookups) and the pdf per unit area of the whole
    /// choice.
    #[inline]
    #[must_use]
    pub fn sample(&self, u: [f32; 3]) -> Option<(&LightTriangle, Vec3, [f32; 2], f32)> {
        let i = self
            .cdf
            .partition_point(|&c| c <= u[0])
            .min(self.triangles.len().checked_sub(1)?);
        let tri = &self.triangles[i];
        let (mut b1, mut b2) = (u[1], u[2]);
        if b1 + b2 > 1.0 {
            (b1, b2) = (1.0 - b1, 1.0 - b2);
        }
        let p = tri.p0 + tri.e1 * b1 + tri.e2 * b2;
        Some((tri, p, [b1, b2], self.area_pdf(tri.material)))
    }

    /// The cumulative distribution over [`TriangleLights::triangles`] that
    /// [`TriangleLights::sample`] searches (normalised: the last entry is 1).
    #[must_use]
    pub fn cdf(&self) -> &[f32] {
        &self.cdf
    }

    /// The pdf per unit area with which [`TriangleLights::sample`] picks a point on a triangle
    /// of material `material`.
    #[must_use]
    pub fn area_pdf(&self, material: u32) -> f32 {
        if self.total_power <= 0.0 {
            return 0.0;
        }
        self.material_weight
            .get(material as usize)
            .copied()
            .unwrap_or(0.0)
            / self.total_power
    }
}

/// An environment: radiance by direction from an equirectangular map (+Y up; u = 0.5 looks
/// down -Z), filtered bilinearly between texel centres (wrapping around in u, clamped at the
/// poles), with a sampling distribution proportional to luminance times solid angle.
///
/// Sampling picks a cell of the texel grid with a piecewise-constant distribution whose weight
/// per cell is the integral of the *filtered* luminance over the cell (the 3 x 3 neighbourhood
/// with weights (1, 6, 1) / 8 along each axis) times the sine of the row's polar angle, then a
/// uniform point in the cell. So the pdf is positive wherever the filtered radiance is (a dark
/// texel next to a bright one still receives samples), and [`Environment::pdf`] is the exact
/// density of [`Environment::sample`]: the chosen cell's probability, read back from the same
/// cumulative tables, over the cell's solid angle. A one-texel map (a uniform environment,
/// [`Environment::uniform`]) is sampled uniformly over the sphere (density 1 / 4 pi) and looked
/// up without map coordinates.
#[derive(Clone, Debug)]
pub struct Environment {
    width: usize,
    height: usize,
    texels: Vec<Vec3>,
    /// Per row, the cumulative distribution over its columns.
    conditional: Vec<f32>,
    /// Cumulative distribution over rows.
    marginal: Vec<f32>,
    /// Sum of the sampling weights (0: the environment is black and never sampled).
    total: f32,
    /// Whether every texel is zero: then every lookup is zero, and a ray that leaves the scene
    /// (every miss of a scene without an environment) skips the map's coordinates.
    zero: bool,
}

impl Environment {
    /// An environment from an equirectangular map of `width` x `height` linear texels.
    #[must_use]
    pub fn from_texels(width: usize, height: usize, texels: Vec<Vec3>, scale: f32) -> Self {
        let texels: Vec<Vec3> = texels
            .into_iter()
            .map(|t| {
                let t = t * scale;
                if t.is_finite() {
                    t.max(Vec3::ZERO)
                } else {
                    Vec3::ZERO
                }
            })
            .collect();
        let mut conditional = vec![0.0; width * height];
        let mut marginal = vec![0.0; height];
        let mut total = 0.0f64;
        let lum: Vec<f32> = texels.iter().map(|&t| luminance(t)).collect();
        // The bilinear reconstruction's integral over a cell, along one axis: 1/8 of each
        // neighbour and 6/8 of the texel itself.
        let row_filtered = |y: usize, x: usize| -> f64 {
            let at = |xx: usize| lum[y * width + xx] as f64;
            let (l, r) = ((x + width - 1) % width, (x + 1) % width);
            (at(l) + 6.0 * at(x) + at(r)) / 8.0
        };
        for y in 0..height {
            let sin_theta = (PI * (y as f32 + 0.5) / height as f32).sin();
            let (up, down) = (y.saturating_sub(1), (y + 1).min(height - 1));
            let mut row = 0.0f64;
            for x in 0..width {
                let cell =
                    (row_filtered(up, x) + 6.0 * row_filtered(y, x) + row_filtered(down, x)) / 8.0;
                row += cell * sin_theta as f64;
                conditional[y * width + x] = row as f32;
            }
            if row > 0.0 {
                for c in &mut conditional[y * width..(y + 1) * width] {
                    *c /= row as f32;
                }
            }
            total += row;
            marginal[y] = total as f32;
        }
        if total > 0.0 {
            for m in &mut marginal {
                *m /= total as f32;
            }
        }
        Environment {
            width,
            height,
            zero: texels.iter().all(|&t| t == Vec3::ZERO),
            texels,
            conditional,
            marginal,
            total: total as f32,
        }
    }

    /// A procedural daylight sky: a blue gradient over a dim ground and a small sun.
    #[must_use]
    pub fn sky(scale: f32) -> Self {
        let (w, h) = (512usize, 256usize);
        let sun = Vec3::new(-0.45, 0.7, 0.55).normalize();
        let cos_sun = (1.2f32).to_radians().cos();
        let mut texels = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let d = texel_direction(x, y, w, h);
                let up = d.y;
                let c = if up >= 0.0 {
                    let t = up.powf(0.4);
                    Vec3::new(0.85, 0.9, 1.0).lerp(Vec3::new(0.25, 0.45, 0.95), t)
                } else {
                    Vec3::new(0.35, 0.32, 0.28) * (1.0 + up).max(0.3)
                };
                let s = if d.dot(sun) >= cos_sun {
                    Vec3::new(2000.0, 1850.0, 1600.0)
                } else {
                    Vec3::ZERO
                };
                texels.push(c + s);
            }
        }
        Environment::from_texels(w, h, texels, scale)
    }

    /// A uniform environment.
    #[must_use]
    pub fn uniform(radiance: Vec3) -> Self {
        Environment::from_texels(1, 1, vec![radiance], 1.0)
    }

    /// Loads an equirectangular map from a Radiance `.hdr` or OpenEXR `.exr` file.
    pub fn load(path: &Path, scale: f32) -> Result<Self, String> {
        let name = path.display();
        let ext = oxray_scene::file_extension(path);
        // A regular file within the input size limit (a FIFO would hang the reader).
        let limits = oxray_scene::files::Limits::get();
        let len = oxray_scene::files::regular_file_size(path)
            .map_err(|e| format!("{name}: cannot read the environment: {e}"))?;
        if len > limits.file_bytes {
            return Err(format!(
                "{name}: the environment map is {len} bytes, over the {} limit (raise it with OXRAY_MAX_FILE_MB)",
                oxray_scene::files::mib(limits.file_bytes)
            ));
        }
        match ext.as_deref() {
            Some("exr") => {
                use exr::prelude::*;
                let img = read_first_rgba_layer_from_file(
                    path,
                    |res, _| {
                        let (w, h) = (res.width(), res.height());
                        (w, h, vec![Vec3::ZERO; w * h])
                    },
                    |(w, _, px): &mut (usize, usize, Vec<Vec3>),
                     pos,
                     (r, g, b, _a): (f32, f32, f32, f32)| {
                        px[pos.y() * *w + pos.x()] = Vec3::new(r, g, b);
                    },
                )
                .map_err(|e| format!("{name}: cannot read the environment: {e}"))?;
                let (w, h, px) = img.layer_data.channel_data.pixels;
                if w == 0 || h == 0 {
                    return Err(format!("{name}: the environment map is empty"));
                }
                Ok(Environment::from_texels(w, h, px, scale))
            }
            Some("hdr") => {
                let img = image::open(path)
                    .map_err(|e| format!("{name}: cannot read the environment: {e}"))?
                    .into_rgb32f();
                let (w, h) = (img.width() as usize, img.height() as usize);
                let px = img.pixels().map(|p| Vec3::from(p.0)).collect();
                Ok(Environment::from_texels(w, h, px, scale))
            }
            _ => Err(format!(
                "{name}: unknown environment format (expected .hdr or .exr)"
            )),
        }
    }

    /// The map coordinates of direction `d`: u around the vertical axis, v from the top.
    fn uv_of(d: Vec3) -> (f32, f32) {
        let u = 0.5 + d.x.atan2(-d.z) / TAU;
        let v = d.y.clamp(-1.0, 1.0).acos() / PI;
        (u, v)
    }

    /// The texel at map coordinates `(u, v)`.
    fn texel_at(&self, (u, v): (f32, f32)) -> usize {
        let x = ((u * self.width as f32) as usize).min(self.width - 1);
        let y = ((v * self.height as f32) as usize).min(self.height - 1);
        y * self.width + x
    }

    #[cfg(test)]
    fn texel_of(&self, d: Vec3) -> usize {
        self.texel_at(Self::uv_of(d))
    }

    /// The map and its sampling tables, as [`Environment::sample`] and [`Environment::pdf`]
    /// read them (for renderers that evaluate the environment elsewhere, such as the device
    /// programs).
    #[must_use]
    pub fn tables(&self) -> EnvironmentTables<'_> {
        EnvironmentTables {
            width: self.width,
            height: self.height,
            texels: &self.texels,
            conditional: &self.conditional,
            marginal: &self.marginal,
            total: self.total,
        }
    }

    /// Whether the map is one texel: a uniform environment, which is looked up without map
    /// coordinates and sampled uniformly over the sphere (as the map's cells would sample it
    /// uniformly in (u, v), denser towards the poles).
    fn uniform_map(&self) -> bool {
        self.width * self.height == 1
    }

    /// Radiance arriving from direction `d` (unit): the map filtered bilinearly between texel
    /// centres, wrapping around in u and clamped at the poles.
    #[must_use]
    pub fn radiance(&self, d: Vec3) -> Vec3 {
        if !d.is_finite() || self.zero {
            return Vec3::ZERO;
        }
        if self.uniform_map() {
            return self.texels[0];
        }
        self.radiance_at(Self::uv_of(d))
    }

    /// [`radiance`](Self::radiance) and [`pdf`](Self::pdf) of direction `d` together: one
    /// `atan2` and one `acos` for both (what a ray that leaves the scene needs).
    #[must_use]
    pub fn radiance_and_pdf(&self, d: Vec3) -> (Vec3, f32) {
        // A zero map has no sampling weight either: its pdf is 0.
        if !d.is_finite() || self.zero {
            return (Vec3::ZERO, 0.0);
        }
        if self.uniform_map() {
            return (self.texels[0], UNIFORM_PDF);
        }
        let uv = Self::uv_of(d);
        (self.radiance_at(uv), self.pdf_at(d, uv))
    }

    /// The radiance at map coordinates `(u, v)`, filtered bilinearly.
    fn radiance_at(&self, (u, v): (f32, f32)) -> Vec3 {
        let (w, h) = (self.width, self.height);
        let xf = u * w as f32 - 0.5;
        let yf = v * h as f32 - 0.5;
        let (x0, y0) = (xf.floor(), yf.floor());
        let (fx, fy) = (xf - x0, yf - y0);
        // u lies in [0, 1], so x0 in [-1, w]: wrap it; rows clamp.
        let x0 = (x0 as i64).rem_euclid(w as i64) as usize;
        let x1 = (x0 + 1) % w;
        let y1 = (y0 as i64 + 1).clamp(0, h as i64 - 1) as usize;
        let y0 = (y0 as i64).clamp(0, h as i64 - 1) as usize;
        let t = |x: usize, y: usize| self.texels[y * w + x];
        let top = t(x0, y0) * (1.0 - fx) + t(x1, y0) * fx;
        let bottom = t(x0, y1) * (1.0 - fx) + t(x1, y1) * fx;
        top * (1.0 - fy) + bottom * fy
    }

    /// The probability with which [`Environment::sample`] picks cell (`x`, `y`): the widths of
    /// its intervals in the marginal and conditional cumulative tables.
    fn cell_probability(&self, x: usize, y: usize) -> f32 {
        let step = |cdf: &[f32], i: usize| cdf[i] - if i == 0 { 0.0 } else { cdf[i - 1] };
        let row = &self.conditional[y * self.width..(y + 1) * self.width];
        step(&self.marginal, y) * step(row, x)
    }

    /// The solid-angle density of a uniform point in a cell of probability `p` at polar sine
    /// `sin_theta`: a cell spans 2 pi^2 / (w h) in (phi, theta).
    fn density(&self, p: f32, sin_theta: f32) -> f32 {
        p * (self.width * self.height) as f32 / (2.0 * PI * PI * sin_theta.max(1e-6))
    }

    /// Whether the environment emits anything.
    #[must_use]
    pub fn is_black(&self) -> bool {
        self.total <= 0.0
    }

    /// The solid-angle pdf of [`Environment::sample`] drawing `d`.
    #[must_use]
    pub fn pdf(&self, d: Vec3) -> f32 {
        if !d.is_finite() || self.total <= 0.0 {
            return 0.0;
        }
        if self.uniform_map() {
            return UNIFORM_PDF;
        }
        self.pdf_at(d, Self::uv_of(d))
    }

    /// [`pdf`](Self::pdf) of the finite direction `d` at map coordinates `uv`.
    fn pdf_at(&self, d: Vec3, uv: (f32, f32)) -> f32 {
        if self.total <= 0.0 {
            return 0.0;
        }
        let i = self.texel_at(uv);
        // The cell's probability is spread uniformly over its (u, v) rectangle.
        let p = self.cell_probability(i % self.width, i / self.width);
        self.density(p, (1.0 - d.y * d.y).max(0.0).sqrt())
    }

    /// Draws a direction in proportion to radiance; returns it with its radiance and pdf.
    #[must_use]
    pub fn sample(&self, u: [f32; 2]) -> Option<(Vec3, Vec3, f32)> {
        if self.total <= 0.0 {
            return None;
        }
        if self.uniform_map() {
            let y = 1.0 - 2.0 * u[0];
            let r = (1.0 - y * y).max(0.0).sqrt();
            let phi = u[1] * TAU;
            let d = Vec3::new(r * phi.cos(), y, r * phi.sin());
            return Some((d, self.texels[0], UNIFORM_PDF));
        }
        let y = self
            .marginal
            .partition_point(|&c| c <= u[0])
            .min(self.height - 1);
        let row = &self.conditional[y * self.width..(y + 1) * self.width];
        let x = row.partition_point(|&c| c <= u[1]).min(self.width - 1);
        // Reuse each number's position inside its bin as the offset inside the texel, so that
        // the density is constant over the texel, as `pdf` assumes.
        let within = |cdf: &[f32], i: usize, u: f32| {
            let lo = if i == 0 { 0.0 } else { cdf[i - 1] };
            let hi = cdf[i];
            if hi > lo {
                ((u - lo) / (hi - lo)).clamp(0.0, 0.999_999)
            } else {
                0.5
            }
        };
        let fy = within(&self.marginal, y, u[0]);
        let fx = within(row, x, u[1]);
        let d = direction_at(
            (x as f32 + fx) / self.width as f32,
            (y as f32 + fy) / self.height as f32,
        );
        let sin_theta = (1.0 - d.y * d.y).max(0.0).sqrt();
        let pdf = self.density(self.cell_probability(x, y), sin_theta);
        (pdf > 0.0 && pdf.is_finite()).then(|| (d, self.radiance(d), pdf))
    }
}

/// An environment's map and sampling tables ([`Environment::tables`]).
#[derive(Clone, Copy, Debug)]
pub struct EnvironmentTables<'a> {
    /// Map width in texels.
    pub width: usize,
    /// Map height in texels.
    pub height: usize,
    /// Radiance per texel, row-major from the top (+Y) row; u = 0.5 looks down -Z.
    pub texels: &'a [Vec3],
    /// Per row, the cumulative distribution over its columns (`width * height`).
    pub conditional: &'a [f32],
    /// The cumulative distribution over rows (`height`).
    pub marginal: &'a [f32],
    /// Sum of the sampling weights (per cell, the bilinearly filtered luminance's integral
    /// over the cell times the sine of the row's polar angle); 0 for a black environment.
    pub total: f32,
}

/// The solid-angle density of a direction drawn uniformly over the sphere.
const UNIFORM_PDF: f32 = 1.0 / (4.0 * PI);

fn direction_at(u: f32, v: f32) -> Vec3 {
    let phi = (u - 0.5) * TAU;
    let theta = v * PI;
    let s = theta.sin();
    Vec3::new(s * phi.sin(), theta.cos(), -s * phi.cos())
}

fn texel_direction(x: usize, y: usize, w: usize, h: usize) -> Vec3 {
    direction_at((x as f32 + 0.5) / w as f32, (y as f32 + 0.5) / h as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use oxray_scene::cornell_box;

    /// A one-texel map is sampled uniformly over the sphere: every sample has the radiance and
    /// the density 1 / 4 pi that `radiance_and_pdf` and `pdf` give its direction, and the
    /// directions' moments are the sphere's (mean 0, mean square 1/3 per axis).
    #[test]
    fn a_uniform_environment_is_sampled_uniformly_over_the_sphere() {
        let c = Vec3::new(0.5, 1.0, 2.0);
        let env = Environment::uniform(c);
        let n = 64 * 64;
        let (mut mean, mut square) = (Vec3::ZERO, Vec3::ZERO);
        for i in 0..n {
            let u = [
                ((i % 64) as f32 + 0.5) / 64.0,
                ((i / 64) as f32 + 0.5) / 64.0,
            ];
            let (d, l, pdf) = env.sample(u).unwrap();
            assert!((d.length() - 1.0).abs() < 1e-5, "{d}");
            assert_eq!(l, c);
            assert_eq!(pdf, 1.0 / (4.0 * PI));
            assert_eq!(env.radiance_and_pdf(d), (c, pdf));
            assert_eq!(env.pdf(d), pdf);
            assert_eq!(env.radiance(d), c);
            mean += d;
            square += d * d;
        }
        let (mean, square) = (mean / n as f32, square / n as f32);
        assert!(mean.abs().max_element() < 1e-3, "{mean}");
        assert!(
            (square - Vec3::splat(1.0 / 3.0)).abs().max_element() < 2e-3,
            "{square}"
        );
        // A black one is never sampled and has no density.
        let black = Environment::uniform(Vec3::ZERO);
        assert!(black.sample([0.5, 0.5]).is_none());
        assert_eq!(black.pdf(Vec3::Y), 0.0);
        assert_eq!(black.radiance_and_pdf(Vec3::Y), (Vec3::ZERO, 0.0));
    }

    #[test]
    fn direction_mapping_round_trips() {
        let env = Environment::from_texels(64, 32, vec![Vec3::ONE; 64 * 32], 1.0);
        for (x, y) in [(0, 0), (13, 7), (63, 31), (32, 16)] {
            let d = texel_direction(x, y, 64, 32);
            assert_eq!(env.texel_of(d), y * 64 + x);
        }
    }

    #[test]
    fn environment_pdf_integrates_to_one_and_matches_sampling() {
        let env = Environment::sky(1.0);
        // Integral of the pdf over the sphere by stratified uniform directions.
        let n = 400_000;
        let mut integral = 0.0f64;
        let mut rng = super::super::bsdf::Rng::new(9, 9, 9);
        for _ in 0..n {
            let z = 1.0 - 2.0 * rng.uniform();
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = TAU * rng.uniform();
            integral += env.pdf(Vec3::new(r * phi.cos(), z, r * phi.sin())) as f64;
        }
        integral *= 4.0 * PI as f64 / n as f64;
        assert!((integral - 1.0).abs() < 0.05, "{integral}");
        // Importance sampling estimates the irradiance-free integral of radiance the same way.
        let mut is = Vec3::ZERO;
        for _ in 0..n {
            let (_, l, pdf) = env.sample([rng.uniform(), rng.uniform()]).unwrap();
            is += l / pdf;
        }
        is /= n as f32;
        let mut uni = Vec3::ZERO;
        for y in 0..env.height {
            let sin_theta = (PI * (y as f32 + 0.5) / env.height as f32).sin();
            for x in 0..env.width {
                uni += env.texels[y * env.width + x] * sin_theta;
            }
        }
        uni *= 2.0 * PI * PI / (env.width * env.height) as f32;
        assert!(
            (is - uni).abs().max_element() / uni.max_element() < 0.03,
            "{is} vs {uni}"
        );
    }

    #[test]
    fn radiance_and_pdf_together_give_the_bits_of_each() {
        let mut rng = super::super::bsdf::Rng::new(3, 1, 4);
        for env in [
            Environment::sky(1.0),
            Environment::uniform(Vec3::ONE),
            Environment::uniform(Vec3::ZERO),
            Environment::from_texels(4, 2, vec![Vec3::ZERO; 8], 1.0),
            Environment::from_texels(2, 1, vec![Vec3::ZERO, Vec3::new(0.0, 1e-3, 0.0)], 1.0),
        ] {
            for _ in 0..20_000 {
                let z = 1.0 - 2.0 * rng.uniform();
                let r = (1.0 - z * z).max(0.0).sqrt();
                let phi = TAU * rng.uniform();
                let d = Vec3::new(r * phi.cos(), z, r * phi.sin());
                let (l, pdf) = env.radiance_and_pdf(d);
                assert_eq!(
                    l.to_array().map(f32::to_bits),
                    env.radiance(d).to_array().map(f32::to_bits)
                );
                assert_eq!(pdf.to_bits(), env.pdf(d).to_bits(), "{d}");
            }
            let nan = Vec3::new(f32::NAN, 0.0, 1.0);
            assert_eq!(env.radiance_and_pdf(nan), (Vec3::ZERO, 0.0));
        }
    }

    #[test]
    fn lookups_are_bilinear_between_texel_centres() {
        // Two columns, one row: black at u = 0.25, white at u = 0.75 (texel centres).
        let env = Environment::from_texels(2, 1, vec![Vec3::ZERO, Vec3::ONE], 1.0);
        let at_u = |u: f32| env.radiance(direction_at(u, 0.5)).x;
        assert!(at_u(0.25).abs() < 1e-5 && (at_u(0.75) - 1.0).abs() < 1e-5);
        assert!((at_u(0.5) - 0.5).abs() < 1e-5, "{}", at_u(0.5));
        assert!((at_u(0.625) - 0.75).abs() < 1e-5, "{}", at_u(0.625));
        // Across the seam at u = 0 the map wraps around.
        assert!((at_u(0.0) - 0.5).abs() < 1e-5, "{}", at_u(0.0));
        assert!((at_u(0.125) - 0.25).abs() < 1e-5, "{}", at_u(0.125));
    }

    /// A map with sharp features: mostly black, a sparse pattern of white texels and two
    /// bright ones, so that the filtered radiance is positive in black texels next to lit ones.
    fn sparse_map() -> Environment {
        let (w, h) = (32, 16);
        let texels = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                if (x, y) == (5, 4) || (x, y) == (20, 11) {
                    Vec3::new(40.0, 30.0, 20.0)
                } else if (x * 7 + y * 3) % 11 == 0 {
                    Vec3::ONE
                } else {
                    Vec3::ZERO
                }
            })
            .collect();
        Environment::from_texels(w, h, texels, 1.0)
    }

    /// Mean and standard error of `n` draws of `f`.
    fn estimate(n: usize, mut f: impl FnMut() -> f64) -> (f64, f64) {
        let (mut s, mut s2) = (0.0, 0.0);
        for _ in 0..n {
            let x = f();
            s += x;
            s2 += x * x;
        }
        let mean = s / n as f64;
        (
            mean,
            ((s2 / n as f64 - mean * mean).max(0.0) / n as f64).sqrt(),
        )
    }

    #[test]
    fn importance_sampling_agrees_with_uniform_sampling_of_the_filtered_map() {
        // Irradiance E(n) = integral of L(d) max(0, n.d) over the sphere, estimated three ways:
        // uniform directions; light sampling alone (biased if the pdf missed directions where
        // the filtered map is positive, or if it were not the sampled density); and MIS of
        // light and cosine sampling with the power heuristic, as the path tracer does.
        let env = sparse_map();
        let mut rng = super::super::bsdf::Rng::new(3, 1, 4);
        let n = 400_000;
        for normal in [Vec3::Y, Vec3::new(0.3, -0.2, 0.9).normalize(), -Vec3::X] {
            let (t, b) = normal.any_orthonormal_pair();
            let lum = |l: Vec3| luminance(l) as f64;
            let (uni, uni_se) = estimate(n, || {
                let z = 1.0 - 2.0 * rng.uniform();
                let r = (1.0 - z * z).max(0.0).sqrt();
                let phi = TAU * rng.uniform();
                let d = Vec3::new(r * phi.cos(), r * phi.sin(), z);
                lum(env.radiance(d)) * d.dot(normal).max(0.0) as f64 * 4.0 * PI as f64
            });
            let (light, light_se) = estimate(n, || {
                let Some((d, l, pdf)) = env.sample([rng.uniform(), rng.uniform()]) else {
                    return 0.0;
                };
                assert!(
                    (pdf - env.pdf(d)).abs() <= 1e-3 * pdf,
                    "{pdf} vs {}",
                    env.pdf(d)
                );
                lum(l) * d.dot(normal).max(0.0) as f64 / pdf as f64
            });
            let (mis, mis_se) = estimate(n, || {
                let mut sum = 0.0;
                if let Some((d, l, pdf)) = env.sample([rng.uniform(), rng.uniform()]) {
                    let cos = d.dot(normal);
                    if cos > 0.0 {
                        let p_cos = cos / PI;
                        let w = pdf * pdf / (pdf * pdf + p_cos * p_cos);
                        sum += lum(l) * (cos * w / pdf) as f64;
                    }
                }
                let (u1, u2) = (rng.uniform(), rng.uniform());
                let r = u1.sqrt();
                let phi = TAU * u2;
                let d = t * (r * phi.cos()) + b * (r * phi.sin()) + normal * (1.0 - u1).sqrt();
                let (cos, pdf) = (d.dot(normal), env.pdf(d));
                if cos > 0.0 {
                    let p_cos = cos / PI;
                    let w = p_cos * p_cos / (pdf * pdf + p_cos * p_cos);
                    sum += lum(env.radiance(d)) * (cos * w / p_cos) as f64;
                }
                sum
            });
            println!(
                "irradiance at {normal}: uniform {uni:.4} ± {uni_se:.4}, light sampling \
                 {light:.4} ± {light_se:.4}, MIS {mis:.4} ± {mis_se:.4}"
            );
            for (name, v, se) in [("light sampling", light, light_se), ("MIS", mis, mis_se)] {
                let z = (v - uni) / (se * se + uni_se * uni_se).sqrt();
                assert!(z.abs() < 4.5, "{name}: {v} vs uniform {uni} (z = {z:.1})");
            }
            // Importance sampling is what makes the estimate cheap.
            assert!(mis_se < 0.5 * uni_se, "{mis_se} vs {uni_se}");
        }
    }

    #[test]
    fn cornell_light_is_the_only_emitter() {
        let lights = TriangleLights::new(&cornell_box());
        assert_eq!(lights.triangles.len(), 2);
        let area: f32 = lights
            .triangles
            .iter()
            .map(|t| 0.5 * t.e1.cross(t.e2).length())
            .sum();
        // Area pdf of a uniform choice over the light: 1 / area.
        let pdf = lights.area_pdf(3);
        assert!((pdf * area - 1.0).abs() < 1e-4, "{pdf} {area}");
        assert_eq!(lights.area_pdf(0), 0.0);
        let (_, p, _, _) = lights.sample([0.7, 0.3, 0.9]).unwrap();
        assert!((p.y - 548.3 / 555.0).abs() < 1e-5);
    }
}
