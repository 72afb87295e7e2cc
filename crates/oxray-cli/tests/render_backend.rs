//! `oxray render --backend`: the Rust programs (`cpu`, the default), the CUDA C++ programs on
//! the CPU (`cpu-cxx`) and on a GPU (`cuda`, an error without one).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The binary under test: `OXRAY_BIN`, or the one Cargo built (a test binary copied to a GPU
/// machine runs a copied `oxray`).
fn oxray(args: &[&str]) -> Output {
    Command::new(
        std::env::var_os("OXRAY_BIN").unwrap_or_else(|| env!("CARGO_BIN_EXE_oxray").into()),
    )
    .args(args)
    .output()
    .unwrap()
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("oxray-render-backend-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// Mean linear RGB of an EXR image.
fn mean_rgb(path: &Path) -> [f64; 3] {
    use exr::prelude::*;
    let img = read_first_rgba_layer_from_file(
        path,
        |res, _| vec![[0.0f32; 3]; res.width() * res.height()],
        |px: &mut Vec<[f32; 3]>, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            let w = (px.len() as f64).sqrt() as usize;
            px[pos.y() * w + pos.x()] = [r, g, b];
        },
    )
    .unwrap();
    let px = img.layer_data.channel_data.pixels;
    let mut m = [0.0f64; 3];
    for p in &px {
        for c in 0..3 {
            m[c] += p[c] as f64 / px.len() as f64;
        }
    }
    m
}

fn render(backend: &str, out: &Path) -> Output {
    oxray(&[
        "render",
        "--size",
        "32x32",
        "--spp",
        "16",
        "--quiet",
        "--backend",
        backend,
        "-o",
        out.to_str().unwrap(),
    ])
}

#[test]
fn cpu_cxx_renders_the_cornell_box_like_the_rust_programs() {
    let (rust, cxx) = (tmp("rust.exr"), tmp("cxx.exr"));
    let a = render("cpu", &rust);
    assert!(a.status.success(), "{}", String::from_utf8_lossy(&a.stderr));
    let b = render("cpu-cxx", &cxx);
    assert!(b.status.success(), "{}", String::from_utf8_lossy(&b.stderr));
    let said = String::from_utf8_lossy(&b.stdout);
    assert!(
        said.contains("with the CUDA C++ programs on the CPU"),
        "{said}"
    );
    assert!(!String::from_utf8_lossy(&a.stdout).contains("CUDA C++"));
    // The statistical comparison of the two versions is oxray-render's; here, the command
    // wires the right renderer: the means agree within a few percent.
    let (ma, mb) = (mean_rgb(&rust), mean_rgb(&cxx));
    for c in 0..3 {
        assert!(ma[c] > 0.0, "{ma:?}");
        assert!((ma[c] - mb[c]).abs() <= 0.05 * ma[c], "{ma:?} vs {mb:?}");
    }
}

#[test]
fn cuda_without_a_gpu_is_one_error_line_and_unknown_backends_are_refused() {
    let out = render("bogus", &tmp("bogus.png"));
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("cpu-cxx"), "{err}");
    if oxray::Device::cuda(0).is_ok() {
        let out = render("cuda", &tmp("cuda.exr"));
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        return;
    }
    let out = render("cuda", &tmp("cuda.png"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(
        lines[0].starts_with("error: --backend cuda:") && lines[0].contains("use --backend cpu"),
        "{err}"
    );
    assert!(!tmp("cuda.png").exists());
}
