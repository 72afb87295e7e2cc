//! `--backend cpu|cuda` of `oxray raycast` and `oxray bench`, through the built binary.
//!
//! Where CUDA is unavailable (CI), `--backend cuda` must fail with exactly one `error:` line
//! that names CUDA. Where a GPU is present, the CUDA results must equal the CPU backend's byte
//! for byte. `OXRAY_REQUIRE_GPU=1` turns a missing GPU into a failure (for runs on a GPU
//! machine), and `OXRAY_BIN` runs another `oxray` binary than the one Cargo built (for a test
//! binary copied to such a machine).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn oxray() -> Command {
    Command::new(
        std::env::var_os("OXRAY_BIN").unwrap_or_else(|| env!("CARGO_BIN_EXE_oxray").into()),
    )
}

fn tmp(name: &str) -> PathBuf {
    let p = std::env::temp_dir()
        .join(format!("oxray-backend-test-{}", std::process::id()))
        .join(name);
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    p
}

fn s(p: &Path) -> String {
    p.to_str().unwrap().to_string()
}

/// Whether this machine can run the CUDA backend, decided as the binary decides it.
fn gpu_available() -> bool {
    match oxray::Device::cuda(0) {
        Ok(device) => {
            println!("GPU: {}", device.describe());
            true
        }
        Err(e) => {
            assert!(
                std::env::var_os("OXRAY_REQUIRE_GPU").is_none(),
                "OXRAY_REQUIRE_GPU is set but CUDA is unavailable: {e}"
            );
            println!("no GPU ({e}): checking that --backend cuda fails cleanly");
            false
        }
    }
}

/// A bumpy 24 x 24 height field over [-1, 1]^2 (1,152 triangles), as OBJ.
fn heightfield_obj(test: &str) -> PathBuf {
    let n = 24;
    let mut text = String::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (
                -1.0 + 2.0 * i as f32 / n as f32,
                -1.0 + 2.0 * j as f32 / n as f32,
            );
            let z = 0.2 * (3.1 * x).sin() * (2.3 * y).cos();
            text += &format!("v {x} {y} {z}\n");
        }
    }
    let v = |i: usize, j: usize| j * (n + 1) + i + 1;
    for j in 0..n {
        for i in 0..n {
            text += &format!("f {} {} {}\n", v(i, j), v(i + 1, j), v(i + 1, j + 1));
            text += &format!("f {} {} {}\n", v(i, j), v(i + 1, j + 1), v(i, j + 1));
        }
    }
    let p = tmp(&format!("{test}/heightfield.obj"));
    std::fs::write(&p, text).unwrap();
    p
}

/// 4,096 slanted rays down onto the height field from irrational-ish offsets (so that none
/// meets a shared edge exactly), some of which miss it, and some with a short `tmax`.
fn rays_file(test: &str) -> PathBuf {
    let mut bytes = Vec::new();
    for k in 0..4096u32 {
        let (i, j) = ((k % 64) as f32, (k / 64) as f32);
        let o = [
            -1.3 + 2.6 * (i + 0.3271) / 64.0,
            -1.3 + 2.6 * (j + 0.5772) / 64.0,
            2.0,
        ];
        let d = [0.11, -0.07, -1.0];
        let tmax = if k % 7 == 3 { 1.9 } else { f32::INFINITY };
        for x in [o[0], o[1], o[2], 0.0, d[0], d[1], d[2], tmax] {
            bytes.extend_from_slice(&x.to_le_bytes());
        }
    }
    let p = tmp(&format!("{test}-rays.bin"));
    std::fs::write(&p, bytes).unwrap();
    p
}

fn raycast(backend: &str, mesh: &Path, rays: &Path, out: &Path, occ: bool) -> Output {
    let mut args = vec![
        "raycast".to_string(),
        s(mesh),
        "--rays".into(),
        s(rays),
        "--out".into(),
        s(out),
        "--backend".into(),
        backend.into(),
    ];
    if occ {
        args.push("--occlusion".into());
    }
    oxray().args(&args).output().unwrap()
}

/// A failure with exactly one `error:` line on stderr, naming CUDA, and no panic.
fn assert_clean_cuda_failure(out: &Output, what: &str) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{what}: {err}");
    assert!(err.starts_with("error: "), "{what}: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{what}: {err}");
    assert!(err.contains("CUDA"), "{what}: {err}");
    assert!(!err.contains("panicked"), "{what}: {err}");
}

