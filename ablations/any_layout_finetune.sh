#!/bin/bash
# Issue #25 item 3, fine-tuning: how many minutes of training on a new layout
# close what is left of the gap between the layout-conditioned model and the
# per-layout one. Starts from the conditioned models of `soma reproduce
# any_layout` (variant any_layout: never trained on the test layouts), trains
# each further on one test take's layout for E epochs (`train.init_from`, the
# same budget otherwise), and scores it on that take exactly as the
# reproduction does (the same corrupted take, `soma label` with the layout,
# `soma eval`).
#
#   [BASE=<model dir>] [TRAIN_ARGS="key=value ..." TAG=<name>] [OUT=<table.csv>] \
#   [TARGETS="hdm05 pig"] \
#   bash ablations/any_layout_finetune.sh [soma binary] [epochs="1 2 4"] [seeds="0 1 2"]
#
# BASE: another conditioned variant to start from, its directory under
# results/reproduce/models/ (e.g. any_layout_perturbed8r_fourier_60's); its
# seeds' model.* overrides (.hydra/overrides.yaml) are passed on, since the
# network must match the checkpoint. Its runs go under
# results/reproduce/finetune/<BASE's name>/, and OUT defaults to
# results/any_layout_finetune_<BASE's name>.csv. TRAIN_ARGS: more overrides
# of the fine-tuning runs (e.g. optimizer.lr=1e-4); they need a TAG, which
# names their runs and table (<BASE's name>_<TAG>). TARGETS: the takes to
# fine-tune for (hdm05, pig; default both).
#
# Needs the finished any_layout reproduction (its models and test data under
# results/reproduce/) and the fitted layouts (ablations/make_layouts.sh).
# Runs go under results/reproduce/finetune/ (kept: a finished run is not
# trained again); the table is results/any_layout_finetune.csv, one line per
# target, seed and epoch count: the training minutes (the sum of the epochs'
# wall time in metrics.csv) and the per-frame accuracy and F1 (mean over the
# take's frames, from soma eval's metrics.yaml). Epochs 0 is the conditioned
# model itself, from the reproduction's own evaluation of it on the take
# (left out when the reproduction did not label that take with it).
set -euo pipefail
SOMA=${1:-./build/soma}
EPOCHS=${2:-1 2 4}
SEEDS=${3:-0 1 2}
BUDGET=(scale=cpu)
read -r -a train_args <<<"${TRAIN_ARGS:-}"
if [[ ${#train_args[@]} -gt 0 && -z ${TAG:-} ]]; then
  echo "any_layout_finetune: TRAIN_ARGS needs a TAG naming its runs and table" >&2
  exit 1
fi
if [[ -n ${BASE:-} ]]; then
  base=${BASE%/}
  if [[ ! -d $base ]]; then
    echo "any_layout_finetune: BASE=$base is not a directory" \
      "(expected a model directory under results/reproduce/models/)" >&2
    exit 1
  fi
  runs_name=$(basename "$base")${TAG:+_$TAG}
  RUNS=results/reproduce/finetune/$runs_name
  OUT=${OUT:-results/any_layout_finetune_$runs_name.csv}
elif [[ -n ${TAG:-} ]]; then
  echo "any_layout_finetune: TAG needs a BASE" >&2
  exit 1
else
  RUNS=results/reproduce/finetune
  OUT=${OUT:-results/any_layout_finetune.csv}
  # The variant any_layout's directory: the other mixed variants
  # (any_layout_perturbed*) share its name's prefix and set perturbed_layouts.
  models=()
  for dir in results/reproduce/models/model-soma_any_layout_synth-layout_sampler-mixed-*; do
    overrides=$(cat "$dir"/seed*/.hydra/overrides.yaml 2>/dev/null || true)
    if [[ -d $dir && $overrides != *perturbed_layouts* ]]; then
      models+=("$dir")
    fi
  done
  if [[ ${#models[@]} -ne 1 ]]; then
    echo "any_layout_finetune: expected one any_layout model directory" \
      "(results/reproduce/models/model-soma_any_layout_synth-layout_sampler-mixed-*)," \
      "found ${#models[@]}: run soma reproduce any_layout first" >&2
    exit 1
  fi
  base=${models[0]}
fi

# target: name, take stem, layout file
all_targets=("hdm05 HDM_mm_01-02_03_120 results/layouts/hdm05.json"
  "pig PiG_Motion-FlatFoot-Hole results/layouts/pig.json")
targets=()
for name in ${TARGETS:-hdm05 pig}; do
  found=
  for target in "${all_targets[@]}"; do
    if [[ ${target%% *} == "$name" ]]; then
      targets+=("$target")
      found=1
    fi
  done
  if [[ -z $found ]]; then
    echo "any_layout_finetune: TARGETS names '$name'; expected hdm05 or pig" >&2
    exit 1
  fi
done

metric() {  # metric <metrics.yaml> <key>
  awk -v k="$2:" '$1 == k { print $2 }' "$1"
}

tmp="$OUT.tmp"
echo "target,seed,epochs,train_minutes,acc_mean,f1_mean,checkpoint" >"$tmp"
for target in "${targets[@]}"; do
  read -r name stem layout <<<"$target"
  if [[ ! -f $layout ]]; then
    echo "any_layout_finetune: $layout is missing: bash ablations/make_layouts.sh" >&2
    exit 1
  fi
  layout_args=(layout=file "layout.path=$layout" layout.allow_unknown_labels=true)
  take_dir=(results/reproduce/testdata/${stem}_OC_05_G_03_BT_00_seed0*/OC_05_G_03_BT_00)
  if [[ ! -f ${take_dir[0]}/$stem.c3d ]]; then
    echo "any_layout_finetune: no corrupted $stem under results/reproduce/testdata:" \
      "run soma reproduce any_layout first" >&2
    exit 1
  fi
  for seed in $SEEDS; do
    init="$base/seed$seed/checkpoints/best.pt"
    if [[ ! -f $init ]]; then
      echo "any_layout_finetune: $init is missing (the run is not finished)" >&2
      exit 1
    fi
    # The base's network: its model.* overrides (e.g. fourier_bands).
    mapfile -t model_args < <(sed -n 's/^- \(model\..*\)$/\1/p' "$base/seed$seed/.hydra/overrides.yaml")
    # Epochs 0: the conditioned model as it is, scored by the reproduction on
    # the same take (its tests/<take>_..._perframe_seed0_*/eval), if it did.
    base_eval=("$base/seed$seed/tests/${stem}_OC_05_G_03_BT_00_perframe_seed0_"*/eval/metrics.yaml)
    if [[ -f ${base_eval[0]} ]]; then
      echo "$name,$seed,0,0.00,$(metric "${base_eval[0]}" acc_mean),$(metric "${base_eval[0]}" f1_mean),$init" >>"$tmp"
    fi
    for epochs in $EPOCHS; do
      run="$RUNS/$name/seed$seed/epochs$epochs"
      if [[ ! -f $run/eval/metrics.yaml ]]; then
        echo "fine-tune $name seed $seed: $epochs epochs"
        mkdir -p "$run"
        if ! "$SOMA" train "${BUDGET[@]}" model=soma_any_layout "${model_args[@]}" "${layout_args[@]}" \
          "train.init_from=$init" "train.max_epochs=$epochs" "${train_args[@]}" "seed=$seed" threads=1 \
          "hydra.run.dir=$run/train" >"$run/train.log" 2>&1; then
          tail -3 "$run/train.log" >&2
          echo "any_layout_finetune: training failed, log: $run/train.log" >&2
          exit 1
        fi
        "$SOMA" label "task.input=${take_dir[0]}/$stem.c3d" \
          "task.checkpoint=$run/train/checkpoints/best.pt" task.tracklet=false \
          task.inference.seed=0 threads=1 "${layout_args[@]}" "hydra.run.dir=$run/label" >/dev/null
        "$SOMA" eval "task.gt=${take_dir[0]}/$stem.h5" \
          "task.rec=$run/label/${stem}_labeled.c3d" "hydra.run.dir=$run/eval" >/dev/null
      fi
      minutes=$(awk -F, 'NR == 1 { for (i = 1; i <= NF; ++i) if ($i == "wall_s") c = i }
        NR > 1 { s += $c } END { printf "%.2f", s / 60 }' "$run/train/metrics.csv")
      acc=$(metric "$run/eval/metrics.yaml" acc_mean)
      f1=$(metric "$run/eval/metrics.yaml" f1_mean)
      echo "$name,$seed,$epochs,$minutes,$acc,$f1,$run/train/checkpoints/best.pt" >>"$tmp"
    done
  done
done
mv "$tmp" "$OUT"
echo "wrote $OUT"
