"""Two measuring frames in one file, and rows repeated from another session.

Two sessions joined in one file with the instrument moved between them
(`joined_sessions`: at restarting pose ids), or an instrument moved or a reflector changed
midway through one session (`changed_midway`), each part fitting in a frame and with a tool
offset of its own while the whole does not; also when one frame and tool fit within
GROSS_MM (`moved_within_gross`: a move of a few mm or a fraction of a degree). Rows of one
session repeated, to the last bit, in another (`shared_rows`): no second session. A file
whose rows were approached from rows of another (`same_session`, by its prev_q columns):
the two are parts of one session split in two.
"""

from __future__ import annotations

import warnings

import torch

from torchcal.calibration.checks.frame_fit import registered
from torchcal.calibration.checks.model_data import check_points
from torchcal.calibration.checks.verdict import Mismatch, rms_of
from torchcal.errors import InputError

SESSION_FLOOR_MM = 2.0  # one frame's rms below this: no search for a moved instrument within GROSS_MM
SESSION_RATIO = 3.0  # each part's own frame must come this many times closer than one frame through both
JOINS = 3  # at most this many pose-id restarts are tried as the joint between two sessions
SPLIT_SHARE = 0.25  # share of the other file's rows approached from rows of the data: one session split in two


def moved_within_gross(model, m, quick_mm: float, pred: torch.Tensor | None = None) -> Mismatch | None:
    """Two measuring frames in one file that one frame and tool offset fit within GROSS_MM
    (an instrument moved by a few mm or a fraction of a degree between two sessions, or
    midway through one): None, or a 'mismatch' naming the parts. Judged when the model's
    rms (`quick_mm`: as it is, or after the closed-form frame when it has base_frame), then
    that of the registered points `pred` (N, 3) mm (`registered`'s, computed when None),
    exceed SESSION_FLOOR_MM: a part fits when its own frame and tool offset leave at most
    1 / SESSION_RATIO of the one-frame rms (`joined_sessions` at restarting pose ids, else
    `changed_midway`). Single sessions of the simulated titan and UR10 series B and D come
    1.0-1.2 times closer at their best cut, a 0.5 deg move 12.6 times. Every fit here adds a
    frame and tool offset of its own, so the figures do not depend on the frame the data
    are in: a model without base_frame (data in the robot's base frame) is judged alike,
    where two frames are a base that moved (the robot mounted elsewhere) between sessions."""
    import dataclasses

    if quick_mm <= SESSION_FLOOR_MM:
        return None
    if pred is None:
        pred = registered(model, m)
    reg = rms_of((pred - m.xyz).norm(dim=-1))
    if reg <= SESSION_FLOOR_MM:
        return None
    bound = reg / SESSION_RATIO

    def fits(mm):
        return rms_of((registered(model, mm) - mm.xyz).norm(dim=-1)) <= bound

    what, name = m.source or "data", model.robot.name
    join = joined_sessions(m, fits)
    cut = join if join is not None else changed_midway(m, fits)
    if cut is None:
        return None
    moved = "the instrument" if "base_frame" in [e.name for e in model.effects] else \
        "the robot's base (the data are in its frame: the model has no base_frame)"
    how = (f"(pose ids restart at {int(m.pose[cut])}): two sessions joined, {moved} moved between them; "
           "calibrate on one, or register each (torchcal register)" if join is not None else
           f": {moved} moved or the reflector was changed midway, by data row {cut + 1} (pose id "
           f"{int(m.pose[cut])}) at the latest; calibrate on one part and register the other (torchcal register)")
    parts = [m.subset(torch.arange(a, b)) for a, b in ((0, cut), (cut, len(m)))]
    each = " and ".join(f"{rms_of((registered(model, p) - p.xyz).norm(dim=-1)):.4g}" for p in parts)
    msg = (f"{what}: two measuring frames in one file: one frame and tool offset for {name} leave rms {reg:.4g} mm, "
           f"but rows 1..{cut} and {cut + 1}..{len(m)} (data rows) leave {each} mm in a frame and with a tool "
           f"offset of their own{'' if join is None else ' '}{how}")
    return dataclasses.replace(check_points(pred, m.xyz, None, what), rms_mm=reg,
                               registered_rms_mm=reg, verdict="mismatch", message=msg)