#[test]
fn raycast_cuda_matches_the_cpu_or_fails_with_one_error_line() {
    let gpu = gpu_available();
    let (mesh, rays) = (heightfield_obj("raycast"), rays_file("raycast"));
    for occ in [false, true] {
        let cpu_out = tmp(&format!("cpu-{occ}.bin"));
        let cuda_out = tmp(&format!("cuda-{occ}.bin"));
        let cpu = raycast("cpu", &mesh, &rays, &cpu_out, occ);
        assert!(
            cpu.status.success(),
            "{}",
            String::from_utf8_lossy(&cpu.stderr)
        );
        let cpu_bytes = std::fs::read(&cpu_out).unwrap();
        assert_eq!(cpu_bytes.len(), 4096 * if occ { 4 } else { 16 });
        let cuda = raycast("cuda", &mesh, &rays, &cuda_out, occ);
        if gpu {
            let text = String::from_utf8_lossy(&cuda.stdout);
            assert!(
                cuda.status.success(),
                "{}",
                String::from_utf8_lossy(&cuda.stderr)
            );
            assert!(text.contains("Mrays/s traced"), "{text}");
            assert!(text.contains("Mrays/s with transfers"), "{text}");
            // Same counts on the summary line, and the same bytes in the file.
            let count = |o: &Output| {
                String::from_utf8_lossy(&o.stdout)
                    .split(" (")
                    .next()
                    .unwrap_or_default()
                    .to_string()
            };
            assert_eq!(count(&cpu), count(&cuda));
            let cuda_bytes = std::fs::read(&cuda_out).unwrap();
            assert!(cuda_bytes == cpu_bytes, "occlusion {occ}: files differ");
        } else {
            assert_clean_cuda_failure(&cuda, &format!("raycast --occlusion {occ}"));
            assert!(!cuda_out.exists(), "nothing is written on failure");
        }
    }
    // The scene is not trivial: some rays hit, some miss.
    let hits = std::fs::read(tmp("cpu-false.bin")).unwrap();
    let prims: Vec<u32> = hits
        .chunks_exact(16)
        .map(|c| u32::from_le_bytes([c[4], c[5], c[6], c[7]]))
        .collect();
    let misses = prims.iter().filter(|&&p| p == u32::MAX).count();
    assert!(misses > 100 && misses < 3000, "{misses} misses");
}

#[test]
fn bench_cuda_compares_with_the_cpu_or_fails_with_one_error_line() {
    let gpu = gpu_available();
    let mesh = heightfield_obj("bench");
    let out = oxray()
        .args([
            "bench",
            &s(&mesh),
            "--side",
            "32",
            "--runs",
            "1",
            "--backend",
            "cuda",
        ])
        .output()
        .unwrap();
    if gpu {
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(text.contains("| device traced Mrays/s |"), "{text}");
        let rows: Vec<&str> = text
            .lines()
            .filter(|l| {
                // The rays table's rows (the structure-life table has one for the mesh too).
                l.starts_with("| heightfield |")
                    && (l.contains("| closest |") || l.contains("| any |"))
            })
            .collect();
        assert_eq!(rows.len(), 6, "{text}");
        for (row, (set, query)) in rows.iter().zip([
            ("coherent", "closest"),
            ("coherent", "any"),
            ("incoherent", "closest"),
            ("incoherent", "any"),
            ("shadow", "closest"),
            ("shadow", "any"),
        ]) {
            assert!(row.contains(&format!("| {set} | {query} |")), "{row}");
            assert!(row.ends_with("| 100.0000% |"), "{row}");
        }
    } else {
        assert_clean_cuda_failure(&out, "bench");
        assert!(out.stdout.is_empty(), "nothing is printed before the error");
    }
}

#[test]
fn bench_instances_run_on_the_device_or_fail_with_one_error_line() {
    let gpu = gpu_available();
    let out = oxray()
        .args([
            "bench",
            &s(&heightfield_obj("instances")),
            "--side",
            "8",
            "--runs",
            "1",
            "--instances",
            "4",
            "--backend",
            "cuda",
        ])
        .output()
        .unwrap();
    if gpu {
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(text.contains("instances traced on NVIDIA"), "{text}");
        assert!(text.contains("| instanced mesh |"), "{text}");
    } else {
        assert_clean_cuda_failure(&out, "bench --instances");
        assert!(String::from_utf8_lossy(&out.stderr).contains("--backend cpu"));
    }
}

