#!/usr/bin/env bash
# Installs the Debian 12 packages flashtwin needs (only the missing ones: scripts/install_deps.sh),
# then configures and builds it in ./build with ccache and -j2. Run as root on a fresh machine, or
# with sudo.
# Usage: scripts/setup.sh [--tests] [--bench] [--sanitize]
#   --sanitize builds ./build-asan instead (ASan + UBSan, with tests).
set -euo pipefail
cd "$(dirname "$0")/.."

# ccache hits across clones (CI builds a fresh clone in another folder): paths below the
# project root are hashed relative to it, and -g builds do not hash the working directory.
export CCACHE_BASEDIR="$PWD" CCACHE_NOHASHDIR=1

# Options given turn targets on; without them the build folder keeps what it had.
BUILD=build
OPTS=()
EXTRA=()  # packages only the tests need: Chromium and Firefox (software WebGL on Mesa's EGL) open view3d.html headless
for a in "$@"; do
  case "$a" in
    --tests) OPTS+=(-DFLASHTWIN_BUILD_TESTS=ON); EXTRA=(chromium firefox-esr libegl1 libegl-mesa0 libgl1-mesa-dri) ;;
    --bench) OPTS+=(-DFLASHTWIN_BUILD_BENCH=ON) ;;
    # A build of its own: sanitized objects never mix with the normal build's.
    --sanitize) BUILD=build-asan; OPTS+=(-DFLASHTWIN_BUILD_TESTS=ON -DFLASHTWIN_SANITIZE=ON) ;;
    *) echo "setup: unknown option $a (expected --tests, --bench or --sanitize)" >&2; exit 2 ;;
  esac
done

scripts/install_deps.sh "${EXTRA[@]}"

cmake -S . -B "$BUILD" -DCMAKE_BUILD_TYPE=Release "${OPTS[@]}" >/dev/null
cmake --build "$BUILD" -j2
