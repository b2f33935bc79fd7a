"""Gross mismatch: data, targets or a robot file that cannot belong to this model.

A fitted model applied to measurements of another robot, to measurements taken in a
measuring frame that moved since the fit, or to numbers in the wrong unit gives errors
of hundreds of mm; without a check the user reads "rms 1203 mm" and goes on. The checks
here turn that into one line naming the likely cause (docs/registration.md).

Measurements (`check_measurements`). With the model's errors d (N,) mm:

- ``rms``: RMS of d as it is; ``registered_rms``: RMS after the best rigid motion of the
  model's points onto the measured ones (Kabsch, `torchcal.calibration.registration`);
  ``spread_ratio``: measured / modelled spread (RMS distance to the centroid; a rigid
  motion leaves it unchanged, and ``|s_measured - s_model| <= registered_rms``).
- Plausible bound ``B = max(GROSS_RATIO * training_rms, GROSS_MM)``: held-out errors a few
  times the training RMS are ordinary (other poses, another day); an order of magnitude
  (GROSS_RATIO = 10) beyond it *and* beyond GROSS_MM = 10 mm, more than an uncalibrated
  industrial arm is off by its nominal model (ISO 9283 absolute accuracy of data sheets:
  0.1 to a few mm), cannot come from a model of this robot. Without a training RMS
  (a nominal robot) only GROSS_MM applies.
- ``rms <= B``: consistent. ``rms > B`` but ``registered_rms <= B``: a rigid motion
  explains the data, i.e. the measuring frame moved (re-register: ``torchcal register``).
  Both beyond B: another robot, or units (the spread ratio says which is more likely: a
  factor near 1000 or 57.3 is a unit, metres or radians).

Targets (`check_targets`, positions (M, 3) mm in the model's frame) against the
workspace of the model: the nominal TCP at `WORKSPACE_POSES` seeded random poses inside
the joint limits. The reach R is their largest distance from the robot base origin (as
the model's base frame maps it). Targets whose median distance from the base origin is below R / 20 (the
factor of `torchcal.calibration.plausibility`'s unit check) sit inside the robot's
base, or whose median distance from the origin of the measuring frame (the instrument) is
below R / 20: metres read as mm (a refusal); targets beyond 1.05 R cannot be reached (a warning
naming them; compensate reports them as not converged).

Before and after a fit (`check_robot_data`, `check_fitted`): the nominal robot with its
measuring frame and tool offset fitted must come within GROSS_MM of the data, else the
cause is named (a frame the model lacks, gross outlier rows, a mirrored frame, reversed
joint columns, another robot or units); a fitted RMS beyond GROSS_MM (the robust fit's
outliers left out) is no calibration (docs/registration.md).

Robot files (`check_robot_lengths`): an arm whose links (sum over joints of
``sqrt(d^2 + a^2)``, prismatic strokes included) reach less than MIN_REACH_MM = 50 mm is
not an industrial arm; its lengths were written in metres.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import torch

GROSS_RATIO = 10.0
GROSS_MM = 10.0
TARGET_RATIO = 20.0
REACH_MARGIN = 1.05
MIN_REACH_MM = 50.0
WORKSPACE_POSES = 2000


class MismatchWarning(UserWarning):
    """Data or targets that do not fit the model, where the command can still go on."""


@dataclass(frozen=True)
class Mismatch:
    """Result of `check_measurements`. rms_mm: model error as is; registered_rms_mm:
    after the best rigid motion; spread_ratio: measured / model spread; bound_mm: the
    plausible bound B; training_rms_mm (None when unknown); frame_mm / frame_deg: the
    rigid motion's translation and rotation angle; verdict: None (consistent), 'frame'
    (a rigid motion explains the data) or 'mismatch' (`check_robot_data` has more);
    message: one line (None when consistent); fix: what corrects it, or None."""

    rms_mm: float
    registered_rms_mm: float
    spread_ratio: float
    bound_mm: float
    training_rms_mm: float | None
    frame_mm: float
    frame_deg: float
    verdict: str | None
    message: str | None
    fix: tuple | None = None  # (keyword, value) of `InputError.fix`


def bound_mm(training_rms_mm: float | None) -> float:
    """The plausible error bound B, mm (module docstring)."""
    if training_rms_mm is None or not math.isfinite(training_rms_mm):
        return GROSS_MM
    return max(GROSS_RATIO * training_rms_mm, GROSS_MM)


def _units_hint(ratio: float) -> str:
    for f, what in ((1000.0, "metres read as mm (length unit m)"), (1e-3, "mm read as metres"),
                    (math.degrees(1.0), "radians read as degrees (angle unit rad)")):
        if abs(math.log(ratio / f)) < math.log(1.5):
            return f"; the spread ratio {ratio:.4g} points at {what}"
    return ""


def check_points(predicted: torch.Tensor, measured: torch.Tensor, training_rms_mm: float | None = None,
                 what: str = "data", model_name: str = "the model") -> Mismatch:
    """Judge measured points (N, 3) mm against a model's predicted points (N, 3) mm."""
    from torchcal.calibration.plausibility import spread_mm
    from torchcal.calibration.registration import kabsch

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
               f"another robot or units (length or angle unit){_units_hint(ratio)}; not a moved measuring "
               f"frame alone (for that, `torchcal register` would do)")
    return Mismatch(rms, reg, ratio, b, training_rms_mm, shift, angle, verdict, msg)


