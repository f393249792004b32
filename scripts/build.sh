#!/usr/bin/env bash
# Configures and builds pp5echo with CMake and Ninja.
# Usage: scripts/build.sh [--asan] [--debug]
#   --asan   Debug build with AddressSanitizer + UndefinedBehaviorSanitizer in build-asan/
#   --debug  plain Debug build in build-debug/
# Shows the configure and build progress on stderr, so that a caller that
# captures stdout still shows it; prints the build folder as its last line on
# stdout.
set -euo pipefail
cd "$(dirname "$0")/.."

type=Release dir=build sanitize=OFF
for a in "$@"; do
  case "$a" in
    --asan) type=Debug dir=build-asan sanitize=ON ;;
    --debug) type=Debug dir=build-debug ;;
    *) echo "build.sh: unknown option '$a' (use --asan or --debug)" >&2; exit 2 ;;
  esac
done

jobs=$(nproc 2>/dev/null || echo 2)
echo "build.sh: configuring $dir ($type build)" >&2
cmake -S . -B "$dir" -G Ninja -DCMAKE_BUILD_TYPE="$type" -DPP5_SANITIZE="$sanitize" \
  -DMPIEXEC_PREFLAGS="--allow-run-as-root;--oversubscribe" >&2
echo "build.sh: building $dir with $jobs jobs (a few minutes the first time; [done/total] below)" >&2
cmake --build "$dir" -j "$jobs" >&2
echo "build.sh: built $dir" >&2
echo "$dir"
