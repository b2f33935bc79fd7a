"""Joint columns mixed up and positions misaligned with the joint values: data refused as
another robot that are this robot's with two joint columns swapped, one in radians read
as degrees (a slide's in metres read as mm), one holding its angle against the base (a
coupled J2/J3), one negated or shifted by a zero position (`column_mistakes`, `column_hint`), or with x, y, z a few rows off the joint values
(`row_lag`).
"""

from __future__ import annotations

import math

import torch

from torchcal.errors import InputError
from torchcal.robots.checks import PARALLEL_DEG

HINT_ROWS = 60  # rows (evenly spread over the file) that judge a one-column mistake
TWIN_REL = 1e-6  # mistakes whose scores agree this closely give the same points: both are named
LAGS = (1, -1, 2, -2)  # row offsets between the joint values and the positions that are tried


def column_mistakes(m, robot):
    """Yield (phrase, Measurements) for each one-column mistake in the joint values of `m`
    (q (N, n) rad / mm): two adjacent q columns swapped; the columns rotated by one, an
    external axis (a track) logged after the arm's joints where the robot has it first, or
    before them where it has it last; one revolute column in radians read as degrees, one
    prismatic column in metres read as mm; one column of a joint whose axis is parallel to
    the one before holding the sum or difference of the two (its angle against the base:
    Fanuc's J2/J3); one column negated (another sign convention); one revolute column
    shifted by +-90 or 180 deg (another zero position, e.g. a controller's against the
    MD-H table's). Columns moved keep the file's values (degrees or mm, as written). The
    rows' predecessors follow the changed q (their row order)."""
    import dataclasses

    def changed(q):
        return dataclasses.replace(m, q=q, q_prev=None)

    n = robot.n
    for j in range(n - 1):
        order = list(range(n))
        order[j], order[j + 1] = j + 1, j
        yield f"columns q{j + 1} and q{j + 2} swapped", changed(reordered(m.q, robot.prismatic, order))
    if n >= 3:
        yield (f"columns rotated: q{n} holding joint 1 and q1..q{n - 1} joints 2..{n} (an external axis, e.g. a "
               f"track, logged after the arm's joints, as KUKA logs E1 after A6)"), \
            changed(reordered(m.q, robot.prismatic, [n - 1, *range(n - 1)]))
        yield (f"columns rotated: q1 holding joint {n} and q2..q{n} joints 1..{n - 1} (an external axis logged "
               f"before the arm's joints)"), changed(reordered(m.q, robot.prismatic, [*range(1, n), 0]))
    rev = (~robot.prismatic.cpu()).tolist()
    for j in range(n):
        if rev[j]:
            q = m.q.clone()
            q[:, j] = q[:, j] * (180.0 / math.pi)
            yield f"column q{j + 1} in radians (read as degrees)", changed(q)
        else:
            q = m.q.clone()
            q[:, j] = q[:, j] * 1000.0
            yield f"column q{j + 1} (prismatic) in metres (read as mm)", changed(q)
    for j in range(n):
        q = m.q.clone()
        q[:, j] = -q[:, j]
        yield f"column q{j + 1} negated (another sign convention)", changed(q)
    alpha = robot.table[:, 3].detach().cpu()
    for j in range(1, n):  # q(j+1) against the base, not link j: parallel revolute axes (a Fanuc's J2/J3)
        if rev[j - 1] and rev[j] and abs(math.sin(float(alpha[j - 1]))) < math.sin(math.radians(PARALLEL_DEG)):
            for s, op in ((1, "+"), (-1, "-")):
                q = m.q.clone()
                q[:, j] = q[:, j] - s * q[:, j - 1]
                yield (f"column q{j + 1} holding q{j + 1} {op} q{j} (joint {j + 1}'s angle against the base, not "
                       f"link {j}: a controller's coupled J{j}/J{j + 1} convention, e.g. Fanuc's)"), changed(q)
    for j in range(n):
        if rev[j]:
            for deg in (90, -90, 180):
                q = m.q.clone()
                q[:, j] = q[:, j] + math.radians(deg)
                yield f"column q{j + 1} shifted by {deg:+d} deg (another zero position)", changed(q)


