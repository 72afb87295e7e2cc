#!/usr/bin/env bash
# Side-by-side: `oxray bench` (CPU), Embree 3 from C (scripts/embree3_bench.c, Debian's
# libembree-dev) and Embree 4 (PyPI embreex, scripts/bench_embree.py) on the same meshes and
# rays, with the agreement of their answers and one table of ratios.
#
#   scripts/bench-vs-embree.sh [MESH...]
#
# MESH: .obj/.ply files; default: the bunny and igea from ../shared/data/meshes (relative
# to the repository root) when present, else what `oxray bench` uses by default.
# Environment:
#   THREADS        thread counts, comma-separated (default: 1 and all logical CPUs, "1,$(nproc)");
#                  oxray (`oxray bench --threads T`) and Embree 3 (T POSIX threads tracing, a
#                  device with "threads=T" building) run at each; Embree 4 at one thread only
#                  (embreex's run() is a serial loop, see bench_embree.py)
#   SIDE           rays per set are SIDE x SIDE (default 1024, `oxray bench --side`)
#   RUNS           repetitions, the median is reported (default 5; also Embree 3's builds)
#   BUILD          the oxray build preset the rays trace: default, fast-build, fast-trace
#                  (default: default)
#   EMBREE3_FLAGS  robust or none: Embree 3's scene flags (default robust: watertight, as oxray)
#   PACKET         1 or 8: Embree 3 traces one ray a call (rtcIntersect1, default) or packets of
#                  eight consecutive rays (rtcIntersect8)
#   EMBREE4        0 to skip Embree 4 (embreex is installed into scripts/.venv-embree on first use)
#   CARGO_TARGET_DIR  where cargo builds; PYTHON (default python3); CC (default cc)
# Installs Embree 3 when missing (scripts/setup-embree3.sh). Writes bench-out/rays (meshes,
# rays and oxray's answers), bench-out/*.txt (each engine's own output) and prints the table.
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
py="${PYTHON:-python3}"
runs="${RUNS:-5}"
side="${SIDE:-1024}"
build="${BUILD:-default}"
threads="${THREADS:-1,$(nproc)}"
e3flags="${EMBREE3_FLAGS:-robust}"
out="bench-out"
rays="$out/rays"

meshes=("$@")
if [ ${#meshes[@]} -eq 0 ]; then
    for f in ../shared/data/meshes/stanford-bunny.obj ../shared/data/meshes/igea.ply; do
        if [ -f "$f" ]; then meshes+=("$f"); fi
    done
fi
if [ ${#meshes[@]} -eq 0 ]; then
    echo "error: no meshes given and ../shared/data/meshes absent" >&2
    exit 1
fi
names=()
for f in "${meshes[@]}"; do
    b="$(basename "$f")"
    names+=("${b%.*}")
done
# Thread counts, deduplicated in order (on a 1-CPU machine "1,1" is one run).
IFS=, read -r -a tlist <<<"$threads"
uniq=()
for t in "${tlist[@]}"; do
    case " ${uniq[*]-} " in *" $t "*) ;; *) uniq+=("$t") ;; esac
done
tlist=("${uniq[@]}")
threads="$(IFS=,; echo "${tlist[*]}")"

echo "== oxray vs Embree: $(date -u '+%Y-%m-%d %H:%M:%S UTC')"
model="$(lscpu 2>/dev/null | sed -n 's/^Model name:[[:space:]]*//p' | head -n1)"
cores="$(lscpu 2>/dev/null | awk -F: '/^Core\(s\) per socket/ {c=$2} /^Socket\(s\)/ {s=$2} END {if (c && s) print c*s}')"
echo "machine: ${model:-unknown CPU}, ${cores:-?} cores, $(nproc) logical CPUs available; $(uname -sr); load average $(cut -d' ' -f1-3 /proc/loadavg 2>/dev/null || echo '?')"
echo "oxray $(git rev-parse --short HEAD 2>/dev/null || echo '?')$(git diff --quiet 2>/dev/null || echo ' (+ uncommitted changes)'), $(rustc --version); threads: $threads; runs: $runs; oxray build traced: $build"

scripts/setup-embree3.sh
cargo build --release -p oxray-cli
mkdir -p "$out"
"${CC:-cc}" -O2 -std=c11 -o "$out/embree3_bench" scripts/embree3_bench.c -lembree3 -lpthread -lm

rm -rf "$rays"
oxray="${CARGO_TARGET_DIR:-target}/release/oxray"
first=1
for t in "${tlist[@]}"; do
    echo
    echo "== oxray, $t thread(s)"
    export_args=()
    if [ $first -eq 1 ]; then export_args=(--export "$rays"); first=0; fi
    "$oxray" bench --threads "$t" --side "$side" --runs "$runs" --build "$build" ${export_args[@]+"${export_args[@]}"} \
        "${meshes[@]}" 2>&1 | tee "$out/oxray-$t.txt"
done
echo
echo "== Embree 3 (C, $threads thread(s))"
"$out/embree3_bench" "$rays" "${names[@]}" --threads "$threads" --runs "$runs" --builds "$runs" \
    --scene-flags "$e3flags" --packet "${PACKET:-1}" 2>&1 | tee "$out/embree3.txt"
rm -f "$out/embree4.txt"
if [ "${EMBREE4:-1}" != 0 ]; then
    echo
    echo "== Embree 4 (embreex, 1 thread)"
    "$py" scripts/bench_embree.py "$rays" --runs "$runs" --threads 1 --flags robust 2>&1 | tee "$out/embree4.txt"
fi
echo
echo "== Side by side"
"$py" scripts/bench_table.py "$out"
