#!/bin/bash
# Issue #25 follow-up: which labels does a layout-conditioned model miss on a
# real take, and are they the labels whose fitted place is far from the
# training layout's? One table, a row per label of the take's layout:
#   label, offset_cm      how far the label sits, on the rest body, from the
#                         same label of the reference layout (empty when the
#                         reference has no such label),
#   nearest_cm, nearest   the closest other label of the take's layout,
#   then the recall of each model given (soma eval's class_report.csv), and
#   the support (ground-truth points of the label) of the first.
#
#   bash ablations/any_layout_label_recall.sh <out.csv> <layout.json> \
#       <reference layout> NAME=<eval dir or class_report.csv>... [-- soma]
#
# <layout.json> is the take's layout (e.g. results/layouts/hdm05.json, from
# ablations/make_layouts.sh); <reference layout> a built-in name (soma53) or
# a layout JSON. Each NAME=PATH is a model's evaluation on the take, e.g.
# results/reproduce/models/<variant>/seed0/tests/<take>/eval. Rest positions
# come from `soma inspect task.pose=rest` (markers.csv), run in a temporary
# directory; the table is written atomically.
set -euo pipefail
if [[ $# -lt 4 ]]; then
  echo "usage: bash ablations/any_layout_label_recall.sh <out.csv> <layout.json> <reference layout> NAME=<eval dir>... [-- soma]" >&2
  exit 2
fi
OUT=$1
LAYOUT=$2
REFERENCE=$3
shift 3
SOMA=./build/soma
MODELS=()
while [[ $# -gt 0 ]]; do
  if [[ $1 == -- ]]; then
    SOMA=$2
    break
  fi
  MODELS+=("$1")
  shift
done
if [[ ! -f $LAYOUT ]]; then
  echo "any_layout_label_recall: layout file $LAYOUT not found (bash ablations/make_layouts.sh writes results/layouts/)" >&2
  exit 1
fi
layout_overrides() {
  if [[ -f $1 ]]; then
    echo "layout=file layout.path=$1 layout.allow_unknown_labels=true"
  else
    echo "layout=$1"
  fi
}
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
for which in take reference; do
  if [[ $which == take ]]; then src=$LAYOUT; else src=$REFERENCE; fi
  # shellcheck disable=SC2046
  if ! "$SOMA" task=inspect task.pose=rest $(layout_overrides "$src") \
    hydra.run.dir="$TMP/$which" >"$TMP/$which.log" 2>&1; then
    echo "any_layout_label_recall: soma inspect failed for layout $src (log: $(tail -1 "$TMP/$which.log"))" >&2
    exit 1
  fi
done
HEADER="label,offset_cm,nearest_cm,nearest"
ARGS=()
for model in "${MODELS[@]}"; do
  name=${model%%=*}
  path=${model#*=}
  [[ -d $path ]] && path=$path/class_report.csv
  if [[ $name == "$model" || ! -f $path ]]; then
    echo "any_layout_label_recall: '$model' is not NAME=<eval dir or class_report.csv> of an existing evaluation" >&2
    exit 1
  fi
  HEADER+=",recall_$name"
  ARGS+=("$path")
done
HEADER+=",support"
# markers.csv: label,vertex_id,x,y,z (metres). class_report.csv:
# label,precision,recall,f1,support,predicted.
{
  echo "$HEADER"
  awk -F, -v nmodels=${#ARGS[@]} '
    FNR == 1 { file++; next }
    file == 1 { tx[$1] = $3; ty[$1] = $4; tz[$1] = $5; order[++n] = $1; next }
    file == 2 { rx[$1] = $3; ry[$1] = $4; rz[$1] = $5; next }
    { recall[file - 2, $1] = $3; if (file == 3) support[$1] = $5 }
    END {
      for (i = 1; i <= n; i++) {
        l = order[i]
        offset = ""
        if (l in rx) {
          dx = tx[l] - rx[l]; dy = ty[l] - ry[l]; dz = tz[l] - rz[l]
          offset = sprintf("%.1f", 100 * sqrt(dx * dx + dy * dy + dz * dz))
        }
        best = -1; who = ""
        for (j = 1; j <= n; j++) {
          m = order[j]
          if (m == l) continue
          dx = tx[l] - tx[m]; dy = ty[l] - ty[m]; dz = tz[l] - tz[m]
          d = sqrt(dx * dx + dy * dy + dz * dz)
          if (best < 0 || d < best) { best = d; who = m }
        }
        line = sprintf("%s,%s,%.1f,%s", l, offset, 100 * best, who)
        for (k = 1; k <= nmodels; k++) line = line "," recall[k, l]
        print line "," support[l]
      }
    }' "$TMP/take/markers.csv" "$TMP/reference/markers.csv" "${ARGS[@]}"
} >"$OUT.tmp"
mv "$OUT.tmp" "$OUT"
echo "any_layout_label_recall: wrote $OUT ($(($(wc -l <"$OUT") - 1)) labels, ${#ARGS[@]} models)"