def check_measurements(model, theta: torch.Tensor, m, training_rms_mm: float | None = None,
                       what: str | None = None) -> Mismatch:
    """`check_points` of a `CalibrationModel` at theta (P,) on `Measurements` m."""
    from torchcal.effects import context_of

    ctx = context_of(model.robot, m)
    model.check_context(ctx)
    with torch.no_grad():
        pred = model.predict(theta.to(m.xyz), ctx)
    return check_points(pred, m.xyz, training_rms_mm, what or (m.source or "data"),
                        f"the model of {model.robot.name}")


def enforce(result: Mismatch, refuse_frame: bool = True, refuse_mismatch: bool = True) -> Mismatch:
    """Raise InputError (a refusal) or warn `MismatchWarning` (the command goes on) for a
    verdict; nothing when consistent. Returns `result`."""
    from torchcal.errors import InputError

    if result.verdict is None:
        return result
    refuse = refuse_frame if result.verdict == "frame" else refuse_mismatch
    if refuse:
        raise InputError(result.message, fix=result.fix)
    warnings.warn(result.message, MismatchWarning, stacklevel=3)
    return result


def workspace(model, theta: torch.Tensor, seed: int = 0):
    """(points (K, 3) mm, origin (3,) mm): the nominal geometry's TCP at WORKSPACE_POSES
    seeded random poses and the robot base origin, both mapped by the model's base frame."""
    from torchcal.effects.base_frame import rotvec_to_matrix
    from torchcal.robots.poses import random_poses

    robot = model.robot
    q = random_poses(robot, WORKSPACE_POSES, torch.Generator().manual_seed(seed))
    with torch.no_grad():
        v = robot.fk(q.to(robot.device, robot.dtype)).detach().to("cpu", torch.float64)
    origin = robot.base[:3, 3].detach().to("cpu", torch.float64)
    for e, sl in zip(model.effects, model.slices[1:]):
        if e.name == "base_frame":
            p = theta[sl].detach().to("cpu", torch.float64)
            R = rotvec_to_matrix(p[3:6])
            v, origin = v @ R.T + p[:3], R @ origin + p[:3]
    return v, origin


