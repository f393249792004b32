#!/usr/bin/env bash
# The real-data benchmark: every tracked recording of ../shared/data/plus
# streamed at its native frame size through the MPI pipeline, paced as a
# scanner would send it, with its own PLUS config (calibration, clip
# rectangle, fan) and the default reconstruction method, into a grid of
# --spacing mm. For each run: frames/s in, images/s out, frames dropped,
# latency median and p95, and each stage's time per frame while streaming
# (the busiest rank's, from stats.csv).
#
# Usage: scripts/bench_recordings.sh [--ranks N] [--spacing MM] [--fps F] [--runs N]
#                                    [--only NAME] [--out DIR] [--bin PP5ECHO] [--set KEY=VALUE]...
#   --ranks    MPI ranks (default 4: the host, 2 graphics and 1 pixel processor)
#   --spacing  voxel size in mm (default 0.5, the grid PLUS's configs use)
#   --fps      pace of the stream (default 30)
#   --runs     runs of each recording (default 1; the table gives each run)
#   --only     only the recordings whose name contains NAME
#   --set      passed on to `pp5echo run` (repeatable), e.g. --set 'recon.method="trilinear"'
#   --out      folder of the runs and the results (default out/bench_recordings)
#   --bin      the pp5echo to run (default build/src/app/pp5echo, built by scripts/build.sh if missing)
# Writes OUT/recordings.csv (a row per run) and OUT/recordings.md (the table it prints).
# Needs a build (scripts/build.sh makes one when build/ has none).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
ranks=4 spacing=0.5 fps=30 runs=1 only="" out=out/bench_recordings bin=
extra=()
while [ $# -gt 0 ]; do
  case "$1" in
    --ranks|--spacing|--fps|--runs|--only|--out|--bin|--set)
      [ $# -ge 2 ] || { echo "bench_recordings.sh: $1 needs a value" >&2; exit 2; }
      case "$1" in
        --ranks) ranks=$2 ;; --spacing) spacing=$2 ;; --fps) fps=$2 ;; --runs) runs=$2 ;;
        --only) only=$2 ;; --out) out=$2 ;; --bin) bin=$2 ;; --set) extra+=(--set "$2") ;;
      esac
      shift 2 ;;
    -h|--help) sed -n '2,21p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "bench_recordings.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done
for v in "$ranks" "$runs"; do [[ "$v" =~ ^[1-9][0-9]*$ ]] || { echo "bench_recordings.sh: '$v' is not a positive count" >&2; exit 2; }; done
for v in "$spacing" "$fps"; do [[ "$v" =~ ^[0-9]*\.?[0-9]+$ ]] || { echo "bench_recordings.sh: '$v' is not a positive number" >&2; exit 2; }; done

data=$root/../shared/data/plus
[ -d "$data" ] || { echo "bench_recordings.sh: no recordings at $data" >&2; exit 1; }
if [ -n "$bin" ]; then
  [ -x "$bin" ] || { echo "bench_recordings.sh: $bin is not an executable" >&2; exit 2; }
else
  bin=$root/build/src/app/pp5echo
  [ -x "$bin" ] || bin=$root/$(bash scripts/build.sh | tail -n 1)/src/app/pp5echo
fi

# Each recording with the config PLUS's own tests use for it (../shared/data/plus/README.md).
recordings=(
  "spine SpinePhantomFreehand.igs.mha PlusDeviceSet_SpinePhantomFreehandReconstructionOnly.xml"
  "bone_l14 BoneUltrasound_L14.igs.mha BoneUltrasound_L14_config.xml"
  "nwire NwirePhantomFreehand.igs.mha PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml"
  "nwire_cropped NwirePhantomFreehandCropped.igs.mha PlusDeviceSet_OpenIGTLinkCommandsTest.xml"
  "fcal12 fCal_Test_Calibration_3NWires.igs.mha PlusDeviceSet_Server_Sim_NwirePhantom.xml"
  "fcal20 fCal_Test_Calibration_3NWires_fCal2.0.igs.mha PlusDeviceSet_fCal_Sim_VolumeReconstruction.xml"
)

