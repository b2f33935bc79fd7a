"""The measurement CSV: ``pose,q1,...,qN,x,y,z[,point][,rx,ry,rz][,payload_kg][,temp_c]
[,prev_q1,...,prev_qN]`` (docs/formats-measurements.md).

`read_measurements` / `write_measurements`: degrees and mm in the file (other units by
``length_unit='m'`` / ``angle_unit='rad'``), radians and mm in `Measurements`; the q
column of a prismatic joint holds a length (mm, or m with ``length_unit='m'``; only
when the robot is given: without it every q column is an angle). ``point``
is an integer reflector id (several measured points per pose); ``rx, ry, rz`` are the
measured orientation as fixed-axis XYZ angles, R = Rz(rz) Ry(ry) Rx(rx). ``prev_q1..prev_qN``
(all or none, units as q) are the angles each row was approached from in the whole
session (`Measurements.q_prev`; a split file written by `torchcal split` carries them).
The header is required, names are exact, columns may come in any order;
every bad file gives one InputError line naming the file, ``line L (data row R)`` and the
column. Joint angles outside the robot's limits warn (`JointLimitWarning`) unless
``strict_limits=True``. Writes are atomic (`torchcal.io.files.atomic_write`).
"""

from __future__ import annotations

import math
import numbers
import re
import warnings
from pathlib import Path

import torch

from torchcal.errors import InputError
from torchcal.io.files import atomic_write, csv_rows
from torchcal.measurements import (_OPTIONAL, CELL_TEMP_C, PAYLOAD_RATIO, ConditionWarning, Measurements,  # noqa: F401
                                   payload_cause, temperature_cause)


class JointLimitWarning(UserWarning):
    """Measured joint angles lie outside the robot's nominal joint limits."""

# ---------------------------------------------------------------------------------------
# Measurement CSV
# ---------------------------------------------------------------------------------------

_INT64_MIN, _INT64_MAX = -(2 ** 63), 2 ** 63 - 1
_POSE_RE = re.compile(r"\s*([+-]?[0-9]+)(?:\.0*)?\s*", re.ASCII)
_QCOL_RE = re.compile(r"q([1-9][0-9]*)", re.ASCII)
_PREV_RE = re.compile(r"prev_q([1-9][0-9]*)", re.ASCII)
_LAYOUT = "pose,q1,...,qN,x,y,z[,point][,rx,ry,rz][,payload_kg][,temp_c][,prev_q1,...,prev_qN]"
_ORIENT = ("rx", "ry", "rz")
LENGTH_UNITS = {"mm": 1.0, "m": 1000.0}  # unit -> mm
ANGLE_UNITS = ("deg", "rad")


def _fail(path, msg: str):
    """Raise InputError with a one-line message (line breaks escaped)."""
    raise InputError(f"{path}: {msg}".replace("\r", "\\r").replace("\n", "\\n"))


def _show(cell: str, width: int = 40) -> str:
    """repr of a cell, cut to `width` characters for a one-line message."""
    cell = cell.strip()
    return repr(cell if len(cell) <= width else cell[:width] + "...")


def _where(line: int, row: int, col: str) -> str:
    return f"line {line} (data row {row}), column {col}"


def _cell_float(path, cell: str, line: int, row: int, col: str, unit: str) -> float:
    try:
        v = float(cell)
        ok = cell.isascii() and "_" not in cell
    except ValueError:
        ok = False
    if not ok:
        got = "an empty cell" if not cell.strip() else _show(cell)
        _fail(path, f"{_where(line, row, col)}: expected a number ({unit}), got {got}")
    if not math.isfinite(v):
        _fail(path, f"{_where(line, row, col)}: expected a finite number ({unit}), got {_show(cell)}")
    return v


def _cell_pose(path, cell: str, line: int, row: int, col: str = "pose") -> int:
    m = _POSE_RE.fullmatch(cell)
    if m is None:
        got = "an empty cell" if not cell.strip() else _show(cell)
        _fail(path, f"{_where(line, row, col)}: expected an integer {col} id, got {got}")
    digits = m.group(1)
    v = int(digits) if len(digits) <= 25 else _INT64_MAX + 1  # no int() of huge digit strings
    if not _INT64_MIN <= v <= _INT64_MAX:
        _fail(path, f"{_where(line, row, col)}: {col} id {digits[:30]} does not fit in a 64-bit integer")
    return v


