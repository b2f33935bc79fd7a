"""The joint range a model was calibrated on, and the rows that leave it.

Effects that depend on a joint angle (gear harmonics, compliance, couplings) and the
geometric parameters themselves are fitted only over the joint values the calibration
data saw; outside that range the model extrapolates. A fitted model records, per
joint, the min and max of the commanded q of its data (`q_range`, (2, n): row 0 min,
row 1 max, rad / mm for a prismatic joint); MODEL.json stores it as
``"calibrated_range": {"q_min", "q_max", "unit"}`` in deg (mm for a prismatic joint).

A value counts as outside when it lies beyond [min, max] by more than the tolerance
``max(RANGE_TOL_FRACTION * (max - min), RANGE_TOL_DEG deg)`` (RANGE_TOL_MM mm for a
prismatic joint): 1 % of the span, at least half a degree.
"""

from __future__ import annotations

import math

import torch

from torchcal.errors import InputError

RANGE_TOL_FRACTION = 0.01  # of the calibrated span
RANGE_TOL_DEG = 0.5  # revolute joints, at least
RANGE_TOL_MM = 0.5  # prismatic joints, at least
SEED_POSES = 32  # calibration poses a model keeps to seed compensate


class CalibratedRangeWarning(UserWarning):
    """Rows or targets lie outside the joint range the model was calibrated on."""


def joint_range(q: torch.Tensor) -> torch.Tensor:
    """(2, n) [min; max] per joint of q (N, n) (rad / mm)."""
    return torch.stack([q.amin(0), q.amax(0)]).detach()


def seed_poses(q: torch.Tensor, k: int = SEED_POSES) -> torch.Tensor:
    """(min(k, N), n) rows of q (N, n) rad / mm spread over the joint space: farthest-point
    sampling (Euclidean in joint values) from row 0, deterministic."""
    q = q.detach()
    if q.shape[0] <= k:
        return q.clone()
    pick = [0]
    d = (q - q[0]).norm(dim=-1)
    for _ in range(k - 1):
        i = int(d.argmax())
        pick.append(i)
        d = torch.minimum(d, (q - q[i]).norm(dim=-1))
    return q[pick].clone()


def range_to_dict(q_range: torch.Tensor, robot, poses: torch.Tensor | None = None) -> dict:
    """{"q_min", "q_max", "unit"[, "poses"]}: q_range (2, n) and the seed poses (K, n)
    rad / mm in deg (mm for a prismatic joint)."""
    user = robot.q_to_user(q_range.detach().to("cpu", torch.float64)).cpu()
    out = {"q_min": user[0].tolist(), "q_max": user[1].tolist(), "unit": robot.joint_units()}
    if poses is not None:
        out["poses"] = robot.q_to_user(poses.detach().to("cpu", torch.float64)).cpu().tolist()
    return out


