//! The wavefront's vertices on plain diffuse surfaces, sixteen paths at a time.
//!
//! A tile's paths are all at one vertex, and on the commonest surfaces (Lambertian, without
//! textures, vertex normals or vertex colours, lit by emissive triangles) a vertex is the same
//! short sequence of arithmetic for every path. Here it runs as loops over sixteen paths' values
//! side by side (structure of arrays), which the compiler turns into vector instructions, and
//! so are the Sobol numbers' hashes and scrambles ([`sampler::vertex_numbers_lanes`]); the
//! steps that look things up (the light's triangle, the Sobol table) stay lane by lane. Every operation is the one
//! [`programs::vertex`] does, in the same order, so a path's numbers come out bit for bit the
//! same; the wavefront's tests compare whole images with the pipeline's.

use crate::bsdf::{hash, sin_cos_turns, Rng};
use crate::filter::sample_offset;
use crate::programs::{self, Params, PathState, ShadowRay};
use crate::sampler::{self, dim, lanes_from, Sampler};
use glam::Vec3;
use oxray::Transform;
use oxray_scene::MaterialDesc;
use std::f32::consts::FRAC_1_PI;

/// Paths per batch: sixteen, one AVX-512 register of floats (two AVX2 ones).
pub(super) const LANES: usize = 16;

/// Whether the processor runs the AVX-512 forms (16 floats a register).
#[cfg(target_arch = "x86_64")]
fn has_avx512() -> bool {
    std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512vl")
        && std::arch::is_x86_feature_detected!("avx512bw")
        && std::arch::is_x86_feature_detected!("avx512dq")
}

