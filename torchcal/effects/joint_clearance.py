"""`joint_clearance:J`: the shaft of joint J moves inside its hole (the paper's source).

With a radial clearance the joint axis can shift (up to the clearance) and tilt (up to
clearance / bearing length) inside its bearing. The load pushes it to one side: the
part of the gravity moment perpendicular to the axis tilts it, the perpendicular part
of the gravity force shifts it. The rest is random per move: two moves to one pose
stop at different places inside the clearance (the paper's repetitions).

Fit role (deterministic, load driven), 2 parameters per joint:
    clear_tilt_J  rad   tilt towards the perpendicular gravity moment of a load at the TCP
    clear_shift_J mm    shift along the perpendicular gravity force
Both are magnitudes (the load pushes the shaft towards its moment and force, never
against them): the fit keeps them >= 0 (`lower_bounds`).
Random role (simulation, and the variance model of `diagnose`): `random_basis` gives the
TCP displacement per unit tilt of the axis about the two directions perpendicular to it.
"""

import math

import torch

from torchcal.effects.base import Effect, per_context
from torchcal.rotations import skew

#: plausible axis tilt (deg) and shift (mm) inside a bearing: clearances of hundredths of
#: a mm over bearing lengths of tens of mm
MAX_TILT_DEG = 0.1
MAX_SHIFT_MM = 0.5
SATURATION_MM = 50.0  # lever below which the pushing moment fades (smooth sign)
SATURATION_FORCE = 0.05  # fraction of gravity below which the pushing force fades


def _unit(v: torch.Tensor, eps: float) -> torch.Tensor:
    return v / torch.sqrt((v * v).sum(-1, keepdim=True) + eps * eps)


def load_directions(ctx, joint: int):
    """Unit directions (N, 3) of the perpendicular gravity moment and force at `joint`.

    Also returns the axis z (N, 3) and origin o (N, 3) of the joint, world frame, mm.
    """
    f = ctx.frames
    z, o = f[:, joint - 1, :3, 2], f[:, joint - 1, :3, 3]
    g = ctx.gravity.expand_as(z)
    lever = f[:, -1, :3, 3] - o
    moment = torch.linalg.cross(lever, g)
    moment = moment - (moment * z).sum(-1, keepdim=True) * z
    force = g - (g * z).sum(-1, keepdim=True) * z
    return _unit(moment, SATURATION_MM), _unit(force, SATURATION_FORCE), z, o


def random_basis(ctx, joint: int, v: torch.Tensor) -> torch.Tensor:
    """TCP displacement (N, 3, 2) mm per rad of tilt of joint `joint` about the two unit
    directions perpendicular to its axis; v (N, 3) the base-frame TCP positions."""
    _, _, z, o = load_directions(ctx, joint)
    helper = torch.where((z[:, :1].abs() < 0.9), torch.tensor([1.0, 0, 0], dtype=z.dtype, device=z.device),
                         torch.tensor([0, 1.0, 0], dtype=z.dtype, device=z.device))
    e1 = _unit(torch.linalg.cross(z, helper), 1e-12)
    e2 = torch.linalg.cross(z, e1)
    lever = v - o
    return torch.stack([torch.linalg.cross(e1, lever), torch.linalg.cross(e2, lever)], dim=-1)


class JointClearance(Effect):
    name = "joint_clearance"
    uses_payload = True
    takes_joints = True

    def param_names(self):
        return [n for j in self.joints for n in (f"clear_tilt_{j}", f"clear_shift_{j}")]

    def param_units(self):
        return ["rad", "mm"] * len(self.joints)

    def plausible_max(self):
        return [math.radians(MAX_TILT_DEG), MAX_SHIFT_MM] * len(self.joints)

    def lower_bounds(self):
        return [0.0, 0.0] * len(self.joints)  # the load pushes towards its moment and force

    @per_context
    def _directions(self, ctx):
        """`load_directions`(ctx, J) of each joint J: the rows' data only, so the residual
        and Jacobian evaluations of a solve on the same rows compute them once."""
        return [load_directions(ctx, j) for j in self.joints]

    def displacement(self, p, ctx, v):
        out = torch.zeros_like(v)
        for i, (m_dir, f_dir, _, o) in enumerate(self._directions(ctx)):
            out = out + p[2 * i] * torch.linalg.cross(m_dir, v - o) + p[2 * i + 1] * f_dir
        return out

    def displacement_jacobian(self, p, ctx, v):
        """d / d p: the columns m x (v - o) and f per joint (N, 3, 2 J); d / d v: sum of
        tilt_J [m_J]x (N, 3, 3)."""
        dp, dv = [], torch.zeros(*v.shape, 3, dtype=v.dtype, device=v.device)
        for i, (m_dir, f_dir, _, o) in enumerate(self._directions(ctx)):
            dp += [torch.linalg.cross(m_dir, v - o), f_dir.expand_as(v)]
            dv = dv + p[2 * i] * skew(m_dir)
        return torch.stack(dp, dim=-1), dv

