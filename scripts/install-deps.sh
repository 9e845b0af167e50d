#!/usr/bin/env bash
# Installs the Debian 12 packages hscloc needs, only those missing. Idempotent and quiet; fast
# (no apt at all) when everything is there. Run as root (or with sudo available).
set -euo pipefail

packages=(
  build-essential cmake ninja-build ccache pkg-config git
  libeigen3-dev libopencv-dev libceres-dev libfaiss-dev libtorch-dev
  libzmq3-dev cppzmq-dev libprotobuf-dev protobuf-compiler prometheus-cpp-dev
  libhdf5-dev libsqlite3-dev sqlite3 libssl-dev libcli11-dev libspdlog-dev libfmt-dev nlohmann-json3-dev
  libopenblas0-pthread
  libgtest-dev libgmock-dev libbenchmark-dev python3 python3-yaml prometheus
  python3-zmq python3-protobuf python3-numpy python3-h5py python3-pytest
  colmap
)

missing=()
for package in "${packages[@]}"; do
  status=$(dpkg-query -W -f='${Status}' "$package" 2>/dev/null || true)
  [[ "$status" == "install ok installed" ]] || missing+=("$package")
done

if ((${#missing[@]} == 0)); then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi

sudo=""
if [[ $(id -u) -ne 0 ]]; then
  command -v sudo >/dev/null || { echo "install-deps: run as root (missing: ${missing[*]})" >&2; exit 1; }
  sudo="sudo"
fi

echo "install-deps: installing ${#missing[@]} packages: ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
echo "install-deps: done"
