"""`Measurements`: measured TCP positions at commanded joint angles (the core data type).

One row per measurement, in the order the measurements were taken; radians and mm inside.
Optional per row: the measured point (reflector id, several per pose) and the measured
orientation (fixed-axis XYZ angles, R = Rz(rz) Ry(ry) Rx(rx)).
Reading and writing the CSV form lives in `torchcal.io.measurement_csv`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from torchcal.errors import InputError
from torchcal.rotations import fixed_xyz_to_matrix

#: degC a robot cell works in; temp_c beyond it is named (thermal_expansion reads temp_c - 20)
CELL_TEMP_C = (-30.0, 60.0)
PAYLOAD_RATIO = 3.0  # payloads beyond this many times the robot's rated payload are named


class ConditionWarning(UserWarning):
    """A temperature (temp_c) or payload (payload_kg), in a file or given as an option, that
    looks like another unit (kelvin, Fahrenheit; grams, pounds)."""


def temperature_cause(median_c: float) -> str:
    """Why temperatures of median `median_c` (read as degC, outside CELL_TEMP_C) look wrong:
    250..350 kelvin, 60..130 degrees Fahrenheit, else beyond any robot cell's."""
    return ("they look like kelvin (degC = K - 273.15)" if 250 <= median_c <= 350 else
            "they look like degrees Fahrenheit (degC = (F - 32) / 1.8)" if CELL_TEMP_C[1] < median_c <= 130 else
            "beyond any robot cell's temperature")


def payload_cause(top_kg: float, rated_kg: float) -> str:
    """Why payloads up to `top_kg` above PAYLOAD_RATIO x the rated payload look wrong."""
    return "grams read as kg?" if top_kg > 100 * rated_kg else "pounds read as kg, or another payload?"


def check_conditions_given(temp_c: float | None = None, payload_kg: float | None = None, robot=None,
                           what: str = "conditions", stacklevel: int = 2) -> None:
    """One `ConditionWarning` per condition given as a number (an option, not a file's
    cells) that looks like another unit: temp_c outside CELL_TEMP_C (degC), payload_kg
    above PAYLOAD_RATIO times `robot`'s rated payload (not judged without one)."""
    import warnings

    lo, hi = CELL_TEMP_C
    if temp_c is not None and not lo <= float(temp_c) <= hi:
        warnings.warn(ConditionWarning(
            f"{what}: temperature {float(temp_c):g} degC is outside {lo:g}..{hi:g} degC: "
            f"{temperature_cause(float(temp_c)).replace('they look', 'it looks')}; the temperature is in degrees "
            "Celsius"), stacklevel=stacklevel + 1)
    rated = float(getattr(robot, "payload_kg", 0.0) or 0.0) if robot is not None else 0.0
    if payload_kg is not None and rated > 0 and float(payload_kg) > PAYLOAD_RATIO * rated:
        warnings.warn(ConditionWarning(
            f"{what}: payload {float(payload_kg):g} kg is above {PAYLOAD_RATIO:g} times the rated payload of "
            f"{robot.name} ({rated:g} kg): {payload_cause(float(payload_kg), rated)} the payload is in kg"),
            stacklevel=stacklevel + 1)

_OPTIONAL = ("payload_kg", "temp_c")

def _as_float(t, name: str) -> torch.Tensor:
    t = torch.as_tensor(t)
    if not t.is_floating_point():
        t = t.to(torch.float64)
    if not torch.isfinite(t).all():
        raise InputError(f"Measurements.{name}: values must be finite")
    return t


def previous_rows(q: torch.Tensor) -> torch.Tensor:
    """(N, n) int64: per joint, the row each row's joint was reached from, for rows q (N, n)
    in measurement order: the last earlier row whose angle differs from the row's, -1 where
    there is none (the joint has not moved yet; it comes from the robot's start, 0)."""
    if q.shape[0] == 0:
        return torch.zeros(q.shape, dtype=torch.int64, device=q.device)
    ext = torch.cat([torch.zeros_like(q[:1]), q])  # (N + 1, n): the start, then the rows
    idx = torch.arange(q.shape[0] + 1, device=q.device).unsqueeze(-1).expand_as(ext)
    moved = torch.cat([torch.zeros_like(q[:1], dtype=torch.bool), ext[1:] != ext[:-1]])
    # row of ext of the last move into each row (0: no move yet, the start)
    last = torch.where(moved, idx, torch.zeros_like(idx)).cummax(0).values[1:]  # (N, n)
    return (last - 2).clamp_min(-1)  # ext row last - 1 is data row last - 2


