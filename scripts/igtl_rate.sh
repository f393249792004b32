#!/usr/bin/env bash
# What the OpenIGTLink server (run.igtl_serve) delivers while the main job
# runs, and what it costs the main job: configs/doll.toml on 4 MPI ranks at
# 30 frames/s with the live viewer on (as scripts/main.sh runs it), its sweep
# taken every 0.5 mm instead of 2 mm so that it streams for about 12 s, with
# clients of Debian's libopenigtlink (pp5-igtl-probe). Cases, each ROUNDS times:
#   hz10   one client, igtl.volume_hz = 10
#   hz30   one client, igtl.volume_hz = 30
#   bad    igtl.volume_hz = 10: one client that reads, one that reads nothing
#          for its first 10 s, one that disconnects in the middle of a message
# One row per run: the run's frames/s in, drops and latency p95 (summary.json),
# and the reading client's volume updates per second and their latency
# (a changed brick's, from the frame's arrival at the host to the client),
# median and p95; docs/benchmarks.md records the table.
# Usage: scripts/igtl_rate.sh [ROUNDS] [BUILD_DIR]   (default 3, build)
set -euo pipefail
cd "$(dirname "$0")/.."
rounds="${1:-3}"
build="${2:-build}"
bin="$build/src/app/pp5echo"
probe="$build/tests/pp5-igtl-probe"
for f in "$bin" "$probe"; do
  [ -x "$f" ] || { echo "igtl_rate.sh: $f is missing; build first (bash scripts/build.sh)" >&2; exit 1; }
done
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }
printf '%-5s %-3s %11s %7s %8s %10s %11s %10s %9s\n' case run "frames/s in" dropped "p95 ms" "updates/s" "median ms" "p95 ms" views/s
for i in $(seq 1 "$rounds"); do
  for c in hz10 hz30 bad; do
    hz=10
    [ "$c" = hz30 ] && hz=30
    port=$(free_port)
    dir="$out/$c-$i"
    bash scripts/mpirun.sh 4 "$bin" run configs/doll.toml -o "$dir" --view 127.0.0.1:0 --igtl-serve "127.0.0.1:$port" \
      --set sim.sweep.capture_interval_mm=0.5 --set igtl.volume_hz=$hz --set run.orbit_frames=0 > "$dir.log" 2>&1 &
    run=$!
    "$probe" "$port" > "$dir.reader.json" 2> "$dir.reader.log" &
    probes=($!)
    if [ "$c" = bad ]; then
      "$probe" "$port" --silent-s 10 > "$dir.silent.json" 2> "$dir.silent.log" &
      probes+=($!)
      "$probe" "$port" --drop-mid > "$dir.drop.json" 2> "$dir.drop.log" &
      probes+=($!)
    fi
    wait "$run" || { echo "igtl_rate.sh: run $c-$i failed:"; tail -5 "$dir.log"; exit 1; }
    for p in "${probes[@]}"; do wait "$p" || true; done
    python3 - "$c" "$i" "$dir/summary.json" "$dir.reader.json" <<'PY'
import json, sys
c, i, summary, reader = sys.argv[1:5]
d = json.load(open(summary))
r = json.load(open(reader))
views = r["devices"].get("IMAGE:RenderedView", {}).get("per_s", 0.0)
print(f'{c:<5} {i:<3} {d["frames_per_s_in"]:11.2f} {d["dropped_frames"]:7d} {d["latency_ms_p95"]:8.1f} '
      f'{r["volume_updates_per_s"]:10.1f} {r["volume_latency_ms_median"]:11.1f} {r["volume_latency_ms_p95"]:10.1f} {views:9.1f}')
PY
    if [ "$c" = bad ]; then
      python3 - "$dir.silent.json" "$dir.drop.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
d = json.load(open(sys.argv[2]))
print(f'      the silent client, once it read: {s["volume_updates_per_s"]:.1f} updates/s, latency p95 '
      f'{s["volume_latency_ms_p95"]:.1f} ms over {s["seconds"]:.1f} s; the dropping client left after '
      f'{d["body_bytes"] // 2} of {d["body_bytes"]} bytes')
PY
    fi
  done
done
echo "igtl_rate.sh: $(date -u +%Y-%m-%d), $(git rev-parse --short HEAD 2>/dev/null || echo '?')"