def check_targets(model, theta: torch.Tensor, targets: torch.Tensor, where: str = "targets") -> list[int]:
    """Refuse targets (M, 3) mm that sit inside the robot's base (metres read as mm);
    warn (`MismatchWarning`) naming targets beyond the reach. Returns the 0-based rows
    beyond the reach."""
    from torchcal.errors import InputError

    pts, origin = workspace(model, theta)
    reach = float((pts - origin).norm(dim=-1).max())
    t = targets.detach().to("cpu", torch.float64)
    dist = (t - origin).norm(dim=-1)
    med = float(dist.median())
    med0 = float(t.norm(dim=-1).median())  # around the origin of the model's (measuring) frame
    if med0 < reach / TARGET_RATIO and med >= reach / TARGET_RATIO:
        metres = med0 * 1000 <= float(origin.norm()) + REACH_MARGIN * reach
        raise InputError(f"{where}: the targets lie a median {med0:.4g} mm from the origin of the measuring frame, "
                         f"where no target of {model.robot.name} can be (its base is {float(origin.norm()):.4g} mm "
                         "away): " + ("they look like metres read as mm" if metres else "wrong unit or wrong frame?"),
                         fix=("length_unit", "m") if metres else None)
    if med < reach / TARGET_RATIO:
        metres = med * 1000 <= REACH_MARGIN * reach
        raise InputError(f"{where}: the targets lie a median {med:.4g} mm from the robot base, inside the base of "
                         f"{model.robot.name} (reach {reach:.4g} mm): "
                         + ("they look like metres read as mm" if metres else "wrong unit or wrong frame?"),
                         fix=("length_unit", "m") if metres else None)
    far = (dist > REACH_MARGIN * reach).nonzero().flatten().tolist()
    if far:
        rows = ", ".join(str(i + 1) for i in far[:10]) + (" ..." if len(far) > 10 else "")
        warnings.warn(f"{where}: {len(far)} target(s) lie beyond the reach of {model.robot.name} ({reach:.4g} mm "
                      f"from the base; up to {float(dist.max()):.4g} mm): row(s) {rows}; another robot, "
                      "another frame (targets are in the model's frame) or units?", MismatchWarning, stacklevel=2)
    return far


def link_reach_mm(table: torch.Tensor, prismatic: torch.Tensor, limits: torch.Tensor) -> float:
    """Sum over joints of sqrt(d^2 + a^2) plus each prismatic joint's largest |limit|, mm;
    table (n, 5) [theta, d, a, alpha, beta], limits (n, 2)."""
    t = table.detach().to("cpu", torch.float64)
    reach = float(torch.sqrt(t[:, 1] ** 2 + t[:, 2] ** 2).sum())
    pris = prismatic.detach().cpu().bool()
    if pris.any():
        reach += float(limits.detach().to("cpu", torch.float64)[pris].abs().max(-1).values.sum())
    return reach


def check_robot_lengths(table, prismatic, limits, where: str = "robot file") -> None:
    """InputError when the links reach less than MIN_REACH_MM (lengths in metres)."""
    from torchcal.errors import InputError

    reach = link_reach_mm(table, prismatic, limits)
    if reach < MIN_REACH_MM:
        raise InputError(f"{where}: the links reach only {reach:.4g} mm in all (sum of sqrt(d_mm^2 + a_mm^2)), less "
                         f"than any industrial arm's {MIN_REACH_MM:g} mm: the lengths look like metres; robot files "
                         "take millimetres (d_mm, a_mm, base, tool, prismatic limits)")


OUTLIER_SHARE = 0.1  # at most this share of rows may be gross outliers (the rest must agree)


def _rms(d: torch.Tensor) -> float:
    return float(d.pow(2).mean().sqrt())


