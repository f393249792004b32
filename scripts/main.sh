#!/usr/bin/env bash
# The main job: installs what is missing, builds, and runs the built-in default
# (the simulated doll phantom), writing its outputs to the folder it prints.
# Usage: scripts/main.sh [OUTPUT_DIR]   (default: out/doll)
set -euo pipefail
cd "$(dirname "$0")/.."

out="${1:-out/doll}"
bash scripts/install-deps.sh
dir=$(bash scripts/build.sh | tail -n 1)
"$dir/src/app/pp5echo" simulate configs/doll.toml -o "$out"
echo "pp5echo: outputs are in $(cd "$out" && pwd)"
