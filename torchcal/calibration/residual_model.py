"""The optional residual stage: a non-physical kernel correction on top of the physical model.

``torchcal fit --residual-model kernel`` (``torchcal.fit(..., residual_model="kernel")``)
fits the probe of `torchcal.diagnosis.probe` to the physical model's residual
(measured - model, (N, 3) mm) on the joint angles alone, as (sin q, cos q) of the revolute
joints that vary (the conditions a compensation knows beforehand): the inputs, RBF
length scale and ridge are chosen by pose-grouped cross-validation on the fit's rows
(forward selection, `probe.choose`), the dual weights by kernel ridge regression on all
of them. The stage then predicts

    position(q) = physical model(q) + k(x(q), X) alpha     (mm)

It is a learned look-up of what the physical model misses, not a physical effect: it
interpolates between the calibration poses and extrapolates worst of all outside them
(the correction fades to zero farther than a few length scales from every training pose).
MODEL.json stores it under ``residual_model`` in plain JSON lists:

    {"kind": "kernel", "non_physical": true, "inputs": ["q2", "q1"],
     "length_scale_rad": l, "ridge": lam, "cv_rms_mm": held-out rms on the fit's poses,
     "q_train_deg": [[...] per training row, the input joints only],
     "dual_weights_mm": [[ax, ay, az] per training row]}

`evaluate` and `compensate` apply it; `export` drops it (a URDF or robot file holds only
the physical model). docs/residual-model.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from torchcal.errors import InputError

KINDS = ("kernel",)


@dataclass(frozen=True, eq=False)
class KernelResidual:
    """inputs: joint names ('q2', ...); joints: their 0-based indices; X: (N, 2 len(inputs))
    training inputs (sin, cos); alpha: (N, 3) mm dual weights; length_scale (rad), ridge;
    cv_rms_mm: the distance RMS the stage left on held-out poses of the fit's data."""

    inputs: tuple
    q_train: torch.Tensor  # (N, len(inputs)) rad
    alpha: torch.Tensor  # (N, 3) mm
    length_scale: float
    ridge: float
    cv_rms_mm: float

    @property
    def joints(self) -> list[int]:
        return [int(k[1:]) - 1 for k in self.inputs]

    def _x(self, q: torch.Tensor) -> torch.Tensor:
        return torch.cat([torch.sin(q), torch.cos(q)], -1)

    def predict(self, q: torch.Tensor) -> torch.Tensor:
        """(M, 3) mm correction at joint values q (M, n) rad (float64, the device of alpha)."""
        from torchcal.kernel_ridge import rbf

        qs = q.detach().to(self.alpha)[:, self.joints]
        return rbf(self._x(qs), self._x(self.q_train), self.length_scale) @ self.alpha

    def to_dict(self) -> dict:
        return {"kind": "kernel", "non_physical": True, "inputs": list(self.inputs),
                "length_scale_rad": self.length_scale, "ridge": self.ridge, "cv_rms_mm": self.cv_rms_mm,
                "q_train_deg": torch.rad2deg(self.q_train).tolist(), "dual_weights_mm": self.alpha.tolist()}

    def describe(self) -> str:
        from torchcal.kernel_ridge import MAX_ROWS

        return (f"residual stage (non-physical kernel correction on {', '.join(self.inputs)}, length scale "
                f"{math.degrees(self.length_scale):.3g} deg, {self.alpha.shape[0]} training rows): cross-validated rms "
                f"{self.cv_rms_mm:.4f} mm on the poses it was chosen on (at most {MAX_ROWS} rows)")


def from_dict(obj, robot, where: str) -> KernelResidual:
    """The stage of MODEL.json's ``residual_model`` (InputError naming `where` when malformed)."""
    try:
        if obj["kind"] != "kernel":
            raise ValueError(f"kind {obj['kind']!r} (known: {', '.join(KINDS)})")
        inputs = tuple(str(k) for k in obj["inputs"])
        joints = [int(k[1:]) - 1 for k in inputs]
        if not all(k.startswith("q") and 0 <= j < robot.n and not bool(robot.prismatic[j])
                   for k, j in zip(inputs, joints)):
            raise ValueError(f"inputs {list(inputs)} are not revolute joints of {robot.name}")
        q = torch.deg2rad(torch.tensor(obj["q_train_deg"], dtype=torch.float64)).reshape(-1, len(inputs))
        alpha = torch.tensor(obj["dual_weights_mm"], dtype=torch.float64).reshape(-1, 3)
        ell, lam = float(obj["length_scale_rad"]), float(obj["ridge"])
        if q.shape[0] != alpha.shape[0] or not (ell > 0) or not (lam > 0):
            raise ValueError("q_train_deg and dual_weights_mm differ in length, or a hyper-parameter is not > 0")
        if not (torch.isfinite(q).all() and torch.isfinite(alpha).all()):
            raise ValueError("non-finite values")
        return KernelResidual(inputs, q, alpha, ell, lam, float(obj.get("cv_rms_mm", float("nan"))))
    except (KeyError, TypeError, ValueError, RuntimeError, IndexError) as exc:
        raise InputError(f"{where}: bad 'residual_model': {exc}") from None


def fit_residual_model(robot, m, residuals: torch.Tensor, *, kind: str = "kernel",
                       seed: int = 0) -> KernelResidual | None:
    """The residual stage for a physical model's residuals (N, 3) mm (measured - model) on
    measurements m; None when no joint angle predicts them (nothing learnable)."""
    from torchcal import kernel_ridge as P
    from torchcal.folds import fold_of_pose

    if kind not in KINDS:
        raise InputError(f"residual model: unknown kind {kind!r} (known: {', '.join(KINDS)})")
    q = m.q.detach().cpu().to(torch.float64)
    pose = m.pose.cpu().numpy()
    values = {f"q{j + 1}": q[:, j].numpy(force=True) for j in range(robot.n)
              if not bool(robot.prismatic[j]) and float(q[:, j].max() - q[:, j].min()) > 0}
    if len(np.unique(pose)) < P.MIN_POSES or not values:
        return None
    feats = P.variable_features(values)
    Y = residuals.detach().cpu().to(torch.float64).reshape(-1, 3)
    fold = fold_of_pose(pose, seed)
    rows = P.subsample(fold, np.ones(len(Y), dtype=bool), pose, seed)
    inputs, ell, lam, mse = P.choose(feats, list(feats), Y, fold, rows)
    if not inputs:
        return None
    joints = [int(k[1:]) - 1 for k in inputs]
    alpha = P.fit_dual(P.stack_inputs(feats, inputs), Y, ell, lam)
    return KernelResidual(tuple(inputs), q[:, joints].clone(), alpha, float(ell), float(lam), math.sqrt(mse))