def _in_frame(model, m, tool: bool = True):
    """Predicted points (N, 3) mm of the nominal `model` (its parameters at zero but its
    measuring frame: base_frame, and tool_offset when `tool`, those of them it has) fitted
    to the measurements `m`, from the closed-form registration."""
    from torchcal.calibration.fit import fit
    from torchcal.calibration.registration import frame_slices, register_frame
    from torchcal.effects import context_of

    ctx = context_of(model.robot, m)
    free = torch.zeros(model.n_params, dtype=torch.bool)
    for sl in frame_slices(model, tool):
        free[sl] = True
    if not bool(free.any()):
        with torch.no_grad():
            return model.predict(model.zeros().to(m.xyz), ctx).detach()
    start, _ = register_frame(model, ctx, m.xyz)
    res = fit(model, ctx, m.xyz, theta0=start, free=free, register=False, max_length_mm=None, max_angle_deg=None)
    return (m.xyz - res.residuals).detach()


def _registered(model, m):
    """`_in_frame` of `model` with base_frame and tool_offset (appended where missing)."""
    from torchcal.calibration.registration import with_frame

    return _in_frame(with_frame(model, model.zeros(), tool=True)[0], m)


def _quick_fit(model, ctx, xyz: torch.Tensor) -> bool:
    """True when the nominal `model` already comes within GROSS_MM as it is or, when it has
    base_frame, after the closed-form rigid motion (no solve): the common case, decided
    cheaply; a frame and tool offset fitted could only come closer."""
    from torchcal.calibration.registration import kabsch

    with torch.no_grad():
        p = model.predict(model.zeros().to(xyz), ctx)
    if "base_frame" in [e.name for e in model.effects] and p.shape[0] >= 3:
        R, t = kabsch(p, xyz)
        p = p @ R.T + t
    return _rms((p - xyz).norm(dim=-1)) <= GROSS_MM


def _fits(model, m) -> bool:
    from torchcal.errors import InputError

    try:
        return _rms((_registered(model, m) - m.xyz).norm(dim=-1)) <= GROSS_MM
    except InputError:
        return False


