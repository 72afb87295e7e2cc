#!/usr/bin/env python3
"""Throughput of oxray's simulation queries (oxray-cpu/src/simulation) against Open3D's
RaycastingScene (Embree underneath) on the same mesh, points and rays, in one run:

    closest point   oxray Gas::closest_point_batch   vs  scene.compute_closest_points
    signed distance oxray Gas::signed_distance_batch vs  scene.compute_signed_distance
    all hits        oxray Gas::all_hits_batch        vs  scene.list_intersections
    hit counts      oxray Gas::count_hits_batch      vs  scene.count_intersections

    scripts/setup-open3d.sh        # once: numpy + open3d-cpu 0.20 in target/open3d-venv
    target/open3d-venv/bin/python scripts/bench_simulation_queries.py \
        [--mesh stanford-bunny] [--points N] [--rays N] [--runs R] [--threads T] [--markdown]
        [--oxray-exe PATH]

Without open3d in the running Python only oxray is measured. The oxray side is the example
crates/oxray-cpu/examples/simulation_queries.rs, built by
`cargo build --release -p oxray-cpu --example simulation_queries` (the workspace's target
directory) and started once as a server: each line it reads runs one batch query and answers
its wall-clock and CPU seconds. Every query runs R + 1 times on each engine, oxray's run and
Open3D's in turn (so that both see the same load), the first run of each being an untimed
warm-up. The table gives the median of the R runs of each engine (and the spread, slowest to
fastest run), in millions of queries per second, the ratio oxray / Open3D of the medians
(above 1: oxray is faster), and the ratio of the median CPU seconds (all threads; Open3D's /
oxray's, above 1: oxray does less work), which other processes on the machine disturb less
than wall-clock time. The machine (CPU model, logical CPUs, threads used, load average before
and after) is printed first: wall-clock numbers from a loaded machine are not comparable.

The mesh is one of ../shared/data/meshes (OBJ), or an icosphere of 20 * 4^5 triangles if
it is missing. Points are uniform in the mesh's box grown by 10 %; rays start on a sphere
twice the box's radius and aim at uniform points of the box (seed 19: the same inputs every
run). Both sides get the same threads (Open3D's RaycastingScene takes nthreads=; oxray a
rayon pool of T threads). Results are cross-checked: closest distances (max abs difference),
inside/outside agreement of the signed distances, and equal hit counts per ray (a ray
crossing an edge may differ: Embree's test is not watertight).
"""

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent


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


def build_runner():
    """Builds the oxray example in release mode; returns its path."""
    subprocess.run(["cargo", "build", "--release", "--quiet", "-p", "oxray-cpu",
                    "--example", "simulation_queries"], cwd=REPO, check=True)
    meta = subprocess.run(["cargo", "metadata", "--format-version", "1", "--no-deps"],
                          cwd=REPO, check=True, capture_output=True, text=True)
    target = Path(json.loads(meta.stdout)["target_directory"])
    return target / "release" / "examples" / "simulation_queries"


