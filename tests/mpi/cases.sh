# Sourced by the MPI fault scripts (clean_ends.sh, killed_recording.sh): the
# checks, a rank's process, and independent cases run side by side.
#
# check NAME CONDITION-STATUS MESSAGE: prints ok or FAIL; a FAIL fails the case.
# rank_pid MPIRUN_PID RANK: the process of that rank of a running mpirun.
# run_cases DIR CASE...: runs each CASE (a shell function) at once, in its own
#   subshell with its output in DIR/CASE.txt, waits for all, prints their
#   outputs in the order given and sets fail=1 when any case failed. The cases
#   wait far more than they compute (a rank stopped until a timeout, a sweep
#   paced at a scanner's rate), so side by side they take the longest case's
#   time, not the sum.
check() {
  if [[ "$2" == 0 ]]; then echo "ok:   $1"; else echo "FAIL: $1: $3"; fail=1; fi
}
rank_pid() {
  local p
  for p in $(pgrep -P "$1"); do
    if tr '\0' '\n' 2>/dev/null < "/proc/$p/environ" | grep -qx "OMPI_COMM_WORLD_RANK=$2"; then echo "$p"; return; fi
  done
}
run_cases() {
  local dir=$1 c st
  shift
  local -a pids=()
  for c in "$@"; do
    ( fail=0; "$c"; exit "$fail" ) > "$dir/$c.txt" 2>&1 &
    pids+=($!)
  done
  local i=0
  for c in "$@"; do
    wait "${pids[$i]}"; st=$?
    cat "$dir/$c.txt"
    if [[ $st -ne 0 ]]; then
      grep -q '^FAIL' "$dir/$c.txt" || echo "FAIL: $c ended with status $st"
      fail=1
    fi
    i=$((i + 1))
  done
}
