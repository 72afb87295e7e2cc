#!/usr/bin/env python3
"""Runs `oxray bench` of this checkout and of an earlier commit side by side, alternating runs so
that both see the same machine state, and prints the medians and their ratios as a markdown
table (for docs/BENCHMARKS.md).

    scripts/bench-vs-commit.py COMMIT [--rounds N] [--side S] [--runs R] [MESH ...]

The earlier commit is built in a temporary git worktree with its own target directory (or pass
--old-binary PATH to reuse one). Meshes default to the bunny and Igea from ../shared/data.
"""
import argparse, os, re, statistics, subprocess, sys, tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
COLUMNS = ["build ms", "SAH", "primary closest", "primary any", "diffuse closest",
           "diffuse any", "shadow"]


def build(commit, target):
    work = Path(tempfile.mkdtemp(prefix="oxray-base-"))
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(work), commit],
                   check=True, stdout=subprocess.DEVNULL)
    try:
        subprocess.run(["cargo", "build", "--release", "-p", "oxray-cli"], cwd=work, check=True,
                       env={**os.environ, "CARGO_TARGET_DIR": str(target)})
    finally:
        subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(work)])
    return target / "release" / "oxray"


def run(binary, mesh, side, runs):
    out = subprocess.run([str(binary), "bench", str(mesh), "--side", str(side), "--runs",
                          str(runs)], check=True, capture_output=True, text=True).stdout
    row = next(l for l in out.splitlines() if l.startswith("| ") and not l.startswith("| mesh"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    # cells: mesh, tris, build (d / fb / ft), SAH (d / fb / ft), 5 Mrays/s columns, ...
    build_ms = float(cells[2].split("/")[0])
    sah = float(cells[3].split("/")[0])
    return [build_ms, sah] + [float(c) for c in cells[4:9]]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("commit")
    ap.add_argument("meshes", nargs="*")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--side", type=int, default=1024)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--old-binary")
    args = ap.parse_args()
    data = ROOT.parent / "shared" / "data" / "meshes"
    meshes = [Path(m) for m in args.meshes] or [data / "stanford-bunny.obj", data / "igea.ply"]
    subprocess.run(["cargo", "build", "--release", "-p", "oxray-cli"], cwd=ROOT, check=True)
    new = ROOT / "target" / "release" / "oxray"
    old = Path(args.old_binary) if args.old_binary else build(
        args.commit, Path(tempfile.gettempdir()) / "oxray-base-target")
    print(f"old: {args.commit} ({old}), new: working tree ({new}); {args.rounds} alternating "
          f"rounds of `oxray bench --side {args.side} --runs {args.runs}`, medians\n")
    print("| mesh | metric | old | new | new / old |")
    print("|---|---|---:|---:|---:|")
    for mesh in meshes:
        res = {"old": [], "new": []}
        for _ in range(args.rounds):
            res["old"].append(run(old, mesh, args.side, args.runs))
            res["new"].append(run(new, mesh, args.side, args.runs))
        for i, name in enumerate(COLUMNS):
            o = statistics.median(r[i] for r in res["old"])
            n = statistics.median(r[i] for r in res["new"])
            unit = "" if name in ("build ms", "SAH") else " Mrays/s"
            print(f"| {mesh.stem} | {name}{unit} | {o:.2f} | {n:.2f} | {n / o:.3f} |")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