#[test]
fn bench_simulation_times_the_queries_on_the_cpu_and_the_device() {
    let gpu = gpu_available();
    let mesh = heightfield_obj("simulation");
    let run = |backend: &str| {
        oxray()
            .args([
                "bench",
                &s(&mesh),
                "--side",
                "16",
                "--runs",
                "1",
                "--simulation",
                "--backend",
                backend,
            ])
            .output()
            .unwrap()
    };
    let rows = |out: &std::process::Output| -> Vec<String> {
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .filter(|l| l.starts_with("| heightfield |"))
            .map(str::to_string)
            .collect()
    };
    let cpu = run("cpu");
    assert!(
        cpu.status.success(),
        "{}",
        String::from_utf8_lossy(&cpu.stderr)
    );
    let cpu_rows = rows(&cpu);
    assert_eq!(cpu_rows.len(), 4, "{cpu_rows:?}");
    for (row, query) in
        cpu_rows
            .iter()
            .zip(["closest point", "signed distance", "all hits", "hit counts"])
    {
        assert!(row.contains(query) && row.contains("| 256 |"), "{row}");
    }
    let out = run("cuda");
    if gpu {
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let rows = rows(&out);
        assert_eq!(rows.len(), 4, "{rows:?}");
        for row in &rows {
            // The signs of points on the surface may differ (none of these is on it).
            assert!(row.ends_with("| 100.00 % |"), "{row}");
        }
    } else {
        assert_clean_cuda_failure(&out, "bench --simulation");
    }
}

/// Three stacked squares over [-1, 1]^2 at z = 0, 0.5 and 1, as OBJ (6 triangles): a ray going
/// down crosses three.
fn stacked_obj(test: &str) -> PathBuf {
    let mut text = String::new();
    for z in [0.0f32, 0.5, 1.0] {
        for (x, y) in [(-1.0f32, -1.0f32), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
            text += &format!("v {x} {y} {z}\n");
        }
    }
    for k in 0..3 {
        let b = 4 * k + 1;
        text += &format!("f {} {} {}\nf {} {} {}\n", b, b + 1, b + 2, b, b + 2, b + 3);
    }
    let p = tmp(&format!("{test}-stacked.obj"));
    std::fs::write(&p, text).unwrap();
    p
}

