"""`base_compliance`: the mount tilts with the arm's overturning moment.

The robot stands on a pedestal, a floor plate or a machine bed; none is rigid. The
gravity moment of the arm and payload about the base tilts the whole robot about an
axis through the base origin, with different stiffness about the base's x and y axes
(a rectangular plate, a pedestal with anchors on two sides). The error depends on q1
(which way the arm leans) and on the reach.

Load model: `torchcal.effects.axis_tilt.load_moment` with links 1..n (equal masses at the
link midpoints, payload at the TCP, normalised by the reference moment of the stretched
arm). With m = R_0^T M / M_ref in the base (joint-1) frame, the tilt is

    omega = R_0 (k_x m_x, k_y m_y, 0),   dv = omega x (v - o_0)   (mm).

Parameters: ``base_tilt_x``, ``base_tilt_y`` rad, the tilt about the base x / y axis at
the reference moment. An isotropic mount (k_x = k_y) tilts about the horizontal axis
perpendicular to the arm's plane, which for an arm with a vertical joint 1 is nearly
parallel to joint 2's axis: then it is close to `joint_compliance:2` (and to the bearing
tilt of joint 1, which is the same rotation); the anisotropy, k_x != k_y, is what only
this effect explains. Measured orientations do not see it (a displacement).
"""

import math

import torch

from torchcal.effects.axis_tilt import MAX_TILT_DEG, load_moment
from torchcal.effects.base import Effect
from torchcal.rotations import skew


class BaseCompliance(Effect):
    name = "base_compliance"
    uses_payload = True

    def param_names(self):
        return ["base_tilt_x", "base_tilt_y"]

    def param_units(self):
        return ["rad", "rad"]

    def plausible_max(self):
        return [math.radians(MAX_TILT_DEG)] * 2

    def _axes(self, ctx):
        """(N, 3, 2): the world tilt per unit parameter, R_0 e_x m_x and R_0 e_y m_y."""
        R0 = ctx.frames[:, 0, :3, :3]
        m = torch.einsum("nij,ni->nj", R0, load_moment(ctx, self.robot, 1))
        return R0[:, :, :2] * m[:, None, :2]

    def displacement(self, p, ctx, v):  # (N, 3) mm
        omega = self._axes(ctx) @ p
        return torch.linalg.cross(omega, v - ctx.frames[:, 0, :3, 3])

    def displacement_jacobian(self, p, ctx, v):  # (N, 3, 2), (N, 3, 3)
        axes = self._axes(ctx)
        lever = (v - ctx.frames[:, 0, :3, 3]).unsqueeze(-1).expand_as(axes)
        dp = torch.linalg.cross(axes, lever, dim=1)
        return dp, skew(axes @ p)
