"""`base_frame`: pose of the robot base in the measurement frame.

Parameters (6): [tx, ty, tz] mm translation and [rx, ry, rz] rad rotation vector; the
measured position is ``R(r) v + t`` for the base-frame TCP position ``v``. Rotation
about z and translation along z trade off against joint 1's dtheta and dd: the
identification holds the redundant ones.
"""

import torch

from torchcal.effects.base import Effect, per_value
from torchcal.rotations import rotvec_jacobian, rotvec_to_matrix


class BaseFrame(Effect):
    name = "base_frame"

    def param_names(self):
        return ["base_tx", "base_ty", "base_tz", "base_rx", "base_ry", "base_rz"]

    def param_units(self):
        return ["mm", "mm", "mm", "rad", "rad", "rad"]

    def plausible_max(self):
        """No prior: the base frame is where the instrument stands, any pose."""
        return None

    # the rotation and its derivative at the last rotation vector: a residual and the
    # Jacobian after it, and positions and orientations, ask for them at the same theta
    @per_value
    def _rotation(self, r):
        """(3, 3) the rotation of the rotation vector r (3,) rad."""
        return rotvec_to_matrix(r)

    @per_value
    def _rotation_jacobian(self, r):
        """(3, 3, 3) its derivative w.r.t. r, last index the component."""
        return rotvec_jacobian(r)

    def world(self, p, ctx, v):
        return v @ self._rotation(p[3:6]).T + p[:3]

    def world_rotation(self, p, ctx):
        return self._rotation(p[3:6])

    def world_jacobian(self, p, ctx, v):
        """d / d p (N, 3, 6): identity for t, dR/dr_k v for r; d / d v: R (N, 3, 3)."""
        dR = self._rotation_jacobian(p[3:6])  # (3, 3, 3)
        dp = torch.cat([torch.eye(3, dtype=v.dtype, device=v.device).expand(v.shape[0], 3, 3),
                        torch.einsum("ijk,nj->nik", dR, v)], dim=-1)
        return dp, self._rotation(p[3:6]).expand(v.shape[0], 3, 3)

    def world_rotation_jacobian(self, p, ctx):
        return torch.cat([torch.zeros(3, 3, 3, dtype=p.dtype, device=p.device), self._rotation_jacobian(p[3:6])],
                         dim=-1)
