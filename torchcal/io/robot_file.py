"""Robot files: a serial robot's nominal MD-H table as JSON (degrees and mm).

    {"name": "my_robot",
     "joints": [{"type": "revolute" | "prismatic",
                 "theta_offset_deg": f, "d_mm": f, "a_mm": f, "alpha_deg": f,
                 "beta_deg": f,            # optional: present = the joint carries a Hayati beta
                 "lower": f, "upper": f},  # deg (revolute) or mm (prismatic)
                ...],
     "base": 4x4 (mm, optional), "tool": 4x4 (mm, optional), "payload_kg": f (optional),
     "gravity": [gx, gy, gz] (optional unit vector in the base frame, default [0, 0, -1]),
     "urdf": {"path", "base_link", "tip_link"} (optional, written by `torchcal robot import`),
     "effects": [...] (optional, informational, written by `torchcal export`),
     "clearance": {"radii_mm": [2n], "clearance_mm": [2n], "bearing_length_mm": [n],
                   "mode": "contact" | "disc"} (optional: the joint-clearance model of
                   `torchcal sweep`, mm, seats 2j-1 and 2j belong to joint j; radii_mm and
                   mode may be left out; torchcal.reliability.uncertainty),
     "gear_ratio": [r1, ..., rn] (optional: per joint the reducer ratio, motor turns per
                   joint turn, > 0, or null where unknown; the `gear_transmission` effect)}

MD-H link transform A_i = Rz(theta) Tz(d) Tx(a) Rx(alpha) Ry(beta). A revolute joint's q
(rad inside, degrees in files) adds to theta; a prismatic joint's q (mm) adds to d.
Unknown keys are errors (a typo must not be ignored); every error is one line naming the
file and the key. Provenance and notes are free: the keys "notes" and "source" and any key
that starts with "x_" (at the top level and in a joint) are accepted and ignored.

The robot a sweep CSV or a partition file was made for (`robot_record`, docs/formats.md):

    {"name": NAME, "fingerprint": SHA-256 hex, "nominal_robot": {ROBOT FILE}}

``fingerprint`` (`robot_fingerprint`) is the SHA-256 of the float64 bytes of the MD-H
table (rad, mm), the joint limits, the base, the tool and the joint types, the identity
of the nominal kinematics and joint limits (the sweep's partial-output manifest uses the
same); ``nominal_robot`` the robot-file dict (degrees, mm), as MODEL.json embeds it, less
its "clearance" section (the clearance model is the sweep's own input).
`check_record` holds a record against the robot a command is given.
"""

from __future__ import annotations

import hashlib
import math
import re
import warnings
from pathlib import Path

import torch

from torchcal.errors import InputError
from torchcal.robots.checks import robot_differences
from torchcal.robots.robot import Robot

JOINT_KEYS = {"type", "theta_offset_deg", "d_mm", "a_mm", "alpha_deg", "beta_deg", "lower", "upper"}
TOP_KEYS = {"name", "joints", "base", "tool", "payload_kg", "gravity", "urdf", "effects", "clearance",
            "gear_ratio"}
URDF_KEYS = {"path", "base_link", "tip_link"}
NOTE_KEYS = {"notes", "source"}  # free provenance / notes, with any key starting "x_"


def _unknown(obj: dict, known: set) -> list[str]:
    """Keys of `obj` that are neither `known` nor notes (NOTE_KEYS, "x_..."), sorted."""
    return sorted(k for k in set(obj) - known - NOTE_KEYS if not str(k).startswith("x_"))


def _num(where: str, key: str, v) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InputError(f"{where}: {key}: expected a finite number, got {v!r}")
    return float(v)


def _matrix(where: str, key: str, v) -> torch.Tensor:
    if (not isinstance(v, list) or len(v) != 4
            or any(not isinstance(r, list) or len(r) != 4 for r in v)):
        raise InputError(f"{where}: {key}: expected a 4x4 matrix (list of 4 rows of 4 numbers, mm)")
    T = torch.tensor([[_num(where, f"{key}[{i}][{j}]", x) for j, x in enumerate(r)] for i, r in enumerate(v)],
                     dtype=torch.float64)
    if not torch.equal(T[3], torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64)):
        raise InputError(f"{where}: {key}: last row must be [0, 0, 0, 1], got {T[3].tolist()}")
    R = T[:3, :3]
    err = float((R.T @ R - torch.eye(3, dtype=torch.float64)).abs().max())
    if err > 1e-6 or float(torch.linalg.det(R)) < 0:
        raise InputError(f"{where}: {key}: the upper-left 3x3 is not a rotation (|R^T R - I| = {err:.3g})")
    return T