def joined_sessions(m, fits) -> int | None:
    """The 0-based row r where the pose ids restart (step down) such that rows [0, r) and
    [r, N) each `fits` (a predicate on `Measurements`, each in a frame of its own): two
    sessions joined in one file, measured in different instrument frames. Tried at the
    first JOINS restarts only when the ids step down at most JOINS times (a session with
    repeats cycles through its poses in random order: no joint to find), each part with at
    least 6 rows; None otherwise."""
    pose = m.pose.detach().cpu()
    down = ((pose[1:] < pose[:-1]).nonzero().flatten() + 1).tolist()
    if not down or len(down) > JOINS:
        return None
    for r in down:
        if r < 6 or len(m) - r < 6:
            continue
        parts = [m.subset(torch.arange(a, b)) for a, b in ((0, r), (r, len(m)))]
        try:
            if all(fits(p) for p in parts):
                return r
        except InputError:
            continue
    return None


def changed_midway(m, fits, least: int = 6) -> int | None:
    """The 0-based row r such that rows [0, r) and [r, N) each `fits` (a predicate on
    `Measurements`, each part in a measuring frame and with a tool offset of its own) while
    the whole file does not (the caller's finding): the instrument moved, or the reflector
    was changed, in the middle of one session without a new point id or restarting pose ids.
    r is the end of the longest first part that fits, found by bisection (about log2 N
    fits; a change smaller than GROSS_MM can leave a few rows after it in the first part);
    None when the first or last `least` rows do not fit on their own, or the rest after r
    does not fit."""
    n = len(m)
    if n < 2 * least:
        return None

    def ok(a, b):
        try:
            return fits(m.subset(torch.arange(a, b)))
        except InputError:
            return False

    if not ok(0, least) or not ok(n - least, n):
        return None
    lo, hi = least, n  # [0, lo) fits, [0, hi) does not (the whole file was refused)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if ok(0, mid) else (lo, mid)
    return lo if n - lo >= least and ok(lo, n) else None


def shared_rows(a, b) -> list[int]:
    """0-based rows of the measurements `b` whose joint values and x, y, z equal, to the
    last bit, those of a row of `a` (the same measurement, copied: two sessions never
    repeat a reading exactly)."""
    seen = {tuple(r) for r in torch.cat([a.q, a.xyz], dim=1).detach().cpu().tolist()}
    return [i for i, r in enumerate(torch.cat([b.q, b.xyz], dim=1).detach().cpu().tolist()) if tuple(r) in seen]


class SameSessionWarning(UserWarning):
    """The transfer session looks like a split of the session searched, not another session."""


def same_session(data, other, stacklevel: int = 1) -> float:
    """One `SameSessionWarning` (at `stacklevel`, counted from the caller) when at least
    SPLIT_SHARE of the rows of `other` (`Measurements`, as `data`) were approached (their
    ``prev_q`` columns, which `torchcal split` writes from the whole session) from joint
    values that are, to the last bit, rows of `data` but no row of `other`: the two files
    are parts of one session (the validation part of a split), whose terms the check would
    confirm. A file without prev_q (a session file as measured) is not judged. Returns that
    share."""
    if other.q_prev is None or len(other) == 0:
        return 0.0
    key = lambda t: {tuple(r) for r in t.detach().cpu().tolist()}  # noqa: E731
    mine, theirs = key(data.q), key(other.q)
    prev = other.q_prev.detach().cpu().tolist()
    hits = sum(1 for r in prev if tuple(r) in mine and tuple(r) not in theirs)
    share = hits / len(other)
    if share >= SPLIT_SHARE:
        warnings.warn(f"{other.source or 'transfer'}: {hits} of {len(other)} rows were approached from joint values "
                      f"that are rows of {data.source or 'the data'} (prev_q columns): the two are parts of one "
                      "session (a split of it), and a transfer check on them confirms the session's own terms; "
                      "give the measurements of another session (another set-up or day)", SameSessionWarning,
                      stacklevel=stacklevel + 1)
    return share
