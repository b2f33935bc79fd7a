"""Measurements against a fitted model (`check_measurements`: evaluate, register, export,
diagnose) and the point ids it was fitted on (`point_ids_differ`); rows far beyond its
training rms that a cause within the gross bound explains (evaluate, register): a tool
offset of their own (`moved_tool`: another reflector or nest), point ids read otherwise
(`swapped_points`), a measuring frame of their own (`moved_frame`: the instrument moved).

With the model's errors d (N,) mm (`check_points`):

- ``rms``: RMS of d as it is; ``registered_rms``: RMS after the best rigid motion of the
  model's points onto the measured ones (Kabsch, `torchcal.calibration.registration`);
  ``spread_ratio``: measured / modelled spread (RMS distance to the centroid; a rigid
  motion leaves it unchanged, and ``|s_measured - s_model| <= registered_rms``).
- the plausible bound B (`torchcal.calibration.checks.verdict.bound_mm`).
- ``rms <= B``: consistent. ``rms > B`` but ``registered_rms <= B``: a rigid motion
  explains the data, i.e. the measuring frame moved (re-register: ``torchcal register``).
  Both beyond B: another robot, or units (the spread ratio says which is more likely: a
  factor near 1000 or 57.3 is a unit, metres or radians), unless one joint column mixed
  up or positions a few rows off (`torchcal.calibration.checks.columns`), or the rows
  beyond the calibrated joint range alone, explain it.
"""

from __future__ import annotations

import math

import torch

from torchcal.calibration.checks.columns import column_hint, lag_words, row_lag
from torchcal.calibration.checks.ranges import range_warning
from torchcal.calibration.checks.units import spread_mm, units_hint
from torchcal.calibration.checks.verdict import Mismatch, MismatchWarning, bound_mm, listed, rms_of


def check_points(predicted: torch.Tensor, measured: torch.Tensor, training_rms_mm: float | None = None,
                 what: str = "data", model_name: str = "the model") -> Mismatch:
    """Judge measured points (N, 3) mm against a model's predicted points (N, 3) mm."""
    from torchcal.rotations import kabsch

    p = predicted.detach().to("cpu", torch.float64)
    x = measured.detach().to("cpu", torch.float64)
    rms = float((x - p).norm(dim=-1).pow(2).mean().sqrt())
    if p.shape[0] >= 3:
        R, t = kabsch(p, x)
        reg = float((p @ R.T + t - x).norm(dim=-1).pow(2).mean().sqrt())
        angle = math.degrees(math.acos(max(-1.0, min(1.0, (float(torch.trace(R)) - 1) / 2))))
        shift = float((x.mean(0) - p.mean(0)).norm())
    else:
        reg, angle, shift = rms, 0.0, 0.0
    s_p, s_x = spread_mm(p), spread_mm(x)
    ratio = s_x / s_p if s_p > 0 else math.inf
    b = bound_mm(training_rms_mm)
    train = "" if training_rms_mm is None else f" ({rms / max(training_rms_mm, 1e-12):.3g} times its training rms " \
                                               f"{training_rms_mm:.3g} mm)"
    verdict = msg = None
    if rms > b and reg <= b:
        verdict = "frame"
        msg = (f"{what}: {model_name} is off by rms {rms:.4g} mm{train}, but a rigid motion of the measuring frame "
               f"({shift:.4g} mm, {angle:.3g} deg) brings it to {reg:.4g} mm: the measuring frame moved since the "
               f"fit; run `torchcal register` on some of these poses (other causes: another robot, units)")
    elif rms > b:
        verdict = "mismatch"
        msg = (f"{what}: cannot come from {model_name}: rms {rms:.4g} mm{train}, still {reg:.4g} mm after the best "
               f"rigid motion, point spread {s_x:.4g} mm measured vs {s_p:.4g} mm modelled; likely causes: data of "
               f"another robot or units (length or angle unit){units_hint(ratio)}; not a moved measuring "
               f"frame alone (for that, `torchcal register` would do)")
    return Mismatch(rms, reg, ratio, b, training_rms_mm, shift, angle, verdict, msg)


