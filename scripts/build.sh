#!/usr/bin/env bash
# Configures and builds pp5echo with CMake and Ninja.
# Usage: scripts/build.sh [--asan] [--debug] [--only pp5echo]
#   --asan          Debug build with AddressSanitizer + UndefinedBehaviorSanitizer in build-asan/
#   --debug         plain Debug build in build-debug/
#   --only TARGET   build that target alone (scripts/main.sh: pp5echo, without the
#                   tests and benchmarks: 114 of 178 steps; main.sh took 227 s from a
#                   fresh clone on a 2-core machine, build and run, 2026-12-04)
# Shows the configure and build progress on stderr, so that a caller that
# captures stdout still shows it; prints the build folder as its last line on
# stdout.
set -euo pipefail
cd "$(dirname "$0")/.."

type=Release dir=build sanitize=OFF
only=""
while [ $# -gt 0 ]; do
  case "$1" in
    --asan) type=Debug dir=build-asan sanitize=ON ;;
    --debug) type=Debug dir=build-debug ;;
    --only)
      [ $# -ge 2 ] || { echo "build.sh: --only needs a target (e.g. pp5echo)" >&2; exit 2; }
      only=$2
      shift ;;
    *) echo "build.sh: unknown option '$1' (use --asan, --debug or --only TARGET)" >&2; exit 2 ;;
  esac
  shift
done

jobs=$(nproc 2>/dev/null || echo 2)
echo "build.sh: configuring $dir ($type build)" >&2
cmake -S . -B "$dir" -G Ninja -DCMAKE_BUILD_TYPE="$type" -DPP5_SANITIZE="$sanitize" \
  -DMPIEXEC_PREFLAGS="--allow-run-as-root;--oversubscribe" >&2
echo "build.sh: building ${only:-everything} in $dir with $jobs jobs (a few minutes the first time; [done/total] below)" >&2
cmake --build "$dir" -j "$jobs" ${only:+--target "$only"} >&2
echo "build.sh: built $dir" >&2
echo "$dir"