def _parse_header(path, names: list[str], n_expected: int | None, robot_name: str | None):
    """Map column name -> field index; returns (cols, n_joints)."""
    if len(names) == 1 and any(sep in names[0] for sep in ";\t|"):
        _fail(path, f"line 1: expected comma-separated columns {_LAYOUT}, got {_show(names[0])}")
    numeric = 0
    for name in names:
        try:
            float(name)
            numeric += 1
        except ValueError:
            pass
    if numeric == len(names):
        _fail(path, f"line 1: expected a header line {_LAYOUT}, got what looks like data; "
                    "add the header")
    cols: dict[str, int] = {}
    qs: list[int] = []
    for i, name in enumerate(names):
        if name == "":
            _fail(path, f"line 1, header column {i + 1}: empty column name; expected {_LAYOUT}")
        if name in cols:
            _fail(path, f"line 1, column {_show(name)}: duplicated header column (columns {cols[name] + 1} "
                        f"and {i + 1})")
        m = _QCOL_RE.fullmatch(name)
        if m:
            qs.append(int(m.group(1)))
        elif _PREV_RE.fullmatch(name):
            pass
        elif name not in ("pose", "x", "y", "z", "point") + _ORIENT + _OPTIONAL:
            _fail(path, f"line 1, column {_show(name)} (header column {i + 1}): unknown column; "
                        f"expected {_LAYOUT} (exact lower-case names)")
        cols[name] = i
    for name in ("pose", "x", "y", "z"):
        if name not in cols:
            _fail(path, f"line 1: missing column {name}; expected {_LAYOUT}")
    if n_expected is not None:
        if len(qs) != n_expected:
            who = f"robot {robot_name}" if robot_name else "the given n_joints"
            found = ", ".join(f"q{k}" for k in sorted(qs)) or "none"
            _fail(path, f"line 1: expected {n_expected} joints for {who}, found {len(qs)} "
                        f"q-columns ({found})")
        n = n_expected
    else:
        if not qs:
            _fail(path, f"line 1: missing column q1; expected {_LAYOUT}")
        n = max(qs)
    for k in range(1, n + 1):
        if f"q{k}" not in cols:
            _fail(path, f"line 1: missing column q{k}; expected q1..q{n}")
    for k in qs:
        if k > n:
            _fail(path, f"line 1, column q{k}: unknown column; expected q1..q{n}")
    have = [c for c in _ORIENT if c in cols]
    if have and len(have) != 3:
        miss = ", ".join(c for c in _ORIENT if c not in cols)
        _fail(path, f"line 1: orientation columns come as rx, ry, rz together; missing {miss}")
    prev = [c for c in cols if _PREV_RE.fullmatch(c)]
    if prev:
        for c in prev:
            if int(_PREV_RE.fullmatch(c).group(1)) > n:
                _fail(path, f"line 1, column {c}: unknown column; expected prev_q1..prev_q{n}")
        for k in range(1, n + 1):
            if f"prev_q{k}" not in cols:
                _fail(path, f"line 1: missing column prev_q{k}; the approach columns come as "
                            f"prev_q1..prev_q{n} together")
    return cols, n


