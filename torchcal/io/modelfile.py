"""MODEL.json: a fitted model on disk (JSON, never pickle).

    {"format": "torchcal-model/2", "robot": NAME, "nominal_robot": {ROBOT FILE},
     "effects": [SPEC...],
     "parameters": [{"name", "value", "unit", "std", "identified", "ci95", "set_by_prior"}...],
     "covariance": {"method", "dof", "sigma_mm", "noise_mm", "pose_mm", "parameters", "units", "matrix"},
     "identifiability": {...}, "fit": {"n", "rms_mm", "max_mm", "robust", "sigma_mm", "sigma_deg", "outlier_poses",
             "iterations", "status"},
     "provenance": {"input", "input_sha256", "torchcal_version", "seed"},
     "calibrated_range": {"q_min": [...], "q_max": [...], "unit": ["deg" | "mm", ...], "poses": [[...]]}
                     (per joint min and max of the calibration data's commanded q; up to 32 of
                     its poses, which seed compensate),
     optional: "points": [ID...] (one tool offset per measured point),
     "point_ids": [ID...] (the point ids of the data it was fitted on, one or several; absent
                  for data without a point column and in older files: then not checked),
     "base_frame": {"translation_mm", "rotation_fixed_xyz_deg"} (measurement <- robot base),
     "registration": {"rms_before_mm", "rms_after_mm", "translation_mm", "rotation_fixed_xyz_deg",
                      "rotation_angle_deg"} (the closed-form start),
     "plausibility": {"max_length_mm", "max_angle_deg", "prior_sigma_mm", "beyond": [NAME...],
                      "set_by_prior": [NAME...]},
     "orientation": {"sigma_mm", "sigma_deg", "weight_mm_per_deg", "rms_deg",
                     "tool_rotation_fixed_xyz_deg"},
     "residual_model": {...} (the optional non-physical residual stage,
                       `torchcal.calibration.residual_model`),
     "residual_test": {"applied", "cv_without_mm", "cv_with_mm", "p_value", "level", "reason"}
                      (its held-out test, `torchcal.diagnosis.residual_stage`),
     interval calibration (``torchcal calibrate``): each parameter's "interval": [lower, upper]
     (the interval hull of `torchcal.calibration.intervals`) and "fit": {..., "damping"},
     and per zone of a partition (a `ZonedFit`): "zone_method", "partition": {PARTITION.json},
     "zones": [{"zone", "level", "poses", "value", "std", "lower", "upper", "identified",
                "held", "rms_mm", "max_mm", "damping", "iterations", "status"[, "note"]}...]}

Values are in the units named beside them: mm and degrees (radians inside; `file_unit`:
'rad' -> 'deg', 'rad/mm' -> 'deg/mm', the joint_compliance payload term -> the joint's
compliance in 'deg/(N m)'; '1', '1/K' as they are); ``covariance.matrix`` is in the same
units (``covariance.units``). Files of format "torchcal-model/1" (values in radians) load
as before. ``std`` is the standard
error, the prior included (posterior; 0 for parameters held at nominal), ``ci95`` its 95 % interval [lower, upper]
(Student's t), ``set_by_prior`` true where the data do not determine the value (posterior
sd at least half the plausible scale, `torchcal.calibration.plausibility`), ``covariance`` the full covariance of the identified parameters (row
'rows' or 'pose-level' when poses repeat; `torchcal.calibration.covariance`); ``fit.status`` is how the
solver stopped ('converged', 'stalled' or 'max_iterations'). Loading rebuilds the `CalibrationModel` and
theta exactly (floats are written with full precision). ``nominal_robot`` embeds the
nominal robot (the robot-file dict, docs/robots.md), so a model file needs no preset and
no robot file; files written before it existed name a preset under ``robot``.
``calibrated_range`` (deg, mm for a prismatic joint) lets evaluate and compensate warn
when the model is used outside the joint range it was fitted on
(`torchcal.calibration.joint_range`).

The file of a per-zone calibration is the file of its global fit plus the zones: the
per-zone arrays are in the order and units (degrees, mm) of "parameters"; a zone without
poses holds the global values (its "note" says so). Files of the older interval-model format
("torchcal-interval-model/1": zones only, values in radians) load too: one zone without a
partition as its fit, else a `ZonedFit` whose global fields are zone 1's (that format stores
no global fit); unknown figures are zero (std) or absent.

`load` returns the one fitted-model type, `torchcal.calibration.fit.FitResult`, with every
field the file holds: theta, std, covariance, identifiability (``report``; identified and
held parameters), the fit's settings (robust, sigma_mm, sigma_deg), status, iterations,
outliers, registration, plausibility (``plausible_limits``, ``implausible``), orientation
(``tool_rotation`` included), calibrated range (``q_range``) and conditions
(``conditions``, "calibrated_conditions": the temperature / payload range its effects
were fitted on), residual stage, training
{n, rms_mm, max_mm} and provenance. What a file does not store is None: ``residuals``
and ``weights`` (per row), and any block of a file written before it existed
(``q_range``, ``covariance``, ...). ``to_dict(load(path))`` writes the same blocks back.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import torch

import torchcal
from torchcal.errors import InputError
from torchcal.calibration.covariance import ParameterCovariance
from torchcal.calibration.fit import SIGMA_DEG, SIGMA_MM, FitResult, Identifiability
from torchcal.io.files import read_json
from torchcal.calibration.model import CalibrationModel
from torchcal.calibration.zone_calibration import ZonedFit
from torchcal.effects.joint_compliance import G_NM_PER_KG_MM
from torchcal.robots.robot import Robot
from torchcal.io.robot_file import model_robot, robot_to_dict
from torchcal.robots.checks import check_same_robot

FORMAT = "torchcal-model/2"
FORMAT_RAD = "torchcal-model/1"  # files written before version 2: values in the model's units (rad)
FORMAT_INTERVAL = "torchcal-interval-model/1"  # the older file of `torchcal calibrate` (zones only, rad)



def file_unit(unit: str) -> tuple[str, float]:
    """(unit in files and printed tables, factor) of a parameter whose model (internal)
    unit is `unit`: value in files = factor * value inside.

    Angles in degrees: 'rad' -> 'deg', 'rad/X' -> 'deg/X' (e.g. the joint_compliance link
    terms, deg per mm of lever). The joint_compliance payload term 'rad/(kg mm)' (gravity
    x compliance, G / K) becomes the joint's compliance 1/K in 'deg/(N m)'. Other units
    ('mm', '1', '1/K', ...) are kept."""
    if unit == "rad/(kg mm)":
        return "deg/(N m)", math.degrees(1.0) / G_NM_PER_KG_MM
    if unit == "rad" or unit.startswith("rad/"):
        return "deg" + unit[3:], math.degrees(1.0)
    return unit, 1.0


def _old_label(name: str, unit: str, expected: str) -> bool:
    """True for the joint_compliance link-moment terms (compl_J_K_mx/my/mz) labelled
    'deg/mm' by earlier versions: the same values in degrees, only the label was wrong."""
    import re

    return (unit, expected) == ("deg/mm", "deg") and re.fullmatch(r"compl_\d+_\d+_m[xyz]", name) is not None


def file_units(model: CalibrationModel) -> tuple[list[str], torch.Tensor]:
    """([unit in files per parameter], (P,) float64 factors) of `model` (`file_unit`)."""
    pairs = [file_unit(u) for u in model.param_units()]
    return [u for u, _ in pairs], torch.tensor([f for _, f in pairs], dtype=torch.float64)


def file_sha256(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def to_dict(res: FitResult, source=None, seed: int = 0, pose_ids=None, partition_source=None) -> dict:
    """The MODEL.json dict of a fitted model (module doc), a `ZonedFit` with its zones.
    source / partition_source: the data / PARTITION.json it was fitted on (paths), recorded
    in the provenance (the data with its SHA-256); without source, ``res.provenance``."""
    from torchcal.calibration.joint_range import range_to_dict
    from torchcal.calibration.registration import base_frame_summary
    from torchcal.rotations import matrix_to_fixed_xyz

    model = res.model
    train = res.training
    if train is None:  # a result built by hand: its own rows
        from torchcal.calibration.fit import training_summary
        train = training_summary(res.residuals)
    lo, hi = (res.theta, res.theta) if res.covariance is None else res.covariance.interval95(res.theta)
    outliers = res.outliers if pose_ids is None else sorted({int(pose_ids[i]) for i in res.outliers})
    extra = {}
    if model.points:
        extra["points"] = list(model.points)
    if model.point_ids:
        extra["point_ids"] = list(model.point_ids)
    base = base_frame_summary(model, res.theta)
    if base is not None:
        extra["base_frame"] = base
    if res.registration is not None:
        extra["registration"] = dict(res.registration)
    if res.plausible_limits is not None:
        extra["plausibility"] = {**res.plausible_limits, "beyond": list(res.implausible),
                                 "set_by_prior": list(res.set_by_prior)}
    if res.q_range is not None:
        extra["calibrated_range"] = range_to_dict(res.q_range, model.robot, res.seed_poses)
    if res.conditions is not None:
        extra["calibrated_conditions"] = {k: list(v) for k, v in res.conditions.items()}
    if res.orientation is not None:
        o = res.orientation
        extra["orientation"] = {k: o[k] for k in ("sigma_mm", "sigma_deg", "rms_deg")}
        extra["orientation"]["weight_mm_per_deg"] = math.radians(o["weight_mm_per_rad"])
        extra["orientation"]["tool_rotation_fixed_xyz_deg"] = torch.rad2deg(
            matrix_to_fixed_xyz(o["tool_rotation"].detach().cpu().double())).tolist()
    if res.residual_model is not None:
        extra["residual_model"] = res.residual_model.to_dict()
    if res.residual_test is not None:
        extra["residual_test"] = dict(res.residual_test)
    units, k = file_units(model)  # degrees and mm in the file, radians inside
    cov = None
    if res.covariance is not None:
        cov = res.covariance.to_dict(model.param_names())
        ki = torch.tensor([float(k[model.param_names().index(n)]) for n in cov["parameters"]], dtype=torch.float64)
        mat = torch.tensor(cov["matrix"], dtype=torch.float64).reshape(len(ki), len(ki))
        cov["matrix"] = (ki[:, None] * mat * ki[None, :]).tolist()
        cov["units"] = [units[model.param_names().index(n)] for n in cov["parameters"]]
    theta, std, lo, hi = (t.detach().to("cpu", torch.float64) * k for t in (res.theta, res.std, lo, hi))
    interval = None if res.radius is None else _interval_rows(res, k)
    fit_extra = {"damping": res.damping} if res.damping else {}
    provenance = dict(res.provenance) if source is None and res.provenance is not None else \
        {"input": None if source is None else str(source),
         "input_sha256": None if source is None else file_sha256(source),
         "torchcal_version": torchcal.__version__, "seed": seed}
    if partition_source is not None:
        provenance["partition"] = str(partition_source)
    if isinstance(res, ZonedFit):
        from torchcal.io.partition_file import partition_to_dict

        extra["zone_method"] = res.method
        extra["partition"] = partition_to_dict(res.partition, res.partition.made_for)  # with its robot record
        extra["zones"] = [_zone_to_dict(res, z, k) for z in range(len(res.zones))]
    return {
        "format": FORMAT,
        "robot": model.robot.name,
        "nominal_robot": robot_to_dict(model.robot),
        "effects": model.specs(),
        "parameters": [
            {"name": n, "unit": u, "value": float(v), "std": float(s), "identified": bool(f),
             "ci95": [float(a), float(b)], "set_by_prior": n in res.set_by_prior,
             **({} if interval is None else {"interval": interval[i]})}
            for i, (n, u, v, s, f, a, b) in enumerate(zip(model.param_names(), units, theta.tolist(),
                                                          std.tolist(), res.report.free.tolist(), lo.tolist(),
                                                          hi.tolist()))],
        "covariance": cov,
        "identifiability": _identifiability(res.report),
        "fit": {"n": int(train["n"]), "rms_mm": float(train["rms_mm"]), "max_mm": float(train["max_mm"]),
                "robust": res.robust, "sigma_mm": res.sigma_mm, "sigma_deg": res.sigma_deg,
                "outlier_poses": outliers, "iterations": res.n_iter,
                "status": res.status, **fit_extra},
        "provenance": provenance,
        **extra,
    }


def _identifiability(report: Identifiability) -> dict:
    """The identifiability block; an unknown condition number (NaN: a file of the older
    interval format holds none) is written as null."""
    out = report.to_dict()
    if not math.isfinite(out["condition_number"]):
        out["condition_number"] = None
    return out


def _interval_rows(res: FitResult, k: torch.Tensor) -> list:
    """Per parameter [lower, upper] = theta -+ radius in file units (k: `file_units` factors)."""
    th, r = (t.detach().to("cpu", torch.float64) * k for t in (res.theta, res.radius))
    return torch.stack([th - r, th + r], dim=-1).tolist()


def _zone_to_dict(res, z: int, k: torch.Tensor) -> dict:
    """Zone z (0-based) of a `ZonedFit` as its MODEL.json entry (module doc), file units."""
    f, poses = res.zones[z], int(res.zone_poses[z])
    th, std = (t.detach().to("cpu", torch.float64) * k for t in (f.theta, f.std))
    r = torch.zeros_like(th) if f.radius is None else f.radius.detach().to("cpu", torch.float64) * k
    train = f.training or {}
    out = {"zone": z + 1, "level": int(res.partition.zone_level[z]), "poses": poses, "value": th.tolist(),
           "std": std.tolist(), "lower": (th - r).tolist(), "upper": (th + r).tolist(),
           "identified": f.report.free.tolist(), "held": list(f.report.held), "rms_mm": f.rms_mm,
           "max_mm": train.get("max_mm"), "damping": f.damping, "iterations": f.n_iter, "status": f.status}
    if poses == 0:
        out["note"] = "no poses in this zone: global parameters"
    return out


class RobotLimitsWarning(UserWarning):
    """The robot given with a model has the model's geometry but other joint limits: the
    given robot's limits are used (`with_limits_of`)."""


