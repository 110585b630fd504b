#!/usr/bin/env bash
# Install what is missing, build with tests, run the whole test suite.
# Usage: scripts/test.sh [--sanitize]
#   (no option)  ./build: every test, the scenario regression (ctest -L scenario) included
#   --sanitize   ./build-asan with AddressSanitizer + UndefinedBehaviorSanitizer: the unit and
#                CLI tests (not the scenario regression nor the whole-pass `pipeline` tests,
#                which that build does not compile);
#                any leak, memory error or undefined behaviour fails the test that caused it
set -euo pipefail
cd "$(dirname "$0")/.."

case "${1:-}" in
  "")
    scripts/setup.sh --tests
    cd build
    ctest -j2 --output-on-failure --timeout 1200
    ;;
  --sanitize)
    scripts/setup.sh --sanitize
    # Leaks inside third-party libraries that this project cannot free are listed, each with
    # its reason, in scripts/sanitizers/lsan.supp; nothing of flashtwin's own is suppressed.
    export ASAN_OPTIONS="detect_leaks=1:strict_string_checks=1:detect_stack_use_after_return=1:check_initialization_order=1:strict_init_order=1"
    export LSAN_OPTIONS="suppressions=$PWD/scripts/sanitizers/lsan.supp:print_suppressions=0"
    export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
    cd build-asan
    ctest -j2 --output-on-failure --timeout 1800 -LE "scenario|pipeline"
    ;;
  -h|--help)
    sed -n '2,8p' "$0" | sed 's/^# \{0,1\}//'
    ;;
  *)
    echo "test.sh: unknown option $1 (expected --sanitize or nothing; --help explains)" >&2
    exit 2
    ;;
esac
