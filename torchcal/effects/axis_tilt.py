"""`axis_tilt:J`: the axis of joint J tilts in its bearing under the gravity load it carries.

A joint's bearing is stiff about the joint axis only through the gear (that is
`joint_compliance`); perpendicular to the axis the bearing itself gives: the part of the
gravity moment perpendicular to the axis tilts everything beyond the bearing about an
axis perpendicular to the joint axis, through the joint's frame origin.

Load model (`load_moment`): the masses beyond the bearing are unknown, so each link
k = J..n is one equal mass at its midpoint (half way between the frame origins o_{k-1}
and o_k of the nominal kinematics at the commanded pose) and the payload (``payload_kg``
per row, 0 when not measured) sits at the TCP, in units of one link mass (the rated
payload). The moment about o_{J-1} is normalised by the joint's reference moment
``M_ref = ((n - J + 1) / 2 + 1) x reach_J`` (about that of the links J..n stretched out
horizontally with the rated payload; reach_J = sum over rows J..n of sqrt(a^2 + d^2) plus
the tool's offset), so the one parameter per joint absorbs the unknown mass and
stiffness:

    tilt (rad, in frame J-1) = tilt_J x (m_x, m_y, 0),   m = R_{J-1}^T M / M_ref,

applied as per-row deviations of row J-1 (dalpha_{J-1} += tilt_J m_x, dbeta_{J-1} +=
tilt_J m_y: rotations of frame J-1 about its x and y axes, both perpendicular to joint J's
axis z_{J-1}; exact for a row whose nominal beta is 0). Measured orientations see it.

Parameters (1 per joint): ``tilt_J`` rad, the tilt at the joint's reference moment. Joint 1's
bearing tilts the whole arm with the overturning moment: that is `base_compliance` (mount
and joint-1 bearing are the same rotation and cannot be told apart), so joint 1 gets no
parameter (``axis_tilt`` alone means joints 2..n; ``axis_tilt:1`` alone is refused).
"""

import math

import torch

from torchcal.effects.base import Effect
from torchcal.errors import InputError

#: largest plausible tilt at the reference moment (deg): a bearing tilts by arc seconds to
#: arc minutes; 0.2 deg (3.5 mm at 1 m) is far beyond a healthy bearing.
MAX_TILT_DEG = 0.2


def reference_moment_mm(robot, first: int = 1) -> float:
    """M_ref (mm, in unit link masses) of the part of the arm beyond joint `first`:
    (number of links / 2 + 1) x reach, reach = sum of the rows first..n's sqrt(a^2 + d^2)
    plus the tool's offset (mm): about the moment of that part stretched out horizontally
    with the rated payload."""
    t = robot.table.detach().cpu().double()[first - 1:]
    reach = float(torch.sqrt(t[:, 1] ** 2 + t[:, 2] ** 2).sum() + robot.tool[:3, 3].detach().cpu().double().norm())
    return ((robot.n - first + 1) / 2 + 1) * max(reach, 1.0)


def load_moment(ctx, robot, first: int) -> torch.Tensor:
    """Normalised gravity moment (N, 3), world frame, about the origin o_{first-1} of
    links first..n (equal masses at their midpoints) and the payload at the TCP (in units
    of one link mass = the rated payload, at least 1 kg), divided by
    `reference_moment_mm(robot, first)`."""
    o = ctx.frames[:, :, :3, 3]  # (N, n + 2, 3): base, frames 1..n, TCP
    n = o.shape[1] - 2
    pivot = o[:, first - 1]
    mid = 0.5 * (o[:, first - 1:n] + o[:, first:n + 1])  # (N, n - first + 1, 3)
    link_kg = max(float(robot.payload_kg), 1.0)
    arm = (mid - pivot.unsqueeze(1)).sum(1) + (ctx.payload_kg / link_kg).unsqueeze(-1) * (o[:, -1] - pivot)
    return torch.linalg.cross(arm, ctx.gravity.expand_as(arm)) / reference_moment_mm(robot, first)


class AxisTilt(Effect):
    name = "axis_tilt"
    takes_joints = True
    uses_payload = True

    def __init__(self, robot, joints=()):
        super().__init__(robot, joints)
        self.tilted = tuple(j for j in self.joints if j > 1)  # joints with a parameter
        if not self.tilted:
            raise InputError("axis_tilt:1: joint 1's bearing tilts the whole arm, which is base_compliance; "
                             "axis_tilt acts on joints 2..n")

    def param_names(self):
        return [f"tilt_{j}" for j in self.tilted]

    def param_units(self):
        return ["rad"] * len(self.tilted)

    def plausible_max(self):
        return [math.radians(MAX_TILT_DEG)] * len(self.tilted)

    def geometric_offset_jacobian(self, p, ctx):  # (N, n, 5, k)
        f = ctx.frames
        out = f.new_zeros(f.shape[0], f.shape[1] - 2, 5, len(self.tilted))
        for i, j in enumerate(self.tilted):
            m = torch.einsum("nij,ni->nj", f[:, j - 1, :3, :3], load_moment(ctx, self.robot, j))  # R^T M
            out[:, j - 2, 3, i] = m[:, 0]
            out[:, j - 2, 4, i] = m[:, 1]
        return out

    def geometric_offset(self, p, ctx):  # (N, n, 5)
        return self.geometric_offset_jacobian(p, ctx) @ p
