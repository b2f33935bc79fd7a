"""MODEL.json: a fitted model on disk (JSON, never pickle).

    {"format": "torchcal-model/1", "robot": NAME, "effects": [SPEC...],
     "parameters": [{"name", "value", "unit", "std", "identified", "ci95"}...],
     "covariance": {"method", "dof", "sigma_mm", "noise_mm", "pose_mm", "parameters", "matrix"},
     "identifiability": {...}, "fit": {"n", "rms_mm", "max_mm", "robust", "outliers"},
     "provenance": {"input", "input_sha256", "torchcal_version", "seed"}}

Values are in the units named beside them (mm, rad, 1/K, ...); ``std`` is the standard
error (0 for parameters held at nominal), ``ci95`` its 95 % interval [lower, upper]
(Student's t), ``covariance`` the full covariance of the identified parameters (row
'rows' or 'pose-level' when poses repeat; `torchcal.calibration.uncertainty`). Loading rebuilds the `CalibrationModel` and
theta exactly (floats are written with full precision).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import torch

import torchcal
from torchcal.errors import InputError
from torchcal.calibration.fit import FitResult
from torchcal.io.files import read_json
from torchcal.calibration.model import CalibrationModel
from torchcal.robots.robot import robot as make_robot

FORMAT = "torchcal-model/1"


def file_sha256(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def to_dict(res: FitResult, source=None, seed: int = 0, robust=None, pose_ids=None) -> dict:
    model = res.model
    dist = res.residuals.norm(dim=-1)
    lo, hi = (res.theta, res.theta) if res.covariance is None else res.covariance.interval95(res.theta)
    outliers = res.outliers if pose_ids is None else sorted({int(pose_ids[i]) for i in res.outliers})
    return {
        "format": FORMAT,
        "robot": model.robot.name,
        "effects": model.specs(),
        "parameters": [
            {"name": n, "unit": u, "value": float(v), "std": float(s), "identified": bool(f),
             "ci95": [float(a), float(b)]}
            for n, u, v, s, f, a, b in zip(model.param_names(), model.param_units(), res.theta.tolist(),
                                           res.std.tolist(), res.report.free.tolist(), lo.tolist(),
                                           hi.tolist())],
        "covariance": None if res.covariance is None else res.covariance.to_dict(model.param_names()),
        "identifiability": res.report.to_dict(),
        "fit": {"n": int(res.residuals.shape[0]), "rms_mm": res.rms_mm, "max_mm": float(dist.max()),
                "robust": robust, "outlier_poses": outliers, "iterations": res.n_iter},
        "provenance": {"input": None if source is None else str(source),
                       "input_sha256": None if source is None else file_sha256(source),
                       "torchcal_version": torchcal.__version__, "seed": seed},
    }


def load(path, robot_name: str | None = None):
    """(CalibrationModel, theta (P,)) from MODEL.json; checks the robot when given."""
    obj = read_json(path, "model file")
    if obj.get("format") != FORMAT:
        raise InputError(f"{path}: not a torchcal model file (format {obj.get('format')!r}, "
                         f"expected {FORMAT!r})")
    try:
        name, effects, params = obj["robot"], obj["effects"], obj["parameters"]
        values = [float(p["value"]) for p in params]
        names = [p["name"] for p in params]
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{path}: model file is missing or has a bad field: {exc}") from None
    if robot_name is not None and robot_name != name:
        raise InputError(f"{path}: model file is for robot {name!r}, not {robot_name!r}")
    try:
        model = CalibrationModel(make_robot(name), effects)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
    if names != model.param_names():
        raise InputError(f"{path}: parameters do not match robot {name!r} with effects {effects}")
    return model, torch.tensor(values, dtype=torch.float64)


def load_covariance(path, model: CalibrationModel) -> torch.Tensor:
    """(P, P) parameter covariance of MODEL.json (zeros for held parameters), in the
    order of `model.param_names()`; InputError when the file has none (written before
    torchcal recorded it)."""
    obj = read_json(path, "model file")
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
    cov = torch.zeros(len(names), len(names), dtype=torch.float64)
    ii = torch.tensor(idx, dtype=torch.long)
    cov[ii[:, None], ii[None, :]] = sub
    return cov
