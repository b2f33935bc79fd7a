"""PARTITION.json: a `torchcal.partition.zones.Partition` on disk (JSON, never pickle).

    {"format": "torchcal.partition", "version": 2,
     "made_for": {"name", "fingerprint", "nominal_robot"} | null,
     "units", "features": ["x", "y", "z", "r_set"], "m", "r_weight", "knn_neighbors", "options",
     "levels": [{"level", "center_r_set", "zones", "feature_mean", "feature_std"}...],
     "zones": [{"zone", "level", "points", "r_set_min", "r_set_mean", "r_set_max", "center_x_mm",
                "center_y_mm", "center_z_mm", "level_center_r_set", "center_features"}...],
     "points": {"point", "x", "y", "z", "r_set", "zone"}}

Positions in mm, R_set in 0..1; floats are written exactly (shortest repr). Unknown or
missing keys are errors (InputError naming the file and the key).

``made_for`` records the robot the partition (its sweep) was made for
(`torchcal.io.robot_file.robot_record`: name, SHA-256 fingerprint of the nominal kinematics
and joint limits, the robot-file dict); null where unknown (a partition of a sweep CSV of an
older torchcal; the partition a MODEL.json embeds, whose own robot is the model's). Given the
robot it is for, `load_partition` / `partition_from_dict` refuse a partition made for
another (`torchcal.io.robot_file.check_record`: one InputError line naming the file, both
robots and what differs) and read one without a record with one `UnrecordedRobotWarning`.
Files of version 1 (no ``made_for``) read as records of no robot.
"""

from __future__ import annotations

import json

import torch

from torchcal.errors import InputError
from torchcal.io.files import dumps_json, read_json, write_json
from torchcal.io.robot_file import check_record, record_from_dict, robot_record
from torchcal.partition.zones import Partition
from torchcal.robots.robot import Robot

__all__ = ["FORMAT", "VERSION", "partition_to_dict", "partition_from_dict", "partition_record", "partition_to_json",
           "partition_from_json", "save_partition", "load_partition"]

FORMAT = "torchcal.partition"
VERSION = 2
VERSIONS = (1, 2)  # read; version 1: no "made_for"


def partition_to_dict(part: Partition, made_for: Robot | dict | None = None) -> dict:
    """A `Partition` as a JSON-ready dict (see `partition_from_dict`); floats are written exactly (shortest repr).

    made_for: the `Robot` the partition was made for, or a robot record as a sweep CSV
    holds it (`torchcal.io.sweep_csv.sweep_record`, copied as it is); None: unknown (null)."""
    record = robot_record(made_for) if isinstance(made_for, Robot) else \
        None if made_for is None else record_from_dict(made_for, "made_for")
    summ = part.summary()
    levels = [{
        "level": lev, "center_r_set": float(part.level_centers[lev - 1]),
        "zones": [int(z) + 1 for z in torch.nonzero(part.zone_level == lev)[:, 0]],
        "feature_mean": part.feature_mean[lev - 1].tolist(),
        "feature_std": part.feature_std[lev - 1].tolist(),
    } for lev in range(1, part.n_levels + 1)]
    zones = [dict(s, center_features=part.zone_centers[s["zone"] - 1].tolist()) for s in summ]
    return {
        "format": FORMAT, "version": VERSION, "made_for": record,
        "units": {"positions": "mm", "r_set": "1 (set reliability, 0..1)"},
        "features": ["x", "y", "z", "r_set"],
        "m": part.m, "r_weight": part.r_weight, "knn_neighbors": part.knn_neighbors,
        "options": part.options,
        "levels": levels, "zones": zones,
        "points": {
            "point": part.point_ids.tolist(),
            "x": part.positions[:, 0].tolist(), "y": part.positions[:, 1].tolist(),
            "z": part.positions[:, 2].tolist(), "r_set": part.r_set.tolist(),
            "zone": part.labels.tolist(),
        },
    }


def partition_to_json(part: Partition, made_for: Robot | dict | None = None) -> str:
    """Deterministic JSON text of `partition_to_dict`."""
    return dumps_json(partition_to_dict(part, made_for))


def partition_record(obj: dict, where: str = "partition") -> dict | None:
    """The robot record of a partition dict (`partition_to_dict`), checked; None for a
    file of version 1 or ``"made_for": null``. InputError for another format or version."""
    if not isinstance(obj, dict):
        raise InputError(f"{where}: expected a JSON object, got {type(obj).__name__}")
    if obj.get("format") != FORMAT or obj.get("version") not in VERSIONS:
        raise InputError(f"{where}: expected format {FORMAT!r} version {VERSION} (or {VERSIONS[0]}), "
                         f"got {obj.get('format')!r} version {obj.get('version')!r}")
    if obj["version"] == 1:
        return None
    if "made_for" not in obj:
        raise InputError(f"{where}: missing key 'made_for' (the robot it was made for, or null)")
    return None if obj["made_for"] is None else record_from_dict(obj["made_for"], f"{where}: made_for")


