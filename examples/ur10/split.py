"""Seeded train / validation split of a torchcal measurement CSV by pose id.

All rows of one pose go to the same side. The poses are permuted by numpy's
``default_rng(seed)``; the first ``round(fraction * poses)`` form the training set. Rows
keep their file (measurement) order on each side.

Usage: python split.py DATA.csv --fraction 0.6 --seed 0 TRAIN.csv VAL.csv
"""

import argparse
import csv

import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data")
    ap.add_argument("train")
    ap.add_argument("val")
    ap.add_argument("--fraction", type=float, default=0.6, help="share of poses for training (default 0.6)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    with open(args.data, newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    col = header.index("pose")
    pose = np.array([int(r[col]) for r in body])
    poses = np.unique(pose)
    train = np.random.default_rng(args.seed).permutation(poses)[: int(round(args.fraction * len(poses)))]
    is_train = np.isin(pose, train)
    for path, keep in ((args.train, is_train), (args.val, ~is_train)):
        with open(path, "w", newline="") as f:
            w = csv.writer(f, lineterminator="\n")
            w.writerow(header)
            w.writerows(r for r, k in zip(body, keep) if k)
    print(f"{args.data}: {len(poses)} poses -> {args.train} {int(is_train.sum())} rows, "
          f"{args.val} {int((~is_train).sum())} rows (seed {args.seed})")


if __name__ == "__main__":
    main()