def read_measurements(path, n_joints: int | None = None, robot=None,
                      strict_limits: bool = False, length_unit: str = "mm",
                      angle_unit: str = "deg") -> Measurements:
    """Read a measurement CSV (docs/design.md):
    ``pose,q1,...,qN,x,y,z[,point][,rx,ry,rz][,payload_kg][,temp_c]``.

    Units: x, y, z in `length_unit` ('mm' default, or 'm'); q1..qN and rx, ry, rz in
    `angle_unit` ('deg' default, or 'rad'). ``point``: integer reflector id. ``rx, ry,
    rz``: measured orientation, fixed-axis XYZ (R = Rz(rz) Ry(ry) Rx(rx)), all three or none.

    Header: required, exact lower-case names, any column order, surrounding spaces ignored.
    The q-columns must be exactly q1..qN; N must equal `n_joints` and/or `robot.n` when
    given, else it is taken from the header. ``prev_q1..prev_qN`` (all or none, units as
    q): the angles each row was approached from (`Measurements.q_prev`); without them
    q_prev comes from the file's own row order. Blank lines are skipped; a UTF-8 byte order
    mark is accepted. Cells: decimal numbers (finite; `pose` an integer, "7.0" accepted;
    `payload_kg` >= 0); optional columns, when present, need a value in every row.

    Angles outside `robot.limits` (when `robot` is given) raise a `JointLimitWarning`
    naming the rows and joints, since real robots are often measured slightly outside
    nominal limits; ``strict_limits=True`` makes it an InputError instead. Rows of one
    pose id whose joint values differ by more than `REPEAT_TOL` (0.1 deg; 0.1 mm for a
    prismatic joint) raise a `PoseIdWarning` naming the first: they are no repeats of
    one commanded pose (two files joined with restarting ids).

    Every problem raises InputError with one line naming the file, the place
    ("line L (data row R)": L counts file lines from 1 with the header as line 1,
    R counts data rows from 1) and the column, and what was expected.

    Returns: Measurements with q (N, n) in rad (converted from the file's degrees),
    xyz (N, 3) mm, float64 on the CPU.
    """
    path = Path(path)
    if length_unit not in LENGTH_UNITS:
        raise InputError(f"length unit {length_unit!r}: expected one of {', '.join(LENGTH_UNITS)}")
    if angle_unit not in ANGLE_UNITS:
        raise InputError(f"angle unit {angle_unit!r}: expected one of {', '.join(ANGLE_UNITS)}")
    lu, au = length_unit, ("degrees" if angle_unit == "deg" else "rad")
    robot_name = getattr(robot, "name", None)
    if n_joints is not None:
        if isinstance(n_joints, bool) or not isinstance(n_joints, numbers.Integral) or n_joints < 1:
            raise InputError(f"read_measurements: n_joints must be a positive integer, got {n_joints!r}")
        n_joints = int(n_joints)
    if robot is not None:
        if n_joints is not None and n_joints != robot.n:
            raise InputError(f"read_measurements: n_joints={n_joints} disagrees with robot "
                             f"{robot_name} ({robot.n} joints)")
        n_joints = robot.n
    header, cols, n = None, None, None
    rows: list[tuple[int, list[str]]] = []
    for line, fields in csv_rows(path, "measurement file", _LAYOUT):
        if not fields or all(not f.strip() for f in fields) and len(fields) == 1:
            continue  # blank line
        if header is None:
            header = [f.strip() for f in fields]
            cols, n = _parse_header(path, header, n_joints, robot_name)
            continue
        rows.append((line, fields))
    if header is None:
        _fail(path, f"empty file; expected a header line {_LAYOUT} and data rows")
    if not rows:
        _fail(path, "has a header but no data rows")

    width = len(header)
    qi = [cols[f"q{k}"] for k in range(1, n + 1)]
    xi = [cols[c] for c in "xyz"]
    opt = [c for c in _OPTIONAL if c in cols]
    has_point, has_rot, has_prev = "point" in cols, "rx" in cols, "prev_q1" in cols
    pi = [cols[f"prev_q{k}"] for k in range(1, n + 1)] if has_prev else []
    N = len(rows)
    pose = [0] * N
    point = [0] * N
    rxyz = [[0.0] * 3 for _ in range(N)]
    q_deg = [[0.0] * n for _ in range(N)]
    prev_deg = [[0.0] * n for _ in range(N)]
    xyz = [[0.0] * 3 for _ in range(N)]
    extra = {c: [0.0] * N for c in opt}
    for r, (line, fields) in enumerate(rows):
        if len(fields) != width:
            _fail(path, f"line {line} (data row {r + 1}): expected {width} fields as in the "
                        f"header, found {len(fields)}")
        row = r + 1
        pose[r] = _cell_pose(path, fields[cols["pose"]], line, row)
        qr = q_deg[r]
        for j, i in enumerate(qi):
            qr[j] = _cell_float(path, fields[i], line, row, f"q{j + 1}", au)
        for j, i in enumerate(pi):
            prev_deg[r][j] = _cell_float(path, fields[i], line, row, f"prev_q{j + 1}", au)
        pr = xyz[r]
        for j, i in enumerate(xi):
            pr[j] = _cell_float(path, fields[i], line, row, "xyz"[j], lu)
        if has_point:
            point[r] = _cell_pose(path, fields[cols["point"]], line, row, "point")
        if has_rot:
            for j, c in enumerate(_ORIENT):
                rxyz[r][j] = _cell_float(path, fields[cols[c]], line, row, c, au)
        for c in opt:
            v = _cell_float(path, fields[cols[c]], line, row, c, "kg" if c == "payload_kg" else "degC")
            if c == "payload_kg" and v < 0:
                _fail(path, f"{_where(line, row, c)}: payload must be >= 0 kg, got {_show(fields[cols[c]])}")
            extra[c][r] = v

    lines = [line for line, _ in rows]  # the file's line number of each data row
    _check_repeats(path, pose, q_deg, lines, au, lu, robot, length_unit)
    _check_copies(path, q_deg, xyz, point if has_point else None, lines)
    if "temp_c" in extra:
        check_temperatures(path, extra["temp_c"], lines)
    if "payload_kg" in extra:
        _check_payloads(path, extra["payload_kg"], lines, robot)
    to_rad = torch.deg2rad if angle_unit == "deg" else (lambda t: t)

    def joints(values):  # (N, n) rad; a prismatic joint's column is a length: mm inside
        t = torch.tensor(values, dtype=torch.float64).reshape(N, n)
        if robot is None:
            return to_rad(t)
        return torch.where(robot.prismatic.cpu(), t * LENGTH_UNITS[length_unit], to_rad(t))
    q = joints(q_deg)
    m = Measurements(
        pose=torch.tensor(pose, dtype=torch.int64),
        q=q,
        xyz=torch.tensor(xyz, dtype=torch.float64).reshape(N, 3) * LENGTH_UNITS[length_unit],
        point=torch.tensor(point, dtype=torch.int64) if has_point else None,
        rxyz=to_rad(torch.tensor(rxyz, dtype=torch.float64).reshape(N, 3)) if has_rot else None,
        payload_kg=torch.tensor(extra["payload_kg"], dtype=torch.float64) if "payload_kg" in extra else None,
        temp_c=torch.tensor(extra["temp_c"], dtype=torch.float64) if "temp_c" in extra else None,
        source=str(path),
        q_prev=joints(prev_deg) if has_prev else None,
    )
    if robot is not None:
        _check_limits(path, m, robot, lines, strict_limits)
    return m


