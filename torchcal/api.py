"""The one way in: ``torchcal.fit(robot_or_model, measurements, effects=...)`` and the same
shape for `evaluate`, `diagnose`, `discover`, `calibrate`, `compensate` and `register`.

Forgiving entry, strict kernels: the first argument may be a preset name or robot file
(``"kr1000titan"``), a `Robot`, a `CalibrationModel` or a fitted model (`FitResult`, or a
MODEL.json path for `evaluate` / `compensate`); measurements may be a `Measurements` or the
path of a measurement CSV (docs/formats.md). Every result is a dataclass whose
``to_dict()`` is the JSON the command line writes; a fitted model (`FitResult`) is
written by `save` (MODEL.json) and read by `load`. Argument order: robot or model
first, then data, then options; ``seed`` is always a random seed, ``q0`` a starting
joint vector (M, n) rad. Units: mm and rad inside, as everywhere in torchcal.

Example::

    import torchcal
    res = torchcal.fit("kr1000titan", "data.csv", effects=["joint_compliance:2,3"])
    print(res.status, res.rms_mm)
    print(torchcal.evaluate(res, "test.csv").to_dict())
    torchcal.save(res, "model.json")
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import torch

from torchcal import threads
from torchcal.calibration.fit import SIGMA_DEG, SIGMA_MM, FitResult
from torchcal.calibration.plausibility import MAX_ANGLE_DEG, MAX_LENGTH_MM
from torchcal.calibration.model import CalibrationModel
from torchcal.errors import InputError
from torchcal.measurements import Measurements
from torchcal.io.robot_file import robot as make_robot
from torchcal.robots.robot import Robot

__all__ = ["fit", "load", "save", "evaluate", "diagnose", "discover", "calibrate", "compensate", "register", "Evaluation",
           "compensate_targets", "TargetCompensation", "export", "Export", "accuracy", "simulate", "Simulation"]


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


def _fitted(model) -> FitResult:
    """The fitted model: a `FitResult` (a `ZonedFit` too) as it is, a MODEL.json path
    loaded into one (`torchcal.io.modelfile.load`)."""
    if isinstance(model, FitResult):
        return model
    if isinstance(model, (str, Path)) and str(model).endswith(".json"):
        return load(model)
    raise InputError(f"model: expected a FitResult (a fitted model) or a MODEL.json path, "
                     f"got {type(model).__name__}")


def load(path, *, robot=None) -> FitResult:
    """The fitted model of a MODEL.json (`torchcal.io.modelfile.load`): parameters,
    effects, settings, tool rotation, calibrated range, covariance, residual stage; a
    `ZonedFit` for the MODEL.json of a per-zone ``calibrate``.
    robot: a `Robot`, preset name or robot file the model must be for (None: no check)."""
    from torchcal.io.modelfile import load as read

    return read(path, robot=robot)


def save(res: FitResult, path, *, source=None, seed: int = 0, pose_ids=None, force: bool = False,
         partition_source=None):
    """Write the fitted model `res` (a `ZonedFit` too) as MODEL.json at `path` (the layout of
    `torchcal.io.modelfile.to_dict`, what ``torchcal fit --out`` and ``calibrate --out``
    write; `load` reads it back): atomically, an existing file only with force, never over
    `source` (the data it was fitted on, recorded with its hash) or `partition_source` (the
    PARTITION.json of a per-zone calibration, recorded). Returns the path."""
    from torchcal.io.files import write_json
    from torchcal.io.modelfile import to_dict

    obj = to_dict(res, source=source, seed=seed, pose_ids=pose_ids, partition_source=partition_source)
    return write_json(path, obj, force=force, inputs=[p for p in (source, partition_source) if p is not None])


def _warn_range(q: torch.Tensor, q_range, robot: Robot, what: str, stage=None) -> int:
    """Rows of q (N, n) rad / mm outside the calibrated range; one `CalibratedRangeWarning` when any
    (saying so when a residual stage `stage` is applied there)."""
    import warnings

    from torchcal.calibration.joint_range import CalibratedRangeWarning, range_warning

    count, msg = range_warning(q, q_range, robot, what)
    if msg is not None and stage is not None:
        msg += "; its non-physical residual stage extrapolates worst of all"
    if msg is not None:
        warnings.warn(msg, CalibratedRangeWarning, stacklevel=3)
    return count


def _measurements(measurements, robot: Robot, length_unit: str = "mm", angle_unit: str = "deg") -> Measurements:
    if isinstance(measurements, Measurements):
        return measurements
    if isinstance(measurements, (str, Path)):
        from torchcal.io.measurement_csv import read_measurements
        return read_measurements(measurements, robot=robot, length_unit=length_unit, angle_unit=angle_unit)
    raise InputError(f"measurements: expected Measurements or a CSV path, got {type(measurements).__name__}")


def _work(model: CalibrationModel, m: Measurements) -> int:
    """Elements of the largest tensors of a fit of `model` to `m` (its Jacobian), for the
    thread policy (`torchcal.threads.for_work`)."""
    return 3 * m.q.shape[0] * model.n_params


def fit(robot_or_model, measurements, effects=(), *, robust: str | None = None, max_iter: int = 60,
        sigma_mm: float = SIGMA_MM, sigma_deg: float = SIGMA_DEG, max_length_mm: float | None = MAX_LENGTH_MM,
        max_angle_deg: float | None = MAX_ANGLE_DEG, length_unit: str = "mm", angle_unit: str = "deg",
        residual_model: str | None = None) -> FitResult:
    """Fit the geometric deviations plus `effects` to measured TCP positions (and
    orientations, when the measurements carry rx, ry, rz).

    robust: None, 'huber' or 'cauchy' (IRLS). sigma_mm / sigma_deg: measurement
    uncertainties (mm, deg) that weigh orientation against position. max_length_mm /
    max_angle_deg: the plausible scales of the MD-H deviations, the prior of the fit
    (each None drops its own prior only; `torchcal.calibration.plausibility`).
    Measurements with several `point` ids need `tool_offset` (one offset per point).
    length_unit ('mm' or 'm') / angle_unit ('deg' or 'rad'): the units of the measurement
    file (a path is read in them; `Measurements` were read in them). Before fitting, the
    unit check (`torchcal.calibration.plausibility.check_units`) refuses data that look like
    metres read as mm or radians read as degrees with one InputError line, the line the
    command line prints; so does the gross-mismatch check of the nominal robot
    (`check_robot_data_of`: another frame the model lacks, another robot, units, a
    mirrored frame, reversed joint columns, gross outliers without `robust`) and, after
    the fit, a fitted RMS beyond what any calibration leaves
    (`torchcal.calibration.mismatch.check_fitted`).
    residual_model: 'kernel' adds the non-physical residual stage
    (`torchcal.calibration.residual_model`) as ``res.residual_model`` only when its held-out
    gain is significant (`torchcal.diagnosis.residual_stage`, the figures in
    ``res.residual_test``; None otherwise); evaluate and compensate apply it.
    Returns a `FitResult` (``.theta``, ``.status``, ``.rms_mm``); `save` writes it as the
    MODEL.json of ``torchcal fit``, `load` reads it back.
    """
    from torchcal.calibration.fit import fit as fit_model
    from torchcal.calibration.mismatch import check_fitted
    from torchcal.effects import context_of

    from torchcal.calibration.plausibility import check_units

    robot = _robot(robot_or_model)
    m = _measurements(measurements, robot, length_unit, angle_unit)
    check_units(m, robot, length_unit=length_unit, angle_unit=angle_unit, where=m.source or "measurements")
    if isinstance(robot_or_model, (CalibrationModel, FitResult)):
        model = _model(robot_or_model, effects)
    else:
        model = CalibrationModel.for_measurements(robot, effects, m)
    ctx = context_of(model.robot, m)
    model.check_context(ctx)  # a missing column first, in the fit's own words
    with threads.for_work(_work(model, m)):
        check_robot_data_of(model, m, robust=robust is not None)  # another frame, robot, units, outliers
        res = fit_model(model, ctx, m.xyz, robust=robust, max_iter=max_iter, pose=m.pose, rotation=m.rotation,
                         sigma_mm=sigma_mm, sigma_deg=sigma_deg, max_length_mm=max_length_mm,
                         max_angle_deg=max_angle_deg)
    gross = check_fitted(res.residuals, res.outliers, m.source or "data", model.robot.name)
    if gross:
        raise InputError(gross)
    if residual_model is not None:
        _add_stage(res, m, ctx, residual_model)
    return res


def _add_stage(res: FitResult, m: Measurements, ctx, kind: str, folds: int = 5, seed: int = 0) -> None:
    """The residual stage on `res` when its held-out test passes (`residual_test` holds the figures)."""
    from torchcal.diagnosis.residual_stage import stage_test

    t = stage_test(res, m, ctx, kind=kind, folds=folds, seed=seed, sigma_mm=res.sigma_mm, sigma_deg=res.sigma_deg)
    res.residual_model, res.residual_test = t.stage, t.to_dict()


@dataclass(frozen=True)
class Evaluation:
    """Distance errors measured - model: n rows; rms_mm, mean_mm, max_mm; per_axis_rms_mm
    [x, y, z]; orientation_rms_deg when the data carry rx, ry, rz and the model was fitted
    to orientations (else None); outside_range: rows whose commanded q lie outside the
    joint range the model was calibrated on (`torchcal.calibration.joint_range`), None
    when the model does not record it (a MODEL.json written before it existed).

    Per row (not in `to_dict`): residuals_mm (N, 3) measured - model; orientation_deg
    (N,) orientation error angle, deg (None as for orientation_rms_deg); outside (N,)
    bool, the row lies outside the calibrated range (None as for outside_range)."""

    n: int
    rms_mm: float
    mean_mm: float
    max_mm: float
    per_axis_rms_mm: list
    orientation_rms_deg: float | None = None
    outside_range: int | None = None
    residuals_mm: torch.Tensor | None = field(default=None, compare=False, repr=False)
    orientation_deg: torch.Tensor | None = field(default=None, compare=False, repr=False)
    outside: torch.Tensor | None = field(default=None, compare=False, repr=False)
    p95_mm: float | None = None

    def to_dict(self) -> dict:
        """{"n", "rms_mm", "mean_mm", "p95_mm", "max_mm", "per_axis_rms_mm"[, "orientation_rms_deg"]
        [, "outside_range"]}: the JSON of ``torchcal evaluate --json`` (`torchcal.metrics.error_summary`)."""
        out = {"n": self.n, "rms_mm": self.rms_mm, "mean_mm": self.mean_mm, "p95_mm": self.p95_mm,
               "max_mm": self.max_mm, "per_axis_rms_mm": list(self.per_axis_rms_mm)}
        if self.orientation_rms_deg is not None:
            out["orientation_rms_deg"] = self.orientation_rms_deg
        if self.outside_range is not None:
            out["outside_range"] = self.outside_range
        return out


def evaluate(model, measurements) -> Evaluation:
    """Errors of a fitted model (`FitResult`, or a MODEL.json path) on measurements.

    Data that cannot come from the model (another robot, a moved measuring frame, units;
    `torchcal.calibration.mismatch`) are refused with one InputError line.

    Rows outside the model's calibrated joint range are counted (``outside_range``) and
    named in one `CalibratedRangeWarning` (the model extrapolates there)."""
    import math

    from torchcal.metrics import error_summary
    from torchcal.rotations import so3_error
    from torchcal.effects import context_of

    from torchcal.calibration.mismatch import check_measurements, enforce

    fm = _fitted(model)
    cm = fm.model
    m = _measurements(measurements, cm.robot)
    ctx = context_of(cm.robot, m)
    cm.check_context(ctx)
    theta = fm.theta.to(m.xyz)
    enforce(check_measurements(cm, theta, m, fm.training_rms_mm))  # another robot, frame, units
    stage = fm.residual_model
    err = m.xyz - fm.predict(ctx)  # (N, 3) mm (each row in its zone); minus the residual stage's correction
    if stage is not None:
        err = err - stage.predict(m.q).to(err)
    fig = error_summary(err)
    orient = orient_rows = None
    tool_r = fm.tool_rotation
    if m.rxyz is not None and tool_r is not None:
        e = so3_error(cm.predict_rotation(theta, ctx) @ tool_r.to(theta), m.rotation)  # (N, 3) rad
        orient = math.degrees(float(e.norm(dim=-1).pow(2).mean().sqrt()))
        orient_rows = torch.rad2deg(e.norm(dim=-1)).detach()
    q_range = fm.q_range
    outside = None if q_range is None else _warn_range(m.q, q_range, cm.robot, "rows", stage)
    rows_out = None
    if q_range is not None:
        from torchcal.calibration.joint_range import outside_range
        rows_out = outside_range(m.q, q_range, cm.robot.prismatic).any(dim=-1)
    return Evaluation(len(m), fig["rms_mm"], fig["mean_mm"], fig["max_mm"], [fig["axes"][a]["rms_mm"] for a in "xyz"],
                      orient, outside, err.detach(), orient_rows, rows_out, fig["p95_mm"])


def _set(**options) -> dict:
    """The options that were given (None: the callee's own default)."""
    return {k: v for k, v in options.items() if v is not None}


def diagnose(robot_or_model, measurements, effects=(), *, folds: int = 5, seed: int = 0, alpha: float | None = None,
             min_gain: float | None = None, sigma_mm: float = SIGMA_MM, sigma_deg: float = SIGMA_DEG):
    """Rank the physical effects missing from the model (`torchcal.diagnosis.diagnose.diagnose`);
    a `CalibrationModel` contributes its robot and effects. folds: cross-validation folds;
    seed: random seed of the fold assignment; alpha: family-wise error level of the tests,
    min_gain: least relative gain in held-out error for an effect to count (None: the
    defaults of `torchcal.diagnosis`); sigma_mm / sigma_deg: measurement uncertainties that
    weigh orientation against position, as in `fit`. Returns a `Diagnosis`.

    Data that no registration of the model (a `FitResult`) or of the nominal robot brings
    near the measurements are refused (InputError: another robot, units), and so are data
    in a measuring frame the effects lack (`check_robot_data_of`: add base_frame
    tool_offset); a fitted model whose measuring frame moved gives a `MismatchWarning`
    (the diagnosis refits the frame)."""
    from torchcal.diagnosis.diagnose import diagnose as run

    model = _model(robot_or_model, effects)
    m = _measurements(measurements, model.robot)
    check_diagnosis_data(robot_or_model, model, m)
    with threads.for_work(_work(model, m)):
        return run(model.robot, m, model.specs(), folds=folds, seed=seed, sigma_mm=sigma_mm, sigma_deg=sigma_deg,
                   **_set(alpha=alpha, min_gain=min_gain))


def check_diagnosis_data(robot_or_model, model: CalibrationModel, m: Measurements):
    """The gross-mismatch check of `diagnose`: a fitted model (`FitResult`) as it is, else
    the nominal robot (`check_robot_data_of`)."""
    from torchcal.calibration.mismatch import check_measurements, enforce

    if isinstance(robot_or_model, FitResult):
        res = check_measurements(model, robot_or_model.theta, m, robot_or_model.training_rms_mm)
        return enforce(res, refuse_frame=False, refuse_mismatch=True)
    return check_robot_data_of(CalibrationModel.for_measurements(model.robot, model.specs(), m), m)


def check_robot_data_of(model: CalibrationModel, m: Measurements, robust: bool | None = None):
    """Refuse (InputError, one line naming the cause) measurements that the nominal robot
    of `model` cannot explain, or that need a measuring frame the model lacks
    (`torchcal.calibration.mismatch.check_robot_data`; robust: True when a robust fit
    follows, False for a fit without, None for a command without a robust loss); fit,
    diagnose and discover call it."""
    from torchcal.calibration.mismatch import check_robot_data, enforce

    found = check_robot_data(model, m, robust=robust)
    return None if found is None else enforce(found)


def discover(robot_or_model, measurements, effects=(), *, folds: int = 5, seed: int = 0,
             max_rounds: int | None = None, alpha: float | None = None, sigma_mm: float = SIGMA_MM,
             sigma_deg: float = SIGMA_DEG, transfer=None, transfer_poses: int = 30,
             residual_model: str | None = None):
    """Add the accepted missing effect each round (`torchcal.diagnosis.diagnose.discover`),
    for at most max_rounds rounds; folds, seed, alpha, sigma_mm, sigma_deg as in `diagnose`
    (None: the defaults of `torchcal.diagnosis`). Data the nominal robot cannot explain,
    or that need a measuring frame the effects lack, are refused as by `diagnose`.
    transfer: measurements of another session (Measurements or CSV path) as a check: a
    step is kept only when it does not raise that session's error after registration on
    its first `transfer_poses` poses (`torchcal.diagnosis.transfer`). residual_model:
    'kernel' adds the residual stage to the final model when its held-out test passes, as
    `fit` does (``.fit.residual_test`` holds the figures). Returns a `Discovery`."""
    from torchcal.diagnosis.diagnose import discover as run
    from torchcal.diagnosis.transfer import TransferCheck
    from torchcal.effects import context_of

    model = _model(robot_or_model, effects)
    m = _measurements(measurements, model.robot)
    check_robot_data_of(CalibrationModel.for_measurements(model.robot, model.specs(), m), m)
    other = None if transfer is None else _measurements(transfer, model.robot)
    check = None if other is None else TransferCheck(other, transfer_poses, other.source or "the other session")
    with threads.for_work(_work(model, m)):
        res = run(model.robot, m, model.specs(), folds=folds, seed=seed, sigma_mm=sigma_mm, sigma_deg=sigma_deg,
                  transfer=check, **_set(max_rounds=max_rounds, alpha=alpha))
        if residual_model is not None:
            _add_stage(res.fit, m, context_of(model.robot, m), residual_model, folds, seed)
    return res


def calibrate(robot_or_model, measurements, effects=(), *, partition=None, zone_method: str = "damped",
              damping="gcv_shared"):
    """Interval calibration, global or per zone (`torchcal.calibration.zone_calibration.calibrate`).

    partition: a `Partition`, a PARTITION.json path or None. Returns the global interval
    fit (a `FitResult` with ``radius``), with a partition a `ZonedFit` (the global fit and
    one fit per zone); `save` writes it as the MODEL.json of ``torchcal calibrate``.
    """
    from torchcal.calibration.zone_calibration import calibrate as run

    model = _model(robot_or_model, effects)
    if isinstance(partition, (str, Path)):
        from torchcal.io.partition_file import load_partition
        partition = load_partition(partition)
    m = _measurements(measurements, model.robot)
    with threads.for_work(_work(model, m)):
        return run(model, m, partition, zone_method, damping)


def _with_stage(stage, cm, theta, t, comp, zone, options, max_rounds: int = 10):
    """Compensation through physical model + residual stage: solve the physical model for
    the target minus the stage's correction at the current solution, until the correction
    changes by at most tol_mm (it varies slowly with q: a few rounds)."""
    from torchcal.calibration.compensate import compensate as run

    tol = float(options.get("tol_mm", 1e-6))
    corr = stage.predict(comp.q).to(t)
    for _ in range(max_rounds):
        comp = run(cm, theta, t - corr, comp.q, zone=zone, **options)
        new = stage.predict(comp.q).to(t)
        moved = float((new - corr).norm(dim=-1).max()) if len(t) else 0.0
        corr = new
        if moved <= tol:
            break
    pred = comp.predicted_mm + corr
    res = t - pred
    return replace(comp, predicted_mm=pred, residual_mm=res, converged=comp.converged & (res.norm(dim=-1) <= tol))


def compensate(model, targets, q0=None, *, tol_mm: float = 1e-6, max_iter: int = 30, max_step_rad: float = 0.2,
               payload_kg=None, temp_c=None, check: bool = True):
    """Corrected joint commands (M, n) rad for target positions (M, 3) mm.

    model: a fitted model (`FitResult`, or a MODEL.json path; a `ZonedFit`'s targets are
    assigned to its zones). targets: in the model's measuring
    frame. q0: (M, n) rad starting commands, default
    `torchcal.calibration.compensate.nominal_start` (the nominal inverse in the measuring
    frame from the nearest calibration pose, as the command line seeds it; a target it
    does not reach is still tried and ends not converged). tol_mm,
    max_iter, max_step_rad: the Newton solve (`torchcal.calibration.compensate.compensate`);
    payload_kg, temp_c: (M,) conditions of the moves, for load and temperature effects. Returns a
    `Compensation`; converged solutions outside the model's calibrated joint range are
    counted (``outside_range``) and named in one `CalibratedRangeWarning`. check: targets
    inside the robot's base (metres read as mm) are refused, targets beyond its reach
    named in a `MismatchWarning` (`torchcal.calibration.mismatch.check_targets`). A model
    with a residual stage (``model.residual_model``) is
    inverted with it (the physical model is solved for the target minus the stage's
    correction, repeated until it settles).
    """
    from torchcal.calibration.compensate import compensate as run, nominal_start

    model = _fitted(model)
    cm, theta, q_range, stage = model.model, model.theta, model.q_range, model.residual_model
    robot = cm.robot
    t = torch.as_tensor(targets, dtype=robot.dtype, device=robot.device)
    if t.ndim != 2 or t.shape[-1] != 3:
        raise InputError(f"targets: expected (M, 3) mm, got shape {tuple(t.shape)}")
    if check:
        from torchcal.calibration.mismatch import check_targets
        check_targets(cm, theta, t)
    if q0 is None:
        q0 = nominal_start(cm, theta, t, poses=model.seed_poses, q_range=q_range).q
    zone = model.assign(t) - 1  # row of zone_theta
    theta = model.zone_theta
    comp = run(cm, theta.to(t), t, q0, zone=zone, tol_mm=tol_mm, max_iter=max_iter, max_step_rad=max_step_rad,
               payload_kg=payload_kg, temp_c=temp_c)
    if stage is not None:
        options = dict(tol_mm=tol_mm, max_iter=max_iter, max_step_rad=max_step_rad, payload_kg=payload_kg,
                       temp_c=temp_c)
        comp = _with_stage(stage, cm, theta.to(t), t, comp, zone, options)
    if q_range is None:
        return comp
    outside = _warn_range(comp.q[comp.converged], q_range, robot, "converged targets", stage)
    return replace(comp, outside_range=outside)


def register(model, measurements, *, tool: bool = False) -> FitResult:
    """Re-estimate only the measuring frame of a fitted model on new measurements: the
    base frame, and the tool offset when `tool` (`torchcal.calibration.registration.reregister`).

    model: a fitted model (`FitResult` or a MODEL.json path), whose geometry, effects,
    covariance, calibrated joint range, settings, tool rotation, residual stage and
    training rms are kept; or a robot
    (preset name, robot file, `Robot`): a registration-only model (nominal geometry in
    the best frame), calibrated on these rows. Data that no frame brings near the model
    (another robot, units) are refused (InputError, `torchcal.calibration.mismatch`).
    Returns a `FitResult` whose ``rms_mm`` and ``residuals`` are those on `measurements`
    and whose ``registration`` records the frame and the rms before and after. An rms
    above 3x the model's training rms is a `TransferWarning`
    (`torchcal.calibration.registration.far_from_training`).
    """
    from torchcal.calibration.joint_range import joint_range
    from torchcal.calibration.mismatch import check_measurements, enforce
    from torchcal.calibration.registration import TransferWarning, far_from_training, reregister
    from torchcal.effects import context_of

    fm = _fitted(model) if _is_model(model) else None
    if fm is not None:
        cm, theta, train, cov = fm.model, fm.theta, fm.training_rms_mm, fm.covariance
        identified, q_range = fm.report.free, fm.q_range
    else:
        robot = _robot(model)
        cm, theta, train, cov, identified, q_range = CalibrationModel(robot), None, None, None, None, None
    m = _measurements(measurements, cm.robot)
    if theta is None:  # registration only: the nominal robot, calibrated on these rows
        cm = CalibrationModel.for_measurements(cm.robot, ["base_frame"] + (["tool_offset"] if tool else []), m)
        theta, identified, q_range = cm.zeros(), torch.zeros(cm.n_params, dtype=torch.bool), joint_range(m.q)
    ctx = context_of(cm.robot, m)
    cm.check_context(ctx)
    if len(m) < 3:
        raise InputError(f"{m.source or 'measurements'}: registration needs at least 3 rows, got {len(m)}")
    res = reregister(cm, theta.to(m.xyz), ctx, m.xyz, tool=tool, pose=m.pose, covariance=cov,
                     identified=identified, q_range=q_range)
    enforce(check_measurements(res.model, res.theta, m, train))  # still off: another robot, units
    far = far_from_training(res.rms_mm, train)
    if far is not None:
        warnings.warn(far, TransferWarning, stacklevel=2)
    if fm is None:
        return res
    return replace(res, orientation=fm.orientation, robust=fm.robust, sigma_mm=fm.sigma_mm, sigma_deg=fm.sigma_deg,
                   seed_poses=fm.seed_poses,
                   residual_model=fm.residual_model, training=fm.training, provenance=fm.provenance,
                   set_by_prior=fm.set_by_prior, residual_test=fm.residual_test)


def _is_model(obj) -> bool:
    """True for a fitted model (FitResult, a MODEL.json path), False for a robot."""
    if isinstance(obj, FitResult):
        return True
    if isinstance(obj, (str, Path)) and str(obj).endswith(".json") and Path(obj).is_file():
        from torchcal.io.files import read_json
        from torchcal.io.modelfile import FORMAT, FORMAT_RAD

        return read_json(obj, "model or robot file").get("format") in (FORMAT, FORMAT_RAD)
    return False


def _sources(model) -> list:
    """Paths the model came from, as it records them: its data (provenance ``input``,
    ``partition``) and the URDF its robot was imported from."""
    out = [(model.provenance or {}).get(k) for k in ("input", "partition")]
    urdf = model.model.robot.urdf
    return [p for p in out + [urdf and urdf.get("path")] if p]


@dataclass
class TargetCompensation:
    """What ``torchcal compensate`` computes and writes: the corrected commands of a
    targets file, each with the zone it was compensated in.

    Attributes:
        targets: (M, 3) mm target positions in `frame`.
        compensation: the `Compensation` (q rad / mm, residuals, convergence, limits).
        zone: (M,) 1-based zone of each target (1 for a single-set model).
        q_user: (M, n) corrected commands in deg (mm for a prismatic joint).
        n_zones, method: the model's parameter sets and how it was calibrated ("fit" for
            a fitted model).
        robot: the robot's name.
        beyond_reach: 0-based rows of targets beyond the robot's reach (named, not refused).
        frame: the frame the targets were given in, "measuring" or "base".
    """

    targets: torch.Tensor
    compensation: object
    zone: torch.Tensor
    q_user: torch.Tensor
    n_zones: int
    method: str
    robot: str
    beyond_reach: list = field(default_factory=list)
    frame: str = "measuring"

    @property
    def residual_mm(self) -> torch.Tensor:
        """(M,) mm distance from the calibrated model's position to each target."""
        return self.compensation.residual_mm.norm(dim=-1)

    @property
    def not_converged(self) -> list:
        """0-based rows that did not meet the tolerance."""
        return (~self.compensation.converged).nonzero().flatten().tolist()

    @property
    def outside_limits(self) -> list:
        """0-based rows whose command lies outside the joint limits."""
        return (~self.compensation.within_limits).nonzero().flatten().tolist()

    @property
    def failed(self) -> list:
        """0-based rows that did not converge or lie outside the joint limits."""
        return sorted(set(self.not_converged) | set(self.outside_limits))

    def to_csv(self) -> str:
        """Q.csv text (`torchcal.io.targets_csv.compensation_csv`)."""
        from torchcal.io.targets_csv import compensation_csv

        c = self.compensation
        return compensation_csv(self.zone, self.q_user, self.residual_mm, c.converged, c.within_limits)

    def to_dict(self) -> dict:
        """Q.csv's rows and the failures (1-based rows), JSON types."""
        c, res = self.compensation, self.residual_mm.tolist()
        rows = [{"point": i + 1, "zone": int(self.zone[i]), "q": self.q_user[i].tolist(), "residual_mm": res[i],
                 "converged": bool(c.converged[i]), "within_limits": bool(c.within_limits[i])}
                for i in range(self.targets.shape[0])]
        return {"robot": self.robot, "frame": self.frame, "n_zones": self.n_zones, "method": self.method,
                "targets": rows,
                "max_residual_mm": max(res), "outside_range": c.outside_range,
                "not_converged": [i + 1 for i in self.not_converged],
                "outside_limits": [i + 1 for i in self.outside_limits],
                "beyond_reach": [i + 1 for i in self.beyond_reach]}


def compensate_targets(model, targets, *, frame: str = "measuring", robot=None, length_unit: str = "mm",
                       angle_unit: str = "deg", seeds=None, payload_kg=None, temp_c=None) -> TargetCompensation:
    """``torchcal compensate``: corrected joint commands for a targets file or tensor.

    model: a MODEL.json path of ``torchcal fit`` or ``torchcal calibrate``, or a fitted
    model (`FitResult`; of a `ZonedFit` each target is compensated with its zone's
    parameters). targets: a TARGETS.csv path
    (`torchcal.io.targets_csv.read_targets`; its seeds and conditions are used, units per
    `length_unit` / `angle_unit`) or (M, 3) mm. frame: the frame the targets are in,
    "measuring" (the model's measuring frame: the tracker's when it has a base_frame
    effect) or "base" (the robot base frame, mapped to the measuring frame with the
    fitted base frame of the first parameter set,
    `torchcal.calibration.compensate.measuring_from_base`). robot: optional robot (preset,
    file, Robot) the model must be for (InputError otherwise). seeds: (M, n) deg (mm for a
    slide) starting commands for tensor targets, default the nominal inverse in the
    measuring frame from the nearest calibration pose
    (`torchcal.calibration.compensate.nominal_start`; a target it does not reach is still
    tried, and reported per row); payload_kg, temp_c: (M,) conditions for tensor targets.
    Targets inside the robot's base or around the origin of their frame (metres read as
    mm) are refused; those beyond its reach are listed in ``beyond_reach``. A model effect that needs a condition the targets lack is
    refused naming it. Converged commands outside the calibrated range: one
    `CalibratedRangeWarning`.
    """
    import warnings

    from torchcal.calibration.compensate import FRAMES, measuring_from_base, nominal_start
    from torchcal.calibration.mismatch import MismatchWarning, check_targets
    from torchcal.effects import make_context
    from torchcal.io.robot_file import check_same_robot

    where = str(targets) if isinstance(targets, (str, Path)) else "targets"
    if frame not in FRAMES:
        raise InputError(f"frame: expected one of {', '.join(FRAMES)}, got {frame!r}")
    im = _fitted(model)
    rob = im.model.robot
    if robot is not None:
        check_same_robot(rob, make_robot(robot), str(model) if isinstance(model, (str, Path)) else "model")
    if isinstance(targets, (str, Path)):
        from torchcal.io.targets_csv import read_targets

        t, seeds, cond = read_targets(targets, rob.n, length_unit=length_unit, angle_unit=angle_unit,
                                      prismatic=rob.prismatic)
        payload_kg, temp_c = cond["payload_kg"], cond["temp_c"]
    else:
        t = torch.as_tensor(targets, dtype=torch.float64)
        if t.ndim != 2 or t.shape[-1] != 3:
            raise InputError(f"targets: expected (M, 3) mm, got shape {tuple(t.shape)}")
    # the model's effects must find what they read (temp_c, payload_kg) in the targets
    probe = make_context(rob, rob.limits.mean(-1).expand(t.shape[0], rob.n), payload_kg, temp_c)
    for e in im.model.effects:
        try:
            e.check_context(probe)
        except InputError as exc:
            need = "column temp_c" if e.name == "thermal_expansion" else str(exc)
            raise InputError(f"{where}: the model's effect {e.spec()} needs {need} "
                             f"in the targets, which they lack") from None
    given = t
    if frame == "base":  # the solve is in the measuring frame, where the model predicts
        R, o = measuring_from_base(im.model, im.theta.to(t))
        t = t @ R.T + o
    with warnings.catch_warnings():  # metres read as mm: refused; beyond the reach: listed
        warnings.simplefilter("ignore", MismatchWarning)
        far = check_targets(im.model, im.theta, t, where=where)
    q0 = nominal_start(im.model, im.theta, t, poses=im.seed_poses, q_range=im.q_range).q if seeds is None else \
        rob.q_from_user(torch.as_tensor(seeds))
    comp = compensate(im, t, q0, check=False, payload_kg=payload_kg, temp_c=temp_c)
    from torchcal.calibration.zone_calibration import ZonedFit

    method = im.method if isinstance(im, ZonedFit) else ("global" if im.radius is not None else "fit")
    return TargetCompensation(given, comp, im.assign(t), rob.q_to_user(comp.q), im.zone_theta.shape[0], method,
                              rob.name, far, frame)


@dataclass
class Export:
    """What ``torchcal export`` computed and wrote.

    Attributes:
        robot: the calibrated `Robot` of the robot file (geometry, base frame and tool offset
            folded in; its ``urdf`` names the written URDF when that URDF has the same chain).
        effects_not_held: [{"spec", "parameters"}] of the model's effects that a robot file, a
            URDF or an MD-H table cannot hold (listed in the robot file; empty after a refit).
        residual_stage_dropped: the model had a non-physical residual stage, which is not exported.
        refit: the `GeometryRefit` on `data` (the geometry alone refitted), else None.
        data_rows: rows of `data` refitted on (None: no refit; data are read only when the
            model has effects the exported robot cannot hold).
        urdf_source: the nominal URDF whose links the calibrated URDF keeps, None for a minimal URDF.
        written: {"robot_file", "urdf", "table"} paths written (None: not asked).
        urdf_links: {"base_link", "tip_link", "frames"} of the written URDF (its base and
            tool links, the names of its separate measuring frames), None without a URDF.
    """

    robot: Robot
    effects_not_held: list
    residual_stage_dropped: bool
    refit: object
    data_rows: int | None
    urdf_source: str | None
    written: dict
    urdf_links: dict | None = None

    def to_dict(self) -> dict:
        r = self.refit
        return {"robot": self.robot.name, "joints": self.robot.n, "written": dict(self.written),
                "effects_not_held": [e["spec"] for e in self.effects_not_held],
                "residual_stage_dropped": self.residual_stage_dropped,
                "urdf": None if self.urdf_links is None else dict(self.urdf_links, source=self.urdf_source),
                "refit": None if r is None else {"rows": self.data_rows, "dropped": list(r.dropped),
                                                 "refit_rms_mm": r.refit_rms_mm, "full_rms_mm": r.full_rms_mm,
                                                 "naive_rms_mm": r.naive_rms_mm, "status": str(r.fit.status)}}


def export(model, *, robot_file=None, urdf=None, table=None, data=None, length_unit: str = "mm",
           angle_unit: str = "deg", force: bool = False) -> Export:
    """``torchcal export``: the calibrated geometry of a model as a robot file, a URDF and/or
    an MD-H table (CSV, `torchcal.io.mdh_table`).

    model: a MODEL.json path (fit or calibrate) or a fitted model (of a `ZonedFit` the
    global fit). The MD-H deviations go into the table, base_frame into
    the base, tool_offset into the tool (`torchcal.calibration.geometry_only.calibrated_robot`).
    Other effects: with `data` (Measurements or CSV path in `length_unit` / `angle_unit`) the
    geometry alone is refitted on them (`refit_geometry`) and that geometry exported; without,
    they are listed in the robot file. A robot imported from a URDF keeps that file's links
    (`torchcal.io.urdf.calibrated_urdf`), any other gets `minimal_urdf`; the URDF keeps
    the robot's own base and tool (``tool0``) and carries the measuring frame and the
    reflector(s) as separate fixed frames ``tracker`` and ``reflector``
    (`torchcal.io.urdf.add_frames`). Every output is checked before any work
    (OutputExistsError without `force`; never one of the inputs or the files the model
    came from, `force` included; its folder must take a new file) and written atomically."""
    import dataclasses

    from torchcal.calibration.geometry_only import calibrated_robot, measuring_frames, refit_geometry
    from torchcal.calibration.mismatch import check_measurements, enforce
    from torchcal.calibration.plausibility import check_units
    from torchcal.io.files import atomic_write, check_output
    from torchcal.io.mdh_table import mdh_table_csv
    from torchcal.io.robot_file import write_robot_file
    from torchcal.io.urdf import add_frames, calibrated_urdf, minimal_urdf

    outs = {"robot_file": robot_file, "urdf": urdf, "table": table}
    if not any(outs.values()):
        raise InputError("export: give at least one output (robot file, URDF or MD-H table)")
    inputs = [p for p in (model, data) if isinstance(p, (str, Path))]
    im = _fitted(model)
    inputs += _sources(im)  # never over the files the model came from, force or not
    for p in outs.values():
        if p is not None:
            check_output(p, force=force, inputs=inputs)
    cm, theta = im.model, im.theta
    cal, rest = calibrated_robot(cm, theta)
    refit, rows = None, None
    if data is not None and rest:  # data only matter when the model has effects the robot cannot hold
        m = _measurements(data, cm.robot, length_unit, angle_unit)
        check_units(m, cm.robot, length_unit=length_unit, angle_unit=angle_unit, where=m.source or "data")
        enforce(check_measurements(cm, theta.to(m.xyz), m, im.training_rms_mm))
        rows, refit = len(m), refit_geometry(cm, theta, m, identified=im.report.free)
        cm, theta = refit.fit.model, refit.fit.theta
        cal, rest = calibrated_robot(cm, theta)[0], []
    urdf_text, urdf_info, source, links = None, None, None, None
    if urdf is not None:  # the robot's own base and tool; the measuring set-up as separate frames
        own = calibrated_robot(cm, theta, fold=False)[0]
        W, reflectors = measuring_frames(cm, theta)
        if own.urdf is not None:
            urdf_text, tip = calibrated_urdf(im.model.robot, own)
            source, base_link = own.urdf["path"], own.urdf["base_link"]
        else:
            urdf_text, tip, base_link = minimal_urdf(own), "tool0", "base_link"
        urdf_text = add_frames(urdf_text, base_link, tip, W, reflectors)
        urdf_info = {"path": str(Path(urdf).resolve()), "base_link": base_link, "tip_link": tip}
        links = dict(urdf_info, frames=(["tracker"] if W is not None else []) + [n for n, _ in reflectors])
        if W is not None or reflectors:  # the robot file folds the frames in: its URDF chain is another
            urdf_info = None
    cal = dataclasses.replace(cal, urdf=urdf_info)  # the calibrated robot file points at the calibrated URDF
    if robot_file is not None:
        write_robot_file(robot_file, cal, effects=rest, force=force, inputs=inputs)
    if urdf is not None:
        atomic_write(urdf, urdf_text, force=force, inputs=inputs)
    if table is not None:
        atomic_write(table, mdh_table_csv(cal), force=force, inputs=inputs)
    return Export(cal, rest, im.residual_model is not None, refit, rows, source,
                  {k: (None if v is None else str(v)) for k, v in outs.items()}, links if urdf else None)


def accuracy(model, *, n: int = 2000, seed: int = 0, payload_kg: float | None = None, temp_c: float = 20.0):
    """``torchcal accuracy``: the predicted TCP sigma of a fitted model at n workspace poses
    (`torchcal.calibration.accuracy.workspace_accuracy`).

    model: a MODEL.json path (its stored covariance; InputError when it has none) or a
    `FitResult` (its covariance). payload_kg: default half the rated payload. Returns an
    `Accuracy` whose ``to_dict()`` holds the figures the command prints."""
    from torchcal.calibration.accuracy import workspace_accuracy

    fm = _fitted(model)
    cm, theta = fm.model, fm.theta
    if isinstance(model, FitResult):
        if model.covariance is None:
            raise InputError("model: the fit holds no parameter covariance")
        cov = model.covariance.cov
    elif isinstance(model, (str, Path)):
        from torchcal.io.modelfile import load_covariance
        cov = load_covariance(model, cm)
    else:
        raise InputError(f"model: expected a MODEL.json path or a FitResult, got {type(model).__name__}")
    return workspace_accuracy(cm, theta, cov, n=n, seed=seed, payload_kg=payload_kg, temp_c=temp_c)


@dataclass
class Simulation:
    """A simulated measurement session (``torchcal simulate``).

    measurements: the `Measurements` (rows in movement order); robot: the nominal `Robot`;
    effects: the virtual robot's effect specs; theta: (P,) its true parameters (model units);
    seed, pose_seed: the robot's seed and the seed of the poses and the session; repeats, noise_mm."""

    measurements: Measurements
    robot: Robot
    effects: list
    theta: torch.Tensor
    parameter_names: list
    seed: int
    pose_seed: int
    repeats: int
    noise_mm: float

    def truth(self) -> dict:
        """The true parameters, as ``torchcal simulate --truth`` writes them (degrees and mm,
        the units of MODEL.json)."""
        from torchcal.calibration.model import CalibrationModel
        from torchcal.io.modelfile import file_units

        units, k = file_units(CalibrationModel(self.robot, self.effects))
        values = (self.theta.detach().to("cpu", torch.float64) * k).tolist()
        return {"robot": self.robot.name, "seed": self.seed, "effects": list(self.effects),
                "parameters": {n: {"value": v, "unit": u} for n, v, u in zip(self.parameter_names, values, units)}}

    def to_dict(self) -> dict:
        m = self.measurements
        return {"robot": self.robot.name, "effects": list(self.effects), "rows": len(m),
                "poses": len(m) // self.repeats, "repeats": self.repeats, "noise_mm": self.noise_mm,
                "seed": self.seed, "pose_seed": self.pose_seed,
                "columns": [c for c, v in (("payload_kg", m.payload_kg), ("temp_c", m.temp_c)) if v is not None]}


def simulate(robot, effects=(), *, n: int = 50, repeats: int = 1, noise_mm: float = 0.02, seed: int = 0,
             pose_seed: int | None = None) -> Simulation:
    """``torchcal simulate``: n random poses of a virtual robot (`robot` with `effects` whose
    true parameters are drawn with `seed`), each measured `repeats` times with noise_mm
    (1 sigma per axis). pose_seed: seed of the poses and the session (default `seed`; another
    value gives fresh poses of the same virtual robot)."""
    from torchcal.effects.spec import parse_specs
    from torchcal.simulation.virtual_robot import VirtualRobot, random_poses

    rob = _robot(robot)
    specs = [str(s) for s in parse_specs(list(effects), rob.n)] if effects else []
    ps = seed if pose_seed is None else pose_seed
    q = random_poses(rob, n, torch.Generator().manual_seed(ps))
    vr = VirtualRobot(rob, specs, seed=seed)
    # the session's seed as VirtualRobot.measure derives it from its own seed (the same file without pose_seed)
    m = vr.measure(q, repeats=repeats, noise_mm=noise_mm, seed=ps * 1_000_003 + 17)
    return Simulation(m, rob, specs, vr.theta, vr.model.param_names(), seed, ps, repeats, noise_mm)