fn u32s(bytes: &[u8]) -> Vec<u32> {
    bytes
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

#[test]
fn raycast_counts_and_lists_every_crossing_on_every_device() {
    let gpu = gpu_available();
    let (mesh, rays) = (stacked_obj("lists"), rays_file("lists"));
    let run = |backend: &str, flag: &[&str], out: &Path| {
        oxray()
            .args([
                "raycast",
                &s(&mesh),
                "--rays",
                &s(&rays),
                "--out",
                &s(out),
                "--backend",
                backend,
            ])
            .args(flag)
            .output()
            .unwrap()
    };
    let mut results = Vec::new();
    for backend in ["cpu", "cuda"] {
        let (counts, lists, closest) = (
            tmp(&format!("{backend}-counts.bin")),
            tmp(&format!("{backend}-lists.bin")),
            tmp(&format!("{backend}-closest.bin")),
        );
        let outs = [
            run(backend, &["--count"], &counts),
            run(backend, &["--all-hits", "2"], &lists),
            run(backend, &[], &closest),
        ];
        if backend == "cuda" && !gpu {
            for o in &outs {
                assert_clean_cuda_failure(o, "raycast --count / --all-hits");
            }
            continue;
        }
        for o in &outs {
            assert!(
                o.status.success(),
                "{backend}: {}",
                String::from_utf8_lossy(&o.stderr)
            );
        }
        let counts = std::fs::read(&counts).unwrap();
        let lists = std::fs::read(&lists).unwrap();
        let closest = std::fs::read(&closest).unwrap();
        let n = closest.len() / 16;
        assert_eq!(
            (counts.len(), lists.len()),
            (4 * n, (8 + 32) * n),
            "{backend}"
        );
        let counts = u32s(&counts);
        let mut crossing_all = 0;
        for i in 0..n {
            let rec = u32s(&lists[40 * i..40 * i + 40]);
            let (listed, complete) = (rec[0] as usize, rec[1] == 1);
            let c = counts[i] as usize;
            assert_eq!(listed, c.min(2), "{backend}: ray {i}");
            assert_eq!(complete, c <= 2, "{backend}: ray {i}");
            if c == 3 {
                crossing_all += 1;
            }
            // The first listed hit is the closest hit; the listed ones go nearest first.
            let first_t = f32::from_bits(rec[2]);
            let closest_t = f32::from_le_bytes(closest[16 * i..16 * i + 4].try_into().unwrap());
            if listed > 0 {
                assert_eq!(first_t, closest_t, "{backend}: ray {i}");
            } else {
                assert_eq!(
                    (first_t, rec[3]),
                    (f32::INFINITY, u32::MAX),
                    "{backend}: ray {i}"
                );
            }
            if listed == 2 {
                assert!(f32::from_bits(rec[6]) > first_t, "{backend}: ray {i}");
            }
        }
        assert!(
            crossing_all > n / 4,
            "{backend}: {crossing_all} of {n} rays cross all three"
        );
        results.push((counts, lists));
    }
    if let [a, b] = &results[..] {
        assert_eq!(a, b, "the devices list the same hits");
    }
    // Bad sizes are refused before anything is written.
    let out = tmp("refused.bin");
    let o = run("cpu", &["--all-hits", "0"], &out);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--all-hits takes 1 to"));
    assert!(!out.exists());
    let o = run("cpu", &["--count", "--occlusion"], &out);
    assert_eq!(o.status.code(), Some(2), "the flags exclude each other");
}

#[test]
fn closest_points_are_the_same_on_every_device() {
    let gpu = gpu_available();
    let mesh = stacked_obj("closest");
    // A grid of points over and between the squares, and one that is not finite.
    let mut bytes = Vec::new();
    let mut points = Vec::new();
    for k in 0..400u32 {
        let p = [
            -1.5 + 3.0 * (k % 20) as f32 / 19.0,
            -1.5 + 3.0 * (k / 20) as f32 / 19.0,
            -0.3 + 1.6 * ((k * 7) % 11) as f32 / 10.0,
        ];
        points.push(p);
    }
    points.push([f32::NAN, 0.0, 0.0]);
    for p in &points {
        for x in p {
            bytes.extend_from_slice(&x.to_le_bytes());
        }
    }
    let points_path = tmp("closest-points.bin");
    std::fs::write(&points_path, &bytes).unwrap();
    let mut results = Vec::new();
    for backend in ["cpu", "cuda"] {
        let out = tmp(&format!("closest-{backend}.bin"));
        let o = oxray()
            .args([
                "closest",
                &s(&mesh),
                "--points",
                &s(&points_path),
                "--out",
                &s(&out),
            ])
            .args(["--backend", backend])
            .output()
            .unwrap();
        if backend == "cuda" && !gpu {
            assert_clean_cuda_failure(&o, "closest");
            continue;
        }
        assert!(
            o.status.success(),
            "{backend}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(String::from_utf8_lossy(&o.stdout).contains("401 points, 1 not finite"));
        let r = std::fs::read(&out).unwrap();
        assert_eq!(r.len(), 20 * points.len());
        let f = |k: usize| f32::from_le_bytes(r[4 * k..4 * k + 4].try_into().unwrap());
        for (i, p) in points[..400].iter().enumerate() {
            // The nearest square: the nearest of z = 0, 0.5, 1, and the distance to its edge
            // outside [-1, 1]^2.
            let dz = [0.0f32, 0.5, 1.0]
                .iter()
                .map(|z| (p[2] - z).abs())
                .fold(f32::INFINITY, f32::min);
            let dx = (p[0].abs() - 1.0).max(0.0);
            let dy = (p[1].abs() - 1.0).max(0.0);
            let want = (dx * dx + dy * dy + dz * dz).sqrt();
            assert!((f(5 * i) - want).abs() < 1e-5, "{backend}: point {i} {p:?}");
        }
        assert_eq!(f(5 * 400), f32::INFINITY);
        results.push(r);
    }
    if let [a, b] = &results[..] {
        assert_eq!(a, b, "the devices find the same points");
    }
}

#[test]
fn unknown_backends_are_rejected_by_the_argument_parser() {
    let (mesh, rays) = (heightfield_obj("bogus"), rays_file("bogus"));
    let out_path = tmp("bogus.bin");
    for args in [
        vec![
            "raycast".to_string(),
            s(&mesh),
            "--rays".into(),
            s(&rays),
            "--out".into(),
            s(&out_path),
            "--backend".into(),
            "bogus".into(),
        ],
        vec![
            "bench".to_string(),
            s(&mesh),
            "--backend".into(),
            "bogus".into(),
        ],
    ] {
        let out = oxray().args(&args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains("invalid value 'bogus'"), "{err}");
        assert!(err.contains("cpu") && err.contains("cuda"), "{err}");
    }
    assert!(!out_path.exists());
}

#[test]
fn the_cpu_backend_is_the_default_and_explicit_cpu_is_the_same() {
    let (mesh, rays) = (heightfield_obj("default"), rays_file("default"));
    let (a, b) = (tmp("default.bin"), tmp("explicit.bin"));
    let default = oxray()
        .args(["raycast", &s(&mesh), "--rays", &s(&rays), "--out", &s(&a)])
        .output()
        .unwrap();
    assert!(default.status.success());
    assert!(String::from_utf8_lossy(&default.stdout).contains("threads)"));
    assert!(raycast("cpu", &mesh, &rays, &b, false).status.success());
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
}
