#!/usr/bin/env python3
"""Per-frame accuracy of a labelled take split by whether the body is on the
floor or in the air (its two lowest points above `--air` metres).

Usage: airborne_split.py TAKE.h5 PER_FRAME.csv [PER_FRAME.csv ...]
  TAKE.h5        the corrupted take's ground truth (`soma corrupt` output;
                 points B x N x 3, missing points all-zero)
  PER_FRAME.csv  `soma eval`'s per_frame.csv of one model on that take
Prints one row per csv: all frames, grounded, airborne, and the number of
frames under 50% per-frame accuracy (catastrophic frames).
"""
import argparse
import csv

import h5py
import numpy as np


def lowest_height(points):
    valid = ~(points == 0).all(2) & np.isfinite(points).all(2)
    out = np.empty(len(points))
    for f in range(len(points)):
        z = np.sort(points[f][valid[f]][:, 2])
        out[f] = z[:2].mean() if len(z) else np.nan
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("take")
    parser.add_argument("per_frame", nargs="+")
    parser.add_argument("--air", type=float, default=0.08,
                        help="lowest-point height (m) above which a frame is airborne")
    args = parser.parse_args()
    with h5py.File(args.take, "r") as f:
        low = lowest_height(f["points"][:])
    air = low > args.air
    print(f"frames {len(low)}, airborne {int(air.sum())} (two lowest points > {args.air} m)")
    print("per_frame.csv | all | grounded | airborne | frames < 50%")
    for path in args.per_frame:
        with open(path) as fh:
            acc = np.array([float(r["accuracy"]) for r in csv.DictReader(fh)])
        if len(acc) != len(low):
            raise SystemExit(f"{path}: {len(acc)} frames, the take has {len(low)}")
        print(f"{path} | {100 * acc.mean():.2f} | {100 * acc[~air].mean():.2f} | "
              f"{100 * acc[air].mean():.2f} | {int((acc < 0.5).sum())}")


if __name__ == "__main__":
    main()
