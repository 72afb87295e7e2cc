#!/bin/bash
# Packs every test binary that touches CUDA, the release and debug `oxray` and the benchmark
# meshes into .gpu/bins.tar.xz, for a GPU machine that has the driver but no Rust toolchain
# (run them there with scripts/gpu-suite-run.sh from the repository root). On a machine with
# both, `OXRAY_REQUIRE_GPU=1 cargo test --workspace` does the same.
#
#   scripts/gpu-suite-pack.sh            # every GPU suite
#   ONLY=oxray:simulation_devices,oxray-cuda:gpu scripts/gpu-suite-pack.sh
set -euo pipefail
cd "$(dirname "$0")/.."
json=$(mktemp)
cargo test --workspace --no-run --message-format=json > "$json"
cargo build --release -p oxray-cli
cargo build -p oxray-cli
rm -rf .gpu/bin .gpu/meshes && mkdir -p .gpu/bin .gpu/meshes
for m in stanford-bunny.obj igea.ply ogre.obj; do
  [ -e "../shared/data/meshes/$m" ] && cp "../shared/data/meshes/$m" .gpu/meshes/
done
JSON="$json" python3 - <<'PY'
import json, os, subprocess
want = {
    'oxray-cuda': ['oxray_cuda', 'gpu', 'gpu_build', 'programs', 'offer_parts'],
    'oxray': ['accel_life', 'conformance', 'conformance_builtins', 'conformance_twins',
              'conformance_twins2', 'conformance_twins3', 'curves', 'device', 'memory', 'motion',
              'motion_devices', 'random_access', 'simulation_devices', 'spheres',
              'instancing_pipeline'],
    'oxray-render': ['crop', 'device_programs', 'motion_blur', 'renderer'],
    'oxray-cli': ['backend', 'render_backend'],
}
only = os.environ.get('ONLY')
exes = {}
for line in open(os.environ['JSON']):
    d = json.loads(line)
    if d.get('reason') != 'compiler-artifact' or '/crates/' not in d.get('manifest_path', ''):
        continue
    t, exe = d['target'], d.get('executable')
    if not exe or 'bin' in t['kind'] or 'example' in t['kind']:
        continue
    crate = d['manifest_path'].split('/crates/')[1].split('/')[0]
    exes[(crate, t['name'])] = exe
lines = []
for crate, names in want.items():
    for n in names:
        if only and f"{crate}:{n}" not in only.split(','):
            continue
        out = f"{crate}__{n}"
        subprocess.run(['strip', '-o', f'.gpu/bin/{out}', exes[(crate, n)]], check=True)
        lines.append(f"{crate} {out} {n}")
open('.gpu/tests.txt', 'w').write("\n".join(lines) + "\n")
PY
rm -f "$json"
strip -o .gpu/bin/oxray target/release/oxray
strip -o .gpu/bin/oxray-debug target/debug/oxray
cp .gpu/tests.txt .gpu/bin/
(cd .gpu && tar -cf - bin meshes | xz -T0 -6 > bins.tar.xz && rm -rf bin meshes)
ls -la .gpu/bins.tar.xz
