#!/usr/bin/env bash
# The soak: FRAMES frames of the default doll (back-and-forth passes over it)
# streamed at the scanner's 30 frames/s through the MPI pipeline (4 ranks, as
# the main job), with each rank's resident memory sampled every 2 s. Prints
# per rank the memory early in the stream (once a fifth of the frames are in)
# and late (the last sample before the input ends), and the slice-to-image latency (median, p95) of the first and the
# last WINDOW frames (1000, or a third of a shorter run).
# Verdicts: memory flat (no rank grows by more than 5% + 4 MiB from a fifth
# of the frames in to the last sample before the input ends) and latency not drifting (the last window's p95 within 10% of the
# first's). --memory-only checks memory alone (CTest's short soak: a latency on
# a shared machine is a benchmark's figure, not a test's).
# Usage: scripts/soak.sh [FRAMES] [--build DIR] [--out DIR] [--memory-only]   (default 10000)
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
frames=10000 build=$root/build out="" memonly=0
while [ $# -gt 0 ]; do
  case "$1" in
    --build) shift; build=$1 ;;
    --out) shift; out=$1 ;;
    --memory-only) memonly=1 ;;
    ''|*[!0-9]*) echo "usage: scripts/soak.sh [FRAMES] [--build DIR] [--out DIR] [--memory-only]" >&2; exit 2 ;;
    *) frames=$1 ;;
  esac
  shift
done
bin=$build/src/app/pp5echo
[ -x "$bin" ] || { echo "soak.sh: $bin is missing; build first (bash scripts/build.sh)" >&2; exit 1; }
[ -n "$out" ] || out=$(mktemp -d)
rm -rf "$out/run" && mkdir -p "$out"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
# A pass over the doll is about 90 frames at the default 2 mm; at most 100
# passes, so a longer soak captures a frame every less than 2 mm.
repeats=$(( frames / 88 + 1 ))
interval=2.0
if [ "$repeats" -gt 100 ]; then
  repeats=100
  interval=$(python3 -c "print(round(2.0 * 8800 / $frames, 3))")
fi
echo "soak.sh: $frames frames at 30 frames/s ($(( frames / 30 )) s), output in $out"
mpirun -n 4 "$bin" run "$root/configs/doll.toml" -o "$out/run" \
  --set 'sim.sweep.kind="back_and_forth"' --set "sim.sweep.repeats=$repeats" --set "sim.sweep.max_frames=$frames" \
  --set "sim.sweep.capture_interval_mm=$interval" \
  --set run.orbit_frames=0 --set run.buildup_every=100 > "$out/run.log" 2>&1 &
mp=$!
trap 'kill "$mp" 2>/dev/null || true' EXIT INT TERM
echo "t_s,frames,rank,rss_kib" > "$out/rss.csv"
t0=$(date +%s)
while kill -0 "$mp" 2>/dev/null; do
  # How far the stream is (the host logs "run: frame N/M" every 2 s).
  n=$(grep -o 'run: frame [0-9]*' "$out/run.log" 2>/dev/null | tail -1 | grep -o '[0-9]*$' || true)
  for p in $(pgrep -P "$mp" || true); do
    # A rank may exit between pgrep and here: the redirection then fails, so
    # stderr is silenced before it and the failure must not stop the script.
    r=$(tr '\0' '\n' 2>/dev/null < "/proc/$p/environ" | sed -n 's/^OMPI_COMM_WORLD_RANK=//p') || true
    kib=$(awk '/^VmRSS:/ {print $2}' "/proc/$p/status" 2>/dev/null || true)
    [ -n "$r" ] && [ -n "$kib" ] && echo "$(( $(date +%s) - t0 )),${n:-0},$r,$kib" >> "$out/rss.csv"
  done
  sleep 2
done
wait "$mp" || { tail -20 "$out/run.log"; echo "soak.sh: the run failed" >&2; exit 1; }
trap - EXIT
python3 - "$out" "$frames" "$memonly" <<'PY'
import csv, json, sys
out, frames, memonly = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "1"
summ = json.load(open(f"{out}/run/summary.json"))
lat = {}
for row in csv.DictReader(open(f"{out}/run/stats.csv")):
    if row["role"] == "0" and float(row["latency_ms"]) >= 0:
        lat[int(row["frame"])] = float(row["latency_ms"])
order = [lat[k] for k in sorted(lat)]
win = min(1000, len(order) // 3)
def q(v, p):
    v = sorted(v)
    return v[min(len(v) - 1, int(p * (len(v) - 1) + 0.5))]
first, last = order[:win], order[-win:]
print(f"frames in: {summ['frames']}, {summ['frames_per_s_in']:.2f} frames/s, dropped {summ['dropped_frames']}")
print(f"latency, first {win} frames: median {q(first, .5):.1f} ms, p95 {q(first, .95):.1f} ms")
print(f"latency, last {win} frames:  median {q(last, .5):.1f} ms, p95 {q(last, .95):.1f} ms")
ratio = q(last, .95) / q(first, .95)
print(f"p95 last / first: {ratio:.3f}")
samples = list(csv.DictReader(open(f"{out}/rss.csv")))
# Memory while streaming: from the first sample with a fifth of the frames in
# to the last one taken while the log still counted frames (the final passes,
# images and volume that follow are not the stream's).
n_in = summ["frames"]
last_logged = max(int(s["frames"]) for s in samples)
ok_mem = True
print(f"| rank | RSS, {n_in // 5} frames in (MiB) | RSS, last sample before the end of input (MiB) | growth |")
print("|---|---|---|---|")
for r in sorted({s["rank"] for s in samples}, key=int):
    mine = [(int(s["frames"]), int(s["rss_kib"])) for s in samples if s["rank"] == r]
    early = [(f, k) for f, k in mine if f >= n_in // 5]
    late = [(f, k) for f, k in mine if f < last_logged]
    if not early or not late:
        print(f"| {r} | - | - | too few samples |")
        continue
    a, b = early[0][1] / 1024.0, late[-1][1] / 1024.0
    grow = b - a
    ok = b <= a * 1.05 + 4.0
    ok_mem &= ok
    print(f"| {r} | {a:.1f} | {b:.1f} (at frame {late[-1][0]}) | {grow:+.1f} MiB ({100 * grow / a:+.1f}%) {'' if ok else 'GROWS'} |")
ok_lat = ratio <= 1.10
print(f"memory flat: {'yes' if ok_mem else 'NO'}; latency not drifting: {'yes' if ok_lat else 'NO'}"
      + (" (not checked: --memory-only)" if memonly else ""))
sys.exit(0 if ok_mem and (memonly or ok_lat) else 1)
PY
