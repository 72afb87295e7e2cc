//! The denoiser (`oxray_render::denoise`, Open Image Denoise loaded at run time): it brings a
//! low-sample render of the Cornell box closer to a converged one, the guides help, its input
//! is checked (typed errors, never a panic), and a missing library is a typed error.
//!
//! The tests that need the library skip, saying so, where it is not installed
//! (`scripts/setup-oidn.sh`), unless `OXRAY_REQUIRE_OIDN=1` (as CI sets), which makes its
//! absence a failure.

use glam::Vec3;
use oxray_render::denoise::{DenoiseError, Denoiser, DeviceType};
use oxray_render::lights::Environment;
use oxray_render::{render_passes, Image, RenderOptions, Rendered};
use std::ops::ControlFlow;
use std::path::Path;

/// The denoiser, or `None` (with a message) where OIDN is not installed and not required.
fn denoiser() -> Option<Denoiser> {
    match Denoiser::new() {
        Ok(d) => Some(d),
        Err(e @ DenoiseError::LibraryNotFound { .. })
            if std::env::var("OXRAY_REQUIRE_OIDN").as_deref() != Ok("1") =>
        {
            eprintln!("skipped: {e}");
            None
        }
        Err(e) => panic!("no denoiser: {e}"),
    }
}

fn cornell(size: u32, spp: u32, seed: u32, aovs: bool) -> Rendered {
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
    .unwrap()
}

/// RMSE of the PNG's 8-bit values (tone-mapped sRGB): the error as the image is seen, where the
/// light's radiance (tens, in linear values) does not outweigh the rest of the image.
fn rmse_png(a: &Image, b: &Image) -> f64 {
    let (a, b) = (a.to_srgb8(), b.to_srgb8());
    let sum: f64 = (a.chunks(4).zip(b.chunks(4)))
        .flat_map(|(p, q)| (0..3).map(move |c| (p[c] as f64 - q[c] as f64).powi(2)))
        .sum();
    (sum / (a.len() / 4 * 3) as f64).sqrt()
}

/// Relative MSE, (x - ref)^2 / (ref^2 + 0.01) averaged over the linear values.
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

fn rgb(image: &Image) -> Vec<[f32; 3]> {
    image.pixels.iter().map(|p| [p[0], p[1], p[2]]).collect()
}

fn with_alpha(size: u32, px: Vec<[f32; 3]>) -> Image {
    Image {
        width: size,
        height: size,
        pixels: px.into_iter().map(|[r, g, b]| [r, g, b, 1.0]).collect(),
    }
}

/// At 1 and 4 spp (64x64, against 512 spp of another seed), measured on the CPU device:
///
/// | spp | PNG RMSE noisy | denoised, no guides | albedo + normal | relMSE noisy | denoised |
/// |----:|------:|------:|------:|------:|------:|
/// |   1 | 34.63 | 12.00 | 11.43 | 0.540 | 0.047 |
/// |   4 | 18.90 |  6.11 |  5.72 | 0.065 | 0.009 |
///
/// The bounds leave room for another device's arithmetic (OIDN's CUDA device in CI).
#[test]
fn denoising_brings_a_low_spp_cornell_box_close_to_the_converged_one() {
    let Some(d) = denoiser() else { return };
    let size = 64;
    let reference = cornell(size, 512, 1000, false).image;
    for spp in [1, 4] {
        let noisy = cornell(size, spp, 0, true);
        let guided = d.denoise_rendered(&noisy).unwrap();
        let plain = with_alpha(
            size,
            d.denoise(&rgb(&noisy.image), None, None, size, size)
                .unwrap(),
        );
        let (e_noisy, e_plain, e_guided) = (
            rmse_png(&noisy.image, &reference),
            rmse_png(&plain, &reference),
            rmse_png(&guided, &reference),
        );
        eprintln!(
            "{spp} spp, PNG RMSE: noisy {e_noisy:.2}, denoised {e_plain:.2}, guided {e_guided:.2}"
        );
        assert!(e_plain < 0.5 * e_noisy, "{spp} spp: {e_plain} vs {e_noisy}");
        assert!(
            e_guided < 0.5 * e_noisy,
            "{spp} spp: {e_guided} vs {e_noisy}"
        );
        assert!(
            e_guided <= e_plain,
            "{spp} spp: guides made it worse, {e_guided} vs {e_plain}"
        );
        let (r_noisy, r_guided) = (
            rel_mse(&noisy.image, &reference),
            rel_mse(&guided, &reference),
        );
        assert!(
            r_guided < 0.25 * r_noisy,
            "{spp} spp relMSE: {r_guided} vs {r_noisy}"
        );
        // The alpha channel is the render's, and the size unchanged.
        assert_eq!((guided.width, guided.height), (size, size));
        assert!(guided.pixels.iter().all(|p| p[3] == 1.0));
    }
}

/// High-dynamic-range input stays in its range: a flat image of radiance 5 (which a
/// low-dynamic-range filter would clip to 1) comes back near 5, its colour kept. A flat image
/// is not what the network was trained on: its pixels drift (4.57 in a corner, measured),
/// hence the bounds, which still no clipped image meets.
#[test]
fn radiance_above_one_is_kept() {
    let Some(d) = denoiser() else { return };
    let out = d
        .denoise(&[[5.0, 2.5, 0.5]; 1024], None, None, 32, 32)
        .unwrap();
    let mean = |c: usize| out.iter().map(|p| p[c]).sum::<f32>() / out.len() as f32;
    assert!((mean(0) - 5.0).abs() < 0.5, "{}", mean(0));
    assert!((mean(1) - 2.5).abs() < 0.25, "{}", mean(1));
    assert!(
        out.iter().all(|p| p[0] > 3.0 && p[0] > p[1] && p[1] > p[2]),
        "{out:?}"
    );
}

