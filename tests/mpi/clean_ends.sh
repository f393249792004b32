#!/usr/bin/env bash
# Clean ends of the distributed pipeline. Every case runs under a timeout and
# asserts the exit status and the message, so a hang fails the test.
#  1. a rank killed mid-sweep ends the job within seconds;
#  2. a corrupt frame in the input ends the job with a message naming it;
#  3. a rank that stops answering (SIGSTOP) ends the job after parallel.timeout_s, named by the host;
#  4. Ctrl-C or SIGTERM through scripts/mpirun.sh finishes the frames acquired and writes every output (tick mode);
#  5. a layout that does not match the job's size is refused with a clear message;
#  6. SIGTERM to mpirun itself does the same (mpirun's own status is non-zero).
# The cases run side by side (tests/mpi/cases.sh): each waits far more than
# it computes, and alone one after another they took 33 s of a 2-core
# machine's CTest with a fifth of one core busy (2026-12-04).
# Usage: clean_ends.sh PP5ECHO OUTDIR DATADIR
set -uo pipefail
bin="$1" out="$2" data="$3"
root="$(cd "$(dirname "$0")/../.." && pwd)"
source "$root/tests/mpi/cases.sh"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
rm -rf "$out" && mkdir -p "$out"
fail=0
small=("$root/tests/configs/mpi_small.toml" --set 'parallel.composite_on="tick"' --set 'run.orbit_frames=0')
# A longer sweep (a frame every 2 mm, 88 frames) paced at 15 frames/s, so
# there is time to interfere (6 s; the sweep streams from the cache). Half
# the frames of a 1 mm sweep at 30 frames/s for the same time: the sanitized
# simulator took 28 s to simulate that one (2026-12-04).
long=("${small[@]}" --set 'sim.sweep.capture_interval_mm=2.0' --set 'run.script=[]' --set 'run.pace_fps=15')

wait_for() {  # wait_for FILE PATTERN SECONDS [PID]: 0 once FILE has PATTERN; 1 on the timeout or once PID has ended
  local i
  for ((i = 0; i < $3 * 10; i++)); do
    grep -q "$2" "$1" 2>/dev/null && return 0
    [[ -z "${4:-}" ]] || kill -0 "$4" 2>/dev/null || return 1
    sleep 0.1
  done
  return 1
}

# 1. kill -9 a graphics processor mid-sweep.
killed_rank() {
  local log="$out/kill.log" mp t0 t1 gp st
  mpirun -n 4 "$bin" run "${long[@]}" -o "$out/kill" > "$log" 2>&1 &
  mp=$!
  wait_for "$log" "run: frame" 60
  t0=$(date +%s)
  gp=$(rank_pid "$mp" 1)
  [[ -n "$gp" ]] && kill -9 "$gp"
  timeout 30 tail --pid="$mp" -f /dev/null; wait "$mp"; st=$?
  t1=$(date +%s)
  check "killed rank: job ends non-zero" "$([[ -n "$gp" && $st -ne 0 ]]; echo $?)" "status $st, rank pid '$gp'"
  check "killed rank: within 20 s" "$([[ $((t1 - t0)) -le 20 ]]; echo $?)" "took $((t1 - t0)) s"
  check "killed rank: mpirun names it" "$(grep -q 'rank 1 with PID' "$log"; echo $?)" "$(tail -5 "$log")"
  check "killed rank: the output folder is marked unfinished" "$([[ -f "$out/kill/RUN_INCOMPLETE.txt" ]]; echo $?)" \
    "$(ls "$out/kill")"
}

# 2. a corrupt frame: 200 kB of garbage in the middle of a compressed PLUS sequence.
corrupt_frame() {
  local seq="$out/corrupt.igs.mha" log st
  cp "$data/SpinePhantomFreehand.igs.mha" "$seq" && chmod u+w "$seq"
  head -c 200000 /dev/zero | tr '\0' '\253' | dd of="$seq" bs=1 seek=1500000 conv=notrunc 2>/dev/null
  log="$out/corrupt.log"
  timeout 120 mpirun -n 4 "$bin" run -o "$out/corrupt" --set 'run.source="sequence"' --set "run.sequence=\"$seq\"" \
    --set "run.plus_config=\"$data/PlusDeviceSet_SpinePhantomFreehandReconstructionOnly.xml\"" --set 'run.orbit_frames=0' \
    > "$log" 2>&1
  st=$?
  check "corrupt frame: job ends non-zero (not by the timeout)" "$([[ $st -ne 0 && $st -ne 124 ]]; echo $?)" "status $st"
  check "corrupt frame: the host names the file and frame" \
    "$(grep -q 'rank 0 (host): .*corrupt.igs.mha: frame [0-9]*: corrupt compressed data' "$log"; echo $?)" "$(tail -5 "$log")"
}

# 3. a pixel processor that stops answering: the job ends after parallel.timeout_s.
stopped_rank() {
  local log="$out/stop.log" mp pp st
  mpirun -n 4 "$bin" run "${long[@]}" --set 'parallel.timeout_s=3.0' -o "$out/stop" > "$log" 2>&1 &
  mp=$!
  wait_for "$log" "run: frame" 60
  pp=$(rank_pid "$mp" 3)
  [[ -n "$pp" ]] && kill -STOP "$pp"
  timeout 40 tail --pid="$mp" -f /dev/null; wait "$mp"; st=$?
  [[ -n "$pp" ]] && kill -9 "$pp" 2>/dev/null
  check "stopped rank: job ends non-zero" "$([[ -n "$pp" && $st -ne 0 ]]; echo $?)" "status $st"
  # The host's heartbeat finds it first and names it (a rank that only said what
  # it had waited for used to be all there was).
  check "stopped rank: the host names it by its heartbeat" \
    "$(grep -q 'rank 3 (pixel processor 0)' "$log"; echo $?)" "$(grep -i 'error' "$log" | head -5)"
}

