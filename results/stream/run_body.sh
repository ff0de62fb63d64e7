#!/usr/bin/env bash
# The online body of `soma stream` (task.solve.enabled=true) on the CMU take
# corrupted by run_accuracy.sh (seed 0), against `soma solve` of the clean,
# ground-truth-labelled take: body-fit metrics of `soma eval` (V2V, joint
# error, PCK). Writes body.csv beside this script. The replay runs as fast as
# possible, which would outrun a background stage I (the stream's default), so
# stage I runs in the foreground here: stage II then solves every frame after
# the calibration segment.
#   bash results/stream/run_body.sh [soma binary] [work dir]
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
soma=${1:-$root/build/soma}
work=${2:-${TMPDIR:-/tmp}/soma_stream_accuracy}
take=cmu_01_01
corrupted=$work/label_eval_${take}_0/OC_05_G_03_BT_50/$take
metric() { sed -n "s/^$2: //p" "$1/metrics.yaml"; }
"$soma" solve "$root/../shared/data/c3d/$take.c3d" hydra.run.dir="$work/solve_$take" > /dev/null
echo "max_solver_time_ms,body_frames,body_mean_rms_mm,solve_p50_ms,solve_p99_ms,latency_p50_ms,latency_p99_ms,body_latency_p50_ms,body_latency_p99_ms,body_latency_max_ms,v2v_mm,joint_err_mm,pck10,pck30" > "$here/body.csv.tmp"
for limit in 2 4; do
  run=$work/stream_body_${take}_$limit
  "$soma" stream "$corrupted.c3d" task.c3d.realtime=false task.model=cmu41 \
    task.solve.enabled=true task.solve.background=false \
    task.solve.max_solver_time_ms=$limit hydra.run.dir="$run" > /dev/null
  "$soma" eval task.gt=null task.rec=null task.body_fit_gt="$work/solve_$take/${take}_stageii.h5" \
    task.body_fit_rec="$run/${take}_stageii.h5" hydra.run.dir="$run/eval_body" > /dev/null
  e=$run/eval_body
  echo "$limit,$(metric "$run" body_frames),$(metric "$run" body_mean_rms_mm),$(metric "$run" solve_p50_ms),$(metric "$run" solve_p99_ms),$(metric "$run" latency_p50_ms),$(metric "$run" latency_p99_ms),$(metric "$run" body_latency_p50_ms),$(metric "$run" body_latency_p99_ms),$(metric "$run" body_latency_max_ms),$(metric "$e" v2v_mm),$(metric "$e" joint_err_mm),$(metric "$e" pck10),$(metric "$e" pck30)" >> "$here/body.csv.tmp"
done
mv "$here/body.csv.tmp" "$here/body.csv"
cat "$here/body.csv"
