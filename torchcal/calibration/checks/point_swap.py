"""Point ids exchanged at some poses of a training file: `swapped_poses`, `warn_swapped_points`.

With several reflectors per pose (the ``point`` column, one tool offset each), a file whose
ids were typed the other way round at a few poses (the operator moved reflector 1 into
nest 2) is fitted as given: the rows pull the tool offsets and the geometry. Reflectors
far apart (100 mm) are refused before the fit as gross outliers (`check_robot_data`, which
then names the exchange as a likely cause); close ones passed in silence (UR5e, 60 poses,
reflectors 2 mm apart, ids exchanged at 1, 3 and 6 poses: fit rms 0.25, 0.43, 0.60 mm
against 0.017 mm honest, exit 0; 10 mm apart at 3 and 6 poses: refused as "two measuring
frames in one file", the wrong cause).

The check, after the fit: at each pose, each pair of rows with two different ids (a, b) is
predicted with the fitted model as measured at the other's reflector. The pose is named
when for some pair the exchanged ids leave at most 1 / SWAP_GAIN (3) of the pair's rms as
given, and that rms lies beyond FAR_FACTOR (3) times the median row error of the fit. On
honest data the ids as given fit to the noise and the exchanged ones miss by the
reflectors' separation, so neither holds; where the separation is within a few times the
noise the exchange changes nothing the fit could see, and is not named either.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections import defaultdict

import torch

from torchcal.calibration.checks.verdict import MismatchWarning, listed

SWAP_GAIN = 3.0  # the exchanged ids must bring a pair's rms down this many times to be named
FAR_FACTOR = 3.0  # and the pair's rms as given must lie beyond this many median row errors


def swapped_poses(err: dict, point: torch.Tensor, pose: torch.Tensor) -> list[int]:
    """The pose ids at which two rows fit each other's reflector (module doc), in order.

    err: {point id: (N, 3) mm error of every row as if measured at that point}; point (N,)
    int64 the ids as given; pose (N,) int64 pose ids. Pure: no fit, no model."""
    rows = defaultdict(list)  # pose id -> its rows
    for i, p in enumerate(pose.tolist()):
        rows[p].append(i)
    ids = point.tolist()
    own = torch.stack([err[k][i] for i, k in enumerate(ids)]).norm(dim=-1)  # (N,) as given
    far = FAR_FACTOR * float(own.median())
    named = []
    for p, rs in rows.items():
        for x, i in enumerate(rs):
            if any(ids[i] != ids[j] and _fit_each_other(err, own, ids, i, j, far) for j in rs[x + 1:]):
                named.append(p)
                break
    return named


def _fit_each_other(err: dict, own: torch.Tensor, ids: list, i: int, j: int, far: float) -> bool:
    """Rows i and j (different ids) fit the exchanged ids SWAP_GAIN times better than their
    own, whose pair rms lies beyond `far` mm."""
    given = float(own[i] ** 2 + own[j] ** 2) / 2
    exchanged = float(err[ids[j]][i].square().sum() + err[ids[i]][j].square().sum()) / 2
    return given > far ** 2 and exchanged * SWAP_GAIN ** 2 <= given


def _errors(predict, robot, points, m) -> dict:
    """{point id: (N, 3) mm error of every row of `m` as if measured at that point} of a
    model's `predict(ctx)`."""
    from torchcal.effects import context_of

    err = {}
    for k in points:
        as_k = dataclasses.replace(m, point=torch.full_like(m.point, k))
        err[k] = (m.xyz - predict(context_of(robot, as_k))).detach().to("cpu", torch.float64)
    return err


def _checked_ids(model, m) -> list:
    """The model's point ids where the data carry two or more, all of them the model's; else []."""
    points = list(getattr(model, "points", None) or [])
    if m.point is None or len(points) < 2:
        return []
    ids = set(m.point.tolist())
    return points if len(ids) >= 2 and ids <= set(points) else []


def message(m, named: list[int]) -> str:
    """The one line naming the poses at which point ids look exchanged."""
    return (f"{m.source or 'data'}: at {len(named)} pose(s) (pose ids {listed(named)}) two rows fit each other's "
            f"reflector at least {SWAP_GAIN:g} times better than their own: the point ids exchanged there?")


def swapped_before_fit(model, m) -> list[int]:
    """`swapped_poses` of the nominal `model` (a `CalibrationModel` with a tool offset per
    point) in its best measuring frame: base_frame and the tool offsets fitted to `m` with
    a Huber loss (the exchanged rows do not pull them), the rest at nominal. The refusals of
    the gross-mismatch check (gross outliers, two sessions) ask it first: reflectors
    tens of mm apart exchanged at a few poses look like either."""
    from torchcal.calibration.fit import fit
    from torchcal.calibration.registration import frame_slices, register_frame, with_frame
    from torchcal.effects import context_of
    from torchcal.errors import InputError

    points = _checked_ids(model, m)
    if not points:
        return []
    model = with_frame(model, model.zeros(), tool=True)[0]
    ctx = context_of(model.robot, m)
    free = torch.zeros(model.n_params, dtype=torch.bool)
    for sl in frame_slices(model, True):
        free[sl] = True
    try:
        start, _ = register_frame(model, ctx, m.xyz)
        res = fit(model, ctx, m.xyz, theta0=start, free=free, register=False, robust="huber", max_length_mm=None,
                  max_angle_deg=None)
    except InputError:
        return []
    return swapped_poses(_errors(res.predict, res.model.robot, points, m), m.point.cpu(), m.pose.cpu())


def warn_swapped_points(res, m, stacklevel: int = 2) -> list[int]:
    """One `MismatchWarning` naming the poses of `m` (`Measurements`) at which the fitted
    model `res` (a `FitResult` with per-point tool offsets) finds two rows' point ids
    exchanged (`swapped_poses`); returns those pose ids. Data with fewer than two ids, or a
    model without them, are not checked."""
    points = _checked_ids(res.model, m)
    if not points:
        return []
    named = swapped_poses(_errors(res.predict, res.model.robot, points, m), m.point.cpu(), m.pose.cpu())
    if named:
        warnings.warn(message(m, named) + " The fit took them as given; correct the point column and fit again",
                      MismatchWarning, stacklevel=stacklevel + 1)
    return named
