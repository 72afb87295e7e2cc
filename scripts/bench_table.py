#!/usr/bin/env python3
"""The side-by-side table of scripts/bench-vs-embree.sh: oxray against Embree 3 and Embree 4.

    python3 scripts/bench_table.py OUTDIR

Reads what the script wrote in OUTDIR (standard library only):
  oxray-T.txt    `oxray bench --threads T` (its markdown table; one file per thread count)
  embree3.txt    scripts/embree3_bench.c (`RESULT ...` and `AGREE ...` lines)
  embree4.txt    scripts/bench_embree.py (its markdown table and notes), optional
and prints markdown: ray throughput (Mrays/s, medians) with the ratios oxray / Embree, build
times, and the agreement of the answers. A ratio above 1 means oxray is faster.
"""

import glob
import os
import re
import sys

# (label, oxray bench column, embree3_bench metric, bench_embree.py column)
QUERIES = [
    ("coherent closest", 4, "coherent_closest", 5),
    ("coherent any", 5, "coherent_any", 6),
    ("incoherent closest", 6, "incoherent_closest", 7),
    ("incoherent any", 7, "incoherent_any", 8),
    ("shadow any", 8, "shadow_any", 9),
]


def cells(line):
    return [c.strip() for c in line.strip().strip("|").split("|")]


def num(s):
    try:
        return float(s)
    except ValueError:
        return None


def read_oxray(path):
    """{mesh: {"tris", "build": [default, fast-build, fast-trace], "sah": [...], col: value}}
    and the traced build's name."""
    out, traced = {}, "?"
    with open(path) as f:
        for line in f:
            m = re.search(r"rays traced on the (\S+) build", line)
            if m:
                traced = m.group(1)
            if line.startswith("structure life"):
                # The tables after the ray table (refit, compaction, save and load) are not
                # read here.
                break
            if not line.startswith("| ") or line.startswith("| mesh"):
                continue
            c = cells(line)
            if len(c) < 9:
                continue
            row = {"tris": c[1], "build": [num(x) for x in c[2].split("/")],
                   "sah": [num(x) for x in c[3].split("/")]}
            for k in range(4, 9):
                row[k] = num(c[k])
            out[c[0]] = row
    return out, traced


def read_embree3(path):
    res, agree, header = {}, [], ""
    with open(path) as f:
        for line in f:
            if line.startswith("RESULT "):
                kv = dict(x.split("=", 1) for x in line.split()[1:])
                res[kv["mesh"], int(kv["threads"]), kv["metric"]] = float(kv["value"])
            elif line.startswith("AGREE "):
                agree.append(line[len("AGREE "):].strip())
            elif line.startswith("Embree") and not header:
                header = line.strip()
    return res, agree, header


def read_embree4(path):
    rows, notes, header = {}, [], ""
    if not os.path.exists(path):
        return rows, notes, header
    with open(path) as f:
        for line in f:
            if line.startswith("Embree") and not header:
                header = line.strip()
            if line.startswith("| ") and not line.startswith("| mesh"):
                c = cells(line)
                if len(c) >= 10 and c[2] == "robust":
                    rows[c[0]] = c
            elif ": hit/miss agree" in line or "WARNING" in line:
                notes.append(line.strip())
    return rows, notes, header


def ratio(a, b):
    return f"{a / b:.2f}" if a and b else "-"


def fmt(x, digits=2):
    return "-" if x is None else f"{x:.{digits}f}"


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    d = sys.argv[1]
    ox = {}
    traced = "?"
    for p in glob.glob(os.path.join(d, "oxray-*.txt")):
        t = int(re.search(r"oxray-(\d+)\.txt$", p).group(1))
        ox[t], traced = read_oxray(p)
    e3, agree, e3_header = read_embree3(os.path.join(d, "embree3.txt"))
    e4, e4_notes, e4_header = read_embree4(os.path.join(d, "embree4.txt"))
    threads = sorted(ox)
    meshes = list(next(iter(ox.values())).keys()) if ox else []

    print(f"Ray throughput, Mrays/s (medians); oxray traces its `{traced}` build; "
          f"Embree 3: {e3_header or '?'}; Embree 4: {e4_header or 'not run'} (one thread, robust)")
    print()
    print("| mesh | threads | rays | oxray | Embree 3 | oxray / Embree 3 | Embree 4 | oxray / Embree 4 |")
    print("|---|---:|---|---:|---:|---:|---:|---:|")
    for mesh in meshes:
        for t in threads:
            row = ox[t].get(mesh)
            if row is None:
                continue
            for label, col, metric, e4col in QUERIES:
                o = row[col]
                a = e3.get((mesh, t, metric))
                b = num(e4[mesh][e4col]) if (t == 1 and mesh in e4) else None
                print(f"| {mesh} | {t} | {label} | {fmt(o)} | {fmt(a)} | {ratio(o, a)} "
                      f"| {fmt(b)} | {ratio(o, b)} |")
    print()
    print("Build, ms (medians): oxray's presets (`Gas::build`: decode, BVH, wide layout, triangle "
          "packing; fast-trace = PREFER_FAST_TRACE with spatial splits, fast-trace-binned = the same "
          "without them) against Embree's MEDIUM quality (rtcCommitScene); Embree 4's is on one "
          "thread. Ratios are Embree 3 / oxray (above 1: oxray builds faster).")
    print()
    names = ["default", "fast-build", "fast-trace", "fast-trace-binned"]
    nb = max((len(r["build"]) for t in threads for r in ox[t].values()), default=3)
    names = names[:nb]
    print("| mesh | threads | " + " | ".join(f"oxray {n}" for n in names)
          + " | Embree 3 | Embree 3 / oxray default | Embree 3 / oxray fast-trace | Embree 4 |")
    print("|---|---:|" + "---:|" * (len(names) + 4))
    for mesh in meshes:
        for t in threads:
            row = ox[t].get(mesh)
            if row is None:
                continue
            b = (row["build"] + [None] * nb)[:nb]
            a = e3.get((mesh, t, "build_ms"))
            e4b = num(e4[mesh][3]) if (t == 1 and mesh in e4) else None
            print(f"| {mesh} | {t} | " + " | ".join(fmt(x, 1) for x in b)
                  + f" | {fmt(a, 1)} | {ratio(a, b[0])} | {ratio(a, b[2])} | {fmt(e4b, 1)} |")
    print()
    print(f"SAH cost (oxray, {' / '.join(names)}): " + "; ".join(
        f"{m} {' / '.join(fmt(x, 2) for x in ox[threads[0]][m]['sah'])}" for m in meshes))
    print()
    print("Agreement, Embree 3 against oxray (same rays, tmin honoured; t within the relative "
          "tolerance shown; a different primitive at the same t is a tie):")
    for a in agree:
        print(f"- {a}")
    if e4_notes:
        print("Agreement, Embree 4 (embreex) against oxray:")
        for n in e4_notes:
            print(f"- {n}")


if __name__ == "__main__":
    main()
