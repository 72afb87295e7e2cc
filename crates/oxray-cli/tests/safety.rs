//! The `oxray` tool never loses a user's file and survives hostile inputs: default output
//! names, outputs that are inputs, atomic writes (a render killed while it writes), closed
//! pipes and full disks, memory limits, invalid rays.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

fn oxray() -> Command {
    Command::new(env!("CARGO_BIN_EXE_oxray"))
}

fn run(args: &[&str], cwd: Option<&Path>) -> Output {
    let mut c = oxray();
    c.args(args);
    if let Some(d) = cwd {
        c.current_dir(d);
    }
    c.output().unwrap()
}

/// A fresh directory for one test.
fn dir(test: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("oxray-safety-{}-{test}", std::process::id()));
    std::fs::remove_dir_all(&d).ok();
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn assert_one_error(out: &Output, needle: &str) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "not one line: {err}");
    assert!(lines[0].starts_with("error: "), "{err}");
    assert!(lines[0].contains(needle), "{err} lacks {needle:?}");
}

fn png_bytes(w: u32, h: u32, rgba: [u8; 4]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, w, h);
    enc.set_color(png::ColorType::Rgba);
    enc.set_depth(png::BitDepth::Eight);
    let data: Vec<u8> = (0..w * h).flat_map(|_| rgba).collect();
    let mut w = enc.write_header().unwrap();
    w.write_image_data(&data).unwrap();
    w.finish().unwrap();
    out
}

/// `Model.obj` with `Model.mtl` whose diffuse texture is `Model.png` (the CesiumMilkTruck
/// case: a texture named like the model).
fn textured_model(d: &Path) -> (PathBuf, PathBuf) {
    let texture = d.join("Model.png");
    std::fs::write(&texture, png_bytes(2, 2, [200, 30, 30, 255])).unwrap();
    std::fs::write(
        d.join("Model.mtl"),
        "newmtl paint\nKd 1 1 1\nmap_Kd Model.png\n",
    )
    .unwrap();
    let obj = d.join("Model.obj");
    std::fs::write(
        &obj,
        "mtllib Model.mtl\nv -1 -1 0\nv 1 -1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl paint\nf 1/1 2/2 3/3\n",
    )
    .unwrap();
    (obj, texture)
}

const SMALL: [&str; 6] = ["--size", "16x16", "--spp", "1", "--quiet", "--env=0.5"];

#[test]
fn the_default_output_never_replaces_the_scene_texture_nor_a_foreign_file() {
    let d = dir("default");
    let (_, texture) = textured_model(&d);
    let before = std::fs::read(&texture).unwrap();
    let args: Vec<&str> = ["render", "Model.obj"]
        .iter()
        .chain(&SMALL)
        .copied()
        .collect();
    let out = run(&args, Some(&d));
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        std::fs::read(&texture).unwrap(),
        before,
        "the texture was overwritten"
    );
    let written = d.join("Model.oxray.png");
    assert!(written.exists());
    // Rendering again replaces oxray's own image.
    let out = run(&args, Some(&d));
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // A file of that name that oxray did not write is left alone.
    std::fs::write(&written, png_bytes(1, 1, [1, 2, 3, 255])).unwrap();
    let mine = std::fs::read(&written).unwrap();
    assert_one_error(&run(&args, Some(&d)), "was not written by oxray");
    assert_eq!(std::fs::read(&written).unwrap(), mine);
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn an_output_that_the_render_reads_is_refused_before_any_work() {
    let d = dir("resource");
    let (obj, texture) = textured_model(&d);
    let before = std::fs::read(&texture).unwrap();
    // -o names the scene's texture, through another path.
    let other = d.join(".").join("Model.png");
    let mut args = vec!["render", s(&obj), "-o", s(&other)];
    args.extend(SMALL);
    assert_one_error(&run(&args, None), "is read by the scene");
    assert_eq!(std::fs::read(&texture).unwrap(), before);
    // -o names the environment map.
    let env = d.join("sky.exr");
    std::fs::write(&env, b"not really an exr").unwrap();
    let out = run(
        &[
            "render",
            s(&obj),
            "-o",
            s(&env),
            "--env",
            s(&env),
            "--quiet",
        ],
        None,
    );
    assert_one_error(&out, "is also an input");
    assert_eq!(std::fs::read(&env).unwrap(), b"not really an exr");
    // A missing folder is reported before the render (which would take minutes here).
    let t = Instant::now();
    let missing = d.join("no/such/folder/out.png");
    let out = run(
        &[
            "render",
            s(&obj),
            "-o",
            s(&missing),
            "--size",
            "4096x4096",
            "--quiet",
        ],
        None,
    );
    assert_one_error(&out, "does not exist");
    assert!(t.elapsed() < Duration::from_secs(10), "{:?}", t.elapsed());
    std::fs::remove_dir_all(&d).ok();
}

