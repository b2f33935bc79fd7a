"""Registration: the rigid frame of the measuring instrument, in closed form, before a fit.

Measurements come in the instrument's (laser tracker's) frame, which may be rotated and
shifted arbitrarily against the robot's base. A fit that starts with the base frame at
identity then starts far from the solution (and trades the rotation for joint-1
deviations). `register` computes the rigid motion that best maps the nominal model's
points onto the measured ones (Kabsch / Umeyama without scale: SVD of the
cross-covariance) and writes it into the model's `base_frame` parameters, so that the
fit starts at the registered frame with every deviation of the robot at zero.

`tool_rotation` does the same for measured orientations: the constant rotation between
the robot's nominal tool frame and the measured (e.g. T-Mac) frame, as the orthogonal
Procrustes solution over all rows.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from torchcal.measurements import matrix_to_fixed_xyz


def kabsch(P: torch.Tensor, Q: torch.Tensor):
    """Rigid (R (3, 3), t (3,)) minimising sum |R p_i + t - q_i|^2; P, Q (N, 3) mm, N >= 3
    points not all on one line (else the rotation about that line is arbitrary)."""
    mp, mq = P.mean(0), Q.mean(0)
    H = (P - mp).T @ (Q - mq)  # (3, 3)
    U, _, Vt = torch.linalg.svd(H)
    d = torch.sign(torch.linalg.det(Vt.T @ U.T))
    D = torch.diag(torch.stack([torch.ones_like(d), torch.ones_like(d), d]))
    R = Vt.T @ D @ U.T
    return R, mq - R @ mp


def procrustes_rotation(A: torch.Tensor, B: torch.Tensor) -> torch.Tensor:
    """Rotation X (3, 3) minimising sum |A_i X - B_i|_F^2 for A, B (N, 3, 3) rotations."""
    M = (A.transpose(1, 2) @ B).sum(0)
    U, _, Vt = torch.linalg.svd(M)
    d = torch.sign(torch.linalg.det(U @ Vt))
    D = torch.diag(torch.stack([torch.ones_like(d), torch.ones_like(d), d]))
    return U @ D @ Vt


def matrix_to_rotvec(R: torch.Tensor) -> torch.Tensor:
    """(3, 3) rotation -> (3,) rotation vector in rad (scipy, off the autograd graph)."""
    rv = Rotation.from_matrix(R.detach().cpu().numpy()).as_rotvec()
    return torch.as_tensor(np.asarray(rv), dtype=R.dtype, device=R.device)


def _base_slice(model):
    for e, sl in zip(model.effects, model.slices[1:]):
        if e.name == "base_frame":
            return sl
    return None


def frame_summary(R: torch.Tensor, t: torch.Tensor) -> dict:
    """{"translation_mm": [x, y, z], "rotation_fixed_xyz_deg": [rx, ry, rz]} (R = Rz Ry Rx)."""
    ang = torch.rad2deg(matrix_to_fixed_xyz(R.detach().cpu().double()))
    return {"translation_mm": [float(v) for v in t.detach().cpu()],
            "rotation_fixed_xyz_deg": [float(v) for v in ang]}


def base_frame_summary(model, theta: torch.Tensor) -> dict | None:
    """The fitted base frame (measurement <- robot base) in mm and fixed-XYZ degrees, or
    None when the model has no base_frame effect."""
    from torchcal.effects.base_frame import rotvec_to_matrix

    sl = _base_slice(model)
    if sl is None:
        return None
    p = theta[sl].detach().cpu().double()
    return frame_summary(rotvec_to_matrix(p[3:6]), p[:3])


def register(model, ctx, xyz: torch.Tensor, theta0: torch.Tensor | None = None):
    """Closed-form registration of the model at theta0 (default zeros) to measured xyz (N, 3).

    Returns (theta (P,), info): theta is theta0 with the base_frame parameters set to the
    rigid motion measured <- model (unchanged when the model has no base_frame); info
    holds "rms_before_mm" (model as is), "rms_after_mm" (after the rigid motion) and the
    frame ("translation_mm", "rotation_fixed_xyz_deg").
    """
    theta = model.zeros() if theta0 is None else theta0.detach().clone()
    sl = _base_slice(model)
    if sl is not None:
        theta[sl] = 0.0
    with torch.no_grad():
        v = model.predict(theta, ctx)
    R, t = kabsch(v, xyz)
    before = float((v - xyz).norm(dim=-1).pow(2).mean().sqrt())
    after = float((v @ R.T + t - xyz).norm(dim=-1).pow(2).mean().sqrt())
    if sl is not None:
        theta[sl] = torch.cat([t, matrix_to_rotvec(R)]).to(theta)
    info = {"rms_before_mm": before, "rms_after_mm": after, **frame_summary(R, t)}
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (float(torch.trace(R)) - 1) / 2))))
    info["rotation_angle_deg"] = angle
    return theta, info
