#!/usr/bin/env bash
# The main job: installs what is missing, builds, and runs the built-in default:
# the simulated doll phantom sweep streamed frame by frame through the pipeline
# (reconstruct, shade, ray-sample, composite) on 4 MPI ranks: the host, two
# graphics processors and one pixel processor. It writes the images, the
# volume and the statistics to the folder it prints. Ctrl-C stops acquiring
# and still writes every output (scripts/mpirun.sh).
# Usage: scripts/main.sh [OUTPUT_DIR [RANKS]]   (default: out/doll, 4)
set -euo pipefail
cd "$(dirname "$0")/.."

out="${1:-out/doll}"
ranks="${2:-4}"
bash scripts/install-deps.sh
dir=$(bash scripts/build.sh | tail -n 1)
bash scripts/mpirun.sh "$ranks" "$dir/src/app/pp5echo" run configs/doll.toml -o "$out"
echo "pp5echo: outputs are in $(cd "$out" && pwd)"
