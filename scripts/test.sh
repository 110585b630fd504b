#!/usr/bin/env bash
# Install what is missing, build with tests, run the whole test suite.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh --tests
cd build
ctest -j2 --output-on-failure --timeout 1200
