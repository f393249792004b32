#!/usr/bin/env bash
# The main job: installs what is missing, builds, and runs the built-in default:
# the simulated doll phantom sweep streamed frame by frame through the pipeline
# (reconstruct, shade, ray-sample, composite) on 4 MPI ranks: the host, two
# graphics processors and one pixel processor, with the live viewer on. Its
# URL is printed first: open it to watch the doll build up and steer the view.
# It writes the images, the volume and the statistics to the folder it prints.
# Run from a terminal, the final volume then stays live in the viewer until
# Enter or Ctrl-C; without a terminal (CI, scripts) the job ends with the
# sweep. Ctrl-C during the sweep stops acquiring and still writes every
# output (scripts/mpirun.sh).
# Usage: scripts/main.sh [OUTPUT_DIR [RANKS [VIEW_PORT]]]   (default: out/doll, 4, 8080)
set -euo pipefail
cd "$(dirname "$0")/.."

out="${1:-out/doll}"
ranks="${2:-4}"
port="${3:-8080}"
bash scripts/install-deps.sh
dir=$(bash scripts/build.sh --only pp5echo | tail -n 1)
args=(run configs/doll.toml -o "$out" --view "127.0.0.1:$port")
if [ -t 0 ]; then
  # Interactive: keep the final volume live until Enter (or Ctrl-C).
  bash scripts/mpirun.sh "$ranks" "$dir/src/app/pp5echo" "${args[@]}" --serve &
  job=$!
  echo "pp5echo: press Enter (or Ctrl-C) to end once you are done with the viewer" >&2
  # mpirun.sh turns TERM, like INT, into a clean stop (an async job ignores INT).
  ( read -r _ && kill -TERM "$job" 2>/dev/null ) < /dev/tty &
  reader=$!
  trap 'kill -TERM "$job" 2>/dev/null || true' INT
  status=0
  wait "$job" || status=$?
  kill "$reader" 2>/dev/null || true
  [ "$status" -eq 0 ] || exit "$status"
else
  bash scripts/mpirun.sh "$ranks" "$dir/src/app/pp5echo" "${args[@]}"
fi
echo "pp5echo: outputs are in $(cd "$out" && pwd)"