def with_limits_of(fitted: FitResult, robot: Robot, where: str, stacklevel: int = 1) -> FitResult:
    """`fitted` as it is when `robot` (already checked to have its geometry,
    `check_same_robot`) has the joint limits of the model's nominal robot; else a copy
    whose nominal robot (of every zone too) has `robot`'s limits, with one
    `RobotLimitsWarning` naming the first joint that differs (`robot_differences`). The
    limits decide which commands `compensate` calls within the limits (and which seeds
    it tries), and which rows lie outside them; the robot given is the one the user says
    the commands are for. Geometry, effects, parameters and calibrated range are shared."""
    import dataclasses
    import warnings

    from torchcal.robots.checks import robot_differences

    there = fitted.model.robot
    if there.n != robot.n or torch.allclose(there.limits.detach().cpu(), robot.limits.detach().to("cpu", there.dtype),
                                            rtol=0, atol=1e-9):
        return fitted
    diff = [d for d in robot_differences(there, robot) if " limits " in d]
    warnings.warn(f"{where}: the model's robot {there.name!r} has other joint limits than the robot given "
                  f"({diff[0].replace(' in the file,', ' in the model,') if diff else 'limits differ'}): the given "
                  "robot's limits are used (compensate's within_limits and seeds, the rows outside the limits)",
                  RobotLimitsWarning, stacklevel=stacklevel + 1)
    cm = fitted.model  # the same effects (their geometry is the robot's), on the robot with the given limits
    model = CalibrationModel(dataclasses.replace(there, limits=robot.limits.to(there.limits)), cm.effects,
                             points=cm.point_ids or None)
    if isinstance(fitted, ZonedFit):
        return dataclasses.replace(fitted, model=model,
                                   zones=[dataclasses.replace(z, model=model) for z in fitted.zones])
    return dataclasses.replace(fitted, model=model)


