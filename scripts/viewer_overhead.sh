#!/usr/bin/env bash
# What the live viewer costs the pipeline with no browser connected: the main
# job paced at the scanner's rate (30 frames/s), alternating without and with
# --view, N rounds; prints the host's figures of each run (docs/benchmarks.md,
# "The live viewer").
# Usage: scripts/viewer_overhead.sh [ROUNDS] [BUILD_DIR]   (default 5, build)
set -euo pipefail
cd "$(dirname "$0")/.."
rounds="${1:-5}"
bin="${2:-build}/src/app/pp5echo"
out=$(mktemp -d)
for i in $(seq 1 "$rounds"); do
  for v in off on; do
    extra=()
    [ "$v" = on ] && extra=(--view 127.0.0.1:0)
    bash scripts/mpirun.sh 4 "$bin" run configs/doll.toml -o "$out/$v-$i" --set run.pace_fps=30 \
      --set run.orbit_frames=0 "${extra[@]}" > "$out/$v-$i.log" 2>&1
    echo "viewer $v, round $i: $(grep -o 'frames/s in [0-9.]*, images/s out [0-9.]*, latency median [0-9.]* ms, p95 [0-9.]* ms' "$out/$v-$i.log")" \
      "$(grep -o 'dropped [0-9]* frames' "$out/$v-$i.log" || echo 'dropped 0 frames')"
  done
done
rm -rf "$out"
