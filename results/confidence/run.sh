#!/usr/bin/env bash
# Calibrated confidence on the two real 41-marker takes (issue #25 item 4;
# results/confidence/README.md). From the repository root with build/soma
# built. MODELS: the directory of the bundled models to measure (default
# models/; the README's numbers used the eb59135 models, MODELS=/work/main/models).
set -euo pipefail
MODELS=${MODELS:-models}
DATA=${DATA:-../shared/data/c3d}
RUNS=${RUNS:-/tmp/confidence_runs}
OUT=results/confidence
metric() { grep "^$2:" "$1/metrics.yaml" | awk '{print $2}'; }
for pair in "cmu41 cmu_01_01" "hdm05 HDM_mm_01-02_03_120"; do
  set -- $pair
  model=$1 take=$2 dir=$OUT/$1_$2
  mkdir -p "$dir"
  # 1. The temperature, on the training run's 2000 synthetic validation frames.
  ./build/soma calibrate task.checkpoint="$MODELS/$model/model.pt" \
      task.output="$dir/calibration.yaml" hydra.run.dir="$RUNS/calibrate_$model" threads=1
  cp "$RUNS/calibrate_$model/reliability.csv" "$dir/synthetic_reliability.csv"
  cp "$RUNS/calibrate_$model/reliability.png" "$dir/synthetic_reliability.png"
  # 2. label_eval (OC_05_G_03_BT_00, seed 0) with the rows only renormalised
  #    (T = 1) and with the fitted temperature.
  for cal in none calibrated; do
    file=none; [[ $cal == calibrated ]] && file="$dir/calibration.yaml"
    run="$RUNS/label_eval_${model}_$cal"
    ./build/soma label_eval "$DATA/$take.c3d" task.checkpoint="$MODELS/$model/model.pt" \
        task.calibration="$file" hydra.run.dir="$run" threads=1
    mkdir -p "$dir/$cal"
    cp "$run/summary.md" "$run/metrics.yaml" "$dir/$cal/"
    for mode in per_frame tracklet; do
      for f in reliability.csv reliability.png precision_coverage.csv precision_coverage.png; do
        cp "$run/$mode/$f" "$dir/$cal/${mode}_$f"
      done
    done
  done
  # 3. The review list at the threshold that keeps 99.5% precision per frame,
  #    runs of a label up to 12 frames (0.1 s at 120 Hz) apart merged.
  threshold=$(metric "$RUNS/label_eval_${model}_calibrated" per_frame_threshold_at_precision)
  run="$RUNS/label_eval_${model}_review"
  ./build/soma label_eval "$DATA/$take.c3d" task.checkpoint="$MODELS/$model/model.pt" \
      task.calibration="$dir/calibration.yaml" task.min_confidence="$threshold" task.review_gap=12 \
      hydra.run.dir="$run" threads=1
  mkdir -p "$dir/review"
  cp "$run/summary.md" "$run/metrics.yaml" "$dir/review/"
  cp "$run/per_frame/${take}_review.csv" "$dir/review/per_frame_review.csv"
  cp "$run/tracklet/${take}_review.csv" "$dir/review/tracklet_review.csv"
done