def as_measurements(measurements, robot, length_unit: str = "mm", angle_unit: str = "deg") -> Measurements:
    """`Measurements` as they are, or the measurement CSV at a path read for `robot` in
    `length_unit` / `angle_unit` (`read_measurements`); InputError for anything else."""
    if isinstance(measurements, Measurements):
        if measurements.source is None:  # built in memory: the conditions checked as a file's are on reading
            check_conditions_of(measurements, robot)
        return measurements
    if isinstance(measurements, (str, Path)):
        return read_measurements(measurements, robot=robot, length_unit=length_unit, angle_unit=angle_unit)
    raise InputError(f"measurements: expected Measurements or a CSV path, got {type(measurements).__name__}")


#: rows of one pose id repeat one commanded pose: their joint values may differ by at most
#: this, in degrees (mm for a prismatic joint), e.g. measured rather than commanded angles
REPEAT_TOL = 0.1


class PoseIdWarning(UserWarning):
    """Rows of one pose id at different joint values (`read_measurements`)."""


class CopiedRowWarning(UserWarning):
    """Rows that copy an earlier row's joint values and x, y, z exactly (`read_measurements`)."""


#: the warnings of reading a measurement CSV, which the command line writes as one line each
FILE_WARNINGS = (JointLimitWarning, PoseIdWarning, CopiedRowWarning, ConditionWarning)

