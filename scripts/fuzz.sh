#!/usr/bin/env bash
# Fuzzes the interface board's frame decoder with libFuzzer (clang), starting
# from a copy of tests/fuzz/corpus.
#
# Usage: scripts/fuzz.sh [SECONDS] [--merge] [--seeds]
#   SECONDS   how long to fuzz (default 60)
#   --merge   afterwards, merge the inputs that add coverage back into
#             tests/fuzz/corpus (minimised; the seed-* files are kept)
#   --seeds   (re)write the seed-* files of tests/fuzz/corpus and stop
# Exit status: 0 clean; 1 a crash, leak, timeout or out-of-memory (the input
# is saved under the build folder's artifacts/) or a build failure; 77 when
# clang++ is not installed (CTest counts that as skipped).
# Build folder: $PP5_FUZZ_BUILD_DIR, default build-fuzz/ in the checkout.
set -euo pipefail

root=$(cd "$(dirname "$0")/.." && pwd)
secs=60
merge=0
seeds=0
for arg in "$@"; do
  case "$arg" in
    --merge) merge=1 ;;
    --seeds) seeds=1 ;;
    ''|*[!0-9]*) echo "usage: scripts/fuzz.sh [SECONDS] [--merge] [--seeds]" >&2; exit 2 ;;
    *) secs=$arg ;;
  esac
done

cxx=""
for c in "${CLANGXX:-}" clang++ clang++-14; do
  if [ -n "$c" ] && command -v "$c" >/dev/null 2>&1; then cxx=$c; break; fi
done
if [ -z "$cxx" ]; then
  echo "fuzz.sh: clang++ not found; the fuzzer needs clang with libFuzzer (Debian: apt-get install clang libclang-rt-14-dev); skipping" >&2
  exit 77
fi

out=${PP5_FUZZ_BUILD_DIR:-$root/build-fuzz}
mkdir -p "$out"
corpus=$root/tests/fuzz/corpus
srcs=("$root/src/interface_board/wire.cpp" "$root/tests/fuzz/fuzz_decoder.cpp")
deps=("${srcs[@]}" "$root/src/interface_board/wire.hpp" "$root/src/core/error.hpp")
flags=(-std=c++20 -O1 -g -fno-omit-frame-pointer -I "$root/src")

# libFuzzer's runtime ships separately from clang on Debian: check it first.
echo 'extern "C" int LLVMFuzzerTestOneInput(const unsigned char*, unsigned long) { return 0; }' >"$out/probe.cpp"
if ! "$cxx" -fsanitize=fuzzer "$out/probe.cpp" -o "$out/probe" 2>"$out/probe.log"; then
  echo "fuzz.sh: $cxx cannot link -fsanitize=fuzzer: libFuzzer's runtime is missing (Debian: apt-get install libclang-rt-14-dev); see $out/probe.log" >&2
  exit 1
fi

# Rebuilds only when a source is newer than the binary.
stale() {
  local bin=$1 f
  [ -x "$bin" ] || return 0
  for f in "${deps[@]}"; do [ "$f" -nt "$bin" ] && return 0; done
  return 1
}

if [ "$seeds" = 1 ]; then
  gen=$out/fuzz_decoder_seeds
  if stale "$gen"; then
    "$cxx" "${flags[@]}" -DPP5_FUZZ_MAKE_CORPUS -fsanitize=address,undefined "${srcs[@]}" -o "$gen" -lz -lfmt
  fi
  mkdir -p "$corpus"
  rm -f "$corpus"/seed-*
  "$gen" "$corpus"
  echo "fuzz.sh: wrote $(ls "$corpus"/seed-* | wc -l) seeds to $corpus"
  exit 0
fi

bin=$out/fuzz_decoder
if stale "$bin"; then
  echo "fuzz.sh: building $bin with $cxx"
  "$cxx" "${flags[@]}" -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=undefined "${srcs[@]}" -o "$bin" -lz -lfmt
fi

# Fuzz a scratch copy so that a run never edits the committed corpus.
work=$out/corpus
rm -rf "$work" "$out/artifacts"
mkdir -p "$work" "$out/artifacts"
cp "$corpus"/* "$work"/ 2>/dev/null || true
opts=(-rss_limit_mb=512 -timeout=5 -max_len=16384 -error_exitcode=1 -timeout_exitcode=1
      -artifact_prefix="$out/artifacts/")
echo "fuzz.sh: fuzzing for ${secs}s from $(ls "$work" | wc -l) inputs"
set +e
ASAN_OPTIONS=detect_leaks=1 "$bin" "${opts[@]}" -max_total_time="$secs" -print_final_stats=1 "$work" \
  >"$out/fuzz.log" 2>&1
rc=$?
set -e
tail -n 25 "$out/fuzz.log"
if [ "$rc" != 0 ]; then
  echo "fuzz.sh: the fuzzer failed (exit $rc); inputs in $out/artifacts/, log in $out/fuzz.log" >&2
  exit 1
fi

if [ "$merge" = 1 ]; then
  # Start from the seeds, then let libFuzzer add only what brings new coverage.
  merged=$out/merged
  rm -rf "$merged" "$out/rest"
  mkdir -p "$merged" "$out/rest"
  cp "$corpus"/seed-* "$merged"/
  find "$corpus" -maxdepth 1 -type f ! -name 'seed-*' -exec cp {} "$out/rest"/ \;
  if ! "$bin" "${opts[@]}" -merge=1 "$merged" "$out/rest" "$work" >"$out/merge.log" 2>&1; then
    echo "fuzz.sh: merging failed; see $out/merge.log" >&2
    exit 1
  fi
  find "$corpus" -maxdepth 1 -type f ! -name 'seed-*' -delete
  find "$merged" -maxdepth 1 -type f ! -name 'seed-*' -exec cp {} "$corpus"/ \;
  echo "fuzz.sh: corpus now $(ls "$corpus" | wc -l) files, $(du -sk "$corpus" | cut -f1) KiB"
fi
echo "fuzz.sh: no failures in ${secs}s"
