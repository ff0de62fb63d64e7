"""Shared code of the notebooks in this folder: find, read and plot results/<name>.csv.

`soma reproduce <name>` writes results/<name>.csv, one row per (variant, test, metric):

    table,variant,variant_label,test,test_label,setting,mode,metric,seeds_done,seeds_planned,
    mean,std_seeds,std_frames,paper,paper_std,status,note

metric is acc or f1, values are percent, an empty cell is "no value"; status is one of
done, partial, not run, skipped. mean is the mean over training seeds, std_seeds the sample std
over seeds, std_frames the mean over seeds of the std over frames, paper/paper_std the published
numbers (empty where the paper has none).

Paths: $SOMA_RESULTS_DIR (default <repo>/results) and $SOMA_FIGURES_DIR (default
$SOMA_RESULTS_DIR/figures, i.e. <repo>/results/figures), where <repo> is the first folder at or
above the working directory (or this file) that holds ablations/. A relative value is taken from
the shell's folder ($PWD), since a Jupyter kernel runs in the notebook's folder.

Every saved figure carries, under the plot, the training budget of its report (the "training budget"
row of results/<name>.md), so a copy still says which models it shows.

Plain Python works too: `python3 notebooks/somaplots.py table5` writes the figure without Jupyter.
"""

from __future__ import annotations

import os
import pathlib
import re
import sys
import textwrap

import matplotlib

# Headless by default (tests, scripts). A Jupyter kernel sets MPLBACKEND to its inline backend,
# which renders with Agg too and shows the figure in the notebook; keep that one.
if "ipykernel" not in sys.modules and not os.environ.get("MPLBACKEND"):
    matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch, Rectangle  # noqa: E402

NAMES = ("table1", "table2", "table3", "table4", "table5", "fig_c1", "fig_c2", "fig_c3")

OURS_COLOR = "tab:blue"
PAPER_COLOR = "tab:gray"
MISSING_COLOR = "#e6e6e6"

NUMERIC = ("seeds_done", "seeds_planned", "mean", "std_seeds", "std_frames", "paper", "paper_std")


# --------------------------------------------------------------------------------------------
# Paths and loading


def repo_root(start: os.PathLike | str | None = None) -> pathlib.Path | None:
    """The first folder at or above `start` (then this file) that holds ablations/."""
    candidates = [pathlib.Path(start or os.getcwd()).resolve(), pathlib.Path(__file__).resolve().parent]
    for first in candidates:
        for d in (first, *first.parents):
            if (d / "ablations").is_dir():
                return d
    return None


def _env_dir(var: str) -> pathlib.Path | None:
    """$var as an absolute folder. A relative value is tried against the working directory, then
    $PWD (the shell's folder: a Jupyter kernel runs in the notebook's folder), then the repository."""
    value = os.environ.get(var)
    if not value:
        return None
    path = pathlib.Path(value).expanduser()
    if path.is_absolute():
        return path
    bases = [pathlib.Path.cwd()]
    if os.environ.get("PWD"):
        bases.append(pathlib.Path(os.environ["PWD"]))
    root = repo_root()
    if root:
        bases.append(root)
    for base in bases:
        if (base / path).is_dir():
            return (base / path).resolve()
    return (pathlib.Path(os.environ.get("PWD") or os.getcwd()) / path).resolve()  # to be created


def results_dir() -> pathlib.Path:
    env = _env_dir("SOMA_RESULTS_DIR")
    if env:
        return env
    root = repo_root()
    return (root / "results") if root else (pathlib.Path.cwd().parent / "results").resolve()


def figures_dir() -> pathlib.Path:
    return _env_dir("SOMA_FIGURES_DIR") or results_dir() / "figures"


def load(name: str) -> pd.DataFrame | None:
    """results/<name>.csv as a DataFrame, or None (with a message) when it does not exist yet;
    "claims" reads every results/<table>_claims.csv instead (load_claims)."""
    if name == "claims":
        return load_claims()
    path = results_dir() / f"{name}.csv"
    if not path.is_file():
        print(f"results/{name}.csv: not run yet (no {path})")
        return None
    df = pd.read_csv(path, dtype=str, keep_default_na=False)
    for col in NUMERIC:
        df[col] = pd.to_numeric(df[col].replace("", np.nan), errors="coerce")
    df["status"] = df["status"].str.strip()
    print(f"{path}: {len(df)} rows, status: " + ", ".join(f"{k} {v}" for k, v in df["status"].value_counts().items()))
    return df


def load_curves(name: str) -> pd.DataFrame | None:
    """results/<name>_curves.csv (per model and epoch: variant, seed, epoch, train_loss, val_loss,
    val_acc, val_f1; accuracies as fractions), or None when it does not exist yet."""
    path = results_dir() / f"{name}_curves.csv"
    if not path.is_file():
        print(f"results/{name}_curves.csv: no training curves yet (no {path})")
        return None
    df = pd.read_csv(path)
    print(f"{path}: {len(df)} rows, {df.groupby(['variant', 'seed']).ngroups} models")
    return df


_BUDGET_ROW = re.compile(r"^\| training budget[^|]*\| `([^`]*)` \|", re.MULTILINE)


def training_budget(name: str) -> str | None:
    """The training overrides of every model of results/<name>.md (its header's "training budget"
    row, written by `soma reproduce`), or None when the report or the row is missing."""
    path = results_dir() / f"{name}.md"
    if not path.is_file():
        return None
    match = _BUDGET_ROW.search(path.read_text(encoding="utf-8"))
    return match.group(1) if match else None


def budget_note(name: str) -> str | None:
    """The figure's provenance line: the training budget of <name> or, for "claims", of every table
    whose report exists (one budget if they share it). None when no report names one."""
    tables = NAMES if name == "claims" else (name,)
    budgets = {t: b for t in tables if (b := training_budget(t))}
    if not budgets:
        return None
    if len(set(budgets.values())) == 1:
        return f"training budget (every model): {next(iter(budgets.values()))}"
    return "training budget (every model): " + "; ".join(f"{t}: {b}" for t, b in budgets.items())


def save(fig, name: str) -> pathlib.Path:
    """Writes the figure to $SOMA_FIGURES_DIR/<name>.png, with the training budget of its report
    (budget_note) printed under it, so a figure says which models it shows (e.g. which marker layout)
    wherever it is copied; shows it in a notebook, closes it otherwise."""
    out = figures_dir()
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.png"
    note = budget_note(name)
    if note:
        # Below the figure: constrained layout keeps every axis label above y = 0, and
        # bbox_inches="tight" grows the saved area to include the note.
        fig.text(0.5, -0.01, note, ha="center", va="top", fontsize=8, color="dimgray", wrap=True)
        print(note)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    print(f"wrote {path}")
    if "inline" in matplotlib.get_backend():
        plt.show()
    else:
        plt.close(fig)
    return path


