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
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

from torchcal import threads
from torchcal._lazy import attach
from torchcal.calibration.fit import SIGMA_DEG, SIGMA_MM, FitResult
from torchcal.calibration.checks.robot_data import check_diagnosis_data, check_robot_data_of
from torchcal.calibration.checks.conditions import check_conditions
from torchcal.calibration.checks.nominal_data import warn_nominal_data
from torchcal.calibration.checks.orientation_frame import check_orientation_frame
from torchcal.calibration.identifiability import FewEquationsWarning, few_equations
from torchcal.calibration.plausibility import MAX_ANGLE_DEG, MAX_LENGTH_MM
from torchcal.calibration.model import CalibrationModel
from torchcal.errors import DataError, InputError, number_argument
from torchcal.measurements import Measurements
from torchcal.io.robot_file import robot as make_robot
from torchcal.robots.robot import Robot

if TYPE_CHECKING:
    from torchcal.calibration.compensate import TargetCompensation
    from torchcal.calibration.evaluation import Evaluation
    from torchcal.io.export import Export
    from torchcal.simulation.session import Simulation

__all__ = ["fit", "load", "save", "evaluate", "diagnose", "discover", "calibrate", "compensate", "register", "Evaluation",
           "compensate_targets", "TargetCompensation", "export", "Export", "accuracy", "simulate", "Simulation",
           "check_diagnosis_data", "check_robot_data_of"]

# the result types live beside their computations; loaded on first use (`torchcal._lazy`)
__getattr__ = attach(__name__, {"torchcal.calibration.evaluation": ["Evaluation"],
                                "torchcal.calibration.compensate": ["TargetCompensation"],
                                "torchcal.io.export": ["Export"],
                                "torchcal.simulation.session": ["Simulation"]})[0]


def _robot(robot_or_model) -> Robot:
    if isinstance(robot_or_model, FitResult):
        return robot_or_model.model.robot
    if isinstance(robot_or_model, CalibrationModel):
        return robot_or_model.robot
    if isinstance(robot_or_model, (str, Path, Robot)):
        return make_robot(robot_or_model)
    raise InputError(f"robot_or_model: expected a preset name, a robot file, a Robot, a CalibrationModel or a "
                     f"FitResult, got {type(robot_or_model).__name__}")


def _specs(effects) -> list:
    """The effect specs of an `effects` argument: a list (tuple) of specs; a single string
    is refused (it would be read letter by letter)."""
    if isinstance(effects, (str, bytes)):
        raise InputError(f"effects: expected a list of effect specs, got the string {effects!r}; "
                         f"pass effects={effects.split()!r}")
    return list(effects)


def _sigmas(sigma_mm, sigma_deg) -> None:
    """The measurement uncertainties that weigh orientation against position: > 0 (sigma_deg
    None: not given, `SIGMA_DEG`)."""
    number_argument("sigma_mm", sigma_mm, above=0)
    if sigma_deg is not None:
        number_argument("sigma_deg", sigma_deg, above=0)


def _sigma_deg(sigma_deg, m) -> float:
    """sigma_deg for the measurements m: `SIGMA_DEG` when not given (None); given for data
    without rx, ry, rz, where it weighs nothing, one `UnusedSigmaWarning` at the caller's
    caller says so (`torchcal.calibration.checks.orientation.warn_unused_sigma_deg`)."""
    from torchcal.calibration.checks.orientation import warn_unused_sigma_deg

    warn_unused_sigma_deg(sigma_deg, m, stacklevel=3)
    return SIGMA_DEG if sigma_deg is None else sigma_deg


def _model(robot_or_model, effects=()) -> CalibrationModel:
    """A `CalibrationModel`; `effects` only with a robot (a model already has its own)."""
    effects = _specs(effects)
    if isinstance(robot_or_model, (CalibrationModel, FitResult)):
        model = robot_or_model if isinstance(robot_or_model, CalibrationModel) else robot_or_model.model
        if effects:
            raise InputError("effects: given with a CalibrationModel or a fitted model, which has its own effects "
                             f"[{', '.join(model.specs())}]; pass a robot instead")
        return model
    return CalibrationModel(_robot(robot_or_model), [str(s) for s in effects])


