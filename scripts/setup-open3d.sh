#!/usr/bin/env bash
# Prepares the Python side of scripts/bench_simulation_queries.py: a virtual environment with
# numpy and Open3D (the CPU wheel, open3d-cpu) under target/open3d-venv (target/ is ignored
# by git), and the system library the wheel loads (libusb-1.0, Debian/Ubuntu package
# libusb-1.0-0) when it is missing. Idempotent: a second run checks and changes nothing.
#
#     scripts/setup-open3d.sh            # then:
#     target/open3d-venv/bin/python scripts/bench_simulation_queries.py
#
# Environment: PYTHON (default python3) makes the venv; OPEN3D_VERSION (default 0.20.0) and
# OPEN3D_PACKAGE (default open3d-cpu; open3d is the full wheel) choose the wheel.
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$repo/target/open3d-venv"
python="${PYTHON:-python3}"
version="${OPEN3D_VERSION:-0.20.0}"
package="${OPEN3D_PACKAGE:-open3d-cpu}"

# libusb-1.0: Open3D's wheel links it (for its RealSense support) even on a headless machine.
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1\.0\.so\.0'; then
    if command -v apt-get >/dev/null; then
        sudo_cmd=()
        if [ "$(id -u)" -ne 0 ]; then sudo_cmd=(sudo); fi
        echo "installing libusb-1.0-0 (apt-get)"
        "${sudo_cmd[@]}" apt-get update -qq
        DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq libusb-1.0-0
    else
        echo "libusb-1.0 is missing and apt-get is not available: install libusb-1.0 by hand" >&2
        exit 1
    fi
fi

if [ ! -x "$venv/bin/python" ]; then
    echo "creating $venv"
    mkdir -p "$repo/target"
    "$python" -m venv "$venv"
fi

if ! "$venv/bin/python" - "$version" <<'EOF' 2>/dev/null
import sys
import numpy  # noqa: F401
import open3d
sys.exit(open3d.__version__ != sys.argv[1])
EOF
then
    echo "installing $package==$version and numpy into $venv"
    "$venv/bin/python" -m pip install --quiet "$package==$version" numpy
fi

"$venv/bin/python" -c 'import numpy, open3d; print(f"open3d {open3d.__version__}, numpy {numpy.__version__}:", __import__("sys").executable)'