# --------------------------------------------------------------------------------------------
# Helpers


def ordered(values) -> list:
    """Unique values in first-seen (CSV = spec) order."""
    return list(dict.fromkeys(values))


def _num(x) -> float | None:
    return None if x is None or pd.isna(x) else float(x)


def status_note(row) -> str:
    """'' for done, 'n/m seeds' for partial, 'not run', 'skipped'."""
    status = row["status"]
    if status == "partial":
        return f"{int(row['seeds_done'])}/{int(row['seeds_planned'])} seeds"
    if status in ("not run", "skipped"):
        return status
    if status == "done" or not status:
        return ""
    return status


def fmt_pm(mean, std) -> str:
    mean, std = _num(mean), _num(std)
    if mean is None:
        return ""
    return f"{mean:.2f}" + (f" ± {std:.2f}" if std is not None else "")


def summary(df: pd.DataFrame) -> pd.DataFrame:
    """Ours vs paper side by side: one row per (variant, test), acc and f1 columns (claims: one row per
    claim, claims_summary)."""
    if "claim" in df.columns:
        return claims_summary(df)
    rows = []
    for (variant, test), g in df.groupby(["variant", "test"], sort=False):
        first = g.iloc[0]
        row = {"variant": first["variant_label"] or variant, "test": first["test_label"] or test}
        for metric in ordered(g["metric"]):
            m = g[g["metric"] == metric].iloc[0]
            ours = fmt_pm(m["mean"], m["std_seeds"])
            row[f"{metric} ours"] = ours or m["status"]
            row[f"{metric} frames ±"] = "" if pd.isna(m["std_frames"]) else f"{m['std_frames']:.2f}"
            row[f"{metric} paper"] = fmt_pm(m["paper"], m["paper_std"]) or "—"
            delta = ""
            if not pd.isna(m["mean"]) and not pd.isna(m["paper"]):
                delta = f"{m['mean'] - m['paper']:+.2f}"
            row[f"{metric} Δ"] = delta
        seeds_planned = first["seeds_planned"]
        row["seeds"] = (
            f"{int(first['seeds_done'])}/{int(seeds_planned)}" if not pd.isna(seeds_planned) and seeds_planned else ""
        )
        row["status"] = first["status"]
        row["note"] = first["note"]
        rows.append(row)
    return pd.DataFrame(rows).set_index(["variant", "test"])


def _metric(df: pd.DataFrame, metric: str = "acc") -> pd.DataFrame:
    return df[df["metric"] == metric].reset_index(drop=True)


def _legend_status(ax, d: pd.DataFrame, markers: bool = False, **legend_kw):
    """Draws the legend and, when some cell of d is partial, an entry that explains how partial cells
    are marked (hatched bars or ringed points). legend_kw (loc, bbox_to_anchor, ...) go to ax.legend."""
    handles, labels = ax.get_legend_handles_labels()
    if d["status"].eq("partial").any():
        if markers:
            handles.append(Line2D([], [], marker="o", ms=10, mfc="none", mec="tab:orange", mew=1.5,
                                  linestyle="none"))
        else:
            handles.append(Patch(facecolor="white", edgecolor="black", hatch="///"))
        labels.append("partial (n/m seeds)")
    if handles:
        ax.legend(handles, labels, **{"fontsize": 8, "loc": "best", **legend_kw})


def _paper_note(df: pd.DataFrame) -> str:
    return "" if df["paper"].notna().any() else "no paper numbers (the paper gives no values for these cells)"


# --------------------------------------------------------------------------------------------
# Table 1: train noise x test noise heatmaps


def plot_table1(df: pd.DataFrame, metric: str = "acc"):
    d = _metric(df, metric)
    variants, tests = ordered(d["variant"]), ordered(d["test"])
    vlabels = [d[d["variant"] == v]["variant_label"].iloc[0] or v for v in variants]
    tlabels = [d[d["test"] == t]["test_label"].iloc[0] or t for t in tests]
    ours = np.full((len(variants), len(tests)), np.nan)
    paper = np.full_like(ours, np.nan)
    notes = [["" for _ in tests] for _ in variants]
    for _, r in d.iterrows():
        i, j = variants.index(r["variant"]), tests.index(r["test"])
        ours[i, j], paper[i, j], notes[i][j] = r["mean"], r["paper"], status_note(r)
    values = np.concatenate([ours[~np.isnan(ours)], paper[~np.isnan(paper)]])
    vmin = float(np.floor(values.min())) if values.size else 0.0
    vmax = 100.0
    if vmin >= vmax:
        vmin = vmax - 1.0

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8), constrained_layout=True)
    cmap = plt.get_cmap("viridis").copy()
    cmap.set_bad(MISSING_COLOR)
    im = None
    for ax, grid, title, with_notes in (
        (axes[0], ours, "ours (mean over seeds)", True),
        (axes[1], paper, "paper", False),
    ):
        im = ax.imshow(np.ma.masked_invalid(grid), cmap=cmap, vmin=vmin, vmax=vmax, aspect="auto")
        ax.set_xticks(range(len(tests)), tlabels)
        ax.set_yticks(range(len(variants)), vlabels)
        ax.set_xlabel("test noise")
        ax.set_ylabel("training noise")
        ax.set_title(title)
        for i in range(len(variants)):
            for j in range(len(tests)):
                v = grid[i, j]
                text = "" if np.isnan(v) else f"{v:.2f}"
                if with_notes and notes[i][j]:
                    text = f"{text}\n({notes[i][j]})" if text else notes[i][j]
                elif not text:
                    text = "—"
                dark = not np.isnan(v) and (v - vmin) / (vmax - vmin) < 0.6
                ax.text(j, i, text, ha="center", va="center", fontsize=8, color="white" if dark else "black")
                if with_notes and d[(d["variant"] == variants[i]) & (d["test"] == tests[j])]["status"].eq("partial").any():
                    ax.add_patch(
                        Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, hatch="///", edgecolor="white", linewidth=0)
                    )
    fig.colorbar(im, ax=axes, label=f"{metric} (%)", shrink=0.9)
    fig.suptitle(f"Table 1 — {metric} (%), training noise × test noise (HDM05); hatched = partial, grey = no value")
    return fig


# --------------------------------------------------------------------------------------------
# Table 2: accuracy vs number of exact occlusions


def _occ_x(test: str, label: str, fallback: int) -> tuple[float, str]:
    m = re.fullmatch(r"occ(\d+)(_g)?", test)
    if not m:
        return float(fallback), label or test
    k = int(m.group(1))
    return (k + 1.0, f"{k} + G") if m.group(2) else (float(k), str(k))