def _for_data(model: CalibrationModel, m) -> CalibrationModel:
    """`model` for the data `m` (`Measurements`): as it is, or, where `m`'s point ids are
    not those the model was made for, its effects rebuilt for `m`'s ids
    (`CalibrationModel.for_measurements`), so that a fitted model refitted on another
    point's data records (and checks against) the ids it was fitted on."""
    ids = () if m.point is None else tuple(sorted(set(m.point.tolist())))
    if not ids or ids == model.point_ids:
        return model
    return CalibrationModel.for_measurements(model.robot, model.specs(), m)


def _fitted(model) -> FitResult:
    """The fitted model: a `FitResult` (a `ZonedFit` too) as it is, a MODEL.json path
    loaded into one (`torchcal.io.modelfile.load`)."""
    if isinstance(model, FitResult):
        return model
    if isinstance(model, (str, Path)):  # whatever its name: the reader says what the file is
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


@contextmanager
def _about(m: Measurements):
    """A `DataError` raised in the block (too few poses) names the file of `m` first."""
    try:
        yield
    except DataError as exc:
        raise exc.about(m.source) from None


def _measurements(measurements, robot: Robot, length_unit: str = "mm", angle_unit: str = "deg") -> Measurements:
    from torchcal.io.measurement_csv import as_measurements

    return as_measurements(measurements, robot, length_unit, angle_unit)


def _work(model: CalibrationModel, m: Measurements) -> int:
    """Elements of the largest tensors of a fit of `model` to `m` (its Jacobian), for the
    thread policy (`torchcal.threads.for_work`)."""
    return 3 * m.q.shape[0] * model.n_params


