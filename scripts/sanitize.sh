#!/usr/bin/env bash
# The sanitizer stage of the test command: a clang build with AddressSanitizer
# and UndefinedBehaviorSanitizer (UBSan's float-cast-overflow and the rest of
# what clang checks and GCC does not), in which the bad-input and fault tests
# run, and then every fuzz target for a bounded time (scripts/fuzz.sh).
# Any finding fails the stage.
#
# Usage: scripts/sanitize.sh [FUZZ_SECONDS] [--build-only | --run-only]
#   FUZZ_SECONDS  how long each fuzz target runs (default 10)
#   --build-only  configure and build the sanitized programs and fuzz targets, and stop
#                 (to build ahead of a later --run-only)
#   --run-only    run the tests and fuzz targets of a build made before
# Build folder: $PP5_FUZZ_BUILD_DIR, default build-fuzz/ (shared with scripts/fuzz.sh).
# The command line's refusals run the release build's test_cli ($PP5_TEST_BUILD_DIR,
# default build/) against the sanitized pp5echo: what is checked is pp5echo, and
# the test driver's own sanitized build was the stage's longest step. Without a
# release build, the sanitized test_cli is built here.
# Exit status 77 when clang++ is not installed.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
secs=10 phase=all
for a in "$@"; do
  case "$a" in
    --build-only) phase=build ;;
    --run-only) phase=run ;;
    *[!0-9]*|"") echo "sanitize.sh: unknown argument '$a' (FUZZ_SECONDS, --build-only or --run-only)" >&2; exit 2 ;;
    *) secs=$a ;;
  esac
done
fuzz_targets=(fuzz_decoder fuzz_metaio fuzz_nrrd fuzz_journal fuzz_plus_xml fuzz_toml fuzz_igtl fuzz_igtl_server fuzz_control)

cxx=$(bash "$root/scripts/clang.sh") || exit 77
dir=${PP5_FUZZ_BUILD_DIR:-$root/build-fuzz}
cli_tests=${PP5_TEST_BUILD_DIR:-$root/build}/tests/test_cli
extra=()
[ -x "$cli_tests" ] || { cli_tests=$dir/tests/test_cli; extra=(test_cli); }
jobs=$(nproc 2>/dev/null || echo 2)
start=$(date +%s)

if [ "$phase" != run ]; then
  echo "sanitize.sh: configuring $dir (clang, ASan + UBSan, fuzzer coverage)" >&2
  mkdir -p "$dir"  # the configure log goes inside it, not beside it in the checkout
  cmake -S . -B "$dir" -G Ninja -DCMAKE_CXX_COMPILER="$cxx" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DPP5_FUZZ=ON \
    -DPP5_BUILD_TESTS=ON -DPP5_BUILD_BENCH=OFF -DMPIEXEC_PREFLAGS="--allow-run-as-root;--oversubscribe" >"$dir/configure.log" 2>&1 ||
    { cat "$dir/configure.log" >&2; exit 1; }
  echo "sanitize.sh: building the sanitized pp5echo, tests and fuzz targets with $jobs jobs (several minutes the first time)" >&2
  cmake --build "$dir" -j "$jobs" --target pp5echo test_io test_plus_config test_calibration test_igtl "${extra[@]}" \
    "${fuzz_targets[@]}" >&2
  echo "sanitize.sh: built in $(( $(date +%s) - start )) s" >&2
  if [ "$phase" = build ]; then exit 0; fi
fi

export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
fail=0
# run NAME ASAN_OPTIONS COMMAND...: one sanitized run, its log in $dir/NAME.log.
run() {
  local name=$1 asan=$2
  shift 2
  echo "sanitize.sh: $name" >&2
  if ASAN_OPTIONS="$asan" "$@" >"$dir/$name.log" 2>&1; then
    echo "ok:   $name" >&2
  else
    tail -n 40 "$dir/$name.log" >&2
    echo "FAIL: $name (log: $dir/$name.log)" >&2
    return 1
  fi
}
# The runs side by side, one per core (each is one process and mostly one
# thread), the next starting as soon as one ends; any failure fails the stage
# once all have ended.
pids=()
spawn() { while [ "${#pids[@]}" -ge "$jobs" ]; do reap; done; run "$@" & pids+=($!); }
reap() {  # waits for one run to end and drops it from pids
  local done_pid p rest=()
  wait -n -p done_pid "${pids[@]}" || fail=1
  for p in "${pids[@]}"; do [ "$p" = "$done_pid" ] || rest+=("$p"); done
  pids=("${rest[@]}")
}
wait_all() { while [ "${#pids[@]}" -gt 0 ]; do reap; done; }
t=$dir/tests
# The command line's refusals, through the sanitized pp5echo, first and in two
# halves (GoogleTest's shards). Leaks are not checked in the child processes:
# Open MPI's runtime keeps memory to exit.
for shard in 0 1; do
  PP5_TEST_BINARY="$dir/src/app/pp5echo" GTEST_TOTAL_SHARDS=2 GTEST_SHARD_INDEX=$shard \
    spawn "bad_input_cli_$shard" detect_leaks=0 "$cli_tests" \
    --gtest_filter='*Refuse*:*Bad*:*Special*:*NotUtf8*:*Malformed*:*Invalid*:*Missing*'
done
# Parsers and bad input: sequences, volumes, PLUS configs, calibration, OpenIGTLink.
spawn bad_input_io detect_leaks=1 "$t/test_io"
spawn plus_config detect_leaks=1 "$t/test_plus_config"
spawn calibration detect_leaks=1 "$t/test_calibration"
spawn igtl detect_leaks=1 "$t/test_igtl"
wait_all
# The faults: a killed, a stopped and a corrupt-fed rank, Ctrl-C, a wrong layout;
# after the pool, alone, as its timeouts assume (its cases run side by side
# inside it).
# SIGTERM to mpirun leaves the host odls_base_sigkill_timeout seconds to write
# its outputs before mpirun's SIGKILL; the case gives 5 s, as under CTest (this
# build wrote them in 1.45 s, 2026-12-02).
PP5_MPIRUN_GRACE_S=5 run faults detect_leaks=0 bash tests/mpi/clean_ends.sh "$dir/src/app/pp5echo" "$dir/clean_ends" "$root/../shared/data/plus" || fail=1
# Every fuzz target, for a bounded time.
if ! PP5_FUZZ_BUILD_DIR="$dir" bash scripts/fuzz.sh "$secs"; then fail=1; fi

echo "sanitize.sh: $(( $(date +%s) - start )) s" >&2
if [ "$fail" != 0 ]; then
  echo "sanitize.sh: FAILED" >&2
  exit 1
fi
echo "sanitize.sh: every sanitized test and fuzz target passed" >&2