def plot_table2(df: pd.DataFrame, metric: str = "acc"):
    d = _metric(df, metric)
    tests = ordered(d["test"])
    xs, ticks = {}, {}
    for n, t in enumerate(tests):
        x, tick = _occ_x(t, d[d["test"] == t]["test_label"].iloc[0], n)
        xs[t], ticks[x] = x, tick
    fig, ax = plt.subplots(figsize=(8, 4.8), constrained_layout=True)
    for variant in ordered(d["variant"]):
        g = d[d["variant"] == variant].copy()
        g["x"] = g["test"].map(xs)
        g = g.sort_values("x")
        label = g["variant_label"].iloc[0] or variant
        have = g[g["mean"].notna()]
        exact = have[~have["test"].str.endswith("_g")]
        ghost = have[have["test"].str.endswith("_g")]
        ax.fill_between(
            exact["x"], exact["mean"] - exact["std_frames"].fillna(0), exact["mean"] + exact["std_frames"].fillna(0),
            color=OURS_COLOR, alpha=0.15, label="ours ± frame std",
        )
        for part, style in ((exact, "-o"), (ghost, "s")):
            if part.empty:
                continue
            ax.errorbar(
                part["x"], part["mean"], yerr=part["std_seeds"].fillna(0), fmt=style, color=OURS_COLOR, capsize=4,
                label=f"ours: {label} (± seed std)" if part is exact or exact.empty else None,
            )
            for _, r in part.iterrows():
                if not pd.isna(r["std_frames"]) and part is ghost:
                    ax.errorbar(r["x"], r["mean"], yerr=r["std_frames"], fmt="none", color=OURS_COLOR, alpha=0.3,
                                elinewidth=8)
        paper = g[g["paper"].notna()]
        pexact = paper[~paper["test"].str.endswith("_g")]
        pghost = paper[paper["test"].str.endswith("_g")]
        if not pexact.empty:
            ax.plot(pexact["x"], pexact["paper"], "--^", color=PAPER_COLOR, label="paper (SOMA*, BMLrub)")
            if pexact["paper_std"].notna().any():
                ax.fill_between(pexact["x"], pexact["paper"] - pexact["paper_std"].fillna(0),
                                pexact["paper"] + pexact["paper_std"].fillna(0), color=PAPER_COLOR, alpha=0.1,
                                label="paper ± std (Table D.1)")
        if not pghost.empty:
            ax.errorbar(pghost["x"], pghost["paper"], yerr=pghost["paper_std"].fillna(0), fmt="^", mfc="white",
                        color=PAPER_COLOR, capsize=4)
        _mark_points(ax, g, "x")
    ax.set_xticks(sorted(ticks), [ticks[x] for x in sorted(ticks)])
    ax.set_xlabel("occluded markers per frame (exactly k; + G = with up to 3 ghost points)")
    ax.set_ylabel(f"{metric} (%)")
    ax.grid(alpha=0.3)
    _legend_status(ax, d, markers=True)
    ax.set_title(f"Table 2 — {metric} vs exact occlusions (HDM05); paper: BMLrub, a reference, not like-for-like",
                 fontsize=10)
    return fig


def _mark_points(ax, g: pd.DataFrame, xcol: str):
    """Hollow hatched markers and 'n/m seeds' for partial points, 'not run'/'skipped' at the bottom."""
    for _, r in g.iterrows():
        note = status_note(r)
        if not note:
            continue
        if pd.isna(r["mean"]):
            ax.annotate(note, (r[xcol], 0), xycoords=("data", "axes fraction"), xytext=(0, 6),
                        textcoords="offset points", ha="center", fontsize=8, color="tab:red", rotation=90)
            ax.axvline(r[xcol], color="tab:red", alpha=0.2, linestyle=":")
        else:
            ax.plot(r[xcol], r["mean"], "o", ms=12, mfc="none", mec="tab:orange", mew=1.5)
            ax.annotate(note, (r[xcol], r["mean"]), xytext=(6, -14), textcoords="offset points", fontsize=8,
                        color="tab:orange")


# --------------------------------------------------------------------------------------------
# Table 3: per-frame vs tracklet, grouped bars


def _dataset_and_mode(test: str, label: str, mode: str) -> tuple[str, str]:
    if "," in label:
        dataset = label.split(",")[0].strip()
    else:
        dataset = re.sub(r"_(frame|tracklet|per_frame)$", "", test)
    return dataset, (mode or ("tracklet" if test.endswith("tracklet") else "per-frame"))


def plot_table3(df: pd.DataFrame):
    metrics = ordered(df["metric"])
    fig, axes = plt.subplots(1, len(metrics), figsize=(6 * len(metrics), 4.8), constrained_layout=True, squeeze=False)
    for ax, metric in zip(axes[0], metrics):
        d = _metric(df, metric).copy()
        dm = [_dataset_and_mode(t, lab, mo) for t, lab, mo in zip(d["test"], d["test_label"], d["mode"])]
        d["dataset"] = [x[0] for x in dm]
        d["mode"] = [x[1] for x in dm]
        datasets, modes = ordered(d["dataset"]), ordered(d["mode"])
        variants = ordered(d["variant"])
        has_paper = d["paper"].notna().any()
        bars = [(v, m, src) for v in variants for m in modes for src in (("ours", "paper") if has_paper else ("ours",))]
        width = 0.8 / len(bars)
        colors = plt.get_cmap("tab10")
        for b, (variant, mode, src) in enumerate(bars):
            for i, ds in enumerate(datasets):
                rows = d[(d["variant"] == variant) & (d["mode"] == mode) & (d["dataset"] == ds)]
                if rows.empty:
                    continue
                r = rows.iloc[0]
                x = i - 0.4 + width * (b + 0.5)
                color = colors(modes.index(mode))
                label = f"{mode}" + ("" if len(variants) == 1 else f" ({variant})") + (" — paper" if src == "paper" else "")
                if src == "paper":
                    if not pd.isna(r["paper"]):
                        ax.bar(x, r["paper"], width, yerr=_num(r["paper_std"]) or 0, color=color, alpha=0.35,
                               edgecolor="black", capsize=3, label=label if i == 0 else None)
                    continue
                note = status_note(r)
                if pd.isna(r["mean"]):
                    ax.bar(x, 0, width, label=label if i == 0 else None, color=color)
                    ax.text(x, 1, note or "no value", rotation=90, ha="center", va="bottom", fontsize=8,
                            color="tab:red")
                    continue
                ax.bar(x, r["mean"], width, yerr=_num(r["std_seeds"]) or 0, color=color, capsize=4,
                       hatch="///" if r["status"] == "partial" else None, edgecolor="black",
                       label=label if i == 0 else None)
                ax.text(x, r["mean"] / 2, f"{r['mean']:.2f}" + (f"\n{note}" if note else ""), ha="center",
                        va="center", fontsize=8, rotation=90, color="white")
        ax.set_xticks(range(len(datasets)), datasets)
        ax.set_ylabel(f"{metric} (%)")
        ax.set_ylim(0, 105)
        ax.grid(axis="y", alpha=0.3)
        _legend_status(ax, d)
        note = _paper_note(d)
        ax.set_title(f"{metric}: per-frame vs tracklet (± seed std)" + (f"\n{note}" if note else ""), fontsize=10)
    fig.suptitle("Table 3 — per-frame vs tracklet labelling, real takes with 50 broken trajectories")
    return fig


