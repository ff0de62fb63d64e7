#!/usr/bin/env bash
# Calibrated confidence of a layout-conditioned model (issue #25 item 4;
# results/confidence/README.md, "The layout-conditioned model"): the
# temperature fitted on the model's own synthetic validation frames, each
# labelled against its sampled layout, then label_eval on the real takes of
# `soma reproduce any_layout` (HDM05, CMU, Plug-in Gait) with the take's
# layout given at label time. From the
# repository root with build/soma built and the fitted layouts made
# (bash ablations/make_layouts.sh).
#   CKPT=<run>/checkpoints/best.pt NAME=<dir name> bash results/confidence/run_any_layout.sh
set -euo pipefail
CKPT=${CKPT:?checkpoint of the conditioned model}
NAME=${NAME:?the output directory under results/confidence}
DATA=${DATA:-../shared/data/c3d}
RUNS=${RUNS:-/tmp/confidence_runs/$NAME}
OUT=results/confidence/$NAME
mkdir -p "$OUT"
# 1. The temperature, on the training run's synthetic validation frames, by
#    the least NLL (the default) and by the least ECE.
for objective in nll ece; do
  ./build/soma calibrate task.checkpoint="$CKPT" task.objective=$objective \
      task.output="$OUT/calibration_$objective.yaml" \
      hydra.run.dir="$RUNS/calibrate_$objective" threads=1
  for f in reliability.csv reliability.png metrics.yaml; do
    cp "$RUNS/calibrate_$objective/$f" "$OUT/synthetic_${objective}_$f"
  done
done
# 2. label_eval (OC_05_G_03_BT_00, seed 0): rows renormalised (T = 1), and
#    with each fitted temperature.
for spec in "hdm05 HDM_mm_01-02_03_120 layout=file layout.path=results/layouts/hdm05.json" \
            "cmu cmu_01_01 layout=cmu41" \
            "pig PiG_Motion-FlatFoot-Hole layout=file layout.path=results/layouts/pig.json layout.allow_unknown_labels=true"; do
  set -- $spec
  test=$1 take=$2
  shift 2
  for cal in none nll ece; do
    file=none; [[ $cal != none ]] && file="$OUT/calibration_$cal.yaml"
    run="$RUNS/label_eval_${test}_$cal"
    ./build/soma label_eval "$DATA/$take.c3d" task.checkpoint="$CKPT" \
        task.calibration="$file" "$@" hydra.run.dir="$run" threads=1
    dir="$OUT/${test}_$cal"
    mkdir -p "$dir"
    cp "$run/summary.md" "$run/metrics.yaml" "$dir/"
    for f in reliability.csv reliability.png precision_coverage.csv precision_coverage.png; do
      cp "$run/per_frame/$f" "$dir/per_frame_$f"
    done
  done
done
