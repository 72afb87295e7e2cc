//! The samplers ([`oxray_render::sampler`]): the Owen-scrambled Sobol sequence's properties
//! (values in [0, 1), every 2^k-point prefix stratified, pixels and dimension groups
//! decorrelated, the hash numbers past the last Sobol dimension), its table shared with the
//! C++ programs, and on the Cornell box: the same mean as independent sampling, a lower error at
//! equal samples against a converged reference, the same sampling in both backends, and images
//! that do not depend on the thread count.
//!
//! `cargo run --release -p oxray-render --example sampler_error` prints the error against
//! samples per pixel for both samplers (the table of `docs/BENCHMARKS.md`).

use glam::Vec3;
use oxray::Device;
use oxray_render::bsdf::Rng;
use oxray_render::device::{render_on, SOURCE};
use oxray_render::lights::Environment;
use oxray_render::sampler::{
    owen_scramble, pixel_seed, sobol, sobol_sample, Draws, SOBOL_DIMENSIONS, SOBOL_DIRECTIONS,
};
use oxray_render::{render, Image, RenderOptions, Sampler};
use oxray_scene::cornell_box;
use std::sync::OnceLock;

/// Whether the first `n` points of the pair of dimensions `(dx, dy)` have one point in every
/// elementary interval of `n` cells (`n` a power of two), for every shape.
fn stratified_2d(points: &[(f32, f32)]) -> bool {
    let n = points.len();
    let k = n.trailing_zeros();
    assert_eq!(1 << k, n);
    (0..=k).all(|a| {
        let (cx, cy) = (1usize << a, 1usize << (k - a));
        let mut seen = vec![false; n];
        points.iter().all(|&(x, y)| {
            let cell = (x * cx as f32) as usize * cy + (y * cy as f32) as usize;
            !std::mem::replace(&mut seen[cell], true)
        })
    })
}

fn stratified_1d(values: &[f32]) -> bool {
    let n = values.len();
    let mut seen = vec![false; n];
    values
        .iter()
        .all(|&v| !std::mem::replace(&mut seen[(v * n as f32) as usize], true))
}

#[test]
fn values_are_in_the_unit_interval() {
    for seed in [0u32, 1, 0xdead_beef, u32::MAX] {
        for dim in 0..SOBOL_DIMENSIONS {
            for index in (0..4096u32).chain([u32::MAX - 1, u32::MAX]) {
                let u = sobol_sample(index, dim, seed);
                assert!((0.0..1.0).contains(&u), "{u} at {index}, {dim}, {seed}");
            }
        }
    }
}

#[test]
fn the_direction_numbers_are_joe_and_kuos() {
    // Joe and Kuo's parameters (degree s, coefficients a, initial m) of dimensions 2 to 4;
    // dimension 1 is van der Corput's.
    let params: [(u32, u32, &[u32]); 3] = [(1, 0, &[1]), (2, 1, &[1, 3]), (3, 1, &[1, 3, 1])];
    for (i, v) in SOBOL_DIRECTIONS[0].iter().enumerate() {
        assert_eq!(*v, 1u32 << (31 - i));
    }
    for (d, (s, a, m0)) in params.into_iter().enumerate() {
        let s = s as usize;
        let mut m: Vec<u32> = m0.to_vec();
        for i in s..32 {
            let mut v = (m[i - s] << s) ^ m[i - s];
            for k in 1..s {
                if (a >> (s - 1 - k)) & 1 == 1 {
                    v ^= m[i - k] << k;
                }
            }
            m.push(v);
        }
        for i in 0..32 {
            assert_eq!(
                SOBOL_DIRECTIONS[d + 1][i],
                m[i] << (31 - i),
                "dim {}",
                d + 1
            );
        }
    }
    // The first points of the unscrambled sequence.
    let x: Vec<[f32; 2]> = (0..4)
        .map(|i| [0, 1].map(|d| sobol(i, d) as f32 / 4294967296.0))
        .collect();
    assert_eq!(x, [[0.0, 0.0], [0.5, 0.5], [0.25, 0.75], [0.75, 0.25]]);
}