# --------------------------------------------------------------------------------------------
# Table 4: marker-layout robustness, accuracy vs k markers removed


def layout_k(variant: str, test: str) -> tuple[str, float | None]:
    """(series, k) of a Table 4 row: ("superset", k) for a test removed_<k> (the full-layout model on a
    take with k markers removed), ("subset", k) for a variant subset_<k> (a model trained without k
    markers, on the full take), ("full", 0) for the full-layout model on the full take, else ("", None)."""
    m = re.fullmatch(r"removed_(\d+)", test)
    if m:
        return "superset", float(m.group(1))
    m = re.fullmatch(r"subset_(\d+)", variant)
    if m:
        return "subset", float(m.group(1))
    if test == "full":
        return "full", 0.0
    return "", None


TABLE4_SERIES = {  # series: (ours, paper's row, color, x offset so that the two series' bars do not overlap)
    "superset": ("superset model on k removed", "Base Model (superset model on k removed)", OURS_COLOR, -0.12),
    "subset": ("subset model (k fewer) on the full layout", "Base MoCap (subset model on the full layout)",
               "tab:green", 0.12),
}


def plot_table4(df: pd.DataFrame, metric: str = "acc"):
    d = _metric(df, metric).copy()
    sk = [layout_k(v, t) for v, t in zip(d["variant"], d["test"])]
    d["series"] = [x[0] for x in sk]
    d["k"] = [x[1] for x in sk]
    fig, ax = plt.subplots(figsize=(9.5, 5.2), constrained_layout=True)
    band_ours, band_paper = "ours ± frame std (bands)", "paper ± std (bands)"
    for series, (ours_label, paper_label, color, dx) in TABLE4_SERIES.items():
        g = d[d["series"] == series].sort_values("k").copy()
        if g.empty:
            continue
        g["x"] = g["k"] + dx
        have = g[g["mean"].notna()]
        if not have.empty:
            ax.fill_between(have["x"], have["mean"] - have["std_frames"].fillna(0),
                            have["mean"] + have["std_frames"].fillna(0), color=color, alpha=0.12,
                            label=band_ours if band_ours not in ax.get_legend_handles_labels()[1] else None)
            ax.errorbar(have["x"], have["mean"], yerr=have["std_seeds"].fillna(0), fmt="-o", color=color,
                        capsize=4, label=f"ours: {ours_label} (± seed std)")
        else:  # nothing done yet: keep the series in the legend, its points say "not run"
            ax.plot([], [], "-o", color=color, label=f"ours: {ours_label} (none done yet)")
        paper = g[g["paper"].notna()]
        if not paper.empty:
            ax.plot(paper["k"], paper["paper"], "--^", color=color, alpha=0.7, label=f"paper: {paper_label}")
            if paper["paper_std"].notna().any():
                ax.fill_between(paper["k"], paper["paper"] - paper["paper_std"].fillna(0),
                                paper["paper"] + paper["paper_std"].fillna(0), facecolor=color, alpha=0.08,
                                hatch="..", edgecolor=color, linewidth=0,
                                label=band_paper if band_paper not in ax.get_legend_handles_labels()[1] else None)
        _mark_points(ax, g, "x")
    full = d[d["series"] == "full"].copy()
    if not full.empty:  # the full-layout model on the full take: the reference (k = 0)
        full["x"] = full["k"]
        r = full.iloc[0]
        if not pd.isna(r["mean"]):
            ax.axhline(r["mean"], color="black", linestyle=":", linewidth=1, alpha=0.6)
            ax.errorbar([0], [r["mean"]], yerr=[_num(r["std_seeds"]) or 0], fmt="D", color="black", capsize=4,
                        label=f"ours: base model on the full take, k = 0 (dotted: {r['mean']:.2f})")
            if not pd.isna(r["std_frames"]):
                ax.errorbar([0], [r["mean"]], yerr=[r["std_frames"]], fmt="none", color="black", alpha=0.2,
                            elinewidth=8)
        if not pd.isna(r["paper"]):
            ax.errorbar([0], [r["paper"]], yerr=[_num(r["paper_std"]) or 0], fmt="^", mfc="white",
                        color=PAPER_COLOR, capsize=4, label="paper: base model on the full take")
        _mark_points(ax, full, "x")
    ks = sorted(d["k"].dropna().unique())
    ax.set_xticks(ks, ["0\n(full take)" if k == 0 else f"{int(k)}" for k in ks])
    ax.set_xlim(min(ks, default=0) - 0.8, max(ks, default=12) + 0.8)
    lo, hi = ax.get_ylim()
    ax.set_ylim(max(lo, 0), min(hi, 105))
    ax.set_xlabel("k markers removed from the 41-marker layout\n"
                  "(superset model: from the test take; subset model: from its training layout)", fontsize=9)
    ax.set_ylabel(f"{metric} (%)")
    ax.grid(alpha=0.3)
    _legend_status(ax, d, markers=True, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    note = _paper_note(d)
    ax.set_title(f"Table 4 — {metric} (%) vs variations of the marker layout (real HDM05 take, per-frame);\n"
                 "paper rows dashed: Base Model (superset on k removed), Base MoCap (subset on the full layout)"
                 + (f"\n({note})" if note else ""), fontsize=10)
    return fig


# --------------------------------------------------------------------------------------------
# Table 5: ablation, horizontal bars per variant


def plot_table5(df: pd.DataFrame, metric: str = "acc"):
    d = _metric(df, metric)
    tests = ordered(d["test"])
    variants = ordered(d["variant"])
    fig, axes = plt.subplots(1, len(tests), figsize=(7 * len(tests), 0.7 * len(variants) + 2.2),
                             constrained_layout=True, squeeze=False, sharey=True)
    h = 0.38
    for ax, test in zip(axes[0], tests):
        g = d[d["test"] == test]
        for i, variant in enumerate(variants):
            rows = g[g["variant"] == variant]
            if rows.empty:
                continue
            r = rows.iloc[0]
            note = status_note(r)
            y_ours, y_paper = i - h / 2, i + h / 2
            if pd.isna(r["mean"]):
                ax.text(1, y_ours, note or "no value", va="center", fontsize=8, color="tab:red")
            else:
                ax.barh(y_ours, r["mean"], h, xerr=_num(r["std_seeds"]) or 0, color=OURS_COLOR, capsize=3,
                        hatch="///" if r["status"] == "partial" else None, edgecolor="black",
                        label="ours (± seed std)" if i == 0 or "ours (± seed std)" not in
                        ax.get_legend_handles_labels()[1] else None)
                ax.text(r["mean"] + (_num(r["std_seeds"]) or 0) + 1, y_ours,
                        f"{r['mean']:.2f}" + (f"  ({note})" if note else ""), va="center", fontsize=8)
            if not pd.isna(r["paper"]):
                ax.barh(y_paper, r["paper"], h, xerr=_num(r["paper_std"]) or 0, color=PAPER_COLOR, alpha=0.6,
                        capsize=3, label="paper (± frame std)" if "paper (± frame std)" not in
                        ax.get_legend_handles_labels()[1] else None)
                ax.text(r["paper"] + (_num(r["paper_std"]) or 0) + 1, y_paper, f"{r['paper']:.2f}", va="center",
                        fontsize=8, color="dimgray")
            else:
                ax.text(1, y_paper, "paper: —", va="center", fontsize=7, color="dimgray")
        labels = [d[d["variant"] == v]["variant_label"].iloc[0] or v for v in variants]
        ax.set_yticks(range(len(variants)), labels)
        ax.set_xlim(0, 118)
        ax.set_xlabel(f"{metric} (%)")
        ax.grid(axis="x", alpha=0.3)
        tl = g["test_label"].iloc[0] if not g.empty else test
        ax.set_title(tl + ("" if g["paper"].notna().any() else " — no paper numbers for this test"), fontsize=10)
        _legend_status(ax, g)
    axes[0][0].invert_yaxis()  # the axes share y: first variant on top, once
    fig.suptitle(f"Table 5 — ablation of SOMA's components, {metric} (%)")
    return fig


# --------------------------------------------------------------------------------------------
# Figures C.1 / C.2: accuracy vs a swept integer


def sweep_x(variant: str) -> float | None:
    """layers_8 -> 8, iters_35 -> 35."""
    m = re.search(r"(\d+)$", variant)
    return float(m.group(1)) if m else None


def plot_sweep(df: pd.DataFrame, name: str, xlabel: str, title: str, metric: str = "acc"):
    d = _metric(df, metric).copy()
    d["x"] = d["variant"].map(sweep_x)
    ticklabel = {x: f"{int(x)}" for x in d["x"].dropna()}
    if d["x"].isna().any():  # a variant name without a trailing number: plot in spec order instead
        d["x"] = d["variant"].map({v: float(i + 1) for i, v in enumerate(ordered(d["variant"]))})
        ticklabel = dict(zip(d["x"], d["variant"]))
    d = d.sort_values("x", kind="stable")
    fig, ax = plt.subplots(figsize=(7.5, 4.8), constrained_layout=True)
    for n, test in enumerate(ordered(d["test"])):
        g = d[d["test"] == test]
        tl = g["test_label"].iloc[0] or test
        color = plt.get_cmap("tab10")(n)
        have = g[g["mean"].notna()]
        if not have.empty:
            ax.fill_between(have["x"], have["mean"] - have["std_frames"].fillna(0),
                            have["mean"] + have["std_frames"].fillna(0), color=color, alpha=0.12,
                            label=f"ours {tl} ± frame std")
            ax.errorbar(have["x"], have["mean"], yerr=have["std_seeds"].fillna(0), fmt="-o", color=color,
                        capsize=4, label=f"ours: {tl} (± seed std)")
        paper = g[g["paper"].notna()]
        if not paper.empty:
            ax.plot(paper["x"], paper["paper"], "--^", color=PAPER_COLOR, label=f"paper: {tl}")
        _mark_points(ax, g, "x")
    xs = sorted(d["x"].unique())
    if xs and min(xs) > 0:
        ax.set_xscale("log")
        ax.minorticks_off()
    ax.set_xticks(xs, [ticklabel[x] for x in xs])
    ax.set_xlabel(xlabel)
    ax.set_ylabel(f"{metric} (%)")
    ax.grid(alpha=0.3)
    _legend_status(ax, d, markers=True)
    note = "" if d["paper"].notna().any() else "no paper numbers: the paper shows this curve only as a figure"
    ax.set_title(title + (f"\n({note})" if note else ""), fontsize=10)
    return fig


def plot_fig_c1(df: pd.DataFrame):
    return plot_sweep(df, "fig_c1", "self-attention layers", "Fig. C.1 — accuracy vs number of attention layers")


def plot_fig_c2(df: pd.DataFrame):
    return plot_sweep(df, "fig_c2", "Sinkhorn iterations", "Fig. C.2 — accuracy vs number of Sinkhorn iterations")


# --------------------------------------------------------------------------------------------
# Figure C.3: training curves with extreme ghosts, and the real-data check


def plot_fig_c3(df: pd.DataFrame, metric: str = "acc"):
    curves = load_curves("fig_c3")
    d = _metric(df, metric)
    variants = ordered(d["variant"])
    label = {v: (d[d["variant"] == v]["variant_label"].iloc[0] or v) for v in variants}
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 4.8), constrained_layout=True,
                                 gridspec_kw={"width_ratios": [3, 2]})
    if curves is None or curves.empty:
        ax.text(0.5, 0.5, "no training curves yet", ha="center", va="center", transform=ax.transAxes)
    else:
        for n, v in enumerate(variants):
            c = curves[curves["variant"] == v]
            if c.empty:
                continue
            g = c.groupby("epoch")[f"val_{metric}"].agg(["mean", "std", "count"]).reset_index()
            color = plt.get_cmap("tab10")(n)
            seeds = c["seed"].nunique()
            ax.plot(g["epoch"], 100 * g["mean"], "-o", ms=3, color=color, label=f"{label[v]} ({seeds} seeds)")
            ax.fill_between(g["epoch"], 100 * (g["mean"] - g["std"].fillna(0)),
                            100 * (g["mean"] + g["std"].fillna(0)), color=color, alpha=0.15)
        ax.legend(fontsize=8)
    ax.set_xlabel("epoch")
    ax.set_ylabel(f"validation {metric} (%), synthetic frames with the training noise")
    ax.set_title("training curves (mean ± seed std)", fontsize=10)
    ax.grid(alpha=0.3)
    # One bar per real test (e.g. the take with B+C+G, and with up to 60 ghosts), grouped by variant.
    tests = ordered(d["test"])
    height = 0.8 / max(len(tests), 1)
    for j, t in enumerate(tests):
        dt = d[d["test"] == t]
        test_label = dt["test_label"].iloc[0] or t
        color = plt.get_cmap("Set2")(j)
        labelled = False
        for i, v in enumerate(variants):
            rows = dt[dt["variant"] == v]
            if rows.empty:
                continue
            r = rows.iloc[0]
            y = i + (j - (len(tests) - 1) / 2) * height
            note = status_note(r)
            if pd.isna(r["mean"]):
                bx.text(1, y, f"{test_label}: {note or 'no value'}", va="center", fontsize=7, color="tab:red")
                continue
            std = _num(r["std_seeds"]) or 0
            bx.barh(y, r["mean"], 0.9 * height, xerr=std, color=color, capsize=3, edgecolor="black",
                    hatch="///" if r["status"] == "partial" else None, label=None if labelled else test_label)
            labelled = True
            bx.text(r["mean"] + std + 1, y, f"{r['mean']:.2f}" + (f"  ({note})" if note else ""),
                    va="center", fontsize=7)
    bx.set_yticks(range(len(variants)), [label[v] for v in variants], fontsize=8)
    bx.set_ylim(len(variants) - 0.5, -0.5)  # first variant on top; room for every test's bar or note
    bx.set_xlim(0, 118)
    bx.set_xlabel(f"{metric} (%)")
    bx.set_title("real data (± seed std)", fontsize=10)
    bx.grid(axis="x", alpha=0.3)
    if tests:
        _legend_status(bx, d, loc="lower right")
    fig.suptitle("Fig. C.3 — training with extreme ghost-point distributions (the paper shows curves only)")
    return fig


