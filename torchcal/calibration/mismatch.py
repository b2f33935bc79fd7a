"""Input checks against a model: data, targets or a robot file that cannot belong to it.

The one place for checks of whether inputs fit a robot or a model (docs/design.md); the
readers of `torchcal.io` check a file's own content (cells, columns, joint limits).

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
the joint limits, each pushed out by the fitted tool offset's length when the model has
one. The reach R is their largest distance from the robot base origin (as the model's
base frame maps it). Targets whose median distance from the base origin is below R / 20 (the
factor of the unit check, `check_units`) sit inside the robot's
base, or whose median distance from the origin of the measuring frame (the instrument) is
below R / 20: a unit (a refusal); targets beyond 1.05 R cannot be reached (a warning
naming them; compensate reports them as not converged), unless more than 10 % of them are
and a unit brings them into the workspace (a refusal). The unit is the first of `MISREAD`
(metres, inches) whose factor, applied about the origin of the frame the targets were given
in, puts their median distance from the base within [R / 20, 1.05 R] and at most 10 % of
them beyond 1.05 R ("they look like inches read as mm; convert them to mm (x 25.4)");
the words and the factor are those of the measurement unit check (`misread_length`).

Seeds of targets (`check_seeds`): the model at each seed should lie on its target (a seed
is the target's nominal command); seeds within +-2 pi "degrees" a median beyond SEED_MM =
100 mm from their targets are radians read as degrees (a refusal), other seeds beyond
SEED_MM are named in a warning. Seeds given in radians (the library's ``q0``) beyond
what a joint can turn (`beyond_turn`: max(2 pi, the widest limit) + 0.01 rad) are degrees
(a refusal).

Before and after a fit (`check_robot_data`, `check_fitted`): the nominal robot with its
measuring frame and tool offset fitted must come within GROSS_MM of the data, else the
cause is named (a frame the model lacks, gross outlier rows, a mirrored frame, reversed
joint columns, two sessions joined, the instrument or reflector changed midway through
one session (`changed_midway`), another robot or units); a fitted RMS beyond GROSS_MM (the robust fit's
outliers left out) is no calibration (docs/registration.md).

Row order (`check_row_order`): backlash reads each row's approach direction from the row
order; a file without prev_q columns and with one row per pose id whose ids step down at
more than 5 % of its rows (sorted or shuffled after the session) gets one warning.

Robots (`check_same_robot`, `robot_differences`): a model applied to another robot, and a
sweep or partition file made for another robot than the one given (another joint count,
joint types, MD-H table, base, tool or joint limits; `torchcal.io.robot_file.check_record`
reads the file's record and names the differences in its one line).

Units (before any fit, `check_units`). Measurements are compared with the nominal model at
the same joint angles by a registration-invariant spread: the RMS distance of the points
to their centroid, ``s = sqrt(mean |p - mean(p)|^2)`` (a rigid change of frame leaves it
unchanged, so the instrument's frame does not matter). For a right file and the right
robot the ratio ``s_measured / s_nominal`` is 1 within a few percent (a different tool
point moves it by tens of percent at most); a unit mistake moves it by about 1000.

- ratio < 1/20 with ``length_unit='mm'``: positions look like metres read as mm
  (fix: ``length_unit='m'``), or inches read as mm when the ratio is 1/25.4 within 10 %
  (no unit option: convert the file); ratio > 20 with ``length_unit='m'``: mm read as metres
  (fix: ``length_unit='mm'``). Any other ratio outside [1/20, 20] is refused too, naming
  the spreads (wrong unit or wrong robot).
- ``angle_unit='deg'`` and every joint angle within +-2 pi (6.283 "degrees") while the
  measured points spread more than 2x the nominal ones: joint angles look like radians
  read as degrees (fix: ``angle_unit='rad'``). A real data set in degrees that only
  moves a few degrees keeps ratio ~1 and passes.
- ``angle_unit='rad'`` and a joint angle beyond max(2 pi, the robot's widest limit) rad
  (+ 0.01): degrees read as radians (fix: ``angle_unit='deg'``).

The check needs at least 3 rows and a nominal spread of at least 1 mm; otherwise it
says nothing.

The calibrated joint range (`range_warning`, `warn_outside_range`): rows or converged
commands beyond the range a model was fitted on (`torchcal.calibration.joint_range`) are
counted and named in one `CalibratedRangeWarning`: the model extrapolates there.

A robot given with a model (`check_same_robot`) must be the robot it was fitted for.

Partitions that record no robot (`check_partition`: one built in memory, an older file)
are judged by geometry: their sweep points are the nominal TCP positions of the robot
they were made for, in its base frame. More than OUTLIER_SHARE = 10 % of them beyond 1.05 R
(R: the reach, as for targets), or calibration poses whose nominal TCP positions lie a median
farther from the nearest sweep point than PARTITION_SPACING = 3 times the sweep's own median
spacing and than R / 20: a partition of another robot (or of another region), refused.
A calibration row or a compensated command whose nominal TCP lies farther than
PARTITION_SPACING sweep spacings from every sweep point (`warn_far_from_sweep`) takes an
extrapolated zone: named in one warning.

Robot files (`check_robot_angles`): every revolute limit within +-2 pi "degrees", or a
twist or offset of pi / 2 or pi "degrees" in a file with no angle beyond 2 pi "degrees",
are radians written where degrees belong. (`check_robot_lengths`): an arm whose links (sum over joints of
``sqrt(d^2 + a^2)``, prismatic strokes included) reach less than MIN_REACH_MM = 50 mm is
not an industrial arm; its lengths were written in metres. One that reaches more than
MAX_REACH_MM = 100 m was written in micrometres (a URDF import: in millimetres).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import torch

from torchcal.errors import InputError

GROSS_RATIO = 10.0
GROSS_MM = 10.0
TARGET_RATIO = 20.0
REACH_MARGIN = 1.05
MIN_REACH_MM = 50.0
MIN_STROKE_MM = 1.0  # a prismatic joint travelling less: its limits were written in metres
MAX_REACH_MM = 100_000.0  # 100 m of links and strokes: beyond the longest linear track
WORKSPACE_POSES = 2000
SEED_MM = 100.0  # a seed whose model point lies farther from its target is no nominal command of it
RATIO_LIMIT = 20.0
RAD_RATIO = 2.0
INCH_MM = 25.4
PARTITION_SPACING = 3.0


#: the length units that numbers read as mm are mistaken in: factor to mm, the words naming
#: the mistake, the `InputError.fix` (None: no unit option reads them; convert the file)
MISREAD = {"metres": (1000.0, "metres read as mm", ("length_unit", "m")),
           "inches": (INCH_MM, f"inches read as mm; convert them to mm (x {INCH_MM:g})", None)}


def misread_length(ratio: float) -> str | None:
    """The unit (a `MISREAD` key) of numbers read as mm that are `ratio` times the size
    they should have: 'inches' when 1/25.4 within 10 %, 'metres' at any other ratio below
    1 / RATIO_LIMIT, else None."""
    if abs(math.log(ratio * INCH_MM)) < math.log(1.1):
        return "inches"
    return "metres" if ratio < 1 / RATIO_LIMIT else None


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


def _listed(values, most: int = 10) -> str:
    """The first `most` values, comma-separated, with " ..." when there are more (a row or
    id list in a one-line message)."""
    values = list(values)
    return ", ".join(map(str, values[:most])) + (" ..." if len(values) > most else "")


def bound_mm(training_rms_mm: float | None) -> float:
    """The plausible error bound B, mm (module docstring)."""
    if training_rms_mm is None or not math.isfinite(training_rms_mm):
        return GROSS_MM
    return max(GROSS_RATIO * training_rms_mm, GROSS_MM)


def spread_mm(p: torch.Tensor) -> float:
    """RMS distance of points p (N, 3) mm to their centroid (invariant to a rigid motion)."""
    return float((p - p.mean(0)).pow(2).sum(-1).mean().sqrt())


def check_units(m, robot, length_unit: str = "mm", angle_unit: str = "deg", where: str = "") -> dict:
    """Refuse the classic unit mistakes (module docstring) with one InputError line.

    m: Measurements (already converted with the given units); robot: the nominal robot.
    Returns {"measured_spread_mm", "nominal_spread_mm", "ratio"} (None values when the
    check could not judge).
    """
    pre = f"{where}: " if where else ""
    rev = ~robot.prismatic.cpu()  # a prismatic joint's q is a length (mm), never an angle
    q = m.q.detach().to("cpu", torch.float64)[..., rev]
    qmax_file = float(q.abs().max()) if q.numel() else 0.0  # rad inside
    if angle_unit == "rad":
        bound = beyond_turn(m.q, robot)
        if bound is not None:
            raise InputError(f"{pre}joint angles reach {qmax_file:.4g} rad, beyond what a joint can "
                             f"turn ({bound:.3g} rad): they look like degrees read as radians",
                             fix=("angle_unit", "deg"))
    out = {"measured_spread_mm": None, "nominal_spread_mm": None, "ratio": None}
    if len(m) < 3:
        return out
    nominal = robot.fk(m.q.to(robot.device, robot.dtype)).detach().to("cpu", torch.float64)
    s_nom = spread_mm(nominal)
    s_meas = spread_mm(m.xyz.detach().to("cpu", torch.float64))
    if s_nom < 1.0:
        return out
    ratio = s_meas / s_nom
    out.update(measured_spread_mm=s_meas, nominal_spread_mm=s_nom, ratio=ratio)
    spreads = (f"the measured points spread {s_meas:.4g} mm (RMS distance to their centroid), "
               f"the nominal {robot.name} at these joint angles {s_nom:.4g} mm")
    if angle_unit == "deg" and q.numel() and math.degrees(qmax_file) <= 2 * math.pi + 1e-9 and ratio > RAD_RATIO:
        raise InputError(f"{pre}every joint angle lies within +-{math.degrees(qmax_file):.4g} deg and "
                         f"{spreads}: the joint angles look like radians read as degrees",
                         fix=("angle_unit", "rad"))
    if ratio < 1 / RATIO_LIMIT:
        if length_unit == "mm":
            _, words, fix = MISREAD[misread_length(ratio)]
            raise InputError(f"{pre}{spreads} ({1 / ratio:.4g} times less): the positions look like {words}",
                             fix=fix)
        raise InputError(f"{pre}{spreads} ({1 / ratio:.4g} times less): wrong unit or wrong robot?")
    if ratio > RATIO_LIMIT:
        if length_unit == "m":
            raise InputError(f"{pre}{spreads} ({ratio:.4g} times more): the positions look like "
                             "mm read as metres", fix=("length_unit", "mm"))
        raise InputError(f"{pre}{spreads} ({ratio:.4g} times more): wrong unit or wrong robot?")
    return out


def beyond_turn(q: torch.Tensor, robot) -> float | None:
    """The bound max(2 pi, the robot's widest revolute limit) + 0.01 rad when a revolute
    joint value of q (..., n) rad / mm lies beyond it (degrees taken for radians), else None."""
    rev = ~robot.prismatic.cpu()
    a = q.detach().to("cpu", torch.float64)[..., rev]
    if not a.numel():
        return None
    bound = max(2 * math.pi, float(robot.limits.detach().cpu()[rev].abs().max())) + 0.01
    return bound if float(a.abs().max()) > bound else None


def _units_hint(ratio: float) -> str:
    # ratio = measured / modelled spread: numbers 1000 times too small are metres read as mm
    for f, what in ((1e-3, "metres read as mm (length unit m)"), (1000.0, "mm read as metres (length unit mm)"),
                    (1 / INCH_MM, "inches read as mm"),
                    (math.degrees(1.0), "radians read as degrees (angle unit rad)")):
        if abs(math.log(ratio / f)) < math.log(1.5):
            return f"; the spread ratio {ratio:.4g} points at {what}"
    return ""


def check_points(predicted: torch.Tensor, measured: torch.Tensor, training_rms_mm: float | None = None,
                 what: str = "data", model_name: str = "the model") -> Mismatch:
    """Judge measured points (N, 3) mm against a model's predicted points (N, 3) mm."""
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
                return _rms((model.predict(theta.to(mm.xyz), c) - mm.xyz).norm(dim=-1)) <= res.bound_mm

        hint = column_hint(m, model.robot, fits)
        if hint is not None:
            return dataclasses.replace(res, fix=None, message=(
                f"{what or (m.source or 'data')}: cannot come from {name} as given: rms {res.rms_mm:.4g} mm, but "
                f"within {res.bound_mm:.3g} mm with the joint {hint}: check the joint columns"))
        lag = row_lag(m, fits)
        if lag is not None:
            return dataclasses.replace(res, fix=None, message=(
                f"{what or (m.source or 'data')}: cannot come from {name} as given: rms {res.rms_mm:.4g} mm, but "
                f"within {res.bound_mm:.3g} mm with {_lag_words(lag)}"))
    if q_range is None:
        return res
    out = outside_range(m.q, q_range.to(m.q), model.robot.prismatic).any(dim=-1).cpu()  # (N,)
    inside = ~out
    if int(inside.sum()) < 3 or not bool(out.any()):
        return res
    d = (m.xyz - pred).detach().to("cpu", torch.float64).norm(dim=-1)
    rms_in = _rms(d[inside])
    if rms_in > res.bound_mm:
        return res
    _, joints = range_warning(m.q, q_range.to(m.q), model.robot, None, max_joints=model.robot.n)
    msg = (f"{what or (m.source or 'data')}: {name} is off by rms {res.rms_mm:.4g} mm, but by {rms_in:.4g} mm on "
           f"the {int(inside.sum())} of {len(m)} rows inside its calibrated joint range; the {int(out.sum())} "
           f"outside it ({joints}) are where it fails: it extrapolates badly beyond the joint values it was "
           f"fitted on; fit it on data that cover them (not another robot, units or a moved measuring frame)")
    return dataclasses.replace(res, message=msg, fix=None)


def enforce(result: Mismatch, refuse_frame: bool = True, refuse_mismatch: bool = True) -> Mismatch:
    """Raise InputError (a refusal) or warn `MismatchWarning` (the command goes on) for a
    verdict; nothing when consistent. Returns `result`."""
    if result.verdict is None:
        return result
    refuse = refuse_frame if result.verdict == "frame" else refuse_mismatch
    if refuse:
        raise InputError(result.message, fix=result.fix)
    warnings.warn(result.message, MismatchWarning, stacklevel=3)
    return result


def workspace(model, theta: torch.Tensor, seed: int = 0):
    """(points (K, 3) mm, origin (3,) mm): the nominal geometry's TCP at WORKSPACE_POSES
    seeded random poses and the robot base origin, both mapped by the model's base frame.
    With a fitted tool offset each point is pushed away from the origin by the longest
    offset, the most the offset can add to its distance (else a target that the fitted
    tool reaches, e.g. a calibration pose with a 290 mm reflector, reads as out of reach)."""
    from torchcal.effects.base_frame import rotvec_to_matrix
    from torchcal.robots.poses import random_poses

    robot = model.robot
    q = random_poses(robot, WORKSPACE_POSES, torch.Generator().manual_seed(seed))
    with torch.no_grad():
        v = robot.fk(q.to(robot.device, robot.dtype)).detach().to("cpu", torch.float64)
    origin = robot.base[:3, 3].detach().to("cpu", torch.float64)
    for e, sl in zip(model.effects, model.slices[1:]):
        if e.name == "tool_offset":  # each point's offset turns with the flange: the farthest
            # point moves out by at most the longest offset (a reflector 290 mm off the flange)
            off = float(theta[sl].detach().to("cpu", torch.float64).reshape(-1, 3).norm(dim=-1).max())
            v = origin + (v - origin) * (1 + off / (v - origin).norm(dim=-1, keepdim=True).clamp_min(1e-9))
        if e.name == "base_frame":
            p = theta[sl].detach().to("cpu", torch.float64)
            R = rotvec_to_matrix(p[3:6])
            v, origin = v @ R.T + p[:3], R @ origin + p[:3]
    return v, origin


def _in_workspace(p: torch.Tensor, origin: torch.Tensor, reach: float) -> bool:
    """Points p (M, 3) mm whose median distance from the base origin lies within
    [reach / TARGET_RATIO, REACH_MARGIN * reach], at most OUTLIER_SHARE of them beyond it."""
    d = (p - origin).norm(dim=-1)
    return reach / TARGET_RATIO <= float(d.median()) <= REACH_MARGIN * reach and \
        float((d > REACH_MARGIN * reach).double().mean()) <= OUTLIER_SHARE


def _scaled_unit(t: torch.Tensor, origin: torch.Tensor, reach: float, about: torch.Tensor) -> str | None:
    """The `MISREAD` unit whose factor brings the targets t (M, 3) (numbers read as mm,
    scaled about `about` (3,), the origin of the frame they were given in, where a file's
    numbers are zero) into the workspace (`_in_workspace`); the first that does in
    `MISREAD`'s order (metres: numbers in metres times 25.4 can land in a large arm's
    workspace near the instrument; inches times 1000 lie 39 times too far), None when none."""
    for unit, (factor, _, _) in MISREAD.items():
        if _in_workspace(about + (t - about) * factor, origin, reach):
            return unit
    return None


def check_targets(model, theta: torch.Tensor, targets: torch.Tensor, where: str = "targets",
                  about: torch.Tensor | None = None, other_frame: tuple | None = None,
                  length_unit: str = "mm") -> list[int]:
    """Refuse targets (M, 3) mm that sit inside the robot's base or around the origin of
    their frame, and targets mostly beyond the reach, when a unit (`MISREAD`: metres,
    inches) or else the other frame would bring them into the workspace (one InputError
    naming it); warn (`MismatchWarning`) naming the other targets beyond the reach. about: (3,)
    mm, the origin of the frame the targets were given in, in the model's frame (None: the
    model's own, the measuring frame). other_frame: (points (M, 3) mm, the targets read in
    the other frame (robot base or measuring) mapped into the model's frame; its name;
    the `InputError.fix` that reads them so), or None. length_unit: the unit the targets
    were given in ('m': read times 1000; targets in mm given so lie 1000 times too far, and
    are refused when a thousandth of them lies in the workspace). Returns the 0-based rows
    beyond the reach."""
    pts, origin = workspace(model, theta)
    reach = float((pts - origin).norm(dim=-1).max())
    t = targets.detach().to("cpu", torch.float64)
    dist = (t - origin).norm(dim=-1)
    med = float(dist.median())
    med0 = float(t.norm(dim=-1).median())  # around the origin of the model's (measuring) frame
    far = (dist > REACH_MARGIN * reach).nonzero().flatten().tolist()
    wrong = med < reach / TARGET_RATIO or med0 < reach / TARGET_RATIO or len(far) > OUTLIER_SHARE * len(t)
    at = torch.zeros(3, dtype=torch.float64) if about is None else about.detach().to("cpu", torch.float64)
    if wrong and length_unit == "m" and _in_workspace(at + (t - at) / 1000.0, origin, reach):
        raise InputError(f"{where}: read in metres, the targets lie a median {med:.4g} mm from the base of "
                         f"{model.robot.name} (reach {reach:.4g} mm; {len(far)} of {len(t)} beyond it), and a "
                         "thousandth of them within its reach: they look like mm read as metres",
                         fix=("length_unit", "mm"))
    unit = _scaled_unit(t, origin, reach, at)
    if wrong and unit is None and other_frame is not None and \
            _in_workspace(other_frame[0].detach().to("cpu", torch.float64), origin, reach):
        raise InputError(f"{where}: as given the targets lie a median {med:.4g} mm from the base of "
                         f"{model.robot.name} (reach {reach:.4g} mm; {len(far)} of {len(t)} beyond it), but read in "
                         f"the {other_frame[1]} they would lie within its reach: they look like coordinates in the "
                         f"{other_frame[1]}", fix=other_frame[2])
    _, words, fix = MISREAD[unit] if unit is not None else (None, "wrong unit or wrong frame?", None)
    look = f"they look like {words}" if unit is not None else words
    if med0 < reach / TARGET_RATIO and med >= reach / TARGET_RATIO:
        raise InputError(f"{where}: the targets lie a median {med0:.4g} mm from the origin of the measuring frame, "
                         f"where no target of {model.robot.name} can be (its base is {float(origin.norm()):.4g} mm "
                         f"away): {look}", fix=fix)
    if med < reach / TARGET_RATIO:
        raise InputError(f"{where}: the targets lie a median {med:.4g} mm from the robot base, inside the base of "
                         f"{model.robot.name} (reach {reach:.4g} mm): {look}", fix=fix)
    if len(far) > OUTLIER_SHARE * len(t) and unit is not None:
        raise InputError(f"{where}: {len(far)} of {len(t)} targets lie beyond the reach of {model.robot.name} "
                         f"({reach:.4g} mm from its base; a median {med:.4g} mm), and x {MISREAD[unit][0]:g} they "
                         f"would lie within it: {look}", fix=fix)
    if far:
        rows = _listed(i + 1 for i in far)
        warnings.warn(f"{where}: {len(far)} target(s) lie beyond the reach of {model.robot.name} ({reach:.4g} mm "
                      f"from the base; up to {float(dist.max()):.4g} mm): row(s) {rows}; another robot, "
                      "another frame (targets are in the model's frame) or units?", MismatchWarning, stacklevel=2)
    return far


def check_partition(partition, robot, q: torch.Tensor, where: str = "partition") -> None:
    """Refuse (one InputError line naming `where`) a `torchcal.partition.zones.Partition`
    that cannot be of `robot` by its geometry (module docstring): sweep points beyond the
    reach, or calibration poses q (N, n) rad / mm far from every sweep point."""
    from torchcal.robots.poses import random_poses

    with torch.no_grad():
        ws = robot.fk(random_poses(robot, WORKSPACE_POSES, torch.Generator().manual_seed(0)).to(
            robot.device, robot.dtype)).detach().to("cpu", torch.float64)
        p = robot.fk(q.to(robot.device, robot.dtype)).detach().to("cpu", torch.float64)  # (N, 3) mm
    origin = robot.base[:3, 3].detach().to("cpu", torch.float64)
    reach = float((ws - origin).norm(dim=-1).max())
    pts = partition.positions.detach().to("cpu", torch.float64)
    dist = (pts - origin).norm(dim=-1)
    far = int((dist > REACH_MARGIN * reach).sum())
    if far > OUTLIER_SHARE * pts.shape[0]:
        raise InputError(f"{where}: {far} of its {pts.shape[0]} sweep points lie beyond the reach of robot "
                         f"{robot.name!r} ({reach:.4g} mm from its base; up to {float(dist.max()):.4g} mm): a "
                         "partition of another robot? make the sweep and partition for this robot")
    if pts.shape[0] < 2 or p.shape[0] == 0:
        return
    spacing, near = partition.nearest_sweep(p)
    near = float(near.median())
    if near > max(PARTITION_SPACING * spacing, reach / TARGET_RATIO):
        raise InputError(f"{where}: the calibration poses of robot {robot.name!r} lie a median {near:.4g} mm from "
                         f"the nearest of its sweep points (spaced a median {spacing:.4g} mm apart): a partition "
                         "of another robot, or of another part of the workspace? make the sweep and partition for "
                         "this robot")


def warn_far_from_sweep(partition, positions: torch.Tensor, where: str = "targets", stacklevel: int = 2) -> list[int]:
    """Name (one `MismatchWarning`) the positions (M, 3) mm, robot base frame, that lie
    farther from the nearest sweep point of `partition` than PARTITION_SPACING times the
    sweep's median spacing: their zone is the nearest sweep points' zone, an extrapolation
    (a sweep of another region of the workspace). Returns their 0-based rows."""
    pts = partition.positions.detach().to("cpu", torch.float64)
    if pts.shape[0] < 2 or positions.shape[0] == 0:
        return []
    spacing, near = partition.nearest_sweep(positions)
    far = (near > PARTITION_SPACING * spacing).nonzero().flatten().tolist()
    if far:
        warnings.warn(f"{where}: {len(far)} command(s) reach nominal TCP positions up to {float(near.max()):.4g} mm "
                      f"from the nearest sweep point of the partition (spaced a median {spacing:.4g} mm apart): "
                      f"row(s) {_listed(i + 1 for i in far)}; their zone is extrapolated from the nearest sweep "
                      "points (sweep the region they lie in)", MismatchWarning, stacklevel=stacklevel + 1)
    return far


def check_seeds(seed_points: torch.Tensor, targets: torch.Tensor, q0: torch.Tensor, robot,
                where: str = "targets", skip=(), angle_unit: str = "deg") -> list[int]:
    """Compensation seeds against their targets: a seed (the ``q1..qN`` of a targets file)
    is normally the nominal command of its target, where the model lies within the robot's
    absolute accuracy (a few mm) of it; the solve starts there and stays in its arm
    configuration.

    seed_points: (M, 3) mm, the model at the seeds q0 (M, n) rad / mm; targets (M, 3) mm in
    the same frame. InputError when every revolute seed lies within +-2 pi "degrees" and
    the median distance from seed point to target exceeds SEED_MM = 100 mm: radians in a
    degree column (the solve would converge from near-zero angles, in another arm
    configuration; fix angle_unit='rad'). A real set of seeds that only moves a few degrees
    sits on its targets and passes. Otherwise a `MismatchWarning` names the targets whose
    seed point lies beyond SEED_MM (the solution may lie in another arm configuration than
    the seed's); rows in `skip` (0-based: targets beyond the reach, named already) are not.
    angle_unit: the unit the seeds were given in: 'deg' (a targets file), or 'rad' (the
    library's q0), where seeds beyond what a joint can turn (`beyond_turn`) are degrees
    given as radians (an InputError naming `where`). Returns the named 0-based rows."""
    d = (seed_points.detach().to("cpu", torch.float64) - targets.detach().to("cpu", torch.float64)).norm(dim=-1)
    if d.numel() == 0:
        return []
    rev = ~robot.prismatic.cpu()
    q = q0.detach().to("cpu", torch.float64)[..., rev]
    med = float(d.median())
    bound = beyond_turn(q0, robot) if angle_unit == "rad" else None
    if bound is not None:
        raise InputError(f"{where}: seed angles reach {float(q.abs().max()):.4g} rad, beyond what a joint can turn "
                         f"({bound:.3g} rad): they look like degrees; seeds are in radians (torch.deg2rad)")
    if angle_unit == "deg" and q.numel() and math.degrees(float(q.abs().max())) <= 2 * math.pi + 1e-9 \
            and med > SEED_MM:
        raise InputError(f"{where}: every seed angle lies within +-{math.degrees(float(q.abs().max())):.4g} deg and "
                         f"the model at the seeds lies a median {med:.4g} mm from the targets: the seeds "
                         f"q1..q{robot.n} look like radians read as degrees", fix=("angle_unit", "rad"))
    far = [i for i in (d > SEED_MM).nonzero().flatten().tolist() if i not in set(skip)]
    if far:
        rows = _listed(i + 1 for i in far)
        warnings.warn(f"{where}: {len(far)} seed(s) lie more than {SEED_MM:g} mm from their targets (the model at "
                      f"the seed; up to {float(d.max()):.4g} mm): row(s) {rows}; a seed is the target's nominal "
                      "command: the solution may lie in another arm configuration", MismatchWarning, stacklevel=2)
    return far


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
    return (f"{what or m.source or 'measurements'}: point id(s) {_listed(other)}, but the model was fitted on the "
            f"data of point id(s) {_listed(model.point_ids)}: its tool is that point's, so every row of another "
            "point is off by the distance between the two (another reflector or nest?)")


ORDER_SHARE = 0.05  # pose ids stepping down at more than this share of rows: not the order taken


class RowOrderWarning(MismatchWarning):
    """A direction-dependent effect on rows that do not look like the measurement order."""


def check_row_order(m, specs) -> int:
    """Warn (`RowOrderWarning`, one line) when an effect that reads the approach direction
    from the row order (backlash) meets a file without ``prev_q`` columns whose pose ids
    step down (id below the previous row's) at more than ORDER_SHARE = 5 % of its rows: rows
    sorted or shuffled after the session (a spreadsheet), whose own order gives every row
    a wrong predecessor. Only files of one row per pose id are judged: a session numbered
    in the order taken steps down nowhere, two sessions joined once; with repeats the
    cycles through the poses run in random order by design (a tracker's, `simulate`'s).
    Returns the number of step-downs (0 when not checked)."""
    from torchcal.measurements import previous_angles

    names = {str(s).split(":")[0] for s in specs}
    if "backlash" not in names or len(m) < 2:
        return 0
    if m.q_prev is not None and not torch.equal(m.q_prev, previous_angles(m.q)):  # true predecessors given
        return 0
    pose = m.pose.detach().cpu()
    if pose.unique().numel() < pose.numel():  # repeats: cycles through the poses in random order (the
        return 0  # tracker's and `simulate`'s), ids out of order by design
    down = (pose[1:] < pose[:-1]).nonzero().flatten()
    if down.numel() <= ORDER_SHARE * len(m):
        return 0
    r = int(down[0]) + 1  # 0-based row that steps down
    warnings.warn(f"{m.source or 'measurements'}: backlash reads each row's approach direction from the row "
                  f"order, but the pose ids step down at {down.numel()} of {len(m)} rows (first: data row {r + 1}, "
                  f"pose id {int(pose[r])} after {int(pose[r - 1])}): rows sorted or shuffled after the session? "
                  f"keep the order taken (a subset: write it with torchcal split, prev_q columns)",
                  RowOrderWarning, stacklevel=3)
    return int(down.numel())


def check_same_robot(model_robot, robot, where: str, what: str = "the given robot") -> None:
    """Refuse (one InputError line naming both) when `robot` is not the robot the model
    was fitted for: another joint count, joint types, nominal table, base or tool, and
    what differs (`robot_differences`: a robot file of the same name with another tool
    reads "the tool differs")."""
    if robot is None or robot.same_geometry(model_robot):
        return
    diff = "; ".join(d for d in robot_differences(model_robot, robot) if " limits " not in d)  # not geometry
    raise InputError(f"{where}: the model is for robot {model_robot.name!r} ({model_robot.n} joints), "
                     f"but {what} is robot {robot.name!r} ({robot.n} joints) with another nominal "
                     f"geometry{f' ({diff})' if diff else ''}; refusing to apply a model to another robot")


def robot_differences(there, here, atol: float = 1e-9) -> list[str]:
    """What differs between the robot `there` (the one a file was made for) and `here`
    (the one given): joint count, joint types, MD-H table, base, tool or joint limits,
    each as a short phrase ("joint 2 limits -185..185 deg in the file, -170..170 deg given");
    [] when they agree up to `atol` (mm, rad: a robot read back from a file). Names,
    payload, gravity and the clearance model are not compared."""
    if there.n != here.n:
        return [f"{there.n} joints in the file, {here.n} given"]
    a, b = there.to("cpu", torch.float64), here.to("cpu", torch.float64)
    kinds = lambda r, j: "prismatic" if bool(r.prismatic[j]) else "revolute"  # noqa: E731
    types = [j for j in range(a.n) if bool(a.prismatic[j]) != bool(b.prismatic[j])]
    if types:
        j = types[0]
        return [f"joint {j + 1} {kinds(a, j)} in the file, {kinds(b, j)} given"]
    out = []
    rows = [j for j in range(a.n) if not torch.allclose(a.table[j], b.table[j], rtol=0, atol=atol)]
    if rows:
        out.append(f"the MD-H table differs at joint(s) {', '.join(str(j + 1) for j in rows)}")
    out += [f"the {t} differs" for t in ("base", "tool")
            if not torch.allclose(getattr(a, t), getattr(b, t), rtol=0, atol=atol)]
    lim = [j for j in range(a.n) if not torch.allclose(a.limits[j], b.limits[j], rtol=0, atol=atol)]
    if lim:
        j, unit = lim[0], a.joint_units()[lim[0]]
        user = lambda r: [v if unit == "mm" else math.degrees(v) for v in r.limits[j].tolist()]  # noqa: E731
        (lo, hi), (lo2, hi2) = user(a), user(b)
        more = f" (and {len(lim) - 1} more joint(s))" if len(lim) > 1 else ""
        out.append(f"joint {j + 1} limits {lo:g}..{hi:g} {unit} in the file, {lo2:g}..{hi2:g} {unit} given{more}")
    return out


def link_reach_mm(table: torch.Tensor, prismatic: torch.Tensor, limits: torch.Tensor) -> float:
    """Sum over joints of sqrt(d^2 + a^2) plus each prismatic joint's largest |limit|, mm;
    table (n, 5) [theta, d, a, alpha, beta], limits (n, 2)."""
    t = table.detach().to("cpu", torch.float64)
    reach = float(torch.sqrt(t[:, 1] ** 2 + t[:, 2] ** 2).sum())
    pris = prismatic.detach().cpu().bool()
    if pris.any():
        reach += float(limits.detach().to("cpu", torch.float64)[pris].abs().max(-1).values.sum())
    return reach


def check_robot_lengths(table, prismatic, limits, where: str = "robot file", urdf: bool = False) -> None:
    """InputError when the links reach less than MIN_REACH_MM (lengths in metres) or more
    than MAX_REACH_MM (a URDF written in mm, read as metres; a robot file in micrometres);
    a robot file's prismatic joint travelling less than MIN_STROKE_MM among links that
    reach farther: one `RobotUnitWarning` (its limits in metres).
    urdf: the lengths were read from a URDF (metres there), named as such."""
    reach = link_reach_mm(table, prismatic, limits)
    if reach > MAX_REACH_MM:
        raise InputError(f"{where}: the links reach {reach / 1000:.4g} m in all (sum of sqrt(d^2 + a^2), prismatic "
                         f"strokes included), more than any robot's {MAX_REACH_MM / 1000:g} m: the lengths look like "
                         + ("millimetres; URDF takes metres (joint origins, prismatic limits)" if urdf else
                            "micrometres; robot files take millimetres (d_mm, a_mm, base, tool, prismatic limits)"))
    pris = prismatic.detach().cpu().bool()
    stroke = (limits[:, 1] - limits[:, 0]).detach().to("cpu", torch.float64)
    short = [j for j in range(len(pris)) if bool(pris[j]) and float(stroke[j]) < MIN_STROKE_MM]
    if short and reach >= MIN_REACH_MM and not urdf:  # a slide in metres among links in mm
        j = short[0]
        lo, hi = limits[j].tolist()
        warnings.warn(f"{where}: joints[{j + 1}] (prismatic) travels only {hi - lo:.4g} mm ({lo:g}..{hi:g}): "
                      f"the limits look like metres ({1000 * lo:g}..{1000 * hi:g} mm if they are); robot files "
                      "take millimetres (lower, upper)", RobotUnitWarning, stacklevel=4)
    if reach < MIN_REACH_MM:
        raise InputError(f"{where}: the links reach only {reach:.4g} mm in all (sum of sqrt(d_mm^2 + a_mm^2)), less "
                         f"than any industrial arm's {MIN_REACH_MM:g} mm: the lengths look like metres; robot files "
                         "take millimetres (d_mm, a_mm, base, tool, prismatic limits)")


class RobotUnitWarning(UserWarning):
    """A robot file's value looks written in another unit (one joint's limits in radians)."""


def check_robot_angles(table, prismatic, limits, where: str = "robot file") -> None:
    """InputError for angles a robot file holds in radians where it takes degrees:
    table (n, 5) [theta, d, a, alpha, beta] rad and limits (n, 2) (rad for a revolute
    joint) as read from the file's degrees (module docstring). Every revolute joint's
    limits within +-2 pi "degrees" (an arm whose joints all turn less than 6.3 deg); or a
    twist alpha or offset theta within 1e-3 of pi / 2 or pi "degrees" while none lies
    beyond 2 pi "degrees" (90 deg written as 1.5708). Some revolute joints' limits within
    +-2 pi "degrees" and the others' beyond: one `RobotUnitWarning` naming the first."""
    t = torch.rad2deg(table.detach().to("cpu", torch.float64))
    rev = ~prismatic.detach().cpu().bool()
    lim = torch.rad2deg(limits.detach().to("cpu", torch.float64))[rev]
    if lim.numel() and float(lim.abs().max()) <= 2 * math.pi + 0.01:
        raise InputError(f"{where}: every revolute joint's limits lie within +-{float(lim.abs().max()):.4g} deg: "
                         "they look like radians; robot files take degrees (lower, upper)")
    turn = lim.abs().amax(-1)  # (revolute joints,) the farthest each turns, "deg"
    narrow = (turn <= 2 * math.pi + 0.01).nonzero().flatten().tolist()
    if narrow:  # some joints in radians, the others in degrees (a URDF's values copied in)
        j = int(rev.nonzero().flatten()[narrow[0]])
        lo, hi = lim[narrow[0]].tolist()
        more = f" (and {len(narrow) - 1} more joint(s))" if len(narrow) > 1 else ""
        warnings.warn(f"{where}: joints[{j + 1}] limits {lo:.6g}..{hi:.6g} deg{more} look like radians "
                      f"({math.degrees(lo):.4g}..{math.degrees(hi):.4g} deg if they are), while the other joints "
                      f"turn up to {float(turn.max()):.4g} deg; robot files take degrees (lower, upper)",
                      RobotUnitWarning, stacklevel=4)
    ang = t[:, [0, 3]]  # theta offsets and twists, deg
    if float(ang.abs().max()) <= 2 * math.pi + 0.01:
        near = [(j, k, float(ang[j, c])) for j in range(ang.shape[0]) for c, k in enumerate(("theta_offset_deg",
                                                                                            "alpha_deg"))
                if min(abs(abs(float(ang[j, c])) - math.pi / 2), abs(abs(float(ang[j, c])) - math.pi)) < 1e-3]
        if near:
            j, k, v = near[0]
            raise InputError(f"{where}: joints[{j + 1}].{k} = {v:.6g}: pi/2 or pi written in radians (and no angle "
                             "of the file beyond 6.3 deg); robot files take degrees (e.g. 90, not 1.5708)")


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
    quick = _frame_fit(model, ctx, m.xyz, start, free)
    if quick is not None:
        return quick
    res = fit(model, ctx, m.xyz, theta0=start, free=free, register=False, max_length_mm=None, max_angle_deg=None)
    return (m.xyz - res.residuals).detach()


def _frame_and_tool(model):
    """(the base_frame effect, its slice, the tool_offset's slice) of a model of exactly
    base_frame and a single tool_offset (one offset for every point), else None: the models
    whose nominal points the tool offset moves linearly (`_frame_fit`, `_frame_bound_mm`)."""
    names = [e.name for e in model.effects]
    if sorted(names) != ["base_frame", "tool_offset"] or model.effects[names.index("tool_offset")].points:
        return None
    i, j = names.index("base_frame"), names.index("tool_offset")
    return model.effects[i], model.slices[1 + i], model.slices[1 + j]


def _frame_fit(model, ctx, xyz: torch.Tensor, start: torch.Tensor, free: torch.Tensor):
    """`_in_frame`'s fit without the kinematic chain in its loop: the predicted points (N, 3)
    mm, or None where it does not apply (then `fit` does it). For a model of exactly
    base_frame and a single tool_offset (every other parameter held at zero, no prior:
    what `fit` solves for `_in_frame`) the points are ``R(r) (c + A u) + t``, c (N, 3) the
    nominal points (base frame) and A (N, 3, 3) their derivative w.r.t. the tool offset u
    (the chain's flange rotations: u enters linearly), both taken once from the model; the
    same Levenberg-Marquardt (`torchcal.calibration.lm`, `fit`'s max_iter) on the same
    residuals and Jacobian from the same start, so the same fit to rounding (a frame fit of
    a refused file runs 20-60 iterations, each of which walked the chain twice or more).
    None too when the identifiability analysis `fit` runs would hold a parameter; the
    same InputError as `fit` for too few rows."""
    from torchcal.calibration.identifiability import check_enough_rows, identifiability
    from torchcal.calibration.lm import levenberg_marquardt

    parts = _frame_and_tool(model)
    if parts is None:
        return None
    frame, frame_sl, tool_sl = parts
    J0 = model.jacobian(start, ctx)  # (N, 3, P) at the start, as `fit`'s identifiability takes it
    report = identifiability(J0, model.param_names(), free, first=torch.ones_like(free))
    if not torch.equal(report.free.cpu(), free.cpu()):
        return None
    check_enough_rows(report, 3 * xyz.shape[0], model, ctx, free)  # `fit`'s refusal of too few rows
    zero = start.clone()
    zero[frame_sl] = 0.0
    zero[tool_sl] = 0.0
    with torch.no_grad():
        c = model.predict(zero, ctx)  # (N, 3) base frame, no tool offset
    A = torch.einsum("ji,njk->nik", frame._rotation(start[frame_sl][3:6]), J0[:, :, tool_sl])  # R0^T dv/du
    n, P = xyz.shape[0], start.shape[0]

    def points(z):
        u = z[tool_sl]
        return c + (A @ u.unsqueeze(-1)).squeeze(-1)

    def res_fn(x):
        z = x[0]
        return (frame.world(z[frame_sl], ctx, points(z)) - xyz).reshape(1, -1)

    def jac_fn(x):
        z = x[0]
        dp, dv = frame.world_jacobian(z[frame_sl], ctx, points(z))
        J = xyz.new_zeros(n, 3, P)
        J[:, :, frame_sl] = dp
        J[:, :, tool_sl] = dv @ A
        return J.reshape(1, n * 3, P)

    res = levenberg_marquardt(res_fn, start.unsqueeze(0), free=free.to(start.device), jacobian_fn=jac_fn,
                              max_iter=60)
    z = res.x[0]
    with torch.no_grad():
        return frame.world(z[frame_sl], ctx, points(z)).detach()


def _registered(model, m):
    """`_in_frame` of `model` with base_frame and tool_offset (appended where missing)."""
    from torchcal.calibration.registration import with_frame

    return _in_frame(with_frame(model, model.zeros(), tool=True)[0], m)


def _quick_rms(model, ctx, xyz: torch.Tensor) -> float:
    """RMS (mm) of the nominal `model` as it is or, when it has base_frame, after the
    closed-form rigid motion (no solve): within GROSS_MM is the common case, decided
    cheaply; a frame and tool offset fitted could only come closer."""
    from torchcal.calibration.registration import kabsch

    with torch.no_grad():
        p = model.predict(model.zeros().to(xyz), ctx)
    if "base_frame" in [e.name for e in model.effects] and p.shape[0] >= 3:
        R, t = kabsch(p, xyz)
        p = p @ R.T + t
    return _rms((p - xyz).norm(dim=-1))


SESSION_FLOOR_MM = 2.0  # one frame's rms below this: no search for a moved instrument within GROSS_MM
SESSION_RATIO = 3.0  # each part's own frame must come this many times closer than one frame through both


def moved_within_gross(model, m, quick_mm: float, pred: torch.Tensor | None = None) -> Mismatch | None:
    """Two measuring frames in one file that one frame and tool offset fit within GROSS_MM
    (an instrument moved by a few mm or a fraction of a degree between two sessions, or
    midway through one): None, or a 'mismatch' naming the parts. Judged only for a model
    with base_frame whose one-frame rms (`quick_mm`, then that of the registered points
    `pred` (N, 3) mm, `_registered`'s, computed when None) exceeds
    SESSION_FLOOR_MM: a part fits when its own frame and tool offset leave at most 1 /
    SESSION_RATIO of the one-frame rms (`joined_sessions` at restarting pose ids, else
    `changed_midway`). Single sessions of the simulated titan and UR10 series B and D come
    1.0-1.2 times closer at their best cut, a 0.5 deg move 12.6 times."""
    import dataclasses

    if "base_frame" not in [e.name for e in model.effects] or quick_mm <= SESSION_FLOOR_MM:
        return None
    if pred is None:
        pred = _registered(model, m)
    reg = _rms((pred - m.xyz).norm(dim=-1))
    if reg <= SESSION_FLOOR_MM:
        return None
    bound = reg / SESSION_RATIO

    def fits(mm):
        return _rms((_registered(model, mm) - mm.xyz).norm(dim=-1)) <= bound

    what, name = m.source or "data", model.robot.name
    join = joined_sessions(m, fits)
    cut = join if join is not None else changed_midway(m, fits)
    if cut is None:
        return None
    how = (f"(pose ids restart at {int(m.pose[cut])}): two sessions joined, the instrument moved between them; "
           "calibrate on one, or register each (torchcal register)" if join is not None else
           f": the instrument moved or the reflector was changed midway, by data row {cut + 1} (pose id "
           f"{int(m.pose[cut])}) at the latest; calibrate on one part and register the other (torchcal register)")
    parts = [m.subset(torch.arange(a, b)) for a, b in ((0, cut), (cut, len(m)))]
    each = " and ".join(f"{_rms((_registered(model, p) - p.xyz).norm(dim=-1)):.4g}" for p in parts)
    msg = (f"{what}: two measuring frames in one file: one frame and tool offset for {name} leave rms {reg:.4g} mm, "
           f"but rows 1..{cut} and {cut + 1}..{len(m)} (data rows) leave {each} mm in a frame and with a tool "
           f"offset of their own{'' if join is None else ' '}{how}")
    return dataclasses.replace(check_points(pred, m.xyz, None, what), rms_mm=reg,
                               registered_rms_mm=reg, verdict="mismatch", message=msg)


def column_mistakes(m, robot):
    """Yield (phrase, Measurements) for each one-column mistake in the joint values of `m`
    (q (N, n) rad / mm): two adjacent q columns swapped, one revolute column in radians
    read as degrees, one column negated (another sign convention), one revolute column
    shifted by +-90 or 180 deg (another zero position, e.g. a controller's against the
    MD-H table's). The rows' predecessors follow the changed q (their row order)."""
    import dataclasses

    def changed(q):
        return dataclasses.replace(m, q=q, q_prev=None)

    n = robot.n
    for j in range(n - 1):
        q = m.q.clone()
        q[:, [j, j + 1]] = q[:, [j + 1, j]]
        yield f"columns q{j + 1} and q{j + 2} swapped", changed(q)
    rev = (~robot.prismatic.cpu()).tolist()
    for j in range(n):
        if rev[j]:
            q = m.q.clone()
            q[:, j] = q[:, j] * (180.0 / math.pi)
            yield f"column q{j + 1} in radians (read as degrees)", changed(q)
    for j in range(n):
        q = m.q.clone()
        q[:, j] = -q[:, j]
        yield f"column q{j + 1} negated (another sign convention)", changed(q)
    for j in range(n):
        if rev[j]:
            for deg in (90, -90, 180):
                q = m.q.clone()
                q[:, j] = q[:, j] + math.radians(deg)
                yield f"column q{j + 1} shifted by {deg:+d} deg (another zero position)", changed(q)


HINT_ROWS = 60  # rows (evenly spread over the file) that judge a one-column mistake


def column_hint(m, robot, fits, score=None, tries: int = 2) -> str | None:
    """The first `column_mistakes` phrase whose corrected data `fits` (a predicate on
    `Measurements`) accepts, else None: data refused as another robot that are this robot's
    with one joint column mixed up. Judged on HINT_ROWS rows spread over the file. With
    `score` (a cheap float of `Measurements`, lower is closer) only the `tries` best-scored
    mistakes go to `fits` (an expensive predicate: the refusal stays quick)."""
    if len(m) > HINT_ROWS:
        m = m.subset(torch.linspace(0, len(m) - 1, HINT_ROWS).round().long())
    cands = list(column_mistakes(m, robot))
    if score is not None:
        cands = sorted(cands, key=lambda c: score(c[1]))[:tries]
    for phrase, fixed in cands:
        try:
            if fits(fixed):
                return phrase
        except InputError:
            continue
    return None


JOINS = 3  # at most this many pose-id restarts are tried as the joint between two sessions


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


LAGS = (1, -1, 2, -2)  # row offsets between the joint values and the positions that are tried


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


def _lag_words(lag: int) -> str:
    """The end of the line naming a `row_lag` (rows whose positions are `lag` rows off)."""
    return (f"each row's x, y, z taken from {abs(lag)} row(s) {'further down' if lag > 0 else 'further up'}: the "
            "positions are misaligned with the joint values (two logs joined with a row more in one); check the rows")


def _fits(model, m) -> bool:
    try:
        if _frame_bound_mm(model, m) > GROSS_MM * (1 + 1e-6):  # no frame and tool can fit: no solve
            return False
        return _rms((_registered(model, m) - m.xyz).norm(dim=-1)) <= GROSS_MM
    except InputError:
        return False


def _frame_bound_mm(model, m) -> float:
    """A lower bound (mm) of the RMS that `_registered` can reach: of min over R in SO(3),
    t, u of the RMS of ``R (c_i + A_i u) + t - x_i`` (c (N, 3) the nominal points, A (N, 3, 3)
    their derivative w.r.t. the tool offset u, x the measured points), for a model of
    base_frame and a single tool_offset once the frame is added (else 0: no bound).
    Rotating each residual by R^T leaves its length: for fixed R the best u and R^T t are
    linear least squares, so the sum of squares is ``f(r) = |Q (X r - c)|^2``, a quadratic
    in r = vec(R) (9,) (Q projects out the columns of [A_i, I]). Relaxing R to
    ``|r|^2 = 3`` (every rotation has it) bounds it from below, and for any lam below the
    smallest eigenvalue of G = X^T Q X, ``f(r) >= 3 lam - b^T (G - lam I)^-1 b + c^T Q c``
    (b = X^T Q c; Lagrangian duality), the tightest such lam found by bisection. Any local
    minimum the fit's solver reaches lies at or above it: a bound beyond GROSS_MM refuses
    a candidate with the verdict the solve would give (on the refusals of
    tests/test_mismatch.py it rules out 108 of the 109 candidates beyond it)."""
    from torchcal.calibration.registration import frame_slices, with_frame
    from torchcal.effects import context_of

    model = with_frame(model, model.zeros(), tool=True)[0]
    parts = _frame_and_tool(model)
    if parts is None or len(m) < 3:
        return 0.0
    ctx = context_of(model.robot, m)
    model.check_context(ctx)
    tool_sl = parts[2]
    zero = model.zeros().to(m.xyz)
    with torch.no_grad():
        c = model.predict(zero, ctx).to(torch.float64).cpu()  # (N, 3)
        A = model.jacobian(zero, ctx)[:, :, tool_sl].to(torch.float64).cpu()  # (N, 3, 3)
    x = m.xyz.detach().to("cpu", torch.float64)
    n = x.shape[0]
    basis, _ = torch.linalg.qr(torch.cat([A, torch.eye(3, dtype=x.dtype).expand(n, 3, 3)], -1).reshape(3 * n, 6))

    def proj(v):  # v (3N, k) with the columns of [A_i, I] projected out
        return v - basis @ (basis.T @ v)

    X = torch.zeros(n, 3, 3, 3, dtype=x.dtype)  # (R^T x_i)_a = sum_b R[b, a] x_ib: r[3 b + a] = R[b, a]
    for a in range(3):
        X[:, a, :, a] = x
    QX, Qc = proj(X.reshape(3 * n, 9)), proj(c.reshape(-1, 1))
    w, V = torch.linalg.eigh(QX.T @ QX)
    bb = (V.T @ (QX.T @ Qc)).flatten()
    k = float((Qc * Qc).sum())
    w0 = float(w[0])

    def norm2(lam):  # |(G - lam I)^-1 b|^2
        return float(((bb / (w - lam)) ** 2).sum())

    def bound(lam):
        return 3 * lam - float((bb ** 2 / (w - lam)).sum()) + k

    step = 1.0 + abs(w0)
    lo, hi = w0 - step, w0 - 1e-12 * step
    if norm2(hi) <= 3:  # the maximum of the dual at lam -> w0: the bound there
        lam = hi
    else:
        while norm2(lo) > 3:
            step *= 2
            lo = w0 - step
        for _ in range(100):
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if norm2(mid) > 3 else (mid, hi)
        lam = lo
    return math.sqrt(max(bound(lam), 0.0) / n)


def shared_rows(a, b) -> list[int]:
    """0-based rows of the measurements `b` whose joint values and x, y, z equal, to the
    last bit, those of a row of `a` (the same measurement, copied: two sessions never
    repeat a reading exactly)."""
    seen = {tuple(r) for r in torch.cat([a.q, a.xyz], dim=1).detach().cpu().tolist()}
    return [i for i, r in enumerate(torch.cat([b.q, b.xyz], dim=1).detach().cpu().tolist()) if tuple(r) in seen]


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
    what = m.source or "data"
    name = model.robot.name
    try:
        ctx = context_of(model.robot, m)
        model.check_context(ctx)
        quick = _quick_rms(model, ctx, m.xyz)
        if quick <= GROSS_MM:
            return moved_within_gross(model, m, quick)
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
            return moved_within_gross(model, m, reg, pred)
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
            ids = _listed(int(m.pose[i]) for i in far)
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
    def kabsch_rms(mm):  # the nominal robot rigidly moved onto the data: no solve
        from torchcal.calibration.registration import kabsch

        with torch.no_grad():
            p = model.predict(model.zeros().to(mm.xyz), context_of(model.robot, mm))
        R, t = kabsch(p, mm.xyz)
        return _rms((p @ R.T + t - mm.xyz).norm(dim=-1))

    def fits(mm):  # the nominal robot in a frame of its own: within GROSS_MM
        return _fits(model, mm)

    join = joined_sessions(m, fits)
    if join is not None:
        return result("mismatch", f"{what}: cannot come from {name} in one measuring frame: rms {reg:.4g} mm with the "
                      f"best frame and tool offset, but rows 1..{join} and {join + 1}..{len(m)} (data rows; pose ids "
                      f"restart at {int(m.pose[join])}) each fit within {GROSS_MM:g} mm in a frame of their own: two "
                      "sessions joined, the instrument moved between them; calibrate on one, or register each "
                      "(torchcal register)")
    lag = row_lag(m, fits)
    change = None if lag is not None else changed_midway(m, fits)
    if change is not None:
        at = f"data row {change + 1} (pose id {int(m.pose[change])})"
        return result("mismatch", f"{what}: cannot come from {name} in one measuring frame with one tool: rms "
                      f"{reg:.4g} mm with the best frame and tool offset, but rows 1..{change} and {change + 1}.."
                      f"{len(m)} each fit within {GROSS_MM:g} mm in a frame and with a tool offset of their own: the "
                      f"instrument moved or the reflector was changed midway, by {at} at the latest; give the rows "
                      "from the change a point id of their own (another reflector), or calibrate on one part and "
                      "register the other (torchcal register)")
    if lag is not None:
        return result("mismatch", f"{what}: cannot come from {name} as given: rms {reg:.4g} mm with the best measuring "
                      f"frame and tool offset, but within {GROSS_MM:g} mm with {_lag_words(lag)}")
    hint = column_hint(m, model.robot, fits, score=kabsch_rms)
    if hint is not None:
        return result("mismatch", f"{what}: cannot come from {name} as given: rms {reg:.4g} mm with the best measuring "
                      f"frame and tool offset, but within {GROSS_MM:g} mm with the joint {hint}: check the "
                      "joint columns")
    s_x, s_p = spread_mm(m.xyz), spread_mm(pred)
    causes = "data of another robot or units (length or angle unit)"
    if abs(math.log(max(s_x, 1e-12) / max(s_p, 1e-12))) < math.log(1.1):  # the same size: no unit mistake
        causes = ("the spreads agree within 10 %, so no unit: data of another robot of that size, or many "
                  f"corrupted rows (more than the {OUTLIER_SHARE:.0%} a robust fit sets aside)")
    return result("mismatch", f"{what}: cannot come from {name}: rms {reg:.4g} mm with the best measuring frame "
                  f"and tool offset, point spread {s_x:.4g} mm measured vs {s_p:.4g} mm modelled; likely causes: "
                  f"{causes}{_units_hint(s_x / max(s_p, 1e-12))}")

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


def check_robot_data_of(model, m, robust: bool | None = None):
    """Refuse (InputError, one line naming the cause) measurements `m` that the nominal
    robot of `model` cannot explain, or that need a measuring frame the model lacks
    (`check_robot_data`; robust: True when a robust fit follows, False for a fit without,
    None for a command without a robust loss), or whose rx, ry, rz do not describe its tool
    (`orientation_mismatch`); fit, diagnose and discover call it."""
    found = check_robot_data(model, m, robust=robust)
    if found is not None:
        return enforce(found)
    msg = orientation_mismatch(model, m)
    if msg is not None:
        raise InputError(msg)
    return None


ORIENT_DEG = 5.0  # rms angle (deg) between measured and nominal tool orientations beyond which they are not the robot's


def _orientation_rms_deg(nominal: torch.Tensor, measured: torch.Tensor, frame: torch.Tensor,
                         rounds: int = 10) -> float:
    """RMS angle (deg) between measured rotations Rm (N, 3, 3) and the nominal ones A
    (N, 3, 3) as F A X, with the measuring-frame rotation F (from `frame` (3, 3), the
    positions' Kabsch) and the constant tool rotation X refined in turn (Procrustes each,
    `rounds` times): a large unknown tool offset, which tilts the positions' F, does not
    count."""
    from torchcal.rotations import nearest_rotation, procrustes_rotation, so3_error

    F = frame
    for _ in range(rounds):
        x = procrustes_rotation(F @ nominal, measured)
        F = nearest_rotation((measured @ (nominal @ x).transpose(-1, -2)).sum(0))
    a = F @ nominal
    x = procrustes_rotation(a, measured)
    return math.degrees(_rms(so3_error(a @ x, measured).norm(dim=-1)))


def orientation_readings(rxyz: torch.Tensor):
    """Yield (phrase, (N, 3, 3) rotations) for other readings of rx, ry, rz (N, 3) as read
    (fixed-axis XYZ in degrees, held in rad): radians read as degrees, intrinsic
    (moving-axis) XYZ angles, a rotation vector (axis-angle, as UR controllers report the
    TCP pose), each in degrees or in radians read as degrees."""
    from torchcal.rotations import fixed_xyz_to_matrix, rotvec_to_matrix

    def intrinsic(r):  # R = Rx(rx) Ry(ry) Rz(rz), each factor a fixed-axis rotation about one axis
        zero = torch.zeros_like(r[:, 0])
        return (fixed_xyz_to_matrix(torch.stack([r[:, 0], zero, zero], -1))
                @ fixed_xyz_to_matrix(torch.stack([zero, r[:, 1], zero], -1))
                @ fixed_xyz_to_matrix(torch.stack([zero, zero, r[:, 2]], -1)))

    for scale, unit in ((1.0, ""), (180.0 / math.pi, " in radians (read as degrees)")):
        r = rxyz * scale
        if scale != 1.0:
            yield f"fixed-axis XYZ angles{unit}", fixed_xyz_to_matrix(r)
        yield f"intrinsic (moving-axis) XYZ angles{unit}", intrinsic(r)
        yield f"a rotation vector (axis-angle, as UR controllers report){unit}", \
            torch.stack([rotvec_to_matrix(v) for v in r])


def orientation_mismatch(model, m) -> str | None:
    """One line when the measured orientations of `m` (rx, ry, rz) cannot be the tool frames
    of `model`'s nominal robot: the RMS angle between them, after the measuring frame's
    rotation (Kabsch on the positions, which agree: `check_robot_data`) and the best
    constant tool rotation (the fit's Procrustes step), beyond ORIENT_DEG = 5 deg (an
    uncalibrated arm is within a degree or so). The line names the reading that fits
    (`orientation_readings`), if one does. None for data without rx, ry, rz, fewer than 3
    rows, or when they agree."""
    from torchcal.calibration.registration import kabsch

    if m.rxyz is None or len(m) < 3:
        return None
    rob = model.robot
    with torch.no_grad():
        q = m.q.to(rob.device, rob.dtype)
        pose = rob.fk_pose(q).detach().to("cpu", torch.float64)  # (N, 4, 4) the nominal tool frames
    nominal, p = pose[:, :3, :3], pose[:, :3, 3]
    frame, _ = kabsch(p, m.xyz.detach().to("cpu", torch.float64))
    measured = m.rotation.detach().to("cpu", torch.float64)
    rms = _orientation_rms_deg(nominal, measured, frame)
    if rms <= ORIENT_DEG:
        return None
    hint = next((phrase for phrase, R in orientation_readings(m.rxyz.detach().to("cpu", torch.float64))
                 if _orientation_rms_deg(nominal, R, frame) <= ORIENT_DEG), None)
    what = m.source or "data"
    cause = f"they look like {hint}" if hint is not None else "another angle convention or unit?"
    return (f"{what}: rx, ry, rz disagree with the tool orientation of {rob.name} by rms {rms:.4g} deg after the best "
            f"measuring-frame and tool rotations (an uncalibrated arm is within a degree or so): {cause}; rx, ry, rz "
            "are fixed-axis XYZ angles, R = Rz(rz) Ry(ry) Rx(rx), in the angle unit (or drop the three columns)")


def check_diagnosis_data(robot_or_model, model, m):
    """The gross-mismatch check of `diagnose`: a fitted model (`FitResult`) as it is (a moved
    frame only warns: the diagnosis refits it), else the nominal robot of `model`
    (`CalibrationModel`) with the frame effects it has (`check_robot_data_of`)."""
    from torchcal.calibration.fit import FitResult
    from torchcal.calibration.model import CalibrationModel

    if isinstance(robot_or_model, FitResult):
        res = check_measurements(model, robot_or_model.theta, m, robot_or_model.training_rms_mm,
                                 q_range=robot_or_model.q_range)
        return enforce(res, refuse_frame=False, refuse_mismatch=True)
    return check_robot_data_of(CalibrationModel.for_measurements(model.robot, model.specs(), m), m)


def check_target_conditions(model, targets: torch.Tensor, payload_kg=None, temp_c=None,
                            where: str = "targets") -> None:
    """InputError naming the effect of `model` that needs a condition (temp_c, payload_kg)
    the targets (M, 3) mm lack."""
    from torchcal.effects import make_context

    rob = model.robot
    probe = make_context(rob, rob.limits.mean(-1).expand(targets.shape[0], rob.n), payload_kg, temp_c)
    for e in model.effects:
        try:
            e.check_context(probe)
        except InputError as exc:
            if e.name == "tool_offset":  # one offset per reflector: which one is each target's?
                raise InputError(f"{where}: the model has one tool offset per reflector (points "
                                 f"{', '.join(map(str, e.points))}) and targets name no reflector; compensate "
                                 f"with a model fitted on the rows of one point") from None
            need = "column temp_c" if e.name == "thermal_expansion" else str(exc)
            raise InputError(f"{where}: the model's effect {e.spec()} needs {need} "
                             f"in the targets, which they lack") from None


def range_warning(q: torch.Tensor, q_range: torch.Tensor | None, robot, what: str | None = "rows",
                  max_joints: int = 3) -> tuple[int, str | None]:
    """(number of rows of q (N, n) rad / mm outside q_range, one-line message or None).

    q_range None (a model file written before torchcal recorded it): (0, None). The
    message names each offending joint (up to `max_joints`) with its farthest value and
    the calibrated range, in deg (mm for a prismatic joint); `what` None: those joints alone."""
    from torchcal.calibration.joint_range import outside_range

    if q_range is None or q.shape[0] == 0:
        return 0, None
    out = outside_range(q, q_range, robot.prismatic)  # (N, n)
    rows = int(out.any(1).sum())
    if rows == 0:
        return 0, None
    r = q_range.to(q)
    dist = torch.where(out, torch.maximum(r[0] - q, q - r[1]), torch.full_like(q, -1.0))
    worst = dist.argmax(0)  # (n,) row farthest outside per joint
    qu = robot.q_to_user(q.detach().to("cpu", torch.float64))
    ru = robot.q_to_user(r.detach().to("cpu", torch.float64))
    units = robot.joint_units()
    joints = out.any(0).nonzero().flatten().tolist()
    parts = [f"joint {j + 1}: {qu[int(worst[j]), j].item():.1f} {units[j]}, calibrated "
             f"{ru[0, j].item():.1f} .. {ru[1, j].item():.1f} {units[j]}" for j in joints[:max_joints]]
    more = f"; and {len(joints) - max_joints} more joint(s)" if len(joints) > max_joints else ""
    if what is None:  # the joints alone
        return rows, f"{'; '.join(parts)}{more}"
    msg = (f"{rows} of {q.shape[0]} {what} lie outside the calibrated joint range "
           f"({'; '.join(parts)}{more}); the model extrapolates there")
    return rows, msg


def warn_outside_range(q: torch.Tensor, q_range, robot, what: str, stage=None, stacklevel: int = 1) -> int:
    """Rows of q (N, n) rad / mm outside the calibrated range q_range (2, n) (None: not
    recorded, 0); one `CalibratedRangeWarning` when any (saying so when a residual stage
    `stage` is applied there). stacklevel: as for `warnings.warn`, counted from the caller."""
    from torchcal.calibration.joint_range import CalibratedRangeWarning

    count, msg = range_warning(q, q_range, robot, what)
    if msg is not None and stage is not None:
        msg += "; its non-physical residual stage extrapolates worst of all"
    if msg is not None:
        warnings.warn(msg, CalibratedRangeWarning, stacklevel=stacklevel + 1)
    return count


def warn_outside_conditions(ranges: dict | None, values: dict, what: str, stacklevel: int = 1) -> int:
    """Rows (`what`: "rows", "targets", ...) whose temperature or payload `values`
    ({"temp_c", "payload_kg"}: (N,) tensors, numbers or None) lie outside the range the
    model was fitted on (`ranges`: FitResult.conditions; None: not recorded, 0); one
    `ConditionRangeWarning` naming each such condition, its fitted range, how many rows
    and the farthest value. Returns the most rows outside for one condition."""
    from torchcal.calibration.joint_range import ConditionRangeWarning, conditions_outside

    found = conditions_outside(ranges, values)
    if not found:
        return 0
    parts = [f"{words} of {n_out} of {n} {what} outside the fitted {lo:.4g} .. {hi:.4g} {unit} (farthest {far:.4g} {unit})"
             for words, unit, lo, hi, n_out, n, far in found]
    warnings.warn(f"{'; '.join(parts)}: the model extrapolates its {' and '.join(f[0] for f in found)} "
                  f"effects there", ConditionRangeWarning, stacklevel=stacklevel + 1)
    return max(f[4] for f in found)
