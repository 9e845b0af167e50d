#!/usr/bin/env bash
# The newcomer's first command: install what is missing, build, and run the whole product on the
# embedded default: `hscloc demo` generates a synthetic city, builds and trains its map, serves it
# on loopback, localizes the day and night queries through hscloc-client, and prints the accuracy,
# the ablations and the latency per stage; the HTML report lands in demo-output/report.html.
# Extra arguments go to `hscloc demo` (e.g. --real for the Lund street photos under data/).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
bash scripts/build.sh
"./${HSCLOC_BUILD_DIR:-build}/tools/hscloc" demo --out "${HSCLOC_DEMO_DIR:-demo-output}" "$@"