def load(path, robot: Robot | str | None = None) -> FitResult:
    """The fitted model (`FitResult`) of MODEL.json (module doc: which fields a file holds).

    robot: a `Robot` or a preset name / robot-file path; when given, a model of another
    robot (joint count, types or nominal geometry) is refused with one line naming both,
    and one of other joint limits is given those limits, with a warning (`with_limits_of`);
    one of another gravity direction is named for a model with gravity-driven effects
    (`torchcal.robots.checks.warn_other_gravity`)."""
    if robot is None:
        return _load(path, None)
    from torchcal.io.robot_file import robot as make_robot

    from torchcal.robots.checks import warn_other_gravity

    given = make_robot(robot)
    res = _load(path, given)
    warn_other_gravity(res, given, str(path), stacklevel=2)
    return with_limits_of(res, given, str(path), stacklevel=2)


def _load(path, robot: Robot | None) -> FitResult:
    """`load` with the robot given resolved (None: not checked)."""
    obj = _read(path)
    if obj["format"] == FORMAT_INTERVAL:
        res = _interval_file(obj, str(path))
        if robot is not None:
            check_same_robot(res.model.robot, robot, str(path))
        return res
    try:
        effects, params = obj["effects"], obj["parameters"]
        if not isinstance(effects, list):  # a string would be read letter by letter ("unknown effect 'b'")
            raise TypeError(f"'effects' must be a list of effect names, got {type(effects).__name__}")
        values = [_number(p, "value", i, path) for i, p in enumerate(params)]
        stds = [_number(p, "std", i, path, 0.0) for i, p in enumerate(params)]
        identified = [bool(p.get("identified", True)) for p in params]
        names = [p["name"] for p in params]
        file_unit_names = [p.get("unit") for p in params]
    except InputError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise InputError(f"{path}: model file is missing or has a bad field: {exc}") from None
    nominal = model_robot(obj, str(path))
    if robot is not None:
        check_same_robot(nominal, robot, str(path))
    try:
        model = CalibrationModel(nominal, effects, points=_point_ids(obj, str(path)))
    except InputError as exc:  # e.g. a user effect whose --effects-module is missing
        raise InputError(f"{path}: {exc}") from None
    if names != model.param_names():
        raise InputError(f"{path}: parameters do not match robot {nominal.name!r} with effects {effects}")
    theta = torch.tensor(values, dtype=torch.float64)
    std = torch.tensor(stds, dtype=torch.float64)
    if obj["format"] != FORMAT_RAD:  # version 2: degrees (file_unit) -> radians inside
        units, k = file_units(model)
        bad = [f"{n} ({u!r}, expected {e!r})" for n, u, e in zip(names, file_unit_names, units)
               if u != e and not _old_label(n, u, e)]
        if bad:
            raise InputError(f"{path}: parameter unit(s) not those of {FORMAT}: {', '.join(bad[:3])}")
        _check_sizes(model, values, file_unit_names, path)
        theta, std = theta / k, std / k
    where = str(path)
    fit = _block(obj, "fit", where)
    plaus = _block(obj, "plausibility", where)
    try:
        training = None
        if isinstance(fit.get("rms_mm"), (int, float)):
            training = {"n": int(fit.get("n", 0)), "rms_mm": float(fit["rms_mm"]),
                        "max_mm": float(fit.get("max_mm", fit["rms_mm"]))}
        settings = dict(robust=fit.get("robust"), sigma_mm=float(fit.get("sigma_mm", SIGMA_MM)),
                        sigma_deg=float(fit.get("sigma_deg", SIGMA_DEG)), status=str(fit.get("status", "converged")),
                        n_iter=int(fit.get("iterations", 0)), outliers=[int(i) for i in fit.get("outlier_poses", [])])
        limits = None if not plaus else {k: plaus[k] for k in ("max_length_mm", "max_angle_deg", "prior_sigma_mm")}
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: bad 'fit' or 'plausibility': {exc}") from None
    stage = None  # the optional non-physical residual stage
    if obj.get("residual_model") is not None:
        from torchcal.calibration.residual_model import from_dict
        stage = from_dict(obj["residual_model"], nominal, where)
    q_range = poses = None  # (2, n), (K, n) rad / mm; absent from files written before they existed
    if obj.get("calibrated_range") is not None:
        from torchcal.calibration.joint_range import poses_from_dict, range_from_dict
        q_range = range_from_dict(obj["calibrated_range"], nominal, where)
        poses = poses_from_dict(obj["calibrated_range"], nominal, where)
    from torchcal.calibration.joint_range import conditions_from_dict
    conditions = conditions_from_dict(obj.get("calibrated_conditions"), where)  # None in older files
    radius = None  # the interval of each parameter, of an interval calibration
    if all("interval" in p for p in params) and params:
        try:
            iv = torch.tensor([[float(v) for v in p["interval"]] for p in params], dtype=torch.float64)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{path}: bad parameter 'interval': {exc}") from None
        if iv.shape[1:] != (2,) or not bool(torch.isfinite(iv).all()):
            raise InputError(f"{path}: parameter 'interval': expected [lower, upper], two finite numbers per "
                             "parameter (a file edited by hand or corrupted)")
        _interval_bounds(iv[:, 0], iv[:, 1], "parameters", path)
        radius = (iv[:, 1] - iv[:, 0]) / 2 / (1.0 if obj["format"] == FORMAT_RAD else file_units(model)[1])
    res = FitResult(model, theta, std, None, None, _report(obj, model, identified, where), covariance=
                    _covariance(obj, model, where), registration=obj.get("registration"),
                    implausible=list(plaus.get("beyond", [])), orientation=_orientation(obj, where),
                    plausible_limits=limits, q_range=q_range, seed_poses=poses, conditions=conditions, residual_model=stage, training=training,
                    provenance=obj.get("provenance"), set_by_prior=list(plaus.get("set_by_prior", [])),
                    residual_test=obj.get("residual_test"), radius=radius, damping=float(fit.get("damping", 0.0)),
                    **settings)
    if obj.get("zones") is None:
        return res
    zones = [_zone_from_dict(z, res, file_units(model)[1], where) for z in _list(obj, "zones", where)]
    return _zoned(res, zones, obj, _block(obj, "partition", where), str(obj.get("zone_method", "damped")), where)