def check_measurements(model, theta: torch.Tensor, m, training_rms_mm: float | None = None,
                       what: str | None = None, q_range: torch.Tensor | None = None) -> Mismatch:
    """`check_points` of a `CalibrationModel` at theta (P,) on `Measurements` m.

    q_range: the model's calibrated joint range (2, n) rad / mm, or None. When the data are
    off (a verdict) but its rows inside that range agree with the model (at least 3 of
    them, RMS within the bound B), the rows outside it are the cause: the model
    extrapolates badly there (a joint that barely moved in the calibration data leaves
    the tool offset or its link undetermined), and the line says so instead of naming
    another robot, units or a moved frame (the verdict, and so the refusal, stays)."""
    import dataclasses

    from torchcal.calibration.joint_range import outside_range
    from torchcal.effects import context_of

    ctx = context_of(model.robot, m)
    model.check_context(ctx)
    with torch.no_grad():
        pred = model.predict(theta.to(m.xyz), ctx)
    name = f"the model of {model.robot.name}"
    res = check_points(pred, m.xyz, training_rms_mm, what or (m.source or "data"), name)
    if res.verdict is None:
        return res
    if res.verdict == "mismatch":  # this robot with one joint column mixed up?
        def fits(mm):
            c = context_of(model.robot, mm)
            with torch.no_grad():
                return rms_of((model.predict(theta.to(mm.xyz), c) - mm.xyz).norm(dim=-1)) <= res.bound_mm

        hint = column_hint(m, model.robot, fits)
        if hint is not None:
            return dataclasses.replace(res, fix=None, message=(
                f"{what or (m.source or 'data')}: cannot come from {name} as given: rms {res.rms_mm:.4g} mm, but "
                f"within {res.bound_mm:.3g} mm with the joint {hint}: check the joint columns"))
        lag = row_lag(m, fits)
        if lag is not None:
            return dataclasses.replace(res, fix=None, message=(
                f"{what or (m.source or 'data')}: cannot come from {name} as given: rms {res.rms_mm:.4g} mm, but "
                f"within {res.bound_mm:.3g} mm with {lag_words(lag)}"))
    if q_range is None:
        return res
    out = outside_range(m.q, q_range.to(m.q), model.robot.prismatic).any(dim=-1).cpu()  # (N,)
    inside = ~out
    if int(inside.sum()) < 3 or not bool(out.any()):
        return res
    d = (m.xyz - pred).detach().to("cpu", torch.float64).norm(dim=-1)
    rms_in = rms_of(d[inside])
    if rms_in > res.bound_mm:
        return res
    _, joints = range_warning(m.q, q_range.to(m.q), model.robot, None, max_joints=model.robot.n)
    msg = (f"{what or (m.source or 'data')}: {name} is off by rms {res.rms_mm:.4g} mm, but by {rms_in:.4g} mm on "
           f"the {int(inside.sum())} of {len(m)} rows inside its calibrated joint range; the {int(out.sum())} "
           f"outside it ({joints}) are where it fails: it extrapolates badly beyond the joint values it was "
           f"fitted on; fit it on data that cover them (not another robot, units or a moved measuring frame)")
    return dataclasses.replace(res, message=msg, fix=None)


class PointIdWarning(MismatchWarning):
    """Data of another measured point (reflector) than the one a model was fitted on."""


def point_ids_differ(model, m, what: str | None = None) -> str | None:
    """One line when the `point` ids of measurements m are not among those of the data the
    `CalibrationModel` was fitted on (``model.point_ids``, recorded in MODEL.json): its
    tool (the fitted tool offset, or the nominal tool) is that point's, and on another
    point's data every row is off by the distance between the two. None when they agree,
    or when the model or the data record no point ids (older files, no point column)."""
    if not model.point_ids or m.point is None:
        return None
    other = sorted(set(m.point.tolist()) - set(model.point_ids))
    if not other:
        return None
    return (f"{what or m.source or 'measurements'}: point id(s) {listed(other)}, but the model was fitted on the "
            f"data of point id(s) {listed(model.point_ids)}: its tool is that point's, so every row of another "
            "point is off by the distance between the two (another reflector or nest?)")


TOOL_GAIN = 3.0  # a tool offset of its own must bring the rms down this many times to be named


class ReflectorWarning(UserWarning):
    """The rows fit the model far better with a tool offset of their own: another reflector
    (or nest) than the model's, no point column to say so."""


def moved_tool(rms_mm: float, err: torch.Tensor, rot: torch.Tensor, training_rms_mm: float | None,
               where: str) -> str | None:
    """One line when the distance errors `err` (N, 3) mm (measured - model, rms `rms_mm`)
    lie beyond FAR_FACTOR (3) times the training rms and a constant offset u (3,) mm of the
    measured point in the tool frame, err_i ~ R_i u with `rot` (N, 3, 3) the model's tool
    rotations in the measuring frame (linear least squares), leaves at most 1 / TOOL_GAIN
    of it: the rows were measured at another point of the tool (another reflector or nest)
    than the model's. None otherwise, or without a training rms."""
    from torchcal.calibration.registration import FAR_FACTOR

    if training_rms_mm is None or rms_mm <= FAR_FACTOR * training_rms_mm or err.shape[0] < 6:
        return None
    e, R = err.detach().to("cpu", torch.float64), rot.detach().to("cpu", torch.float64)
    u = torch.linalg.lstsq(R.reshape(-1, 3), e.reshape(-1, 1)).solution.flatten()
    after = float((e - R @ u).norm(dim=-1).pow(2).mean().sqrt())
    if after * TOOL_GAIN > rms_mm:
        return None
    return (f"{where}: rms {rms_mm:.4g} mm ({rms_mm / training_rms_mm:.3g} times the model's training rms "
            f"{training_rms_mm:.4g} mm), but {after:.4g} mm with the measured point moved by {float(u.norm()):.4g} mm "
            f"on the tool ([{', '.join(f'{v:.3f}' for v in u.tolist())}] mm in the tool frame): measured at another "
            "reflector or nest than the model's? Re-estimate its tool on some of these rows (register with the "
            "tool), or give each reflector its own point id")


