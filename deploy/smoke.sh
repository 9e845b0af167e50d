#!/usr/bin/env bash
# Smoke test of a scaled-out deployment, with the arguments the manifests use (kubernetes/,
# compose.yaml), as plain processes on loopback: a broker, two workers, a batch client, CURVE
# between all of them (keys from make-keys.sh), each process probed on its own admin endpoint; one
# worker is killed while the batch runs; every query must be answered; the broker's Prometheus
# metrics count them, the joined and the dropped worker (checked with promtool when present);
# everything stops cleanly.
#   deploy/smoke.sh BIN_DIR CITY_DIR
# BIN_DIR holds hscloc and hscloc-client; CITY_DIR holds city/ and a trained map/
# (tests/make_trained_city.sh).
set -euo pipefail
bin=$1 dir=$2
work=$(mktemp -d)
front=$((20000 + $$ % 20000)) back=$((front + 1)) admin=$((front + 2))
pids=()
cleanup() {
  for pid in "${pids[@]}"; do kill -9 "$pid" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT

bash "$(dirname "$0")/make-keys.sh" "$work/keys" "$bin/hscloc" > /dev/null
keys=$work/keys

"$bin/hscloc" serve --broker --bind "tcp://127.0.0.1:$front" --backend "tcp://127.0.0.1:$back" \
  --admin-bind "tcp://127.0.0.1:$admin" --metrics-bind 127.0.0.1:0 \
  --curve-secret-key "$keys/broker.key" --curve-allowed-keys "$keys/clients.txt" \
  --backend-curve-secret-key "$keys/backend.key" --curve-allowed-worker-keys "$keys/workers.txt" \
  > "$work/broker.log" 2>&1 &
broker=$!
pids+=("$broker")
for n in 1 2; do
  "$bin/hscloc" serve --map "$dir/map" --connect "tcp://127.0.0.1:$back" --workers 1 \
    --admin-bind "tcp://127.0.0.1:$((admin + n))" --metrics-bind 127.0.0.1:0 \
    --curve-secret-key "$keys/worker.key" --curve-server-key "$keys/backend.pub" \
    > "$work/worker$n.log" 2>&1 &
  pids+=("$!")
done
worker1=${pids[1]} worker2=${pids[2]}

# The manifests' probes: each process on its own admin endpoint, until it is ready.
probe() {
  local port=$1 tries=600
  until "$bin/hscloc-client" --server "tcp://127.0.0.1:$port" --timeout-ms 2000 --retries 0 \
      health > "$work/probe.log" 2>&1; do
    tries=$((tries - 1))
    [ "$tries" -gt 0 ] || { cat "$work/probe.log"; echo "smoke: port $port never ready" >&2; exit 1; }
    sleep 0.1
  done
  "$bin/hscloc-client" --server "tcp://127.0.0.1:$port" --timeout-ms 2000 --retries 0 \
    health --live > /dev/null
}
for port in $((admin + 1)) $((admin + 2)) "$admin"; do probe "$port"; done

client=("$bin/hscloc-client" --server "tcp://127.0.0.1:$front" --timeout-ms 120000 --retries 0
        --curve-server-key "$keys/broker.pub" --curve-secret-key "$keys/client.key")
"${client[@]}" health > /dev/null
echo "smoke: broker and workers up and ready, CURVE on"
if "$bin/hscloc-client" --server "tcp://127.0.0.1:$front" --timeout-ms 1000 --retries 0 \
    --curve-server-key "$keys/broker.pub" health > /dev/null 2>&1; then
  echo "smoke: a client with a key not on the allow-list was answered" >&2
  exit 1
fi

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

# The broker's metrics, as Prometheus scrapes them (the URL it printed: its port was free).
scrape() {
  local url
  url=$(grep -o 'http://[0-9.:]*/metrics' "$1" | head -1)
  python3 -c 'import sys, urllib.request; sys.stdout.write(urllib.request.urlopen(sys.argv[1]).read().decode())' \
    "$url"
}
sample() { awk -v series="$1" '$1 == series {print $2}' "$work/broker.metrics"; }
for _ in $(seq 100); do
  scrape "$work/broker.log" > "$work/broker.metrics"
  [ "$(sample hscloc_broker_workers_dropped_total)" = 1 ] && break
  sleep 0.1
done
answered_metric=$(sample 'hscloc_broker_requests_total{outcome="answered"}')
echo "smoke: broker metrics: $answered_metric answered, $(sample hscloc_broker_workers_joined_total) workers joined, $(sample hscloc_broker_workers_dropped_total) dropped, $(sample hscloc_broker_requests_retried_total) requests retried"
[ "$(sample hscloc_broker_workers_joined_total)" = 2 ] || { echo "smoke: workers joined miscounted" >&2; exit 1; }
[ "$(sample hscloc_broker_workers_dropped_total)" = 1 ] || { echo "smoke: the killed worker is not counted" >&2; exit 1; }
[ "${answered_metric%.*}" -ge "$expected" ] || { echo "smoke: answered requests miscounted" >&2; exit 1; }
scrape "$work/worker2.log" > "$work/worker2.metrics"
grep -q '^hscloc_requests_total{kind="localize",status="OK"} [1-9]' "$work/worker2.metrics" ||
  { echo "smoke: worker 2 counted no localized request" >&2; exit 1; }
if command -v promtool > /dev/null; then
  for metrics in "$work/broker.metrics" "$work/worker2.metrics"; do
    promtool check metrics < "$metrics" || { echo "smoke: promtool rejects $metrics" >&2; exit 1; }
  done
fi

kill -TERM "$worker2" "$broker"
wait "$worker2" || { cat "$work/worker2.log"; echo "smoke: worker 2 did not stop cleanly" >&2; exit 1; }
wait "$broker" || { cat "$work/broker.log"; echo "smoke: the broker did not stop cleanly" >&2; exit 1; }
pids=()
echo "smoke: passed"
