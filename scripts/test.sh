#!/usr/bin/env bash
# The test command: installs what is missing, builds, and runs every test.
# Usage: scripts/test.sh [--asan]   (--asan: CTest in the GCC sanitizer build, ASan + UBSan)
# The sanitizer stage (scripts/sanitize.sh) builds with clang, ASan and UBSan,
# runs the bad-input and fault tests there and every fuzz target for a bounded
# time (PP5_SKIP_SANITIZE=1 leaves that stage out, for a quick local run). Its
# build runs while CTest does, at the lowest CPU priority (nice 19), so it only
# takes the cores the tests leave idle (paced runs, browsers, waits) and the
# tests keep the machine as if it were not there.
set -euo pipefail
cd "$(dirname "$0")/.."

t0=$(date +%s)
bash scripts/install-deps.sh
dir=$(bash scripts/build.sh "$@" | tail -n 1)
t1=$(date +%s)
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
# Every ASan, LSan and UBSan finding fails the test.
export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1}" UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}"
sanitize=0
if [ "${PP5_SKIP_SANITIZE:-0}" != 1 ]; then
  if bash scripts/clang.sh >/dev/null 2>&1; then
    sanitize=1
    mkdir -p build-fuzz
    echo "test.sh: building the sanitizer stage in the background at nice 19 while CTest runs (log: build-fuzz/background.log)" >&2
    # Its own process group, so that a failed or interrupted run ends it whole.
    setsid nice -n 19 bash scripts/sanitize.sh --build-only >build-fuzz/background.log 2>&1 &
    builder=$!
    trap 'kill -- "-$builder" 2>/dev/null || true' EXIT
  else
    echo "test.sh: no clang++; the sanitizer stage was skipped" >&2
  fi
fi
rc=0
ctest --test-dir "$dir" --output-on-failure -j "$(nproc 2>/dev/null || echo 2)" || rc=$?
[ "$rc" = 0 ] || exit "$rc"
t2=$(date +%s)
if [ "$sanitize" = 1 ]; then
  # The rest of the build at full speed now, its progress every 20 s.
  renice -n 0 -g "$builder" >/dev/null 2>&1 || true
  n=0
  while kill -0 "$builder" 2>/dev/null; do
    [ $((n % 10)) = 0 ] && echo "test.sh: the sanitizer stage's build: $(grep -o '^\[[0-9]*/[0-9]*\]' build-fuzz/background.log | tail -n 1)" >&2
    n=$((n + 1))
    sleep 2
  done
  brc=0
  wait "$builder" || brc=$?
  trap - EXIT
  if [ "$brc" != 0 ]; then
    tail -n 40 build-fuzz/background.log >&2
    echo "test.sh: the sanitizer stage's build failed (log: build-fuzz/background.log)" >&2
    exit 1
  fi
  bash scripts/sanitize.sh "${PP5_FUZZ_SECONDS:-10}" --run-only
fi
t3=$(date +%s)
echo "test.sh: every test passed in $((t3 - t0)) s: install and build $((t1 - t0)) s, CTest $((t2 - t1)) s, the rest of the sanitizer stage $((t3 - t2)) s" >&2