/// The C++ programs carry the same direction numbers and the same dimension layout.
#[test]
fn the_cxx_programs_have_the_same_table() {
    let start = SOURCE.find("PT_SOBOL[4][32] = {").expect("the C++ table");
    let end = start + SOURCE[start..].find("};").unwrap();
    let numbers: Vec<u32> = SOURCE[start + 20..end]
        .split(|c: char| !c.is_ascii_alphanumeric())
        .filter(|t| t.starts_with("0x"))
        .map(|t| u32::from_str_radix(t.trim_start_matches("0x").trim_end_matches('u'), 16))
        .collect::<Result<_, _>>()
        .unwrap();
    assert_eq!(numbers, SOBOL_DIRECTIONS.concat());
    use oxray_render::sampler::dim;
    for (name, v) in [
        ("PT_DIM_PIXEL", dim::PIXEL),
        ("PT_DIM_CAMERA", dim::CAMERA),
        ("PT_DIM_PER_VERTEX", dim::PER_VERTEX),
        ("PT_DIM_LIGHT_0", dim::LIGHT[0]),
        ("PT_DIM_LIGHT_1", dim::LIGHT[1]),
        ("PT_DIM_LIGHT_2", dim::LIGHT[2]),
        ("PT_DIM_LIGHT_PICK", dim::LIGHT_PICK),
        ("PT_DIM_BSDF_0", dim::BSDF[0]),
        ("PT_DIM_BSDF_1", dim::BSDF[1]),
        ("PT_DIM_BSDF_2", dim::BSDF[2]),
        ("PT_DIM_ROULETTE", dim::ROULETTE),
        ("PT_DIM_PUNCTUAL", dim::PUNCTUAL),
    ] {
        assert!(
            SOURCE.contains(&format!("#define {name} {v}u\n")),
            "{name} is not {v} in the C++ programs"
        );
    }
    assert!(SOURCE.contains("#define PT_SOBOL_DIMS (PT_DIM_CAMERA + 5u * PT_DIM_PER_VERTEX)"));
    assert_eq!(SOBOL_DIMENSIONS, dim::vertex(5));
}

/// Every prefix of 2^k samples of a pixel is stratified: one point per elementary interval in
/// the first pair of each group of four dimensions (a (0, 2)-sequence), and one per interval of
/// length 2^-k in every dimension.
#[test]
fn prefixes_are_stratified() {
    for pixel in [0u32, 1, 77, 4095, 123_456] {
        let seed = pixel_seed(pixel, 0x5eed);
        for group in 0..SOBOL_DIMENSIONS / 4 {
            let d = group * 4;
            for k in 0..=10 {
                let n = 1u32 << k;
                let pts: Vec<(f32, f32)> = (0..n)
                    .map(|i| (sobol_sample(i, d, seed), sobol_sample(i, d + 1, seed)))
                    .collect();
                assert!(
                    stratified_2d(&pts),
                    "pixel {pixel}, dims {d}, {}, 2^{k}",
                    d + 1
                );
                for j in 0..4 {
                    let v: Vec<f32> = (0..n).map(|i| sobol_sample(i, d + j, seed)).collect();
                    assert!(stratified_1d(&v), "pixel {pixel}, dim {}, 2^{k}", d + j);
                }
            }
        }
    }
}

/// The scramble is a nested uniform one: it maps each dyadic interval onto one of the same
/// length (so it keeps the sequence's stratification), and it is a bijection.
#[test]
fn the_owen_scramble_keeps_dyadic_intervals() {
    let mut rng = Rng::new(1, 2, 3);
    for _ in 0..200 {
        let seed = (rng.uniform() * 4294967296.0) as u32;
        let x = (rng.uniform() * 4294967296.0) as u32;
        for bits in 1..32 {
            // Two numbers that share their first `bits` digits still share them scrambled.
            let y = x ^ (((rng.uniform() * 4294967296.0) as u32) >> bits);
            let (sx, sy) = (owen_scramble(x, seed), owen_scramble(y, seed));
            assert_eq!(sx >> (32 - bits), sy >> (32 - bits));
        }
    }
    let seed = 0x1234_5678;
    let mut seen = vec![false; 1 << 16];
    for x in 0..1u32 << 16 {
        // The low 16 digits of x << 16 are zero; the scramble of the first 16 is a bijection.
        let s = owen_scramble(x << 16, seed) >> 16;
        assert!(!std::mem::replace(&mut seen[s as usize], true));
    }
}

