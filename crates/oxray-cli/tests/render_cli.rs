//! `oxray render` through the built binary: scene files in, PNG and EXR out, and one clear error
//! line for every kind of bad input.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn oxray(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_oxray"))
        .args(args)
        .output()
        .unwrap()
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("oxray-render-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Fails unless the command failed with exactly one line on stderr, starting `error:` and
/// containing `needle`.
fn assert_one_error(out: &Output, needle: &str) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "succeeded: {err}");
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "not one line: {err}");
    assert!(lines[0].starts_with("error: "), "{err}");
    assert!(lines[0].contains(needle), "{err} lacks {needle:?}");
    assert!(!err.contains("panicked"));
}

/// A red triangle over a grey floor, as OBJ + MTL with an emissive material.
fn obj_scene() -> PathBuf {
    let obj = tmp("lit.obj");
    std::fs::write(
        tmp("lit.mtl"),
        "newmtl red\nKd 0.8 0.1 0.1\nnewmtl lamp\nKd 0 0 0\nKe 5 5 5\n",
    )
    .unwrap();
    std::fs::write(
        &obj,
        "mtllib lit.mtl\nv -1 0 -1\nv 1 0 -1\nv 0 1.5 -1\nv -3 -0.01 -3\nv 3 -0.01 -3\nv 3 -0.01 3\nv -3 -0.01 3\n\
         v -0.5 3 -0.5\nv 0.5 3 -0.5\nv 0.5 3 0.5\nv -0.5 3 0.5\n\
         o tri\nusemtl red\nf 1 2 3\no floor\nusemtl red\nf 4 7 6 5\no lamp\nusemtl lamp\nf 8 9 10 11\n",
    )
    .unwrap();
    obj
}

#[test]
fn renders_an_obj_scene_to_png_and_exr() {
    let scene = obj_scene();
    let png = tmp("lit.png");
    let out = oxray(&[
        "render",
        s(&scene),
        "-o",
        s(&png),
        "--size",
        "40x30",
        "--spp",
        "4",
        "--quiet",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let decoder = png::Decoder::new(std::fs::File::open(&png).unwrap());
    let reader = decoder.read_info().unwrap();
    assert_eq!((reader.info().width, reader.info().height), (40, 30));

    let exr = tmp("lit.exr");
    let out = oxray(&[
        "render",
        s(&scene),
        "-o",
        s(&exr),
        "--size",
        "40x30",
        "--spp",
        "4",
        "--quiet",
        "--env",
        "none",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let img = exr::prelude::read_first_rgba_layer_from_file(
        &exr,
        |res, _| (res.width(), vec![[0f32; 3]; res.width() * res.height()]),
        |(w, px): &mut (usize, Vec<[f32; 3]>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            px[pos.y() * *w + pos.x()] = [r, g, b];
        },
    )
    .unwrap();
    let px = &img.layer_data.channel_data.pixels.1;
    assert_eq!(px.len(), 40 * 30);
    // Linear radiance: the lamp light makes the red triangle redder than it is green, and
    // nothing is negative or NaN.
    assert!(px.iter().flatten().all(|c| c.is_finite() && *c >= 0.0));
    let red: f32 = px.iter().map(|p| p[0]).sum();
    let green: f32 = px.iter().map(|p| p[1]).sum();
    assert!(red > 1.5 * green && red > 0.0, "{red} {green}");
}

#[test]
fn the_cornell_box_is_the_default_scene() {
    let png = tmp("cornell.png");
    let out = oxray(&[
        "render",
        "-o",
        s(&png),
        "--size",
        "16x16",
        "--spp",
        "1",
        "--quiet",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("32 triangles"));
}

#[test]
fn bad_input_gives_one_error_line() {
    let png = tmp("bad.png");
    let missing = tmp("no-such-scene.gltf");
    assert_one_error(
        &oxray(&["render", s(&missing), "-o", s(&png)]),
        "no-such-scene.gltf",
    );
    let unknown = tmp("scene.xyz");
    std::fs::write(&unknown, "hello").unwrap();
    assert_one_error(&oxray(&["render", s(&unknown), "-o", s(&png)]), "unknown");
    let broken = tmp("broken.gltf");
    std::fs::write(
        &broken,
        "{ \"asset\": { \"version\": \"2.0\" }, \"meshes\": [ {",
    )
    .unwrap();
    assert_one_error(
        &oxray(&["render", s(&broken), "-o", s(&png)]),
        "broken.gltf",
    );
    assert_one_error(
        &oxray(&["render", "-o", s(&png), "--size", "0x10"]),
        "--size",
    );
    assert_one_error(
        &oxray(&["render", "-o", s(&png), "--size", "100000x100000"]),
        "--size",
    );
    assert_one_error(
        &oxray(&["render", "-o", s(&png), "--size", "16384x16384"]),
        "2^26 pixels",
    );
    assert_one_error(&oxray(&["render", "-o", s(&png), "--spp", "0"]), "--spp");
    assert_one_error(
        &oxray(&["render", "-o", s(&tmp("out.bmp"))]),
        "unknown image format",
    );
    assert_one_error(
        &oxray(&["render", "-o", s(&png), "--env", s(&tmp("nothing.hdr"))]),
        "nothing.hdr",
    );
    assert_one_error(
        &oxray(&[
            "render",
            "-o",
            s(&png),
            "--camera",
            "3",
            "--size",
            "8x8",
            "--spp",
            "1",
        ]),
        "camera 3",
    );
    let dir_out = tmp("a-directory.png");
    std::fs::create_dir_all(&dir_out).unwrap();
    assert_one_error(
        &oxray(&[
            "render",
            "-o",
            s(&dir_out),
            "--size",
            "8x8",
            "--spp",
            "1",
            "--quiet",
        ]),
        "cannot write",
    );
}

#[test]
fn gltf_scene_renders_with_warnings_for_missing_textures() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/gltf/smallpine/scene.gltf");
    if !path.exists() {
        eprintln!("skipping: {} is absent", path.display());
        return;
    }
    let png = tmp("pine.png");
    let out = oxray(&[
        "render",
        s(&path),
        "-o",
        s(&png),
        "--size",
        "24x24",
        "--spp",
        "1",
        "--quiet",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.lines()
            .any(|l| l.starts_with("warning:") && l.contains("normal")),
        "{err}"
    );
}

#[test]
fn info_on_a_gltf_scene_counts_instances_and_builds_an_ias() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/hierarchy.gltf");
    let out = oxray(&["info", s(&path)]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    // Four nodes place meshes; one mesh is placed twice (5 unique triangles, 6 instanced).
    for line in [
        "meshes: 3",
        "triangles: 5 unique, 6 instanced",
        "instances: 4",
        "cameras: 1",
        "IAS BVH: 1 nodes, 4 leaves",
    ] {
        assert!(text.contains(line), "{line:?} missing from:\n{text}");
    }
    assert!(text.contains("warning:") && text.contains("missing.png"));
}
