"""TARGETS.csv of ``torchcal compensate`` (docs/formats.md): the positions to reach and,
optionally, the seed of each target and the conditions of each move.

Header ``x,y,z`` (mm, in the frame the caller names: the model's measuring frame or the
robot base frame, `torchcal.api.compensate_targets`; metres with ``length_unit="m"``), optionally
``q1..qN`` (degrees, mm for a prismatic joint; ``angle_unit="rad"``, ``length_unit="m"``),
``payload_kg`` and ``temp_c``; an optional ``point`` column is ignored.
Q.csv of ``torchcal compensate``: `compensation_csv`.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch

from torchcal.errors import InputError
from torchcal.io.files import csv_rows
from torchcal.io.measurement_csv import LENGTH_UNITS, check_temperatures

__all__ = ["read_targets", "compensation_csv"]


def read_targets(path, n: int, length_unit: str = "mm", angle_unit: str = "deg", prismatic=None):
    """(targets (M, 3) mm, seeds (M, n) deg (mm for a prismatic joint) or None, extra
    {"payload_kg", "temp_c": (M,) or None}) from the CSV; InputError naming line and column.

    prismatic: optional (n,) bool; those seed columns are lengths in `length_unit`, the
    others angles in `angle_unit`."""
    path = Path(path)
    rows = [(line, row) for line, row in csv_rows(path, "targets file", f"x,y,z[,q1..q{n}]")
            if row and any(c.strip() for c in row)]  # blank lines are skipped
    if not rows:
        raise InputError(f"{path}: empty file; expected a header x,y,z[,q1..q{n}]")
    header = [h.strip() for h in rows[0][1]]
    for i, h in enumerate(header):
        if h in header[:i]:
            raise InputError(f"{path}: column {h!r}: duplicated header column "
                             f"(columns {header.index(h) + 1} and {i + 1})")
    qcols = [f"q{k}" for k in range(1, n + 1)]
    for c in ("x", "y", "z"):
        if c not in header:
            raise InputError(f"{path}: header has no column {c!r}; expected x,y,z[,q1..q{n}], got {','.join(header)}")
    has_q = any(h.startswith("q") for h in header)
    if has_q and not all(c in header for c in qcols):
        missing = [c for c in qcols if c not in header]
        raise InputError(f"{path}: seed columns incomplete: missing {','.join(missing)} (expected q1..q{n} in degrees)")
    opt = [c for c in ("payload_kg", "temp_c") if c in header]
    unknown = [h for h in header if h not in ("x", "y", "z", "point", "payload_kg", "temp_c", *qcols)]
    if unknown:
        what = " (a measurement file? targets are the positions to reach)" if "pose" in unknown else ""
        raise InputError(f"{path}: unknown column(s) {','.join(unknown)}{what}; "
                         f"expected x,y,z[,q1..q{n}][,payload_kg][,temp_c]")
    extra = {c: [] for c in opt}
    slides = [False] * n if prismatic is None else [bool(p) for p in prismatic]
    idx = {h: i for i, h in enumerate(header)}
    xyz, qs = [], []
    for line, row in rows[1:]:
        if len(row) != len(header):
            raise InputError(f"{path}: line {line}: expected {len(header)} columns, got {len(row)}")

        def num(col, unit):
            cell = row[idx[col]].strip()
            try:
                v = float(cell)
            except ValueError:
                raise InputError(f"{path}: line {line}, column {col}: expected a number ({unit}), got {cell!r}") from None
            if not math.isfinite(v):
                raise InputError(f"{path}: line {line}, column {col}: expected a finite number ({unit}), got {cell!r}")
            return v
        xyz.append([num(c, length_unit) for c in ("x", "y", "z")])
        if has_q:
            qs.append([num(c, length_unit if p else ("degrees" if angle_unit == "deg" else "rad"))
                       for c, p in zip(qcols, slides)])
        for c in opt:
            v = num(c, "kg" if c == "payload_kg" else "degC")
            if c == "payload_kg" and v < 0:
                raise InputError(f"{path}: line {line}, column payload_kg: payload must be >= 0 kg, got {v}")
            extra[c].append(v)
    if not xyz:
        raise InputError(f"{path}: no target rows")
    t = torch.tensor(xyz, dtype=torch.float64) * LENGTH_UNITS[length_unit]
    seeds = None
    if has_q:
        seeds = torch.tensor(qs, dtype=torch.float64)
        if angle_unit == "rad":
            seeds = torch.rad2deg(seeds)
        if prismatic is not None:  # a slide's seed is a length, never an angle
            pris = torch.as_tensor(prismatic, dtype=torch.bool).cpu()
            seeds = torch.where(pris, torch.tensor(qs, dtype=torch.float64) * LENGTH_UNITS[length_unit], seeds)
    if "temp_c" in extra:  # kelvin or Fahrenheit: one warning line, as for measurements
        check_temperatures(path, extra["temp_c"], [line for line, _ in rows[1:]])
    cond = {c: (torch.tensor(extra[c], dtype=torch.float64) if c in extra else None)
            for c in ("payload_kg", "temp_c")}
    return t, seeds, cond


def compensation_csv(result) -> str:
    """Q.csv text ``point,zone,q1..qN,residual_mm,converged,within_limits`` of a
    `torchcal.calibration.compensate.TargetCompensation`: zone 1-based, q in deg (mm for a
    prismatic joint), residual_mm the distance in mm, converged and within_limits as
    true / false; points 1-based."""
    zone, q_user, residual_mm = result.zone, result.q_user, result.residual_mm
    converged, within_limits = result.compensation.converged, result.compensation.within_limits
    n = q_user.shape[1]
    lines = [",".join(["point", "zone", *(f"q{k}" for k in range(1, n + 1)), "residual_mm", "converged",
                       "within_limits"])]
    for i in range(q_user.shape[0]):
        lines.append(",".join([str(i + 1), str(int(zone[i])), *("%.15g" % v for v in q_user[i].tolist()),
                               repr(float(residual_mm[i])), str(bool(converged[i])).lower(),
                               str(bool(within_limits[i])).lower()]))
    return "\n".join(lines) + "\n"