def fit(robot_or_model, measurements, effects=(), *, robust: str | None = None, max_iter: int = 60,
        sigma_mm: float = SIGMA_MM, sigma_deg: float | None = None, max_length_mm: float | None = MAX_LENGTH_MM,
        max_angle_deg: float | None = MAX_ANGLE_DEG, length_unit: str = "mm", angle_unit: str = "deg",
        residual_model: str | None = None) -> FitResult:
    """Fit the geometric deviations plus `effects` to measured TCP positions (and
    orientations, when the measurements carry rx, ry, rz).

    robust: None, 'huber' or 'cauchy' (IRLS). sigma_mm / sigma_deg: measurement
    uncertainties (mm, deg) that weigh orientation against position (sigma_deg None:
    `SIGMA_DEG`; given for data without rx, ry, rz it weighs nothing, and one
    `UnusedSigmaWarning` says so). max_length_mm /
    max_angle_deg: the plausible scales of the MD-H deviations, the prior of the fit
    (each None drops its own prior only; `torchcal.calibration.plausibility`).
    Measurements with several `point` ids need `tool_offset` (one offset per point).
    length_unit ('mm' or 'm') / angle_unit ('deg' or 'rad'): the units of the measurement
    file (a path is read in them; `Measurements` were read in them). Before fitting, the
    unit check (`torchcal.calibration.checks.units.check_units`) refuses data that look like
    metres read as mm or radians read as degrees with one InputError line, the line the
    command line prints; so does the gross-mismatch check of the nominal robot
    (`check_robot_data_of`: another frame the model lacks, another robot, units, a
    mirrored frame, reversed joint columns, gross outliers without `robust`) and, after
    the fit, a fitted RMS beyond what any calibration leaves
    (`torchcal.calibration.checks.robot_data.check_fitted`); rx, ry, rz in another frame than x, y, z
    are refused too (`torchcal.calibration.checks.orientation_frame`). Positions that agree with the nominal
    robot within 0.01 mm rms (computed, e.g. the controller's TCP, not measured) get one
    `NominalDataWarning` (`torchcal.calibration.checks.nominal_data`). With several point ids,
    poses at which two rows fit each other's reflector (ids exchanged) are named in one
    `MismatchWarning` after the fit (`torchcal.calibration.checks.point_swap`).
    residual_model: 'kernel' adds the non-physical residual stage
    (`torchcal.calibration.residual_model`) as ``res.residual_model`` only when its held-out
    gain is significant (`torchcal.diagnosis.residual_stage`, the figures in
    ``res.residual_test``; None otherwise); evaluate and compensate apply it.
    Returns a `FitResult` (``.theta``, ``.status``, ``.rms_mm``); `save` writes it as the
    MODEL.json of ``torchcal fit``, `load` reads it back.
    """
    from torchcal.calibration.fit import fit as fit_model
    from torchcal.calibration.checks.point_swap import warn_swapped_points
    from torchcal.calibration.checks.robot_data import check_fitted
    from torchcal.calibration.checks.units import check_units
    from torchcal.effects import context_of

    robot = _robot(robot_or_model)
    effects = _specs(effects)
    _sigmas(sigma_mm, sigma_deg)
    m = _measurements(measurements, robot, length_unit, angle_unit)
    check_units(m, robot, length_unit=length_unit, angle_unit=angle_unit, where=m.source or "measurements")
    sigma_deg = _sigma_deg(sigma_deg, m)
    if isinstance(robot_or_model, (CalibrationModel, FitResult)):
        model = _for_data(_model(robot_or_model, effects), m)
    else:
        model = CalibrationModel.for_measurements(robot, effects, m)
    check_conditions(model, m)  # a missing column (temp_c) first, naming the file
    ctx = context_of(model.robot, m)
    with threads.for_work(_work(model, m)), _about(m):
        check_robot_data_of(model, m, robust=robust is not None)  # another frame, robot, units, outliers
        warn_nominal_data(model, m, stacklevel=2)  # the controller's positions, not measured ones
        check_orientation_frame(model, m)  # rx, ry, rz left in another frame than x, y, z
        res = fit_model(model, ctx, m.xyz, robust=robust, max_iter=max_iter, pose=m.pose, rotation=m.rotation,
                         sigma_mm=sigma_mm, sigma_deg=sigma_deg, max_length_mm=max_length_mm,
                         max_angle_deg=max_angle_deg)
    gross = check_fitted(res.residuals, res.outliers, m.source or "data", model.robot.name)
    if gross:
        raise InputError(gross)
    warn_swapped_points(res, m, stacklevel=2)  # two reflectors' ids exchanged at a few poses
    few = few_equations(res.report, m)
    if few:
        warnings.warn(few, FewEquationsWarning, stacklevel=2)
    if residual_model is not None:
        _add_stage(res, m, ctx, residual_model)
    return res


def _add_stage(res: FitResult, m: Measurements, ctx, kind: str, folds: int = 5, seed: int = 0) -> None:
    """The residual stage on `res` when its held-out test passes (`residual_test` holds the figures)."""
    from torchcal.diagnosis.residual_stage import stage_test

    t = stage_test(res, m, ctx, kind=kind, folds=folds, seed=seed, sigma_mm=res.sigma_mm, sigma_deg=res.sigma_deg)
    res.residual_model, res.residual_test = t.stage, t.to_dict()


def evaluate(model, measurements) -> Evaluation:
    """Errors of a fitted model (`FitResult`, or a MODEL.json path) on measurements.

    Data that cannot come from the model (another robot, a moved measuring frame, units;
    `torchcal.calibration.checks`) are refused with one InputError line.

    Rows outside the model's calibrated joint range are counted (``outside_range``) and
    named in one `CalibratedRangeWarning` (the model extrapolates there)."""
    from torchcal.calibration.evaluation import evaluate as run

    fm = _fitted(model)
    return run(fm, _measurements(measurements, fm.model.robot), stacklevel=2)


def _set(**options) -> dict:
    """The options that were given (None: the callee's own default)."""
    return {k: v for k, v in options.items() if v is not None}


