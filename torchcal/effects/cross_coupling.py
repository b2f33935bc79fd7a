"""`cross_coupling:J`: joint J turns by an amount proportional to the joints before it.

In a coupled drive one joint's angle leaks into another's: the motors of a wrist sit in
the forearm, so their shafts pass through the joints before them (joint 5's and 6's
transmissions turn with joint 4), and a parallelogram arm couples joint 3 to joint 2. The
controller removes the nominal coupling; what is left is a small ratio error. Joint J
turns by

    q_J + sum_{I < J} c_{I,J} q_I.

Parameters (J - 1 per joint): ``coupling_I_J`` (dimensionless, rad of joint J per rad of
joint I), I = 1..J-1. A spec's joints are the *driven* ones; the fit says which joint
drives. Joint 1 has no joint before it: it gets no parameter (``cross_coupling:1`` alone
is refused). The term ``c_{J,J} q_J``
is `encoder_scale` and the constant is joint J's dtheta; neither is repeated here.
"""

import torch

from torchcal.effects.base import Effect
from torchcal.errors import InputError

#: largest plausible |c| (1 %: 0.9 deg of joint J when joint I moves 90 deg); a residual
#: coupling is a ratio error of the same order as an encoder scale error.
MAX_COUPLING = 0.01


class CrossCoupling(Effect):
    name = "cross_coupling"
    takes_joints = True

    def __init__(self, robot, joints=()):
        super().__init__(robot, joints)
        if not self.pairs():
            raise InputError(f"{self.spec()}: no joint before it of the same type (revolute or prismatic) to be "
                             "coupled to; list driven joints 2..n")

    def pairs(self) -> list[tuple[int, int]]:
        """(driving I, driven J), 1-based, one per parameter; joints of one type only (a
        slide's q in mm does not drive a revolute joint's angle, nor the reverse)."""
        pris = self.robot.prismatic.tolist()
        return [(i, j) for j in self.joints for i in range(1, j) if pris[i - 1] == pris[j - 1]]

    def param_names(self):
        return [f"coupling_{i}_{j}" for i, j in self.pairs()]

    def param_units(self):
        return ["1"] * self.n_params

    def plausible_max(self):
        return [MAX_COUPLING] * self.n_params

    def _maps(self, ctx):
        """One-hot (k, n) matrices: the driving joint and the driven joint of each parameter."""
        n, pairs = ctx.q.shape[1], self.pairs()
        drive = ctx.q.new_zeros(len(pairs), n)
        into = ctx.q.new_zeros(len(pairs), n)
        for r, (i, j) in enumerate(pairs):
            drive[r, i - 1] = 1.0
            into[r, j - 1] = 1.0
        return drive, into

    def joint_offset(self, p, ctx):  # (N, n) rad
        drive, into = self._maps(ctx)
        return ((ctx.q @ drive.T) * p) @ into

    def joint_offset_jacobian(self, p, ctx):  # (N, n, k)
        drive, into = self._maps(ctx)
        return (ctx.q @ drive.T).unsqueeze(1) * into.T.contiguous()  # (N, 1, k) * (n, k), contiguous