def _point_ids(obj: dict, where: str) -> list | None:
    """The point ids of the data the model was fitted on: "point_ids" (one or several), else
    the older "points" (several, one tool offset each), else None (not recorded)."""
    ids = obj.get("point_ids", obj.get("points"))
    if ids is None:
        return None
    if not isinstance(ids, list) or not ids or any(isinstance(i, bool) or not isinstance(i, int) for i in ids):
        raise InputError(f"{where}: 'point_ids': expected a list of integer point ids, got {ids!r}")
    if "points" in obj and obj["points"] != ids:
        raise InputError(f"{where}: 'points' {obj['points']!r} and 'point_ids' {ids!r} differ")
    return ids


def _number(p: dict, key: str, i: int, where, default=None) -> float:
    """Parameter `i`'s `key` ("value", "std") as a float: a finite JSON number (a string, a
    null, NaN or infinity, e.g. of a file edited by hand, is one InputError naming the
    parameter). `default` when the key is absent (None: the key is required)."""
    if not isinstance(p, dict):
        raise InputError(f"{where}: parameters[{i}]: expected an object with name, value, unit, std, "
                         f"got {type(p).__name__}")
    name = p.get("name", f"#{i + 1}")
    if key not in p and default is not None:
        return default
    v = p.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        got = "no value" if key not in p else f"{v!r} ({type(v).__name__})"
        raise InputError(f"{where}: parameter {name}: {key!r} must be a number, got {got}")
    if not math.isfinite(v):
        raise InputError(f"{where}: parameter {name}: {key!r} must be finite, got {v!r}")
    return float(v)


