#!/usr/bin/env bash
# The CURVE keys of a broker deployment (docs/deploy.md, "Keys"), written to KEYS_DIR:
#   broker.key/.pub   the front's key pair (clients need broker.pub)
#   backend.key/.pub  the back's key pair (workers need backend.pub)
#   worker.key/.pub   the workers' key pair; workers.txt lists worker.pub
#   client.key/.pub   a first client's key pair; clients.txt lists client.pub
#   deploy/make-keys.sh KEYS_DIR [HSCLOC_BINARY]
# Existing key files are kept, so that running it again adds nothing and replaces nothing.
set -euo pipefail
keys=$1 hscloc=${2:-hscloc}
mkdir -p "$keys"
chmod 700 "$keys"
for name in broker backend worker client; do
  [ -f "$keys/$name.key" ] || "$hscloc" keygen --out "$keys/$name" > /dev/null
done
[ -f "$keys/clients.txt" ] || cp "$keys/client.pub" "$keys/clients.txt"
[ -f "$keys/workers.txt" ] || cp "$keys/worker.pub" "$keys/workers.txt"
# Containers read the files as another user; the directory's mode keeps other users out.
chmod 644 "$keys"/*
echo "keys in $keys"
