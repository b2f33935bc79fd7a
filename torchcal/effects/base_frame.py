"""`base_frame`: pose of the robot base in the measurement frame.

Parameters (6): [tx, ty, tz] mm translation and [rx, ry, rz] rad rotation vector; the
measured position is ``R(r) v + t`` for the base-frame TCP position ``v``. Rotation
about z and translation along z trade off against joint 1's dtheta and dd: the
identification holds the redundant ones.
"""

import torch

from torchcal.effects.base import Effect


def rotvec_to_matrix(r: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula, safe at r = 0. r (3,) rad -> (3, 3)."""
    theta2 = (r * r).sum()
    theta = torch.sqrt(theta2 + 1e-300)
    small = theta2 < 1e-12
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / (theta2 + 1e-300))
    zero = torch.zeros_like(r[0])
    k = torch.stack([torch.stack([zero, -r[2], r[1]]),
                     torch.stack([r[2], zero, -r[0]]),
                     torch.stack([-r[1], r[0], zero])])
    return torch.eye(3, dtype=r.dtype, device=r.device) + a * k + b * (k @ k)


class BaseFrame(Effect):
    name = "base_frame"

    def param_names(self):
        return ["base_tx", "base_ty", "base_tz", "base_rx", "base_ry", "base_rz"]

    def param_units(self):
        return ["mm", "mm", "mm", "rad", "rad", "rad"]

    def plausible_max(self):
        """No prior: the base frame is where the instrument stands, any pose."""
        return None

    def world(self, p, ctx, v):
        return v @ rotvec_to_matrix(p[3:6]).T + p[:3]

    def world_rotation(self, p, ctx):
        return rotvec_to_matrix(p[3:6])