# Beyond these sizes (file units) a parameter held by the plausibility prior is no deviation
# of a robot: no joint, link or harmonic term is off by more than a full turn or 100 m.
MAX_FILE_SIZE = {"deg": 360.0, "mm": 1e5}


def _check_sizes(model: CalibrationModel, values, units, where) -> None:
    """InputError naming the first parameter beyond MAX_FILE_SIZE for its unit: a model file
    edited by hand or corrupted (a fit never ends there: the prior holds such a parameter near
    its plausible size, docs/effects.md). Parameters without a prior (the measuring frame,
    "any pose", and the tool offset, "whatever the user mounted") are not bounded: data in
    a site frame far from the robot fit to a base frame that far."""
    names = model.param_names()
    free = set()
    for e, sl in zip(model.effects, model.slices[1:]):
        if e.plausible_max() is None:
            free.update(names[sl])
    for n, v, u in zip(names, values, units):
        lim = MAX_FILE_SIZE.get(u)
        if lim is not None and n not in free and abs(v) > lim:
            raise InputError(f"{where}: parameter {n} = {v:.6g} {u} is beyond any robot (|value| <= {lim:g} {u}): "
                             f"the file was edited or corrupted; refit the model")


def _zoned(glob: FitResult, zones: list, obj: dict, partition: dict, method: str, where: str) -> ZonedFit:
    """The `ZonedFit` of a file: its global fit, zone fits, PARTITION.json dict and method."""
    from torchcal.io.partition_file import partition_from_dict

    part = partition_from_dict(partition, f"{where}: partition")
    listed = [z.get("zone") for z in obj["zones"]]
    if listed != list(range(1, len(listed) + 1)):  # zone k's parameters apply to the partition's zone k
        raise InputError(f"{where}: zones listed as {listed[:8]}{' ...' if len(listed) > 8 else ''}, expected "
                         f"1..{len(listed)} in order (a file edited by hand or corrupted: each entry's parameters "
                         "would apply to another zone)")
    levels = [z.get("level") for z in obj["zones"]]
    if None not in levels and len(levels) == part.n_zones and levels != [int(v) for v in part.zone_level]:
        k = next(i for i, (a, b) in enumerate(zip(levels, part.zone_level)) if a != int(b))
        raise InputError(f"{where}: zone {k + 1} is of level {levels[k]} but the embedded partition's zone {k + 1} "
                         f"of level {int(part.zone_level[k])}: zones and partition do not match (a file edited by "
                         "hand or corrupted)")
    try:
        return ZonedFit.of(glob, zones, part, method, [int(z.get("poses") or 0) for z in obj["zones"]])
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None


