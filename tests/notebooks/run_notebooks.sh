#!/usr/bin/env bash
# Executes every notebooks/*.ipynb headless with Debian's nbconvert and checks the outcome.
#
#   tests/notebooks/run_notebooks.sh [RESULTS_DIR [FIGURES_DIR]]
#
# RESULTS_DIR (else $SOMA_RESULTS_DIR, else <repo>/results) holds the <name>.csv files of
# `soma reproduce <name>`; FIGURES_DIR (else $SOMA_FIGURES_DIR, else RESULTS_DIR/figures) receives
# <name>.png. Fixture mode (CTest notebooks.fixtures): RESULTS_DIR = tests/notebooks/fixtures.
#
# Fails (exit 1) if a notebook raises, if a notebook whose CSV exists writes no fresh PNG or does not
# print the training budget of its report (<name>.md) under its figure, or if a notebook whose CSV is
# missing does not say "not run yet" or writes a PNG. Executed copies go to a
# temporary folder (kept with KEEP_NOTEBOOK_OUTPUTS=1); the notebooks in the tree stay clean.
set -uo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd -P)
repo=$(cd "$here/../.." && pwd)
nbdir="$repo/notebooks"
python=${SOMA_NOTEBOOK_PYTHON:-/usr/bin/python3}

results=${1:-${SOMA_RESULTS_DIR:-$repo/results}}
figures=${2:-${SOMA_FIGURES_DIR:-$results/figures}}
[[ -d "$results" ]] || { echo "run_notebooks: no folder $results" >&2; exit 1; }
results=$(cd "$results" && pwd)
mkdir -p "$figures" || exit 1
figures=$(cd "$figures" && pwd)

if ! "$python" -c "import nbconvert, nbformat, ipykernel, pandas, matplotlib" 2>/dev/null; then
  echo "run_notebooks: $python lacks nbconvert/nbformat/ipykernel/pandas/matplotlib" \
       "(scripts/install_deps.sh installs the Debian packages)" >&2
  exit 1
fi

tmp=$(mktemp -d "${TMPDIR:-/tmp}/soma-notebooks.XXXXXX") || exit 1
if [[ -z "${KEEP_NOTEBOOK_OUTPUTS:-}" ]]; then
  trap 'rm -rf "$tmp"' EXIT
else
  echo "run_notebooks: executed notebooks kept in $tmp"
fi

export SOMA_RESULTS_DIR=$results SOMA_FIGURES_DIR=$figures
export MPLBACKEND=Agg                  # headless; no inline images stored in the executed copies
export JUPYTER_RUNTIME_DIR=$tmp/runtime  # kernel connection files out of $HOME
export PYDEVD_DISABLE_FILE_VALIDATION=1  # silence the debugger warning of frozen modules
# A read-only or missing $HOME must not break matplotlib's font cache.
if [[ -z "${MPLCONFIGDIR:-}" && ! -w "${HOME:-/nonexistent}" ]]; then export MPLCONFIGDIR=$tmp/mpl; fi

shopt -s nullglob
notebooks=("$nbdir"/*.ipynb)
if ((${#notebooks[@]} == 0)); then echo "run_notebooks: no notebooks in $nbdir" >&2; exit 1; fi

stamp=$tmp/stamp
touch "$stamp"
sleep 1  # PNG mtimes must be strictly newer than the stamp (1 s filesystem granularity)

failed=()
start=$SECONDS
for nb in "${notebooks[@]}"; do
  name=$(basename "$nb" .ipynb)
  t0=$SECONDS
  log=$tmp/$name.log
  if ! "$python" -m nbconvert --to notebook --execute --ExecutePreprocessor.timeout=120 \
       --ExecutePreprocessor.startup_timeout=300 --ExecutePreprocessor.kernel_name=python3 \
       --output-dir "$tmp" "$nb" >"$log" 2>&1; then
    echo "FAIL $name: the notebook raised"
    tail -n 40 "$log" | sed 's/^/    /'
    failed+=("$name")
    continue
  fi
  png=$figures/$name.png
  # claims.ipynb reads every <table>_claims.csv; the others read <name>.csv.
  input=$results/$name.csv
  if [[ $name == claims ]]; then
    inputs=("$results"/*_claims.csv)
    input=${inputs[0]:-$results/<table>_claims.csv}
  fi
  if [[ -f "$input" ]]; then
    if [[ ! -s "$png" || ! "$png" -nt "$stamp" ]]; then
      echo "FAIL $name: $input exists but no fresh $png was written"
      failed+=("$name")
      continue
    fi
    # A report's training budget (results/<name>.md; claims: that of any table) is printed under
    # the figure (somaplots.budget_note), so a copied figure still says which models it shows.
    reports=("$results/$name.md")
    [[ $name == claims ]] && reports=("$results"/table*.md "$results"/fig_*.md)
    budget=""
    for md in "${reports[@]}"; do
      [[ -f "$md" ]] || continue
      budget=$(sed -n 's/^| training budget[^|]*| `\([^`]*\)` |.*$/\1/p' "$md" | head -n 1)
      [[ -n "$budget" ]] && break
    done
    # (claims.ipynb names each table's budget when they differ, so look for the budget itself.)
    if [[ -n "$budget" ]] && ! { grep -qF "training budget (every model): " "$tmp/$name.ipynb" &&
                                 grep -qF -- "$budget" "$tmp/$name.ipynb"; }; then
      echo "FAIL $name: the figure does not state the training budget of its report ($budget)"
      failed+=("$name")
      continue
    fi
    # any_layout.ipynb also plots the fine-tuning tables beside its report.
    if [[ $name == any_layout ]]; then
      tables=("$results"/finetune*.csv "$results"/any_layout_finetune*.csv)
      extra=$figures/${name}_finetune.png
      if ((${#tables[@]} > 0)) && [[ ! -s "$extra" || ! "$extra" -nt "$stamp" ]]; then
        echo "FAIL $name: ${tables[0]} exists but no fresh $extra was written"
        failed+=("$name")
        continue
      fi
    fi
    echo "ok   $name ($((SECONDS - t0)) s): $png${budget:+ (training budget: $budget)}"
  else
    if ! grep -q "not run yet" "$tmp/$name.ipynb"; then
      echo "FAIL $name: no $input, but the notebook did not say \"not run yet\""
      failed+=("$name")
      continue
    fi
    if [[ -f "$png" && "$png" -nt "$stamp" ]]; then
      echo "FAIL $name: no $input, but $png was written"
      failed+=("$name")
      continue
    fi
    echo "ok   $name ($((SECONDS - t0)) s): not run yet (no $input)"
  fi
done

for csv in "$results"/*.csv; do
  base=$(basename "$csv" .csv)
  base=${base%_curves}  # <name>_curves.csv is read by <name>.ipynb
  base=${base%_seeds}   # <name>_seeds.csv too (any_layout.ipynb: a dot per seed)
  [[ $base == *_claims ]] && base=claims  # <name>_claims.csv by claims.ipynb
  [[ $base == finetune* || $base == any_layout_finetune* ]] && base=any_layout  # its fine-tuning figure
  [[ -f "$nbdir/$base.ipynb" ]] || echo "note: no notebook plots $csv"
done
echo "run_notebooks: ${#notebooks[@]} notebooks in $((SECONDS - start)) s; results $results, figures $figures"
if ((${#failed[@]} > 0)); then
  echo "run_notebooks: FAILED: ${failed[*]}" >&2
  exit 1
fi
