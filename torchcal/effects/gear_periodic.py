"""`gear_periodic:J`: periodic transmission error, harmonics of the joint angle.

Parameters (2 H per joint, H = len(HARMONICS)): ``gear_J_sinK``, ``gear_J_cosK`` rad, the
offset ``sum_K s_K sin(K q) + c_K cos(K q)``. Harmonics 1..4 of the output revolution
(eccentricity, ovality, three- and four-lobe errors of the output stage); the
once-per-tooth errors of the input stages are far above what a few hundred poses resolve. The constant term is
joint J's dtheta and is not repeated here.
"""

import math

import torch

from torchcal.effects.base import Effect, joint_columns, per_context, revolute_only, scatter_joints

HARMONICS = (1, 2, 3, 4)
#: plausible sine or cosine amplitude of one harmonic (deg), the scale of the fit's prior.
#: The transmission error of an industrial reducer (harmonic drive, RV, cycloid) is about
#: an arc minute (0.017 deg); 0.1 deg is six times that. Larger fits have used the
#: harmonics as a polynomial over a narrow range of the joint (on a real UR10 session
#: whose joint 2 spanned 64 deg: amplitudes of 17 rad that cancel on the calibration
#: poses and gave 1.1 m of error at a pose 32 deg outside that range).
MAX_AMPLITUDE_DEG = 0.1


class GearPeriodic(Effect):
    name = "gear_periodic"
    takes_joints = True

    def __init__(self, robot, joints=(), harmonics=HARMONICS):
        super().__init__(robot, joints)
        revolute_only(self)
        self.harmonics = tuple(harmonics)

    def param_names(self):
        return [f"gear_{j}_{f}{k}" for j in self.joints for k in self.harmonics for f in ("sin", "cos")]

    def param_units(self):
        return ["rad"] * self.n_params

    def plausible_max(self):
        return [math.radians(MAX_AMPLITUDE_DEG)] * self.n_params

    def _angles(self, ctx):
        """(N, J) rad: the angle whose harmonics make the error (here the joint angle)."""
        return ctx.q[:, [j - 1 for j in self.joints]]

    @per_context
    def _basis(self, ctx):
        """(N, J, H, 2) sin and cos of each harmonic of each listed joint's `_angles`."""
        k = torch.tensor(self.harmonics, dtype=ctx.q.dtype, device=ctx.q.device)
        arg = self._angles(ctx).unsqueeze(-1) * k  # (N, J, H)
        return torch.stack([torch.sin(arg), torch.cos(arg)], dim=-1)

    def joint_offset(self, p, ctx):
        coef = p.reshape(len(self.joints), len(self.harmonics), 2)
        return scatter_joints((self._basis(ctx) * coef).sum((-1, -2)), self.joints, ctx.q.shape[1])

    def joint_offset_columns(self, p, ctx):
        basis = self._basis(ctx).to(p)
        per = 2 * len(self.harmonics)
        return [j - 1 for j in self.joints for _ in range(per)], basis.reshape(basis.shape[0], -1)

    def joint_offset_jacobian(self, p, ctx):
        basis = self._basis(ctx).to(p)
        return joint_columns(basis.reshape(*basis.shape[:2], -1), self.joints, ctx.q.shape[1])