def _list(obj: dict, key: str, where: str) -> list:
    """obj[key] as a non-empty list."""
    v = obj.get(key)
    if not isinstance(v, list) or not v:
        raise InputError(f"{where}: {key!r} is not a non-empty list")
    return v


def _zone_fit(model, theta, std, radius, free, info: dict, where: str, shared: dict) -> FitResult:
    """A zone's `FitResult` from its values (model units) and its file entry `info`
    (held, poses, rms_mm, max_mm, damping, iterations, status); shared: the calibrated
    range (q_range, seed_poses) and provenance of the whole model."""
    try:
        rms, poses = info.get("rms_mm"), int(info.get("poses") or 0)
        training = None if rms is None else {"n": poses, "rms_mm": float(rms),
                                             "max_mm": float(info.get("max_mm") or rms)}
        report = Identifiability(free, list(info.get("held", [])), int(free.sum()), float("nan"), {}, poses)
        return FitResult(model, theta, std, None, None, report, int(info.get("iterations", 0)),
                         status=str(info.get("status", "converged")), training=training, radius=radius,
                         damping=float(info.get("damping", 0.0)), **shared)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: zone {info.get('zone')}: bad field: {exc}") from None


def _vector(z: dict, key: str, P: int, where: str, dtype=torch.float64) -> torch.Tensor:
    """(P,) values of a zone entry's `key`; InputError naming the zone and key."""
    try:
        v = torch.tensor(z[key], dtype=dtype)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{where}: zone {z.get('zone')}: missing or bad {key!r}: {exc}") from None
    if v.shape != (P,):
        raise InputError(f"{where}: zone {z.get('zone')}: {key} has {v.numel()} values, expected {P}")
    if v.is_floating_point() and not bool(torch.isfinite(v).all()):
        i = int((~torch.isfinite(v)).nonzero()[0])
        raise InputError(f"{where}: zone {z.get('zone')}: {key}[{i}] is {float(v[i])}, expected a finite number "
                         f"(a file edited by hand or corrupted; calibrate again)")
    return v


