"""The sweep CSV of ``torchcal sweep`` (docs/formats.md), one row per workspace point,
after one line recording the robot it was made for:

    # torchcal-sweep/2 {"made_for": {"name", "fingerprint", "nominal_robot"}}
    point,q1..qN,x,y,z,ex_lo,ex_hi,ey_lo,ey_hi,ez_lo,ez_hi,dist_lo,dist_hi,eta,r_set

A sweep of worst-case bounds (`torchcal sweep --bounds worst`, `SweepResult.bounds`) has
one more column, ``dist_hi_outer`` after ``dist_hi``: its guaranteed first-order upper
bound of the distance error (`torchcal.reliability.worst_case`); the header so says which
bounds the rows hold, and `read_sweep` reads both.

The first line is `RECORD` and one line of JSON: the robot record of
`torchcal.io.robot_file.robot_record` (name, SHA-256 fingerprint of the nominal kinematics
and joint limits, the robot-file dict). q in degrees (mm for a prismatic joint),
positions and errors in mm; floats are written exactly (shortest repr). `write_sweep`
writes a `torchcal.reliability.sweep.SweepResult` atomically
(`torchcal.io.files.atomic_write`), the record line when its ``robot`` is known;
`read_sweep` reads one back (the linearised bounds, allowed_mm and n_samples are not
stored: None), and refuses, given a robot, a sweep made for another
(`torchcal.io.robot_file.check_record`). A file of an older torchcal (no record line)
still reads: with a robot given, one `UnrecordedRobotWarning`. Every bad file gives one
InputError naming the file, row (file line) and column.
"""

from __future__ import annotations

import csv
import io as _io
import json
import math
from pathlib import Path

import numpy as np
import torch

from torchcal.errors import InputError
from torchcal.io.files import atomic_write
from torchcal.io.robot_file import check_record, record_from_dict, robot_from_dict, robot_record
from torchcal.reliability.sweep import SweepResult

__all__ = ["sweep_columns", "sweep_head", "sweep_csv_text", "sweep_csv_rows", "write_sweep", "read_sweep",
           "sweep_record"]

#: the start of the sweep CSV's first line, the robot record (then one line of JSON)
RECORD = "# torchcal-sweep/2 "


def sweep_columns(n: int, bounds: str = "sampled") -> list[str]:
    """The header of a sweep CSV for n joints and `bounds` ("sampled" or "worst": with the
    column dist_hi_outer)."""
    outer = ["dist_hi_outer"] if bounds == "worst" else []
    return (["point"] + [f"q{i + 1}" for i in range(n)] + ["x", "y", "z", "ex_lo", "ex_hi", "ey_lo",
            "ey_hi", "ez_lo", "ez_hi", "dist_lo", "dist_hi"] + outer + ["eta", "r_set"])