/// Neighbouring pixels, and groups of dimensions, see unrelated points.
#[test]
fn pixels_and_groups_are_decorrelated() {
    let n = 4096u32;
    let corr = |a: &dyn Fn(u32) -> f32, b: &dyn Fn(u32) -> f32| {
        let (xa, xb): (Vec<f64>, Vec<f64>) = (0..n).map(|i| (a(i) as f64, b(i) as f64)).unzip();
        let m = |v: &[f64]| v.iter().sum::<f64>() / n as f64;
        let (ma, mb) = (m(&xa), m(&xb));
        let cov: f64 = xa.iter().zip(&xb).map(|(x, y)| (x - ma) * (y - mb)).sum();
        let va: f64 = xa.iter().map(|x| (x - ma) * (x - ma)).sum();
        let vb: f64 = xb.iter().map(|y| (y - mb) * (y - mb)).sum();
        cov / (va * vb).sqrt()
    };
    let (s0, s1) = (pixel_seed(10, 0x5eed), pixel_seed(11, 0x5eed));
    assert_ne!(s0, s1);
    // The same dimension in two pixels, and the same position in two groups of one pixel.
    let r = corr(&|i| sobol_sample(i, 4, s0), &|i| sobol_sample(i, 4, s1));
    assert!(r.abs() < 0.08, "pixels correlate: {r}");
    let r = corr(&|i| sobol_sample(i, 4, s0), &|i| sobol_sample(i, 8, s0));
    assert!(r.abs() < 0.08, "groups correlate: {r}");
    // Another user seed gives another scramble.
    assert_ne!(pixel_seed(10, 0x5eed), pixel_seed(10, 0x5eee));
}

/// Past the last Sobol dimension the draws are the hash stream's, and the hash stream advances
/// alike with either sampler.
#[test]
fn deep_dimensions_fall_back_to_the_hash_stream() {
    let rng = Rng::new(5, 6, 7);
    let mut sobol = Draws::new(Sampler::Sobol, rng, 5, 6, 7);
    let mut independent = Draws::new(Sampler::Independent, rng, 5, 6, 7);
    let mut plain = rng;
    for d in 0..SOBOL_DIMENSIONS + 20 {
        let (s, i, p) = (sobol.get(d), independent.get(d), plain.uniform());
        assert_eq!(i, p);
        if d < SOBOL_DIMENSIONS {
            assert_eq!(s, sobol_sample(6, d, pixel_seed(5, 7)));
        } else {
            assert_eq!(s, p, "dimension {d}");
        }
        assert_eq!(sobol.rng.0, plain.0);
    }
    // A vertex whose dimensions start past the last: hash numbers too.
    sobol.base = SOBOL_DIMENSIONS;
    assert_eq!(sobol.get(0), plain.uniform());
}

fn opts(size: u32, spp: u32, sampler: Sampler, seed: u32) -> RenderOptions {
    RenderOptions {
        width: size,
        height: size,
        spp,
        max_depth: 8,
        sampler,
        seed,
        ..Default::default()
    }
}

fn dark() -> Environment {
    Environment::uniform(Vec3::ZERO)
}

fn rmse(a: &Image, b: &Image) -> f64 {
    let n = a.pixels.len() * 3;
    let sum: f64 = a
        .pixels
        .iter()
        .zip(&b.pixels)
        .flat_map(|(p, q)| (0..3).map(move |c| (p[c] as f64 - q[c] as f64).powi(2)))
        .sum();
    (sum / n as f64).sqrt()
}

/// A 64 x 64 reference of the Cornell box: 1024 samples per pixel, independent sampling with
/// its own seed (its noise is unrelated to the renders it judges).
fn reference() -> &'static Image {
    static R: OnceLock<Image> = OnceLock::new();
    R.get_or_init(|| {
        render(
            &cornell_box(),
            &dark(),
            &opts(64, 1024, Sampler::Independent, 99),
            |_| {},
        )
        .unwrap()
    })
}