def previous_angles(q: torch.Tensor) -> torch.Tensor:
    """(N, n) rad: per joint, the last angle before each row that differs from the row's
    (0 before the first row, the robot's start), for rows q (N, n) in measurement order
    (the rows of `previous_rows`)."""
    rows = previous_rows(q)
    return torch.where(rows >= 0, q.gather(0, rows.clamp_min(0)), torch.zeros_like(q))


def split_by_pose(pose: torch.Tensor, fraction: float, seed: int) -> torch.Tensor:
    """(N,) bool: the training rows of a seeded split by pose id.

    pose (N,) int64 pose ids; all rows of one pose fall on one side. The distinct ids
    (sorted) are permuted by numpy's ``default_rng(seed)`` and the first
    ``round(fraction * poses)`` train; ``fraction`` in (0, 1). InputError when either
    side would be empty.
    """
    import numpy as np

    if not 0.0 < float(fraction) < 1.0:
        raise InputError(f"split: fraction must lie strictly between 0 and 1, got {fraction}")
    ids = np.unique(pose.cpu().numpy())
    k = int(round(float(fraction) * len(ids)))
    if not 0 < k < len(ids):
        raise InputError(f"split: fraction {fraction} of {len(ids)} poses leaves "
                         f"{'no training' if k == 0 else 'no validation'} pose")
    train = np.random.default_rng(seed).permutation(ids)[:k]
    return torch.from_numpy(np.isin(pose.cpu().numpy(), train)).to(pose.device)