def moved_frame(rms_mm: float, err: torch.Tensor, xyz: torch.Tensor, training_rms_mm: float | None,
                where: str) -> str | None:
    """One line when the distance errors `err` (N, 3) mm (measured `xyz` (N, 3) mm - model,
    rms `rms_mm`) lie beyond FAR_FACTOR (3) times the training rms and the best rigid motion
    of the model's points onto the measured ones (Kabsch) leaves at most 1 / TOOL_GAIN of
    it: the measuring frame moved since the fit by less than the gross-mismatch bound (a
    tracker bumped, set up again near its old place). None otherwise, or without a
    training rms."""
    from torchcal.calibration.registration import FAR_FACTOR
    from torchcal.rotations import kabsch

    if training_rms_mm is None or rms_mm <= FAR_FACTOR * training_rms_mm or err.shape[0] < 6:
        return None
    x = xyz.detach().to("cpu", torch.float64)
    p = x - err.detach().to("cpu", torch.float64)
    R, t = kabsch(p, x)
    after = float((p @ R.T + t - x).norm(dim=-1).pow(2).mean().sqrt())
    if after * TOOL_GAIN > rms_mm:
        return None
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (float(torch.trace(R)) - 1) / 2))))
    shift = float((p @ R.T + t - p).norm(dim=-1).mean())
    return (f"{where}: rms {rms_mm:.4g} mm ({rms_mm / training_rms_mm:.3g} times the model's training rms "
            f"{training_rms_mm:.4g} mm), but {after:.4g} mm after a rigid motion of the measuring frame (the points "
            f"move {shift:.4g} mm on average, {angle:.3g} deg): the instrument moved since the fit (bumped, or set up "
            "again near its old place)? Register the model on some of these rows")


MAX_POINTS_SWAPPED = 4  # point ids whose relabellings are all tried (4! = 24)


def swapped_points(fm, m, rms_mm: float, stage=None) -> str | None:
    """One line when the rows of `m` (`Measurements`) carry several point ids (at most
    MAX_POINTS_SWAPPED, all those of the fitted model `fm`, a `FitResult`), their rms
    `rms_mm` lies beyond FAR_FACTOR (3) times the training rms, and another assignment of
    the ids to the model's tool offsets leaves at most 1 / TOOL_GAIN of it: the point column
    of the file labels the reflectors otherwise than the data the model was fitted on. None
    otherwise. stage: the residual stage, subtracted."""
    import dataclasses
    import itertools

    from torchcal.calibration.registration import FAR_FACTOR
    from torchcal.effects import context_of

    train = fm.training_rms_mm
    ids = sorted(set(m.point.tolist()))
    if train is None or rms_mm <= FAR_FACTOR * train or not 2 <= len(ids) <= MAX_POINTS_SWAPPED:
        return None
    corr = 0.0 if stage is None else stage.predict(m.q).to(m.xyz)
    err = {}  # point id k -> (N, 3) mm error of every row as if measured at point k
    for k in ids:
        as_k = dataclasses.replace(m, point=torch.full_like(m.point, k))
        err[k] = (m.xyz - fm.predict(context_of(fm.model.robot, as_k)) - corr).detach()
    label = m.point.to(m.xyz.device)
    best = None
    for perm in itertools.permutations(ids):
        if list(perm) == ids:
            continue
        e = torch.zeros_like(m.xyz)
        for k, to in zip(ids, perm):
            rows = label == k
            e[rows] = err[to][rows]
        rms = float(e.norm(dim=-1).pow(2).mean().sqrt())
        if best is None or rms < best[0]:
            best = (rms, perm)
    if best is None or best[0] * TOOL_GAIN > rms_mm:
        return None
    mapping = ", ".join(f"{k} as {to}" for k, to in zip(ids, best[1]) if k != to)
    return (f"{m.source or 'data'}: rms {rms_mm:.4g} mm ({rms_mm / train:.3g} times the model's training rms "
            f"{train:.4g} mm), but {best[0]:.4g} mm with the point ids read {mapping}: the point column labels the "
            "reflectors otherwise than the data the model was fitted on? Check which reflector each id is")
