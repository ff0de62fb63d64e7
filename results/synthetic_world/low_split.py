#!/usr/bin/env python3
"""Per-frame accuracy of a labelled take split by body height: frames whose
highest labelled marker is below `--low` metres (crouched, on hands and feet,
kneeling) against the rest, per block of 1000 frames, and the marker-level
errors in the low frames (by true label and by confusion).

Usage: low_split.py TAKE.h5 PER_FRAME_DIR [PER_FRAME_DIR ...]
  TAKE.h5        the corrupted take's ground truth (`soma label_eval` writes
                 it under <run>/<setting>/: points F x N x 3, labels F x N
                 with the label count for ghosts, missing points all-zero)
  PER_FRAME_DIR  `soma label_eval`'s <run>/per_frame/ of one model: its
                 per_frame.csv and <take>_labels.h5 (the labels per point)
Prints one row per model and its low-frame confusions.
"""
import argparse
import collections
import csv
import glob
import os

import h5py
import numpy as np


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("take")
    parser.add_argument("per_frame_dirs", nargs="+")
    parser.add_argument("--low", type=float, default=1.0,
                        help="highest-marker height (m) below which a frame is low")
    parser.add_argument("--block", type=int, default=1000)
    parser.add_argument("--top", type=int, default=8, help="confusions listed")
    args = parser.parse_args()
    with h5py.File(args.take, "r") as f:
        names = [str(x) for x in f.attrs["labels"]]
        gt_labels = f["labels"][:]
        gt_points = f["points"][:]
    present = ~(gt_points == 0).all(2)
    labelled = present & (gt_labels < len(names))
    top = np.where(labelled, gt_points[:, :, 2], -np.inf).max(1)
    low = top < args.low
    n = len(top)
    blocks = [(b, min(b + args.block, n)) for b in range(0, n, args.block)]
    print(f"frames {n}, low {int(low.sum())} (highest labelled marker < {args.low} m)")
    print("model | all | low | others | low-frame marker errors | " +
          " | ".join(f"{b}-{e - 1}" for b, e in blocks))
    for d in args.per_frame_dirs:
        with open(os.path.join(d, "per_frame.csv")) as f:
            acc = np.array([float(r["accuracy"]) for r in csv.DictReader(f)])
        if len(acc) != n:
            raise SystemExit(f"{d}/per_frame.csv: {len(acc)} frames, the take has {n}")
        (labels_file,) = glob.glob(os.path.join(d, "*_labels.h5"))
        with h5py.File(labels_file, "r") as f:
            out_names = [str(x) for x in f.attrs["labels"]]
            out_labels = f["labels"][:]
            out_points = f["points"][:]
        errors, total = collections.Counter(), collections.Counter()
        for t in np.where(low)[0]:
            gi = np.where(present[t])[0]
            for j in range(out_points.shape[1]):
                x = out_points[t, j]
                if not np.isfinite(x).all() or (x == 0).all():
                    continue
                dist = np.abs(gt_points[t, gi] - x).max(1)
                k = dist.argmin()
                if dist[k] > 1e-5:
                    raise SystemExit(f"{labels_file}: frame {t}: a point not in the take")
                g = gt_labels[t, gi[k]]
                truth = names[g] if g < len(names) else "null"
                p = out_labels[t, j]
                said = out_names[p] if 0 <= p < len(out_names) else "null"
                total[truth] += 1
                if truth != said:
                    errors[(truth, said)] += 1
        cells = [acc.mean(), acc[low].mean(), acc[~low].mean()]
        blocks_acc = [acc[b:e].mean() for b, e in blocks]
        print(d + " | " + " | ".join(f"{100 * c:.2f}" for c in cells) +
              f" | {sum(errors.values())} of {sum(total.values())} | " +
              " | ".join(f"{100 * c:.2f}" for c in blocks_acc))
        by_label = collections.Counter()
        for (truth, _), count in errors.items():
            by_label[truth] += count
        print("  low frames, errors by true label: " + ", ".join(
            f"{k} {v}/{total[k]}" for k, v in by_label.most_common(args.top)))
        print("  low frames, top confusions: " + ", ".join(
            f"{a}->{b} {v}" for (a, b), v in errors.most_common(args.top)))


if __name__ == "__main__":
    main()
