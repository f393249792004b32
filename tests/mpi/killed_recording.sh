#!/usr/bin/env bash
# A live recording survives any rank killed with SIGKILL. An OpenIGTLink
# server streams 300 frames at 30 frames/s into `pp5echo record` under
# mpirun; once the recording's journal holds 60 frames (read while it is being
# written), one rank is killed with kill -9: the host (rank 0), a graphics
# processor (rank 1) or a pixel processor (rank 3). Afterwards, the recording
# (restored from its journal by `pp5echo restore` where the job left one)
# holds at least those 60 frames, and they are the first frames the server
# sent, pixel and pose alike, read by an independent reader of PLUS's format
# (tests/plus_mha.py) and by pp5echo; nothing half-written is left beside it.
# The three kills run side by side (tests/mpi/cases.sh), each with its own
# server, job and folder.
# Usage: killed_recording.sh PP5ECHO IGTL_SERVER SRCDIR WORKDIR
set -uo pipefail
bin=$1 server=$2 src=$3 work=$4
source "$src/tests/mpi/cases.sh"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
rm -rf "$work" && mkdir -p "$work"
cfg=$src/tests/configs/board_small.toml
fail=0
complete_frames() {  # what pp5echo reads from a journal now, while it is written
  "$bin" info "$1" 2>/dev/null | grep -o '"complete_frames": [0-9]*' | grep -o '[0-9]*$'
}

"$bin" simulate "$cfg" -o "$work/sim" > "$work/simulate.log" 2>&1 || { echo "FAIL: simulate"; exit 1; }
seq=$work/sim/doll_sweep.igs.mha

kill_rank() {  # kill_rank RANK
  local victim=$1 name=("host" "graphics processor" "" "pixel processor") what w spid mp journal before n pid st rec kept left
  what="kill -9 ${name[$victim]} (rank $victim)"
  w=$work/rank$victim
  mkdir -p "$w"
  "$server" "$seq" --port 0 --port-file "$w/port" --frames 300 --fps 30 --transform ProbeToTracker \
    --write-sent "$w/sent.igs.mha" > "$w/server.log" 2>&1 &
  spid=$!
  for _ in $(seq 100); do [ -s "$w/port" ] && break; sleep 0.1; done
  mpirun -n 4 "$bin" record "$cfg" -o "$w/out" --source "igtl://127.0.0.1:$(cat "$w/port")" \
    --set "run.plus_config=\"$work/sim/doll_config.xml\"" --set run.igtl_reconnect_s=0 > "$w/run.log" 2>&1 &
  mp=$!
  journal=$w/out/recording.mha.journal
  before=0
  for _ in $(seq 300); do
    n=$(complete_frames "$journal")
    if [[ -n "$n" && $n -ge 60 ]]; then before=$n; break; fi
    sleep 0.1
  done
  check "$what: the journal is read while it is written ($before frames)" "$([[ $before -ge 60 ]]; echo $?)" \
    "$(tail -3 "$w/run.log")"
  pid=$(rank_pid "$mp" "$victim")
  [[ -n "$pid" ]] && kill -9 "$pid"
  timeout 60 tail --pid="$mp" -f /dev/null; wait "$mp"; st=$?
  timeout 30 tail --pid="$spid" -f /dev/null; wait "$spid" 2>/dev/null
  check "$what: the job ends non-zero" "$([[ -n "$pid" && $st -ne 0 ]]; echo $?)" "status $st, pid '$pid'"
  if [[ -f "$journal" ]]; then
    "$bin" restore "$journal" > "$w/restore.log" 2>&1
    check "$what: pp5echo restore" "$?" "$(cat "$w/restore.log")"
    check "$what: the journal is gone once restored" "$([[ ! -e "$journal" ]]; echo $?)" "still there"
  fi
  rec=$w/out/recording.mha
  kept=$(python3 "$src/tests/plus_mha.py" count "$rec" 2>&1)
  check "$what: the recording keeps every frame journalled before the kill ($kept >= $before)" \
    "$([[ "$kept" =~ ^[0-9]+$ && $kept -ge $before ]]; echo $?)" "$kept"
  python3 "$src/tests/plus_mha.py" prefix "$rec" "$w/sent.igs.mha" > "$w/prefix.log" 2>&1
  check "$what: they are the first frames sent, pixels and poses" "$?" "$(cat "$w/prefix.log")"
  "$bin" info "$rec" 2>&1 | grep -q "\"frame_count\": $kept" 
  check "$what: pp5echo reads them" "$?" "$("$bin" info "$rec" 2>&1 | tail -3)"
  check "$what: the output folder is marked unfinished" "$([[ -f "$w/out/RUN_INCOMPLETE.txt" ]]; echo $?)" \
    "$(ls "$w/out")"
  left=$(find "$w/out" -name '.recording.mha.tmp-*' | wc -l)
  check "$what: nothing half-written left beside it" "$([[ $left -eq 0 ]]; echo $?)" "$(ls -a "$w/out")"
}
kill_host() { kill_rank 0; }
kill_graphics_processor() { kill_rank 1; }
kill_pixel_processor() { kill_rank 3; }

run_cases "$work" kill_host kill_graphics_processor kill_pixel_processor
exit $fail
