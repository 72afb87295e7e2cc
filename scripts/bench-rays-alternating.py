#!/usr/bin/env python3
"""oxray's CPU kernels and Embree 3 on the same exported ray sets, run alternately.

    python3 scripts/bench-rays-alternating.py [--rounds 3] [--runs 3] [--threads 1] MESH_NAME...

On a machine that others share, throughput drifts by tens of percent within minutes, so two
engines measured one after the other (as scripts/bench-vs-embree.sh does) can see different
machines. Here each round runs Embree 3 (scripts/embree3_bench.c) and then oxray
(`cargo bench -p oxray-cpu --bench ray_sets`) on every set of one mesh, and the table keeps,
per engine, the best of the rounds' medians: the figure least disturbed by the others' load.

Needs what scripts/bench-vs-embree.sh leaves: the meshes and rays in bench-out/rays
(`oxray bench --export`) and bench-out/embree3_bench. Prints a markdown table of Mrays/s and
oxray / Embree 3 ratios (above 1: oxray is faster), and oxray's batched queries (packets for
camera rays), single-ray queries and the programmable pipeline on the camera rays, and how
Embree 3's answers agree with those oxray exported.
"""

import argparse
import glob
import os
import re
import subprocess
import sys

# Embree 3's agreement with oxray's exported answers (`AGREE` lines), once per set.
AGREE = set()

SETS = [
    ("coherent", "closest"),
    ("coherent", "any"),
    ("incoherent", "closest"),
    ("incoherent", "any"),
    ("shadow", "any"),
]


def ray_sets_binary(root):
    subprocess.run(
        ["cargo", "bench", "-p", "oxray-cpu", "--bench", "ray_sets", "--no-run"],
        cwd=root, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    target = os.environ.get("CARGO_TARGET_DIR", os.path.join(root, "target"))
    found = [p for p in glob.glob(os.path.join(target, "release", "deps", "ray_sets-*"))
             if os.access(p, os.X_OK) and not p.endswith(".d")]
    if not found:
        sys.exit("ray_sets bench binary not found")
    return max(found, key=os.path.getmtime)


def oxray(binary, rays, mesh, s, q, runs, threads):
    out = subprocess.run([binary, rays, mesh, s, q, str(runs), str(threads)],
                         check=True, capture_output=True, text=True).stdout
    m = re.search(r": ([0-9.]+) Mrays/s", out)
    return float(m.group(1))


def embree(binary, rays, mesh, runs, threads):
    out = subprocess.run([binary, rays, mesh, "--threads", str(threads), "--runs", str(runs),
                          "--builds", str(runs)], check=True, capture_output=True, text=True).stdout
    res = {}
    for line in out.splitlines():
        if line.startswith("AGREE "):
            AGREE.add(line[len("AGREE "):].strip())
        if line.startswith("RESULT "):
            kv = dict(x.split("=", 1) for x in line.split()[1:])
            res[kv["metric"]] = float(kv["value"])
    return res


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("meshes", nargs="+")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args()
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    rays = os.path.join(root, "bench-out", "rays")
    e3 = os.path.join(root, "bench-out", "embree3_bench")
    if not os.path.exists(e3):
        sys.exit("bench-out/embree3_bench is missing: run scripts/bench-vs-embree.sh once")
    binary = ray_sets_binary(root)
    print(f"{a.rounds} alternating rounds, each engine's best round (median of {a.runs} runs "
          f"each), {a.threads} thread(s); Mrays/s")
    print()
    print("| mesh | rays | oxray | Embree 3 | oxray / Embree 3 |")
    print("|---|---|---:|---:|---:|")
    extra = []
    for mesh in a.meshes:
        best_o, best_e, modes = {}, {}, {}
        for _ in range(a.rounds):
            for k, v in embree(e3, rays, mesh, a.runs, a.threads).items():
                best_e[k] = max(best_e.get(k, 0.0), v)
            for s, q in SETS:
                v = oxray(binary, rays, mesh, s, q, a.runs, a.threads)
                best_o[s, q] = max(best_o.get((s, q), 0.0), v)
            for q in ("single", "pipeline"):
                v = oxray(binary, rays, mesh, "coherent", q, a.runs, a.threads)
                modes[q] = max(modes.get(q, 0.0), v)
        for s, q in SETS:
            o, e = best_o[s, q], best_e.get(f"{s}_{q}", 0.0)
            print(f"| {mesh} | {s} {q} | {o:.2f} | {e:.2f} | {o / e:.2f} |")
        extra.append((mesh, best_o["coherent", "closest"], modes["single"], modes["pipeline"]))
    print()
    print("Camera rays (closest hit), oxray: batched (packets), single-ray queries, the pipeline")
    print()
    print("| mesh | batched | single rays | pipeline | pipeline / single rays |")
    print("|---|---:|---:|---:|---:|")
    for mesh, b, s, p in extra:
        print(f"| {mesh} | {b:.2f} | {s:.2f} | {p:.2f} | {p / s:.2f} |")
    if AGREE:
        print()
        print("Embree 3 against the answers `oxray bench --export` wrote:")
        for line in sorted(AGREE):
            print(f"- {line}")


if __name__ == "__main__":
    main()
