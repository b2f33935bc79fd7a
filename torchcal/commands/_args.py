"""Argument types and option groups shared by the sub-commands."""

from __future__ import annotations

import argparse
import math


def positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return v


def positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v


def add_output(p, name="--out", help="output file", required=True):
    p.add_argument(name, required=required, help=help)


def add_force(p):
    p.add_argument("--force", action="store_true", help="replace existing output files")


def add_viz(p):
    p.add_argument("--rrd", help="write a rerun recording (.rrd) here")
    p.add_argument("--plots", help="write PNG figures into this folder")