/// Sobol renders have the mean of independent ones: over the image and over 16 x 16 blocks,
/// the mean difference per channel is within 4.5 standard errors (pixels are independent
/// draws, their differences estimate the noise) plus 0.5 % for the reference's own noise.
#[test]
fn sobol_converges_to_the_independent_mean() {
    let scene = cornell_box();
    let sobol = render(&scene, &dark(), &opts(64, 64, Sampler::Sobol, 3), |_| {}).unwrap();
    let reference = reference();
    let (w, s) = (64usize, 16usize);
    for by in 0..=w / s {
        // Block w / s stands for the whole image.
        let pixels: Vec<usize> = if by == w / s {
            (0..w * w).collect()
        } else {
            (0..s * w).map(|k| (by * s + k / w) * w + k % w).collect()
        };
        for c in 0..3 {
            let d: Vec<f64> = pixels
                .iter()
                .map(|&i| sobol.pixels[i][c] as f64 - reference.pixels[i][c] as f64)
                .collect();
            let n = d.len() as f64;
            let mean = d.iter().sum::<f64>() / n;
            let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
            let level = pixels
                .iter()
                .map(|&i| reference.pixels[i][c] as f64)
                .sum::<f64>()
                / n;
            let allowed = 4.5 * (var / n).sqrt() + 5e-3 * level;
            assert!(
                mean.abs() <= allowed,
                "rows {by}, channel {c}: mean difference {mean} > {allowed} (level {level})"
            );
        }
    }
}

/// At equal samples the Sobol sampler's error against the reference is lower. Measured
/// (`docs/BENCHMARKS.md`, eight seeds): 0.64 of independent sampling's at 4 samples, 0.43 at
/// 16 (seed 0: 0.63 and 0.43; the worst of eight seeds at 4 samples, 0.68); asserted with
/// margin.
#[test]
fn sobol_lowers_the_error_at_equal_samples() {
    let scene = cornell_box();
    let reference = reference();
    for (spp, bound) in [(4, 0.85), (16, 0.65)] {
        let e = |sampler| {
            let img = render(&scene, &dark(), &opts(64, spp, sampler, 0), |_| {}).unwrap();
            rmse(&img, reference)
        };
        let (sobol, independent) = (e(Sampler::Sobol), e(Sampler::Independent));
        let ratio = sobol / independent;
        println!(
            "{spp} spp: RMSE Sobol {sobol:.5}, independent {independent:.5}, ratio {ratio:.3}"
        );
        assert!(ratio < bound, "{spp} spp: ratio {ratio:.3} (bound {bound})");
    }
}

/// The C++ programs sample as the Rust ones do: with either sampler their images differ far
/// less than two seeds of one sampler do.
#[test]
fn both_backends_sample_alike() {
    let scene = cornell_box();
    for sampler in [Sampler::Sobol, Sampler::Independent] {
        let o = opts(32, 8, sampler, 0);
        let rust = render(&scene, &dark(), &o, |_| {}).unwrap();
        let cxx = render_on(&Device::cpu(), &scene, &dark(), &o, |_| {}).unwrap();
        let other = render(&scene, &dark(), &opts(32, 8, sampler, 1), |_| {}).unwrap();
        let (same, seeds) = (rmse(&rust, &cxx), rmse(&rust, &other));
        let identical = rust
            .pixels
            .iter()
            .zip(&cxx.pixels)
            .filter(|(p, q)| p == q)
            .count();
        println!(
            "{sampler}: Rust against C++ {same:.5}, against another seed {seeds:.5}; \
             {identical} of {} pixels bit-identical",
            rust.pixels.len()
        );
        assert!(same < 0.2 * seeds, "{sampler}: {same} against {seeds}");
    }
}

fn bits(img: &Image) -> Vec<u32> {
    img.pixels.iter().flatten().map(|v| v.to_bits()).collect()
}

#[test]
fn images_do_not_depend_on_the_thread_count() {
    let scene = cornell_box();
    let o = opts(32, 4, Sampler::Sobol, 5);
    let run = |threads: usize, cxx: bool| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| match cxx {
            false => render(&scene, &dark(), &o, |_| {}).unwrap(),
            true => render_on(&Device::cpu(), &scene, &dark(), &o, |_| {}).unwrap(),
        })
    };
    for cxx in [false, true] {
        assert_eq!(
            bits(&run(1, cxx)),
            bits(&run(3, cxx)),
            "C++ programs: {cxx}"
        );
    }
}