fn ray_bytes(rays: &[[f32; 8]]) -> Vec<u8> {
    rays.iter()
        .flatten()
        .flat_map(|x| x.to_le_bytes())
        .collect()
}

#[test]
fn raycast_refuses_to_write_over_its_mesh_or_its_rays() {
    let d = dir("raycast-out");
    let mesh = d.join("tri.obj");
    std::fs::write(&mesh, "v -1 -1 0\nv 1 -1 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let rays = d.join("rays.bin");
    let bytes = ray_bytes(&[[0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0, f32::INFINITY]]);
    std::fs::write(&rays, &bytes).unwrap();
    let mesh_text = std::fs::read(&mesh).unwrap();
    for out in [&rays, &mesh] {
        let o = run(
            &["raycast", s(&mesh), "--rays", s(&rays), "--out", s(out)],
            None,
        );
        assert_one_error(&o, "is also an input");
    }
    assert_eq!(std::fs::read(&rays).unwrap(), bytes);
    assert_eq!(std::fs::read(&mesh).unwrap(), mesh_text);
    let o = run(
        &[
            "raycast",
            s(&mesh),
            "--rays",
            s(&rays),
            "--out",
            s(&d.join("none/hits.bin")),
        ],
        None,
    );
    assert_one_error(&o, "does not exist");
    std::fs::remove_dir_all(&d).ok();
}

/// A render killed while it writes its image leaves the previous image intact: outputs are
/// written to a temporary file and renamed into place.
#[test]
fn a_render_killed_while_writing_keeps_the_previous_image() {
    let d = dir("killed");
    let mesh = d.join("tri.obj");
    std::fs::write(&mesh, "v -1 -1 0\nv 1 -1 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let out = d.join("out.exr");
    let previous = b"the previous image".to_vec();
    let mut caught = false;
    for size in ["1024x1024", "2048x2048", "4096x4096"] {
        std::fs::write(&out, &previous).unwrap();
        let mut child = oxray()
            .args([
                "render",
                s(&mesh),
                "-o",
                s(&out),
                "--size",
                size,
                "--spp",
                "1",
            ])
            .args(["--env", "0.5", "--quiet", "--threads", "1"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        // Kill it as soon as its writing shows: a temporary file, or (if it wrote in place)
        // the output changing.
        loop {
            let writing = std::fs::read_dir(&d).unwrap().any(|e| {
                e.unwrap()
                    .file_name()
                    .to_string_lossy()
                    .ends_with(".oxray-tmp")
            }) || std::fs::metadata(&out).map(|m| m.len()).ok()
                != Some(previous.len() as u64);
            if writing {
                child.kill().unwrap();
                child.wait().unwrap();
                caught = true;
                break;
            }
            if child.try_wait().unwrap().is_some() {
                break;
            }
            std::thread::sleep(Duration::from_micros(200));
        }
        if caught {
            break;
        }
    }
    assert!(
        caught,
        "the render finished before it could be killed while writing"
    );
    assert_eq!(
        std::fs::read(&out).unwrap(),
        previous,
        "the previous image was lost"
    );
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn a_closed_pipe_ends_quietly_and_a_full_disk_is_an_error() {
    let d = dir("pipe");
    let mesh = d.join("tri.obj");
    std::fs::write(&mesh, "v -1 -1 0\nv 1 -1 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    // `oxray info f | head -0`: the reader is gone before oxray writes.
    let mut child = oxray()
        .args(["info", s(&mesh)])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{:?}: {err}", out.status);
    assert!(err.is_empty(), "{err}");
    // Standard output on a full device.
    if let Ok(full) = std::fs::OpenOptions::new().write(true).open("/dev/full") {
        let out = oxray()
            .args(["info", s(&mesh)])
            .stdout(full)
            .output()
            .unwrap();
        assert_one_error(&out, "cannot write to standard output");
    }
    std::fs::remove_dir_all(&d).ok();
}