mkdir -p "$out"
csv=$out/recordings.csv
echo "recording,run,frames,frames_per_s_in,images_per_s_out,dropped,latency_median_ms,latency_p95_ms,receive_ms,reconstruct_ms,shade_ms,sample_ms,composite_ms,exit" >"$csv"
total=0
for rec in "${recordings[@]}"; do [[ -z "$only" || "${rec%% *}" == *"$only"* ]] && total=$((total + runs)); done
[ "$total" -gt 0 ] || { echo "bench_recordings.sh: no recording matches '$only'" >&2; exit 2; }
n=0
for rec in "${recordings[@]}"; do
  read -r name seq cfg <<<"$rec"
  [[ -z "$only" || "$name" == *"$only"* ]] || continue
  for ((r = 1; r <= runs; r++)); do
    n=$((n + 1))
    dir=$out/$name-$r
    rm -rf "$dir"
    echo "bench_recordings.sh: [$n/$total] $name (run $r): $seq at ${fps} frames/s, ${spacing} mm, $ranks ranks" >&2
    rc=0
    bash scripts/mpirun.sh "$ranks" "$bin" run --set 'run.source="sequence"' --set "run.sequence=\"$data/$seq\"" \
      --set "run.plus_config=\"$data/$cfg\"" --set "run.pace_fps=$fps" --set "grid.spacing=[$spacing,$spacing,$spacing]" \
      "${extra[@]}" -o "$dir" >"$out/$name-$r.log" 2>&1 || rc=$?
    if [ "$rc" != 0 ] || [ ! -f "$dir/summary.json" ]; then
      echo "bench_recordings.sh: $name run $r failed (exit $rc); the last lines of $out/$name-$r.log:" >&2
      tail -n 5 "$out/$name-$r.log" >&2
      echo "$name,$r,,,,,,,,,,,,$rc" >>"$csv"
      continue
    fi
    python3 - "$dir" "$name" "$r" >>"$csv" <<'EOF'
import collections, csv, json, sys
d = sys.argv[1]
s = json.load(open(d + "/summary.json"))
frames = max(1, s["frames"])
# Each stage's time over the stream (stats.csv's rows with control = 0; the
# final images, orbit and volume are the control rows), summed per rank: the
# busiest rank's, per frame in.
stages = ("receive", "reconstruct", "shade", "sample", "composite")
tot = collections.defaultdict(float)
for row in csv.DictReader(open(d + "/stats.csv")):
    if row["control"] == "0":
        for k in stages:
            tot[(row["rank"], k)] += float(row[k + "_ms"])
per = [max([v for (_, k2), v in tot.items() if k2 == k] or [0.0]) / frames for k in stages]
row = [sys.argv[2], sys.argv[3], s["frames"], s["frames_per_s_in"], s["images_per_s_out"], s["dropped_frames"],
       s["latency_ms_median"], s["latency_ms_p95"]] + per + [0]
print(",".join(f"{v:.2f}" if isinstance(v, float) else str(v) for v in row))
EOF
  done
done

python3 - "$csv" "$out/recordings.md" "$ranks" "$spacing" "$fps" <<'EOF'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
head = ("| recording | run | frames | frames/s in | images/s out | dropped | latency median | p95 | "
        "per frame: receive | reconstruct | shade | sample | composite |")
lines = [f"{sys.argv[3]} ranks, {sys.argv[4]} mm, paced at {sys.argv[5]} frames/s; stage times in ms per frame "
         "(the busiest rank's)", "", head, "|" + "---|" * 13]
for r in rows:
    if r["exit"] != "0":
        lines.append(f"| {r['recording']} | {r['run']} | failed (exit {r['exit']}) |" + " |" * 10)
        continue
    lines.append("| " + " | ".join([r["recording"], r["run"], r["frames"], r["frames_per_s_in"], r["images_per_s_out"],
                                    r["dropped"], r["latency_median_ms"] + " ms", r["latency_p95_ms"] + " ms",
                                    r["receive_ms"], r["reconstruct_ms"], r["shade_ms"], r["sample_ms"],
                                    r["composite_ms"]]) + " |")
text = "\n".join(lines) + "\n"
open(sys.argv[2], "w").write(text)
print(text)
failed = sum(r["exit"] != "0" for r in rows)
sys.exit(1 if failed else 0)
EOF