def _interval_bounds(lower: torch.Tensor, upper: torch.Tensor, what: str, where: str) -> None:
    """InputError naming the first parameter whose interval is inverted (lower > upper)."""
    bad = (lower > upper).nonzero().flatten()
    if bad.numel():
        i = int(bad[0])
        raise InputError(f"{where}: {what}: parameter {i + 1}: interval lower {float(lower[i]):.6g} > upper "
                         f"{float(upper[i]):.6g}, expected lower <= upper (a file edited by hand or corrupted)")


def _zone_from_dict(z: dict, glob: FitResult, k: torch.Tensor, where: str) -> FitResult:
    """One zone entry of a `ZonedFit` file (file units, factors k) as a `FitResult`."""
    if not isinstance(z, dict):
        raise InputError(f"{where}: a zone entry is not an object")
    P = glob.model.n_params
    theta, lower, upper = (_vector(z, key, P, where) for key in ("value", "lower", "upper"))
    _interval_bounds(lower, upper, f"zone {z.get('zone')}", where)  # in the file's units
    theta, lower, upper = theta / k, lower / k, upper / k
    std = _vector(z, "std", P, where) / k
    shared = {"q_range": glob.q_range, "seed_poses": glob.seed_poses, "provenance": glob.provenance}
    return _zone_fit(glob.model, theta, std, (upper - lower) / 2, _vector(z, "identified", P, where, torch.bool),
                     z, where, shared)


def _interval_file(obj: dict, where: str) -> FitResult:
    """A file of the older interval-model format (module doc): its one zone as a
    `FitResult`, or with a partition a `ZonedFit` whose global fields are zone 1's."""
    from torchcal.calibration.joint_range import poses_from_dict, range_from_dict

    nominal = model_robot(obj, where)
    try:
        model = CalibrationModel(nominal, list(obj["effects"]))
        names = list(obj["parameter_names"])
    except (KeyError, TypeError) as exc:
        raise InputError(f"{where}: missing or malformed field: {exc}") from None
    if names != model.param_names():
        raise InputError(f"{where}: parameter names do not match robot {nominal.name!r} with effects {obj['effects']}")
    block = obj.get("calibrated_range")
    shared = {"q_range": None if block is None else range_from_dict(block, nominal, where),
              "seed_poses": None if block is None else poses_from_dict(block, nominal, where),
              "provenance": dict(obj.get("provenance") or {})}
    P = model.n_params
    zones = []
    for z in _list(obj, "zones", where):
        theta, lower, upper = (_vector(z, key, P, where) for key in ("theta", "lower", "upper"))
        _interval_bounds(lower, upper, f"zone {z.get('zone')}", where)
        zones.append(_zone_fit(model, theta, torch.zeros(P, dtype=torch.float64), (upper - lower) / 2,
                               _vector(z, "free", P, where, torch.bool), z, where, shared))
    if obj.get("partition") is None:
        return zones[0]
    return _zoned(zones[0], zones, obj, obj["partition"], str(obj.get("method", "damped")), where)