def reordered(q, prismatic, order) -> "torch.Tensor":
    """Joint values (N, n) rad / mm with column k taken from column order[k] of q (N, n)
    as the file wrote it: degrees where q's column was read as revolute, mm where
    prismatic, then read for column k's type (a track's mm moved to a revolute column are
    degrees there)."""
    pris = prismatic.detach().cpu().bool().tolist()
    file = torch.stack([q[:, k] if pris[k] else torch.rad2deg(q[:, k]) for k in range(q.shape[1])], -1)
    moved = file[:, list(order)]
    return torch.stack([moved[:, k] if pris[k] else torch.deg2rad(moved[:, k]) for k in range(q.shape[1])], -1)


def column_hint(m, robot, fits, score=None, tries: int = 2) -> str | None:
    """The first `column_mistakes` phrase whose corrected data `fits` (a predicate on
    `Measurements`) accepts, else None: data refused as another robot that are this robot's
    with one joint column mixed up. Judged on HINT_ROWS rows spread over the file. With
    `score` (a cheap float of `Measurements`, lower is closer) only the `tries` best-scored
    mistakes go to `fits` (an expensive predicate: the refusal stays quick), and the
    mistakes of the same score (within TWIN_REL) that fit too are named with it, "A or B":
    on a UR arm q1 negated and q2 shifted by 180 deg give the same points to 9 digits, and
    naming one of them named the wrong column half the time."""
    if len(m) > HINT_ROWS:
        m = m.subset(torch.linspace(0, len(m) - 1, HINT_ROWS).round().long())
    cands = [(None, p, f) for p, f in column_mistakes(m, robot)]
    if score is not None:
        cands = sorted(((score(f), p, f) for _, p, f in cands), key=lambda c: c[0])[:tries]
    for i, (s, phrase, fixed) in enumerate(cands):
        if _fits(fits, fixed):
            twins = [p for s2, p, f in cands[i + 1:]
                     if s is not None and s2 <= s * (1 + TWIN_REL) + 1e-9 and _fits(fits, f)]
            return " or ".join([phrase, *twins]) + (f", which give the same positions on {robot.name}" if twins
                                                     else "")
    return None


def _fits(fits, mm) -> bool:
    """fits(mm), False where it raises InputError."""
    try:
        return bool(fits(mm))
    except InputError:
        return False


def row_lag(m, fits) -> int | None:
    """The first offset k of LAGS such that the rows with q of row i and x, y, z (and
    rx, ry, rz) of row i + k `fits` (a predicate on `Measurements`), else None: positions
    misaligned with the joint values by k rows over the whole file (a joined log with a
    row more at its start). Judged on up to HINT_ROWS rows spread over the shifted rows."""
    import dataclasses

    n = len(m)
    for k in LAGS:
        if n - abs(k) < 3 * max(1, abs(k)) or n - abs(k) < 6:
            continue
        rows = torch.arange(max(0, -k), n - max(0, k))
        if rows.numel() > HINT_ROWS:
            rows = rows[torch.linspace(0, rows.numel() - 1, HINT_ROWS).round().long()]
        sub = m.subset(rows)
        moved = dataclasses.replace(sub, xyz=m.xyz[rows + k],
                                    rxyz=None if m.rxyz is None else m.rxyz[rows + k])
        try:
            if fits(moved):
                return k
        except InputError:
            continue
    return None


def lag_words(lag: int) -> str:
    """The end of the line naming a `row_lag` (rows whose positions are `lag` rows off)."""
    return (f"each row's x, y, z taken from {abs(lag)} row(s) {'further down' if lag > 0 else 'further up'}: the "
            "positions are misaligned with the joint values (two logs joined with a row more in one); check the rows")
