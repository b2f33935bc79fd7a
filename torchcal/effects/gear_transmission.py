"""`gear_transmission:J`: transmission error at the reducer ratio (motor-side harmonics).

A reducer's transmission error repeats with the input (motor) shaft: eccentricity of the
motor shaft and of the first stage once per motor turn, the two-lobed wave generator of a
harmonic drive twice per motor turn. With the reducer ratio r_J (motor turns per joint
turn, the robot file's ``gear_ratio``), joint J turns by

    q_J + sum_h  s_h sin(h r_J q_J) + c_h cos(h r_J q_J),   h = 1, 2.

Parameters (4 per joint): ``gtrans_J_sin1``, ``gtrans_J_cos1``, ``gtrans_J_sin2``,
``gtrans_J_cos2`` rad. The harmonics of the output revolution are `gear_periodic`. The
effect needs ``gear_ratio`` for each listed joint; without it it refuses with one line.
Identifying it needs joint angles known to a small fraction of a motor turn
(1 / r_J of a joint turn): encoder angles, not rounded ones.
"""

import math

import torch

from torchcal.effects.base import Effect, scatter_joints
from torchcal.errors import InputError

HARMONICS = (1, 2)
#: largest plausible sine or cosine amplitude (deg): the lost motion and transmission
#: error of robot reducers are about an arc minute; 0.1 deg is generous.
MAX_AMPLITUDE_DEG = 0.1


class GearTransmission(Effect):
    name = "gear_transmission"
    takes_joints = True

    def __init__(self, robot, joints=()):
        super().__init__(robot, joints)
        ratio = robot.gear_ratio
        missing = [j for j in self.joints if ratio is None or j > len(ratio) or ratio[j - 1] is None]
        if missing:
            raise InputError(f"{self.spec()}: the robot file of {robot.name!r} gives no gear_ratio for joint(s) "
                             f"{', '.join(map(str, missing))} (robot file key \"gear_ratio\": one reducer ratio "
                             f"per joint)")
        self.ratios = tuple(float(ratio[j - 1]) for j in self.joints)

    def param_names(self):
        return [f"gtrans_{j}_{f}{h}" for j in self.joints for h in HARMONICS for f in ("sin", "cos")]

    def param_units(self):
        return ["rad"] * self.n_params

    def plausible_max(self):
        return [math.radians(MAX_AMPLITUDE_DEG)] * self.n_params

    def _basis(self, ctx):
        """(N, J, H, 2): sin and cos of h r_J q_J."""
        q = ctx.q[:, [j - 1 for j in self.joints]]
        r = torch.tensor(self.ratios, dtype=q.dtype, device=q.device)
        h = torch.tensor(HARMONICS, dtype=q.dtype, device=q.device)
        arg = (q * r).unsqueeze(-1) * h  # (N, J, H)
        return torch.stack([torch.sin(arg), torch.cos(arg)], dim=-1)

    def joint_offset(self, p, ctx):  # (N, n) rad
        coef = p.reshape(len(self.joints), len(HARMONICS), 2)
        return scatter_joints((self._basis(ctx) * coef).sum((-1, -2)), self.joints, ctx.q.shape[1])

    def joint_offset_jacobian(self, p, ctx):  # (N, n, k)
        b = self._basis(ctx).reshape(ctx.q.shape[0], len(self.joints), -1)  # (N, J, 2H)
        out = ctx.q.new_zeros(ctx.q.shape[0], ctx.q.shape[1], self.n_params)
        w = b.shape[-1]
        for i, j in enumerate(self.joints):
            out[:, j - 1, i * w:(i + 1) * w] = b[:, i]
        return out