@dataclass(frozen=True, eq=False)
class Measurements:
    """Measured TCP positions at commanded joint angles, one row per measurement.

    Rows are in the order the measurements were taken (docs/design.md, "Measurement file").

    Attributes:
        pose: (N,) int64 pose ids; repeated measurements of one commanded pose share an id.
        q: (N, n) commanded joint angles in rad (the file holds degrees).
        xyz: (N, 3) measured TCP positions in mm, robot base frame.
        payload_kg: (N,) payload mass in kg (>= 0), or None when the file has no column.
        temp_c: (N,) temperature in degrees Celsius, or None.
        source: the file these came from, or None.
        point: (N,) int64 reflector / marker ids, or None (one point per pose).
        rxyz: (N, 3) rad measured orientation as fixed-axis XYZ angles (rx, ry, rz):
            R = Rz(rz) Ry(ry) Rx(rx), measurement frame <- tool frame; or None.
        q_prev: (N, n) rad, the commanded joint angles the robot moved *from* to reach each
            row: per joint, the last commanded angle before the row that differs from the
            row's (the previous row where the joint moved; a repeat of a pose looks past
            the rows that did not move it), all-zero joints before the first row. Its sign
            against q is the approach direction (`torchcal.effects.context.make_context`).
            Computed from `q` when not given, and carried by `subset`, so
            direction-dependent effects (backlash) stay right on a subset. In the file
            as the columns ``prev_q1..prev_qN`` when present (`torchcal split` writes
            them); without them it is recomputed from the file's own row order.

    The constructor checks shapes and finiteness and raises InputError naming the field.
    """

    pose: torch.Tensor
    q: torch.Tensor
    xyz: torch.Tensor
    payload_kg: torch.Tensor | None = None
    temp_c: torch.Tensor | None = None
    source: str | None = None
    q_prev: torch.Tensor | None = field(default=None, repr=False)
    point: torch.Tensor | None = None
    rxyz: torch.Tensor | None = None

    def __post_init__(self):
        set_ = object.__setattr__
        pose = torch.as_tensor(self.pose)
        if pose.is_floating_point() or pose.is_complex() or pose.dtype == torch.bool:
            raise InputError(f"Measurements.pose: expected integer pose ids, got dtype {pose.dtype}")
        pose = pose.to(torch.int64)
        if pose.ndim != 1:
            raise InputError(f"Measurements.pose: expected shape (N,), got {tuple(pose.shape)}")
        N = pose.shape[0]
        q = _as_float(self.q, "q")
        if q.ndim != 2 or q.shape[0] != N or q.shape[1] < 1:
            raise InputError(f"Measurements.q: expected shape ({N}, n) rad, got {tuple(q.shape)}")
        xyz = _as_float(self.xyz, "xyz")
        if tuple(xyz.shape) != (N, 3):
            raise InputError(f"Measurements.xyz: expected shape ({N}, 3) mm, got {tuple(xyz.shape)}")
        set_(self, "pose", pose)
        set_(self, "q", q)
        set_(self, "xyz", xyz)
        for name in _OPTIONAL:
            v = getattr(self, name)
            if v is None:
                continue
            v = _as_float(v, name)
            if tuple(v.shape) != (N,):
                raise InputError(f"Measurements.{name}: expected shape ({N},), got {tuple(v.shape)}")
            if name == "payload_kg" and (v < 0).any():
                raise InputError("Measurements.payload_kg: payload must be >= 0 kg")
            set_(self, name, v)
        if self.point is not None:
            pt = torch.as_tensor(self.point)
            if pt.is_floating_point() or pt.is_complex() or pt.dtype == torch.bool:
                raise InputError(f"Measurements.point: expected integer point ids, got dtype {pt.dtype}")
            if tuple(pt.shape) != (N,):
                raise InputError(f"Measurements.point: expected shape ({N},), got {tuple(pt.shape)}")
            set_(self, "point", pt.to(torch.int64))
        if self.rxyz is not None:
            r = _as_float(self.rxyz, "rxyz")
            if tuple(r.shape) != (N, 3):
                raise InputError(f"Measurements.rxyz: expected shape ({N}, 3) rad, got {tuple(r.shape)}")
            set_(self, "rxyz", r)
        if self.source is not None:
            set_(self, "source", str(self.source))
        if self.q_prev is None:
            set_(self, "q_prev", previous_angles(q))
        else:
            qp = _as_float(self.q_prev, "q_prev")
            if qp.shape != q.shape:
                raise InputError(f"Measurements.q_prev: expected shape {tuple(q.shape)} rad, "
                                 f"got {tuple(qp.shape)}")
            set_(self, "q_prev", qp)

    def __len__(self) -> int:
        return self.pose.shape[0]

    @property
    def n(self) -> int:
        """Number of joints (q-columns)."""
        return self.q.shape[1]

    @property
    def q_deg(self) -> torch.Tensor:
        """(N, n) commanded joint angles in degrees."""
        return torch.rad2deg(self.q)

    def subset(self, index) -> "Measurements":
        """The rows selected by `index`, kept in measurement (file) order.

        `index`: a slice, a (N,) bool mask, or integer row indices (negative allowed;
        repeats allowed, e.g. for a bootstrap). Whatever the order of `index`, the rows come
        out in the order they were measured; `q_prev` keeps each row's true predecessor.
        """
        N = len(self)
        if isinstance(index, slice):
            rows = torch.arange(N)[index]
        else:
            idx = torch.as_tensor(index)
            if idx.dtype == torch.bool:
                if tuple(idx.shape) != (N,):
                    raise InputError(f"subset: a bool mask must have shape ({N},), got {tuple(idx.shape)}")
                rows = idx.nonzero().flatten()
            elif idx.is_floating_point() or idx.is_complex():
                raise InputError(f"subset: expected integer row indices or a bool mask, got dtype {idx.dtype}")
            else:
                rows = idx.to(torch.int64).flatten()
                if rows.numel() and (rows.min() < -N or rows.max() >= N):
                    raise InputError(f"subset: row indices must lie in [-{N}, {N}), got "
                                     f"{rows.min().item()}..{rows.max().item()}")
                rows = torch.where(rows < 0, rows + N, rows)
        rows = rows.sort().values

        def take(t):
            return None if t is None else t[rows.to(t.device)]
        return Measurements(take(self.pose), take(self.q), take(self.xyz), take(self.payload_kg),
                            take(self.temp_c), self.source, take(self.q_prev), take(self.point),
                            take(self.rxyz))

    def to(self, device=None, dtype=None) -> "Measurements":
        """A copy on `device`; floating tensors cast to `dtype` (pose stays int64)."""
        def mv(t):
            if t is None:
                return None
            return t.to(device=device, dtype=dtype if t.is_floating_point() else None)
        return Measurements(mv(self.pose), mv(self.q), mv(self.xyz), mv(self.payload_kg),
                            mv(self.temp_c), self.source, mv(self.q_prev), mv(self.point),
                            mv(self.rxyz))

    @property
    def rotation(self) -> torch.Tensor | None:
        """(N, 3, 3) measured orientation matrices R = Rz(rz) Ry(ry) Rx(rx), or None."""
        return None if self.rxyz is None else fixed_xyz_to_matrix(self.rxyz)
