#!/bin/bash
# Builds the real-marker noise bank of Table 5's "+ real-noise model" row
# (SOMA's AMASS noise model, REFERENCE.md 3.4) from the labelled real takes
# of ../shared/data that are NOT test takes of any spec (cmu_01_01 and
# HDM_mm_01-02_03_120 are): each is fitted with `soma solve` on the 41-marker
# layout and the residuals observed - simulated go into one bank.
#   bash ablations/make_noise_bank.sh [soma binary] [data dir]
# Output: results/noise_bank/cmu41.h5 (+ .csv, the runs under results/noise_bank/).
set -euo pipefail
SOMA=${1:-./build/soma}
DATA=${2:-${SOMA_SHARED_DATA:-../shared/data}}
OUT=results/noise_bank
TAKES=(Movement_trial PiG_Calibration-FlatFoot-Full PiG_Motion-FlatFoot-Hole shd01)
fits=()
for take in "${TAKES[@]}"; do
  "$SOMA" solve "$DATA/c3d/$take.c3d" layout=cmu41 hydra.run.dir="$OUT/solve_$take"
  fits+=("$OUT/solve_$take/${take}_stageii.h5")
done
list=$(IFS=,; echo "${fits[*]}")
"$SOMA" noise_bank "task.fits=[$list]" task.output="$(pwd)/$OUT/cmu41.h5" \
  hydra.run.dir="$OUT/bank"
cp "$OUT/bank/noise_bank.csv" "$OUT/cmu41.csv"
