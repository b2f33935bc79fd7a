"""`backlash:J`: lost motion that depends on the approach direction.

Parameters (1 per joint): ``backlash_J`` rad, the full lost motion. A joint that last
moved in the + direction stops ``backlash_J / 2`` past the mean position, one that came
from the - direction ``backlash_J / 2`` before it: offset ``approach * backlash_J / 2``.
The approach direction comes from the measurement order (`Context.approach`).
Lost motion cannot be negative: the fit keeps ``backlash_J >= 0`` (`lower_bounds`).
"""

import math

from torchcal.effects.base import Effect, joint_columns, revolute_only, scatter_joints

#: plausible full lost motion (deg): reducers of industrial arms lose arc minutes
MAX_BACKLASH_DEG = 0.2


class Backlash(Effect):
    name = "backlash"
    takes_joints = True
    uses_approach = True

    def __init__(self, robot, joints=()):
        super().__init__(robot, joints)
        revolute_only(self)

    def param_names(self):
        return [f"backlash_{j}" for j in self.joints]

    def param_units(self):
        return ["rad"] * len(self.joints)

    def plausible_max(self):
        return [math.radians(MAX_BACKLASH_DEG)] * len(self.joints)

    def lower_bounds(self):
        return [0.0] * len(self.joints)  # lost motion is never negative

    def joint_offset(self, p, ctx):
        cols = ctx.approach[:, [j - 1 for j in self.joints]] * (0.5 * p)  # (N, J)
        return scatter_joints(cols, self.joints, ctx.q.shape[1])

    def joint_offset_jacobian(self, p, ctx):
        cols = 0.5 * ctx.approach[:, [j - 1 for j in self.joints]]  # (N, J)
        return joint_columns(cols.unsqueeze(-1).to(p), self.joints, ctx.q.shape[1])
