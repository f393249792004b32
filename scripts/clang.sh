#!/usr/bin/env bash
# Prints the clang++ that the sanitizer stage and the fuzzers use ($CLANGXX,
# else clang++, else clang++-14); exits 77 (CTest's "skipped") with a line on
# stderr when there is none. Used by scripts/fuzz.sh and scripts/sanitize.sh.
for c in "${CLANGXX:-}" clang++ clang++-14; do
  if [ -n "$c" ] && command -v "$c" >/dev/null 2>&1; then
    echo "$c"
    exit 0
  fi
done
echo "clang++ not found; the sanitizer stage and the fuzzers need clang with libFuzzer (Debian: apt-get install clang libclang-rt-14-dev); skipping" >&2
exit 77
