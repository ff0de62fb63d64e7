#!/usr/bin/env bash
# `soma fit_layout` (issue #25 item 2: layouts for marker sets we have never
# seen) on every real take in ../shared/data/c3d: the body fitted to the
# markers the alias table recognises (layout=superset89, all 89 labels with an
# anatomical rule), every other marker placed on the fitted body. Res16bits
# (French anatomical names) also through res16bits_name_map.yaml. Takes that
# cannot be fitted get a row with the one-line error. Writes
# capture_layouts.csv beside this script, and each run's layout JSON/CSV under
# the work dir.
#   bash results/capture_layouts/run_capture_layouts.sh [soma binary] [work dir]
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
soma=$(realpath "${1:-$root/build/soma}")
work=$(realpath -m "${2:-${TMPDIR:-/tmp}/soma_capture_layouts}")
cd "$root"  # paths in the CSV relative to the project root
data=${SOMA_SHARED_DATA:-../shared/data}/c3d
mkdir -p "$work"
metric() { sed -n "s/^$2: //p" "$1/metrics.yaml" | awk '{printf "%g", $1}'; }
mm() { sed -n "s/^$2: //p" "$1/metrics.yaml" | awk '{printf "%.2f", $1}'; }
marker_set() {
  case "$1" in
    cmu_01_01) echo "CMU 41";;
    HDM_mm_*) echo "HDM05 41 (CMU names)";;
    Movement_trial) echo "Plug-in Gait 39 + PiG outputs";;
    PiG_*) echo "Plug-in Gait 35 + PiG outputs";;
    Gait) echo "Helen Hayes + upper body 33";;
    Res16bits*) echo "French anatomical 44";;
    shd01) echo "upper body 27 (Vicon names)";;
    vicon_nexus_markers_analogs) echo "shoulder 43 + box 8";;
    mocap36) echo "OptiTrack Skeleton_* 36";;
    Eb015*) echo "lower body 26 gait";;
    Optotrak_truncated) echo "Optotrak 54 generic";;
    phasespace_sample) echo "PhaseSpace 40 unlabelled";;
    *) echo "?";;
  esac
}
out=$here/capture_layouts.csv.tmp
echo "take,marker_set,name_map,markers,recognised,placed,not_placed,frame,fit_rms_mm,layout_rms_mm,fitted_layout_rms_mm,error" > "$out"
run_one() {  # take, name map ("" for none), run name
  local take=$1 map=$2 name=$3 run=$work/$3
  local args=("$data/$take.c3d" layout=superset89 hydra.run.dir="$run")
  [[ -n $map ]] && args+=(task.name_map="results/capture_layouts/$map")
  rm -rf "$run"
  if "$soma" fit_layout "${args[@]}" > "$run.log" 2>&1; then
    echo "$take,$(marker_set "$name"),$map,$(metric "$run" markers),$(metric "$run" recognised),$(metric "$run" placed),$(metric "$run" not_placed),$(metric "$run" frame),$(mm "$run" fit_rms_mm),$(mm "$run" layout_rms_mm),$(mm "$run" fitted_layout_rms_mm)," >> "$out"
  else
    local error
    error=$(grep -m1 "Job 0 failed: " "$run.log" | sed 's/.*Job 0 failed: //; s/,/;/g; s/"//g')
    echo "$take,$(marker_set "$name"),$map,,,,,,,,,\"$error\"" >> "$out"
  fi
}
for file in "$data"/*.c3d; do
  take=$(basename "$file" .c3d)
  run_one "$take" "" "$take"
done
run_one Res16bits res16bits_name_map.yaml Res16bits_name_map
mv "$out" "$here/capture_layouts.csv"
column -s, -t < "$here/capture_layouts.csv" | cut -c1-200
