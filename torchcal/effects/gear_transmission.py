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

from torchcal.effects.gear_periodic import GearPeriodic
from torchcal.errors import InputError

HARMONICS = (1, 2)
#: largest plausible sine or cosine amplitude (deg): the lost motion and transmission
#: error of robot reducers are about an arc minute; 0.1 deg is generous.
MAX_AMPLITUDE_DEG = 0.1


class GearTransmission(GearPeriodic):
    """`gear_periodic` at the motor-side angle r_J q_J (its basis, offset and Jacobian)."""

    name = "gear_transmission"

    def __init__(self, robot, joints=()):
        super().__init__(robot, joints, harmonics=HARMONICS)
        ratio = robot.gear_ratio
        missing = [j for j in self.joints if ratio is None or j > len(ratio) or ratio[j - 1] is None]
        if missing:
            raise InputError(f"{self.spec()}: the robot file of {robot.name!r} gives no gear_ratio for joint(s) "
                             f"{', '.join(map(str, missing))} (robot file key \"gear_ratio\": one reducer ratio "
                             f"per joint)")
        self.ratios = tuple(float(ratio[j - 1]) for j in self.joints)

    def param_names(self):
        return [f"gtrans_{j}_{f}{h}" for j in self.joints for h in HARMONICS for f in ("sin", "cos")]

    def plausible_max(self):
        return [math.radians(MAX_AMPLITUDE_DEG)] * self.n_params

    def _angles(self, ctx):  # (N, J) rad: the motor-side angle r_J q_J
        q = ctx.q[:, [j - 1 for j in self.joints]]
        return q * torch.tensor(self.ratios, dtype=q.dtype, device=q.device)
