"""MODEL.json: a fitted model on disk (JSON, never pickle).

    {"format": "torchcal-model/2", "robot": NAME, "nominal_robot": {ROBOT FILE},
     "effects": [SPEC...],
     "parameters": [{"name", "value", "unit", "std", "identified", "ci95"}...],
     "covariance": {"method", "dof", "sigma_mm", "noise_mm", "pose_mm", "parameters", "units", "matrix"},
     "identifiability": {...}, "fit": {"n", "rms_mm", "max_mm", "robust", "sigma_mm", "sigma_deg", "outlier_poses",
             "iterations", "status"},
     "provenance": {"input", "input_sha256", "torchcal_version", "seed"},
     "calibrated_range": {"q_min": [...], "q_max": [...], "unit": ["deg" | "mm", ...]}
                     (per joint min and max of the calibration data's commanded q),
     optional: "points": [ID...] (one tool offset per measured point),
     "base_frame": {"translation_mm", "rotation_fixed_xyz_deg"} (measurement <- robot base),
     "registration": {"rms_before_mm", "rms_after_mm", "translation_mm", "rotation_fixed_xyz_deg",
                      "rotation_angle_deg"} (the closed-form start),
     "plausibility": {"max_length_mm", "max_angle_deg", "prior_sigma_mm", "beyond": [NAME...]},
     "orientation": {"sigma_mm", "sigma_deg", "weight_mm_per_deg", "rms_deg",
                     "tool_rotation_fixed_xyz_deg"},
     "residual_model": {...} (the optional non-physical residual stage,
                       `torchcal.calibration.residual_model`)}

Values are in the units named beside them: mm and degrees (radians inside; `file_unit`:
'rad' -> 'deg', 'rad/mm' -> 'deg/mm', the joint_compliance payload term -> the joint's
compliance in 'deg/(N m)'; '1', '1/K' as they are); ``covariance.matrix`` is in the same
units (``covariance.units``). Files of format "torchcal-model/1" (values in radians) load
as before. ``std`` is the standard
error (0 for parameters held at nominal), ``ci95`` its 95 % interval [lower, upper]
(Student's t), ``covariance`` the full covariance of the identified parameters (row
'rows' or 'pose-level' when poses repeat; `torchcal.calibration.covariance`); ``fit.status`` is how the
solver stopped ('converged', 'stalled' or 'max_iterations'). Loading rebuilds the `CalibrationModel` and
theta exactly (floats are written with full precision). ``nominal_robot`` embeds the
nominal robot (the robot-file dict, docs/robots.md), so a model file needs no preset and
no robot file; files written before it existed name a preset under ``robot``.
``calibrated_range`` (deg, mm for a prismatic joint) lets evaluate and compensate warn
when the model is used outside the joint range it was fitted on
(`torchcal.calibration.joint_range`); `load` puts it on the model as
``model.calibrated_range`` ((2, n) rad / mm, None in files written before it existed).
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import torch

import torchcal
from torchcal.errors import InputError
from torchcal.calibration.fit import FitResult
from torchcal.io.files import read_json
from torchcal.calibration.model import CalibrationModel
from torchcal.effects.joint_compliance import G_NM_PER_KG_MM
from torchcal.robots.robot import Robot
from torchcal.robots.robot_file import check_same_robot, model_robot, robot_to_dict

FORMAT = "torchcal-model/2"
FORMAT_RAD = "torchcal-model/1"  # files written before version 2: values in the model's units (rad)



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


def file_units(model: CalibrationModel) -> tuple[list[str], torch.Tensor]:
    """([unit in files per parameter], (P,) float64 factors) of `model` (`file_unit`)."""
    pairs = [file_unit(u) for u in model.param_units()]
    return [u for u, _ in pairs], torch.tensor([f for _, f in pairs], dtype=torch.float64)


def file_sha256(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def to_dict(res: FitResult, source=None, seed: int = 0, pose_ids=None) -> dict:
    from torchcal.calibration.joint_range import range_to_dict
    from torchcal.calibration.registration import base_frame_summary
    from torchcal.rotations import matrix_to_fixed_xyz

    model = res.model
    dist = res.residuals.norm(dim=-1)
    lo, hi = (res.theta, res.theta) if res.covariance is None else res.covariance.interval95(res.theta)
    outliers = res.outliers if pose_ids is None else sorted({int(pose_ids[i]) for i in res.outliers})
    extra = {}
    if model.points:
        extra["points"] = list(model.points)
    base = base_frame_summary(model, res.theta)
    if base is not None:
        extra["base_frame"] = base
    if res.registration is not None:
        extra["registration"] = dict(res.registration)
    if res.plausible_limits is not None:
        extra["plausibility"] = {**res.plausible_limits, "beyond": list(res.implausible)}
    if res.q_range is not None:
        extra["calibrated_range"] = range_to_dict(res.q_range, model.robot)
    if res.orientation is not None:
        o = res.orientation
        extra["orientation"] = {k: o[k] for k in ("sigma_mm", "sigma_deg", "rms_deg")}
        extra["orientation"]["weight_mm_per_deg"] = math.radians(o["weight_mm_per_rad"])
        extra["orientation"]["tool_rotation_fixed_xyz_deg"] = torch.rad2deg(
            matrix_to_fixed_xyz(o["tool_rotation"].detach().cpu().double())).tolist()
    stage = getattr(model, "residual_model", None)
    if stage is not None:
        extra["residual_model"] = stage.to_dict()
    units, k = file_units(model)  # degrees and mm in the file, radians inside
    cov = None
    if res.covariance is not None:
        cov = res.covariance.to_dict(model.param_names())
        ki = torch.tensor([float(k[model.param_names().index(n)]) for n in cov["parameters"]], dtype=torch.float64)
        mat = torch.tensor(cov["matrix"], dtype=torch.float64).reshape(len(ki), len(ki))
        cov["matrix"] = (ki[:, None] * mat * ki[None, :]).tolist()
        cov["units"] = [units[model.param_names().index(n)] for n in cov["parameters"]]
    theta, std, lo, hi = (t.detach().to("cpu", torch.float64) * k for t in (res.theta, res.std, lo, hi))
    return {
        "format": FORMAT,
        "robot": model.robot.name,
        "nominal_robot": robot_to_dict(model.robot),
        "effects": model.specs(),
        "parameters": [
            {"name": n, "unit": u, "value": float(v), "std": float(s), "identified": bool(f),
             "ci95": [float(a), float(b)]}
            for n, u, v, s, f, a, b in zip(model.param_names(), units, theta.tolist(),
                                           std.tolist(), res.report.free.tolist(), lo.tolist(),
                                           hi.tolist())],
        "covariance": cov,
        "identifiability": res.report.to_dict(),
        "fit": {"n": int(res.residuals.shape[0]), "rms_mm": res.rms_mm, "max_mm": float(dist.max()),
                "robust": res.robust, "sigma_mm": res.sigma_mm, "sigma_deg": res.sigma_deg,
                "outlier_poses": outliers, "iterations": res.n_iter,
                "status": res.status},
        "provenance": {"input": None if source is None else str(source),
                       "input_sha256": None if source is None else file_sha256(source),
                       "torchcal_version": torchcal.__version__, "seed": seed},
        **extra,
    }


def load(path, robot: Robot | str | None = None):
    """(CalibrationModel, theta (P,)) from MODEL.json.

    robot: a `Robot` or a preset name / robot-file path; when given, a model of another
    robot (joint count, types or nominal geometry) is refused with one line naming both."""
    obj = _read(path)
    try:
        effects, params = obj["effects"], obj["parameters"]
        values = [float(p["value"]) for p in params]
        names = [p["name"] for p in params]
        file_unit_names = [p.get("unit") for p in params]
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise InputError(f"{path}: model file is missing or has a bad field: {exc}") from None
    nominal = model_robot(obj, str(path))
    if robot is not None:
        from torchcal.robots.robot import robot as make_robot

        check_same_robot(nominal, make_robot(robot), str(path))
    try:
        model = CalibrationModel(nominal, effects, points=obj.get("points"))
    except InputError as exc:  # e.g. a user effect whose --effects-module is missing
        raise InputError(f"{path}: {exc}") from None
    model.tool_rotation = None  # measured tool frame <- nominal tool frame, when fitted
    orient = obj.get("orientation")
    if isinstance(orient, dict) and "tool_rotation_fixed_xyz_deg" in orient:
        from torchcal.rotations import fixed_xyz_to_matrix
        try:
            r = torch.deg2rad(torch.tensor([float(v) for v in orient["tool_rotation_fixed_xyz_deg"]],
                                           dtype=torch.float64))
        except (TypeError, ValueError) as exc:
            raise InputError(f"{path}: bad orientation.tool_rotation_fixed_xyz_deg: {exc}") from None
        model.tool_rotation = fixed_xyz_to_matrix(r)
    if names != model.param_names():
        raise InputError(f"{path}: parameters do not match robot {nominal.name!r} with effects {effects}")
    theta = torch.tensor(values, dtype=torch.float64)
    if obj["format"] != FORMAT_RAD:  # version 2: degrees (file_unit) -> radians inside
        units, k = file_units(model)
        bad = [f"{n} ({u!r}, expected {e!r})" for n, u, e in zip(names, file_unit_names, units) if u != e]
        if bad:
            raise InputError(f"{path}: parameter unit(s) not those of {FORMAT}: {', '.join(bad[:3])}")
        theta = theta / k
    fit = obj.get("fit")  # the training rms, for the gross-mismatch check (torchcal.calibration.mismatch)
    rms = fit.get("rms_mm") if isinstance(fit, dict) else None
    model.training_rms_mm = float(rms) if isinstance(rms, (int, float)) else None
    model.calibrated_range = None  # (2, n) rad / mm; absent from files written before it existed
    if obj.get("calibrated_range") is not None:
        from torchcal.calibration.joint_range import range_from_dict
        model.calibrated_range = range_from_dict(obj["calibrated_range"], nominal, str(path))
    model.residual_model = None  # the optional non-physical residual stage
    if obj.get("residual_model") is not None:
        from torchcal.calibration.residual_model import from_dict
        model.residual_model = from_dict(obj["residual_model"], nominal, str(path))
    return model, theta


def _read(path) -> dict:
    """The model file's dict, of a format this version reads (FORMAT, or FORMAT_RAD)."""
    obj = read_json(path, "model file")
    if obj.get("format") not in (FORMAT, FORMAT_RAD):
        raise InputError(f"{path}: not a torchcal model file (format {obj.get('format')!r}, "
                         f"expected {FORMAT!r})")
    return obj


def load_covariance(path, model: CalibrationModel) -> torch.Tensor:
    """(P, P) parameter covariance of MODEL.json (zeros for held parameters), in the
    order of `model.param_names()`; InputError when the file has none (written before
    torchcal recorded it)."""
    obj = _read(path)
    c = obj.get("covariance")
    names = model.param_names()
    try:
        idx = [names.index(n) for n in c["parameters"]]
        sub = torch.tensor(c["matrix"], dtype=torch.float64).reshape(len(idx), len(idx))
    except (KeyError, TypeError, ValueError, RuntimeError):
        raise InputError(f"{path}: model file has no usable 'covariance' (refit it with this "
                         f"torchcal version)") from None
    if not torch.isfinite(sub).all():
        raise InputError(f"{path}: 'covariance' holds non-finite values")
    if obj["format"] != FORMAT_RAD:  # version 2: file units (degrees) -> radians inside
        k = file_units(model)[1][idx]
        sub = sub / (k[:, None] * k[None, :])
    cov = torch.zeros(len(names), len(names), dtype=torch.float64)
    ii = torch.tensor(idx, dtype=torch.long)
    cov[ii[:, None], ii[None, :]] = sub
    return cov
