#!/usr/bin/env bash
# Installs what scripts/bench_vs_mitsuba.py needs: Mitsuba 3 and Dr.Jit (pinned, with NumPy and
# Pillow) in a virtual environment at target/mitsuba-venv, and the libLLVM that Dr.Jit's LLVM backend (the
# llvm_ad_rgb variant) loads at run time. Dr.Jit dlopen()s libLLVM itself: it looks for
# /usr/lib/x86_64-linux-gnu/libLLVM*.so.* unless DRJIT_LIBLLVM_PATH names the library. This
# script installs Debian's libllvm19 (with apt-get, as root, when it is missing) and pins that
# library through DRJIT_LIBLLVM_PATH, so the version does not depend on which other LLVMs the
# machine has. Idempotent and quiet; checks that llvm_ad_rgb really renders.
#
# Usage: scripts/setup-mitsuba.sh
# Prints two lines for the benchmark: the venv's python, and DRJIT_LIBLLVM_PATH=<library>.
# With OXRAY_MITSUBA_LLVM=none it skips libLLVM and the benchmark falls back to scalar_rgb.
set -euo pipefail
cd "$(dirname "$0")/.."
MITSUBA_VERSION=3.9.1
DRJIT_VERSION=1.5.0
LLVM_MAJOR=19
venv="$PWD/target/mitsuba-venv"
py="$venv/bin/python"

if ! "$py" -c "import mitsuba, drjit, numpy, PIL; assert mitsuba.__version__ == '$MITSUBA_VERSION' and drjit.__version__ == '$DRJIT_VERSION'" 2>/dev/null; then
    python3.11 -m venv "$venv" >&2 || python3 -m venv "$venv" >&2
    "$py" -m pip install --quiet --disable-pip-version-check \
        "mitsuba==$MITSUBA_VERSION" "drjit==$DRJIT_VERSION" "numpy>=1.26,<3" "pillow==11.3.0" >&2
fi

lib=""
if [ "${OXRAY_MITSUBA_LLVM:-}" != none ]; then
    lib="/usr/lib/x86_64-linux-gnu/libLLVM-$LLVM_MAJOR.so"
    if [ ! -e "$lib" ]; then
        if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
            DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "libllvm$LLVM_MAJOR" >&2 ||
                { apt-get update -qq >&2 && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "libllvm$LLVM_MAJOR" >&2; }
        else
            echo "setup-mitsuba: $lib is missing: install Debian's libllvm$LLVM_MAJOR (as root)" >&2
            exit 1
        fi
    fi
    # The check: a tiny scene rendered by the LLVM variant.
    if ! DRJIT_LIBLLVM_PATH="$lib" "$py" - <<'PY' >&2; then
import mitsuba as mi
mi.set_variant("llvm_ad_rgb")
scene = mi.load_dict({"type": "scene", "s": {"type": "sphere"},
                      "e": {"type": "constant"}, "integrator": {"type": "path"},
                      "sensor": {"type": "perspective",
                                 "film": {"type": "hdrfilm", "width": 8, "height": 8}}})
image = mi.render(scene, spp=4)
assert image.shape == (8, 8, 3), image.shape
PY
        echo "setup-mitsuba: the llvm_ad_rgb variant does not run with $lib" >&2
        exit 1
    fi
fi
echo "$py"
echo "DRJIT_LIBLLVM_PATH=$lib"
