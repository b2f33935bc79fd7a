"""Robust row weights of the fit (IRLS), a pure function of the per-pose distance residual.

The scale is the median distance residual ``m``; with ``u = d / m`` (a typical row has
u = 1) and the threshold ``k = ROBUST_K`` (2.5):

- Huber: ``w(u) = 1`` for ``u <= k``, ``k / u`` beyond (psi(u) / u of Huber's loss);
- Cauchy: ``w(u) = 1 / (1 + (u / k)^2)``.

Rows within ``k`` times the median (`inliers`) are the ordinary ones: the prior's
strength is their RMS (`torchcal.calibration.prior`).
"""

from __future__ import annotations

import torch

from torchcal.errors import InputError

ROBUST_K = 2.5  # IRLS threshold, in units of the median distance residual
LOSSES = ("huber", "cauchy")


def inliers(dist: torch.Tensor) -> torch.Tensor:
    """(N,) bool: rows within ROBUST_K times the median distance residual dist (N,) mm,
    the rows a robust loss treats as ordinary."""
    return dist <= ROBUST_K * dist.median().clamp_min(1e-9)


def robust_weights(dist: torch.Tensor, kind: str) -> torch.Tensor:
    """(N,) IRLS weights in (0, 1] of the distance residuals dist (N,) mm for the loss
    `kind` ('huber' or 'cauchy'; module doc)."""
    u = dist / dist.median().clamp_min(1e-9)  # typical distance residual = 1
    if kind == "huber":
        return torch.where(u <= ROBUST_K, torch.ones_like(u), ROBUST_K / u)
    if kind == "cauchy":
        return 1.0 / (1.0 + (u / ROBUST_K) ** 2)
    raise InputError(f"robust: unknown loss {kind!r}; expected 'huber' or 'cauchy'")
