"""Registration: the rigid frame of the measuring instrument, in closed form, before a fit.

Measurements come in the instrument's (laser tracker's) frame, which may be rotated and
shifted arbitrarily against the robot's base. A fit that starts with the base frame at
identity then starts far from the solution (and trades the rotation for joint-1
deviations). `register_frame` computes the rigid motion that best maps the nominal model's
points onto the measured ones (Kabsch / Umeyama without scale: SVD of the
cross-covariance) and writes it into the model's `base_frame` parameters, so that the
fit starts at the registered frame with every deviation of the robot at zero.

The fit does the same for measured orientations: the constant rotation between the robot's
nominal tool frame and the measured (e.g. T-Mac) frame, as the orthogonal Procrustes
solution over all rows (`torchcal.rotations.procrustes_rotation`).
"""

from __future__ import annotations

import math

import torch

from torchcal.rotations import kabsch, matrix_to_fixed_xyz, matrix_to_rotvec, rotvec_to_matrix


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
    sl = _base_slice(model)
    if sl is None:
        return None
    p = theta[sl].detach().cpu().double()
    return frame_summary(rotvec_to_matrix(p[3:6]), p[:3])


def register_frame(model, ctx, xyz: torch.Tensor, theta0: torch.Tensor | None = None):
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
