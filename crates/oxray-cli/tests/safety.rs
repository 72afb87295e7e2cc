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

#[test]
fn raycast_refuses_to_write_over_a_gltf_buffer_it_read() {
    // The mesh is a glTF whose geometry is in separate buffer files: they are inputs too.
    let d = dir("raycast-gltf-out");
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../oxray-scene/tests/data");
    for f in [
        "meshopt_fallback.gltf",
        "meshopt_fallback.bin",
        "meshopt_fallback.fallback.bin",
    ] {
        std::fs::copy(data.join(f), d.join(f)).unwrap();
    }
    let (mesh, buffer) = (
        d.join("meshopt_fallback.gltf"),
        d.join("meshopt_fallback.bin"),
    );
    let rays = d.join("rays.bin");
    std::fs::write(
        &rays,
        ray_bytes(&[[0.0, 0.0, 5.0, 0.0, 0.0, 0.0, -1.0, f32::INFINITY]]),
    )
    .unwrap();
    let before = std::fs::read(&buffer).unwrap();
    let o = run(
        &["raycast", s(&mesh), "--rays", s(&rays), "--out", s(&buffer)],
        None,
    );
    assert_one_error(&o, "is also an input");
    assert_eq!(std::fs::read(&buffer).unwrap(), before);
    // Another name is fine.
    let o = run(
        &[
            "raycast",
            s(&mesh),
            "--rays",
            s(&rays),
            "--out",
            s(&d.join("hits.bin")),
        ],
        None,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
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

fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in bytes {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xedb8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

fn chunk(out: &mut Vec<u8>, ty: &[u8; 4], data: &[u8]) {
    out.extend((data.len() as u32).to_be_bytes());
    let mut body = ty.to_vec();
    body.extend_from_slice(data);
    out.extend_from_slice(&body);
    out.extend(crc32(&body).to_be_bytes());
}

/// A PNG that declares `w` x `h` (8-bit, `color` type) with the given extra chunks before a
/// small IDAT: a decompression bomb for large sizes.
fn crafted_png(w: u32, h: u32, color: u8, extra: &[(&[u8; 4], Vec<u8>)]) -> Vec<u8> {
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend(w.to_be_bytes());
    ihdr.extend(h.to_be_bytes());
    ihdr.extend([8, color, 0, 0, 0]);
    chunk(&mut out, b"IHDR", &ihdr);
    for (ty, data) in extra {
        chunk(&mut out, ty, data);
    }
    // zlib of a 1x1 row: filter 0, index 0 (stored block).
    chunk(
        &mut out,
        b"IDAT",
        &[
            0x78, 0x01, 0x01, 0x02, 0x00, 0xfd, 0xff, 0, 0, 0x00, 0x02, 0x00, 0x01,
        ],
    );
    chunk(&mut out, b"IEND", &[]);
    out
}

/// An OBJ triangle whose materials use the given texture files, one material each.
fn obj_with_textures(d: &Path, textures: &[&str]) -> PathBuf {
    let mut mtl = String::new();
    let mut obj =
        String::from("mtllib scene.mtl\nv -1 -1 0\nv 1 -1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n");
    for (i, t) in textures.iter().enumerate() {
        mtl += &format!("newmtl m{i}\nKd 1 1 1\nmap_Kd {t}\n");
        obj += &format!("usemtl m{i}\nf 1/1 2/2 3/3\n");
    }
    std::fs::write(d.join("scene.mtl"), mtl).unwrap();
    let p = d.join("scene.obj");
    std::fs::write(&p, obj).unwrap();
    p
}

#[test]
fn image_bombs_and_texture_budgets_are_errors_before_decoding() {
    let d = dir("bombs");
    std::fs::write(d.join("bomb.png"), crafted_png(16384, 16384, 6, &[])).unwrap();
    let scene = obj_with_textures(&d, &["bomb.png"]);
    let out = d.join("out.png");
    let t = Instant::now();
    let o = run(&["info", s(&scene)], None);
    // `info` on OBJ reads the geometry only; `render` loads the textures.
    assert!(o.status.success());
    let mut args = vec!["render", s(&scene), "-o", s(&out)];
    args.extend(SMALL);
    assert_one_error(&run(&args, None), "over the limit of 256 MiB per image");
    assert!(t.elapsed() < Duration::from_secs(10));
    // Several images that each fit but together do not (the limit lowered to keep it small).
    for i in 0..3 {
        std::fs::write(
            d.join(format!("t{i}.png")),
            png_bytes(512, 512, [9, 9, 9, 255]),
        )
        .unwrap();
    }
    let scene = obj_with_textures(&d, &["t0.png", "t1.png", "t2.png"]);
    let mut args = vec!["render", s(&scene), "-o", s(&out)];
    args.extend(SMALL);
    let o = oxray()
        .args(&args)
        .env("OXRAY_MAX_TEXTURES_MB", "2")
        .output()
        .unwrap();
    assert_one_error(&o, "OXRAY_MAX_TEXTURES_MB");
    let o = oxray()
        .args(&args)
        .env("OXRAY_MAX_TEXTURES_MB", "3")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = oxray()
        .args(&args)
        .env("OXRAY_MAX_TEXTURES_MB", "lots")
        .output()
        .unwrap();
    assert_one_error(&o, "OXRAY_MAX_TEXTURES_MB must be a whole number");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn a_palette_png_with_a_bad_palette_is_a_warning_not_a_panic() {
    let d = dir("palette");
    // Colour type 3 with a 4-byte PLTE (not a multiple of 3).
    let png = crafted_png(1, 1, 3, &[(b"PLTE", vec![255, 0, 0, 7])]);
    std::fs::write(d.join("pal.png"), png).unwrap();
    let scene = obj_with_textures(&d, &["pal.png"]);
    let out = d.join("out.png");
    let mut args = vec!["render", s(&scene), "-o", s(&out)];
    args.extend(SMALL);
    let o = run(&args, None);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(err.lines().all(|l| l.starts_with("warning: ")), "{err}");
    assert!(err.contains("pal.png"), "{err}");
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn devices_and_fifos_are_refused_without_reading() {
    let d = dir("devices");
    let gltf = d.join("zero.gltf");
    std::fs::write(
        &gltf,
        r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":4294967295,"uri":"/dev/zero"}]}"#,
    )
    .unwrap();
    let t = Instant::now();
    assert_one_error(&run(&["info", s(&gltf)], None), "not a regular file");
    let fifo = d.join("fifo.png");
    let made = Command::new("mkfifo").arg(&fifo).status();
    if made.is_ok_and(|s| s.success()) {
        let scene = obj_with_textures(&d, &["fifo.png"]);
        let out = d.join("out.png");
        let mut args = vec!["render", s(&scene), "-o", s(&out)];
        args.extend(SMALL);
        assert_one_error(&run(&args, None), "not a regular file");
        let rays = d.join("rays.fifo");
        Command::new("mkfifo").arg(&rays).status().unwrap();
        let o = run(
            &[
                "raycast",
                s(&scene),
                "--rays",
                s(&rays),
                "--out",
                s(&d.join("h.bin")),
            ],
            None,
        );
        assert_one_error(&o, "not a regular file");
    }
    assert!(t.elapsed() < Duration::from_secs(10));
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn ray_files_and_flattened_instances_are_bounded_before_allocating() {
    let d = dir("bounds");
    let mesh = d.join("tri.obj");
    std::fs::write(&mesh, "v -1 -1 0\nv 1 -1 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    // A 2 GiB ray file (sparse: nothing is written) is refused from its size.
    let rays = d.join("big.rays");
    std::fs::File::create(&rays)
        .unwrap()
        .set_len(2 << 30)
        .unwrap();
    let hits = d.join("hits.bin");
    let t = Instant::now();
    let o = run(
        &["raycast", s(&mesh), "--rays", s(&rays), "--out", s(&hits)],
        None,
    );
    assert_one_error(&o, "OXRAY_MAX_RAYS");
    assert!(t.elapsed() < Duration::from_secs(5), "{:?}", t.elapsed());
    std::fs::File::create(&rays).unwrap().set_len(33).unwrap();
    let o = run(
        &["raycast", s(&mesh), "--rays", s(&rays), "--out", s(&hits)],
        None,
    );
    assert_one_error(&o, "not a whole number of 32-byte rays");
    // A small glTF whose many instances flatten past the geometry limit.
    let nodes: Vec<String> = (0..30000).map(|_| r#"{"mesh":0}"#.to_string()).collect();
    let roots: Vec<String> = (0..30000).map(|i| i.to_string()).collect();
    let gltf = d.join("many.gltf");
    std::fs::write(
        &gltf,
        format!(
            r#"{{"asset":{{"version":"2.0"}},"scenes":[{{"nodes":[{}]}}],"nodes":[{}],"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],"accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3"}}],"bufferViews":[{{"buffer":0,"byteLength":36}}],"buffers":[{{"byteLength":36,"uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAA"}}]}}"#,
            roots.join(","),
            nodes.join(",")
        ),
    )
    .unwrap();
    std::fs::write(
        &rays,
        ray_bytes(&[[0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0, 1e30]]),
    )
    .unwrap();
    let args = ["raycast", s(&gltf), "--rays", s(&rays), "--out", s(&hits)];
    let o = oxray()
        .args(args)
        .env("OXRAY_MAX_GEOMETRY_MB", "1")
        .output()
        .unwrap();
    assert_one_error(&o, "30000 instances flatten to");
    let o = oxray().args(args).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn raycast_counts_invalid_rays_and_clamps_a_negative_tmin() {
    let d = dir("invalid-rays");
    let mesh = d.join("tri.obj");
    std::fs::write(&mesh, "v -1 -1 0\nv 1 -1 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let inf = f32::INFINITY;
    let nan = f32::NAN;
    let rays = d.join("rays.bin");
    std::fs::write(
        &rays,
        ray_bytes(&[
            // A plain hit at t = 5, with tmin = -1e30: clamped, still a hit.
            [0.0, 0.0, 5.0, -1e30, 0.0, 0.0, -1.0, inf],
            // NaN origin, zero direction, NaN tmax, tmin > tmax: not traced.
            [nan, 0.0, 5.0, 0.0, 0.0, 0.0, -1.0, inf],
            [0.0, 0.0, 5.0, 0.0, 0.0, 0.0, 0.0, inf],
            [0.0, 0.0, 5.0, 0.0, 0.0, 0.0, -1.0, nan],
            [0.0, 0.0, 5.0, 6.0, 0.0, 0.0, -1.0, 4.0],
            // A valid hit.
            [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0, inf],
        ]),
    )
    .unwrap();
    let hits = d.join("hits.bin");
    let o = run(
        &["raycast", s(&mesh), "--rays", s(&rays), "--out", s(&hits)],
        None,
    );
    let stdout = String::from_utf8_lossy(&o.stdout);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(stdout.starts_with("6 rays, 2 hits, 4 invalid"), "{stdout}");
    assert!(
        stderr.contains("4 invalid rays written as misses"),
        "{stderr}"
    );
    assert!(stderr.contains("1 rays with tmin < 0"), "{stderr}");
    let h = std::fs::read(&hits).unwrap();
    let t = |i: usize| f32::from_le_bytes(h[16 * i..16 * i + 4].try_into().unwrap());
    assert_eq!(t(0), 5.0);
    for i in 1..5 {
        assert_eq!(t(i), inf, "ray {i}");
    }
    assert_eq!(t(5), 1.0);
    std::fs::remove_dir_all(&d).ok();
}
