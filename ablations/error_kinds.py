#!/usr/bin/env python3
"""What kind of errors a labelling makes, from `soma eval` outputs.

    /usr/bin/python3 ablations/error_kinds.py <out.csv> NAME=<eval dir>...

Each <eval dir> is a `soma eval` run directory (its confusion.csv and
per_frame.csv), e.g. results/reproduce/models/<variant>/seed0/tests/<take>/eval.
One row per NAME, every count over the take's (ground truth, prediction)
pairs of confusion.csv, whose label `nan` is "no marker" (a ghost point in
the ground truth, an unlabelled point in the prediction):

    name, pairs, correct,
    swapped         a marker given another marker's label,
    missed          a marker left unlabelled,
    ghost_labelled  a ghost point given a marker's label,
    then each of the three as a percentage of the pairs (swapped_pct,
    missed_pct, ghost_labelled_pct), and
    bad_frames      frames with accuracy below 50% (per_frame.csv), and
    bad_frames_pct  the points those frames lose, as a percentage of the
                    mean per-frame accuracy (how much of the error is
                    whole-frame failures rather than a few labels per frame).

The table is written atomically (a temporary file, then a rename).
"""

from __future__ import annotations

import csv
import os
import pathlib
import sys
import tempfile

NULL = "nan"
FIELDS = ("name", "pairs", "correct", "swapped", "missed", "ghost_labelled", "swapped_pct", "missed_pct",
          "ghost_labelled_pct", "bad_frames", "bad_frames_pct")


def fail(message: str) -> None:
    print(f"error_kinds: {message}", file=sys.stderr)
    sys.exit(1)


def confusion_counts(path: pathlib.Path) -> dict[str, int]:
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    if not rows or len(rows[0]) < 2:
        fail(f"{path}: empty or without a header (expected soma eval's confusion.csv)")
    predicted = rows[0][1:]
    counts = dict(pairs=0, correct=0, swapped=0, missed=0, ghost_labelled=0)
    for row in rows[1:]:
        if len(row) != len(rows[0]):
            fail(f"{path}: row '{row[0] if row else ''}' has {len(row)} cells, the header {len(rows[0])}")
        truth = row[0]
        for label, cell in zip(predicted, row[1:]):
            try:
                n = int(float(cell))
            except ValueError:
                fail(f"{path}: cell ({truth}, {label}) is '{cell}', expected a count")
            counts["pairs"] += n
            if label == truth:
                counts["correct"] += n
            elif label == NULL:
                counts["missed"] += n
            elif truth == NULL:
                counts["ghost_labelled"] += n
            else:
                counts["swapped"] += n
    return counts


def bad_frames(path: pathlib.Path) -> tuple[int, float]:
    """(frames below 50% accuracy, the accuracy they cost in points of the per-frame mean)."""
    with path.open(newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows or "accuracy" not in rows[0]:
        fail(f"{path}: no 'accuracy' column (expected soma eval's per_frame.csv)")
    accuracy = [float(r["accuracy"]) for r in rows]
    bad = [a for a in accuracy if a < 0.5]
    return len(bad), 100.0 * sum(1.0 - a for a in bad) / len(accuracy)


def main(argv: list[str]) -> int:
    if len(argv) < 2 or any("=" not in a for a in argv[1:]):
        print(__doc__.split("\n\n")[1], file=sys.stderr)
        return 2
    out = pathlib.Path(argv[0])
    rows = []
    for arg in argv[1:]:
        name, directory = arg.split("=", 1)
        directory = pathlib.Path(directory)
        for file in ("confusion.csv", "per_frame.csv"):
            if not (directory / file).is_file():
                fail(f"{directory / file} is missing (expected a soma eval run directory)")
        c = confusion_counts(directory / "confusion.csv")
        if c["pairs"] == 0:
            fail(f"{directory / 'confusion.csv'}: no pairs")
        frames, cost = bad_frames(directory / "per_frame.csv")
        row = dict(name=name, **c, bad_frames=frames, bad_frames_pct=f"{cost:.2f}")
        for kind in ("swapped", "missed", "ghost_labelled"):
            row[f"{kind}_pct"] = f"{100.0 * c[kind] / c['pairs']:.2f}"
        rows.append(row)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=out.parent, prefix=out.name, suffix=".tmp")
    with os.fdopen(fd, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    os.replace(tmp, out)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
