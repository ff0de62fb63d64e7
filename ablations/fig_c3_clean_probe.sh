#!/bin/bash
# Fig. C.3 follow-up: do the 60-ghost models fail on the real HDM05 take
# because of the test's ghosts and occlusions, or on the take itself? Labels
# the take clean (OC_00_G_00_BT_00: nothing occluded, no ghost) and with the
# protocol's ghosts but no occlusion (OC_00_G_03_BT_00) with every finished
# model of a fig_c3 reproduction, per frame, and evaluates each as the
# reproduction does (`soma label`, `soma eval`).
#
#   bash ablations/fig_c3_clean_probe.sh <ledger> <out.csv> [soma binary]
#
# <ledger> is the reproduction's directory, results/reproduce/fig_c3-<hash>
# (its jobs.yaml names every model's directory and overrides). Runs go under
# <ledger>/clean_probe/ (kept: a finished evaluation is not redone); the
# table has one line per model and setting: the variant, the seed, the
# per-frame accuracy and F1 (mean over the take's frames, soma eval's
# metrics.yaml) and the model directory.
set -euo pipefail
if [[ $# -lt 2 ]]; then
  echo "usage: bash ablations/fig_c3_clean_probe.sh <results/reproduce/fig_c3-HASH> <out.csv> [soma]" >&2
  exit 2
fi
LEDGER=$1
OUT=$2
SOMA=${3:-./build/soma}
TAKE=../shared/data/c3d/HDM_mm_01-02_03_120.c3d
SETTINGS=(OC_00_G_00_BT_00 OC_00_G_03_BT_00)
RUNS=$LEDGER/clean_probe

if [[ ! -f $LEDGER/jobs.yaml ]]; then
  echo "fig_c3_clean_probe: $LEDGER/jobs.yaml is missing: pass the directory of a fig_c3 reproduction" >&2
  exit 1
fi
if [[ ! -f $TAKE ]]; then
  echo "fig_c3_clean_probe: $TAKE is missing (../shared/data)" >&2
  exit 1
fi

metric() { # metric <metrics.yaml> <key>
  awk -v k="$2:" '$1 == k { print $2 }' "$1"
}

# The variant of a model from its overrides (ablations/fig_c3.yaml).
variant() {
  case "$1" in
  *distribution=uniform*) echo ghosts60_uniform ;;
  *distribution=skewed_gaussian*) echo ghosts60_skewed ;;
  *noise=extreme_ghosts*) echo ghosts60_gaussian ;;
  *) echo base ;;
  esac
}

for setting in "${SETTINGS[@]}"; do
  data=$RUNS/testdata/$setting
  if [[ ! -f $data/$setting/HDM_mm_01-02_03_120.h5 ]]; then
    "$SOMA" corrupt "task.files=[$TAKE]" "task.settings=[$setting]" seed=0 \
      "hydra.run.dir=$data" >/dev/null
  fi
done

tmp="$OUT.tmp"
echo "variant,seed,setting,acc_mean,f1_mean,model_dir" >"$tmp"
# jobs.yaml: each job's overrides (a list) come before its dir.
awk '/^- num:/ { o = "" } /^  - / { o = o " " $2 } /^  dir:/ { print $2 "\t" o }' \
  "$LEDGER/jobs.yaml" | while IFS=$'\t' read -r dir overrides; do
  checkpoint=$dir/checkpoints/best.pt
  if [[ ! -f $checkpoint ]]; then
    echo "fig_c3_clean_probe: $checkpoint is missing (not trained yet): skipped" >&2
    continue
  fi
  name=$(variant "$overrides")
  seed=${dir##*seed}
  for setting in "${SETTINGS[@]}"; do
    run=$RUNS/$name/seed$seed/$setting
    if [[ ! -f $run/eval/metrics.yaml ]]; then
      echo "label $name seed $seed: $setting"
      "$SOMA" label "task.input=$RUNS/testdata/$setting/$setting/HDM_mm_01-02_03_120.c3d" \
        "task.checkpoint=$checkpoint" task.tracklet=false task.inference.seed=0 threads=1 \
        "hydra.run.dir=$run/label" >/dev/null
      "$SOMA" eval "task.gt=$RUNS/testdata/$setting/$setting/HDM_mm_01-02_03_120.h5" \
        "task.rec=$run/label/HDM_mm_01-02_03_120_labeled.c3d" "hydra.run.dir=$run/eval" >/dev/null
    fi
    acc=$(metric "$run/eval/metrics.yaml" acc_mean)
    f1=$(metric "$run/eval/metrics.yaml" f1_mean)
    echo "$name,$seed,$setting,$acc,$f1,$dir" >>"$tmp"
  done
done
mv "$tmp" "$OUT"
echo "wrote $OUT"
