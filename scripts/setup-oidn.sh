#!/usr/bin/env bash
# Installs Intel Open Image Denoise (Apache-2.0) from the PyPI wheel `pyoidn` into target/oidn,
# for `oxray render --denoise` and the denoiser's tests: the wheel carries OIDN's shared
# libraries with the trained weights built in (the CPU device with TBB, and the CUDA device).
# Only those are unpacked (not the Python wrapper, nor the SYCL and HIP devices and their
# runtimes). Prints the directory holding libOpenImageDenoise.so.2, for OXRAY_OIDN_LIB or
# LD_LIBRARY_PATH; the renderer also finds it there on its own. Idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
dir="$PWD/target/oidn"
lib="$dir/lib"
if [ ! -e "$lib/libOpenImageDenoise.so.2" ]; then
    mkdir -p "$dir"
    python3 -m pip download --quiet --no-deps --only-binary=:all: \
        --platform manylinux2014_x86_64 --python-version 3.12 \
        -d "$dir/wheel" "pyoidn==2.5.1" >&2
    python3 - "$dir"/wheel/pyoidn-*.whl "$lib" <<'PY' >&2
import os, re, shutil, sys, zipfile
wheel, lib = sys.argv[1], sys.argv[2]
wanted = re.compile(r"pyoidn/oidn/lib/(libOpenImageDenoise(_core|_device_cpu|_device_cuda)?\.so[.0-9]*|libtbb\.so\.12)$")
tmp = lib + ".part"
os.makedirs(tmp, exist_ok=True)
with zipfile.ZipFile(wheel) as z:
    for name in z.namelist():
        if wanted.match(name):
            with z.open(name) as src, open(os.path.join(tmp, os.path.basename(name)), "wb") as dst:
                dst.write(src.read())
# The directory appears whole or not at all, so an interrupted run is redone.
shutil.rmtree(lib, ignore_errors=True)
os.rename(tmp, lib)
PY
    rm -rf "$dir/wheel"
fi
echo "$lib"
