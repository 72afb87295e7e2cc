#!/usr/bin/env python3
"""Throughput of oxray's simulation queries (oxray-cpu/src/simulation) against Open3D's
RaycastingScene (Embree underneath) on the same mesh, points and rays:

    closest point   oxray Gas::closest_point_batch   vs  scene.compute_closest_points
    signed distance oxray Gas::signed_distance_batch vs  scene.compute_signed_distance
    all hits        oxray Gas::all_hits_batch        vs  scene.list_intersections
    hit counts      oxray Gas::count_hits_batch      vs  scene.count_intersections

    python3 scripts/bench_simulation_queries.py [--mesh stanford-bunny] [--points N]
                                                [--rays N] [--runs R] [--threads T]

Needs numpy and open3d (PyPI `open3d` or `open3d-cpu`) in the running Python; without
open3d only oxray is measured. The oxray side is a small Rust program written to a
temporary directory and built in release mode against this checkout's crates (oxray-cpu,
oxray-core, with the workspace's lock file), so the first run compiles for a few minutes.

The mesh is one of ../shared/data/meshes (OBJ), or an icosphere of 20 * 4^5 triangles if
it is missing. Points are uniform in the mesh's box grown by 10 %; rays start on a sphere
twice the box's radius and aim at uniform points of the box. Both sides get the same
threads (Open3D's RaycastingScene takes nthreads=; oxray a rayon pool of T threads).
Results are cross-checked: closest distances (max abs difference), inside/outside
agreement of the signed distances, and equal hit counts per ray (a ray crossing an edge
may differ: Embree's test is not watertight). Times are the best of R runs.
"""

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent

RUNNER = r"""
use glam::Vec3;
use oxray_core::Ray;
use oxray_cpu::{AllHits, Gas};
use std::time::Instant;

fn read(path: &std::path::Path) -> Vec<u8> {
    std::fs::read(path).unwrap()
}
fn f32s(b: &[u8]) -> Vec<f32> {
    b.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect()
}
fn u32s(b: &[u8]) -> Vec<u32> {
    b.chunks_exact(4).map(|c| u32::from_le_bytes(c.try_into().unwrap())).collect()
}
fn best<T>(runs: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut best = f64::INFINITY;
    let mut out = None;
    for _ in 0..runs {
        let t = Instant::now();
        let r = f();
        best = best.min(t.elapsed().as_secs_f64());
        out = Some(r);
    }
    (best, out.unwrap())
}
fn write(path: &std::path::Path, v: &[u8]) {
    std::fs::write(path, v).unwrap();
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let dir = std::path::Path::new(&args[1]);
    let runs: usize = args[2].parse().unwrap();
    let threads: usize = args[3].parse().unwrap();
    let max_hits: usize = args[4].parse().unwrap();
    rayon::ThreadPoolBuilder::new().num_threads(threads).build_global().unwrap();
    let mesh = read(&dir.join("mesh.bin"));
    let (nv, nt) = (u32s(&mesh[..4])[0] as usize, u32s(&mesh[4..8])[0] as usize);
    let v: Vec<[f32; 3]> = f32s(&mesh[8..8 + 12 * nv]).chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let t: Vec<[u32; 3]> = u32s(&mesh[8 + 12 * nv..8 + 12 * nv + 12 * nt]).chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let points: Vec<Vec3> = f32s(&read(&dir.join("points.bin"))).chunks_exact(3).map(|c| Vec3::new(c[0], c[1], c[2])).collect();
    let rays: Vec<Ray> = f32s(&read(&dir.join("rays.bin"))).chunks_exact(6)
        .map(|c| Ray::new(Vec3::new(c[0], c[1], c[2]), Vec3::new(c[3], c[4], c[5]))).collect();

    let (build, gas) = best(1, || Gas::from_mesh(&v, &t).unwrap());
    let (closest, cp) = best(runs, || {
        let mut out = vec![None; points.len()];
        gas.closest_point_batch(&points, &mut out).unwrap();
        out
    });
    let (signed, sd) = best(runs, || {
        let mut out = vec![0.0f32; points.len()];
        gas.signed_distance_batch(&points, &mut out).unwrap();
        out
    });
    let (all, hits) = best(runs, || {
        let mut out = AllHits::new();
        gas.all_hits_batch(&rays, max_hits, &mut out).unwrap();
        out
    });
    let (count, counts) = best(runs, || {
        let mut out = vec![0u32; rays.len()];
        gas.count_hits_batch(&rays, &mut out).unwrap();
        out
    });
    let d: Vec<u8> = cp.iter().flat_map(|c| c.unwrap().distance.to_le_bytes()).collect();
    write(&dir.join("oxray.closest"), &d);
    let s: Vec<u8> = sd.iter().flat_map(|x| x.to_le_bytes()).collect();
    write(&dir.join("oxray.signed"), &s);
    let c: Vec<u8> = counts.iter().flat_map(|x| x.to_le_bytes()).collect();
    write(&dir.join("oxray.counts"), &c);
    println!(
        "{{\"build\": {build}, \"closest_point\": {closest}, \"signed_distance\": {signed}, \"all_hits\": {all}, \"count_hits\": {count}, \"listed_hits\": {}}}",
        hits.all().len()
    );
}
"""


