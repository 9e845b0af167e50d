#!/usr/bin/env bash
# The newcomer's first command: install what is missing, build, and run the main job.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh
./"${HSCLOC_BUILD_DIR:-build}"/tools/hscloc --help