def _block(obj: dict, key: str, where: str) -> dict:
    """obj[key] as a dict ({} when absent)."""
    b = obj.get(key)
    if b is None:
        return {}
    if not isinstance(b, dict):
        raise InputError(f"{where}: {key!r} is not an object")
    return b


def _report(obj: dict, model: CalibrationModel, identified: list, where: str) -> Identifiability:
    """The identifiability block (rank, condition number, held parameters, observability)."""
    ident = _block(obj, "identifiability", where)
    free = torch.tensor(identified, dtype=torch.bool)
    try:
        return Identifiability(free, list(ident.get("held_at_nominal", [])), int(ident.get("rank", int(free.sum()))),
                               float(ident.get("condition_number") or float("nan")),
                               dict(ident.get("observability", {})), int(ident.get("poses", 0)))
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: bad 'identifiability': {exc}") from None


def _covariance(obj: dict, model: CalibrationModel, where: str) -> ParameterCovariance | None:
    """The file's `ParameterCovariance` (radians inside), None when it has none."""
    c = obj.get("covariance")
    if c is None:
        return None
    cov = _covariance_matrix(obj, model, where)
    try:
        return ParameterCovariance(cov, int(c.get("dof", 1)), float(c.get("sigma_mm", 0.0)),
                                   str(c.get("method", "rows")), c.get("noise_mm"), c.get("pose_mm"))
    except (TypeError, ValueError, AttributeError) as exc:
        raise InputError(f"{where}: bad 'covariance': {exc}") from None


def _orientation(obj: dict, where: str) -> dict | None:
    """The fit's orientation block as `FitResult.orientation` (tool rotation (3, 3))."""
    o = obj.get("orientation")
    if not isinstance(o, dict) or "tool_rotation_fixed_xyz_deg" not in o:
        return None
    from torchcal.rotations import fixed_xyz_to_matrix
    try:
        r = torch.deg2rad(torch.tensor([float(v) for v in o["tool_rotation_fixed_xyz_deg"]], dtype=torch.float64))
        return {"sigma_mm": float(o["sigma_mm"]), "sigma_deg": float(o["sigma_deg"]),
                "weight_mm_per_rad": math.degrees(float(o["weight_mm_per_deg"])),
                "tool_rotation": fixed_xyz_to_matrix(r), "rms_deg": float(o["rms_deg"])}
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise InputError(f"{where}: bad 'orientation': {exc}") from None


def _read(path) -> dict:
    """The model file's dict, of a format this version reads (FORMAT, or FORMAT_RAD)."""
    obj = read_json(path, "model file")
    if obj.get("format") not in (FORMAT, FORMAT_RAD, FORMAT_INTERVAL):
        raise InputError(f"{path}: not a torchcal model file (format {obj.get('format')!r}, "
                         f"expected {FORMAT!r})")
    return obj


def load_covariance(path, model: CalibrationModel) -> torch.Tensor:
    """(P, P) parameter covariance of MODEL.json (zeros for held parameters), in the
    order of `model.param_names()`; InputError when the file has none (written before
    torchcal recorded it)."""
    return _covariance_matrix(_read(path), model, str(path))


def _covariance_matrix(obj: dict, model: CalibrationModel, where: str) -> torch.Tensor:
    """(P, P) covariance of the file dict `obj` (radians inside, zeros where held)."""
    c = obj.get("covariance")
    names = model.param_names()
    try:
        idx = [names.index(n) for n in c["parameters"]]
        sub = torch.tensor(c["matrix"], dtype=torch.float64).reshape(len(idx), len(idx))
    except (KeyError, TypeError, ValueError, RuntimeError):
        raise InputError(f"{where}: model file has no usable 'covariance' (refit it with this "
                         f"torchcal version)") from None
    if not torch.isfinite(sub).all():
        raise InputError(f"{where}: 'covariance' holds non-finite values")
    neg = [n for n, v in zip(c["parameters"], sub.diagonal().tolist()) if v < 0]
    if neg:  # a variance below zero: a broken or hand-edited file (accuracy would print sigma 0)
        raise InputError(f"{where}: 'covariance' has a negative variance for {', '.join(neg[:5])}")
    if obj["format"] != FORMAT_RAD:  # version 2: file units (degrees) -> radians inside
        k = file_units(model)[1][idx]
        sub = sub / (k[:, None] * k[None, :])
    cov = torch.zeros(len(names), len(names), dtype=torch.float64)
    ii = torch.tensor(idx, dtype=torch.long)
    cov[ii[:, None], ii[None, :]] = sub
    return cov
