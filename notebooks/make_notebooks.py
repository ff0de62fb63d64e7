#!/usr/bin/env python3
"""Writes notebooks/<name>.ipynb for every reproduced table and figure, without outputs.

Run after editing this file: /usr/bin/python3 notebooks/make_notebooks.py
The notebooks are thin: the loading and plotting code lives in somaplots.py, next to them.
"""

import pathlib

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

HERE = pathlib.Path(__file__).resolve().parent

NOTEBOOKS = {
    "table1": (
        "Table 1 — training noise × test noise",
        "Four models trained with the noise models B, B+C, B+G, B+C+G (rows), each tested on a real HDM05 "
        "take corrupted with the same four settings (columns). Plot: two heatmaps of per-frame accuracy, ours "
        "(mean over seeds) and the paper's, with the values written in the cells; partial cells are hatched "
        "and say how many seeds finished, cells without a value are grey.",
    ),
    "table2": (
        "Table 2 — robustness to exact per-frame occlusions",
        "The base model on a real HDM05 take with exactly k = 0..5 occluded markers per frame, and 5 plus "
        "ghost points. Plot: accuracy vs k, ours with seed-std error bars and a frame-std band, the paper's "
        "SOMA* row (BMLrub: a reference, not like-for-like) as a dashed line with its std band.",
    ),
    "table3": (
        "Table 3 — per-frame vs tracklet labelling",
        "The base model on real takes with 50 broken trajectories, labelled per frame and by tracklet. Plot: "
        "grouped bars per take (per-frame vs tracklet), accuracy and F1, error bars = seed std. The paper's "
        "datasets are not available, so there is no paper column.",
    ),
    "table4": (
        "Table 4 — robustness to variations in the marker layout",
        "The base model (trained on the full 41-marker layout, the superset) on a real HDM05 take with k = 3, "
        "5, 6, 12 markers removed, and one model per reduced layout (trained without those k markers, the "
        "subset) on the full take (B+C+G). Plot: accuracy vs k (parsed from the test name `removed_<k>` and "
        "the variant name `subset_<k>`), both series of ours with seed-std error bars and a frame-std band, "
        "the paper's two rows (Base Model, Base MoCap) as dashed lines with their std bands, and the base "
        "model on the full take (k = 0) as a reference point and dotted line.",
    ),
    "table5": (
        "Table 5 — ablation of SOMA's components",
        "The full model and one component removed at a time, tested on real HDM05 and CMU takes (B+C+G). "
        "Plot: horizontal bars per variant, ours (error bars = seed std) next to the paper (error bars = its "
        "frame std; HDM05 only). Skipped and not-run variants are written in red, partial ones hatched.",
    ),
    "fig_c1": (
        "Fig. C.1 — accuracy vs number of self-attention layers",
        "One model per number of attention layers (1, 2, 4, 8; x parsed from the variant name), tested on a "
        "real HDM05 take (B+C+G). Plot: accuracy vs layers, ours with seed-std error bars and a frame-std "
        "band. The paper gives this curve only as a figure: there are no paper numbers to plot.",
    ),
    "fig_c2": (
        "Fig. C.2 — accuracy vs number of Sinkhorn iterations",
        "One model per number of Sinkhorn iterations (1, 5, 15, 35; x parsed from the variant name), tested "
        "on a real HDM05 take (B+C+G). Plot: accuracy vs iterations, ours with seed-std error bars and a "
        "frame-std band. The paper gives this curve only as a figure: there are no paper numbers to plot.",
    ),
    "fig_c3": (
        "Fig. C.3 — training with extreme ghost-point distributions",
        "One model per ghost distribution with up to 60 ghosts per frame (spherical Gaussian, uniform in "
        "[-2, 2] m, skewed Gaussian) next to the base (up to 3). Plot: validation accuracy per epoch "
        "(results/fig_c3_curves.csv, mean ± seed std; synthetic frames with each model's training noise) and "
        "the accuracy of every model on the real HDM05 take, corrupted as B+C+G and with up to 60 Gaussian "
        "ghosts (does a 60-ghost model fail on real data, or on the shift from 60 ghosts to 3?). The paper "
        "shows curves only.",
    ),
    "any_layout": (
        "Any layout — one layout-conditioned labeller against a model per layout (issue #25, not a paper table)",
        "Each conditioned variant (trained once, never on the test layouts) labels three real takes, each with "
        "its own layout given at label time, beside the per-layout model trained on that layout. Plot: one "
        "panel per take, a bar per conditioned variant (mean over seeds ± seed std, each seed a dot from "
        "results/any_layout_seeds.csv), the per-layout model as a line and the issue's target, at most 3 points "
        "behind it, shaded. The paper trains one model per layout, so there is no paper column. When the folder "
        "also holds fine-tuning tables (finetune*.csv of ablations/any_layout_finetune.sh), a second figure, "
        "any_layout_finetune.png, plots each take's accuracy against epochs of fine-tuning on its layout (each "
        "point labelled with its minutes of training), with the per-layout models of the report's claims as lines.",
    ),
    "claims": (
        "The paper's claims, across every table",
        "Every qualitative claim of the paper that a reproduction checks (the `claims:` of "
        "`ablations/<name>.yaml`), read from all `results/<name>_claims.csv`: the paper's gap, ours (the "
        "claim's better − worse, in points, ± its standard error over training seeds) and the verdict. A "
        "verdict is flagged \"within seed noise\" when the claim's boundary (0, or ± the tolerance of a "
        "\"close\" claim) is under 2 s.e. from our gap. Plot: a forest plot, one row per claim, our gap with "
        "±2 s.e. (filled: resolved, hollow: within seed noise; green pass, red fail), the region where the "
        "claim passes shaded, and the paper's gap as a cross.",
    ),
}

