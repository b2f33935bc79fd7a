"""`base_frame`: pose of the robot base in the measurement frame.

Parameters (6): [tx, ty, tz] mm translation and [rx, ry, rz] rad rotation vector; the
measured position is ``R(r) v + t`` for the base-frame TCP position ``v``. Rotation
about z and translation along z trade off against joint 1's dtheta and dd: the
identification holds the redundant ones.
"""

from torchcal.effects.base import Effect
from torchcal.rotations import rotvec_to_matrix


class BaseFrame(Effect):
    name = "base_frame"

    def param_names(self):
        return ["base_tx", "base_ty", "base_tz", "base_rx", "base_ry", "base_rz"]

    def param_units(self):
        return ["mm", "mm", "mm", "rad", "rad", "rad"]

    def world(self, p, ctx, v):
        return v @ rotvec_to_matrix(p[3:6]).T + p[:3]

    def world_rotation(self, p, ctx):
        return rotvec_to_matrix(p[3:6])
