"""`base_frame`: pose of the robot base in the measurement frame.

Parameters (6): [tx, ty, tz] mm translation and [rx, ry, rz] rad rotation vector; the
measured position is ``R(r) v + t`` for the base-frame TCP position ``v``. Rotation
about z and translation along z trade off against joint 1's dtheta and dd: the
identification holds the redundant ones.
"""

from torchcal.effects.base import Effect
from torchcal.rotations import rotvec_to_matrix


def rotvec_jacobian(r: torch.Tensor) -> torch.Tensor:
    """d rotvec_to_matrix(r) / d r (3, 3, 3), last index the component of r.

    With R = I + a(s) K + b(s) K^2, s = |r|^2, K = [r]x and E_k = [e_k]x:
    dR/dr_k = 2 r_k (a' K + b' K^2) + a E_k + b (E_k K + K E_k), the same series as
    `rotvec_to_matrix` below |r| = 1e-6.
    """
    s = (r * r).sum()
    t = torch.sqrt(s + 1e-300)
    small = s < 1e-12
    sin, cos = torch.sin(t), torch.cos(t)
    a = torch.where(small, 1 - s / 6, sin / t)
    b = torch.where(small, 0.5 - s / 24, (1 - cos) / (s + 1e-300))
    da = torch.where(small, torch.full_like(s, -1 / 6), (t * cos - sin) / (2 * t ** 3 + 1e-300))
    db = torch.where(small, torch.full_like(s, -1 / 24), (t * sin - 2 * (1 - cos)) / (2 * s * s + 1e-300))
    eye = torch.eye(3, dtype=r.dtype, device=r.device)
    E = torch.linalg.cross(eye[:, None, :].expand(3, 3, 3), eye[None, :, :].expand(3, 3, 3)).permute(0, 2, 1)
    # E[k] = [e_k]x: column j of [e_k]x is e_k x e_j
    K = torch.einsum("kij,k->ij", E, r)
    KK = K @ K
    out = (2 * r[:, None, None] * (da * K + db * KK) + a * E + b * (E @ K + K @ E))  # (k, 3, 3)
    return out.permute(1, 2, 0)


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

    def world_jacobian(self, p, ctx, v):
        """d / d p (N, 3, 6): identity for t, dR/dr_k v for r; d / d v: R (N, 3, 3)."""
        dR = rotvec_jacobian(p[3:6])  # (3, 3, 3)
        dp = torch.cat([torch.eye(3, dtype=v.dtype, device=v.device).expand(v.shape[0], 3, 3),
                        torch.einsum("ijk,nj->nik", dR, v)], dim=-1)
        return dp, rotvec_to_matrix(p[3:6]).expand(v.shape[0], 3, 3)

    def world_rotation_jacobian(self, p, ctx):
        return torch.cat([torch.zeros(3, 3, 3, dtype=p.dtype, device=p.device), rotvec_jacobian(p[3:6])], dim=-1)