def diagnose(robot_or_model, measurements, effects=(), *, folds: int = 5, seed: int = 0, alpha: float | None = None,
             min_gain: float | None = None, sigma_mm: float = SIGMA_MM, sigma_deg: float | None = None):
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

    _sigmas(sigma_mm, sigma_deg)
    model = _model(robot_or_model, effects)
    m = _measurements(measurements, model.robot)
    check_conditions(CalibrationModel.for_measurements(model.robot, model.specs(), m), m)  # a missing column
    check_diagnosis_data(robot_or_model, model, m)
    sigma_deg = _sigma_deg(sigma_deg, m)
    check_orientation_frame(model, m)  # rx, ry, rz left in another frame than x, y, z
    with threads.for_work(_work(model, m)), _about(m):
        return run(model.robot, m, model.specs(), folds=folds, seed=seed, sigma_mm=sigma_mm, sigma_deg=sigma_deg,
                   **_set(alpha=alpha, min_gain=min_gain))


def discover(robot_or_model, measurements, effects=(), *, folds: int = 5, seed: int = 0,
             max_rounds: int | None = None, alpha: float | None = None, sigma_mm: float = SIGMA_MM,
             sigma_deg: float | None = None, transfer=None, transfer_poses: int = 30,
             residual_model: str | None = None, report_rest: bool = True):
    """Add the accepted missing effect each round (`torchcal.diagnosis.diagnose.discover`),
    for at most max_rounds rounds; folds, seed, alpha, sigma_mm, sigma_deg as in `diagnose`
    (None: the defaults of `torchcal.diagnosis`). Data the nominal robot cannot explain,
    or that need a measuring frame the effects lack, are refused as by `diagnose`, in
    `measurements` and in `transfer` alike. transfer: measurements of another session (Measurements or CSV path;
    rows that repeat rows of `measurements` exactly are refused) as a check: a
    step is kept only when it lowers that session's error beyond chance after registration on
    its first `transfer_poses` poses (`torchcal.diagnosis.transfer`). residual_model:
    'kernel' adds the residual stage to the final model when its held-out test passes, as
    `fit` does (``.fit.residual_test`` holds the figures). report_rest=False skips the probe
    of what the final model leaves (``.unexplained`` None; the search is the same). Returns a
    `Discovery`."""
    from torchcal.diagnosis.diagnose import discover as run
    from torchcal.diagnosis.transfer import TransferCheck
    from torchcal.effects import context_of

    _sigmas(sigma_mm, sigma_deg)
    model = _model(robot_or_model, effects)
    m = _measurements(measurements, model.robot)
    check_conditions(CalibrationModel.for_measurements(model.robot, model.specs(), m), m)  # a missing column
    check_robot_data_of(CalibrationModel.for_measurements(model.robot, model.specs(), m), m)
    sigma_deg = _sigma_deg(sigma_deg, m)
    warn_nominal_data(CalibrationModel.for_measurements(model.robot, model.specs(), m), m, stacklevel=2)
    check_orientation_frame(model, m)
    other = None if transfer is None else _measurements(transfer, model.robot)
    if other is not None and m.temp_c is not None and other.temp_c is None:  # else a traceback mid-search
        raise InputError(f"{other.source or 'transfer'}: the transfer session has no temp_c column, which "
                         f"{m.source or 'the data'} have: thermal_expansion, a candidate on those data, is "
                         f"scored on both sessions; add temp_c (degC) to it or drop the column from both")
    if other is not None:  # the other session's data are held to the same check (another robot, units)
        from torchcal.calibration.checks.sessions import same_session, shared_rows
        from torchcal.calibration.checks.verdict import listed

        check_robot_data_of(CalibrationModel.for_measurements(model.robot, model.specs(), other), other)
        same = shared_rows(m, other)
        if same:  # the search's own rows would confirm every step it takes
            raise InputError(f"{other.source or 'transfer'}: {len(same)} of {len(other)} rows repeat rows of "
                             f"{m.source or 'the data'} (the same joint values and x, y, z; data row(s) "
                             f"{listed(i + 1 for i in same)}): the transfer check needs the measurements of "
                             "another session, not the data searched")
        same_session(m, other, stacklevel=2)  # the validation part of a split of the same session
    check = None if other is None else TransferCheck(other, transfer_poses, other.source or "the other session")
    with threads.for_work(_work(model, m)), _about(m):
        res = run(model.robot, m, model.specs(), folds=folds, seed=seed, sigma_mm=sigma_mm, sigma_deg=sigma_deg,
                  transfer=check, report_rest=report_rest, **_set(max_rounds=max_rounds, alpha=alpha))
        from torchcal.calibration.checks.point_swap import warn_swapped_points
        warn_swapped_points(res.fit, m, stacklevel=2)  # two reflectors' ids exchanged at a few poses
        if residual_model is not None:
            _add_stage(res.fit, m, context_of(model.robot, m), residual_model, folds, seed)
    return res


