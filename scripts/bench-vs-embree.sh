#!/usr/bin/env bash
# Side-by-side: `oxray bench` and Embree 4 (PyPI embreex, scripts/bench_embree.py) on the
# same meshes, rays and thread count.
#
#   scripts/bench-vs-embree.sh [MESH...]
#
# MESH: .obj/.ply files; default: the bunny and igea from ../shared/data/meshes (relative
# to the repository root) when present, else what `oxray bench` uses by default.
# Environment: RUNS (default 5, both sides), THREADS (default: the thread count embreex's
# run() traces with, measured by `bench_embree.py --print-threads`), CARGO_TARGET_DIR (where
# cargo builds), PYTHON (default
# python3; numpy and embreex are installed into scripts/.venv-embree when missing).
# Writes bench-out/rays (meshes and rays exported by oxray); prints both tables.
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
py="${PYTHON:-python3}"
runs="${RUNS:-5}"
out="bench-out/rays"

meshes=("$@")
if [ ${#meshes[@]} -eq 0 ]; then
    for f in ../shared/data/meshes/stanford-bunny.obj ../shared/data/meshes/igea.ply; do
        if [ -f "$f" ]; then meshes+=("$f"); fi
    done
fi

echo "== oxray vs Embree: $(date -u '+%Y-%m-%d %H:%M:%S UTC')"
model="$(lscpu 2>/dev/null | sed -n 's/^Model name:[[:space:]]*//p' | head -n1)"
cores="$(lscpu 2>/dev/null | awk -F: '/^Core\(s\) per socket/ {c=$2} /^Socket\(s\)/ {s=$2} END {if (c && s) print c*s}')"
echo "machine: ${model:-unknown CPU}, ${cores:-?} cores, $(nproc) logical CPUs available; $(uname -sr); load average $(cut -d' ' -f1-3 /proc/loadavg 2>/dev/null || echo '?')"
echo "oxray $(git rev-parse --short HEAD 2>/dev/null || echo '?')$(git diff --quiet 2>/dev/null || echo ' (+ uncommitted changes)'), $(rustc --version)"

cargo build --release -p oxray-cli

threads="${THREADS:-}"
if [ -z "$threads" ]; then
    threads="$("$py" scripts/bench_embree.py --print-threads)"
fi
echo "threads: $threads (the number embreex's run() traces with; both sides use it)"

rm -rf "$out"
echo
echo "== oxray"
"${CARGO_TARGET_DIR:-target}/release/oxray" bench --threads "$threads" --runs "$runs" --export "$out" ${meshes[@]+"${meshes[@]}"} 2>&1
echo
echo "== Embree (embreex)"
"$py" scripts/bench_embree.py "$out" --runs "$runs" --threads "$threads" 2>&1
