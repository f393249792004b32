#!/usr/bin/env bash
# The main job: installs what is missing, builds, and runs the built-in default:
# the simulated doll phantom sweep streamed frame by frame through the pipeline
# (reconstruct, shade, ray-sample, composite), writing the images, the volume
# and the statistics to the folder it prints. (The pipeline runs serially
# until the MPI ranks arrive; `pp5echo run` then runs under mpirun.)
# Usage: scripts/main.sh [OUTPUT_DIR]   (default: out/doll)
set -euo pipefail
cd "$(dirname "$0")/.."

out="${1:-out/doll}"
bash scripts/install-deps.sh
dir=$(bash scripts/build.sh | tail -n 1)
"$dir/src/app/pp5echo" run configs/doll.toml -o "$out"
echo "pp5echo: outputs are in $(cd "$out" && pwd)"