def robot_from_dict(obj, where: str = "robot file") -> Robot:
    """Validate a robot-file dict and build the `Robot` (radians and mm inside).

    `where` names the source in error messages (the file path)."""
    if not isinstance(obj, dict):
        raise InputError(f"{where}: expected a JSON object with keys name, joints[, base, tool, payload_kg, gravity]")
    unknown = _unknown(obj, TOP_KEYS)
    if unknown:
        raise InputError(f"{where}: unknown key(s) {', '.join(unknown)}; expected {', '.join(sorted(TOP_KEYS))} "
                         f"(notes: {', '.join(sorted(NOTE_KEYS))} or any key starting with x_)")
    for key in ("name", "joints"):
        if key not in obj:
            raise InputError(f"{where}: missing key {key!r}")
    name = obj["name"]
    if not isinstance(name, str) or not name.strip():
        raise InputError(f"{where}: name: expected a non-empty string, got {name!r}")
    joints = obj["joints"]
    if not isinstance(joints, list) or not joints:
        raise InputError(f"{where}: joints: expected a non-empty list of joint objects")
    rows, has_beta, limits, pris = [], [], [], []
    for i, j in enumerate(joints, start=1):
        key = f"joints[{i}]"  # 1-based, as joints are numbered everywhere else
        if not isinstance(j, dict):
            raise InputError(f"{where}: {key}: expected an object")
        unknown = _unknown(j, JOINT_KEYS)
        if unknown:
            raise InputError(f"{where}: {key}: unknown key(s) {', '.join(unknown)}; "
                             f"expected {', '.join(sorted(JOINT_KEYS))} "
                             f"(notes: {', '.join(sorted(NOTE_KEYS))} or any key starting with x_)")
        missing = [k for k in ("type", "theta_offset_deg", "d_mm", "a_mm", "alpha_deg", "lower", "upper") if k not in j]
        if missing:
            raise InputError(f"{where}: {key}: missing key(s) {', '.join(missing)}")
        if j["type"] not in ("revolute", "prismatic"):
            raise InputError(f"{where}: {key}.type: expected 'revolute' or 'prismatic', got {j['type']!r}")
        p = j["type"] == "prismatic"
        vals = {k: _num(where, f"{key}.{k}", j[k]) for k in JOINT_KEYS - {"type"} if k in j}
        lo, hi = vals["lower"], vals["upper"]
        if not lo < hi:
            raise InputError(f"{where}: {key}: lower ({lo:g}) must be below upper ({hi:g}) "
                             f"({'mm' if p else 'deg'})")
        rows.append([math.radians(vals["theta_offset_deg"]), vals["d_mm"], vals["a_mm"],
                     math.radians(vals["alpha_deg"]), math.radians(vals.get("beta_deg", 0.0))])
        has_beta.append("beta_deg" in j)
        limits.append([lo, hi] if p else [math.radians(lo), math.radians(hi)])
        pris.append(p)
    base = _matrix(where, "base", obj["base"]) if "base" in obj else torch.eye(4, dtype=torch.float64)
    tool = _matrix(where, "tool", obj["tool"]) if "tool" in obj else torch.eye(4, dtype=torch.float64)
    payload = _num(where, "payload_kg", obj["payload_kg"]) if "payload_kg" in obj else 0.0
    if payload < 0:
        raise InputError(f"{where}: payload_kg: expected a number >= 0, got {payload:g}")
    gravity = torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64)
    if "gravity" in obj:
        g = obj["gravity"]
        if not isinstance(g, list) or len(g) != 3:
            raise InputError(f"{where}: gravity: expected [gx, gy, gz], a unit vector in the base frame")
        gravity = torch.tensor([_num(where, f"gravity[{k}]", x) for k, x in enumerate(g)], dtype=torch.float64)
        norm = float(gravity.norm())
        if abs(norm - 1.0) > 1e-6:
            raise InputError(f"{where}: gravity: expected a unit vector, got length {norm:.6g}")
    urdf = obj.get("urdf")
    if urdf is not None:
        if not isinstance(urdf, dict) or set(urdf) != URDF_KEYS or not all(isinstance(v, str) for v in urdf.values()):
            raise InputError(f"{where}: urdf: expected {{\"path\", \"base_link\", \"tip_link\"}} (strings)")
    if "effects" in obj and not isinstance(obj["effects"], list):
        raise InputError(f"{where}: effects: expected a list (informational, written by torchcal export)")
    clearance = None
    if "clearance" in obj:
        from torchcal.reliability.uncertainty import clearance_from_dict

        clearance = clearance_from_dict(obj["clearance"], f"{where}: clearance", len(rows)).to_dict()
    from torchcal.robots.checks import check_robot_angles, check_robot_lengths

    table, lims, prismatic = (torch.tensor(rows, dtype=torch.float64), torch.tensor(limits, dtype=torch.float64),
                              torch.tensor(pris))
    check_robot_lengths(table, prismatic, lims, where)  # lengths in metres
    check_robot_angles(table, prismatic, lims, where)  # angles in radians
    ratio = _gear_ratio(where, obj["gear_ratio"], len(rows)) if "gear_ratio" in obj else None
    return Robot(name, table, torch.tensor(has_beta), lims, base, tool, payload, gravity,
                 prismatic, None if urdf is None else dict(urdf), clearance, ratio)


