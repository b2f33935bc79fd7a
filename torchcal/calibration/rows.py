"""The fit's measurement rows: positions and, when measured, orientations with the
tool-rotation step.

Each pose gives three position residuals ``model - measured`` (mm) and, with measured
orientations ``Rm`` (N, 3, 3) (measurement frame <- measured tool frame), three more: the
orientation error `torchcal.rotations.so3_error` of ``Rp X`` against ``Rm`` (rad), times
``w_rot = sigma_mm / radians(sigma_deg)`` mm per rad, so both kinds of row are weighed
by their stated measurement uncertainty (`orientation_weight`). ``Rp`` is the model's
nominal tool frame and ``X`` (3, 3) the constant rotation between the nominal and the
measured tool frame, solved in closed form (`tool_rotation`, Procrustes) and held fixed
while the parameters move: the tool-rotation step (the fit takes it at the start and
again after its first solve, `Rows.with_tool_rotation`).

The Jacobian is analytic (`CalibrationModel.jacobians`); the orientation rows' through
`so3_error_jacobian`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch

from torchcal.rotations import procrustes_rotation, so3_error


def orientation_weight(sigma_mm: float, sigma_deg: float) -> float:
    """mm per rad that makes an orientation row of uncertainty sigma_deg weigh as a
    position row of uncertainty sigma_mm."""
    return sigma_mm / math.radians(sigma_deg)


def tool_rotation(model, theta: torch.Tensor, ctx, rotation: torch.Tensor) -> torch.Tensor:
    """(3, 3) X minimising sum |Rp_i X - Rm_i|_F^2: the model's tool frames Rp (N, 3, 3) at
    theta (P,), the measured ones `rotation` (N, 3, 3) (off the autograd graph)."""
    with torch.no_grad():
        return procrustes_rotation(model.predict_rotation(theta, ctx), rotation)


def so3_error_jacobian(Rp: torch.Tensor, Rm: torch.Tensor, W: torch.Tensor, scale: float = 1.0) -> torch.Tensor:
    """d `so3_error`(Rp, Rm) / d theta (N, 3, P) for d Rp / d theta_k = [W_k]x Rp,
    W (N, 3, P) rad per unit (`CalibrationModel.rotation_jacobian`), times `scale`. With
    E = Rp^T Rm, dE_k = -[w_k]x E for w_k = Rp^T W_k, and the axial vector of the skew
    part of [w]x E is (tr(E) I - E) w / 2. (The scale multiplies the (N, 3, 3) factor,
    not the (N, 3, P) result.)"""
    E = Rp.transpose(-1, -2) @ Rm
    tr = E.diagonal(dim1=-2, dim2=-1).sum(-1)
    M = torch.diag_embed(tr.unsqueeze(-1).expand(-1, 3)) - E
    return ((-0.5 * scale) * (M @ Rp.transpose(-1, -2))) @ W.contiguous()


@dataclass(frozen=True)
class Rows:
    """The measurement rows of a fit: model (`CalibrationModel`), ctx (`Context`), xyz
    (N, 3) mm measured; rotation (N, 3, 3) measured orientations or None; w_rot mm per
    rad (`orientation_weight`); tool_R (3, 3) the tool rotation X (None until
    `with_tool_rotation`; needed when rotation is given)."""

    model: object
    ctx: object
    xyz: torch.Tensor
    rotation: torch.Tensor | None = None
    w_rot: float = 1.0
    tool_R: torch.Tensor | None = None

    @property
    def k(self) -> int:
        """Residuals per pose: 3 (positions) or 6 (and orientations)."""
        return 3 if self.rotation is None else 6

    def with_tool_rotation(self, theta: torch.Tensor) -> "Rows":
        """The same rows with the tool rotation solved at theta (P,) (the tool-rotation step)."""
        return replace(self, tool_R=tool_rotation(self.model, theta, self.ctx, self.rotation))

    def residual(self, theta: torch.Tensor, walk_once: bool = False) -> torch.Tensor:
        """(N, k) model - measured at theta (P,): position mm, orientation mm-equivalent.
        walk_once: with orientations, positions and orientations from one walk of the chain
        (`CalibrationModel.predict_pose`, about 0.8x the time), equal to the two walks'
        to rounding: for the chord iterations, whose fixed point is certified to
        `torchcal.calibration.refit.STEP_TOL`; the LM keeps the two walks (where its
        tolerances stop it moves with the rounding of its path, beyond 1e-6 relative)."""
        if self.rotation is None:
            return self.model.predict(theta, self.ctx) - self.xyz
        if walk_once:
            v, R = self.model.predict_pose(theta, self.ctx)
        else:
            v, R = self.model.predict(theta, self.ctx), self.model.predict_rotation(theta, self.ctx)
        e = so3_error(R @ self.tool_R, self.rotation)
        return torch.cat([v - self.xyz, -self.w_rot * e], dim=-1)

    def jacobian(self, theta: torch.Tensor, out: torch.Tensor | None = None, *, residual: bool = False):
        """(N, k, P) d residual / d theta at theta (P,), analytic; written into `out`
        (N, k, P) when given (a view of the solver's stacked Jacobian: no copy of it).
        residual: (J, the `residual` (N, k) at theta) from the same chain walk (equal to
        `residual`'s to rounding; no second forward pass)."""
        if self.rotation is None:
            J, _, v = self.model.jacobians(theta, self.ctx, position=True, out=out)
            return (J, v - self.xyz) if residual else J
        if out is None:
            N, P = self.xyz.shape[0], theta.shape[-1]
            out = theta.new_empty(N, 6, P)
        J, W, R, v = self.model.jacobians(theta, self.ctx, rotation=True, frame=True, position=True,
                                          out=out[:, :3])  # the position rows written in place
        Rt = R @ self.tool_R
        out[:, 3:] = so3_error_jacobian(Rt, self.rotation, W, -self.w_rot)
        if not residual:
            return out
        return out, torch.cat([v - self.xyz, -self.w_rot * so3_error(Rt, self.rotation)], dim=-1)
