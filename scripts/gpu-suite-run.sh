#!/bin/bash
# Runs the binaries scripts/gpu-suite-pack.sh packed, with OXRAY_REQUIRE_GPU=1 (a missing or
# unusable GPU fails instead of skipping), then the GPU benchmarks of docs/BENCHMARKS.md that
# the open goals need. From the repository root; the log goes to $OUT/log.txt
# (or ./log.txt). BENCH=0 skips the benchmarks, TESTS=0 the test binaries, PROFILE=1 adds an
# Nsight Compute profile. Every test binary takes about twelve minutes on an H100, more than a
# device call's ten: pack them in two parts (the pack script's ONLY) or set TEST_TIMEOUT.
set -u
export OXRAY_REQUIRE_GPU=1
root=$(pwd)
out=${OUT:-$root}
log=$out/log.txt
[ -e /work/main ] || { mkdir -p /work && ln -s "$root" /work/main; }
(cd "$root/.gpu" && tar -xJf bins.tar.xz) || { echo "unpack failed" >> "$log"; exit 1; }
mkdir -p "$root/target/debug" && cp "$root/.gpu/bin/oxray-debug" "$root/target/debug/oxray"
M=$root/.gpu/meshes
export OXRAY_MESH_DIR=$M
nvidia-smi --query-gpu=name,driver_version --format=csv >> "$log" 2>&1
[ "${TESTS:-1}" = 0 ] || while read -r crate exe name; do
  echo "=== $crate $name" >> "$log"
  (cd "$root/crates/$crate" && timeout "${TEST_TIMEOUT:-240}" "$root/.gpu/bin/$exe" --test-threads 4 > "$out/t.txt" 2>&1)
  rc=$?
  grep -E "test result|FAILED|panicked|failed" "$out/t.txt" | head -30 >> "$log"
  if [ $rc -ne 0 ]; then grep -v "^   \|^  at \|^stack\|^note" "$out/t.txt" | tail -60 >> "$log"; fi
  echo "rc=$rc (${SECONDS}s)" >> "$log"
done < "$root/.gpu/bin/tests.txt"
rm -f "$out/t.txt"
# PROFILE=1: Nsight Compute on the query kernel's and the pipeline's launches of the bunny's
# three ray sets (docs/BENCHMARKS.md, "The pipeline, sixth round"); the 402 launches skipped
# are `oxray bench`'s launches of one ray (201 of each kernel). The report goes to $OUT/ncu.txt.
if [ "${PROFILE:-0}" = 1 ]; then
  ncu=$(command -v ncu || ls /usr/local/cuda*/bin/ncu 2>/dev/null | head -1)
  echo "=== ncu $ncu" >> "$log"
  timeout 400 "$ncu" -k regex:'__oxray_pipeline|oxray_closest_bvh2' --launch-skip 402 \
    --launch-count 24 --section SpeedOfLight --section Occupancy --section LaunchStats \
    --section WarpStateStats --section SchedulerStats --section MemoryWorkloadAnalysis \
    --section InstructionStats --section SourceCounters \
    "$root/.gpu/bin/oxray" bench --backend cuda --runs 1 "$M/stanford-bunny.obj" > "$out/ncu.txt" 2>&1
  echo "rc=$? (${SECONDS}s)" >> "$log"
fi
[ "${BENCH:-1}" = 0 ] && exit 0
X=$root/.gpu/bin/oxray
run() { echo "=== $*" >> "$log"; timeout 200 "$X" "$@" >> "$log" 2>&1; echo "rc=$? (${SECONDS}s)" >> "$log"; }
# Issue 13's open goal: the pipeline against the query kernel on the same rays (each rays row
# of `oxray bench --backend cuda` has both), small meshes and a 4.4 M-triangle one.
run bench --backend cuda --runs 5 "$M/stanford-bunny.obj" "$M/igea.ply"
run bench --backend cuda --runs 3 --subdivide 3 "$M/stanford-bunny.obj"
# Measured on 2026-12-05 (docs/BENCHMARKS.md); rerun after changing the simulation kernels or
# the device builder.
run bench --backend cuda --simulation --side 1024 --runs 5 "$M/stanford-bunny.obj" "$M/igea.ply"
run bench --backend cuda --gas-builds --subdivide 3 --runs 5 "$M/ogre.obj"
