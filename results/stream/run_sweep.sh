#!/usr/bin/env bash
# The online tracklet vote's two knobs (vote half-life, swap restart) on the
# corrupted takes of run_accuracy.sh, corruption seed 0. Needs that script's
# work dir. Writes sweep.csv beside this script.
#   bash results/stream/run_sweep.sh [soma binary] [work dir]
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
soma=${1:-$root/build/soma}
work=${2:-${TMPDIR:-/tmp}/soma_stream_accuracy}
setting=OC_05_G_03_BT_50
out=$here/sweep.csv
echo "take,half_life,swap_frames,online_acc,swaps" > "$out.tmp"
for spec in HDM_mm_01-02_03_120:hdm05 cmu_01_01:cmu41; do
  take=${spec%%:*}
  model=${spec##*:}
  corrupted=$work/label_eval_${take}_0/$setting/$take
  for half_life in 0 60 240 1000; do
    for swap in 0 30; do
      run=$work/sweep_${take}_${half_life}_$swap
      "$soma" stream "$corrupted.c3d" task.c3d.realtime=false task.model=$model \
        task.gt="$corrupted.h5" task.tracklet.half_life=$half_life \
        task.tracklet.swap_frames=$swap hydra.run.dir="$run" > /dev/null
      echo "$take,$half_life,$swap,$(sed -n 's/^online_acc: //p' "$run/metrics.yaml"),$(sed -n 's/^swaps: //p' "$run/metrics.yaml")" >> "$out.tmp"
    done
  done
done
mv "$out.tmp" "$out"
cat "$out"