# --------------------------------------------------------------------------------------------
# The paper's claims across every table: results/<name>_claims.csv

CLAIM_NUMERIC = ("tolerance", "paper_gap", "gap", "gap_se")
PASS_COLOR = "tab:green"
FAIL_COLOR = "tab:red"


def load_claims() -> pd.DataFrame | None:
    """Every results/<name>_claims.csv, in NAMES order, as one DataFrame, or None (with a message) when
    none exists yet. One row per claim: table, claim, rule, kind (greater|close|not_behind), metric, better,
    better_test, worse, worse_test, tolerance, paper_gap, gap, gap_se (points), paired, verdict
    (pass|fail|not run), within_noise (the boundary is under 2 s.e. from the gap), paper_note."""
    paths = [p for p in (results_dir() / f"{n}_claims.csv" for n in NAMES) if p.is_file()]
    if not paths:
        print(f"results/<name>_claims.csv: not run yet (none in {results_dir()})")
        return None
    df = pd.concat([pd.read_csv(p, dtype=str, keep_default_na=False) for p in paths], ignore_index=True)
    for col in CLAIM_NUMERIC:
        df[col] = pd.to_numeric(df[col].replace("", np.nan), errors="coerce")
    df["paired"] = df["paired"] == "1"
    df["within_noise"] = df["within_noise"] == "1"
    # Whose claim: paper (the paper's own), ours, duplicate (a paper's claim repeated on another take).
    if "origin" not in df.columns:
        df["origin"] = "paper"
    df["origin"] = df["origin"].replace("", "paper")
    print(f"{len(paths)} claims files, {len(df)} claims: "
          + ", ".join(f"{k} {v}" for k, v in df["verdict"].value_counts().items())
          + f"; {int(df['within_noise'].sum())} within seed noise")
    return df