def load_obj(path):
    verts, faces = [], []
    for line in path.read_text(errors="replace").splitlines():
        p = line.split()
        if not p:
            continue
        if p[0] == "v":
            verts.append([float(x) for x in p[1:4]])
        elif p[0] == "f":
            idx = [int(x.split("/")[0]) for x in p[1:]]
            idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
            for k in range(1, len(idx) - 1):
                faces.append([idx[0], idx[k], idx[k + 1]])
    return np.array(verts, np.float32), np.array(faces, np.uint32)


def icosphere(subdivisions):
    t = (1 + 5 ** 0.5) / 2
    v = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
         [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]
    v = [list(np.array(p) / np.linalg.norm(p)) for p in v]
    f = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    for _ in range(subdivisions):
        cache, nf = {}, []

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = (np.array(v[a]) + np.array(v[b])) / 2
                v.append(list(m / np.linalg.norm(m)))
                cache[key] = len(v) - 1
            return cache[key]

        for a, b, c in f:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            nf += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        f = nf
    return np.array(v, np.float32), np.array(f, np.uint32)


def build_runner(work):
    crate = work / "runner"
    (crate / "src").mkdir(parents=True)
    (crate / "src" / "main.rs").write_text(RUNNER)
    # The workspace's versions: its glam requirement and its lock file.
    glam = re.search(r'^glam\s*=\s*\{\s*version\s*=\s*"([^"]+)"',
                     (REPO / "Cargo.toml").read_text(), re.M).group(1)
    crates = REPO / "crates"
    (crate / "Cargo.toml").write_text(
        "[package]\nname = \"bench-simulation-queries\"\nversion = \"0.0.0\"\nedition = \"2021\"\n"
        "[workspace]\n[dependencies]\n"
        f"oxray-cpu = {{ path = \"{crates / 'oxray-cpu'}\" }}\n"
        f"oxray-core = {{ path = \"{crates / 'oxray-core'}\" }}\n"
        f"glam = \"{glam}\"\nrayon = \"1\"\n")
    shutil.copy(REPO / "Cargo.lock", crate / "Cargo.lock")
    target = REPO / "target" / "bench-simulation-queries"
    subprocess.run(["cargo", "build", "--release", "--quiet"], cwd=crate, check=True,
                   env={**os.environ, "CARGO_TARGET_DIR": str(target)})
    return target / "release" / "bench-simulation-queries"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mesh", default="stanford-bunny")
    ap.add_argument("--points", type=int, default=200_000)
    ap.add_argument("--rays", type=int, default=200_000)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--threads", type=int, default=os.cpu_count())
    ap.add_argument("--max-hits", type=int, default=64)
    args = ap.parse_args()

    path = REPO.parent / "shared" / "data" / "meshes" / f"{args.mesh}.obj"
    if path.exists():
        v, f = load_obj(path)
        name = args.mesh
    else:
        v, f = icosphere(5)
        name = "icosphere(5)"
    rng = np.random.default_rng(19)
    lo, hi = v.min(0), v.max(0)
    c, ext = (lo + hi) / 2, (hi - lo) / 2
    points = (c + ext * 1.1 * rng.uniform(-1, 1, (args.points, 3))).astype(np.float32)
    radius = float(np.linalg.norm(ext))
    u = rng.normal(size=(args.rays, 3))
    origins = c + 2 * radius * u / np.linalg.norm(u, axis=1, keepdims=True)
    targets = c + ext * rng.uniform(-1, 1, (args.rays, 3))
    dirs = targets - origins
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    rays = np.hstack([origins, dirs]).astype(np.float32)
    print(f"mesh {name}: {len(v)} vertices, {len(f)} triangles; {args.points} points, "
          f"{args.rays} rays, {args.threads} threads, best of {args.runs}")

    work = Path(tempfile.mkdtemp(prefix="oxray-simq-"))
    try:
        with open(work / "mesh.bin", "wb") as out:
            out.write(np.array([len(v), len(f)], np.uint32).tobytes())
            out.write(v.tobytes())
            out.write(f.tobytes())
        (work / "points.bin").write_bytes(points.tobytes())
        (work / "rays.bin").write_bytes(rays.tobytes())
        exe = build_runner(work)
        res = subprocess.run([str(exe), str(work), str(args.runs), str(args.threads),
                              str(args.max_hits)], check=True, capture_output=True, text=True)
        ox = json.loads(res.stdout)
        ox_closest = np.fromfile(work / "oxray.closest", np.float32)
        ox_signed = np.fromfile(work / "oxray.signed", np.float32)
        ox_counts = np.fromfile(work / "oxray.counts", np.uint32)
    finally:
        shutil.rmtree(work, ignore_errors=True)

    rows = [("closest point", "closest_point", args.points),
            ("signed distance", "signed_distance", args.points),
            (f"all hits (<= {args.max_hits})", "all_hits", args.rays),
            ("hit counts", "count_hits", args.rays)]
    try:
        import open3d as o3d
    except ImportError:
        o3d = None
        print("open3d is not installed: oxray only")
    o3 = {}
    if o3d is not None:
        scene = o3d.t.geometry.RaycastingScene(nthreads=args.threads)
        mesh = o3d.t.geometry.TriangleMesh()
        mesh.vertex.positions = o3d.core.Tensor(v)
        mesh.triangle.indices = o3d.core.Tensor(f)
        scene.add_triangles(mesh)
        pts = o3d.core.Tensor(points)
        rts = o3d.core.Tensor(rays)

        def best(fn):
            t, r = float("inf"), None
            for _ in range(args.runs):
                s = time.perf_counter()
                r = fn()
                t = min(t, time.perf_counter() - s)
            return t, r

        t0 = time.perf_counter()
        scene.count_intersections(rts[:1])  # commits the scene (the BVH build)
        o3["build"] = time.perf_counter() - t0
        o3["closest_point"], cp = best(lambda: scene.compute_closest_points(pts))
        o3["signed_distance"], sd = best(lambda: scene.compute_signed_distance(pts))
        o3["all_hits"], lh = best(lambda: scene.list_intersections(rts))
        o3["count_hits"], cnt = best(lambda: scene.count_intersections(rts))
        o3_closest = np.linalg.norm(cp["points"].numpy() - points, axis=1)
        print(f"closest distance: max |oxray - open3d| = "
              f"{np.abs(o3_closest - ox_closest).max():.3g} (mesh radius {radius:.3g})")
        agree = np.mean((sd.numpy() < 0) == (ox_signed < 0))
        print(f"inside/outside agreement: {100 * agree:.3f} % of points")
        same = np.mean(cnt.numpy().astype(np.uint32) == ox_counts)
        print(f"equal hit counts: {100 * same:.3f} % of rays; listed hits: oxray "
              f"{ox['listed_hits']}, open3d {len(lh['t_hit'].numpy())}")

    print(f"\n{'query':<22}{'oxray Mq/s':>12}{'open3d Mq/s':>13}{'ratio':>8}")
    print(f"{'build (s)':<22}{ox['build']:>12.3f}{o3.get('build', float('nan')):>13.3f}")
    for label, key, n in rows:
        a = n / ox[key] / 1e6
        b = n / o3[key] / 1e6 if key in o3 else float("nan")
        print(f"{label:<22}{a:>12.2f}{b:>13.2f}{a / b:>8.2f}")


if __name__ == "__main__":
    sys.exit(main())
