"""Rotations: the one convention and the closed-form fits, in one place.

Convention (files, reports, URDF): fixed-axis XYZ angles ``r = [rx, ry, rz]`` rad,

    R = Rz(rz) Ry(ry) Rx(rx),

the same as URDF's roll-pitch-yaw. A rotation vector ``r`` (3,) rad is the axis times
the angle (Rodrigues). Matrices are (..., 3, 3), float, on the device of their input.

- `fixed_xyz_to_matrix` / `matrix_to_fixed_xyz`: angles <-> matrix (ry in [-pi/2, pi/2]);
- `rotvec_to_matrix` (differentiable, smooth at 0) / `matrix_to_rotvec` (off the graph);
- `nearest_rotation`: the proper rotation closest to a 3x3 matrix (SVD with the det
  correction), behind `kabsch` (rigid motion between point sets) and
  `procrustes_rotation` (constant rotation between two sets of rotations);
- `so3_error`: a smooth orientation residual between two rotations.
"""

from __future__ import annotations

import functools

import numpy as np
import torch

__all__ = ["skew", "fixed_xyz_to_matrix", "matrix_to_fixed_xyz", "rotvec_to_matrix", "rotvec_jacobian", "matrix_to_rotvec",
           "nearest_rotation", "kabsch", "procrustes_rotation", "so3_error"]


def skew(w: torch.Tensor) -> torch.Tensor:
    """Cross-product (hat) matrices: w (..., 3) -> (..., 3, 3) with skew(w) x = w x x."""
    w0, w1, w2 = w.unbind(-1)
    zero = torch.zeros_like(w0)
    return torch.stack([zero, -w2, w1, w2, zero, -w0, -w1, w0, zero], -1).reshape(*w.shape[:-1], 3, 3)


def _axis(axis: int, a: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotation about axis 0/1/2 (x/y/z) by angles a (...,) rad."""
    c, s = torch.cos(a), torch.sin(a)
    o, z = torch.ones_like(a), torch.zeros_like(a)
    m = {0: [o, z, z, z, c, -s, z, s, c],
         1: [c, z, s, z, o, z, -s, z, c],
         2: [c, -s, z, s, c, z, z, z, o]}[axis]
    return torch.stack(m, dim=-1).reshape(*a.shape, 3, 3)


def fixed_xyz_to_matrix(r: torch.Tensor) -> torch.Tensor:
    """Fixed-axis XYZ angles r (..., 3) rad [rx, ry, rz] -> R = Rz(rz) Ry(ry) Rx(rx) (..., 3, 3)."""
    return _axis(2, r[..., 2]) @ _axis(1, r[..., 1]) @ _axis(0, r[..., 0])


def matrix_to_fixed_xyz(R: torch.Tensor) -> torch.Tensor:
    """Inverse of `fixed_xyz_to_matrix`: (..., 3, 3) -> (..., 3) rad, ry in [-pi/2, pi/2]
    (rx = 0 at gimbal lock, the whole turn about z then in rz)."""
    cy = torch.hypot(R[..., 0, 0], R[..., 1, 0])
    ry = torch.atan2(-R[..., 2, 0], cy)
    lock = cy < 1e-9
    rx = torch.where(lock, torch.zeros_like(ry), torch.atan2(R[..., 2, 1], R[..., 2, 2]))
    rz = torch.where(lock, torch.atan2(-R[..., 0, 1], R[..., 1, 1]), torch.atan2(R[..., 1, 0], R[..., 0, 0]))
    return torch.stack([rx, ry, rz], dim=-1)


def rotvec_to_matrix(r: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula, safe (and differentiable) at r = 0. r (3,) rad -> (3, 3)."""
    theta2 = (r * r).sum()
    theta = torch.sqrt(theta2 + 1e-300)
    small = theta2 < 1e-12
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / (theta2 + 1e-300))
    k = skew(r)
    return torch.eye(3, dtype=r.dtype, device=r.device) + a * k + b * (k @ k)


