#!/usr/bin/env bash
# Whether the main job keeps up with the scanner: runs the README's main job
# (configs/doll.toml on 4 MPI ranks, streamed at 30 frames/s, the live viewer
# on as scripts/main.sh has it, on a free port, with no browser connected)
# N times one after the other and prints one row per run: frames/s in, frames
# dropped, slice-to-image latency median and p95, an incremental frame's bytes,
# and whether the run met issue 17's bar (>= 29.5 frames/s in, no drop,
# p95 <= 100 ms). docs/benchmarks.md records its tables.
# Usage: scripts/main_rate.sh [RUNS] [BUILD_DIR]   (default 10, build)
set -euo pipefail
cd "$(dirname "$0")/.."
runs="${1:-10}"
bin="${2:-build}/src/app/pp5echo"
[ -x "$bin" ] || { echo "main_rate.sh: $bin is missing; build first (bash scripts/build.sh)" >&2; exit 1; }
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
printf '%-4s %12s %8s %12s %12s %16s %s\n' run "frames/s in" dropped "median ms" "p95 ms" "kB/inc. frame" verdict
met=0
for i in $(seq 1 "$runs"); do
  bash scripts/mpirun.sh 4 "$bin" run configs/doll.toml -o "$out/$i" --view 127.0.0.1:0 > "$out/$i.log" 2>&1 ||
    { echo "main_rate.sh: run $i failed:"; tail -5 "$out/$i.log"; exit 1; }
  row=$(python3 - "$out/$i/summary.json" <<'PY'
import json, sys
d = json.load(open(sys.argv[1]))
ok = d["frames_per_s_in"] >= 29.5 and d["dropped_frames"] == 0 and d["latency_ms_p95"] <= 100.0
print(f'{d["frames_per_s_in"]:12.2f} {d["dropped_frames"]:8d} {d["latency_ms_median"]:12.1f} '
      f'{d["latency_ms_p95"]:12.1f} {d["incremental_bytes_per_frame"]["total"] / 1e3:16.0f} {"met" if ok else "MISSED"}')
PY
)
  printf '%-4s %s\n' "$i" "$row"
  case "$row" in *" met") met=$((met + 1)) ;; esac
done
echo "main_rate.sh: $met of $runs runs met the bar ($(date -u +%Y-%m-%d), $(git rev-parse --short HEAD 2>/dev/null || echo '?'))"