#[test]
fn sizes_and_guides_are_checked() {
    let Some(d) = denoiser() else { return };
    let px = vec![[0.5f32; 3]; 12];
    let mismatch = |r: Result<Vec<[f32; 3]>, DenoiseError>, which: &str| match r {
        Err(DenoiseError::SizeMismatch {
            image,
            got,
            expected,
            ..
        }) => {
            assert_eq!(image, which);
            assert_ne!(got, expected);
        }
        other => panic!("{other:?}"),
    };
    mismatch(d.denoise(&px, None, None, 4, 4), "beauty");
    mismatch(d.denoise(&px, Some(&px[..11]), None, 4, 3), "albedo");
    mismatch(d.denoise(&px, Some(&px), Some(&px[1..]), 4, 3), "normal");
    assert!(matches!(
        d.denoise(&px, None, Some(&px), 4, 3),
        Err(DenoiseError::NormalWithoutAlbedo)
    ));
    for (w, h) in [(0, 12), (12, 0), (u32::MAX, u32::MAX)] {
        assert!(matches!(
            d.denoise(&px, None, None, w, h),
            Err(DenoiseError::BadSize { .. })
        ));
    }
    // AOVs of another size than the image.
    let mut r = cornell(8, 1, 0, true);
    r.aovs.as_mut().unwrap().width = 4;
    assert!(matches!(
        d.denoise_rendered(&r),
        Err(DenoiseError::SizeMismatch { .. })
    ));
    // And the same call with matching sizes works, with or without the guides.
    assert_eq!(
        d.denoise(&px, Some(&px), Some(&px), 4, 3).unwrap().len(),
        12
    );
    assert_eq!(d.denoise(&px, Some(&px), None, 3, 4).unwrap().len(), 12);
}

/// NaN, infinite and negative values, one-pixel and one-row images, and guides out of their
/// range give finite, non-negative images, without a panic.
#[test]
fn bad_values_never_panic() {
    let Some(d) = denoiser() else { return };
    let mut px = vec![[0.25f32; 3]; 64];
    px[3] = [f32::NAN, f32::INFINITY, -1.0];
    px[9] = [f32::NEG_INFINITY, 1e30, -0.0];
    let wild = vec![[f32::NAN, 7.0, -3.0]; 64];
    for (w, h) in [(8, 8), (64, 1), (1, 64)] {
        let out = d.denoise(&px, Some(&wild), Some(&wild), w, h).unwrap();
        assert!(
            out.iter().flatten().all(|v| v.is_finite() && *v >= 0.0),
            "{w}x{h}: {out:?}"
        );
    }
    let one = d.denoise(&[[1.0, 0.5, 0.25]], None, None, 1, 1).unwrap();
    assert!(one[0].iter().all(|v| v.is_finite()));
}

/// One denoiser serves several threads, each getting its own image's result.
#[test]
fn a_denoiser_is_shared_between_threads() {
    let Some(d) = denoiser() else { return };
    let images: Vec<Vec<[f32; 3]>> = (1..=4).map(|i| vec![[i as f32 * 0.2; 3]; 256]).collect();
    let alone: Vec<_> = images
        .iter()
        .map(|im| d.denoise(im, None, None, 16, 16).unwrap())
        .collect();
    std::thread::scope(|s| {
        let handles: Vec<_> = images
            .iter()
            .map(|im| s.spawn(|| d.denoise(im, None, None, 16, 16).unwrap()))
            .collect();
        for (h, expected) in handles.into_iter().zip(&alone) {
            assert_eq!(&h.join().unwrap(), expected);
        }
    });
}

/// Without the library (or with another library in its place) the denoiser is a typed error
/// whose message says how to install it. Needs no OIDN.
#[test]
fn a_missing_library_is_a_typed_error() {
    let missing = Path::new("/nonexistent/oxray/libOpenImageDenoise.so.2");
    match Denoiser::from_library(missing, DeviceType::Cpu) {
        Err(e @ DenoiseError::LibraryNotFound { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains("scripts/setup-oidn.sh"), "{msg}");
            assert!(msg.contains("OXRAY_OIDN_LIB"), "{msg}");
            assert!(msg.contains("/nonexistent/oxray"), "{msg}");
        }
        other => panic!("{other:?}"),
    }
    // A library that loads but is not OIDN (the C maths library, present wherever Rust runs
    // on Linux).
    #[cfg(target_os = "linux")]
    match Denoiser::from_library(Path::new("libm.so.6"), DeviceType::Cpu) {
        Err(DenoiseError::LibraryNotFound { reason }) => {
            assert!(reason.contains("lacks oidnNewDevice"), "{reason}")
        }
        other => panic!("{other:?}"),
    }
}

/// A device this machine lacks is OIDN's error, typed, not a crash; one it has is reported as
/// the device it is.
#[test]
fn devices_are_chosen_or_refused() {
    let Some(d) = denoiser() else { return };
    assert!(matches!(
        d.device_type(),
        DeviceType::Cpu | DeviceType::Cuda
    ));
    let cpu = Denoiser::with_device(DeviceType::Cpu).unwrap();
    assert_eq!(cpu.device_type(), DeviceType::Cpu);
    match Denoiser::with_device(DeviceType::Cuda) {
        Ok(gpu) => assert_eq!(gpu.device_type(), DeviceType::Cuda),
        Err(DenoiseError::Device { code, message }) => {
            assert_ne!(code, 0);
            assert!(!message.is_empty());
        }
        Err(e) => panic!("{e}"),
    }
}