def matrix_to_rotvec(R: torch.Tensor) -> torch.Tensor:
    """(3, 3) rotation -> (3,) rotation vector in rad, angle in [0, pi] (off the autograd
    graph). Through the unit quaternion of Shepperd's method (the largest of 1 + trace and
    1 + 2 R_ii - trace picks the stable formula), as scipy's ``Rotation`` does."""
    dtype, R = R.dtype, R.detach().to(torch.float64)
    d = torch.cat([torch.diagonal(R), torch.diagonal(R).sum().reshape(1)])
    i = int(torch.argmax(d))
    q = torch.empty(4, dtype=R.dtype, device=R.device)  # x, y, z, w
    if i == 3:
        q[0], q[1], q[2] = R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]
        q[3] = 1 + d[3]
    else:
        j, k = (i + 1) % 3, (i + 2) % 3
        q[i] = 1 - d[3] + 2 * R[i, i]
        q[j], q[k] = R[j, i] + R[i, j], R[k, i] + R[i, k]
        q[3] = R[k, j] - R[j, k]
    q = q / q.norm()
    if q[3] < 0:
        q = -q
    v = q[:3]
    angle = 2 * torch.atan2(v.norm(), q[3])
    a2 = angle * angle
    scale = 2 + a2 / 12 + 7 * a2 * a2 / 2880 if angle <= 1e-3 else angle / torch.sin(angle / 2)
    return (scale * v).to(dtype)


def nearest_rotation(M: torch.Tensor) -> torch.Tensor:
    """The proper rotation X (3, 3) maximising trace(X^T M) for M (3, 3): U D V^T from
    M = U S V^T, D = diag(1, 1, det(U V^T)) so that det X = +1."""
    U, _, Vt = torch.linalg.svd(M)
    d = torch.sign(torch.linalg.det(U @ Vt))
    D = torch.diag(torch.stack([torch.ones_like(d), torch.ones_like(d), d]))
    return U @ D @ Vt


def kabsch(P: torch.Tensor, Q: torch.Tensor):
    """Rigid (R (3, 3), t (3,)) minimising sum |R p_i + t - q_i|^2; P, Q (N, 3) mm, N >= 3
    points not all on one line (else the rotation about that line is arbitrary)."""
    mp, mq = P.mean(0), Q.mean(0)
    R = nearest_rotation((P - mp).T @ (Q - mq)).T
    return R, mq - R @ mp


def procrustes_rotation(A: torch.Tensor, B: torch.Tensor) -> torch.Tensor:
    """Rotation X (3, 3) minimising sum |A_i X - B_i|_F^2 for A, B (N, 3, 3) rotations."""
    return nearest_rotation((A.transpose(1, 2) @ B).sum(0))


def so3_error(Rp: torch.Tensor, Rm: torch.Tensor) -> torch.Tensor:
    """Orientation residual (..., 3) rad between Rp and Rm (..., 3, 3): the axis times
    sin(angle) of Rp^T Rm (the rotation vector to third order; smooth at zero, unlike the
    exact logarithm)."""
    E = Rp.transpose(-1, -2) @ Rm
    return 0.5 * torch.stack([E[..., 2, 1] - E[..., 1, 2], E[..., 0, 2] - E[..., 2, 0],
                              E[..., 1, 0] - E[..., 0, 1]], dim=-1)


@functools.lru_cache(maxsize=8)
def _unit_skews(dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """(3, 3, 3) [e_k]x for k = 0, 1, 2 (a constant, built once per dtype and device)."""
    return skew(torch.eye(3, dtype=dtype, device=device))


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
    E = _unit_skews(r.dtype, r.device)  # E[k] = [e_k]x
    K = torch.einsum("kij,k->ij", E, r)
    KK = K @ K
    out = (2 * r[:, None, None] * (da * K + db * KK) + a * E + b * (E @ K + K @ E))  # (k, 3, 3)
    return out.permute(1, 2, 0)
