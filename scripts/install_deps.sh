#!/usr/bin/env bash
# Installs the Debian 12 packages flashtwin needs, only the missing ones, plus any extra
# packages named on the command line (scripts/fuzz.sh adds clang's). Used by scripts/setup.sh
# and scripts/fuzz.sh. Run as root on a fresh machine, or with sudo available.
# Usage: scripts/install_deps.sh [EXTRA_PACKAGE ...]
set -euo pipefail

PACKAGES=(build-essential cmake ccache pkg-config git
  libeigen3-dev libnanoflann-dev libyaml-cpp-dev libspdlog-dev nlohmann-json3-dev libcli11-dev
  liburdfdom-dev libassimp-dev libpcl-dev libembree-dev libopenvdb-dev libtbb-dev
  libmujoco-dev libmujoco-samples libosmesa6-dev libstb-dev zlib1g-dev ffmpeg
  libgtest-dev libgmock-dev libbenchmark-dev
  "$@")

missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
# npm fetches three.js once for the 3D viewer (viewer/package.json). Debian's npm package,
# unless an npm is already there (a Node.js from elsewhere brings its own and conflicts).
command -v npm >/dev/null 2>&1 || missing+=(npm)
if ((${#missing[@]})); then
  echo "install_deps: installing ${#missing[@]} missing package(s): ${missing[*]}"
  SUDO=""
  [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends \
    "${missing[@]}" >/dev/null
fi
