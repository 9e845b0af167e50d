#!/usr/bin/env bash
# The newcomer's first command: install what is missing, build, and run the main job on the
# embedded default (a synthetic city): generate it, build its map, and inspect the map.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh
hscloc=./"${HSCLOC_BUILD_DIR:-build}"/tools/hscloc
work=${HSCLOC_DEMO_DIR:-demo-output}
mkdir -p "$work"
"$hscloc" --help
"$hscloc" synth --preset small --out "$work/city" --overwrite
"$hscloc" build-map --model "$work/city/map" --features "$work/city/features.h5" --out "$work/map"
"$hscloc" inspect "$work/map"