def calibrate(robot_or_model, measurements, effects=(), *, partition=None, zone_method: str = "damped",
              damping="gcv_shared"):
    """Interval calibration, global or per zone (`torchcal.calibration.zone_calibration.calibrate`).

    The measurements are checked as `fit` checks them: data that the nominal robot cannot
    explain, or that need a measuring frame the model lacks (tracker data without
    base_frame tool_offset), are refused with one InputError line, and so is a global fit
    still off by more than any calibrated arm; positions that are the nominal robot's own
    get one `NominalDataWarning` (`torchcal.calibration.checks.nominal_data`). Rows whose nominal TCP lies beyond the
    partition's swept region are named in a `MismatchWarning` (their zone is extrapolated).
    partition: a `Partition`, a PARTITION.json path or None. A path is read for the model's
    robot: a partition made for another robot (or other joint limits) is refused
    (InputError), one without a record read with an `UnrecordedRobotWarning`
    (`torchcal.io.partition_file.load_partition`); a `Partition` is held to the record it
    was read with (``made_for``), and one without (built in memory, an older file) to its
    geometry (`torchcal.calibration.checks.partition.check_partition`: sweep points beyond the
    robot's reach, calibration poses far from every sweep point: InputError). Returns the global interval
    fit (a `FitResult` with ``radius``), with a partition a `ZonedFit` (the global fit and
    one fit per zone); `save` writes it as the MODEL.json of ``torchcal calibrate``.
    """
    from torchcal.calibration.zone_calibration import calibrate as run, check_one_point

    from torchcal.partition.zones import Partition

    model = _model(robot_or_model, effects)
    if isinstance(partition, (str, Path)):
        from torchcal.io.partition_file import load_partition
        partition = load_partition(partition, model.robot)
    elif partition is not None and not isinstance(partition, Partition):
        raise InputError(f"partition: expected a Partition, a PARTITION.json path or None, "
                         f"got {type(partition).__name__}")
    elif partition is not None and partition.made_for is not None:  # built from a file: its record
        from torchcal.io.robot_file import check_record
        check_record(partition.made_for, model.robot, "partition", "sweep and partition")
    m = _measurements(measurements, model.robot)
    ids = [] if m.point is None else sorted(set(m.point.tolist()))
    if len(ids) == 1 and not isinstance(robot_or_model, (CalibrationModel, FitResult)):
        model = CalibrationModel(model.robot, model.specs(), points=ids)  # MODEL.json records the point id
    elif isinstance(robot_or_model, (CalibrationModel, FitResult)):
        model = _for_data(model, m)
    if partition is not None and partition.made_for is None:  # no record: judged by its geometry
        from torchcal.calibration.checks.partition import check_partition
        check_partition(partition, model.robot, m.q, "partition")
    from torchcal.calibration.checks.robot_data import check_fitted

    if partition is not None:  # rows beyond the swept region: their zone is extrapolated (as compensate says)
        from torchcal.calibration.checks.partition import warn_far_from_sweep
        warn_far_from_sweep(partition, model.robot.fk(m.q).detach(), m.source or "measurements", stacklevel=2)
    check_one_point(m)  # several reflectors: refused in calibrate's own words
    check_conditions(model, m)  # a missing column (temp_c) first, naming the file
    with threads.for_work(_work(model, m)), _about(m):
        check_robot_data_of(model, m)  # another frame (tracker data without base_frame tool_offset), robot, units
        warn_nominal_data(model, m, stacklevel=2)
        res = run(model, m, partition, zone_method, damping)
    gross = check_fitted(res.residuals, (), m.source or "data", model.robot.name)
    if gross:
        raise InputError(gross)
    return res


