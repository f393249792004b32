#!/usr/bin/env bash
# Fuzzes pp5echo's parsers with libFuzzer (clang, with ASan and UBSan):
#   decoder  the interface board's frame decoder (corpus: tests/fuzz/corpus)
#   metaio   a MetaIO file read as a sequence and as a volume
#   nrrd     the same for NRRD
#   journal  a cut-off recording's journal (formats/recording_journal.hpp)
#   plus_xml a PLUS device-set config (coordinates, reconstruction, phantom, segmentation)
#   toml     a TOML settings file with every section pp5echo registers
#   igtl     an OpenIGTLink stream decoded by the live source's client
#   igtl_server  a client's stream read by the OpenIGTLink server (run.igtl_serve), commands parsed
#   control  the live viewer's control messages
# The parsers' corpora are made from ../shared/data/plus, configs/ and packed
# seed messages each time, in the build folder; only the decoder's is committed.
#
# Usage: scripts/fuzz.sh [SECONDS] [--only NAME[,NAME...]] [--merge] [--seeds]
#   SECONDS   how long to fuzz each target (default 60)
#   --only    these targets (default: all eight)
#   --merge   afterwards, merge the decoder's inputs that add coverage back into
#             tests/fuzz/corpus (minimised; the seed-* files are kept)
#   --seeds   (re)write the seed-* files of tests/fuzz/corpus and stop
# Exit status: 0 clean; 1 a crash, leak, timeout or out-of-memory (the input
# is saved under the build folder's artifacts-NAME/) or a build failure; 77
# when clang++ is not installed (CTest counts that as skipped).
# Build folder: $PP5_FUZZ_BUILD_DIR, default build-fuzz/ in the checkout.
set -euo pipefail

root=$(cd "$(dirname "$0")/.." && pwd)
secs=60
merge=0
seeds=0
only="decoder,metaio,nrrd,journal,plus_xml,toml,igtl,igtl_server,control"
while [ $# -gt 0 ]; do
  case "$1" in
    --merge) merge=1 ;;
    --seeds) seeds=1 ;;
    --only) shift; only=${1:?--only needs target names} ;;
    ''|*[!0-9]*) echo "usage: scripts/fuzz.sh [SECONDS] [--only NAME[,NAME...]] [--merge] [--seeds]" >&2; exit 2 ;;
    *) secs=$1 ;;
  esac
  shift
done

cxx=$(bash "$root/scripts/clang.sh") || exit 77

out=${PP5_FUZZ_BUILD_DIR:-$root/build-fuzz}
mkdir -p "$out"

# libFuzzer's runtime ships separately from clang on Debian: check it first.
echo 'extern "C" int LLVMFuzzerTestOneInput(const unsigned char*, unsigned long) { return 0; }' >"$out/probe.cpp"
if ! "$cxx" -fsanitize=fuzzer "$out/probe.cpp" -o "$out/probe" 2>"$out/probe.log"; then
  echo "fuzz.sh: $cxx cannot link -fsanitize=fuzzer: libFuzzer's runtime is missing (Debian: apt-get install libclang-rt-14-dev); see $out/probe.log" >&2
  exit 1
fi

IFS=, read -r -a names <<<"$only"
targets=()
for n in "${names[@]}"; do
  case "$n" in
    decoder|metaio|nrrd|journal|plus_xml|toml|igtl|igtl_server|control) targets+=("fuzz_$n") ;;
    *) echo "fuzz.sh: unknown target '$n' (decoder, metaio, nrrd, journal, plus_xml, toml, igtl, igtl_server, control)" >&2; exit 2 ;;
  esac
done
[ "$seeds" = 1 ] && targets=(fuzz_decoder_seeds)

# Every library is built with the fuzzer's coverage and the sanitizers
# (PP5_FUZZ in CMakeLists.txt); ninja rebuilds only what changed.
gen=()
command -v ninja >/dev/null 2>&1 && gen=(-G Ninja)
if [ ! -f "$out/CMakeCache.txt" ]; then
  echo "fuzz.sh: configuring $out with $cxx"
  cmake -S "$root" -B "$out" "${gen[@]}" -DCMAKE_CXX_COMPILER="$cxx" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DPP5_FUZZ=ON -DPP5_BUILD_TESTS=OFF -DPP5_BUILD_BENCH=OFF >"$out/configure.log" 2>&1 ||
    { echo "fuzz.sh: configuring failed; see $out/configure.log" >&2; exit 1; }
fi
echo "fuzz.sh: building ${targets[*]} in $out"
cmake --build "$out" --target "${targets[@]}" -- >"$out/build.log" 2>&1 ||
  { tail -n 30 "$out/build.log" >&2; echo "fuzz.sh: the build failed; see $out/build.log" >&2; exit 1; }
bindir=$out/tests/fuzz

if [ "$seeds" = 1 ]; then
  corpus=$root/tests/fuzz/corpus
  mkdir -p "$corpus"
  rm -f "$corpus"/seed-*
  "$bindir/fuzz_decoder_seeds" "$corpus"
  echo "fuzz.sh: wrote $(ls "$corpus"/seed-* | wc -l) seeds to $corpus"
  exit 0
fi