def claims_counts(df: pd.DataFrame) -> pd.DataFrame:
    """Per table and origin (the paper's own claims, ours, the paper's repeated on another take): how many
    claims pass, fail or are not run, and how many verdicts are within seed noise."""
    rows = []
    for (table, origin), g in df.groupby(["table", "origin"], sort=False):
        rows.append({"table": table, "origin": origin, "claims": len(g),
                     "pass": int((g["verdict"] == "pass").sum()),
                     "fail": int((g["verdict"] == "fail").sum()),
                     "not run": int((g["verdict"] == "not run").sum()),
                     "within seed noise": int(g["within_noise"].sum())})
    out = pd.DataFrame(rows)
    numeric = [c for c in out.columns if c not in ("table", "origin")]
    totals = [{"table": "all", "origin": origin, **{c: int(g[c].sum()) for c in numeric}}
              for origin, g in out.groupby("origin", sort=False)]
    return pd.concat([out, pd.DataFrame(totals)], ignore_index=True).set_index(["table", "origin"])


def claims_summary(df: pd.DataFrame) -> pd.DataFrame:
    """One row per claim: its rule, the paper's gap, ours ± s.e. and the verdict."""
    rows = []
    for _, r in df.iterrows():
        ours = "" if pd.isna(r["gap"]) else f"{r['gap']:+.2f}"
        if ours and not pd.isna(r["gap_se"]):
            ours += f" ± {r['gap_se']:.2f}" + (" (paired)" if r["paired"] else "")
        paper = "" if pd.isna(r["paper_gap"]) else f"{r['paper_gap']:+.2f}"
        rows.append({"table": r["table"], "claim": r["claim"], "rule": r["rule"],
                     "paper gap": paper or "—", "our gap ± s.e.": ours or "—",
                     "verdict": r["verdict"] + (" (within seed noise)" if r["within_noise"] else "")})
    return pd.DataFrame(rows).set_index(["table", "claim"])


def _shorten(text: str, n: int = 70) -> str:
    return text if len(text) <= n else text[: n - 1] + "…"


