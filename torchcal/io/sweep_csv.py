"""The sweep CSV of ``torchcal sweep`` (docs/formats.md), one row per workspace point:

    point,q1..qN,x,y,z,ex_lo,ex_hi,ey_lo,ey_hi,ez_lo,ez_hi,dist_lo,dist_hi,eta,r_set

q in degrees (mm for a prismatic joint), positions and errors in mm; floats are written
exactly (shortest repr). `write_sweep` writes a `torchcal.reliability.sweep.SweepResult`
atomically (`torchcal.io.files.atomic_write`); `read_sweep` reads one back (the linearised
bounds, allowed_mm and n_samples are not stored: None). Every bad file gives one
InputError naming the file, row (file line) and column.
"""

from __future__ import annotations

import csv
import io as _io
import math
from pathlib import Path

import numpy as np
import torch

from torchcal.errors import InputError
from torchcal.io.files import atomic_write
from torchcal.reliability.sweep import SweepResult

__all__ = ["sweep_columns", "sweep_csv_text", "sweep_csv_rows", "write_sweep", "read_sweep"]


def sweep_columns(n: int) -> list[str]:
    """The header of a sweep CSV for n joints."""
    return (["point"] + [f"q{i + 1}" for i in range(n)] + ["x", "y", "z", "ex_lo", "ex_hi", "ey_lo",
            "ey_hi", "ez_lo", "ez_hi", "dist_lo", "dist_hi", "eta", "r_set"])


def sweep_csv_text(result: SweepResult) -> str:
    """The CSV text of a sweep: q in degrees (mm for a prismatic joint), mm."""
    return ",".join(sweep_columns(result.q.shape[1])) + "\n" + sweep_csv_rows(result)


def sweep_csv_rows(result: SweepResult) -> str:
    """The data rows of the sweep CSV (no header), ids from `result.point` (default 0..N-1)."""
    q = torch.rad2deg(result.q)
    if result.prismatic is not None:
        q = torch.where(result.prismatic.to(q.device), result.q, q)
    cols = [q, result.positions,
            torch.stack([result.err_lower, result.err_upper], dim=-1).reshape(-1, 6),
            result.dist_lower[:, None], result.dist_upper[:, None], result.eta[:, None], result.r_set[:, None]]
    data = torch.cat([c.detach().to("cpu", torch.float64) for c in cols], dim=1).numpy()
    buf = _io.StringIO()
    ids = range(len(data)) if result.point is None else result.point.tolist()
    for i, row in zip(ids, data.tolist()):
        buf.write(f"{i}," + ",".join(map(repr, row)) + "\n")
    return buf.getvalue()


def write_sweep(result: SweepResult, path, force: bool = False) -> Path:
    """Write the sweep CSV atomically; an existing file only with force=True."""
    return atomic_write(path, sweep_csv_text(result), force=force)


def read_sweep(path, device=None, prismatic=None) -> SweepResult:
    """Read a sweep CSV into a `SweepResult` (linearised bounds, allowed_mm, n_samples: None).

    prismatic: optional (n,) bool, joints whose q column is mm (kept), not degrees.

    One InputError naming the file, row (file line) and column for a bad header, a
    ragged row, a non-numeric or non-finite value, or an R_set outside [0, 1].
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: sweep CSV does not exist")
    try:
        with open(path, newline="") as fh:
            rows = list(csv.reader(fh))
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a text CSV file ({exc})") from None
    except csv.Error as exc:
        raise InputError(f"{path}: malformed CSV: {exc}") from None
    if not rows:
        raise InputError(f"{path}: empty file, expected a sweep CSV header")
    header = [h.strip() for h in rows[0]]
    n = len([h for h in header if len(h) > 1 and h[0] == "q" and h[1:].isdigit()])
    expected = sweep_columns(n)
    if n == 0 or header != expected:
        raise InputError(f"{path}: header must be {','.join(expected if n else ['point', 'q1', '...'])}, "
                         f"got {','.join(header)}")
    rows = [(line, row) for line, row in enumerate(rows[1:], start=2)
            if row and any(c.strip() for c in row)]  # blank lines are skipped
    if not rows:
        raise InputError(f"{path}: no data rows")
    data = np.empty((len(rows), len(header) - 1))
    ids = np.empty(len(rows), dtype=np.int64)
    for i, (r, row) in enumerate(rows):
        if len(row) != len(header):
            raise InputError(f"{path}: row {r}: expected {len(header)} columns, got {len(row)}")
        try:
            ids[i] = int(row[0])
        except ValueError:
            raise InputError(f"{path}: row {r}, column point: not an integer: {row[0]!r}") from None
        for c, v in enumerate(row[1:], start=1):
            try:
                data[i, c - 1] = float(v)
            except ValueError:
                raise InputError(f"{path}: row {r}, column {header[c]}: not a number: {v!r}") from None
            if not math.isfinite(data[i, c - 1]):
                raise InputError(f"{path}: row {r}, column {header[c]}: not finite: {v!r}")
        if not 0.0 <= data[i, -1] <= 1.0:
            raise InputError(f"{path}: row {r}, column r_set: {data[i, -1]} is outside [0, 1]")
    t = torch.from_numpy(data).to(device)
    k = n
    q = torch.deg2rad(t[:, :k])
    if prismatic is not None:
        prismatic = torch.as_tensor(prismatic, dtype=torch.bool, device=q.device)
        q = torch.where(prismatic, t[:, :k], q)
    e = t[:, k + 3:k + 9].reshape(-1, 3, 2)
    return SweepResult(q=q, positions=t[:, k:k + 3], err_lower=e[..., 0].contiguous(),
                       err_upper=e[..., 1].contiguous(), dist_lower=t[:, k + 9], dist_upper=t[:, k + 10],
                       eta=t[:, k + 11], r_set=t[:, k + 12], point=torch.from_numpy(ids).to(device),
                       prismatic=prismatic)
