#!/usr/bin/env bash
# Smoke test of a scaled-out deployment, with the arguments the manifests use (kubernetes/,
# compose.yaml), as plain processes on loopback: a broker, two workers, a batch client; one worker
# is killed while the batch runs; every query must be answered; everything stops cleanly.
#   deploy/smoke.sh BIN_DIR CITY_DIR
# BIN_DIR holds hscloc and hscloc-client; CITY_DIR holds city/ and a trained map/
# (tests/make_trained_city.sh).
set -euo pipefail
bin=$1 dir=$2
work=$(mktemp -d)
front=$((20000 + $$ % 20000)) back=$((front + 1))
pids=()
cleanup() {
  for pid in "${pids[@]}"; do kill -9 "$pid" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT

"$bin/hscloc" serve --broker --bind "tcp://127.0.0.1:$front" --backend "tcp://127.0.0.1:$back" \
  > "$work/broker.log" 2>&1 &
broker=$!
pids+=("$broker")
for n in 1 2; do
  "$bin/hscloc" serve --map "$dir/map" --connect "tcp://127.0.0.1:$back" --workers 1 \
    > "$work/worker$n.log" 2>&1 &
  pids+=("$!")
done
worker1=${pids[1]} worker2=${pids[2]}

client=("$bin/hscloc-client" --server "tcp://127.0.0.1:$front" --timeout-ms 120000 --retries 0)
"${client[@]}" health > /dev/null
echo "smoke: broker and workers up"

queries="$dir/city/queries/day_time_queries_with_intrinsics.txt"
"${client[@]}" batch --queries "$queries" --features "$dir/city/features.h5" \
  --out "$work/submission.txt" --inflight 4 > "$work/batch.log" 2>&1 &
batch=$!
sleep 3
kill -9 "$worker1"
echo "smoke: killed worker 1 during the batch"
wait "$batch" || { cat "$work/batch.log"; echo "smoke: the batch failed" >&2; exit 1; }

expected=$(grep -cv '^\s*\(#\|$\)' "$queries")
answered=$(wc -l < "$work/submission.txt")
failed=$(wc -l < "$work/submission.txt.failures.txt")
echo "smoke: $answered of $expected queries answered, $failed not localized"
[ "$answered" -eq "$expected" ] || { echo "smoke: queries were lost" >&2; exit 1; }
[ "$failed" -eq 0 ] || { cat "$work/submission.txt.failures.txt"; exit 1; }
grep -q "requests go to others" "$work/broker.log" || echo "smoke: (no request was in flight on worker 1)"

kill -TERM "$worker2" "$broker"
wait "$worker2" || { cat "$work/worker2.log"; echo "smoke: worker 2 did not stop cleanly" >&2; exit 1; }
wait "$broker" || { cat "$work/broker.log"; echo "smoke: the broker did not stop cleanly" >&2; exit 1; }
pids=()
echo "smoke: passed"
