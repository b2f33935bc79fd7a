"""`link_bending:J`: link J sags under gravity like a cantilever.

Link J runs from frame origin o_{J-1} (on joint J's axis) to o_J, length L and direction
u at the commanded pose (nominal kinematics). Its weight and the weight it carries bend
it in the direction of the gravity component perpendicular to it,
g_perp = g - (g . u) u (|g_perp| = cos of the link's inclination): the tip moves by
b_J L g_perp and turns by the cantilever's tip slope, 1.5 b_J (tip-loaded beam: slope =
1.5 deflection / L), about u x g, which carries everything beyond the tip:

    dv = b_J [ L g_perp + 1.5 (u x g) x (v - o_J) ]   (mm).

Parameters (1 per joint): ``bend_J`` rad, the tip deflection over the link length when the
link is horizontal. The payload's share of the load is left out (the sag is that of the
arm's own weight). Links without length (a wrist's intersecting axes) cannot bend: they get
no parameter (``link_bending:J`` of such a link alone is refused). Measured orientations do not see it (a displacement).

Identifiability: for a link whose inclination follows one joint only (the upper arm of an
arm with a vertical joint 1: cos of q2 + const), the rotation about the link's root is
a first harmonic of that joint (`gear_periodic`) and part of its gravity compliance; only
the extra tip slope (0.5 b_J, a rotation about o_J) tells bending apart.
"""

import math

import torch

from torchcal.effects.base import Effect
from torchcal.rotations import skew
from torchcal.errors import InputError

#: largest plausible tip deflection over length (deg): 0.1 deg is 1.7 mm per metre of link.
MAX_BEND_DEG = 0.1
TIP_SLOPE = 1.5  # tip slope / (deflection / L) of a tip-loaded cantilever
MIN_LENGTH_MM = 1.0


class LinkBending(Effect):
    name = "link_bending"
    takes_joints = True

    def __init__(self, robot, joints=()):
        super().__init__(robot, joints)
        t = robot.table.detach().cpu().double()
        self.links = tuple(j for j in self.joints if bool(robot.prismatic[j - 1])
                           or float(torch.hypot(t[j - 1, 1], t[j - 1, 2])) >= MIN_LENGTH_MM)
        if not self.links:
            raise InputError(f"{self.spec()}: link(s) without length (|a|, |d| < {MIN_LENGTH_MM:g} mm) "
                             f"cannot bend")

    def param_names(self):
        return [f"bend_{j}" for j in self.links]

    def param_units(self):
        return ["rad"] * len(self.links)

    def plausible_max(self):
        return [math.radians(MAX_BEND_DEG)] * len(self.links)

    def _columns(self, ctx, v):
        """dv / dp (N, 3, k) mm per rad, and the slope axes 1.5 u x g (N, 3, k)."""
        o = ctx.frames[:, :, :3, 3]
        cols, axes = [], []
        for j in self.links:
            link = o[:, j] - o[:, j - 1]
            length = link.norm(dim=-1, keepdim=True)
            u = link / length.clamp_min(1e-9)
            g = ctx.gravity.expand_as(u)
            axis = TIP_SLOPE * torch.linalg.cross(u, g)
            cols.append(length * (g - (g * u).sum(-1, keepdim=True) * u) + torch.linalg.cross(axis, v - o[:, j]))
            axes.append(axis)
        return torch.stack(cols, -1), torch.stack(axes, -1)

    def displacement(self, p, ctx, v):  # (N, 3) mm
        return self._columns(ctx, v)[0] @ p

    def displacement_jacobian(self, p, ctx, v):  # (N, 3, k), (N, 3, 3)
        cols, axes = self._columns(ctx, v)
        return cols, skew(axes @ p)