def _gear_ratio(where: str, v, n: int) -> tuple:
    """The "gear_ratio" list: n entries, each a number > 0 or None (unknown); one below 1
    is named in a warning (`torchcal.robots.checks.check_gear_ratio`)."""
    from torchcal.robots.checks import check_gear_ratio
    if not isinstance(v, list) or len(v) != n:
        raise InputError(f"{where}: gear_ratio: expected a list of {n} reducer ratios (one per joint, "
                         f"null where unknown)")
    out = []
    for i, x in enumerate(v, start=1):
        r = None if x is None else _num(where, f"gear_ratio[{i}]", x)
        if r is not None and r <= 0:
            raise InputError(f"{where}: gear_ratio[{i}]: expected a ratio > 0 or null, got {r:g}")
        out.append(r)
    check_gear_ratio(out, where)
    return tuple(out)


def robot_to_dict(robot: Robot, effects=None) -> dict:
    """The robot-file dict of `robot` (degrees, mm). `effects`: optional list stored
    under "effects" (informational)."""
    r = robot.to(device="cpu", dtype=torch.float64)
    joints = []
    for i in range(r.n):
        off, d, a, alpha, beta = r.table[i].tolist()
        p = bool(r.prismatic[i])
        lo, hi = r.limits[i].tolist()
        j = {"type": "prismatic" if p else "revolute", "theta_offset_deg": math.degrees(off), "d_mm": d,
             "a_mm": a, "alpha_deg": math.degrees(alpha)}
        if bool(r.has_beta[i]):
            j["beta_deg"] = math.degrees(beta)
        j["lower"], j["upper"] = (lo, hi) if p else (math.degrees(lo), math.degrees(hi))
        joints.append(j)
    obj = {"name": r.name, "joints": joints, "base": r.base.tolist(), "tool": r.tool.tolist(),
           "payload_kg": float(r.payload_kg), "gravity": r.gravity.tolist()}
    if r.urdf is not None:
        obj["urdf"] = dict(r.urdf)
    if r.clearance is not None:
        obj["clearance"] = dict(r.clearance)
    if r.gear_ratio is not None:
        obj["gear_ratio"] = list(r.gear_ratio)
    if effects:
        obj["effects"] = list(effects)
    return obj


def load_robot_file(path) -> Robot:
    """The `Robot` of the robot file at `path`; one InputError line naming file and key.
    Consecutive parallel axes without a Hayati beta are named in one warning
    (`torchcal.robots.checks.warn_parallel_axes`; not for a model file's embedded
    robot, which was named when the model was fitted)."""
    from torchcal.io.files import read_json
    from torchcal.robots.checks import warn_parallel_axes

    p = Path(path)
    if p.suffix.lower() in (".urdf", ".xacro", ".xml") or (p.is_file() and p.read_bytes()[:200].lstrip().startswith(b"<")):
        raise InputError(f"{path}: this is a URDF (XML), not a torchcal robot file (JSON); convert it first: "
                         f"torchcal robot import {path} --base BASE_LINK --tip TIP_LINK --out ROBOT.json")
    robot = robot_from_dict(read_json(path, "robot file"), str(path))
    warn_parallel_axes(robot, str(path), stacklevel=2)
    return robot


def write_robot_file(path, robot: Robot, effects=None, force: bool = False, inputs=()) -> Path:
    """Atomically write `robot` as a robot file (JSON, degrees and mm)."""
    from torchcal.io.files import write_json

    return write_json(path, robot_to_dict(robot, effects), force=force, inputs=inputs)


def model_robot(obj: dict, where: str) -> Robot:
    """The nominal robot of a model file's dict: the embedded robot file under
    "nominal_robot" or, in model files written before it existed, the preset "robot"."""
    if "nominal_robot" in obj:
        return robot_from_dict(obj["nominal_robot"], f"{where}: nominal_robot")
    if "robot" not in obj:
        raise InputError(f"{where}: model file names no robot (keys nominal_robot or robot)")
    return robot(obj["robot"])