/// Defines `$name`, which runs `$of` compiled for AVX-512 or AVX2 where the processor has
/// them (so that the lanes' loops become vector code of that width), as plain code elsewhere.
/// `$of` must be `#[inline(always)]`.
macro_rules! simd_form {
    ($(#[$doc:meta])* fn $name:ident($($arg:ident: $ty:ty),*) -> $ret:ty = $of:ident) => {
        $(#[$doc])*
        fn $name($($arg: $ty),*) -> $ret {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx2,avx512f,avx512vl,avx512bw,avx512dq")]
                unsafe fn avx512($($arg: $ty),*) -> $ret {
                    $of($($arg),*)
                }
                #[target_feature(enable = "avx2")]
                unsafe fn avx2($($arg: $ty),*) -> $ret {
                    $of($($arg),*)
                }
                if has_avx512() {
                    // SAFETY: the processor has the AVX-512 features, checked just above.
                    return unsafe { avx512($($arg),*) };
                }
                if std::arch::is_x86_feature_detected!("avx2") {
                    // SAFETY: the processor has AVX2, checked just above.
                    return unsafe { avx2($($arg),*) };
                }
            }
            $of($($arg),*)
        }
    };
}

simd_form!(
    /// [`vertices_of`] in the processor's widest vector instructions.
    fn vertices_simd(
        p: &Params,
        inputs: &[Input; LANES],
        n: usize,
        seq: Option<[F; 8]>,
        out: &mut [Output]
    ) -> () = vertices_of
);

simd_form!(
    /// [`camera_paths_of`] in the processor's widest vector instructions.
    fn camera_paths_simd(p: &Params, lx: &[u32; LANES], ly: &[u32; LANES]) -> [PathState; LANES]
        = camera_paths_of
);

simd_form!(
    /// [`sobol_numbers_of`] in the processor's widest vector instructions.
    fn sobol_numbers_simd(
        index: u32,
        depth: u32,
        pixels: &[u32; LANES],
        salt: u32,
        needed: u8
    ) -> Option<[F; 8]> = sobol_numbers_of
);

/// Whether [`vertices`] applies to a scene at all: it samples emissive triangles and the
/// environment but no punctual light, writes no AOVs, and reads emission without textures.
/// Then a hit qualifies by [`qualifies_material`] and [`qualifies_prim`].
pub(super) fn applies(p: &Params) -> bool {
    p.aov.is_none()
        && p.scene.lights.is_empty()
        && p.scene
            .materials
            .iter()
            .all(|m| m.emissive_texture.is_none())
}

/// Whether a hit on material `m` may be a plain diffuse vertex (if its primitive
/// [`qualifies_prim`]): no texture, no normal map, no metal, no coat, no transmission.
pub(super) fn qualifies_material(m: &MaterialDesc) -> bool {
    let surf = crate::bsdf::Surface::new(
        Vec3::ZERO,
        m.metallic,
        m.roughness,
        m.transmission,
        m.ior,
        m.specular,
    );
    surf.is_lambertian()
        && m.base_color_texture.is_none()
        && m.metallic_roughness_texture.is_none()
        && m.normal_texture.is_none()
}

/// Whether a hit on primitive `prim` may be a plain diffuse vertex (if its material
/// [`qualifies_material`]): no vertex normals, no vertex colours.
pub(super) fn qualifies_prim(prim: &oxray_scene::Primitive) -> bool {
    prim.normals.is_empty() && prim.colors.is_empty()
}

/// One path of a batch, as gathered for [`vertices`].
#[derive(Clone, Copy, Default)]
pub(super) struct Input {
    pub state: PathState,
    /// The full image's pixel (the random stream's key).
    pub image_pixel: u32,
    pub origin: Vec3,
    pub dir: Vec3,
    pub t: f32,
    /// The hit triangle in world space.
    pub vertices: [Vec3; 3],
    /// The material's base colour, emission and sidedness, and its area pdf as a light.
    pub base: Vec3,
    pub emissive: Vec3,
    pub double_sided: bool,
    pub area_pdf: f32,
    /// Whether next-event estimation samples this surface's emission (it does not move).
    pub sampled: bool,
}

/// What [`vertices`] gives back per path: its new state and its light sample's shadow ray.
pub(super) type Output = (PathState, Option<ShadowRay>);

/// Structure-of-arrays values of a batch.
type F = [f32; LANES];

fn splat(x: f32) -> F {
    [x; LANES]
}

/// `f` lane by lane (a loop the compiler vectorizes for simple `f`), its results transposed
/// into one array per value.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // the lane indexes both the input and the output rows
fn map<const K: usize>(f: impl Fn(usize) -> [f32; K]) -> [F; K] {
    let mut out = [[0.0; LANES]; K];
    for l in 0..LANES {
        let v = f(l);
        for k in 0..K {
            out[k][l] = v[k];
        }
    }
    out
}

/// The vertices of up to [`LANES`] paths, all at one depth (`inputs[n..]` are padding, and
/// `n` is at least 1), each what [`programs::vertex`] computes for it; `out[i]` for
/// `inputs[i]`.
pub(super) fn vertices(p: &Params, inputs: &[Input; LANES], n: usize, out: &mut [Output]) {
    // The vertex's Sobol numbers, apart: inlined into the vertex, their vector registers
    // pushed the vertex's own values out to the stack (measured 5 % slower a sample).
    let seq = if p.sampler == Sampler::Sobol {
        let salt = programs::stream_salt(p.seed);
        let pixels = lanes_from(|l| inputs[l].image_pixel);
        // What a plain diffuse vertex draws: the light's triangle and point, its pick where
        // the environment is lit too, the direction (never a lobe: there is one), and roulette
        // where `programs::continue_path` plays it (at the new vertex's depth).
        let depth = inputs[0].state.depth;
        let bit = |d: u32| 1u8 << d;
        let drawn = [
            dim::LIGHT[0],
            dim::LIGHT[1],
            dim::LIGHT[2],
            dim::BSDF[1],
            dim::BSDF[2],
        ];
        let mut needed = drawn.iter().fold(0, |m, &d| m | bit(d));
        if p.p_env > 0.0 {
            needed |= bit(dim::LIGHT_PICK);
        }
        if depth + 1 >= p.roulette_depth {
            needed |= bit(dim::ROULETTE);
        }
        sobol_numbers_simd(p.sample, depth, &pixels, salt, needed)
    } else {
        None
    };
    vertices_simd(p, inputs, n, seq, out);
}

/// The camera paths of sixteen pixels (launch indices `lx`, `ly`), each what
/// [`programs::camera_path`] makes: the same draws and arithmetic in the same order, as loops
/// over the lanes. `None` for a moving camera (a shutter), whose paths draw a time.
pub(super) fn camera_paths(
    p: &Params,
    lx: &[u32; LANES],
    ly: &[u32; LANES],
) -> Option<[PathState; LANES]> {
    if p.shutter.is_some() {
        return None;
    }
    Some(camera_paths_simd(p, lx, ly))
}

#[inline(always)]
fn camera_paths_of(p: &Params, lx: &[u32; LANES], ly: &[u32; LANES]) -> [PathState; LANES] {
    let [w, h] = p.image;
    let x: [u32; LANES] = lanes_from(|l| p.window[0] + lx[l]);
    let y: [u32; LANES] = lanes_from(|l| p.window[1] + ly[l]);
    let index: [u32; LANES] = lanes_from(|l| y[l] * w + x[l]);
    let salt = programs::stream_salt(p.seed);
    // `Rng::new(index, p.sample, salt)`, then the two draws of the pixel's offset.
    let key = hash(p.sample.wrapping_add(hash(salt)));
    let mut rng: [u32; LANES] = lanes_from(|l| hash(index[l] ^ key));
    let mut hashed = [[0.0f32; LANES]; 2];
    for h in &mut hashed {
        for l in 0..LANES {
            let mut g = Rng(rng[l]);
            h[l] = g.uniform();
            rng[l] = g.0;
        }
    }
    let [jx, jy] = if p.sampler == Sampler::Sobol {
        let seeds = lanes_from(|l| sampler::pixel_seed(index[l], salt));
        sampler::pixel_numbers_lanes(p.sample, &seeds)
    } else {
        hashed
    };
    let ox: F = lanes_from(|l| 0.5 + sample_offset(p.filter, jx[l]));
    let oy: F = lanes_from(|l| 0.5 + sample_offset(p.filter, jy[l]));
    let c = p.camera;
    lanes_from(|l| {
        let sx = 2.0 * (x[l] as f32 + ox[l]) / w as f32 - 1.0;
        let sy = 1.0 - 2.0 * (y[l] as f32 + oy[l]) / h as f32;
        let dir = (c.forward + c.right * sx + c.up * sy).normalize();
        PathState {
            seed: rng[l],
            throughput: [1.0; 3],
            origin: c.origin.to_array(),
            direction: dir.to_array(),
            ..Default::default()
        }
    })
}

/// The pixels' Sobol seeds ([`sampler::pixel_seed`]), then their numbers
/// ([`sampler::vertex_numbers_lanes_of`]).
#[inline(always)]
fn sobol_numbers_of(
    index: u32,
    depth: u32,
    pixels: &[u32; LANES],
    salt: u32,
    needed: u8,
) -> Option<[F; 8]> {
    let seeds = lanes_from(|l| sampler::pixel_seed(pixels[l], salt));
    sampler::vertex_numbers_lanes_of(index, depth, &seeds, needed)
}

/// The vertex; `seq`: its Sobol numbers ([`sampler::vertex_numbers_lanes`]), if the sampler
/// is Sobol and the sequence reaches the vertex's dimensions.
#[inline(always)]
#[allow(clippy::too_many_lines)]
fn vertices_of(
    p: &Params,
    inputs: &[Input; LANES],
    n: usize,
    seq: Option<[F; 8]>,
    out: &mut [Output],
) {
    let i = inputs;
    // The hit point and the geometric normal (through the identity's inverse transpose, as
    // the closest-hit context computes it without an instance).
    let [px, py, pz] = map(|l| {
        let (o, d, t) = (i[l].origin, i[l].dir, i[l].t);
        [o.x + d.x * t, o.y + d.y * t, o.z + d.z * t]
    });
    let r = Transform::IDENTITY.0;
    let [nx, ny, nz] = map(|l| {
        let [a, b, c] = i[l].vertices;
        let (e1, e2) = (b - a, c - a);
        let n = [
            e1.y * e2.z - e2.y * e1.z,
            e1.z * e2.x - e2.z * e1.x,
            e1.x * e2.y - e2.x * e1.y,
        ];
        [
            r[0] * n[0] + r[4] * n[1] + r[8] * n[2],
            r[1] * n[0] + r[5] * n[1] + r[9] * n[2],
            r[2] * n[0] + r[6] * n[1] + r[10] * n[2],
        ]
    });
    // normalize_or(Y), facing the ray.
    let [gx, gy, gz, front] = map(|l| {
        let len = (nx[l] * nx[l] + ny[l] * ny[l] + nz[l] * nz[l]).sqrt();
        let rcp = 1.0 / len;
        let ok = rcp.is_finite() && rcp > 0.0;
        let (x, y, z) = if ok {
            (nx[l] * rcp, ny[l] * rcp, nz[l] * rcp)
        } else {
            (0.0, 1.0, 0.0)
        };
        let d = i[l].dir;
        let front = (x * d.x + y * d.y + z * d.z) < 0.0;
        let s = if front { 1.0 } else { -1.0 };
        // `-v` flips the sign bit; `v * -1.0` does the same for every value.
        [x * s, y * s, z * s, if front { 1.0 } else { 0.0 }]
    });

    // Emission, weighted against the light sample that could have found it.
    let mut rad = map(|l| i[l].state.radiance);
    let thr = map(|l| i[l].state.throughput);
    for l in 0..n {
        let s = &i[l].state;
        let lit = front[l] != 0.0 || i[l].double_sided;
        let le = if lit { i[l].emissive } else { Vec3::ZERO };
        if le != Vec3::ZERO {
            let w = if s.pdf > 0.0 {
                let t = i[l].t;
                let d = i[l].dir;
                let cos_l = (gx[l] * -d.x + gy[l] * -d.y + gz[l] * -d.z).abs().max(1e-6);
                let light_pdf = match i[l].sampled {
                    true => (1.0 - p.p_env) * i[l].area_pdf * t * t / cos_l,
                    false => 0.0,
                };
                programs::power_heuristic(s.pdf, light_pdf)
            } else {
                1.0
            };
            let c = [
                thr[0][l] * le.x * w,
                thr[1][l] * le.y * w,
                thr[2][l] * le.z * w,
            ];
            for k in 0..3 {
                rad[k][l] += c[k];
            }
        }
    }

    let depth = i[0].state.depth + 1;
    if depth >= p.max_depth {
        for l in 0..n {
            let mut s = i[l].state;
            s.depth = depth;
            s.done = 1;
            s.radiance = [rad[0][l], rad[1][l], rad[2][l]];
            out[l] = (s, None);
        }
        return;
    }

    // The draws: the hash stream advances once per draw, the numbers are the vertex's Sobol
    // points where the sequence reaches (or the stream's own).
    let mut rng: [u32; LANES] = lanes_from(|l| i[l].state.seed);
    let mut hashed = [[0.0f32; LANES]; 7];
    // The stream after the light's four draws: the shadow ray's payload word 0.
    let mut rng4 = [0u32; LANES];
    for (k, h) in hashed.iter_mut().enumerate() {
        for l in 0..LANES {
            let mut g = Rng(rng[l]);
            h[l] = g.uniform();
            rng[l] = g.0;
        }
        if k == 3 {
            rng4 = rng;
        }
    }
    // Draw order: the light's pick and point (dimensions 3, 2, 0, 1), the BSDF's (6, 4, 5);
    // roulette (7) only where it is asked.
    const ORDER: [usize; 7] = [3, 2, 0, 1, 6, 4, 5];
    let numbers = seq.unwrap_or_else(|| {
        let mut numbers = [[f32::NAN; LANES]; 8];
        for (k, &d) in ORDER.iter().enumerate() {
            numbers[d] = hashed[k];
        }
        numbers
    });
    // `Surface::eval` of a Lambertian surface at light direction `wi`.
    let eval = |l: usize, wi: Vec3| {
        let d = i[l].dir;
        let cos_o = gx[l] * -d.x + gy[l] * -d.y + gz[l] * -d.z;
        let cos_i = gx[l] * wi.x + gy[l] * wi.y + gz[l] * wi.z;
        if cos_o <= 0.0 || cos_i <= 0.0 {
            (Vec3::ZERO, 0.0)
        } else {
            (i[l].base * (FRAC_1_PI * cos_i), cos_i * FRAC_1_PI)
        }
    };
    let eps = p.eps;
    // `offset`: the point pushed off the surface along the geometric normal, towards `dir`.
    let scale = map(|l| {
        let m = |a: f32, b: f32| if a > b { a } else { b };
        [eps + m(m(px[l].abs(), py[l].abs()), pz[l].abs()) * 1e-6]
    })[0];
    let offset = |l: usize, dx: f32, dy: f32, dz: f32| {
        let s = if dx * gx[l] + dy * gy[l] + dz * gz[l] >= 0.0 {
            1.0f32
        } else {
            -1.0
        };
        // `point + ng * scale` or `point - ng * scale`.
        let k = |p: f32, g: f32| {
            if s > 0.0 {
                p + g * scale[l]
            } else {
                p - g * scale[l]
            }
        };
        [k(px[l], gx[l]), k(py[l], gy[l]), k(pz[l], gz[l])]
    };
    let mut shadows: [Option<ShadowRay>; LANES] = [None; LANES];
    // One light sample, on the environment or the emissive triangles (`TriangleLights::sample`),
    // lane by lane: a search and a gather.
    let mut light_ok = [false; LANES];
    let mut lp = [[0.0f32; LANES]; 3];
    let mut ln = [[0.0f32; LANES]; 3];
    let mut two_sided = [false; LANES];
    let mut light_area_pdf = splat(0.0);
    let mut light_le = [[0.0f32; LANES]; 3];
    for l in 0..n {
        let u = [numbers[2][l], numbers[0][l], numbers[1][l]];
        if numbers[3][l] < p.p_env {
            let Some((wi, le, pdf)) = p.env.sample([u[0], u[1]]) else {
                continue;
            };
            let pdf = pdf * p.p_env;
            let (f, bsdf_pdf) = eval(l, wi);
            if f == Vec3::ZERO || wi.x * gx[l] + wi.y * gy[l] + wi.z * gz[l] <= 0.0 {
                continue;
            }
            let thr_l = Vec3::new(thr[0][l], thr[1][l], thr[2][l]);
            let [ox, oy, oz] = offset(l, wi.x, wi.y, wi.z);
            shadows[l] = Some(ShadowRay {
                from: Vec3::new(ox, oy, oz),
                dir: wi,
                tmax: f32::INFINITY,
                seed: rng4[l],
                radiance: thr_l * (f * le * (programs::power_heuristic(pdf, bsdf_pdf) / pdf)),
            });
            continue;
        }
        let Some((tri, q, _, area_pdf)) = p.lights.sample(u) else {
            continue;
        };
        let Some(lm) = p.scene.materials.get(tri.material as usize) else {
            continue;
        };
        // `emission` without a texture: the factor times white.
        let le = Vec3::from(lm.emissive) * Vec3::ONE;
        light_ok[l] = true;
        (lp[0][l], lp[1][l], lp[2][l]) = (q.x, q.y, q.z);
        (ln[0][l], ln[1][l], ln[2][l]) = (tri.normal.x, tri.normal.y, tri.normal.z);
        two_sided[l] = tri.two_sided;
        light_area_pdf[l] = area_pdf;
        (light_le[0][l], light_le[1][l], light_le[2][l]) = (le.x, le.y, le.z);
    }
    let [fx, fy, fz] = map(|l| offset(l, lp[0][l] - px[l], lp[1][l] - py[l], lp[2][l] - pz[l]));
    let [wx, wy, wz, dist] = map(|l| {
        let (tx, ty, tz) = (lp[0][l] - fx[l], lp[1][l] - fy[l], lp[2][l] - fz[l]);
        let dist = (tx * tx + ty * ty + tz * tz).sqrt();
        [tx / dist, ty / dist, tz / dist, dist]
    });
    for l in 0..n {
        if !light_ok[l] || dist[l].is_nan() || dist[l] <= 0.0 {
            continue;
        }
        let dot_l = ln[0][l] * wx[l] + ln[1][l] * wy[l] + ln[2][l] * wz[l];
        let cos_l = if two_sided[l] { dot_l.abs() } else { -dot_l };
        let (f, bsdf_pdf) = eval(l, Vec3::new(wx[l], wy[l], wz[l]));
        let wi_ng = wx[l] * gx[l] + wy[l] * gy[l] + wz[l] * gz[l];
        if f == Vec3::ZERO || wi_ng <= 0.0 || cos_l <= 1e-6 {
            continue;
        }
        let le = Vec3::new(light_le[0][l], light_le[1][l], light_le[2][l]);
        let pdf = (1.0 - p.p_env) * light_area_pdf[l] * dist[l] * dist[l] / cos_l;
        if le == Vec3::ZERO || pdf.is_nan() || pdf <= 0.0 {
            continue;
        }
        let contribution = f * le * (programs::power_heuristic(pdf, bsdf_pdf) / pdf);
        let thr_l = Vec3::new(thr[0][l], thr[1][l], thr[2][l]);
        shadows[l] = Some(ShadowRay {
            from: Vec3::new(fx[l], fy[l], fz[l]),
            dir: Vec3::new(wx[l], wy[l], wz[l]),
            tmax: dist[l] * (1.0 - 1e-4) - eps,
            seed: rng4[l],
            radiance: thr_l * contribution,
        });
    }

    // The BSDF sample: a cosine-weighted direction around the normal (`Surface::sample`).
    let [bx, by, bz, cos_o] = map(|l| {
        let d = i[l].dir;
        [
            gx[l],
            gy[l],
            gz[l],
            gx[l] * -d.x + gy[l] * -d.y + gz[l] * -d.z,
        ]
    });
    // `any_orthonormal_pair`.
    let [t0, t1, t2, b0, b1, b2] = map(|l| {
        let (x, y, z) = (bx[l], by[l], bz[l]);
        let sign = z.signum();
        let a = -1.0 / (sign + z);
        let b = x * y * a;
        [
            1.0 + sign * x * x * a,
            sign * b,
            -sign * x,
            b,
            sign + y * y * a,
            -y,
        ]
    });
    let [rr, sq] = map(|l| {
        let u1 = numbers[4][l];
        [u1.sqrt(), (1.0 - u1).max(0.0).sqrt()]
    });
    let [sin_phi, cos_phi] = map(|l| {
        let (s, c) = sin_cos_turns(numbers[5][l]);
        [s, c]
    });
    let [vx, vy, vz] = map(|l| {
        let (rc, rs) = (rr[l] * cos_phi[l], rr[l] * sin_phi[l]);
        [
            t0[l] * rc + b0[l] * rs + bx[l] * sq[l],
            t1[l] * rc + b1[l] * rs + by[l] * sq[l],
            t2[l] * rc + b2[l] * rs + bz[l] * sq[l],
        ]
    });
    let [wx, wy, wz] = map(|l| {
        let rcp = 1.0 / (vx[l] * vx[l] + vy[l] * vy[l] + vz[l] * vz[l]).sqrt();
        [vx[l] * rcp, vy[l] * rcp, vz[l] * rcp]
    });
    let [ox, oy, oz] = map(|l| offset(l, wx[l], wy[l], wz[l]));

    for l in 0..n {
        let mut s = i[l].state;
        s.depth = depth;
        let mut t = Vec3::new(thr[0][l], thr[1][l], thr[2][l]);
        let mut seed = rng[l];
        // `Surface::sample`, then the vertex's acceptance of it.
        let cos_i = bx[l] * wx[l] + by[l] * wy[l] + bz[l] * wz[l];
        let sampled = if cos_o[l] <= 0.0 || cos_i <= 0.0 {
            None
        } else {
            let (f, pdf) = (i[l].base * (FRAC_1_PI * cos_i), cos_i * FRAC_1_PI);
            (pdf > 0.0 && pdf.is_finite()).then(|| (f / pdf, pdf))
        };
        let wi_ng = wx[l] * gx[l] + wy[l] * gy[l] + wz[l] * gz[l];
        match sampled {
            Some((weight, pdf)) if wi_ng > 0.0 => {
                let (origin, wi) = (
                    Vec3::new(ox[l], oy[l], oz[l]),
                    Vec3::new(wx[l], wy[l], wz[l]),
                );
                programs::continue_path(p, &mut s, &mut t, weight, pdf, origin, wi, || {
                    // The roulette's draw: the hash stream advances; the number is the
                    // sequence's where it reaches.
                    let mut g = Rng(seed);
                    let u = g.uniform();
                    seed = g.0;
                    if numbers[7][l].is_nan() {
                        u
                    } else {
                        numbers[7][l]
                    }
                });
            }
            _ => s.done = 1,
        }
        s.seed = seed;
        s.radiance = [rad[0][l], rad[1][l], rad[2][l]];
        s.throughput = t.to_array();
        out[l] = (s, shadows[l]);
    }
}
