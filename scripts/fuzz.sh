#!/usr/bin/env bash
# Builds the libFuzzer harnesses of fuzz/ (clang, ASan + UBSan) in ./build-fuzz and runs each
# for a given time on a working copy of its corpus. See fuzz/README.md and --help.
set -euo pipefail
cd "$(dirname "$0")/.."

ALL=(scenario robot ply pcd stl obj paths_json pose_json)
# Largest input per harness [bytes]: a few times the largest seed, so that runs test the
# readers rather than the allocator.
declare -A MAX_LEN=([scenario]=8192 [robot]=8192 [ply]=8192 [pcd]=8192 [stl]=8192 [obj]=8192
                    [paths_json]=8192 [pose_json]=4096)

usage() {
  cat <<'EOF'
Usage: scripts/fuzz.sh [--time SECONDS] [--jobs N] [NAME ...] [-- LIBFUZZER_FLAG ...]

Builds the libFuzzer harnesses fuzz/fuzz_NAME.cpp with clang, AddressSanitizer and
UndefinedBehaviorSanitizer in ./build-fuzz (installing clang, libclang-rt-14-dev and the
packages of scripts/install_deps.sh when missing), then runs each named harness for SECONDS
on fuzz-out/NAME/corpus: a working copy of the committed seeds fuzz/corpus/NAME/ that keeps
what earlier runs found (the committed corpus is never written), with fuzz/NAME.dict.

Harnesses (default: all): scenario robot ply pcd stl obj paths_json pose_json

  --time SECONDS   fuzzing time of each harness (default 600)
  --jobs N         run up to N harnesses at the same time, one core each (default 1)
  -- FLAG ...      extra libFuzzer flags for every harness, e.g. -- -fork=2 -ignore_crashes=1
  -h, --help       this text

Prints one line per harness: executions, executions per second, coverage (cov: and ft: of
libFuzzer's last stats line) and whether it found something. A finding is a crash, a
sanitizer report, a leak, an input slower than 10 s (-timeout=10), more than 2 GB of memory
(-rss_limit_mb=2048) or an exception other than flashtwin::InputError escaping a reader.
Its input is saved as fuzz-out/NAME/crash-* (or leak-*, timeout-*, oom-*), the whole log is
fuzz-out/NAME/fuzz.log, and the script exits 1 naming the file. Reproduce a finding with
  build-fuzz/fuzz/fuzz_NAME fuzz-out/NAME/crash-...
EOF
}

TIME=600
JOBS=1
NAMES=()
EXTRA=()
while (($#)); do
  case "$1" in
    -h | --help) usage; exit 0 ;;
    --time) TIME="${2:-}"; shift 2 || { echo "fuzz: --time needs a value" >&2; exit 2; } ;;
    --time=*) TIME="${1#*=}"; shift ;;
    --jobs) JOBS="${2:-}"; shift 2 || { echo "fuzz: --jobs needs a value" >&2; exit 2; } ;;
    --jobs=*) JOBS="${1#*=}"; shift ;;
    --) shift; EXTRA=("$@"); break ;;
    -*) echo "fuzz: unknown option $1 (see --help)" >&2; exit 2 ;;
    *)
      [[ " ${ALL[*]} " == *" $1 "* ]] || {
        echo "fuzz: unknown harness '$1' (expected one of: ${ALL[*]})" >&2
        exit 2
      }
      NAMES+=("$1")
      shift
      ;;
  esac