def compensate(model, targets, q0=None, *, tol_mm: float = 1e-6, max_iter: int = 30, max_step_rad: float = 0.2,
               payload_kg=None, temp_c=None, check: bool = True):
    """Corrected joint commands (M, n) rad for target positions (M, 3) mm.

    model: a fitted model (`FitResult`, or a MODEL.json path; a `ZonedFit`'s targets are
    assigned to its zones). targets: in the model's measuring
    frame. q0: (M, n) rad starting commands (one per target; with `check`, seeds beyond what
    a joint can turn are refused as degrees, and seeds whose model point lies more than
    100 mm from their target named in a `MismatchWarning`), default
    `torchcal.calibration.compensate.nominal_start` (the nominal inverse in the measuring
    frame from the nearest calibration pose, as the command line seeds it; a target
    beyond the reach, `check`, is tried from its nearest pose only and ends not converged). tol_mm,
    max_iter, max_step_rad: the Newton solve (`torchcal.calibration.compensate.compensate`);
    payload_kg, temp_c: (M,) conditions of the moves, for load and temperature effects. Returns a
    `Compensation`; converged solutions outside the model's calibrated joint range are
    counted (``outside_range``) and named in one `CalibratedRangeWarning`. check: targets
    inside the robot's base (metres read as mm) are refused, targets beyond its reach
    named in a `MismatchWarning` (`torchcal.calibration.checks.targets.check_targets`). A model
    with a residual stage (``model.residual_model``) is
    inverted with it (the physical model is solved for the target minus the stage's
    correction, repeated until it settles).
    """
    from torchcal.calibration.compensate import compensate_fitted

    return compensate_fitted(_fitted(model), targets, q0, tol_mm=tol_mm, max_iter=max_iter, max_step_rad=max_step_rad,
                             payload_kg=payload_kg, temp_c=temp_c, check=check, stacklevel=2)


def register(model, measurements, *, tool: bool = False) -> FitResult:
    """Re-estimate only the measuring frame of a fitted model on new measurements: the
    base frame, and the tool offset when `tool` (`torchcal.calibration.registration.reregister`).

    model: a fitted model (`FitResult` or a MODEL.json path), whose geometry, effects,
    covariance, calibrated joint range, settings, tool rotation, residual stage and
    training rms are kept; or a robot
    (preset name, robot file, `Robot`): a registration-only model (nominal geometry in
    the best frame), calibrated on these rows. Data that no frame brings near the model
    (another robot, units) are refused (InputError, `torchcal.calibration.checks`).
    Returns a `FitResult` whose ``rms_mm`` and ``residuals`` are those on `measurements`
    and whose ``registration`` records the frame and the rms before and after; for a
    per-zone model a `ZonedFit` whose zones take the global frame's change
    (`torchcal.calibration.new_setup.zones_moved`). An rms
    above 3x the model's training rms is a `TransferWarning`
    (`torchcal.calibration.registration.far_from_training`).
    """
    from torchcal.calibration.new_setup import register_model

    fm = _fitted(model) if _is_model(model) else None
    robot = fm.model.robot if fm is not None else _robot(model)
    m = _measurements(measurements, robot)
    with _about(m):
        return register_model(fm, robot, m, tool=tool, stacklevel=2)