# Notebooks whose table cell shows more than sp.summary(df).
TABLES = {
    "claims": """\
# Per table: how many claims pass, fail, are not run; then every claim.
if df is not None:
    display(sp.claims_counts(df))
    display(sp.summary(df))""",
}

# Notebooks with more cells after the plot.
EXTRA = {
    "any_layout": """\
# Fine-tuning (item 3's second question): accuracy on each take against epochs of training on its
# layout, from the finetune*.csv tables of ablations/any_layout_finetune.sh beside the report.
ft = sp.load_finetune() if df is not None else None
if ft is not None:
    fig = sp.plot_any_layout_finetune(ft, df)
    sp.save(fig, NAME + "_finetune")  # $SOMA_FIGURES_DIR/any_layout_finetune.png""",
}

SETUP = '''\
import os, pathlib, sys

# Make somaplots.py (next to this notebook) importable from any working directory.
for d in (pathlib.Path.cwd(), *pathlib.Path.cwd().parents):
    if (d / "somaplots.py").is_file():
        sys.path.insert(0, str(d)); break
    if (d / "notebooks" / "somaplots.py").is_file():
        sys.path.insert(0, str(d / "notebooks")); break

import somaplots as sp

NAME = "{name}"
print("results:", sp.results_dir(), "| figures:", sp.figures_dir())
df = sp.load(NAME)  # None (and a "not run yet" message) when results/{name}.csv does not exist'''

TABLE = '''\
# Ours (mean ± seed std, frame std) beside the paper (mean ± std); Δ = ours − paper.
if df is not None:
    display(sp.summary(df))'''

PLOT = '''\
if df is not None:
    fig = sp.plot_{name}(df)
    sp.save(fig, NAME)  # $SOMA_FIGURES_DIR/{name}.png'''


def reads(name: str) -> str:
    """What the notebook reads and writes, in a sentence."""
    source = (
        "every `$SOMA_RESULTS_DIR/<name>_claims.csv` (default: `results/` of the repository), written by "
        "`soma reproduce <name>` for each table with claims,"
        if name == "claims"
        else f"`$SOMA_RESULTS_DIR/{name}.csv` (default: `results/` of the repository), written by "
        f"`soma reproduce {name}` (spec: `ablations/{name}.yaml`),"
    )
    return (
        f"Reads {source} and saves the figure to `$SOMA_FIGURES_DIR/{name}.png` (default: `figures/` in the "
        "results folder). Without its input it only says \"not run yet\"."
    )


def notebook(name: str, title: str, text: str) -> nbformat.NotebookNode:
    nb = new_notebook()
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    nb.metadata["language_info"] = {"name": "python"}
    nb.cells = [
        new_markdown_cell(f"# {title}\n\n{text}\n\n{reads(name)} Generated by `make_notebooks.py`: edit that, not this file."),
        new_code_cell(SETUP.format(name=name)),
        new_code_cell(TABLES.get(name, TABLE)),
        new_code_cell(PLOT.format(name=name)),
    ]
    if name in EXTRA:
        nb.cells.append(new_code_cell(EXTRA[name]))
    for i, cell in enumerate(nb.cells):
        cell["id"] = f"{name}-{i}"  # stable ids: regenerating does not churn the files
    return nb


def main() -> None:
    for name, (title, text) in NOTEBOOKS.items():
        nb = notebook(name, title, text)
        nbformat.validate(nb)
        path = HERE / f"{name}.ipynb"
        nbformat.write(nb, str(path))
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