done
[[ "$TIME" =~ ^[1-9][0-9]*$ ]] || { echo "fuzz: --time: expected seconds > 0, got '$TIME'" >&2; exit 2; }
[[ "$JOBS" =~ ^[1-9][0-9]*$ ]] || { echo "fuzz: --jobs: expected a count > 0, got '$JOBS'" >&2; exit 2; }
((${#NAMES[@]})) || NAMES=("${ALL[@]}")

# clang 14 with its libFuzzer/sanitizer runtimes and OpenMP, llvm-symbolizer for readable stacks.
scripts/install_deps.sh clang libclang-rt-14-dev libomp-14-dev llvm-14

# ccache hits across clones (CI builds a fresh clone in another folder): paths below the
# project root are hashed relative to it, and -g builds do not hash the working directory.
export CCACHE_BASEDIR="$PWD" CCACHE_NOHASHDIR=1

# CC/CXX matter on the first configure only; the option check rejects any other compiler.
CC=clang CXX=clang++ cmake -S . -B build-fuzz -DFLASHTWIN_BUILD_FUZZ=ON \
  -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null
TARGETS=()
for n in "${NAMES[@]}"; do TARGETS+=("fuzz_$n"); done
cmake --build build-fuzz -j2 --target "${TARGETS[@]}"

export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}"
# The same list of third-party leaks as scripts/test.sh --sanitize (nothing of ours in it).
if [ -z "${LSAN_OPTIONS:-}" ] && [ -f scripts/sanitizers/lsan.supp ]; then
  export LSAN_OPTIONS="suppressions=$PWD/scripts/sanitizers/lsan.supp:print_suppressions=0"
fi
if [ -z "${ASAN_SYMBOLIZER_PATH:-}" ] && [ -x /usr/lib/llvm-14/bin/llvm-symbolizer ]; then
  export ASAN_SYMBOLIZER_PATH=/usr/lib/llvm-14/bin/llvm-symbolizer
fi

# Runs harness $1; its log goes to fuzz-out/$1/fuzz.log, its exit code to fuzz-out/$1/rc.
run_one() {
  local n="$1" out="fuzz-out/$1"
  mkdir -p "$out/corpus"
  rm -f "$out/rc"
  local f
  for f in fuzz/corpus/"$n"/*; do
    [ -e "$out/corpus/${f##*/}" ] || cp "$f" "$out/corpus/"
  done
  local dict=()
  [ -f "fuzz/$n.dict" ] && dict=("-dict=fuzz/$n.dict")
  local rc=0
  "build-fuzz/fuzz/fuzz_$n" "$out/corpus" -max_total_time="$TIME" -timeout=10 \
    -rss_limit_mb=2048 -max_len="${MAX_LEN[$n]}" "${dict[@]}" -artifact_prefix="$out/" \
    -print_final_stats=1 "${EXTRA[@]}" >"$out/fuzz.log" 2>&1 || rc=$?
  echo "$rc" >"$out/rc"
}

# Last value of a libFuzzer stats field ("cov: 12", or "exec/s 34" in fork mode) in a log.
last_field() {
  local v
  v=$(grep -oE "(^|[[:space:]])$2:? [0-9]+" "$1" | tail -n 1 | grep -oE '[0-9]+$' || true)
  echo "${v:-?}"
}

# One line on what a failed run found, from its log.
finding() {
  local log="$1" what
  what=$(grep -m 1 -oE "terminate called after throwing an instance of '[^']*'" "$log" |
         sed -E "s/.*instance of /uncaught exception /" || true)
  [ -n "$what" ] || what=$(grep -m 1 -oE "ERROR: AddressSanitizer: [a-z-]+( on [a-z]+ address)?" "$log" |
                           sed 's/ERROR: //' || true)
  [ -n "$what" ] || what=$(grep -m 1 -oE "runtime error: .{0,80}" "$log" | sed 's/^/UBSan /' || true)
  [ -n "$what" ] || what=$(grep -m 1 -oE "ERROR: LeakSanitizer: [a-z ]+" "$log" | sed 's/ERROR: //' || true)
  [ -n "$what" ] || what=$(grep -m 1 -oE "ERROR: libFuzzer: [a-z -]+" "$log" | sed 's/ERROR: //' || true)
  echo "${what:-exited with code $(cat "${log%/*}/rc" 2>/dev/null || echo '?')}"
}

echo "fuzz: ${#NAMES[@]} harness(es), ${TIME} s each, ${JOBS} at a time; logs in fuzz-out/NAME/fuzz.log"
for n in "${NAMES[@]}"; do
  while (($(jobs -rp | wc -l) >= JOBS)); do wait -n || true; done
  run_one "$n" &
done
wait

failed=0
for n in "${NAMES[@]}"; do
  out="fuzz-out/$n" log="fuzz-out/$n/fuzz.log"
  rc=$(cat "$out/rc" 2>/dev/null || echo "?")
  if [ ! -s "$log" ]; then
    failed=1
    printf '%-11s did not run (no %s)\n' "$n" "$log"
    continue
  fi
  execs=$(grep -oE 'stat::number_of_executed_units: [0-9]+' "$log" | grep -oE '[0-9]+$' || true)
  [ -n "$execs" ] || execs=$(grep -oE '^#[0-9]+' "$log" | tail -n 1 | tr -d '#' || true)
  rate=$(grep -oE 'stat::average_exec_per_sec: [0-9]+' "$log" | grep -oE '[0-9]+$' || true)
  [ -n "$rate" ] || rate=$(last_field "$log" "exec/s")
  cov=$(last_field "$log" "cov")
  ft=$(last_field "$log" "ft")
  if [ "$rc" = 0 ]; then
    result="no crash"
  else
    failed=1
    artifact=$(grep -oE 'Test unit written to [^ ]+' "$log" | tail -n 1 | sed 's/Test unit written to //' || true)
    result="CRASH: $(finding "$log")${artifact:+ -> $artifact}"
  fi
  printf '%-11s %11s execs %7s exec/s  cov: %-6s ft: %-7s %s\n' "$n" "${execs:-?}" "${rate:-?}" \
    "$cov" "$ft" "$result"
done
if ((failed)); then
  echo "fuzz: findings above; reproduce with build-fuzz/fuzz/fuzz_NAME ARTIFACT (logs: fuzz-out/NAME/fuzz.log)" >&2
  exit 1
fi