def plot_claims(df: pd.DataFrame):
    """A forest plot: one row per claim, our gap (better − worse, points) with ±2 s.e., the region where
    the claim passes shaded (gap > 0, |gap| ≤ tolerance, or gap ≤ tolerance), and the paper's gap where it is known."""
    n = len(df)
    fig, ax = plt.subplots(figsize=(12, 0.34 * n + 1.8), constrained_layout=True)
    finite = pd.concat([df["gap"] + 2 * df["gap_se"].fillna(0), df["gap"] - 2 * df["gap_se"].fillna(0),
                        df["paper_gap"], df["tolerance"], -df["tolerance"]]).dropna()
    lo, hi = (min(finite.min(), 0.0), max(finite.max(), 0.0)) if not finite.empty else (-1.0, 1.0)
    pad = 0.06 * (hi - lo or 1.0)
    lo, hi = lo - pad, hi + pad
    labels = []
    for i, (_, r) in enumerate(df.iterrows()):
        if r["kind"] == "close" and not pd.isna(r["tolerance"]):
            ax.add_patch(Rectangle((-r["tolerance"], i - 0.4), 2 * r["tolerance"], 0.8, color=PASS_COLOR,
                                   alpha=0.12, lw=0))
        elif r["kind"] == "not_behind" and not pd.isna(r["tolerance"]):
            ax.add_patch(Rectangle((lo, i - 0.4), r["tolerance"] - lo, 0.8, color=PASS_COLOR, alpha=0.12, lw=0))
        else:
            ax.add_patch(Rectangle((0, i - 0.4), hi, 0.8, color=PASS_COLOR, alpha=0.12, lw=0))
        if not pd.isna(r["paper_gap"]):
            ax.plot(r["paper_gap"], i, "x", color="dimgray", ms=7, mew=1.6)
        if pd.isna(r["gap"]):
            ax.text(lo + pad / 2, i, "not run", va="center", fontsize=8, color=FAIL_COLOR)
        else:
            color = PASS_COLOR if r["verdict"] == "pass" else FAIL_COLOR
            if not pd.isna(r["gap_se"]):
                ax.errorbar(r["gap"], i, xerr=2 * r["gap_se"], fmt="none", ecolor=color, capsize=3, lw=1.2)
            ax.plot(r["gap"], i, "o", ms=7, mec=color, mew=1.6, mfc="white" if r["within_noise"] else color)
        tag = {"ours": " [ours]", "duplicate": " [repeat]"}.get(r["origin"], "")
        labels.append(f"{r['table']}: {_shorten(r['claim'])}{tag}")
    ax.axvline(0, color="black", lw=0.8)
    ax.set_xlim(lo, hi)
    ax.set_ylim(n - 0.5, -0.5)
    ax.set_yticks(range(n), labels, fontsize=8)
    tables = list(df["table"])
    for i in range(1, n):
        if tables[i] != tables[i - 1]:
            ax.axhline(i - 0.5, color="gray", lw=0.6, ls=":")
    ax.set_xlabel("gap in points (the claim's better − worse; close claims: pass inside ± tolerance)")
    ax.grid(axis="x", alpha=0.3)
    ax.legend(handles=[
        Line2D([], [], marker="o", ls="none", color=PASS_COLOR, label="ours: pass (± 2 s.e. over seeds)"),
        Line2D([], [], marker="o", ls="none", color=FAIL_COLOR, label="ours: fail"),
        Line2D([], [], marker="o", ls="none", mec="black", mfc="white", label="hollow: within seed noise"),
        Line2D([], [], marker="x", ls="none", color="dimgray", label="the paper's gap"),
        Patch(color=PASS_COLOR, alpha=0.12, label="where the claim passes"),
    ], fontsize=8, loc="lower left", bbox_to_anchor=(0, 1.0), ncol=5, frameon=False)
    own = df[df["origin"] == "paper"]
    counts = own["verdict"].value_counts()
    others = len(df) - len(own)
    fig.suptitle(f"The paper's own claims at our scale: {counts.get('pass', 0)} pass, {counts.get('fail', 0)} fail, "
                 f"{counts.get('not run', 0)} not run; within seed noise: {int(own['within_noise'].sum())}"
                 + (f" (plus {others} of ours or repeated on another take)" if others else ""))
    return fig


# --------------------------------------------------------------------------------------------
# Issue #25 item 3 (not a paper table): one layout-conditioned model against a model per layout


# The take -> per-layout model map and item 3's tolerance when the report has no claims CSV.
PER_LAYOUT = {"hdm05": "hdm05_layout", "cmu": "cmu41_layout", "pig": "pig_layout"}
TARGET_POINTS = 3.0


def not_behind_claims(metric: str = "acc") -> pd.DataFrame | None:
    """The spec's `not_behind` claims on `metric` as the report wrote them
    (<results>/any_layout_claims.csv: better = the per-layout variant, worse_test = the take), the
    claims the run decided before those it did not run; None without the file."""
    path = results_dir() / "any_layout_claims.csv"
    if not path.is_file():
        return None
    c = pd.read_csv(path)
    c = c[(c["kind"] == "not_behind") & (c["metric"] == metric)]
    return pd.concat([c[c["verdict"] != "not run"], c[c["verdict"] == "not run"]])


def any_layout_targets(metric: str = "acc") -> tuple[dict[str, tuple[str, float]], set[str]]:
    """(take -> (its per-layout variant, points a conditioned model may trail it), every per-layout
    variant), from not_behind_claims (the first claim of each take); PER_LAYOUT and TARGET_POINTS
    without them."""
    targets: dict[str, tuple[str, float]] = {}
    per_layout = set(PER_LAYOUT.values())
    c = not_behind_claims(metric)
    if c is not None:
        for _, row in c.iterrows():
            targets.setdefault(row["worse_test"], (row["better"], float(row["tolerance"])))
            per_layout.add(row["better"])
    return targets or {test: (v, TARGET_POINTS) for test, v in PER_LAYOUT.items()}, per_layout


