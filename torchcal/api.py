"""The one way in: ``torchcal.fit(robot_or_model, measurements, effects=...)`` and the same
shape for `evaluate`, `diagnose`, `discover`, `calibrate` and `compensate`.

Forgiving entry, strict kernels: the first argument may be a preset name or robot file
(``"kr1000titan"``), a `Robot`, a `CalibrationModel` or a fitted model (`FitResult`, or a
MODEL.json path for `evaluate` / `compensate`); measurements may be a `Measurements` or the
path of a measurement CSV (docs/formats.md). Every result is a dataclass whose
``to_dict()`` is the JSON the command line writes. Argument order: robot or model
first, then data, then options; ``seed`` is always a random seed, ``q0`` a starting
joint vector (M, n) rad. Units: mm and rad inside, as everywhere in torchcal.

Example::

    import torchcal
    res = torchcal.fit("kr1000titan", "data.csv", effects=["joint_compliance:2,3"])
    print(res.status, res.rms_mm)
    print(torchcal.evaluate(res, "test.csv").to_dict())
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import torch

from torchcal.calibration.fit import SIGMA_DEG, SIGMA_MM, FitResult
from torchcal.calibration.plausibility import MAX_ANGLE_DEG, MAX_LENGTH_MM
from torchcal.calibration.model import CalibrationModel
from torchcal.errors import InputError
from torchcal.measurements import Measurements
from torchcal.robots.robot import Robot, robot as make_robot

__all__ = ["fit", "evaluate", "diagnose", "discover", "calibrate", "compensate", "Evaluation"]


def _robot(robot_or_model) -> Robot:
    if isinstance(robot_or_model, FitResult):
        return robot_or_model.model.robot
    if isinstance(robot_or_model, CalibrationModel):
        return robot_or_model.robot
    if isinstance(robot_or_model, (str, Path, Robot)):
        return make_robot(robot_or_model)
    raise InputError(f"robot_or_model: expected a preset name, a robot file, a Robot, a CalibrationModel or a "
                     f"FitResult, got {type(robot_or_model).__name__}")


def _model(robot_or_model, effects=()) -> CalibrationModel:
    """A `CalibrationModel`; `effects` only with a robot (a model already has its own)."""
    if isinstance(robot_or_model, (CalibrationModel, FitResult)):
        model = robot_or_model if isinstance(robot_or_model, CalibrationModel) else robot_or_model.model
        if effects:
            raise InputError("effects: given with a CalibrationModel or a fitted model, which has its own effects "
                             f"[{', '.join(model.specs())}]; pass a robot instead")
        return model
    return CalibrationModel(_robot(robot_or_model), [str(s) for s in effects])


def _fitted(model_or_fit):
    """(CalibrationModel, theta (P,)) of a FitResult, a MODEL.json path or (model, theta)."""
    if isinstance(model_or_fit, FitResult):
        return model_or_fit.model, model_or_fit.theta
    if isinstance(model_or_fit, (str, Path)) and str(model_or_fit).endswith(".json"):
        from torchcal.io.modelfile import load
        return load(model_or_fit)
    if isinstance(model_or_fit, tuple) and len(model_or_fit) == 2 and isinstance(model_or_fit[0], CalibrationModel):
        return model_or_fit
    raise InputError(f"model: expected a FitResult, a MODEL.json path or (CalibrationModel, theta), "
                     f"got {type(model_or_fit).__name__}")


def _q_range(model_or_fit, cm: CalibrationModel):
    """(2, n) calibrated joint range rad / mm of a fitted model, or None (unknown)."""
    if isinstance(model_or_fit, FitResult):
        return model_or_fit.q_range
    return getattr(cm, "calibrated_range", None)


def _warn_range(q: torch.Tensor, q_range, robot: Robot, what: str) -> int:
    """Rows of q (N, n) rad / mm outside the calibrated range; one `CalibratedRangeWarning` when any."""
    import warnings

    from torchcal.calibration.joint_range import CalibratedRangeWarning, range_warning

    count, msg = range_warning(q, q_range, robot, what)
    if msg is not None:
        warnings.warn(msg, CalibratedRangeWarning, stacklevel=3)
    return count


def _measurements(measurements, robot: Robot) -> Measurements:
    if isinstance(measurements, Measurements):
        return measurements
    if isinstance(measurements, (str, Path)):
        from torchcal.io.measurement_csv import read_measurements
        return read_measurements(measurements, robot=robot)
    raise InputError(f"measurements: expected Measurements or a CSV path, got {type(measurements).__name__}")


def fit(robot_or_model, measurements, effects=(), robust: str | None = None, max_iter: int = 60,
        sigma_mm: float = SIGMA_MM, sigma_deg: float = SIGMA_DEG, max_length_mm: float | None = MAX_LENGTH_MM,
        max_angle_deg: float | None = MAX_ANGLE_DEG) -> FitResult:
    """Fit the geometric deviations plus `effects` to measured TCP positions (and
    orientations, when the measurements carry rx, ry, rz).

    robust: None, 'huber' or 'cauchy' (IRLS). sigma_mm / sigma_deg: measurement
    uncertainties (mm, deg) that weigh orientation against position. max_length_mm /
    max_angle_deg: the plausible scales of the MD-H deviations, the prior of the fit
    (None: no prior on them; `torchcal.calibration.plausibility`).
    Measurements with several `point` ids need `tool_offset` (one offset per point).
    Returns a `FitResult` (``.theta``, ``.status``, ``.rms_mm``, ``.to_dict()`` = the
    MODEL.json of ``torchcal fit``).
    """
    from torchcal.calibration.fit import fit as fit_model
    from torchcal.effects import context_of

    robot = _robot(robot_or_model)
    m = _measurements(measurements, robot)
    if isinstance(robot_or_model, (CalibrationModel, FitResult)):
        model = _model(robot_or_model, effects)
    else:
        model = CalibrationModel.for_measurements(robot, effects, m)
    ctx = context_of(model.robot, m)
    return fit_model(model, ctx, m.xyz, robust=robust, max_iter=max_iter, pose=m.pose, rotation=m.rotation,
                     sigma_mm=sigma_mm, sigma_deg=sigma_deg, max_length_mm=max_length_mm,
                     max_angle_deg=max_angle_deg)


@dataclass(frozen=True)
class Evaluation:
    """Distance errors measured - model: n rows; rms_mm, mean_mm, max_mm; per_axis_rms_mm
    [x, y, z]; orientation_rms_deg when the data carry rx, ry, rz and the model was fitted
    to orientations (else None); outside_range: rows whose commanded q lie outside the
    joint range the model was calibrated on (`torchcal.calibration.joint_range`), None
    when the model does not record it (a MODEL.json written before it existed)."""

    n: int
    rms_mm: float
    mean_mm: float
    max_mm: float
    per_axis_rms_mm: list
    orientation_rms_deg: float | None = None
    outside_range: int | None = None

    def to_dict(self) -> dict:
        """{"n", "rms_mm", "mean_mm", "max_mm", "per_axis_rms_mm"[, "orientation_rms_deg"]
        [, "outside_range"]}: the JSON of ``torchcal evaluate --json``."""
        out = {"n": self.n, "rms_mm": self.rms_mm, "mean_mm": self.mean_mm, "max_mm": self.max_mm,
               "per_axis_rms_mm": list(self.per_axis_rms_mm)}
        if self.orientation_rms_deg is not None:
            out["orientation_rms_deg"] = self.orientation_rms_deg
        if self.outside_range is not None:
            out["outside_range"] = self.outside_range
        return out


def evaluate(model, measurements) -> Evaluation:
    """Errors of a fitted model (FitResult, MODEL.json path or (model, theta)) on measurements.

    Rows outside the model's calibrated joint range are counted (``outside_range``) and
    named in one `CalibratedRangeWarning` (the model extrapolates there)."""
    import math

    from torchcal.calibration.fit import _so3_error
    from torchcal.effects import context_of

    cm, theta = _fitted(model)
    m = _measurements(measurements, cm.robot)
    ctx = context_of(cm.robot, m)
    cm.check_context(ctx)
    theta = theta.to(m.xyz)
    err = m.xyz - cm.predict(theta, ctx)  # (N, 3) mm
    d = err.norm(dim=-1)
    orient = None
    tool_r = getattr(cm, "tool_rotation", None)
    if m.rxyz is not None and tool_r is not None:
        e = _so3_error(cm.predict_rotation(theta, ctx) @ tool_r.to(theta), m.rotation)  # (N, 3) rad
        orient = math.degrees(float(e.norm(dim=-1).pow(2).mean().sqrt()))
    q_range = _q_range(model, cm)
    outside = None if q_range is None else _warn_range(m.q, q_range, cm.robot, "rows")
    return Evaluation(len(m), float(d.pow(2).mean().sqrt()), float(d.mean()), float(d.max()),
                      err.pow(2).mean(0).sqrt().tolist(), orient, outside)


def diagnose(robot_or_model, measurements, effects=(), folds: int = 5, seed: int = 0, **options):
    """Rank the physical effects missing from the model (`torchcal.diagnosis.diagnose.diagnose`);
    a `CalibrationModel` contributes its robot and effects. Returns a `Diagnosis`."""
    from torchcal.diagnosis.diagnose import diagnose as run

    model = _model(robot_or_model, effects)
    return run(model.robot, _measurements(measurements, model.robot), model.specs(), folds=folds, seed=seed,
               **options)


def discover(robot_or_model, measurements, effects=(), folds: int = 5, seed: int = 0, **options):
    """Add the best significant missing effect each round (`torchcal.diagnosis.diagnose.discover`).
    Returns a `Discovery`."""
    from torchcal.diagnosis.diagnose import discover as run

    model = _model(robot_or_model, effects)
    return run(model.robot, _measurements(measurements, model.robot), model.specs(), folds=folds, seed=seed,
               **options)


def calibrate(robot_or_model, measurements, effects=(), partition=None, zone_method: str = "damped",
              damping="gcv_shared"):
    """Interval calibration, global or per zone (`torchcal.workflows.zones.calibrate`).

    partition: a `Partition`, a PARTITION.json path or None. Returns an `IntervalModel`
    (`torchcal.io.interval_model.interval_model_to_dict` gives the MODEL.json of ``torchcal
    calibrate``) whose ``global_fit`` is the global `IntervalFit`.
    """
    from torchcal.workflows.zones import calibrate as run

    model = _model(robot_or_model, effects)
    if isinstance(partition, (str, Path)):
        from torchcal.io.partition_file import load_partition
        partition = load_partition(partition)
    im, glob = run(model, _measurements(measurements, model.robot), partition, zone_method, damping)
    im.global_fit = glob
    return im


def compensate(model, targets, q0=None, **options):
    """Corrected joint commands (M, n) rad for target positions (M, 3) mm.

    model: a fitted model (FitResult, MODEL.json path, (model, theta)) or an
    `IntervalModel` (targets assigned to its zones). q0: (M, n) rad starting commands,
    default the nominal inverse from the middle of the joint limits. Returns a
    `Compensation`; converged solutions outside the model's calibrated joint range are
    counted (``outside_range``) and named in one `CalibratedRangeWarning`.
    """
    from torchcal.calibration.compensate import compensate as run, nominal_inverse
    from torchcal.calibration.intervals import IntervalModel

    if isinstance(model, IntervalModel):
        cm, theta = model.model, model.theta
        q_range = model.q_range
    else:
        cm, theta = _fitted(model)
        q_range = _q_range(model, cm)
    robot = cm.robot
    t = torch.as_tensor(targets, dtype=robot.dtype, device=robot.device)
    if t.ndim != 2 or t.shape[-1] != 3:
        raise InputError(f"targets: expected (M, 3) mm, got shape {tuple(t.shape)}")
    if q0 is None:
        q0 = nominal_inverse(robot, t).q
    zone = model.assign(t) if isinstance(model, IntervalModel) else None
    comp = run(cm, theta.to(t), t, q0, zone=zone, **options)
    if q_range is None:
        return comp
    outside = _warn_range(comp.q[comp.converged], q_range, robot, "converged targets")
    return replace(comp, outside_range=outside)
