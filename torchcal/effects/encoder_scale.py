"""`encoder_scale:J`: joint angle scale (gear ratio) error.

Parameters (1 per joint): ``scale_J`` (dimensionless); the joint turns
``q * (1 + scale_J)``, i.e. an offset ``scale_J * q`` rad.
"""

from torchcal.effects.base import Effect, joint_columns, scatter_joints

#: plausible relative scale error: an encoder or a gear ratio off by more than 0.5 %
#: would be a wrong robot file, not a calibration error
MAX_SCALE = 5e-3


class EncoderScale(Effect):
    name = "encoder_scale"
    takes_joints = True

    def param_names(self):
        return [f"scale_{j}" for j in self.joints]

    def param_units(self):
        return ["1"] * len(self.joints)

    def plausible_max(self):
        return [MAX_SCALE] * len(self.joints)

    def joint_offset(self, p, ctx):
        cols = ctx.q[:, [j - 1 for j in self.joints]] * p  # (N, J)
        return scatter_joints(cols, self.joints, ctx.q.shape[1])

    def joint_offset_jacobian(self, p, ctx):
        cols = ctx.q[:, [j - 1 for j in self.joints]]  # (N, J)
        return joint_columns(cols.unsqueeze(-1).to(p), self.joints, ctx.q.shape[1])