def machine(threads):
    """One line on the machine: CPU model, logical CPUs, threads used, OS."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (f"{model}, {os.cpu_count()} logical CPUs, {threads} threads; "
            f"{platform.system()} {platform.release()}")


def load():
    try:
        return "/".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "?"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mesh", default="stanford-bunny")
    ap.add_argument("--points", type=int, default=200_000)
    ap.add_argument("--rays", type=int, default=200_000)
    ap.add_argument("--runs", type=int, default=7, help="timed runs per query and engine")
    ap.add_argument("--threads", type=int, default=os.cpu_count())
    ap.add_argument("--max-hits", type=int, default=64)
    ap.add_argument("--markdown", action="store_true", help="also print a Markdown table")
    ap.add_argument("--oxray-exe", type=Path,
                    help="an already built runner (the example of another checkout, to "
                         "compare versions) instead of building this checkout's")
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

    try:
        import open3d as o3d
    except ImportError:
        o3d = None
    exe = args.oxray_exe or build_runner()
    print(f"machine: {machine(args.threads)}")
    print(f"oxray runner: {exe}")
    print(f"mesh {name}: {len(v)} vertices, {len(f)} triangles; {args.points} points, "
          f"{args.rays} rays; median of {args.runs} runs after one warm-up")
    print(f"open3d: {o3d.__version__ if o3d else 'not installed (oxray only)'}; "
          f"load average before: {load()}")

    rows = [("closest point", "closest_point", args.points),
            ("signed distance", "signed_distance", args.points),
            (f"all hits (<= {args.max_hits})", "all_hits", args.rays),
            ("hit counts", "count_hits", args.rays)]
    o3_calls = {}
    if o3d is not None:
        scene = o3d.t.geometry.RaycastingScene(nthreads=args.threads)
        mesh = o3d.t.geometry.TriangleMesh()
        mesh.vertex.positions = o3d.core.Tensor(v)
        mesh.triangle.indices = o3d.core.Tensor(f)
        scene.add_triangles(mesh)
        pts = o3d.core.Tensor(points)
        rts = o3d.core.Tensor(rays)
        o3_calls = {"closest_point": lambda: scene.compute_closest_points(pts),
                    "signed_distance": lambda: scene.compute_signed_distance(pts),
                    "all_hits": lambda: scene.list_intersections(rts),
                    "count_hits": lambda: scene.count_intersections(rts)}

    work = Path(tempfile.mkdtemp(prefix="oxray-simq-"))
    ox = {k: [] for _, k, _ in rows}
    o3 = {k: [] for k in o3_calls}
    ox_cpu = {k: [] for _, k, _ in rows}
    o3_cpu = {k: [] for k in o3_calls}
    o3_out = {}
    try:
        with open(work / "mesh.bin", "wb") as out:
            out.write(np.array([len(v), len(f)], np.uint32).tobytes())
            out.write(v.tobytes())
            out.write(f.tobytes())
        (work / "points.bin").write_bytes(points.tobytes())
        (work / "rays.bin").write_bytes(rays.tobytes())
        runner = subprocess.Popen([str(exe), str(work), str(args.threads), str(args.max_hits)],
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        ox_build = json.loads(runner.stdout.readline())["build"]
        if o3d is not None:
            t0 = time.perf_counter()
            scene.count_intersections(rts[:1])  # commits the scene (the BVH build)
            o3_build = time.perf_counter() - t0
        else:
            o3_build = float("nan")
        # Run 0 is the warm-up of both engines; then each query runs on oxray and on Open3D
        # in turn, so that both see the same load.
        for run in range(args.runs + 1):
            for _, key, _ in rows:
                runner.stdin.write(key + "\n")
                runner.stdin.flush()
                r = json.loads(runner.stdout.readline())
                if run > 0:
                    ox[key].append(r["wall"])
                    ox_cpu[key].append(r["cpu"])
                if key in o3_calls:
                    s, c = time.perf_counter(), time.process_time()
                    o3_out[key] = o3_calls[key]()
                    s, c = time.perf_counter() - s, time.process_time() - c
                    if run > 0:
                        o3[key].append(s)
                        o3_cpu[key].append(c)
        runner.stdin.close()
        runner.wait()
        ox_closest = np.fromfile(work / "oxray.closest", np.float32)
        ox_signed = np.fromfile(work / "oxray.signed", np.float32)
        ox_counts = np.fromfile(work / "oxray.counts", np.uint32)
        ox_listed = int(np.fromfile(work / "oxray.listed", np.uint64)[0])
    finally:
        shutil.rmtree(work, ignore_errors=True)

    if o3d is not None:
        cp, sd = o3_out["closest_point"], o3_out["signed_distance"]
        lh, cnt = o3_out["all_hits"], o3_out["count_hits"]
        o3_closest = np.linalg.norm(cp["points"].numpy() - points, axis=1)
        print(f"closest distance: max |oxray - open3d| = "
              f"{np.abs(o3_closest - ox_closest).max():.3g} (mesh radius {radius:.3g})")
        agree = np.mean((sd.numpy() < 0) == (ox_signed < 0))
        print(f"inside/outside agreement: {100 * agree:.3f} % of points")
        same = np.mean(cnt.numpy().astype(np.uint32) == ox_counts)
        print(f"equal hit counts: {100 * same:.3f} % of rays; listed hits: oxray "
              f"{ox_listed}, open3d {len(lh['t_hit'].numpy())}")
    print(f"load average after: {load()}")

    def rate(n, times):
        """Median Mq/s, and the Mq/s of the slowest and fastest runs."""
        return (n / statistics.median(times) / 1e6, n / max(times) / 1e6,
                n / min(times) / 1e6)

    nan = float("nan")
    table = []
    for label, key, n in rows:
        a = rate(n, ox[key])
        b = rate(n, o3[key]) if key in o3 else (nan, nan, nan)
        cpu_a = statistics.median(ox_cpu[key])
        cpu_b = statistics.median(o3_cpu[key]) if key in o3 else nan
        table.append((label, a, b, a[0] / b[0], cpu_b / cpu_a))
    print(f"\n{'query':<22}{'oxray Mq/s':>12}{'(min-max)':>15}{'open3d Mq/s':>13}"
          f"{'(min-max)':>15}{'ratio':>8}{'CPU ratio':>11}")
    print(f"{'build (s)':<22}{ox_build:>12.3f}{'':>15}{o3_build:>13.3f}")
    for label, a, b, ratio, cpu in table:
        print(f"{label:<22}{a[0]:>12.2f}{f'{a[1]:.2f}-{a[2]:.2f}':>15}{b[0]:>13.2f}"
              f"{f'{b[1]:.2f}-{b[2]:.2f}':>15}{ratio:>8.2f}{cpu:>11.2f}")
    print("ratio: oxray's median throughput / Open3D's (above 1: oxray is faster); CPU ratio: "
          "Open3D's median CPU seconds / oxray's (all threads), less sensitive to other load")
    if args.markdown:
        print("\n| query | oxray Mq/s (min-max) | Open3D Mq/s (min-max) | oxray / Open3D "
              "| CPU-time ratio |")
        print("|---|---:|---:|---:|---:|")
        for label, a, b, ratio, cpu in table:
            print(f"| {label} | {a[0]:.2f} ({a[1]:.2f}-{a[2]:.2f}) | "
                  f"{b[0]:.2f} ({b[1]:.2f}-{b[2]:.2f}) | {ratio:.2f} | {cpu:.2f} |")

if __name__ == "__main__":
    sys.exit(main())