def _is_model(obj) -> bool:
    """True for a fitted model (FitResult, a MODEL.json path), False for a robot."""
    if isinstance(obj, FitResult):
        return True
    if isinstance(obj, (str, Path)) and str(obj).endswith(".json") and Path(obj).is_file():
        from torchcal.io.files import read_json
        from torchcal.io.modelfile import FORMAT, FORMAT_RAD

        return read_json(obj, "model or robot file").get("format") in (FORMAT, FORMAT_RAD)
    return False


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
    file, Robot) the model must be for (InputError otherwise); where its joint limits differ
    from the model's, its limits are used (`torchcal.io.modelfile.with_limits_of`, one
    `RobotLimitsWarning`). seeds: (M, n) deg (mm for a
    slide) starting commands for tensor targets, default the nominal inverse in the
    measuring frame from the nearest calibration pose
    (`torchcal.calibration.compensate.nominal_start`; a target it does not reach is still
    tried, and reported per row); payload_kg, temp_c: (M,) conditions for tensor targets.
    Targets inside the robot's base or around the origin of their frame (metres read as
    mm) are refused; those beyond its reach are listed in ``beyond_reach``. A model effect that needs a condition the targets lack is
    refused naming it. Converged commands outside the calibrated range: one
    `CalibratedRangeWarning`.
    """
    from torchcal.calibration.compensate import compensate_targets as run
    from torchcal.robots.checks import check_same_robot, warn_other_gravity

    from_file = isinstance(targets, (str, Path))  # read in length_unit; a tensor is in mm
    where = str(targets) if from_file else "targets"
    im = _fitted(model)
    rob = im.model.robot
    if robot is not None:
        from torchcal.io.modelfile import with_limits_of

        given, name = make_robot(robot), str(model) if isinstance(model, (str, Path)) else "model"
        check_same_robot(rob, given, name)
        warn_other_gravity(im, given, name, stacklevel=2)
        im = with_limits_of(im, given, name, stacklevel=2)
        rob = im.model.robot
    if isinstance(targets, (str, Path)):
        from torchcal.io.targets_csv import read_targets

        targets, seeds, cond = read_targets(targets, rob.n, length_unit=length_unit, angle_unit=angle_unit,
                                            prismatic=rob.prismatic)
        payload_kg, temp_c = cond["payload_kg"], cond["temp_c"]
    return run(im, targets, frame=frame, seeds=seeds, payload_kg=payload_kg, temp_c=temp_c, where=where,
               stacklevel=2, length_unit=length_unit if from_file else "mm")


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
    from torchcal.io.export import export as run

    inputs = [p for p in (model, data) if isinstance(p, (str, Path))]
    return run(_fitted(model), robot_file=robot_file, urdf=urdf, table=table, data=data,
               length_unit=length_unit, angle_unit=angle_unit, force=force, inputs=inputs,
               where=str(model) if isinstance(model, (str, Path)) else "model")


def accuracy(model, *, n: int = 2000, seed: int = 0, payload_kg: float | None = None, temp_c: float = 20.0,
             within: str = "calibrated"):
    """``torchcal accuracy``: the predicted TCP sigma of a fitted model at n workspace poses
    (`torchcal.calibration.accuracy.workspace_accuracy`), drawn inside the joint range it
    was calibrated on (within="calibrated") or inside the joint limits ("limits").

    model: a MODEL.json path (its stored covariance; InputError when it has none) or a
    `FitResult` (its covariance). payload_kg: default half the rated payload. Returns an
    `Accuracy` whose ``to_dict()`` holds the figures the command prints."""
    import warnings

    from torchcal.calibration.accuracy import ZoneAccuracyWarning, workspace_accuracy, zone_accuracy_note

    fm = _fitted(model)
    note = zone_accuracy_note(fm)  # independent zones: the figures are the global fit's
    if note is not None:
        warnings.warn(f"{model if isinstance(model, (str, Path)) else 'model'}: {note}", ZoneAccuracyWarning,
                      stacklevel=2)
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
    return workspace_accuracy(cm, theta, cov, n=n, seed=seed, payload_kg=payload_kg, temp_c=temp_c,
                              q_range=fm.q_range, within=within, conditions=getattr(fm, "conditions", None))


def simulate(robot, effects=(), *, n: int = 50, repeats: int = 1, noise_mm: float = 0.02, seed: int = 0,
             pose_seed: int | None = None) -> Simulation:
    """``torchcal simulate``: n random poses of a virtual robot (`robot` with `effects` whose
    true parameters are drawn with `seed`), each measured `repeats` times with noise_mm
    (1 sigma per axis). pose_seed: seed of the poses and the session (default `seed`; another
    value gives fresh poses of the same virtual robot)."""
    from torchcal.simulation.session import simulate as run

    return run(_robot(robot), effects, n=n, repeats=repeats, noise_mm=noise_mm, seed=seed, pose_seed=pose_seed)
