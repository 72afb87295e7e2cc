//! The error against samples per pixel of the path tracer's two samplers
//! (`RenderOptions::sampler`, `--sampler`): the Rust programs on the CPU render the built-in
//! Cornell box and, where `../shared/data/gltf` has it, the pine glTF scene under the sky at
//! 64 x 64 pixels with paths of up to 8 vertices, and the RMSE against a reference of 1024
//! samples (independent sampling with another seed) is the RMS over eight seeds (one render's
//! error is heavy-tailed at few samples: a firefly weighs a lot). Prints the table of
//! `docs/BENCHMARKS.md`.
//!
//! `cargo run --release -p oxray-render --example sampler_error`

use glam::Vec3;
use oxray_render::lights::Environment;
use oxray_render::{render, Image, RenderOptions, Sampler};
use oxray_scene::{cornell_box, SceneDesc};
use std::time::{Duration, Instant};

fn opts(spp: u32, sampler: Sampler, seed: u32) -> RenderOptions {
    RenderOptions {
        width: 64,
        height: 64,
        spp,
        max_depth: 8,
        sampler,
        seed,
        ..Default::default()
    }
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

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let pine = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/gltf/smallpine/scene.gltf");
    let mut scenes: Vec<(&str, SceneDesc, Environment)> = vec![(
        "Cornell box",
        cornell_box(),
        Environment::uniform(Vec3::ZERO),
    )];
    match SceneDesc::load(&pine) {
        Ok(s) => scenes.push(("smallpine glTF", s, Environment::sky(1.0))),
        Err(e) => println!("skipping the glTF scene: {e}"),
    }
    let seeds = 8;
    for (name, scene, env) in &scenes {
        let reference = render(scene, env, &opts(1024, Sampler::Independent, 99), |_| {})?;
        println!(
            "| {name} | spp | RMSE independent | RMSE Sobol | ratio | time independent / Sobol |"
        );
        for spp in [1, 2, 4, 8, 16, 32, 64] {
            let error = |sampler| -> Result<(f64, Duration), Box<dyn std::error::Error>> {
                let t = Instant::now();
                let mut mse = 0.0;
                for seed in 0..seeds {
                    let img = render(scene, env, &opts(spp, sampler, seed), |_| {})?;
                    mse += rmse(&img, &reference).powi(2);
                }
                Ok(((mse / seeds as f64).sqrt(), t.elapsed() / seeds))
            };
            let (independent, ti) = error(Sampler::Independent)?;
            let (sobol, ts) = error(Sampler::Sobol)?;
            println!(
                "| | {spp} | {independent:.4} | {sobol:.4} | {:.2} | {ti:.1?} / {ts:.1?} |",
                sobol / independent
            );
        }
    }
    Ok(())
}
