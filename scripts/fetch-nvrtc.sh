#!/usr/bin/env bash
# Fetches NVRTC (the CUDA run-time compiler) from PyPI into target/nvrtc, so that the CUDA
# kernels are compiled by the tests on machines without a GPU or a CUDA toolkit. Prints the
# directory to put on LD_LIBRARY_PATH. Idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
dir="$PWD/target/nvrtc"
lib="$dir/nvidia/cu13/lib"
if [ ! -e "$lib/libnvrtc.so.13" ]; then
    mkdir -p "$dir"
    python3 -m pip download --quiet --no-deps --only-binary=:all: \
        --platform manylinux_2_12_x86_64 --python-version 3.12 \
        -d "$dir/wheel" "nvidia-cuda-nvrtc==13.0.88" >&2
    python3 -m zipfile -e "$dir"/wheel/nvidia_cuda_nvrtc-*.whl "$dir" >&2
fi
echo "$lib"