def sweep_head(n: int, robot=None, bounds: str = "sampled") -> str:
    """The lines before the rows of a sweep CSV for n joints: the record of `robot` (when
    given, module doc) and the column header (of `bounds`)."""
    head = ",".join(sweep_columns(n, bounds)) + "\n"
    if robot is None:
        return head
    record = json.dumps({"made_for": robot_record(robot)}, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return RECORD + record + "\n" + head


def sweep_csv_text(result: SweepResult) -> str:
    """The CSV text of a sweep: its robot's record (when known), the header, the rows; q in
    degrees (mm for a prismatic joint), mm."""
    return sweep_head(result.q.shape[1], result.robot, result.bounds) + sweep_csv_rows(result)


def sweep_csv_rows(result: SweepResult) -> str:
    """The data rows of the sweep CSV (no header), ids from `result.point` (default 0..N-1)."""
    q = torch.rad2deg(result.q)
    if result.prismatic is not None:
        q = torch.where(result.prismatic.to(q.device), result.q, q)
    cols = [q, result.positions,
            torch.stack([result.err_lower, result.err_upper], dim=-1).reshape(-1, 6),
            result.dist_lower[:, None], result.dist_upper[:, None]]
    if result.dist_upper_outer is not None:  # bounds "worst"
        cols.append(result.dist_upper_outer[:, None])
    cols += [result.eta[:, None], result.r_set[:, None]]
    data = torch.cat([c.detach().to("cpu", torch.float64) for c in cols], dim=1).numpy()
    buf = _io.StringIO()
    ids = range(len(data)) if result.point is None else result.point.tolist()
    for i, row in zip(ids, data.tolist()):
        buf.write(f"{i}," + ",".join(map(repr, row)) + "\n")
    return buf.getvalue()


def write_sweep(result: SweepResult, path, force: bool = False) -> Path:
    """Write the sweep CSV atomically; an existing file only with force=True."""
    return atomic_write(path, sweep_csv_text(result), force=force)


def read_sweep(path, device=None, prismatic=None, robot=None) -> SweepResult:
    """Read a sweep CSV into a `SweepResult` (linearised bounds, allowed_mm, n_samples: None;
    ``robot``: the robot of its record, None for a file without one; ``bounds`` "worst"
    with ``dist_upper_outer`` where the header has the column dist_hi_outer, else "sampled").

    prismatic: optional (n,) bool, joints whose q column is mm (kept), not degrees;
        default: those of the recorded robot (or of `robot` for a file without a record).
    robot: optional `Robot` the sweep is for: a sweep made for another robot (another
        fingerprint, and another joint count, types, MD-H table, base, tool or joint limits)
        is refused (`torchcal.io.robot_file.check_record`); a file without a record reads,
        with one `UnrecordedRobotWarning`.

    One InputError naming the file, row (file line) and column for a bad record line, a
    bad header, a ragged row, a non-numeric or non-finite value, or an R_set outside [0, 1].
    """
    path = Path(path)
    record = sweep_record(path)
    try:
        with open(path, newline="") as fh:
            if record is not None:
                fh.readline()  # the record line, read by sweep_record
            rows = list(csv.reader(fh))
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a text CSV file ({exc})") from None
    except csv.Error as exc:
        raise InputError(f"{path}: malformed CSV: {exc}") from None
    top = 1 if record is None else 2  # the file line of the header
    if not rows:
        raise InputError(f"{path}: {'empty file' if record is None else 'only the robot record'}, "
                         f"expected a sweep CSV header")
    header = [h.strip() for h in rows[0]]
    n = len([h for h in header if len(h) > 1 and h[0] == "q" and h[1:].isdigit()])
    bounds = "worst" if "dist_hi_outer" in header else "sampled"
    expected = sweep_columns(n, bounds)
    if n == 0 or header != expected:
        raise InputError(f"{path}: {'' if top == 1 else f'line {top}: '}header must be "
                         f"{','.join(expected if n else ['point', 'q1', '...'])}, got {','.join(header)}")
    made = None if record is None else robot_from_dict(record["nominal_robot"], f"{path}: line 1: nominal_robot")
    if made is not None and made.n != n:
        raise InputError(f"{path}: line 1 records robot {record['name']!r} with {made.n} joints, "
                         f"but the header has {n} joint columns (q1..q{n})")
    if robot is not None:
        check_record(record, robot, str(path), "sweep")
    source = made if made is not None else robot
    if prismatic is None and source is not None:
        prismatic = source.prismatic.cpu()
    rows = [(line, row) for line, row in enumerate(rows[1:], start=top + 1)
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
    _check_unique_points(path, ids, [line for line, _ in rows])
    _check_r_set_of_eta(path, data[:, -2], data[:, -1], [line for line, _ in rows])
    x = 1 if bounds == "worst" else 0  # dist_hi_outer between dist_hi and eta
    _check_one_allowed(path, data[:, -4 - x], data[:, -3 - x], data[:, -2], [line for line, _ in rows])
    t = torch.from_numpy(data).to(device)
    k = n
    q = torch.deg2rad(t[:, :k])
    if prismatic is not None:
        prismatic = torch.as_tensor(prismatic, dtype=torch.bool, device=q.device)
        q = torch.where(prismatic, t[:, :k], q)
    e = t[:, k + 3:k + 9].reshape(-1, 3, 2)
    return SweepResult(q=q, positions=t[:, k:k + 3], err_lower=e[..., 0].contiguous(),
                       err_upper=e[..., 1].contiguous(), dist_lower=t[:, k + 9], dist_upper=t[:, k + 10],
                       eta=t[:, -2], r_set=t[:, -1], point=torch.from_numpy(ids).to(device),
                       prismatic=prismatic, robot=made, bounds=bounds,
                       dist_upper_outer=t[:, k + 11] if x else None)


def _check_unique_points(path, ids: np.ndarray, lines: list[int]) -> None:
    """InputError naming the first row whose point id (N,) an earlier row has: a sweep
    appended twice, or two sweeps in one file, would count its points twice in every zone."""
    counts = np.unique(ids, return_counts=True)[1]
    if not (counts > 1).any():
        return
    seen: dict[int, int] = {}
    for i, p in enumerate(ids.tolist()):
        if p in seen:
            raise InputError(f"{path}: row {lines[i]}, column point: id {p} repeats row {lines[seen[p]]} "
                             f"({int((counts > 1).sum())} ids repeat): the sweep appended twice, or two sweeps in one "
                             f"file? each point would count twice in its zone")
        seen[p] = i


#: largest |r_set - clip((1 + eta) / 2, 0, 1)| a sweep row may show (a file rounded to 4 digits)
R_SET_TOL = 1e-3


def _check_r_set_of_eta(path, eta: np.ndarray, r_set: np.ndarray, lines: list[int]) -> None:
    """InputError naming the first row whose r_set (N,) is not the R_set its eta (N,)
    gives: for the sweep's one crisp distance limit, R_set = clip((1 + eta) / 2, 0, 1)
    (`torchcal.reliability.rset`). Another R_set (1 - R_set, a column edited or pasted from
    another sweep) would make every level and zone of a partition wrong."""
    with np.errstate(over="ignore", invalid="ignore"):
        want = np.clip((1.0 + eta) / 2.0, 0.0, 1.0)
    bad = np.nonzero(np.abs(want - r_set) > R_SET_TOL)[0]
    if not bad.size:
        return
    i = int(bad[0])
    inverted = bool(np.all(np.abs(1.0 - want[bad] - r_set[bad]) <= R_SET_TOL))
    hint = ("1 - R_set in that column (an unreliability?)" if inverted
            else "the column edited, or pasted from another sweep or another definition of R_set")
    raise InputError(f"{path}: row {lines[i]}, column r_set: {r_set[i]:.6g} is not the R_set of its eta "
                     f"{eta[i]:.6g} (clip((1 + eta) / 2, 0, 1) = {want[i]:.6g}; {bad.size} of {len(r_set)} rows "
                     f"differ by more than {R_SET_TOL:g}): {hint}; write the sweep again with torchcal sweep")


#: largest relative spread of the allowed distance error the rows' eta imply (rounded files)
ALLOWED_REL_TOL = 1e-3


def _check_one_allowed(path, d_lo: np.ndarray, d_hi: np.ndarray, eta: np.ndarray, lines: list[int]) -> None:
    """InputError naming two rows whose eta (N,) imply different allowed distance errors D
    (mm): eta = (D - c) / r for the distance interval [d_lo, d_hi] (N,) mm of centre c and
    radius r > 0, so D = c + eta r. One sweep has one D; rows of sweeps made with other
    --allowed values, put in one file, give R_set values that cannot be compared."""
    c, r = (d_lo + d_hi) / 2.0, (d_hi - d_lo) / 2.0
    with np.errstate(over="ignore", invalid="ignore"):
        D = c + eta * r
    ok = np.nonzero((r > 0) & np.isfinite(D))[0]
    if ok.size < 2:
        return
    lo, hi = ok[np.argmin(D[ok])], ok[np.argmax(D[ok])]
    if D[hi] - D[lo] <= ALLOWED_REL_TOL * max(abs(D[hi]), abs(D[lo])):
        return
    raise InputError(f"{path}: rows {lines[lo]} and {lines[hi]}: eta and the distance interval give an allowed "
                     f"distance error of {D[lo]:.6g} mm and {D[hi]:.6g} mm (D = centre + eta x half-width): rows of "
                     f"sweeps made with different allowed errors in one file, whose R_set cannot be compared; make "
                     f"the sweep again with one allowed error")


def sweep_record(path) -> dict | None:
    """The robot record of the sweep CSV at `path` (its first line, module doc), None for
    a file of an older torchcal (no record line). One InputError naming the file for a
    missing file or a bad record line."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: sweep CSV does not exist")
    try:
        with open(path, newline="") as fh:
            first = fh.readline()
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a text CSV file ({exc})") from None
    return _record(first, path) if first.startswith(("#", '"#')) else None


def _record(line: str, path) -> dict:
    """The robot record of a sweep CSV's first line `line` (which starts with '#', or '"#':
    the line as a spreadsheet saves it back, split at its commas into quoted cells)."""
    if line.startswith('"#'):
        raise InputError(f"{path}: line 1: the robot record was saved back as quoted CSV cells (by a spreadsheet?); "
                         f"put back the line as torchcal sweep wrote it ({RECORD.strip()} {{...}}), or write the "
                         f"sweep again")
    if not line.startswith(RECORD):
        raise InputError(f"{path}: line 1: expected the robot record ({RECORD.strip()} {{...}}) or the header "
                         f"point,q1,..., got {line.strip()[:40]!r}")
    try:
        obj = json.loads(line[len(RECORD):])
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: line 1: the robot record is not valid JSON ({exc}); write the sweep again") from None
    if not isinstance(obj, dict) or set(obj) != {"made_for"}:
        raise InputError(f"{path}: line 1: expected the robot record {{\"made_for\": {{...}}}}")
    return record_from_dict(obj["made_for"], f"{path}: line 1: made_for")
