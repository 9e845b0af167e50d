#!/usr/bin/env bash
# Rolls a map update over the workers, one at a time, while traffic flows:
#   deploy/roll-map.sh [--client HSCLOC_CLIENT] ADMIN_ENDPOINT...
#   deploy/roll-map.sh --kubernetes [LABEL_SELECTOR]     (default app=hscloc,role=worker)
# First put the new map where every worker's --map points, atomically (e.g. a link turned with
# `ln -sfn maps/v2 maps/city.next && mv -T maps/city.next maps/city`). Then each worker in turn
# reloads on its admin endpoint: its reply comes once the new map is loaded and verified, and the
# worker swaps maps between two requests, so no request fails and every reply names the map that
# made it (LocalizeResponse.map_id). The roll stops at the first worker whose reload fails (that
# worker keeps its old map) or whose Health does not name the new map, and exits non-zero.
# With --kubernetes each worker pod's own loopback admin endpoint is reached with kubectl exec.
set -euo pipefail
client=hscloc-client
if [ "${1:-}" = "--client" ]; then client=$2; shift 2; fi
targets=()
kubernetes=false
if [ "${1:-}" = "--kubernetes" ]; then
  kubernetes=true
  mapfile -t targets < <(kubectl get pods -l "${2:-app=hscloc,role=worker}" -o name)
else
  targets=("$@")
fi
[ "${#targets[@]}" -gt 0 ] || { echo "roll-map: no worker given" >&2; exit 2; }

ask() {  # TARGET ARGS...: hscloc-client on the target's admin endpoint
  local target=$1
  shift
  if $kubernetes; then
    kubectl exec "$target" -- hscloc-client --server tcp://127.0.0.1:5557 --retries 0 "$@"
  else
    "$client" --server "$target" --retries 0 "$@"
  fi
}

map_id=""
for target in "${targets[@]}"; do
  if ! reply=$(ask "$target" --timeout-ms 600000 reload 2>&1); then
    echo "roll-map: $target: the reload failed, it keeps its map; the roll stops here" >&2
    echo "$reply" >&2
    exit 1
  fi
  health=$(ask "$target" --timeout-ms 10000 health)
  served=$(sed -n 's/^[A-Z_]* map \([^ ]*\) .*/\1/p' <<< "$health")
  if [ -z "$map_id" ]; then map_id=$served; fi
  if [ -z "$served" ] || [ "$served" != "$map_id" ]; then
    echo "roll-map: $target serves '$served' after its reload, the workers before it '$map_id';" \
      "the roll stops here" >&2
    exit 1
  fi
  echo "roll-map: $target serves $served"
done
echo "roll-map: ${#targets[@]} workers serve $map_id"