def check_conditions_of(m: Measurements, robot) -> None:
    """The checks a file's temp_c / payload_kg columns get (`check_temperatures`,
    `_check_payloads`: kelvin, Fahrenheit, grams, pounds) for measurements built in memory
    (no source file), naming them "measurements" and their rows 1..N."""
    where = m.source or "measurements"
    rows = list(range(1, len(m) + 1))
    if m.temp_c is not None:
        check_temperatures(where, m.temp_c.tolist(), rows, at="row")
    if m.payload_kg is not None:
        _check_payloads(where, m.payload_kg.tolist(), rows, robot, at="row")


def _check_payloads(path, payloads: list[float], lines: list[int], robot, at: str = "line") -> None:
    """Warn (ConditionWarning, one line) when payload_kg exceeds PAYLOAD_RATIO times the
    rated payload of `robot` (its robot file's payload_kg; not judged when it has none):
    grams or pounds read as kg, which scale every load-driven effect (joint_compliance)."""
    rated = float(getattr(robot, "payload_kg", 0.0) or 0.0) if robot is not None else 0.0
    if rated <= 0:
        return
    out = [r for r, v in enumerate(payloads) if v > PAYLOAD_RATIO * rated]
    if not out:
        return
    top = max(payloads)
    cause = payload_cause(top, rated)
    r = out[0]
    warnings.warn(f"{path}: column payload_kg: {len(out)} of {len(payloads)} row(s) above {PAYLOAD_RATIO:g} times "
                  f"the rated payload of {robot.name} ({rated:g} kg; first: {at} {lines[r]}, {payloads[r]:g}; up to "
                  f"{top:g}): {cause} payload_kg is in kg", ConditionWarning, stacklevel=3)


