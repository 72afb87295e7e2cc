//! End-to-end tests of `oxray raycast` and `oxray info` through the built binary.

use std::path::PathBuf;
use std::process::Command;

fn oxray() -> Command {
    Command::new(env!("CARGO_BIN_EXE_oxray"))
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("oxray-cli-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// A quad and a triangle behind it, as OBJ; the quad is a polygon, fan-triangulated.
fn scene_obj() -> PathBuf {
    // Written once per process: tests share it and run in parallel.
    static DONE: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    DONE.get_or_init(scene_obj_file).clone()
}

fn scene_obj_file() -> PathBuf {
    let p = tmp("scene.obj");
    std::fs::write(
        &p,
        "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nv -1 -1 2\nv 1 -1 2\nv 0 1 2\nf 1 2 3 4\nf 5 6 7\n",
    )
    .unwrap();
    p
}

fn rays_file(name: &str, rays: &[[f32; 8]]) -> PathBuf {
    let p = tmp(name);
    let bytes: Vec<u8> = rays
        .iter()
        .flatten()
        .flat_map(|x| x.to_le_bytes())
        .collect();
    std::fs::write(&p, bytes).unwrap();
    p
}

fn words(bytes: &[u8]) -> Vec<u32> {
    bytes
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

#[test]
fn raycast_writes_hits_in_file_order_and_agrees_with_the_library() {
    let mesh = scene_obj();
    let inf = f32::INFINITY;
    let rays = [
        // Hits the quad's second fan triangle (file triangle 1) at t = 5.
        [-0.5, 0.5, -5.0, 0.0, 0.0, 0.0, 1.0, inf],
        // Starts past the quad (tmin = 5.5) and hits the triangle behind (file triangle 2) at 7.
        [0.0, 0.0, -5.0, 5.5, 0.0, 0.0, 1.0, inf],
        // Misses everything.
        [5.0, 5.0, -5.0, 0.0, 0.0, 0.0, 1.0, inf],
    ];
    let rays_path = rays_file("rays.bin", &rays);
    let out = tmp("hits.bin");
    let status = oxray()
        .args([
            "raycast",
            mesh.to_str().unwrap(),
            "--rays",
            rays_path.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .status()
        .unwrap();
    assert!(status.success());
    let w = words(&std::fs::read(&out).unwrap());
    assert_eq!(w.len(), 3 * 4);
    let f = |i: usize| f32::from_bits(w[i]);
    assert_eq!((f(0), w[1]), (5.0, 1));
    assert_eq!((f(4), w[5]), (7.0, 2));
    assert_eq!((f(8), w[9]), (inf, 0xFFFF_FFFF));

    // The same through the library.
    let m = oxray_scene::mesh::Mesh::load(&mesh).unwrap();
    let gas = oxray_cli::bench::build_gas(&m, oxray::BuildFlags::PREFER_FAST_TRACE).unwrap();
    let parsed =
        oxray_cli::raycast::parse_rays(&std::fs::read(&rays_path).unwrap(), "rays").unwrap();
    for (k, r) in parsed.iter().enumerate() {
        let h = gas.intersect(r);
        assert_eq!(h.map_or(inf, |h| h.t), f(4 * k));
        assert_eq!(h.map_or(u32::MAX, |h| h.primitive_index), w[4 * k + 1]);
        assert_eq!(h.map_or(0.0, |h| h.u), f(4 * k + 2));
        assert_eq!(h.map_or(0.0, |h| h.v), f(4 * k + 3));
    }

    let occ = tmp("occ.bin");
    let status = oxray()
        .args([
            "raycast",
            mesh.to_str().unwrap(),
            "--rays",
            rays_path.to_str().unwrap(),
            "--out",
            occ.to_str().unwrap(),
            "--occlusion",
        ])
        .status()
        .unwrap();
    assert!(status.success());
    assert_eq!(words(&std::fs::read(&occ).unwrap()), [1, 1, 0]);
}

#[test]
fn bad_inputs_give_one_error_line_and_a_nonzero_exit() {
    let mesh = scene_obj();
    let s = |p: &PathBuf| p.to_str().unwrap().to_string();
    let short = tmp("short.bin");
    std::fs::write(&short, [0u8; 33]).unwrap();
    let ply = tmp("broken.ply");
    std::fs::write(
        &ply,
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1",
    )
    .unwrap();
    let cases: Vec<Vec<String>> = vec![
        vec![
            "raycast".into(),
            "/nonexistent/mesh.obj".into(),
            "--rays".into(),
            "x".into(),
            "--out".into(),
            "y".into(),
        ],
        vec![
            "raycast".into(),
            s(&mesh),
            "--rays".into(),
            "/nonexistent/rays.bin".into(),
            "--out".into(),
            "y".into(),
        ],
        vec![
            "raycast".into(),
            s(&mesh),
            "--rays".into(),
            s(&short),
            "--out".into(),
            s(&tmp("o.bin")),
        ],
        vec!["info".into(), s(&tmp("mesh.xyz"))],
        vec!["info".into(), s(&ply)],
    ];
    for args in cases {
        let out = oxray().args(&args).output().unwrap();
        assert!(!out.status.success(), "{args:?} succeeded");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.starts_with("error: "), "{args:?}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
}

#[test]
fn info_reports_counts_and_bvh_statistics() {
    let out = oxray()
        .args(["info", scene_obj().to_str().unwrap()])
        .output()
        .unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("triangles: 3 (3 active)"), "{text}");
    assert!(text.contains("instances: 1"), "{text}");
    assert!(text.contains("BVH: 1 nodes"), "{text}");
    assert!(text.contains("SAH cost"), "{text}");
}

/// `-h` gives one line per option, `--help` the details; completions are generated for the
/// shells clap knows.
#[test]
fn short_help_long_help_and_completions() {
    let run = |args: &[&str]| {
        let out = oxray().args(args).output().unwrap();
        assert!(
            out.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).unwrap()
    };
    for command in ["render", "raycast", "info", "bench"] {
        let short = run(&[command, "-h"]);
        let long = run(&[command, "--help"]);
        assert!(
            long.len() > short.len(),
            "{command}: --help adds the details"
        );
        for line in short.lines() {
            // An option's summary is one line of one sentence, defaults included.
            assert!(line.len() <= 140, "{command} -h: a long line: {line}");
        }
    }
    let short = run(&["render", "-h"]);
    assert!(!short.contains("Hill's ACES fit"));
    assert!(run(&["render", "--help"]).contains("Hill's ACES fit"));
    assert!(short.contains("-q, --quiet") && short.contains("-t, --threads"));
    assert!(run(&["raycast", "-h"]).contains(".gltf"));

    let bash = run(&["completions", "bash"]);
    assert!(bash.contains("--look-from") && bash.contains("raycast"));
    assert!(run(&["completions", "fish"]).contains("complete -c oxray"));
    let bad = oxray().args(["completions", "tcsh"]).output().unwrap();
    assert!(!bad.status.success());
}
