#!/usr/bin/env python3
"""Per-frame accuracy of a labelled take split by body height: frames whose
highest labelled marker is below `--low` metres (crouched, on hands and feet,
kneeling) against the rest, and per block of 1000 frames.

Usage: low_split.py TAKE.h5 PER_FRAME.csv [PER_FRAME.csv ...]
  TAKE.h5        the corrupted take's ground truth (`soma corrupt` or
                 `soma label_eval` output: points F x N x 3, labels F x N
                 with -1 for ghosts and missing points all-zero)
  PER_FRAME.csv  `soma eval` / `soma label_eval`'s per_frame.csv of one model
Prints one row per csv: all frames, low frames, the others, and the blocks.
"""
import argparse
import csv

import h5py
import numpy as np


def highest_marker(points, labels):
    valid = (labels >= 0) & ~(points == 0).all(2) & np.isfinite(points).all(2)
    z = np.where(valid, points[:, :, 2], -np.inf)
    return z.max(1)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("take")
    parser.add_argument("per_frame", nargs="+")
    parser.add_argument("--low", type=float, default=1.0,
                        help="highest-marker height (m) below which a frame is low")
    parser.add_argument("--block", type=int, default=1000)
    args = parser.parse_args()
    with h5py.File(args.take, "r") as f:
        top = highest_marker(f["points"][:], f["labels"][:])
    low = top < args.low
    n = len(top)
    blocks = [(b, min(b + args.block, n)) for b in range(0, n, args.block)]
    print(f"frames {n}, low {int(low.sum())} (highest labelled marker < {args.low} m)")
    print("per_frame.csv | all | low | others | " +
          " | ".join(f"{b}-{e - 1}" for b, e in blocks))
    for path in args.per_frame:
        with open(path) as f:
            acc = np.array([float(r["accuracy"]) for r in csv.DictReader(f)])
        if len(acc) != n:
            raise SystemExit(f"{path}: {len(acc)} frames, the take has {n}")
        cells = [acc.mean(), acc[low].mean(), acc[~low].mean()]
        cells += [acc[b:e].mean() for b, e in blocks]
        print(path + " | " + " | ".join(f"{100 * c:.2f}" for c in cells))


if __name__ == "__main__":
    main()
