#!/usr/bin/env bash
# Makes a synthetic city, builds its map and trains its network with the command-line tool, as a
# user would: make_trained_city.sh HSCLOC PRESET OUT_DIR ITERATIONS
# OUT_DIR/city holds the city (COLMAP model, features, queries), OUT_DIR/map the trained bundle.
# The test suite runs it once as a fixture; tests that need a trained map share its output.
# Augmentation noise of norm 0.8 matches the synthetic night's descriptor noise: the map serves
# night queries too (docs/decisions.md).
set -euo pipefail
hscloc=$1 preset=$2 out=$3 iterations=$4
rm -rf "$out"
mkdir -p "$out"
"$hscloc" synth --preset "$preset" --out "$out/city" --overwrite
"$hscloc" build-map --model "$out/city/map" --features "$out/city/features.h5" --out "$out/map"
"$hscloc" train --map "$out/map" --iterations "$iterations" --noise-norm 0.8 --eval \
  --log-every 100