def partition_from_dict(obj: dict, where: str = "partition", robot: Robot | None = None) -> Partition:
    """Rebuild a `Partition` from `partition_to_dict` output; unknown or missing keys are errors.

    robot: the `Robot` it is for (module doc): a partition made for another is refused,
    one without a record read with one `UnrecordedRobotWarning`; None: not checked."""
    record = partition_record(obj, where)
    top = {"format", "version", "units", "features", "m", "r_weight", "knn_neighbors",
           "options", "levels", "zones", "points"} | ({"made_for"} if obj["version"] >= 2 else set())
    _keys(obj, top, where)
    if robot is not None:
        check_record(record, robot, where, "sweep and partition")
    try:
        levels = sorted(obj["levels"], key=lambda r: r["level"])
        for i, r in enumerate(levels):
            _keys(r, {"level", "center_r_set", "zones", "feature_mean", "feature_std"}, f"{where}: levels[{i}]")
        zones = sorted(obj["zones"], key=lambda r: r["zone"])
        zone_keys = {"zone", "level", "points", "r_set_min", "r_set_mean", "r_set_max", "center_x_mm",
                     "center_y_mm", "center_z_mm", "level_center_r_set", "center_features"}
        for i, r in enumerate(zones):
            _keys(r, zone_keys, f"{where}: zones[{i}]")
        pts = obj["points"]
        _keys(pts, {"point", "x", "y", "z", "r_set", "zone"}, f"{where}: points")
        f64 = torch.float64
        part = Partition(
            positions=torch.tensor([pts["x"], pts["y"], pts["z"]], dtype=f64).T.contiguous(),
            r_set=torch.tensor(pts["r_set"], dtype=f64),
            labels=torch.tensor(pts["zone"], dtype=torch.int64),
            point_ids=torch.tensor(pts["point"], dtype=torch.int64),
            level_centers=torch.tensor([r["center_r_set"] for r in levels], dtype=f64),
            zone_level=torch.tensor([r["level"] for r in zones], dtype=torch.int64),
            zone_centers=torch.tensor([r["center_features"] for r in zones], dtype=f64).reshape(len(zones), 4),
            feature_mean=torch.tensor([r["feature_mean"] for r in levels], dtype=f64).reshape(len(levels), 4),
            feature_std=torch.tensor([r["feature_std"] for r in levels], dtype=f64).reshape(len(levels), 4),
            m=float(obj["m"]), r_weight=float(obj["r_weight"]), knn_neighbors=int(obj["knn_neighbors"]),
            options=dict(obj["options"]), made_for=record,
        )
    except (TypeError, ValueError, KeyError, RuntimeError) as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"{where}: malformed partition data ({exc})") from None
    part.validate(where)
    return part


def partition_from_json(text: str, where: str = "partition JSON", robot: Robot | None = None) -> Partition:
    """Rebuild from `partition_to_json` text (robot: as for `partition_from_dict`)."""
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{where}: not valid JSON: {exc}") from None
    if not isinstance(obj, dict):
        raise InputError(f"{where}: expected a JSON object")
    return partition_from_dict(obj, where, robot)


def save_partition(part: Partition, path, force: bool = False, inputs=(), made_for: Robot | dict | None = None):
    """Write the JSON file atomically (see `torchcal.io.files.write_json`); made_for: the
    robot it was made for, or the record of its sweep (`partition_to_dict`); None: the
    record the partition was read with (``part.made_for``), if any."""
    record = made_for if made_for is not None else part.made_for
    return write_json(path, partition_to_dict(part, record), force=force, inputs=inputs)


def load_partition(path, robot: Robot | None = None) -> Partition:
    """Read a partition JSON file; robot: the `Robot` it is for, checked against the file's
    record (`partition_from_dict`)."""
    return partition_from_dict(read_json(path, "partition JSON"), str(path), robot)


def _keys(obj, expected: set, where: str) -> None:
    if not isinstance(obj, dict):
        raise InputError(f"{where}: expected a JSON object, got {type(obj).__name__}")
    missing, extra = expected - obj.keys(), obj.keys() - expected
    if missing or extra:
        raise InputError(f"{where}: missing keys {sorted(missing)}, unknown keys {sorted(extra)}")
