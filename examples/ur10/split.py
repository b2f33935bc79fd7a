"""Seeded train / validation split of a torchcal measurement CSV by pose id, by the tool:
``torchcal split DATA --fraction F --seed S --out TRAIN VAL --robot ur10.json``.

All rows of one pose go to the same side (the pose ids permuted by numpy's
``default_rng(seed)``; the first ``round(fraction * poses)`` train). Rows keep their
measurement order, and both files carry ``prev_q1..prev_q6``, the angles each row was
approached from in the whole session, so backlash-like effects read them as in DATA.

Usage: python split.py DATA.csv --fraction 0.6 --seed 0 TRAIN.csv VAL.csv [--force]
"""

import argparse
import subprocess
import sys
from pathlib import Path


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data")
    ap.add_argument("train")
    ap.add_argument("val")
    ap.add_argument("--fraction", default="0.6", help="share of poses for training (default 0.6)")
    ap.add_argument("--seed", default="0")
    ap.add_argument("--force", action="store_true", help="replace existing TRAIN / VAL files")
    args = ap.parse_args()
    cmd = [sys.executable, "-m", "torchcal", "split", args.data, "--fraction", args.fraction, "--seed", args.seed,
           "--robot", str(Path(__file__).with_name("ur10.json")), "--out", args.train, args.val]
    sys.exit(subprocess.run(cmd + (["--force"] if args.force else [])).returncode)


if __name__ == "__main__":
    main()