# 4. Ctrl-C (SIGINT), or SIGTERM, through scripts/mpirun.sh, in tick mode: a
#    clean end with every output and the folder no longer marked unfinished.
interrupted() {  # interrupted INT|TERM
  local sig=$1 log="$out/interrupt-$1.log" sh st f
  # (A background job starts with SIGINT ignored, and bash cannot trap a signal
  # ignored on entry; python restores the default first, as a terminal has it.)
  python3 -c 'import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_DFL); os.execvp("bash", ["bash"] + sys.argv[1:])' \
    "$root/scripts/mpirun.sh" 4 "$bin" run "${long[@]}" -o "$out/interrupt-$sig" > "$log" 2>&1 &
  sh=$!
  wait_for "$log" "run: frame" 60
  kill -"$sig" "$sh"
  timeout 120 tail --pid="$sh" -f /dev/null; wait "$sh"; st=$?
  check "SIG$sig: exit 0" "$([[ $st -eq 0 ]]; echo $?)" "status $st: $(tail -5 "$log")"
  check "SIG$sig: the host says so" "$(grep -q 'interrupted; finishing the' "$log"; echo $?)" "$(tail -5 "$log")"
  for f in buildup.gif final_over.png final_mip.png mpr_axial.png volume.mha stats.csv summary.json settings.toml; do
    check "SIG$sig: wrote $f" "$([[ -s "$out/interrupt-$sig/$f" ]]; echo $?)" "missing"
  done
  check "SIG$sig: the folder is not marked unfinished" "$([[ ! -e "$out/interrupt-$sig/RUN_INCOMPLETE.txt" ]]; echo $?)" \
    "RUN_INCOMPLETE.txt is there"
}
sigint() { interrupted INT; }
sigterm() { interrupted TERM; }

# 6. SIGTERM to mpirun itself (as a batch system sends it): mpirun passes it to
#    every rank, the host finishes the frames it has and writes every output;
#    mpirun's own status for a signalled job is non-zero. Open MPI 4.1's mpirun
#    sends its ranks SIGCONT, waits odls_base_sigkill_timeout seconds (GRACE_S),
#    sends SIGTERM, waits as long again and sends SIGKILL: the host has GRACE_S
#    seconds to write everything. What is checked is that it does write
#    everything, not how fast: the case gives 5 s (PP5_MPIRUN_GRACE_S says
#    otherwise). mpirun's default of 1 s is a speed figure and no bound on a
#    run's ending: this small job's took 0.68 to 1.04 s on this machine
#    (2026-12-02) and 0.31 to 0.37 s (2026-11-28), and a large run needs more
#    (docs/cluster.md, "Stopping").
#    The sweep is paced at 7.5 frames/s, 12 s in all, so that the SIGTERM
#    reaches a host still streaming, which the first check asserts.
term_mpirun() {
  local grace=${PP5_MPIRUN_GRACE_S:-5} log="$out/term-mpirun.log" mp f st
  mpirun -n 4 --mca odls_base_sigkill_timeout "$grace" "$bin" run "${long[@]}" \
    --set 'run.pace_fps=7.5' -o "$out/term-mpirun" > "$log" 2>&1 &
  mp=$!
  wait_for "$log" "run: frame" 60
  kill -TERM "$mp"
  timeout 120 tail --pid="$mp" -f /dev/null; wait "$mp"; st=$?
  check "SIGTERM to mpirun: the host finishes" "$(grep -q 'interrupted; finishing the' "$log"; echo $?)" "$(tail -5 "$log")"
  grep -h 'after the interruption' "$log"
  for f in buildup.gif final_over.png volume.mha summary.json; do
    check "SIGTERM to mpirun: wrote $f" "$([[ -s "$out/term-mpirun/$f" ]]; echo $?)" "missing"
  done
  check "SIGTERM to mpirun: the folder is not marked unfinished" \
    "$([[ ! -e "$out/term-mpirun/RUN_INCOMPLETE.txt" ]]; echo $?)" "RUN_INCOMPLETE.txt is there"
}

# 5. a layout that does not fit the job.
layout() {
  local log="$out/layout.log" st
  timeout 60 mpirun -n 3 "$bin" run "${small[@]}" --gps 2 --pps 2 -o "$out/layout" > "$log" 2>&1
  st=$?
  check "layout mismatch: refused" "$([[ $st -ne 0 && $st -ne 124 ]]; echo $?)" "status $st"
  check "layout mismatch: says why" "$(grep -q 'need 5 ranks, but the job has 3' "$log"; echo $?)" "$(tail -3 "$log")"
}

# The long sweep simulated once into the sweep cache before the cases start,
# which then stream it: five at once would each simulate it, slowly under the
# sanitizers, and a case's signal would reach a host still simulating. The
# run is stopped once it streams, the cache written by then, unless it has
# ended first (a cache that holds it already makes this a second's work).
warm="$out/warm-sweep.log"
"$bin" run "${long[@]}" --serial --set 'run.pace_fps=0' -o "$out/warm-sweep" > "$warm" 2>&1 &
wp=$!
wait_for "$warm" "run: frame" 300 "$wp"; streamed=$?
kill -9 "$wp" 2>/dev/null; wait "$wp" 2>/dev/null; st=$?  # no "Killed" notice
check "the long sweep is in the cache" "$([[ $streamed == 0 || $st == 0 ]]; echo $?)" "status $st: $(tail -3 "$warm")"

run_cases "$out" killed_rank corrupt_frame stopped_rank sigint sigterm term_mpirun layout
exit $fail
