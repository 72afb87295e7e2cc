#!/bin/bash
# Runs the binaries scripts/gpu-suite-pack.sh packed, with OXRAY_REQUIRE_GPU=1 (a missing or
# unusable GPU fails instead of skipping), then the GPU benchmarks of docs/BENCHMARKS.md that
# the open goals need. From the repository root; the log goes to $OUT/log.txt
# (or ./log.txt). BENCH=0 skips the benchmarks, TESTS=0 the test binaries (each fits a device
# call of at most ten minutes).
set -u
export OXRAY_REQUIRE_GPU=1
root=$(pwd)
out=${OUT:-$root}
log=$out/log.txt
[ -e /work/main ] || { mkdir -p /work && ln -s "$root" /work/main; }
(cd "$root/.gpu" && tar -xJf bins.tar.xz) || { echo "unpack failed" >> "$log"; exit 1; }
mkdir -p "$root/target/debug" && cp "$root/.gpu/bin/oxray-debug" "$root/target/debug/oxray"
export OXRAY_MESH_DIR=$root/.gpu/meshes
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
[ "${BENCH:-1}" = 0 ] && exit 0
M=$root/.gpu/meshes
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