def check_robot_data(model, m, robust: bool | None = False) -> Mismatch | None:
    """Can the measurements `m` (`Measurements`) come from `model`'s robot at all? Judged
    before a fit (nominal geometry, every parameter at zero) against GROSS_MM, the
    plausible error of an uncalibrated arm. Returns None (consistent, or too few rows to
    judge) or a `Mismatch` whose verdict names the cause:

    - 'frame': the robot in its best measuring frame with its best tool offset fits, with
      the frame effects the model has (base_frame, tool_offset, or none) it does not (a
      tracker's frame, a reflector on the flange);
    - 'outliers' (not when `robust` is True, a robust fit follows): at most OUTLIER_SHARE
      of the rows lie beyond the bound and the frame refitted on the others fits them;
      with robust False the fix is ``robust='huber'``, with None (a command without a
      robust loss) none;
    - 'mirrored': the data with one axis negated fit (a rigid motion with a reflection,
      e.g. two of x, y, z swapped; a proper rigid motion does not);
    - 'reversed': the data with the joint columns in reverse order fit;
    - 'mismatch': none of these (another robot, or units: the spread ratio's hint).
    """
    import dataclasses

    from torchcal.effects import context_of
    from torchcal.errors import InputError

    what = m.source or "data"
    name = model.robot.name
    try:
        ctx = context_of(model.robot, m)
        model.check_context(ctx)
        if _quick_fit(model, ctx, m.xyz):
            return None
        pred = _registered(model, m)
    except InputError:
        return None  # too few rows, missing columns: the fit says it in its own words
    d = (pred - m.xyz).norm(dim=-1)
    reg = _rms(d)
    have = [e.name for e in model.effects]
    missing = [n for n in ("base_frame", "tool_offset") if n not in have]

    def result(verdict, msg, fix=None, rms=reg):
        return dataclasses.replace(check_points(pred, m.xyz, None, what), rms_mm=rms, registered_rms_mm=reg,
                                   verdict=verdict, message=msg, fix=fix)

    if reg <= GROSS_MM:
        as_is = reg if not missing else _rms((_in_frame(model, m) - m.xyz).norm(dim=-1))
        if as_is <= GROSS_MM:
            return None
        return result("frame", f"{what}: the measurements are in another frame: the nominal {name} is off by rms "
                      f"{as_is:.4g} mm with the effects given and by {reg:.4g} mm with a fitted measuring frame and "
                      f"tool offset, which the model lacks (tracker data need base_frame tool_offset; data in the "
                      f"robot's base frame with its nominal tool need neither)",
                      ("effects", [*model.specs(), *missing]), as_is)
    n = d.shape[0]
    keep = d <= max(GROSS_MM, 3 * float(d.median()))
    n_far = n - int(keep.sum())
    if n_far <= OUTLIER_SHARE * n and int(keep.sum()) >= 3:
        sub = m.subset(keep.nonzero().flatten())
        try:
            inlier_rms = _rms((_registered(model, sub) - sub.xyz).norm(dim=-1))
        except InputError:
            inlier_rms = math.inf
        if inlier_rms <= GROSS_MM:
            if robust:
                return None
            far = (~keep).nonzero().flatten().tolist()
            ids = ", ".join(str(int(m.pose[i])) for i in far[:10]) + (" ..." if len(far) > 10 else "")
            return result("outliers", f"{what}: {n_far} of {n} rows (pose ids {ids}) lie {float(d[~keep].min()):.4g}"
                          f" to {float(d.max()):.4g} mm off the nominal {name} in its best frame while the others "
                          f"agree to rms {inlier_rms:.4g} mm: gross outliers (mis-typed or corrupted rows) would "
                          "pull the fit; remove them, or fit with a robust loss (it names them)",
                          None if robust is None else ("robust", "huber"))
    flipped_xyz = m.xyz * torch.tensor([-1.0, 1.0, 1.0], dtype=m.xyz.dtype, device=m.xyz.device)
    if _fits(model, dataclasses.replace(m, xyz=flipped_xyz)):
        return result("mirrored", f"{what}: a mirror image of {name}: rms {reg:.4g} mm after the best rigid motion, "
                      f"but within {GROSS_MM:g} mm after one with a reflection; the x, y, z columns describe a "
                      "left-handed frame (two of them swapped, or one negated)")
    if model.robot.n > 1 and _fits(model, dataclasses.replace(m, q=m.q.flip(-1))):
        return result("reversed", f"{what}: the joint columns are in reverse order: rms {reg:.4g} mm as given "
                      f"but within {GROSS_MM:g} mm with q{model.robot.n} .. q1 read as q1 .. q{model.robot.n}")
    from torchcal.calibration.plausibility import spread_mm

    s_x, s_p = spread_mm(m.xyz), spread_mm(pred)
    return result("mismatch", f"{what}: cannot come from {name}: rms {reg:.4g} mm with the best measuring frame "
                  f"and tool offset, point spread {s_x:.4g} mm measured vs {s_p:.4g} mm modelled; likely causes: "
                  f"data of another robot or units (length or angle unit){_units_hint(s_x / max(s_p, 1e-12))}")

def check_fitted(residuals: torch.Tensor, outliers=(), what: str = "data", name: str = "the model") -> str | None:
    """After a fit: None, or one line when its residuals (N, 3) mm, the rows in `outliers`
    (0-based, the robust fit's) left out, have an RMS beyond GROSS_MM: no calibration of
    this robot is that far off, so nothing sensible was fitted."""
    keep = torch.ones(residuals.shape[0], dtype=torch.bool)
    keep[list(outliers)] = False
    rms = _rms(residuals.detach().cpu()[keep].norm(dim=-1))
    if rms <= GROSS_MM:
        return None
    return (f"{what}: the fitted model of {name} is still off by rms {rms:.4g} mm (a calibrated arm is off by less "
            f"than {GROSS_MM:g} mm): nothing sensible was fitted; likely causes: data of another robot, units, "
            "joint columns in another order, a mirrored frame, gross outliers (a robust loss), or a measuring "
            "frame the model lacks (the effects base_frame tool_offset)")
