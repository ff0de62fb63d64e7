#!/bin/bash
# Fits the marker layout of Table 5's "+ target layout" row. SOMA's protocol
# for a new dataset is to fit its marker layout to one labelled frame
# (MoSh on a single frame; here `soma fit_layout`, issue #8) and to train on
# it. Our other rows train on the built-in cmu41 layout, which matches the
# CMU take but not the HDM05 one (HDM05's RBAC sits left of the spine).
# The frame is frame 0 of the HDM05 test take itself, the only HDM05 take in
# ../shared/data: one frame's marker positions, no labels of the frames the
# table scores beyond that one.
#   bash ablations/make_layouts.sh [soma binary] [data dir]
# Output: results/layouts/hdm05.json (+ .csv, the run under results/layouts/).
set -euo pipefail
SOMA=${1:-./build/soma}
DATA=${2:-${SOMA_SHARED_DATA:-../shared/data}}
OUT=results/layouts
take=HDM_mm_01-02_03_120
"$SOMA" fit_layout "$DATA/c3d/$take.c3d" task.frame=0 hydra.run.dir="$OUT/fit_$take"
cp "$OUT/fit_$take/${take}_layout.json" "$OUT/hdm05.json.tmp"
mv "$OUT/hdm05.json.tmp" "$OUT/hdm05.json"
cp "$OUT/fit_$take/${take}_layout.csv" "$OUT/hdm05.csv"
echo "wrote $OUT/hdm05.json"
