"""A user-written effect: joint coupling (docs/effects.md walks through it).

In a coupled drive (a wrist whose motors sit in the forearm, a belt or a parallelogram
linkage) one joint's angle leaks into another's: joint J turns by

    q_J + sum_{I < J} k_{I,J} q_I

instead of q_J. Spec ``joint_coupling:J[,J...]`` lists the *driven* joints; each driven
joint J is coupled to every joint I below it, so ``joint_coupling:3`` has the
parameters ``coupling_1_3`` and ``coupling_2_3`` (dimensionless, rad of joint J per rad
of joint I): "joint 2 drives joint 3" is ``coupling_2_3``. Joint 1 has no joint below
it: ``joint_coupling:1`` has no parameters (diagnosis finds nothing to add there).

Use it with any command that takes effects:

    torchcal simulate --effects-module examples/joint_coupling.py \\
        --robot ur5e --effects joint_coupling:3 --n 80 --out coupled.csv
    torchcal discover coupled.csv --robot ur5e --effects-module examples/joint_coupling.py
"""

from torchcal.effects import Effect


class JointCoupling(Effect):
    name = "joint_coupling"  # the spec name; must not clash with another effect
    takes_joints = True  # joint_coupling:J[,J...] lists the driven joints (1-based)

    def pairs(self):
        """(driving I, driven J) 1-based, one per parameter, in parameter order."""
        return [(i, j) for j in self.joints for i in range(1, j)]

    def param_names(self):
        return [f"coupling_{i}_{j}" for i, j in self.pairs()]

    def param_units(self):
        return ["1"] * len(self.pairs())  # rad per rad

    def joint_offset(self, p, ctx):
        """(N, n) rad added to the commanded angles ctx.q (N, n) rad: k_{I,J} q_I on joint J."""
        n = ctx.q.shape[1]
        pairs = self.pairs()
        # (k, n) maps each parameter's driving joint I to its driven joint J: a fixed 0/1
        # matrix, so the offset is linear in p and autograd-friendly (no in-place on p)
        drive = ctx.q.new_zeros(len(pairs), n)
        into = ctx.q.new_zeros(len(pairs), n)
        for r, (i, j) in enumerate(pairs):
            drive[r, i - 1] = 1.0
            into[r, j - 1] = 1.0
        return ((ctx.q @ drive.T) * p) @ into  # (N, k) * (k,) -> (N, k) @ (k, n)
