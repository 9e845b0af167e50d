#!/usr/bin/env bash
# Configures and builds hscloc (Release, Ninja, ccache when present) into ${HSCLOC_BUILD_DIR:-build}.
# Extra arguments go to cmake's configure step, e.g. -DHSCLOC_SANITIZE=ON.
set -euo pipefail
cd "$(dirname "$0")/.."
build_dir=${HSCLOC_BUILD_DIR:-build}
cmake -S . -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=Release "$@" >/dev/null
# Each libtorch translation unit needs over 1 GiB to compile: one job per core.
ninja -C "$build_dir" -j "$(nproc)"
