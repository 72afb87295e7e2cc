//! Helpers that several of the renderer's test binaries include (`mod common;`).
#![allow(dead_code)] // each binary uses some of them

use oxray_render::Image;
use oxray_scene::Primitive;

/// A 2 x 2 quad facing +Z at the origin, with texture coordinates (v down the image), of
/// material `material`.
pub fn quad(material: u32) -> Primitive {
    Primitive {
        positions: vec![
            [-1.0, -1.0, 0.0],
            [1.0, -1.0, 0.0],
            [1.0, 1.0, 0.0],
            [-1.0, 1.0, 0.0],
        ],
        uvs: vec![[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        material,
        ..Default::default()
    }
}

/// The mean difference `a - b` over `pixels` (indices) of channel `c`, its standard error and
/// the mean of `a`: every pixel's difference is an independent draw of the two renders'
/// Monte-Carlo errors.
pub fn region(a: &Image, b: &Image, pixels: &[usize], c: usize) -> (f64, f64, f64) {
    let n = pixels.len() as f64;
    let d: Vec<f64> = pixels
        .iter()
        .map(|&i| a.pixels[i][c] as f64 - b.pixels[i][c] as f64)
        .collect();
    let mean = d.iter().sum::<f64>() / n;
    let var = d.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (n - 1.0);
    let reference = pixels.iter().map(|&i| a.pixels[i][c] as f64).sum::<f64>() / n;
    (mean, (var / n).sqrt(), reference)
}
