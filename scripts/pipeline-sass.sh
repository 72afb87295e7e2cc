#!/usr/bin/env bash
# Reads the machine code of the CUDA pipeline's walk beside the query kernels' without a GPU
# (docs/BENCHMARKS.md, "The pipeline, fifth round"): compiles `oxray bench --backend cuda`'s
# pipeline and the trace kernels to PTX with NVRTC, assembles them for sm_90 with ptxas from
# the PyPI wheels (fetched into target/cuda-tools), and prints, for each kernel, ptxas's
# registers and spills and, for each loop that loads BVH nodes, its instructions and local
# memory accesses (LDL/STL: the stack, and spilled values reloaded at every node). The
# pipeline's first two loops are the fast path's walks (closest hit, first hit), the others
# the general traversal's.
#
#   scripts/pipeline-sass.sh                 # the pipeline as compiled by default
#   MIN_BLOCKS=8 scripts/pipeline-sass.sh    # with other launch bounds (blocks of 128 per SM)
set -euo pipefail
cd "$(dirname "$0")/.."
tools="$PWD/target/cuda-tools"
fetch() { # wheel version
    if [ ! -e "$tools/.$1" ]; then
        python3 -m pip download --quiet --no-deps --only-binary=:all: \
            --platform manylinux2014_x86_64 --python-version 3.12 -d "$tools/wheels" "$1==$2" >&2
        python3 -m zipfile -e "$tools"/wheels/"${1//-/_}"-"$2"-*.whl "$tools" >&2
        touch "$tools/.$1"
    fi
}
fetch nvidia-cuda-nvcc 13.0.88
fetch nvidia-cuda-cuobjdump 13.2.86
fetch nvidia-cuda-nvdisasm 13.5.37
bin="$tools/nvidia/cu13/bin"
chmod +x "$bin"/*
export PATH="$bin:$PATH"
LD_LIBRARY_PATH="$(scripts/fetch-nvrtc.sh)${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
export LD_LIBRARY_PATH
out="$PWD/target/sass"
cargo run --quiet --release -p oxray-cli --example pipeline_ptx -- "$out" > /dev/null
if [ -n "${MIN_BLOCKS:-}" ]; then
    sed -i "s/^\.minnctapersm .*/.minnctapersm $MIN_BLOCKS/" "$out/pipeline.ptx"
fi
for job in "pipeline __oxray_pipeline" "trace oxray_closest_bvh2" "trace oxray_occluded_bvh2"; do
    set -- $job
    ptxas -arch=sm_90 -v "$out/$1.ptx" -o "$out/$1.cubin" 2> "$out/$1.ptxas.txt"
    cuobjdump -sass -fun "$2" "$out/$1.cubin" > "$out/$2.sass"
    python3 - "$out/$1.ptxas.txt" "$out/$2.sass" "$2" <<'PY'
import re, sys
info, sass, name = sys.argv[1:]
lines = open(info).read().splitlines()
for i, line in enumerate(lines):
    if f"entry function '{name}'" in line:
        props = " ".join(l.split(":", 1)[-1].strip() for l in lines[i + 1:i + 4])
        print(f"{name}: {props}")
ins = []
for line in open(sass):
    m = re.match(r"\s*/\*([0-9a-f]{4,})\*/\s+(.*?);", line)
    if m:
        ins.append((int(m.group(1), 16), m.group(2).strip()))
for a, t in ins:
    m = re.search(r"BRA (?:!?P\d, )?0x([0-9a-f]+)", t)
    if not m or int(m.group(1), 16) >= a:
        continue
    lo = int(m.group(1), 16)
    body = [u for b, u in ins if lo <= b <= a]
    # A loop over BVH nodes loads a node's fourth row (its links) at offset 0x30.
    if len(body) < 2000 and any("LDG.E.128" in u and "+0x30]" in u for u in body):
        ldl = sum("LDL" in u for u in body)
        stl = sum("STL" in u for u in body)
        print(f"  loop {lo:#x}-{a:#x}: {len(body)} instructions, {ldl} LDL, {stl} STL")
PY
done
