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
    // Written once per process: tests share it and run in parallel.
    static DONE: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    DONE.get_or_init(obj_scene_files).clone()
}

fn obj_scene_files() -> PathBuf {
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
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../oxray-scene/tests/data/hierarchy.gltf");
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

#[test]
fn raycast_on_a_gltf_scene_follows_the_flattened_file_order() {
    // Every ray aimed at a triangle's centroid (from outside, along its normal) must report that
    // triangle's index in the flattened order that `Mesh::load` documents.
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../oxray-scene/tests/data/hierarchy.gltf");
    let mesh = oxray_scene::mesh::Mesh::load(&path).unwrap();
    let mut rays = Vec::new();
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| glam::Vec3::from(mesh.positions[i as usize]));
        let n = (b - a).cross(c - a).normalize();
        let centroid = (a + b + c) / 3.0;
        let o = centroid + n * 0.5;
        rays.push([o.x, o.y, o.z, 0.0, -n.x, -n.y, -n.z, 1.0]);
    }
    let rays_path = tmp("gltf.rays");
    let bytes: Vec<u8> = rays
        .iter()
        .flatten()
        .flat_map(|x| x.to_le_bytes())
        .collect();
    std::fs::write(&rays_path, bytes).unwrap();
    let hits = tmp("gltf.hits");
    let out = oxray(&[
        "raycast",
        s(&path),
        "--rays",
        s(&rays_path),
        "--out",
        s(&hits),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let words: Vec<u32> = std::fs::read(&hits)
        .unwrap()
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    assert_eq!(words.len(), 4 * mesh.triangles.len());
    // The fixture's fan has overlapping triangles, so a ray may report another triangle that
    // also covers its target: the hit must then lie on that triangle too, and agree with the
    // library query on the flattened mesh.
    let gas = oxray_cli::bench::build_gas(&mesh, oxray::BuildFlags::PREFER_FAST_TRACE).unwrap();
    let mut own = 0;
    for (k, r) in rays.iter().enumerate() {
        assert!((f32::from_bits(words[4 * k]) - 0.5).abs() < 1e-4, "ray {k}");
        let prim = words[4 * k + 1];
        own += (prim == k as u32) as usize;
        let ray = oxray::Ray::new(
            glam::Vec3::new(r[0], r[1], r[2]),
            glam::Vec3::new(r[4], r[5], r[6]),
        );
        assert_eq!(gas.intersect(&ray).map(|h| h.primitive_index), Some(prim));
    }
    assert!(
        own + 1 >= mesh.triangles.len(),
        "{own} of {}",
        mesh.triangles.len()
    );
}

#[test]
fn bench_prints_one_row_per_mesh_with_the_three_ray_kinds() {
    let mesh = tmp("bench.obj");
    std::fs::write(
        &mesh,
        "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nv 0 0 1\nf 1 2 5\nf 2 3 5\nf 3 4 5\nf 4 1 5\nf 1 3 2\nf 1 4 3\n",
    )
    .unwrap();
    let out = oxray(&["bench", s(&mesh), "--side", "16", "--runs", "1"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let header = text.lines().find(|l| l.starts_with("| mesh")).unwrap();
    for kind in ["primary closest", "diffuse closest", "shadow"] {
        assert!(header.contains(kind), "{header}");
    }
    let row = text.lines().find(|l| l.starts_with("| bench |")).unwrap();
    assert_eq!(
        row.matches('|').count(),
        header.matches('|').count(),
        "{row}"
    );
    // Every throughput cell is a positive number.
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    for c in &cells[5..10] {
        assert!(c.parse::<f64>().unwrap() > 0.0, "{row}");
    }
}

#[test]
fn exposure_darkens_or_brightens_the_png() {
    let mean_byte = |ev: &str| {
        let png = tmp(&format!("exposure{ev}.png"));
        let out = oxray(&[
            "render",
            "-o",
            s(&png),
            "--size",
            "16x16",
            "--spp",
            "2",
            "--quiet",
            "--exposure",
            ev,
        ]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let mut reader = png::Decoder::new(std::fs::File::open(&png).unwrap())
            .read_info()
            .unwrap();
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).unwrap();
        let bytes = &buf[..info.buffer_size()];
        bytes.iter().map(|&b| b as f64).sum::<f64>() / bytes.len() as f64
    };
    let (dark, normal, bright) = (mean_byte("-2"), mean_byte("0"), mean_byte("2"));
    assert!(dark < normal && normal < bright, "{dark} {normal} {bright}");
    assert_one_error(
        &oxray(&["render", "-o", s(&tmp("e.png")), "--exposure", "1000"]),
        "--exposure",
    );
}

#[test]
fn tone_curves_and_pixel_filters_are_chosen_on_the_command_line() {
    let mean_byte = |args: &[&str]| {
        let png = tmp(&format!("look-{}.png", args.join("-")));
        let mut all = vec![
            "render",
            "-o",
            s(&png),
            "--size",
            "16x16",
            "--spp",
            "2",
            "--quiet",
        ];
        all.extend_from_slice(args);
        let out = oxray(&all);
        assert!(
            out.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let mut reader = png::Decoder::new(std::fs::File::open(&png).unwrap())
            .read_info()
            .unwrap();
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).unwrap();
        let bytes = &buf[..info.buffer_size()];
        bytes.iter().map(|&b| b as f64).sum::<f64>() / bytes.len() as f64
    };
    // The neutral curve keeps mid tones darker than ACES's boosted exposure and brighter than
    // nothing; the curves differ.
    let aces = mean_byte(&["--tonemap", "aces"]);
    let neutral = mean_byte(&["--tonemap", "neutral"]);
    let linear = mean_byte(&["--tonemap", "linear"]);
    assert!(
        aces != neutral && neutral != linear,
        "{aces} {neutral} {linear}"
    );
    for f in ["box", "gaussian", "blackman-harris"] {
        assert!(mean_byte(&["--filter", f]) > 0.0);
    }
    assert_one_error(
        &oxray(&["render", "-o", s(&tmp("t.png")), "--tonemap", "filmic"]),
        "--tonemap: unknown tone curve",
    );
    assert_one_error(
        &oxray(&["render", "-o", s(&tmp("f.png")), "--filter", "lanczos"]),
        "--filter: unknown pixel filter",
    );
}

#[test]
fn the_sampler_is_chosen_on_the_command_line() {
    let render = |args: &[&str]| {
        let png = tmp(&format!("sampler-{}.png", args.join("-")));
        let mut all = vec![
            "render",
            "-o",
            s(&png),
            "--size",
            "16x16",
            "--spp",
            "4",
            "--quiet",
        ];
        all.extend_from_slice(args);
        let out = oxray(&all);
        assert!(
            out.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        std::fs::read(&png).unwrap()
    };
    // Sobol is the default; independent numbers make another image.
    let sobol = render(&["--sampler", "sobol"]);
    assert_eq!(render(&[]), sobol);
    assert_ne!(render(&["--sampler", "independent"]), sobol);
    assert_one_error(
        &oxray(&["render", "-o", s(&tmp("s.png")), "--sampler", "halton"]),
        "--sampler: unknown sampler",
    );
}

/// `oxray render SCENE -o OUT` at 24x16 pixels and 2 spp, quietly, with `extra` options.
fn render_small(scene: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "render",
        s(scene),
        "-o",
        s(out),
        "--size",
        "24x16",
        "--spp",
        "2",
        "--quiet",
    ];
    args.extend_from_slice(extra);
    oxray(&args)
}

#[test]
fn seeds_and_aov_layers() {
    let scene = obj_scene();
    let render = |out: &Path, extra: &[&str]| render_small(&scene, out, extra);
    let bytes = |p: &Path| std::fs::read(p).unwrap();
    let (a, b, c) = (tmp("seed-a.png"), tmp("seed-b.png"), tmp("seed-c.png"));
    assert!(render(&a, &["--seed", "5"]).status.success());
    assert!(render(&b, &["--seed", "5"]).status.success());
    assert!(render(&c, &["--seed", "6"]).status.success());
    assert_eq!(bytes(&a), bytes(&b), "the same seed, the same image");
    assert_ne!(bytes(&a), bytes(&c), "another seed, another image");

    let exr = tmp("layers.exr");
    let out = render(&exr, &["--aov"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let read = exr::prelude::read_all_flat_layers_from_file(&exr).unwrap();
    let names: Vec<String> = read.layer_data[0]
        .channel_data
        .list
        .iter()
        .map(|c| c.name.to_string())
        .collect();
    for layer in ["R", "albedo.R", "normal.Z", "depth.Z", "samples.Y"] {
        assert!(
            names.iter().any(|n| n == layer),
            "{layer} missing from {names:?}"
        );
    }
    let png = tmp("layers.png");
    assert_one_error(
        &render(&png, &["--aov"]),
        "--aov writes layers of an OpenEXR file",
    );
    assert!(!png.exists());
}

/// `--time` ends the render at the end of a pass and writes the samples done; an interrupt
/// (SIGINT, as Ctrl-C sends) does the same and exits with status 130.
#[test]
fn a_time_budget_or_an_interrupt_writes_the_samples_done() {
    let scene = obj_scene();
    let budget = tmp("budget.png");
    // A render far too long to finish, stopped by the options in `extra`; what it said.
    let stopped = |extra: &[&str]| {
        let mut args = vec![
            "render",
            s(&scene),
            "-o",
            s(&budget),
            "--size",
            "16x16",
            "--spp",
            "65536",
        ];
        args.extend_from_slice(extra);
        let out = oxray(&args);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let said = stopped(&["--time", "0.5"]);
    assert!(said.contains("out of time after"), "{said}");
    assert!(said.contains("M samples/s"), "{said}");
    assert!(said.contains(" Mrays/s after "), "{said}");
    assert!(said.contains(" s of setup)"), "{said}");
    assert!(budget.exists());
    assert_one_error(
        &oxray(&["render", "-o", s(&budget), "--time", "0"]),
        "--time must be",
    );
    // Checkpoints: the image so far, written while the render goes on.
    let said = stopped(&["--time", "1", "--checkpoint", "0.1", "--quiet"]);
    assert!(said.contains("checkpoint images before"), "{said}");
    assert_one_error(
        &oxray(&["render", "-o", s(&budget), "--checkpoint", "nan"]),
        "--checkpoint must be",
    );

    let interrupted = tmp("interrupted.png");
    let child = Command::new(env!("CARGO_BIN_EXE_oxray"))
        .args([
            "render",
            s(&scene),
            "-o",
            s(&interrupted),
            "--size",
            "16x16",
            "--spp",
            "65536",
            "--quiet",
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Well after the handler is installed (the scene loads in milliseconds).
    std::thread::sleep(std::time::Duration::from_millis(1500));
    let kill = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    let out = child.wait_with_output().unwrap();
    let said = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        out.status.code(),
        Some(130),
        "{said} {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(said.contains("interrupted after"), "{said}");
    let decoder = png::Decoder::new(std::fs::File::open(&interrupted).unwrap());
    let reader = decoder.read_info().unwrap();
    assert_eq!((reader.info().width, reader.info().height), (16, 16));
}

/// `--look-from`, `--look-at`, `--up` and `--fov` aim the camera.
#[test]
fn the_camera_is_aimed_from_the_command_line() {
    let scene = obj_scene();
    let radiance = |extra: &[&str]| -> f32 {
        let out_path = tmp("aimed.exr");
        let mut args = vec![
            "render",
            s(&scene),
            "-o",
            s(&out_path),
            "--size",
            "16x16",
            "--spp",
            "2",
            "--quiet",
            "--env",
            "none",
        ];
        args.extend_from_slice(extra);
        let out = oxray(&args);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let img = exr::prelude::read_first_rgba_layer_from_file(
            &out_path,
            |res, _| vec![0f32; res.width() * res.height()],
            |px: &mut Vec<f32>, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                px[pos.y() * 16 + pos.x()] = r + g + b;
            },
        )
        .unwrap();
        img.layer_data.channel_data.pixels.iter().sum()
    };
    let towards = radiance(&["--look-from", "0,1,5", "--look-at", "0,0.5,-1"]);
    let away = radiance(&["--look-from", "0,1,5", "--look-at", "0,1,10"]);
    let narrow = radiance(&[
        "--look-from",
        "0,1,5",
        "--look-at",
        "0,0.5,-1",
        "--fov",
        "5",
    ]);
    assert!(towards > 0.0, "the lit scene is in view");
    assert_eq!(
        away, 0.0,
        "nothing is behind the camera and the environment is black"
    );
    assert_ne!(narrow, towards, "a narrower view sees less of the scene");
    // Only --fov or --up: the chosen camera, changed in that.
    assert!(radiance(&["--fov", "30"]) > 0.0);
    assert!(radiance(&["--look-at", "0,-2,-1", "--up", "0,0,-1"]) > 0.0);

    let out_path = tmp("refused.png");
    let o = s(&out_path);
    let refused = |args: &[&str], needle: &str| {
        let mut all = vec!["render", s(&scene), "-o", o];
        all.extend_from_slice(args);
        let out = oxray(&all);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} succeeded");
        assert!(err.contains(needle), "{args:?}: {err} lacks {needle:?}");
        assert!(!err.contains("panicked"));
    };
    refused(&["--look-from", "1,2"], "three finite numbers");
    refused(&["--look-at", "1,nan,2"], "three finite numbers");
    refused(
        &["--look-from", "1,1,1", "--look-at", "1,1,1"],
        "different points",
    );
    refused(
        &[
            "--look-from",
            "0,0,5",
            "--look-at",
            "0,0,0",
            "--up",
            "0,0,-1",
        ],
        "parallel",
    );
    refused(&["--fov", "0"], "--fov must be in");
    assert!(!out_path.exists());
}

/// Reads an 8-bit RGBA PNG: its width, height and bytes.
fn read_png(p: &Path) -> (u32, u32, Vec<u8>) {
    let decoder = png::Decoder::new(std::fs::File::open(p).unwrap());
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    assert_eq!(info.color_type, png::ColorType::Rgba);
    (info.width, info.height, buf)
}

/// `--crop X0,Y0,X1,Y1` writes the window of the full render, pixel for pixel; windows that
/// are empty, malformed or past the image are one error line, and nothing is written.
#[test]
fn crop_renders_a_window_of_the_image() {
    let scene = obj_scene();
    let render = |out: &Path, extra: &[&str]| render_small(&scene, out, extra);
    let (whole, part) = (tmp("crop-full.png"), tmp("crop-part.png"));
    assert!(render(&whole, &[]).status.success());
    let out = render(&part, &["--crop", "5,3,17,11"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(said.contains("12x8, pixels 5,3,17,11 of 24x16"), "{said}");
    let (fw, _, full) = read_png(&whole);
    let (w, h, crop) = read_png(&part);
    assert_eq!((w, h), (12, 8));
    for y in 0..h as usize {
        for x in 0..w as usize {
            let p = (y * w as usize + x) * 4;
            let q = ((y + 3) * fw as usize + x + 5) * 4;
            assert_eq!(crop[p..p + 4], full[q..q + 4], "pixel ({x}, {y})");
        }
    }
    let bad = tmp("crop-bad.png");
    for (window, needle) in [
        ("5,3,5,11", "has no pixels"),
        ("1,2,3", "expected four whole numbers"),
        ("0,0,25,16", "reaches past the 24x16 image"),
        ("0,10,4,17", "reaches past the 24x16 image"),
    ] {
        assert_one_error(&render(&bad, &["--crop", window]), needle);
        assert!(!bad.exists());
    }
}

/// A glTF scene whose one node slides a square from x = -1 to x = +1 in one second, lit by
/// the default environment, with its own camera.
fn sliding_gltf() -> PathBuf {
    // Written once per process: tests share it and run in parallel.
    static DONE: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    DONE.get_or_init(sliding_gltf_files).clone()
}

fn sliding_gltf_files() -> PathBuf {
    let mut bin: Vec<u8> = Vec::new();
    let square = [
        -0.5f32, -0.5, 0.0, 0.5, -0.5, 0.0, 0.5, 0.5, 0.0, -0.5, 0.5, 0.0,
    ];
    let keys = [0.0f32, 1.0, -1.0, 0.0, 0.0, 1.0, 0.0, 0.0];
    for x in square.iter().chain(&keys) {
        bin.extend(x.to_le_bytes());
    }
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend(i.to_le_bytes());
    }
    std::fs::write(tmp("slide.bin"), &bin).unwrap();
    let gltf = tmp("slide.gltf");
    std::fs::write(
        &gltf,
        r#"{"asset": {"version": "2.0"},
  "buffers": [{"uri": "slide.bin", "byteLength": 92}],
  "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 80},
                  {"buffer": 0, "byteOffset": 80, "byteLength": 12}],
  "accessors": [
    {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
     "min": [-0.5, -0.5, 0], "max": [0.5, 0.5, 0]},
    {"bufferView": 0, "byteOffset": 48, "componentType": 5126, "count": 2, "type": "SCALAR",
     "min": [0], "max": [1]},
    {"bufferView": 0, "byteOffset": 56, "componentType": 5126, "count": 2, "type": "VEC3"},
    {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"}],
  "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 3}]}],
  "cameras": [{"type": "perspective", "perspective": {"yfov": 0.8, "znear": 0.1}}],
  "nodes": [{"mesh": 0}, {"camera": 0, "translation": [0, 0, 4]}],
  "scenes": [{"nodes": [0, 1]}],
  "animations": [{"samplers": [{"input": 1, "output": 2}],
                  "channels": [{"sampler": 0, "target": {"node": 0, "path": "translation"}}]}]
}"#,
    )
    .unwrap();
    gltf
}

/// `--shutter OPEN,CLOSE` blurs what the glTF animation moves, with the Rust programs and the
/// CUDA C++ ones alike; a closed shutter poses the scene at its time; bad intervals and
/// missing animations are one error line each.
#[test]
fn shutter_renders_the_gltf_animation_as_motion_blur() {
    let scene = sliding_gltf();
    let render = |out: &Path, extra: &[&str]| render_small(&scene, out, extra);
    let (rest, blur, posed, blur_cxx) = (
        tmp("slide-rest.png"),
        tmp("slide-blur.png"),
        tmp("slide-posed.png"),
        tmp("slide-blur-cxx.png"),
    );
    for (out, extra) in [
        (&rest, &[][..]),
        (&blur, &["--shutter", "0,1"][..]),
        (&posed, &["--shutter", "0,0"][..]),
        (&blur_cxx, &["--shutter", "0,1", "--backend", "cpu-cxx"][..]),
    ] {
        let o = render(out, extra);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let (_, _, rest) = read_png(&rest);
    let (_, _, blur) = read_png(&blur);
    let (_, _, posed) = read_png(&posed);
    let (_, _, blur_cxx) = read_png(&blur_cxx);
    // At rest the square is in the middle; at t = 0 it is one unit to the left; blurred it
    // is smeared over both.
    assert_ne!(rest, posed);
    assert_ne!(rest, blur);
    assert_ne!(posed, blur);
    assert_ne!(rest, blur_cxx, "the C++ programs blur too");
    // The two path tracers draw their samples alike: the same blur up to rounding.
    let mean = |p: &[u8]| p.iter().map(|&v| v as f64).sum::<f64>() / p.len() as f64;
    assert!(
        (mean(&blur) - mean(&blur_cxx)).abs() < 2.0,
        "{} {}",
        mean(&blur),
        mean(&blur_cxx)
    );
    let bad = tmp("slide-bad.png");
    for (extra, needle) in [
        (&["--shutter", "1,0"][..], "CLOSE not before OPEN"),
        (&["--shutter", "0"][..], "expected OPEN,CLOSE"),
        (
            &["--shutter", "0,1", "--animation", "2"][..],
            "the scene has 1 animation",
        ),
    ] {
        assert_one_error(&render(&bad, extra), needle);
        assert!(!bad.exists());
    }
    // A scene without animation renders, with a warning that nothing moves.
    let obj = render_small(&obj_scene(), &tmp("still.png"), &["--shutter", "0,1"]);
    assert!(obj.status.success());
    assert!(String::from_utf8_lossy(&obj.stderr).contains("--shutter blurs nothing"));
}

/// `--denoise` writes the denoised image (PNG, or EXR with the noisy image as a layer beside
/// the AOVs with `--aov`); without Open Image Denoise it is one error line before any render,
/// and nothing is written. Skips (saying so) where OIDN is not installed
/// (`scripts/setup-oidn.sh`), unless `OXRAY_REQUIRE_OIDN=1`.
#[test]
fn denoise_writes_the_denoised_image() {
    let missing = tmp("denoise-missing.png");
    let out = Command::new(env!("CARGO_BIN_EXE_oxray"))
        .args(["render", "-o", s(&missing), "--size", "8x8", "--spp", "1"])
        .args(["--quiet", "--denoise"])
        .env(
            "OXRAY_OIDN_LIB",
            "/nonexistent/oxray/libOpenImageDenoise.so.2",
        )
        .output()
        .unwrap();
    assert_one_error(&out, "--denoise: cannot load Open Image Denoise");
    assert_one_error(&out, "scripts/setup-oidn.sh");
    assert!(!missing.exists());

    let png = tmp("denoised.png");
    let noisy_png = tmp("noisy.png");
    let args = ["--size", "32x32", "--spp", "2", "--quiet"];
    let out = oxray(&[&["render", "-o", s(&png), "--denoise"], &args[..]].concat());
    let err = String::from_utf8_lossy(&out.stderr);
    if !out.status.success()
        && err.contains("cannot load Open Image Denoise")
        && std::env::var("OXRAY_REQUIRE_OIDN").as_deref() != Ok("1")
    {
        eprintln!("skipped: {err}");
        return;
    }
    assert!(out.status.success(), "{err}");
    assert!(String::from_utf8_lossy(&out.stdout).contains("denoised on the"));
    assert!(
        oxray(&[&["render", "-o", s(&noisy_png)], &args[..]].concat())
            .status
            .success()
    );
    let (w, h, clean) = read_png(&png);
    let (_, _, noisy) = read_png(&noisy_png);
    assert_eq!((w, h), (32, 32));
    // Denoising smooths: neighbouring pixels differ less than in the noisy render.
    let roughness = |px: &[u8]| -> u64 {
        px.chunks(4)
            .zip(px.chunks(4).skip(1))
            .map(|(a, b)| (0..3).map(|c| a[c].abs_diff(b[c]) as u64).sum::<u64>())
            .sum()
    };
    assert!(
        roughness(&clean) < roughness(&noisy) * 3 / 4,
        "{} vs {}",
        roughness(&clean),
        roughness(&noisy)
    );

    let exr = tmp("denoised.exr");
    let out = oxray(&[&["render", "-o", s(&exr), "--denoise", "--aov"], &args[..]].concat());
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let read = exr::prelude::read_all_flat_layers_from_file(&exr).unwrap();
    let names: Vec<String> = read.layer_data[0]
        .channel_data
        .list
        .iter()
        .map(|c| c.name.to_string())
        .collect();
    for layer in [
        "R", "A", "albedo.R", "normal.Z", "noisy.R", "noisy.G", "noisy.B",
    ] {
        assert!(
            names.iter().any(|n| n == layer),
            "{layer} missing from {names:?}"
        );
    }
}
