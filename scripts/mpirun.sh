#!/usr/bin/env bash
# Runs a command under mpirun on this machine: as root and with more ranks
# than cores (the flags Open MPI wants for both are set here), and with Ctrl-C
# turned into a clean stop: mpirun itself would kill every rank on SIGINT, so
# it runs in its own session and gets SIGUSR1 instead, which it forwards; the
# host rank then finishes the frames it has and writes every output.
# Usage: scripts/mpirun.sh RANKS COMMAND [ARGS...]
set -euo pipefail
if [[ $# -lt 2 || ! "$1" =~ ^[0-9]+$ ]]; then
  echo "usage: scripts/mpirun.sh RANKS COMMAND [ARGS...]" >&2
  exit 2
fi
n="$1"
shift
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
setsid mpirun -n "$n" "$@" &
pid=$!
trap 'kill -USR1 "$pid" 2>/dev/null || true' INT TERM
status=0
while kill -0 "$pid" 2>/dev/null; do
  wait "$pid" && status=0 || status=$?
done
exit "$status"