def poses_from_dict(obj, robot, where: str = "model file") -> torch.Tensor | None:
    """(K, n) rad / mm seed poses of a "calibrated_range" block (deg, mm for a prismatic
    joint), None when the block has none; InputError naming `where` when malformed."""
    rows = (obj or {}).get("poses")
    if rows is None:
        return None
    try:
        q = torch.tensor(rows, dtype=torch.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: bad 'calibrated_range.poses': {exc}") from None
    if q.ndim != 2 or q.shape[1] != robot.n or not torch.isfinite(q).all():
        raise InputError(f"{where}: 'calibrated_range.poses' must be rows of {robot.n} finite joint values")
    return robot.q_from_user(q).detach()


def range_from_dict(obj, robot, where: str = "model file") -> torch.Tensor:
    """(2, n) rad / mm from {"q_min", "q_max", "unit"} (deg, mm for a prismatic joint);
    InputError naming `where` when malformed or for another joint layout."""
    try:
        lo = [float(v) for v in obj["q_min"]]
        hi = [float(v) for v in obj["q_max"]]
        unit = list(obj["unit"])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{where}: bad 'calibrated_range': {exc}") from None
    if not (len(lo) == len(hi) == len(unit) == robot.n) or unit != robot.joint_units():
        raise InputError(f"{where}: 'calibrated_range' has {len(lo)} joints in units {unit}; "
                         f"expected {robot.n} in {robot.joint_units()}")
    if not all(math.isfinite(v) for v in lo + hi) or any(a > b for a, b in zip(lo, hi)):
        raise InputError(f"{where}: 'calibrated_range' needs finite q_min <= q_max per joint")
    return robot.q_from_user(torch.tensor([lo, hi], dtype=torch.float64)).detach()


def _tolerance(q_range: torch.Tensor, prismatic: torch.Tensor) -> torch.Tensor:
    """(n,) tolerance in rad / mm."""
    floor = torch.where(prismatic, torch.full_like(q_range[0], RANGE_TOL_MM),
                        torch.full_like(q_range[0], math.radians(RANGE_TOL_DEG)))
    return torch.maximum(RANGE_TOL_FRACTION * (q_range[1] - q_range[0]), floor)


def outside_range(q: torch.Tensor, q_range: torch.Tensor, prismatic: torch.Tensor) -> torch.Tensor:
    """(N, n) bool: q (N, n) beyond q_range (2, n) by more than the tolerance (rad / mm)."""
    r = q_range.to(q)
    tol = _tolerance(r, prismatic.to(q.device))
    return (q < r[0] - tol) | (q > r[1] + tol)


# The conditions an effect reads (docs/effects.md): a model records the range its data
# spanned of each condition one of its effects reads (`condition_range`); MODEL.json keeps
# it as ``"calibrated_conditions": {"temp_c": [lo, hi], "payload_kg": [lo, hi]}`` (degC,
# kg). A row counts as outside when beyond [lo, hi] by more than
# max(RANGE_TOL_FRACTION * (hi - lo), the floor below).
#: (name in Measurements / Context, the effect's flag, words, unit, tolerance floor)
CONDITIONS = (("temp_c", "uses_temperature", "temperature", "degC", 0.5),
              ("payload_kg", "uses_payload", "payload", "kg", 0.1))


class ConditionRangeWarning(UserWarning):
    """Rows or targets at a temperature or payload outside the range the model was fitted on."""


def condition_range(effects, ctx) -> dict | None:
    """{name: [lo, hi]} (degC, kg) of each condition (CONDITIONS) that one of `effects`
    reads, over the rows of the Context `ctx` (payload_kg zeros when not measured); None
    when no effect reads one."""
    out = {}
    for name, flag, *_ in CONDITIONS:
        v = getattr(ctx, name)
        if v is not None and v.numel() and any(getattr(e, flag, False) for e in effects):
            out[name] = [float(v.min()), float(v.max())]
    return out or None


def conditions_from_dict(obj, where: str = "model file") -> dict | None:
    """The "calibrated_conditions" block of a model file (None: absent, a file written
    before torchcal recorded it); InputError naming `where` when malformed."""
    if obj is None:
        return None
    names = {c[0] for c in CONDITIONS}
    try:
        out = {str(k): [float(v[0]), float(v[1])] for k, v in dict(obj).items()}
    except (TypeError, ValueError, IndexError, KeyError) as exc:
        raise InputError(f"{where}: bad 'calibrated_conditions': {exc}") from None
    bad = [k for k, (lo, hi) in out.items() if k not in names or not (math.isfinite(lo) and math.isfinite(hi))
           or lo > hi]
    if bad:
        raise InputError(f"{where}: 'calibrated_conditions': {bad[0]!r} needs to be one of {sorted(names)} "
                         f"with finite [lo, hi], lo <= hi")
    return out


def conditions_outside(ranges: dict | None, values: dict) -> list[tuple]:
    """[(words, unit, lo, hi, rows outside, rows, farthest value)] for each recorded
    condition of `ranges` (`condition_range`) whose `values` ({name: (N,) tensor, a number
    or None}; payload_kg None reads as 0 kg, as `make_context` does; temp_c None is not
    judged) leave [lo, hi] by more than the tolerance."""
    out = []
    for name, _, words, unit, floor in CONDITIONS:
        if not ranges or name not in ranges:
            continue
        v = values.get(name)
        if v is None and name == "payload_kg":
            v = 0.0
        if v is None:
            continue
        v = torch.as_tensor(v, dtype=torch.float64).detach().cpu().reshape(-1)
        lo, hi = ranges[name]
        tol = max(RANGE_TOL_FRACTION * (hi - lo), floor)
        off = (v < lo - tol) | (v > hi + tol)
        if bool(off.any()):
            far = torch.where(off, torch.maximum(lo - v, v - hi), torch.full_like(v, -1.0)).argmax()
            out.append((words, unit, lo, hi, int(off.sum()), v.numel(), float(v[far])))
    return out
