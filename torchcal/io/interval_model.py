"""MODEL.json of ``torchcal calibrate``: an `IntervalModel` on disk (JSON, never pickle).

    {"format": "torchcal-interval-model/1", "robot", "nominal_robot", "effects",
     "parameter_names", "parameter_units", "method",
     "zones": [{"zone", "level", "poses", "theta", "lower", "upper", "free", "held",
                "rms_mm", "damping"}...],
     "partition": {PARTITION.json} or null, "provenance",
     "calibrated_range": {"q_min", "q_max", "unit"}}

Values in the model's units (mm, rad, ...); zones 1-based. ``nominal_robot`` embeds the
nominal robot (the robot-file dict, docs/robots.md); ``partition`` is the file of
`torchcal.io.partition_file`; ``calibrated_range`` the calibration data's joint range in
deg (mm for a prismatic joint; `torchcal.calibration.joint_range`), absent in older files.
"""

from __future__ import annotations

import torch

from torchcal.calibration.intervals import IntervalModel
from torchcal.calibration.joint_range import poses_from_dict, range_from_dict, range_to_dict
from torchcal.calibration.model import CalibrationModel
from torchcal.errors import InputError
from torchcal.io.partition_file import partition_from_dict, partition_to_dict
from torchcal.io.robot_file import model_robot, robot_to_dict

__all__ = ["INTERVAL_MODEL_FORMAT", "interval_model_to_dict", "interval_model_from_dict", "load_interval_model"]

INTERVAL_MODEL_FORMAT = "torchcal-interval-model/1"


def interval_model_to_dict(im: IntervalModel, *, source=None, partition_source=None) -> dict:
    """A JSON-ready dict of `im` (see `interval_model_from_dict`): the MODEL.json of
    ``torchcal calibrate``. source: the measurement CSV it was calibrated on, partition_source:
    the PARTITION.json (paths): with `source` the provenance records them, the CSV's SHA-256
    and the torchcal version; without, `im.provenance`."""
    m = im.model
    provenance = im.provenance or {}
    if source is not None:
        import torchcal
        from torchcal.io.modelfile import file_sha256

        provenance = {"input": str(source), "input_sha256": file_sha256(source),
                      "partition": None if partition_source is None else str(partition_source),
                      "torchcal_version": torchcal.__version__}
    zones = []
    for z, info in enumerate(im.zones):
        zones.append({**info, "theta": im.theta[z].tolist(), "lower": im.lower[z].tolist(),
                      "upper": im.upper[z].tolist(), "free": im.free[z].tolist()})
    out = {"format": INTERVAL_MODEL_FORMAT, "robot": m.robot.name,
           "nominal_robot": robot_to_dict(m.robot), "effects": m.specs(),
           "parameter_names": m.param_names(), "parameter_units": m.param_units(),
           "method": im.method, "zones": zones,
           "partition": None if im.partition is None else partition_to_dict(im.partition),
           "provenance": provenance}
    if im.q_range is not None:
        out["calibrated_range"] = range_to_dict(im.q_range, m.robot, im.seed_poses)
    return out


def interval_model_from_dict(obj: dict, where: str = "interval model") -> IntervalModel:
    """Rebuild from `interval_model_to_dict` output; raises InputError naming what is wrong."""
    if obj.get("format") != INTERVAL_MODEL_FORMAT:
        raise InputError(f"{where}: not a torchcal interval model (format {obj.get('format')!r}, "
                         f"expected {INTERVAL_MODEL_FORMAT!r})")
    try:
        model = CalibrationModel(model_robot(obj, where), list(obj["effects"]))
        if list(obj["parameter_names"]) != model.param_names():
            raise InputError(f"{where}: parameter names do not match robot {obj['robot']!r} with "
                             f"effects {obj['effects']}")
        zs = obj["zones"]
        if not zs:
            raise InputError(f"{where}: no zones")
        P = model.n_params

        def vec(z, key, dtype=torch.float64):
            v = torch.tensor(z[key], dtype=dtype)
            if v.shape != (P,):
                raise InputError(f"{where}: zone {z.get('zone')}: {key} has {v.numel()} values, expected {P}")
            return v
        theta = torch.stack([vec(z, "theta") for z in zs])
        lower = torch.stack([vec(z, "lower") for z in zs])
        upper = torch.stack([vec(z, "upper") for z in zs])
        free = torch.stack([vec(z, "free", torch.bool) for z in zs])
        info = [{k: v for k, v in z.items() if k not in ("theta", "lower", "upper", "free")} for z in zs]
        part = None if obj.get("partition") is None else partition_from_dict(obj["partition"], f"{where}: partition")
    except (KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"{where}: missing or malformed field: {exc}") from None
    if part is not None and part.n_zones != len(zs):
        raise InputError(f"{where}: the partition has {part.n_zones} zones but the model {len(zs)}")
    block = obj.get("calibrated_range")
    q_range = None if block is None else range_from_dict(block, model.robot, where)
    poses = None if block is None else poses_from_dict(block, model.robot, where)
    return IntervalModel(model, theta, lower, upper, free, info, part, str(obj.get("method", "global")),
                         dict(obj.get("provenance") or {}), q_range=q_range, seed_poses=poses)


def load_interval_model(path) -> IntervalModel:
    """An `IntervalModel` from a MODEL.json of ``torchcal calibrate`` or of ``torchcal fit``
    (one zone with the fit's parameters; method "fit"): what compensate and export read."""
    from torchcal.io import modelfile
    from torchcal.io.files import read_json

    obj = read_json(path, "model file")
    if obj.get("format") == INTERVAL_MODEL_FORMAT:
        return interval_model_from_dict(obj, str(path))
    return IntervalModel.of_fit(modelfile.load(path))
