#!/usr/bin/env bash
# Smoke test of a scaled-out deployment, with the arguments the manifests use (kubernetes/,
# compose.yaml), as plain processes on loopback: two brokers, two workers registered with both, a
# batch client given both, CURVE between all of them (keys from make-keys.sh), each process probed
# on its own admin endpoint. Broker A is killed while a first batch runs, then a worker while a
# second one runs; every query must be answered, and both batches must give the same poses; the
# surviving broker's Prometheus metrics count the replies, the joined and the dropped worker
# (checked with promtool when present); everything stops cleanly.
#   deploy/smoke.sh BIN_DIR CITY_DIR
# BIN_DIR holds hscloc and hscloc-client; CITY_DIR holds city/ and a trained map/
# (tests/make_trained_city.sh).
set -euo pipefail
bin=$1 dir=$2
work=$(mktemp -d)
front=$((20000 + $$ % 20000)) back=$((front + 1)) admin=$((front + 2))
front_b=$((front + 5)) back_b=$((front + 6)) admin_b=$((front + 7))
pids=()
cleanup() {
  local status=$?
  for pid in "${pids[@]}"; do kill -9 "$pid" 2>/dev/null || true; done
  if [ "$status" -ne 0 ]; then
    # What each process said last, for the failure's cause.
    for log in "$work"/broker*.log "$work"/worker*.log; do
      [ -f "$log" ] && { echo "== $(basename "$log") (last lines)"; grep -v '\] \[info\] request ' "$log" | tail -n 15; }
    done
  fi
  rm -rf "$work"
}
trap cleanup EXIT

bash "$(dirname "$0")/make-keys.sh" "$work/keys" "$bin/hscloc" > /dev/null
keys=$work/keys

start_broker() {  # FRONT BACK ADMIN LOG
  "$bin/hscloc" serve --broker --bind "tcp://127.0.0.1:$1" --backend "tcp://127.0.0.1:$2" \
    --admin-bind "tcp://127.0.0.1:$3" --metrics-bind 127.0.0.1:0 \
    --curve-secret-key "$keys/broker.key" --curve-allowed-keys "$keys/clients.txt" \
    --backend-curve-secret-key "$keys/backend.key" --curve-allowed-worker-keys "$keys/workers.txt" \
    > "$4" 2>&1 &
  pids+=("$!")
}
start_broker "$front" "$back" "$admin" "$work/broker-a.log"
broker_a=$!
start_broker "$front_b" "$back_b" "$admin_b" "$work/broker.log"
broker=$!
for n in 1 2; do
  "$bin/hscloc" serve --map "$dir/map" --connect "tcp://127.0.0.1:$back" \
    --connect "tcp://127.0.0.1:$back_b" --workers 1 \
    --admin-bind "tcp://127.0.0.1:$((admin + n))" --metrics-bind 127.0.0.1:0 \
    --curve-secret-key "$keys/worker.key" --curve-server-key "$keys/backend.pub" \
    > "$work/worker$n.log" 2>&1 &
  pids+=("$!")
done
worker1=${pids[2]} worker2=${pids[3]}

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
for port in $((admin + 1)) $((admin + 2)) "$admin" "$admin_b"; do probe "$port"; done
# Each broker's Health lists its workers with the map each serves: both workers, on both.
for port in "$admin" "$admin_b"; do
  for _ in $(seq 100); do
    "$bin/hscloc-client" --server "tcp://127.0.0.1:$port" health > "$work/broker-health.txt"
    grep -q "2 workers" "$work/broker-health.txt" && break
    sleep 0.1
  done
  grep -q "2 workers.*2 on map@" "$work/broker-health.txt" ||
    { cat "$work/broker-health.txt"; echo "smoke: a broker does not list both workers" >&2; exit 1; }
done

client=("$bin/hscloc-client" --server "tcp://127.0.0.1:$front" --server "tcp://127.0.0.1:$front_b"
        --timeout-ms 30000 --retries 2
        --curve-server-key "$keys/broker.pub" --curve-secret-key "$keys/client.key")
"${client[@]}" health > /dev/null
echo "smoke: two brokers and two workers up and ready, CURVE on"
if "$bin/hscloc-client" --server "tcp://127.0.0.1:$front" --timeout-ms 1000 --retries 0 \
    --curve-server-key "$keys/broker.pub" health > /dev/null 2>&1; then
  echo "smoke: a client with a key not on the allow-list was answered" >&2
  exit 1
fi

queries=("$dir/city/queries/day_time_queries_with_intrinsics.txt"
         "$dir/city/queries/night_time_queries_with_intrinsics.txt")
expected=$(cat "${queries[@]}" | grep -cv '^\s*\(#\|$\)')
# A batch during which `victim` is killed once a tenth of the queries are answered (the
# submission grows in query order); every query must be answered.
batch_killing() {  # NAME VICTIM_PID WHAT
  "${client[@]}" batch --queries "${queries[@]}" --features "$dir/city/features.h5" \
    --out "$work/$1.txt" --inflight 4 > "$work/$1.log" 2>&1 &
  local batch=$!
  until [ "$(cat "$work/$1.txt" 2>/dev/null | wc -l)" -ge $((expected / 10)) ]; do sleep 0.02; done
  kill -9 "$2"
  echo "smoke: killed $3 during the batch"
  wait "$batch" || { cat "$work/$1.log"; echo "smoke: the batch failed" >&2; exit 1; }
  local answered failed
  answered=$(wc -l < "$work/$1.txt")
  failed=$(wc -l < "$work/$1.txt.failures.txt")
  echo "smoke: $answered of $expected queries answered, $failed not localized"
  [ "$answered" -eq "$expected" ] || { echo "smoke: queries were lost" >&2; exit 1; }
  [ "$failed" -eq 0 ] || { cat "$work/$1.txt.failures.txt"; exit 1; }
}
batch_killing first "$broker_a" "broker A"
batch_killing submission "$worker1" "worker 1"
cmp -s "$work/first.txt" "$work/submission.txt" || { diff "$work/first.txt" "$work/submission.txt" | head -20;
  echo "smoke: the poses differ between the two batches" >&2; exit 1; }
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
