#!/usr/bin/env bash
# Installs the Debian 12 packages flashtwin needs (only the missing ones), then configures and
# builds it in ./build with ccache and -j2. Run as root on a fresh machine, or with sudo.
# Usage: scripts/setup.sh [--tests] [--bench]
set -euo pipefail
cd "$(dirname "$0")/.."

PACKAGES=(build-essential cmake ccache pkg-config git
  libeigen3-dev libnanoflann-dev libyaml-cpp-dev libspdlog-dev nlohmann-json3-dev libcli11-dev
  liburdfdom-dev libassimp-dev libpcl-dev libembree-dev libopenvdb-dev libtbb-dev
  libmujoco-dev libmujoco-samples libosmesa6-dev libstb-dev ffmpeg
  libgtest-dev libgmock-dev libbenchmark-dev)

missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "setup: installing ${#missing[@]} missing package(s): ${missing[*]}"
  SUDO=""
  [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends \
    "${missing[@]}" >/dev/null
fi

# Options given turn targets on; without them the build folder keeps what it had.
OPTS=()
for a in "$@"; do
  case "$a" in
    --tests) OPTS+=(-DFLASHTWIN_BUILD_TESTS=ON) ;;
    --bench) OPTS+=(-DFLASHTWIN_BUILD_BENCH=ON) ;;
    *) echo "setup: unknown option $a (expected --tests or --bench)" >&2; exit 2 ;;
  esac
done

cmake -S . -B build -DCMAKE_BUILD_TYPE=Release "${OPTS[@]}" >/dev/null
cmake --build build -j2
