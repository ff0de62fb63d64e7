#!/usr/bin/env bash
# The backlog policies of `soma stream` when frames come faster than they are
# labelled: the corrupted HDM05 take of run_accuracy.sh (seed 0) replayed at
# 1x-32x its capture rate (120-3840 Hz), catch_up vs drop. Writes
# backlog.csv beside this script.
#   bash results/stream/run_backlog.sh [soma binary] [work dir]
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
soma=${1:-$root/build/soma}
work=${2:-${TMPDIR:-/tmp}/soma_stream_accuracy}
take=HDM_mm_01-02_03_120
corrupted=$work/label_eval_${take}_0/OC_05_G_03_BT_50/$take
metric() { sed -n "s/^$2: //p" "$1/metrics.yaml"; }
echo "speed,rate_hz,backlog,frames,frames_dropped,frames_late,latency_p50_ms,latency_p99_ms,latency_max_ms,online_acc" > "$here/backlog.csv.tmp"
for speed in 1 8 32; do
  for backlog in catch_up drop; do
    run=$work/backlog_${speed}_$backlog
    "$soma" stream "$corrupted.c3d" task.model=hdm05 task.c3d.speed=$speed task.backlog=$backlog \
      task.gt="$corrupted.h5" hydra.run.dir="$run" > /dev/null
    echo "$speed,$((120 * speed)),$backlog,$(metric "$run" frames),$(metric "$run" frames_dropped),$(metric "$run" frames_late),$(metric "$run" latency_p50_ms),$(metric "$run" latency_p99_ms),$(metric "$run" latency_max_ms),$(metric "$run" online_acc)" >> "$here/backlog.csv.tmp"
  done
done
mv "$here/backlog.csv.tmp" "$here/backlog.csv"
cat "$here/backlog.csv"
