#!/usr/bin/env bash
# What a person watching the live viewer feels: runs the browser test's
# measurement (tests/browser/viewer_test.mjs --measure: Debian's chromium,
# headless, on the default doll streamed at 30 frames/s through 4 MPI ranks)
# N times one after the other, prints one row per run and then every run's
# frames together: a frame's arrival at the host to the first image showing
# it, median and p95, and where that time went (the pipeline to the image on
# the host, the host's encoder, the socket and the page). Issue 16's bars:
# >= 25 images/s in the sweep, latency p95 <= 150 ms, >= 15 images/s in a
# drag, the drag's first response <= 100 ms. docs/benchmarks.md records its tables.
# Usage: scripts/viewer_rate.sh [RUNS] [BUILD_DIR] [--set KEY=VALUE ...]   (default 5, build)
set -euo pipefail
cd "$(dirname "$0")/.."
runs="${1:-5}"
build="${2:-build}"
case "$build" in /*) ;; *) build="$(pwd)/$build" ;; esac
bin="$build/src/app/pp5echo"
shift $(( $# < 2 ? $# : 2 ))  # the rest: options for the run (e.g. another build's page: --set view.web_root=...)
[ -x "$bin" ] || { echo "viewer_rate.sh: $bin is missing; build first (bash scripts/build.sh)" >&2; exit 1; }
[ -d tests/browser/node_modules/playwright-core ] ||
  { echo "viewer_rate.sh: playwright-core is missing (bash scripts/install-deps.sh installs it)" >&2; exit 1; }
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
for i in $(seq 1 "$runs"); do
  (cd tests/browser && node viewer_test.mjs --pp5echo "$bin" --out "$out/$i" --pace 30 \
     --set sim.sweep.capture_interval_mm=2 "$@" --measure) > "$out/$i.log" 2>&1 ||
    { echo "viewer_rate.sh: run $i failed:"; grep -E 'FAIL|Error' "$out/$i.log" | head -20; exit 1; }
  echo "viewer_rate.sh: run $i of $runs done" >&2
done
python3 - "$out" "$runs" <<'PY'
import json, math, sys
out, runs = sys.argv[1], int(sys.argv[2])
def q(v, p):  # the nearest-rank quantile, as the browser test computes it
    v = sorted(v)
    return v[max(0, math.ceil(p * len(v)) - 1)] if v else float('nan')
parts = ['pipeline', 'encoder', 'socket', 'page']
def cell(v, width):  # a figure, or '-' where the run had none
    return f'{v:{width}d}' if v is not None else f'{"-":>{width}}'
print(f'{"run":<4} {"images/s":>9} {"latency median":>15} {"p95":>5} {"frames":>7} {"drag images/s":>14} {"first response":>15}')
pooled, parts_pooled, met = [], [], {'sweep': 0, 'p95': 0, 'drag': 0, 'first': 0}
for i in range(1, runs + 1):
    f = json.load(open(f'{out}/{i}/figures.json'))
    pooled += f['latency_ms']
    parts_pooled += f.get('latency_parts', [])  # absent from a build whose images carry no host times
    met['sweep'] += f['sweep_images_per_s'] >= 25
    met['p95'] += f['latency_ms_p95'] is not None and f['latency_ms_p95'] <= 150
    met['drag'] += f['drag_images_per_s'] >= 15
    met['first'] += f['drag_first_response_ms'] is not None and f['drag_first_response_ms'] <= 100
    print(f'{i:<4} {f["sweep_images_per_s"]:9.1f} {cell(f["latency_ms_median"], 15)} {cell(f["latency_ms_p95"], 5)} '
          f'{f["latency_frames"]:7d} {f["drag_images_per_s"]:14.1f} {cell(f["drag_first_response_ms"], 15)}'
          f'{"" if f.get("drag_during_sweep") else "  (the drag began after the sweep)"}')
print(f'every run\'s frames together ({len(pooled)}): latency median {q(pooled, 0.5)} ms, p95 {q(pooled, 0.95)} ms')
if parts_pooled:
    print('  where it went, median and p95 (ms):')
    for k in parts:
        v = [p[k] for p in parts_pooled]
        print(f'  {k:<9} {q(v, 0.5):5d} {q(v, 0.95):5d}')
print(f'runs that met issue 16\'s bars: images/s {met["sweep"]} of {runs}, latency p95 {met["p95"]} of {runs}, '
      f'drag images/s {met["drag"]} of {runs}, first response {met["first"]} of {runs}')
PY
echo "viewer_rate.sh: $(date -u +%Y-%m-%d), $(git rev-parse --short HEAD 2>/dev/null || echo '?')"