def check_temperatures(path, temps: list[float], lines: list[int], at: str = "line") -> None:
    """Warn (ConditionWarning, one line) when temp_c values (of a measurement or targets
    file `path`, `lines` their line numbers) lie outside CELL_TEMP_C: a
    median of 250..350 looks like kelvin, one of 60..130 like degrees Fahrenheit.
    thermal_expansion fits each link's growth per degree from 20 degC: in another scale its
    coefficients come out wrong (a factor 1.8 in Fahrenheit) and the reference offset
    moves into the link lengths."""
    lo, hi = CELL_TEMP_C
    out = [r for r, v in enumerate(temps) if not lo <= v <= hi]
    if not out:
        return
    med = sorted(temps)[len(temps) // 2]
    cause = temperature_cause(med)
    r = out[0]
    warnings.warn(f"{path}: column temp_c: {len(out)} of {len(temps)} row(s) outside {lo:g}..{hi:g} degC (first: "
                  f"{at} {lines[r]}, {temps[r]:g}; median {med:g}): {cause}; temp_c is in degrees Celsius",
                  ConditionWarning, stacklevel=3)


FROZEN_ROWS = 3  # rows repeating an earlier row's x, y, z at other joint values that are named


def _check_copies(path, q: list[list[float]], xyz: list[list[float]], point, lines: list[int]) -> None:
    """Warn (CopiedRowWarning, one line) when rows repeat an earlier row's joint values and
    measured x, y, z exactly, to every written digit (and its point id): a repeated
    measurement differs by the instrument's noise (hundredths of a mm), a copy does not. A
    block pasted twice, a file joined with itself: the copies are taken as repeats (folds,
    a noise floor of 0 from them) and double the weight of their rows. One more line when
    at least FROZEN_ROWS rows repeat an earlier row's x, y, z exactly at other joint values
    (beyond REPEAT_TOL: not a repeat of its pose): a frozen reading (the instrument lost
    the reflector) or a cell filled down in a spreadsheet."""
    seen: dict[tuple, int] = {}
    at: dict[tuple, int] = {}  # x, y, z (and point) -> first row
    copies, frozen = [], []  # (row, the earlier row it copies / whose x, y, z it repeats at other joint values)
    for r in range(len(q)):
        key = (*q[r], *xyz[r], point[r] if point is not None else 0)
        f = seen.setdefault(key, r)
        if f != r:
            copies.append((r, f))
            continue
        g = at.setdefault((*xyz[r], point[r] if point is not None else 0), r)
        if g != r and max(abs(a - b) for a, b in zip(q[r], q[g])) > REPEAT_TOL:  # not a repeat of that pose
            frozen.append((r, g))
    if copies:
        r, f = copies[0]
        warnings.warn(f"{path}: {len(copies)} of {len(q)} row(s) copy an earlier row's joint values and x,y,z to "
                      f"every digit (first: line {lines[r]} = line {lines[f]}); repeated measurements differ by the "
                      f"instrument's noise: a block pasted twice? copies count as repeats and double their weight",
                      CopiedRowWarning, stacklevel=3)
    if len(frozen) >= FROZEN_ROWS:
        r, f = frozen[0]
        warnings.warn(f"{path}: {len(frozen)} of {len(q)} row(s) repeat an earlier row's x,y,z to every digit at "
                      f"other joint values (first: line {lines[r]}, the x,y,z of line {lines[f]}): the instrument's "
                      "reading froze (a lost reflector) or a value was filled down? those rows measure nothing",
                      CopiedRowWarning, stacklevel=3)


def _check_repeats(path, pose: list[int], q: list[list[float]], lines: list[int], au: str, lu: str,
                   robot, length_unit: str) -> None:
    """Warn (PoseIdWarning, one line) when rows' joint values q (file units) differ by more
    than REPEAT_TOL from the first row of their pose id (two sessions joined with
    restarting ids, a mistyped id): such rows are no repeats of one pose, yet folds, split
    and the noise floor from repeats take them as one."""
    n = len(q[0])
    slide = [False] * n if robot is None else [bool(v) for v in robot.prismatic.cpu().tolist()]
    tol = [REPEAT_TOL / LENGTH_UNITS[length_unit] if sl else
           (REPEAT_TOL if au == "degrees" else math.radians(REPEAT_TOL)) for sl in slide]
    first: dict[int, int] = {}
    bad = []  # (row, first row of its id, joint)
    for r, p in enumerate(pose):
        f = first.setdefault(p, r)
        j = next((j for j in range(n) if abs(q[r][j] - q[f][j]) > tol[j]), None)
        if j is not None:
            bad.append((r, f, j))
    if not bad:
        return
    r, f, j = bad[0]
    unit = lu if slide[j] else au
    warnings.warn(f"{path}: {len(bad)} row(s) repeat a pose id at other joint values (first: line {lines[r]}, "
                  f"pose id {pose[r]}, q{j + 1}={q[r][j]:.6g} {unit}, on line {lines[f]} {q[f][j]:.6g}); "
                  f"rows of one pose id are taken as repeats of one commanded pose (folds, split, noise "
                  f"floor): give each pose its own id (two files joined?)", PoseIdWarning, stacklevel=3)


def _check_limits(path, m: Measurements, robot, lines: list[int], strict: bool) -> None:
    rb = robot.to("cpu", torch.float64)
    lim = rb.q_to_user(rb.limits.detach().T).T  # (n, 2) deg (mm for a prismatic joint)
    qd = rb.q_to_user(m.q)  # (N, n) deg / mm, as rounded from the file's values
    units = rb.joint_units()
    # half a micro-degree of slack so a value written at the limit itself is never flagged
    eps = 5e-7
    out = (qd < lim[:, 0] - eps) | (qd > lim[:, 1] + eps)  # (N, n)
    if not out.any():
        return
    bad = out.nonzero().tolist()
    shown = [f"line {lines[r]} q{j + 1}={qd[r, j].item():.6g} {units[j]} "
             f"(limits {lim[j, 0].item():.6g}..{lim[j, 1].item():.6g})" for r, j in bad[:5]]
    more = f"; and {len(bad) - 5} more out-of-limit values" if len(bad) > 5 else ""
    rows = int(out.any(1).sum())
    msg = (f"{path}: {rows} row(s) outside the joint limits of robot {robot.name}: "
           f"{'; '.join(shown)}{more}")
    if strict:
        raise InputError(msg)
    warnings.warn(msg, JointLimitWarning, stacklevel=3)


def _fmt(v: float) -> str:
    """Shortest text that reads back to exactly the same float64."""
    return repr(float(v))


def _fmt_deg(v: float) -> str:
    """Joint angle in degrees to 15 significant digits (1e-15 relative).

    Degrees cannot carry the exact float64 of an angle in rad (deg -> rad -> deg moves
    the last bit or two), so they are written to 15 digits, which a read + write turns
    back into the same text: re-writing a file read from disk changes nothing.
    """
    text = "%.15g" % v
    return text if ("." in text or "e" in text or "n" in text) else text + ".0"


def format_measurements(m: Measurements, robot=None, approach: bool = False) -> str:
    """The CSV text of `m`: joint angles in degrees, positions in mm.

    approach: also write ``prev_q1..prev_qN`` (`m.q_prev`, units as q), so that the rows
    read back with the approach directions they had in `m` (a subset of a session).
    Deterministic: header in the canonical order
    ``pose,q1..qN,x,y,z[,point][,rx,ry,rz][,payload_kg][,temp_c][,prev_q1..prev_qN]``,
    xyz / payload_kg / temp_c in Python's shortest exact repr (they round-trip bit for
    bit), joint angles in degrees to 15 significant digits (they round-trip to ~1e-15
    relative, and writing what was read reproduces the text).
    """
    n = m.n
    opt = [c for c in _OPTIONAL if getattr(m, c) is not None]
    pt = [] if m.point is None else ["point"]
    rot = [] if m.rxyz is None else list(_ORIENT)
    prev = [f"prev_q{k}" for k in range(1, n + 1)] if approach else []
    header = ["pose", *(f"q{k}" for k in range(1, n + 1)), "x", "y", "z", *pt, *rot, *opt, *prev]
    points = None if m.point is None else m.point.cpu().tolist()
    rdeg = None if m.rxyz is None else torch.rad2deg(m.rxyz.detach().cpu().to(torch.float64)).T.tolist()
    pose = m.pose.cpu().tolist()

    def user(t):  # (N, n) rad -> n lists of N deg / mm
        t = t.detach().cpu().to(torch.float64)
        return (torch.rad2deg(t) if robot is None else robot.to("cpu", torch.float64).q_to_user(t)).T.tolist()
    qd = user(m.q)
    pd = user(m.q_prev) if approach else []
    xyz = m.xyz.detach().cpu().to(torch.float64).T.tolist()  # 3 lists of N mm
    extra = [getattr(m, c).detach().cpu().to(torch.float64).tolist() for c in opt]
    lines = [",".join(header)]
    for r in range(len(m)):
        cells = [str(int(pose[r]))]
        cells += [_fmt_deg(c[r]) for c in qd]
        cells += [_fmt(c[r]) for c in xyz]
        if points is not None:
            cells.append(str(int(points[r])))
        if rdeg is not None:
            cells += [_fmt_deg(c[r]) for c in rdeg]
        cells += [_fmt(c[r]) for c in extra]
        cells += [_fmt_deg(c[r]) for c in pd]
        lines.append(",".join(cells))
    return "\n".join(lines) + "\n"


def write_measurements(path, m: Measurements, force: bool = False, inputs=(), robot=None,
                       approach: bool = False) -> Path:
    """Atomically write `m` as a measurement CSV (joint angles in degrees, mm; with
    `robot`, a prismatic joint's column in mm; with `approach`, the ``prev_q`` columns).

    Refuses to replace an existing file unless `force`, and never writes over `m.source`
    or any of `inputs` (docs/design.md: nothing written over an input file).
    """
    if not isinstance(m, Measurements):
        raise InputError(f"write_measurements: expected Measurements, got {type(m).__name__}")
    if len(m) == 0:
        raise InputError(f"{path}: refusing to write a measurement file with no rows")
    return atomic_write(path, format_measurements(m, robot, approach), force=force, inputs=(m.source, *inputs))