def robot(name) -> Robot:
    """A preset robot ('kr1000titan', 'ur5e', 'puma560', `torchcal.robots.robot.PRESETS`),
    the robot file at path `name` (JSON, this module) or a `Robot` as it is."""
    from torchcal.robots.robot import PRESETS, preset

    if isinstance(name, Robot) or (isinstance(name, str) and name.lower() in PRESETS):
        return preset(name)
    if isinstance(name, (str, Path)) and (Path(name).suffix.lower() == ".json" or Path(name).is_file()):
        return load_robot_file(name)
    raise InputError(f"unknown robot {str(name)!r}; expected one of {', '.join(sorted(PRESETS))} "
                     f"or the path of a robot file (.json)")


class UnrecordedRobotWarning(UserWarning):
    """A sweep or partition file that records no robot (written before torchcal recorded
    it): it reads as before, but whether it was made for the given robot is not checked."""


RECORD_KEYS = {"name", "fingerprint", "nominal_robot"}


def robot_fingerprint(robot: Robot) -> str:
    """SHA-256 hex digest of the robot's nominal kinematics and joint limits: the float64
    bytes (CPU) of the table (n, 5), limits (n, 2), base, tool and joint types (0 / 1)."""
    r = robot.to("cpu", torch.float64)
    h = hashlib.sha256()
    for t in (r.table, r.limits, r.base, r.tool, r.prismatic):
        h.update(t.detach().to("cpu", torch.float64).contiguous().numpy().tobytes())
    return h.hexdigest()


def robot_record(robot: Robot) -> dict:
    """The record of the robot a file is made for (module doc): name, fingerprint and
    the robot-file dict."""
    nominal = robot_to_dict(robot)
    nominal.pop("clearance", None)  # the sweep's clearance model is its own input (a robot file's or --clearance)
    return {"name": robot.name, "fingerprint": robot_fingerprint(robot), "nominal_robot": nominal}


def record_from_dict(obj, where: str) -> dict:
    """A robot record read from a file, checked (keys, name, a SHA-256 hex fingerprint,
    a valid robot-file dict; `where` names the file and key in the one-line InputError)."""
    if not isinstance(obj, dict):
        raise InputError(f"{where}: expected an object {{name, fingerprint, nominal_robot}}, "
                         f"got {type(obj).__name__}")
    missing, extra = RECORD_KEYS - obj.keys(), obj.keys() - RECORD_KEYS
    if missing or extra:
        raise InputError(f"{where}: missing keys {sorted(missing)}, unknown keys {sorted(extra)}")
    if not isinstance(obj["name"], str) or not obj["name"].strip():
        raise InputError(f"{where}: name: expected a non-empty string, got {obj['name']!r}")
    if not isinstance(obj["fingerprint"], str) or not re.fullmatch(r"[0-9a-f]{64}", obj["fingerprint"]):
        raise InputError(f"{where}: fingerprint: expected a SHA-256 digest (64 hex digits), got {obj['fingerprint']!r}")
    robot_from_dict(obj["nominal_robot"], f"{where}: nominal_robot")
    return obj


def check_record(record: dict | None, robot: Robot, where: str, what: str) -> None:
    """Refuse a file made for another robot: `record` (`record_from_dict`, None for a file
    written before records existed: one `UnrecordedRobotWarning`) against the given
    `robot`. The same fingerprint, or the same joint count, types, MD-H table, base, tool
    and joint limits up to 1e-9 (a robot read back from a file), pass; a name alone does
    not matter. Otherwise one InputError line: `where` (the file), both robots with their
    fingerprints, what differs (`torchcal.robots.checks.robot_differences`) and
    `what` to make again ("sweep", "sweep and partition")."""
    if record is None:
        warnings.warn(f"{where}: records no robot (a file of an older torchcal, or made from one): could not check "
                      f"that it was made for robot {robot.name!r}", UnrecordedRobotWarning, stacklevel=3)
        return
    mine = robot_fingerprint(robot)
    if record["fingerprint"] == mine:
        return
    diff = robot_differences(robot_from_dict(record["nominal_robot"], f"{where}: nominal_robot"), robot)
    if not diff:
        return
    raise InputError(f"{where}: made for robot {record['name']!r} (fingerprint {record['fingerprint'][:12]}), "
                     f"not {robot.name!r} (fingerprint {mine[:12]}): {'; '.join(diff)}; make the {what} again "
                     f"for this robot")
