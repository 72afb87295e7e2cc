//! The denoiser's error against a converged reference: the built-in Cornell box rendered at
//! 1, 4 and 16 samples per pixel, compared with a high-sample render of it before and after
//! denoising (without guides, with the albedo, with albedo and normal), and the denoiser's
//! time. Needs Open Image Denoise (`scripts/setup-oidn.sh`).
//!
//! ```text
//! cargo run --release -p oxray-render --example denoise_error -- [SIZE] [REFERENCE_SPP]
//! ```
//!
//! Prints Markdown tables (docs/BENCHMARKS.md, "Denoising").

use glam::Vec3;
use oxray_render::denoise::Denoiser;
use oxray_render::lights::Environment;
use oxray_render::{render_passes, Image, RenderOptions, Rendered};
use std::ops::ControlFlow;
use std::time::Instant;

/// An error measure of an image against the reference.
type Metric = fn(&Image, &Image) -> f64;

fn render(size: u32, spp: u32, seed: u32, aovs: bool) -> Rendered {
    let opts = RenderOptions {
        width: size,
        height: size,
        spp,
        seed,
        aovs,
        ..Default::default()
    };
    let dark = Environment::uniform(Vec3::ZERO);
    render_passes(&oxray_scene::cornell_box(), &dark, &opts, |_| {
        ControlFlow::Continue(())
    })
    .expect("the Cornell box renders")
}

/// Root-mean-square error of the linear RGB values.
fn rmse(a: &Image, b: &Image) -> f64 {
    let sum: f64 = (a.pixels.iter().zip(&b.pixels))
        .flat_map(|(p, q)| (0..3).map(move |c| (p[c] as f64 - q[c] as f64).powi(2)))
        .sum();
    (sum / (a.pixels.len() * 3) as f64).sqrt()
}

/// [`rmse`] over the pixels whose reference is below 1 in every channel: all but the ceiling
/// light (46 of 64x64 pixels), whose radiance (17, 12, 4) makes the few pixels on its edges
/// dominate the linear RMSE of the whole image.
fn rmse_unlit(a: &Image, b: &Image) -> f64 {
    let dim = |q: &&[f32; 4]| q[..3].iter().all(|&v| v < 1.0);
    let (sum, n) = (a.pixels.iter().zip(&b.pixels))
        .filter(|(_, q)| dim(q))
        .fold((0.0, 0usize), |(s, n), (p, q)| {
            let e: f64 = (0..3).map(|c| (p[c] as f64 - q[c] as f64).powi(2)).sum();
            (s + e, n + 3)
        });
    (sum / n.max(1) as f64).sqrt()
}

/// Root-mean-square error of the PNG's 8-bit values (tone-mapped sRGB, [`Image::to_srgb8`]):
/// the error as the image is seen.
fn rmse_png(a: &Image, b: &Image) -> f64 {
    let (a, b) = (a.to_srgb8(), b.to_srgb8());
    let sum: f64 = (a.chunks(4).zip(b.chunks(4)))
        .flat_map(|(p, q)| (0..3).map(move |c| (p[c] as f64 - q[c] as f64).powi(2)))
        .sum();
    (sum / (a.len() / 4 * 3) as f64).sqrt()
}

/// Relative mean squared error, (x - ref)^2 / (ref^2 + 0.01) averaged: the error relative to
/// the brightness, so that the light's bright pixels do not outweigh the dark walls.
fn rel_mse(a: &Image, b: &Image) -> f64 {
    let sum: f64 = (a.pixels.iter().zip(&b.pixels))
        .flat_map(|(p, r)| {
            (0..3).map(move |c| {
                let (x, y) = (p[c] as f64, r[c] as f64);
                (x - y).powi(2) / (y * y + 0.01)
            })
        })
        .sum();
    sum / (a.pixels.len() * 3) as f64
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let size: u32 = args.next().map_or(Ok(64), |a| a.parse())?;
    let reference_spp: u32 = args.next().map_or(Ok(4096), |a| a.parse())?;
    let denoiser = Denoiser::new()?;
    let t = Instant::now();
    // Another seed than the noisy renders', so that its error is independent of theirs.
    let reference = render(size, reference_spp, 1000, false).image;
    println!(
        "reference: {size}x{size}, {reference_spp} spp in {:.1} s; denoiser on {:?} ({})\n",
        t.elapsed().as_secs_f64(),
        denoiser.device_type(),
        denoiser.library()
    );
    println!("| spp | metric | noisy | denoised, no guides | albedo | albedo + normal |");
    println!("|---:|---|---:|---:|---:|---:|");
    let mut times = Vec::new();
    for spp in [1, 4, 16] {
        let noisy = render(size, spp, 0, true);
        let aovs = noisy.aovs.as_ref().expect("AOVs were asked for");
        let beauty: Vec<[f32; 3]> = noisy
            .image
            .pixels
            .iter()
            .map(|p| [p[0], p[1], p[2]])
            .collect();
        let as_image = |px: Vec<[f32; 3]>| Image {
            width: size,
            height: size,
            pixels: px.into_iter().map(|[r, g, b]| [r, g, b, 1.0]).collect(),
        };
        let plain = as_image(denoiser.denoise(&beauty, None, None, size, size)?);
        let albedo = as_image(denoiser.denoise(&beauty, Some(&aovs.albedo), None, size, size)?);
        let t = Instant::now();
        let both = denoiser.denoise_rendered(&noisy)?;
        times.push((spp, t.elapsed().as_secs_f64() * 1e3));
        let metrics: [(&str, Metric); 4] = [
            ("RMSE, linear", rmse),
            ("RMSE, linear, without the light", rmse_unlit),
            ("RMSE, PNG (0-255)", rmse_png),
            ("relMSE", rel_mse),
        ];
        for (name, metric) in metrics {
            println!(
                "| {spp} | {name} | {:.4} | {:.4} | {:.4} | {:.4} |",
                metric(&noisy.image, &reference),
                metric(&plain, &reference),
                metric(&albedo, &reference),
                metric(&both, &reference),
            );
        }
    }
    // The network's time does not depend on the noise: time it once more at a larger size.
    let big = render(512, 1, 0, true);
    denoiser.denoise_rendered(&big)?;
    let t = Instant::now();
    let runs = 3;
    for _ in 0..runs {
        denoiser.denoise_rendered(&big)?;
    }
    println!();
    for (spp, ms) in times {
        println!("denoise {size}x{size} ({spp} spp, albedo + normal): {ms:.1} ms");
    }
    println!(
        "denoise 512x512 (albedo + normal): {:.0} ms (mean of {runs})",
        t.elapsed().as_secs_f64() * 1e3 / runs as f64
    );
    Ok(())
}