def plot_any_layout(df: pd.DataFrame, metric: str = "acc"):
    """One panel per real take: a bar per conditioned variant (mean over seeds, ± seed std, each
    seed a dot), the take's per-layout model as a solid line and item 3's target (at most 3 points
    behind it, ahead by any margin) shaded; model and tolerance from any_layout_targets. Variants
    not run on a take are left out."""
    d = _metric(df, metric)
    tests = ordered(d["test"])
    targets, per_layout = any_layout_targets(metric)
    variants = [v for v in ordered(d["variant"])
                if v not in per_layout and d[d["variant"] == v]["mean"].notna().any()]
    fig, axes = plt.subplots(1, len(tests), figsize=(6 * len(tests), 0.8 * len(variants) + 2.6),
                             constrained_layout=True, squeeze=False, sharey=True)
    seeds = None
    seeds_path = results_dir() / "any_layout_seeds.csv"
    if seeds_path.is_file():
        seeds = pd.read_csv(seeds_path)
        seeds = seeds[seeds["metric"] == metric]
    for ax, test in zip(axes[0], tests):
        g = d[d["test"] == test]
        ref_variant, tolerance = targets.get(test, ("", TARGET_POINTS))
        ref = g[g["variant"] == ref_variant]
        if not ref.empty and not pd.isna(ref.iloc[0]["mean"]):
            r = ref.iloc[0]["mean"]
            ax.axvspan(r - tolerance, 100, color="tab:green", alpha=0.15,
                       label=f"at most {tolerance:g} points behind it (item 3's target)")
            ax.axvline(r, color="tab:green", lw=2, label=f"per-layout model {r:.2f}")
        for i, variant in enumerate(variants):
            rows = g[g["variant"] == variant]
            if rows.empty or pd.isna(rows.iloc[0]["mean"]):
                continue
            row = rows.iloc[0]
            std = _num(row["std_seeds"]) or 0
            ax.barh(i, row["mean"], 0.6, xerr=std, color=OURS_COLOR, capsize=3, edgecolor="black",
                    hatch="///" if row["status"] == "partial" else None)
            if seeds is not None:
                s = seeds[(seeds["variant"] == variant) & (seeds["test"] == test)]["value"]
                ax.plot(s, [i] * len(s), "o", color="black", ms=3)
            note = status_note(row)
            ax.text(row["mean"] + std + 0.5, i, f"{row['mean']:.2f}" + (f" ({note})" if note else ""),
                    va="center", fontsize=8)
        labels = [(d[d["variant"] == v]["variant_label"].iloc[0] or v).removeprefix("one conditioned model: ")
                  for v in variants]
        ax.set_yticks(range(len(variants)), ["\n".join(textwrap.wrap(t, 48)[:3]) for t in labels], fontsize=7)
        lo = np.nanmin(g["mean"]) if g["mean"].notna().any() else 0
        ax.set_xlim(max(0, lo - 10), 100)
        ax.set_xlabel(f"{metric} per frame (%), mean ± std over seeds (dots: seeds)")
        ax.grid(axis="x", alpha=0.3)
        ax.set_title(g["test_label"].iloc[0] if not g.empty else test, fontsize=10)
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2, fontsize=7, frameon=False)
    axes[0][0].invert_yaxis()
    fig.suptitle(f"One layout-conditioned model, never trained on the test layouts, against a model per layout ({metric})")
    return fig


FINETUNE_GLOBS = ("finetune*.csv", "any_layout_finetune*.csv")


def load_finetune() -> pd.DataFrame | None:
    """Every fine-tuning table beside the report (<results>/finetune*.csv or
    any_layout_finetune*.csv, written by ablations/any_layout_finetune.sh: target, seed, epochs,
    train_minutes, acc_mean, f1_mean, checkpoint; epochs 0 is the conditioned model before
    fine-tuning) as one DataFrame with a `run` column, the file's stem without its "finetune"
    prefix (e.g. "lr1e-4"), or None when there is none."""
    paths = sorted({p for g in FINETUNE_GLOBS for p in results_dir().glob(g)})
    if not paths:
        print(f"fine-tuning: not run yet (no finetune*.csv in {results_dir()})")
        return None
    frames = []
    for path in paths:
        d = pd.read_csv(path)
        d["run"] = re.sub(r"^(any_layout_)?finetune_?", "", path.stem) or "default"
        frames.append(d)
    df = pd.concat(frames, ignore_index=True)
    print(f"fine-tuning: {len(paths)} tables, {len(df)} rows ({', '.join(ordered(df['run']))})")
    return df


def plot_any_layout_finetune(ft: pd.DataFrame, df: pd.DataFrame | None = None, metric: str = "acc"):
    """Issue #25 item 3's second question: how much training on a new layout closes the rest of
    the gap. One panel per take: per fine-tuning table, the take's accuracy per frame against
    epochs of fine-tuning (mean over seeds of each epoch count; bars: seed std; epochs 0 is the
    conditioned model as it was; each point labelled with the mean minutes of training, wall time
    that depends on what else ran beside it, hence epochs on the axis), and, from the report `df`
    (any_layout.csv), the per-layout models item 3's claims compare with, as lines."""
    col = f"{metric}_mean"
    targets = ordered(ft["target"])
    fig, axes = plt.subplots(1, len(targets), figsize=(6.5 * len(targets), 4.6), constrained_layout=True,
                             squeeze=False)
    claims = not_behind_claims(metric)
    for ax, target in zip(axes[0], targets):
        g = ft[ft["target"] == target]
        for run in ordered(g["run"]):
            r = g[g["run"] == run].groupby("epochs").agg(
                minutes=("train_minutes", "mean"), value=(col, "mean"), std=(col, "std"), n=("seed", "count"))
            seeds = int(r["n"].max())
            ax.errorbar(r.index, 100 * r["value"], yerr=100 * r["std"].fillna(0), marker="o", capsize=3,
                        label=f"fine-tuned, {run} ({seeds} seed{'s' if seeds != 1 else ''})")
            for epochs, row in r.iterrows():
                if epochs > 0:
                    ax.annotate(f"{row['minutes']:.1f} min", (epochs, 100 * row["value"]),
                                textcoords="offset points", xytext=(0, 6), ha="center", fontsize=7)
        if df is not None:
            d = _metric(df, metric)
            d = d[(d["test"] == target) & d["mean"].notna()]
            refs = ordered(claims[claims["worse_test"] == target]["better"]) if claims is not None else []
            refs = refs or [PER_LAYOUT.get(target, "")]
            drawn = 0
            for variant in refs:
                row = d[d["variant"] == variant]
                if row.empty:
                    continue
                value = row.iloc[0]["mean"]
                ax.axhline(value, color="tab:green", ls=("-", "--", ":", "-.")[drawn % 4], lw=1.5,
                           label=f"per-layout model {variant}: {value:.2f}")
                drawn += 1
        ax.set_xscale("symlog", base=2, linthresh=1)
        ticks = sorted(int(e) for e in g["epochs"].unique())
        ax.set_xticks(ticks, [str(e) for e in ticks])
        ax.set_xlim(-0.3, max(ticks) * 1.25)
        ax.set_xlabel("epochs of fine-tuning on the take's layout (labels: minutes of training, mean over seeds)")
        ax.set_ylabel(f"{metric} per frame (%)")
        ax.grid(alpha=0.3)
        ax.set_title(target, fontsize=10)
        ax.legend(fontsize=7, loc="lower right")
    fig.suptitle("Fine-tuning a layout-conditioned model on a new layout: accuracy against epochs of training")
    return fig


PLOTS = {
    "table1": plot_table1,
    "table2": plot_table2,
    "table3": plot_table3,
    "table4": plot_table4,
    "table5": plot_table5,
    "fig_c1": plot_fig_c1,
    "fig_c2": plot_fig_c2,
    "fig_c3": plot_fig_c3,
    "claims": plot_claims,
    "any_layout": plot_any_layout,
}


def plot(name: str, df: pd.DataFrame):
    return PLOTS[name](df)


def main(argv: list[str]) -> int:
    for name in argv or (*NAMES, "claims"):
        df = load(name)
        if df is not None:
            print(summary(df).to_string())
            save(plot(name, df), name)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