data=$root/../shared/data/plus
# The starting inputs of one target, in $2.
make_corpus() {
  local t=$1 dir=$2 f
  rm -rf "$dir"
  mkdir -p "$dir"
  case "$t" in
    fuzz_decoder) cp "$root"/tests/fuzz/corpus/* "$dir"/ 2>/dev/null || true ;;
    fuzz_metaio|fuzz_nrrd)
      local ext=mha
      [ "$t" = fuzz_nrrd ] && ext=nrrd
      for f in "$data"/*."$ext"; do
        [ -f "$f" ] || continue
        # Headers with the first 4 KiB of data: every header field, short data.
        python3 - "$f" "$dir/$(basename "$f")" <<'PY'
import sys
raw = open(sys.argv[1], "rb").read()
for mark in (b"ElementDataFile = LOCAL\n", b"\n\n"):
    i = raw.find(mark)
    if i >= 0:
        raw = raw[: i + len(mark) + 4096]
        break
open(sys.argv[2], "wb").write(raw[:65536])
PY
      done ;;
    fuzz_plus_xml) cp "$data"/*.xml "$dir"/ 2>/dev/null || true ;;
    fuzz_toml)
      cp "$root"/configs/*.toml "$root"/tests/configs/*.toml "$dir"/ 2>/dev/null || true ;;
    fuzz_igtl|fuzz_igtl_server|fuzz_control|fuzz_journal) PP5_FUZZ_SEEDS_DIR="$dir" "$bindir/$t" ;;
  esac
}

# One target: its corpus, then libFuzzer for $secs seconds; the exit status in $out/$t.rc.
fuzz_one() {
  local t=$1 work=$out/corpus-$1 art=$out/artifacts-$1 rc
  rm -f "$out/$t.log"
  if ! make_corpus "$t" "$work" >"$out/$t.log" 2>&1; then
    echo "fuzz.sh: making $t's starting inputs failed" >>"$out/$t.log"
    echo 1 >"$out/$t.rc"
    return 0
  fi
  rm -rf "$art"
  mkdir -p "$art"
  set +e
  ASAN_OPTIONS=detect_leaks=1 "$bindir/$t" "${opts[@]}" -artifact_prefix="$art/" -max_total_time="$secs" \
    -print_final_stats=1 "$work" >>"$out/$t.log" 2>&1
  rc=$?
  set -e
  echo "$rc" >"$out/$t.rc"
}
opts=(-rss_limit_mb=1024 -malloc_limit_mb=512 -timeout=10 -max_len=65536 -error_exitcode=1 -timeout_exitcode=1)

# The targets run side by side, one per core (each is one thread): the same
# seconds of fuzzing each, in less wall time.
jobs=$(nproc 2>/dev/null || echo 1)
echo "fuzz.sh: ${#targets[@]} targets for ${secs}s each, $jobs at a time"
running=0
for t in "${targets[@]}"; do
  rm -f "$out/$t.rc"
  fuzz_one "$t" &
  running=$((running + 1))
  if [ "$running" -ge "$jobs" ]; then
    wait -n || true
    running=$((running - 1))
  fi
done
wait || true

status=0
for t in "${targets[@]}"; do
  work=$out/corpus-$t
  art=$out/artifacts-$t
  rc=$(cat "$out/$t.rc" 2>/dev/null || echo 1)
  echo "fuzz.sh: $t for ${secs}s from $(ls "$work" 2>/dev/null | wc -l) inputs at the end: $(grep -E "^stat::number_of_executed_runs|^stat::peak_rss_mb|^#[0-9]+ +DONE" "$out/$t.log" | tr '\n' ' ' || true)"
  if [ "$rc" != 0 ]; then
    tail -n 40 "$out/$t.log" >&2 || true
    echo "fuzz.sh: $t failed (exit $rc); inputs in $art/, log in $out/$t.log" >&2
    status=1
    continue
  fi
  if [ "$merge" = 1 ] && [ "$t" = fuzz_decoder ]; then
    # Start from the seeds, then let libFuzzer add only what brings new coverage.
    corpus=$root/tests/fuzz/corpus
    merged=$out/merged
    rm -rf "$merged" "$out/rest"
    mkdir -p "$merged" "$out/rest"
    cp "$corpus"/seed-* "$merged"/
    find "$corpus" -maxdepth 1 -type f ! -name 'seed-*' -exec cp {} "$out/rest"/ \;
    if ! "$bindir/$t" "${opts[@]}" -artifact_prefix="$art/" -merge=1 "$merged" "$out/rest" "$work" >"$out/merge.log" 2>&1; then
      echo "fuzz.sh: merging failed; see $out/merge.log" >&2
      exit 1
    fi
    find "$corpus" -maxdepth 1 -type f ! -name 'seed-*' -delete
    find "$merged" -maxdepth 1 -type f ! -name 'seed-*' -exec cp {} "$corpus"/ \;
    echo "fuzz.sh: corpus now $(ls "$corpus" | wc -l) files, $(du -sk "$corpus" | cut -f1) KiB"
  fi
done
[ "$status" = 0 ] && echo "fuzz.sh: no failures in ${secs}s per target (${targets[*]})"
exit "$status"
