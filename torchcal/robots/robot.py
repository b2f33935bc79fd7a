"""`Robot`: a nominal MD-H table with joint limits, base and tool frames, and presets.

`robot(name)` returns a preset; `Robot` validates user input once (shapes, finiteness)
and calls the strict kernels of `torchcal.kinematics.mdh`.

Presets (lengths mm, angles degrees in the tables below, radians inside):

- ``kr1000titan``: docs/paper.md Table 1, theta offsets zero as in the paper, Hayati beta on
  joint 2. Joint limits from KUKA's data sheet (A1 +-150, A2 -130..+17.5 mapped to the
  MD-H zero, A3 -110..+145 shifted by -90 deg since MD-H q3 = 0 bends the forearm at a right angle, A4 +-350, A5 +-118, A6 +-350); rated payload 1000 kg.
- ``ur5e``: Universal Robots' published DH (d1 162.5, a2 -425, a3 -392.2, d4 133.3,
  d5 99.7, d6 99.6; alpha 90, 0, 0, 90, -90, 0), beta on joints 2 and 3 (parallel axes
  2-3-4), limits +-360, payload 5 kg.
- ``puma560``: the classical standard DH of Corke (a2 431.8, a3 20.32, d3 150.05,
  d4 431.8), beta on joint 2, payload 2.5 kg.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from torchcal.kinematics import mdh as K
from torchcal.kinematics.chain import Chain
from torchcal.errors import InputError

G_MM_S2 = 9806.65  # standard gravity, mm/s^2


@dataclass(frozen=True, eq=False)
class Robot:
    """A serial robot with a nominal MD-H table.

    Joint values q: rad for a revolute joint (q adds to theta), mm for a prismatic joint
    (q adds to d).

    Attributes:
        name: preset name or the robot file's "name".
        table: (n, 5) float64 [theta_offset rad, d mm, a mm, alpha rad, beta rad].
        has_beta: (n,) bool, joints whose Hayati beta the table declares.
        limits: (n, 2) float64 joint limits [lower, upper], rad (revolute) or mm (prismatic).
        base: (4, 4) world <- joint-1 frame (mm).
        tool: (4, 4) flange <- TCP (mm).
        payload_kg: rated payload.
        gravity: (3,) unit vector of gravity in the world (base) frame.
        prismatic: (n,) bool, prismatic joints (None: all revolute).
        urdf: {"path", "base_link", "tip_link"} when imported from a URDF, else None.
        clearance: the robot file's optional "clearance" section (validated dict with
            radii_mm, clearance_mm, bearing_length_mm[, mode]; mm), the joint-clearance
            model of `torchcal sweep` (torchcal.reliability.uncertainty), else None.
        gear_ratio: per joint the reducer ratio (motor turns per joint turn, > 0) or None
            where unknown; None: no ratios given (the robot file's optional "gear_ratio";
            read by the `gear_transmission` effect).
        chain: the kinematic structure (table, prismatic, base, tool) as the kernels of
            `torchcal.kinematics.mdh` take it (built from the fields above).
    """

    name: str
    table: torch.Tensor
    has_beta: torch.Tensor
    limits: torch.Tensor
    base: torch.Tensor = field(default_factory=lambda: torch.eye(4, dtype=torch.float64))
    tool: torch.Tensor = field(default_factory=lambda: torch.eye(4, dtype=torch.float64))
    payload_kg: float = 0.0
    gravity: torch.Tensor = field(default_factory=lambda: torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64))
    prismatic: torch.Tensor | None = None
    urdf: dict | None = None
    clearance: dict | None = None
    gear_ratio: tuple | None = None
    chain: Chain = field(init=False, repr=False)

    def __post_init__(self):
        if self.prismatic is None:
            object.__setattr__(self, "prismatic", torch.zeros(self.table.shape[0], dtype=torch.bool,
                                                              device=self.table.device))
        object.__setattr__(self, "chain", Chain(self.table, self.prismatic, self.base, self.tool))

    def __eq__(self, other) -> bool:
        """Same name, joint types, table, limits, frames, payload and gravity (exact)."""
        if not isinstance(other, Robot):
            return NotImplemented
        tensors = ("table", "has_beta", "limits", "base", "tool", "gravity", "prismatic")
        return (self.name == other.name and self.n == other.n and self.payload_kg == other.payload_kg
                and self.gear_ratio == other.gear_ratio
                and all(getattr(self, t).shape == getattr(other, t).shape
                        and torch.equal(getattr(self, t).cpu(), getattr(other, t).cpu().to(getattr(self, t).dtype))
                        for t in tensors))

    __hash__ = object.__hash__

    def same_geometry(self, other: "Robot", atol: float = 1e-9) -> bool:
        """Same joint count, types, nominal table, base and tool up to `atol` (mm, rad):
        what decides whether a model of one robot may be applied to data of the other
        (names and limits may differ after a round trip through a file)."""
        if self.n != other.n or not torch.equal(self.prismatic.cpu(), other.prismatic.cpu()):
            return False
        return all(torch.allclose(getattr(self, t).cpu().double(), getattr(other, t).cpu().double(),
                                  rtol=0, atol=atol) for t in ("table", "base", "tool"))

    def q_from_user(self, q) -> torch.Tensor:
        """Joint values in file / command-line units (deg revolute, mm prismatic) -> rad / mm."""
        q = torch.as_tensor(q, dtype=self.dtype, device=self.device)
        return torch.where(self.prismatic, q, torch.deg2rad(q))

    def q_to_user(self, q) -> torch.Tensor:
        """Joint values rad / mm -> deg (revolute) / mm (prismatic)."""
        q = torch.as_tensor(q)
        return torch.where(self.prismatic.to(q.device), q, torch.rad2deg(q))

    def joint_units(self) -> list[str]:
        """Per joint: 'deg' or 'mm' (the units of q in files)."""
        return ["mm" if p else "deg" for p in self.prismatic.tolist()]

    @property
    def n(self) -> int:
        """Number of joints."""
        return self.table.shape[0]

    @property
    def dtype(self):
        return self.table.dtype

    @property
    def device(self):
        return self.table.device

    def to(self, device=None, dtype=None) -> "Robot":
        """A copy with every tensor moved to `device` / cast to `dtype`."""
        def mv(t):
            return t.to(device=device, dtype=dtype if t.is_floating_point() else None)
        return Robot(self.name, mv(self.table), self.has_beta.to(device), mv(self.limits),
                     mv(self.base), mv(self.tool), self.payload_kg, mv(self.gravity),
                     self.prismatic.to(device), self.urdf, self.clearance, self.gear_ratio)

    # -- validation -----------------------------------------------------------------
    def check_q(self, q, name: str = "q") -> torch.Tensor:
        """Convert joint values to a tensor of the robot's dtype/device and check them.

        q (..., n) rad (revolute) / mm (prismatic). Raises InputError on a wrong last dimension or non-finite values.
        """
        q = torch.as_tensor(q, device=self.device)
        if not q.is_floating_point():
            q = q.to(self.dtype)
        if q.ndim == 0 or q.shape[-1] != self.n:
            raise InputError(f"{name}: expected joint angles of shape (..., {self.n}) for "
                             f"{self.name}, got shape {tuple(q.shape)}")
        if not torch.isfinite(q).all():
            bad = (~torch.isfinite(q)).nonzero()[0].tolist()
            raise InputError(f"{name}: joint angles must be finite, got {q[tuple(bad)].item()} at index {bad}")
        return q

    def check_params(self, params, name: str = "params") -> torch.Tensor | None:
        """params (..., n, 5) MD-H deviations or None."""
        if params is None:
            return None
        params = torch.as_tensor(params, device=self.device)
        if not params.is_floating_point():
            params = params.to(self.dtype)
        if params.ndim < 2 or params.shape[-2:] != (self.n, 5):
            raise InputError(f"{name}: expected MD-H deviations of shape (..., {self.n}, 5) "
                             f"[dtheta, dd, da, dalpha, dbeta], got shape {tuple(params.shape)}")
        if not torch.isfinite(params).all():
            raise InputError(f"{name}: MD-H deviations must be finite")
        return params

    def _prep(self, q, params):
        q = self.check_q(q)
        params = self.check_params(params)
        if params is not None:
            try:
                np.broadcast_shapes(q.shape[:-1], params.shape[:-2])  # torch's would import sympy
            except ValueError:
                raise InputError(f"q batch {tuple(q.shape[:-1])} and params batch "
                                 f"{tuple(params.shape[:-2])} do not broadcast") from None
        dtype = q.dtype if params is None else torch.promote_types(q.dtype, params.dtype)
        return q.to(dtype), None if params is None else params.to(dtype), self.chain.to(dtype)

    # -- kinematics -----------------------------------------------------------------
    def fk(self, q, params=None, chunk: int | None = None) -> torch.Tensor:
        """TCP positions (..., 3) mm for q (..., n) rad and deviations params (..., n, 5)."""
        q, params, chain = self._prep(q, params)
        return K.fk_positions(q, chain, params, chunk=chunk)

    def fk_pose(self, q, params=None) -> torch.Tensor:
        """TCP poses (..., 4, 4) mm."""
        q, params, chain = self._prep(q, params)
        return K.fk_pose(q, chain, params)

    def frames(self, q, params=None) -> torch.Tensor:
        """World poses of base, each link frame and TCP: (..., n + 2, 4, 4)."""
        q, params, chain = self._prep(q, params)
        return K.fk_frames(q, chain, params)

    def param_jacobian(self, q, params=None) -> torch.Tensor:
        """(..., 3, 5n) analytic dP/d[params] (mm per rad or mm per mm)."""
        q, params, chain = self._prep(q, params)
        return K.param_jacobian(q, chain, params)

    def joint_jacobian(self, q, params=None) -> torch.Tensor:
        """(..., 3, n) dP/dq in mm/rad."""
        q, params, chain = self._prep(q, params)
        return K.joint_jacobian(q, chain, params)

    def within_limits(self, q) -> torch.Tensor:
        """(...,) bool: every joint inside its limits. q (..., n) rad."""
        q = self.check_q(q)
        lim = self.limits.to(q)
        return ((q >= lim[:, 0]) & (q <= lim[:, 1])).all(-1)

    def param_names(self) -> list[str]:
        """Names of the 5n MD-H deviations, e.g. 'dtheta1', 'dbeta2' (1-based joints)."""
        return [f"{p}{i + 1}" for i in range(self.n) for p in K.PARAM_NAMES]


def _make(name, rows_deg, beta_joints, limits_deg, payload_kg) -> Robot:
    """rows_deg: per joint (theta_offset deg, d mm, a mm, alpha deg)."""
    t = torch.tensor(rows_deg, dtype=torch.float64)
    n = t.shape[0]
    table = torch.zeros(n, 5, dtype=torch.float64)
    table[:, 0] = torch.deg2rad(t[:, 0])
    table[:, 1] = t[:, 1]
    table[:, 2] = t[:, 2]
    table[:, 3] = torch.deg2rad(t[:, 3])
    has_beta = torch.zeros(n, dtype=torch.bool)
    has_beta[[j - 1 for j in beta_joints]] = True
    limits = torch.deg2rad(torch.tensor(limits_deg, dtype=torch.float64))
    return Robot(name, table, has_beta, limits, payload_kg=payload_kg)


PRESETS = {
    "kr1000titan": lambda: _make(
        "kr1000titan",
        [(0, 1100, 600, -90), (0, 0, 1400, 0), (0, 0, 65, -90),
         (0, 1200, 0, 90), (0, 0, 0, -90), (0, 372, 0, 0)],
        beta_joints=[2],
        limits_deg=[(-150, 150), (-130, 17.5), (-200, 55), (-350, 350), (-118, 118), (-350, 350)],
        payload_kg=1000.0),
    "ur5e": lambda: _make(
        "ur5e",
        [(0, 162.5, 0, 90), (0, 0, -425, 0), (0, 0, -392.2, 0),
         (0, 133.3, 0, 90), (0, 99.7, 0, -90), (0, 99.6, 0, 0)],
        beta_joints=[2, 3],
        limits_deg=[(-360, 360)] * 6,
        payload_kg=5.0),
    "puma560": lambda: _make(
        "puma560",
        [(0, 0, 0, 90), (0, 0, 431.8, 0), (0, 150.05, 20.32, -90),
         (0, 431.8, 0, 90), (0, 0, 0, -90), (0, 0, 0, 0)],
        beta_joints=[2],
        limits_deg=[(-160, 160), (-225, 45), (-45, 225), (-110, 170), (-100, 100), (-266, 266)],
        payload_kg=2.5),
}


def preset(name) -> Robot:
    """A preset robot by name ('kr1000titan', 'ur5e', 'puma560'; case-insensitive); a
    `Robot` is returned as it is. A robot file or any name: `torchcal.io.robot_file.robot`."""
    if isinstance(name, Robot):
        return name
    if isinstance(name, str) and name.lower() in PRESETS:
        return PRESETS[name.lower()]()
    raise InputError(f"unknown robot {str(name)!r}; expected one of {', '.join(sorted(PRESETS))}")
