#!/bin/bash
# Fits the marker layouts of the target-layout rows. SOMA's protocol for a new
# dataset is to fit its marker layout to one labelled frame (MoSh on a single
# frame; here `soma fit_layout`, issue #8) and to train on it.
#   hdm05.json  Table 5's "+ target layout" row and every table at the
#               headline budget. Our quick-budget rows train on the built-in
#               cmu41 layout, which matches the CMU take but not the HDM05 one
#               (HDM05's RBAC sits left of the spine). The frame is frame 0 of
#               the HDM05 test take itself, the only HDM05 take in
#               ../shared/data: one frame's marker positions, no labels of the
#               frames the table scores beyond that one.
#   pig.json    the Plug-in Gait test of ablations/any_layout.yaml: frame 0 of
#               the subject's static calibration trial
#               (PiG_Calibration-FlatFoot-Full), fitted with superset89's
#               alias table (every Plug-in Gait marker is recognised; the
#               model's virtual points are left out); scored on the motion
#               trial of the same subject.
# A layout that exists is kept: models are keyed by the layout's path, so a
# refitted file would change what an existing model directory means. Delete
# it to refit.
#   bash ablations/make_layouts.sh [soma binary] [data dir]
# Output: results/layouts/<name>.json (+ .csv, the run under results/layouts/).
set -euo pipefail
SOMA=${1:-./build/soma}
DATA=${2:-${SOMA_SHARED_DATA:-../shared/data}}
OUT=results/layouts

# fit <name> <take> [overrides...]
fit() {
  local name=$1 take=$2
  shift 2
  if [[ -e "$OUT/$name.json" ]]; then
    echo "kept $OUT/$name.json (delete it to refit)"
    return
  fi
  "$SOMA" fit_layout "$DATA/c3d/$take.c3d" task.frame=0 "$@" hydra.run.dir="$OUT/fit_$take"
  cp "$OUT/fit_$take/${take}_layout.json" "$OUT/$name.json.tmp"
  mv "$OUT/$name.json.tmp" "$OUT/$name.json"
  cp "$OUT/fit_$take/${take}_layout.csv" "$OUT/$name.csv"
  echo "wrote $OUT/$name.json"
}

fit hdm05 HDM_mm_01-02_03_120
fit pig PiG_Calibration-FlatFoot-Full layout=superset89
