#!/usr/bin/env bash
# Installs Embree 3's C library and headers (Debian/Ubuntu package libembree-dev, with oneTBB)
# for scripts/embree3_bench.c, when they are missing. Run by scripts/bench-vs-embree.sh.
set -euo pipefail

if [ -f /usr/include/embree3/rtcore.h ] && ldconfig -p 2>/dev/null | grep -q 'libembree3\.so\b'; then
    exit 0
fi
if ! command -v apt-get >/dev/null; then
    echo "error: Embree 3 is missing and this system has no apt-get; install Embree 3.x" \
        "(headers in /usr/include/embree3, libembree3.so) by other means" >&2
    exit 1
fi
sudo=""
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null; then sudo="sudo"; else
        echo "error: installing libembree-dev needs root (no sudo here)" >&2
        exit 1
    fi
fi
echo "(installing libembree-dev: Embree 3 from the distribution)" >&2
$sudo apt-get install -y libembree-dev >&2 || {
    $sudo apt-get update >&2
    $sudo apt-get install -y libembree-dev >&2
}
