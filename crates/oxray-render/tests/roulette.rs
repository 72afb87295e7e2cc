//! Russian roulette on the path throughput, from a chosen vertex on (`roulette_depth`, 3 by
//! default: the first bounces carry most of the image and are never cut short), with the
//! probability `programs::roulette_survival` (three times the throughput, at most 1). Measured
//! on the Cornell box at equal samples: the mean squared error against a converged reference,
//! for roulette from the second vertex, the third (the default) and the fourth, with wall-clock
//! times (only indicative on a loaded machine). What the test asserts is that roulette stays
//! unbiased: each setting's image has the reference's mean, and its error is variance (it
//! shrinks with the samples).

use glam::Vec3;
use oxray_render::lights::Environment;
use oxray_render::{render, Image, RenderOptions};
use oxray_scene::cornell_box;

fn cornell(spp: u32, roulette_depth: u32) -> (Image, f64) {
    let o = RenderOptions {
        width: 32,
        height: 32,
        spp,
        max_depth: 8,
        roulette_depth,
        ..Default::default()
    };
    let t = std::time::Instant::now();
    let img = render(
        &cornell_box(),
        &Environment::uniform(Vec3::ZERO),
        &o,
        |_| {},
    )
    .unwrap();
    (img, t.elapsed().as_secs_f64())
}

fn mse(a: &Image, b: &Image) -> f64 {
    let n = a.pixels.len() * 3;
    a.pixels
        .iter()
        .zip(&b.pixels)
        .flat_map(|(p, q)| (0..3).map(move |c| (p[c] as f64 - q[c] as f64).powi(2)))
        .sum::<f64>()
        / n as f64
}

/// The mean over pixels of `a - b` (channels summed) and its standard error.
fn mean_difference(a: &Image, b: &Image) -> (f64, f64) {
    let d: Vec<f64> = a
        .pixels
        .iter()
        .zip(&b.pixels)
        .map(|(p, q)| (0..3).map(|c| p[c] as f64 - q[c] as f64).sum())
        .collect();
    let n = d.len() as f64;
    let mean = d.iter().sum::<f64>() / n;
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

#[test]
fn roulette_is_unbiased_from_any_vertex_and_its_variance_is_measured() {
    let (reference, _) = cornell(1024, 8);
    let mut errors = Vec::new();
    for depth in [2, 3, 4] {
        let (img, seconds) = cornell(16, depth);
        let e = mse(&img, &reference);
        let (diff, se) = mean_difference(&img, &reference);
        assert!(
            diff.abs() < 4.5 * se,
            "roulette from {depth}: the mean differs from the reference's by {diff} ({se} standard error)"
        );
        println!(
            "roulette from vertex {depth}: MSE at 16 spp {e:.5}, {seconds:.2} s, \
             1/(MSE time) {:.1}",
            1.0 / (e * seconds)
        );
        errors.push(e);
    }
    let (more, _) = cornell(64, 3);
    let e64 = mse(&more, &reference);
    println!("roulette from vertex 3: MSE at 64 spp {e64:.5}");
    assert!(e64 < 0.5 * errors[1], "{e64} vs {}", errors[1]);
}
