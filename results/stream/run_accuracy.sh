#!/usr/bin/env bash
# Online (soma stream) vs offline (soma label_eval) labelling accuracy on the
# two real 41-marker takes corrupted with OC_05_G_03_BT_50, corruption seeds
# 0-2, bundled models. Writes accuracy.csv beside this script.
#   bash results/stream/run_accuracy.sh [soma binary] [work dir]
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
soma=${1:-$root/build/soma}
work=${2:-${TMPDIR:-/tmp}/soma_stream_accuracy}
data=$root/../shared/data/c3d
setting=OC_05_G_03_BT_50
mkdir -p "$work"
metric() { sed -n "s/^$2: //p" "$1/metrics.yaml"; }
out=$here/accuracy.csv
echo "take,model,seed,offline_per_frame_acc,offline_tracklet_acc,stream_per_frame_acc,online_acc,online_null_all_acc,latency_p50_ms,latency_p99_ms,latency_max_ms" > "$out.tmp"
for spec in HDM_mm_01-02_03_120:hdm05 cmu_01_01:cmu41; do
  take=${spec%%:*}
  model=${spec##*:}
  for seed in 0 1 2; do
    le=$work/label_eval_${take}_$seed
    "$soma" label_eval "$data/$take.c3d" task.setting=$setting task.model=$model \
      seed=$seed hydra.run.dir="$le" > /dev/null
    corrupted=$le/$setting/$take
    st=$work/stream_${take}_$seed
    "$soma" stream "$corrupted.c3d" task.c3d.realtime=false task.model=$model \
      task.gt="$corrupted.h5" hydra.run.dir="$st" > /dev/null
    na=$work/stream_null_all_${take}_$seed
    "$soma" stream "$corrupted.c3d" task.c3d.realtime=false task.model=$model \
      task.gt="$corrupted.h5" task.tracklet.duplicates=null_all \
      hydra.run.dir="$na" > /dev/null
    echo "$take,$model,$seed,$(metric "$le" per_frame_acc),$(metric "$le" tracklet_acc),$(metric "$st" per_frame_acc),$(metric "$st" online_acc),$(metric "$na" online_acc),$(metric "$st" latency_p50_ms),$(metric "$st" latency_p99_ms),$(metric "$st" latency_max_ms)" >> "$out.tmp"
  done
done
mv "$out.tmp" "$out"
cat "$out"
