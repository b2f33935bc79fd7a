"""Identification: identifiability analysis and the fit of a `CalibrationModel`.

Identifiability (at the starting point, on the column-scaled Jacobian):

- QR with column pivoting orders the free parameters from most to least independent;
  those whose pivot |R_kk| falls below ``rank_tol * |R_00|`` cannot be identified from
  these poses. They are reported by name and *held at nominal* (zero deviation) instead
  of being silently damped as eq. 29 would.
- Singular values of the identifiable columns give the condition number and the
  observability indices of Borm & Menq / Nahvi & Hollerbach (O1..O5, m = number of poses).

The fit is Levenberg-Marquardt (`torchcal.calibration.lm`) on the identifiable parameters, with
optional robust row weights by IRLS (Huber or Cauchy on the per-pose distance residual,
scale = the median distance residual, thresholds at 2.5 times it). Standard errors from ``s^2 (J^T W J)^-1``, s^2 = weighted RSS / dof,
pose-level when poses repeat (`torchcal.calibration.uncertainty`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
import torch

from torchcal.effects.base import Context
from torchcal.errors import InputError
from torchcal.calibration.lm import levenberg_marquardt
from torchcal.calibration.model import CalibrationModel
from torchcal.calibration.uncertainty import ParameterCovariance, parameter_covariance

RANK_TOL = 1e-6


@dataclass
class Identifiability:
    """Rank analysis of the scaled Jacobian.

    free: (P,) bool identifiable parameters; held: names held at nominal; rank: number
    identifiable; condition: condition number of the scaled identifiable columns;
    observability: dict O1..O5.
    """

    free: torch.Tensor
    held: list[str]
    rank: int
    condition: float
    observability: dict
    n_rows: int

    def to_dict(self) -> dict:
        return {"rank": self.rank, "condition_number": self.condition, "held_at_nominal": self.held,
                "observability": self.observability, "poses": self.n_rows}


def identifiability(J: torch.Tensor, names, candidate_free, rank_tol: float = RANK_TOL) -> Identifiability:
    """J (N, 3, P) or (R, P) position Jacobian; candidate_free (P,) bool."""
    n_rows = J.shape[0]
    J = J.reshape(-1, J.shape[-1]).detach().cpu().double().numpy()
    cand = np.flatnonzero(candidate_free.cpu().numpy())
    norms = np.linalg.norm(J[:, cand], axis=0)
    live = cand[norms > 1e-12 * max(norms.max(initial=0.0), 1e-300)]
    Js = J[:, live] / np.linalg.norm(J[:, live], axis=0)
    free = torch.zeros(J.shape[1], dtype=torch.bool)
    if live.size:
        _, R, piv = scipy.linalg.qr(Js, mode="economic", pivoting=True)
        d = np.abs(np.diag(R))
        rank = int((d > rank_tol * d[0]).sum())
        keep = live[piv[:rank]]
        free[torch.as_tensor(np.sort(keep))] = True
        s = np.linalg.svd(Js[:, np.sort(piv[:rank])], compute_uv=False)
    else:
        rank, s = 0, np.ones(1)
    held = [names[i] for i in cand if not free[i]]
    m = max(n_rows, 1)
    obs = {
        "O1": float(np.exp(np.log(s).mean()) / np.sqrt(m)),
        "O2": float(s[-1] / s[0]),
        "O3": float(s[-1]),
        "O4": float(s[-1] ** 2 / s[0]),
        "O5": float(1.0 / np.sum(1.0 / s)),
    }
    return Identifiability(free, held, rank, float(s[0] / s[-1]), obs, n_rows)


@dataclass
class FitResult:
    """A fitted model.

    theta: (P,) parameters; std: (P,) standard errors (0 where held); residuals: (N, 3)
    mm measured - model; weights: (N,) final robust weights (ones when not robust);
    report: identifiability; outliers: row indices with weight below 0.1 (robust fits);
    status: how the (last) LM solve stopped, 'converged', 'stalled' or 'max_iterations'
    (`torchcal.calibration.lm.LMStatus`).
    """

    model: CalibrationModel
    theta: torch.Tensor
    std: torch.Tensor
    residuals: torch.Tensor
    weights: torch.Tensor
    report: Identifiability
    n_iter: int
    outliers: list = field(default_factory=list)
    covariance: ParameterCovariance | None = None  # (P, P) and how it was estimated
    status: str = "converged"

    @property
    def converged(self) -> bool:
        """True only when the solver met its convergence rule (never for a stalled solve)."""
        return self.status == "converged"

    def to_dict(self, source=None, seed: int = 0, robust=None, pose_ids=None) -> dict:
        """The MODEL.json object of ``torchcal fit`` (`torchcal.io.modelfile.to_dict`):
        format, robot, effects, parameters (value, unit, std, ci95), covariance,
        identifiability, fit (n, rms_mm, max_mm, robust, outlier_poses, iterations,
        status), provenance."""
        from torchcal.io.modelfile import to_dict

        return to_dict(self, source=source, seed=seed, robust=robust, pose_ids=pose_ids)

    @property
    def rms_mm(self) -> float:
        """RMS of the distance residual per pose, mm."""
        return float(self.residuals.norm(dim=-1).pow(2).mean().sqrt())


def _robust_weights(dist: torch.Tensor, kind: str) -> torch.Tensor:
    u = dist / dist.median().clamp_min(1e-9)  # typical distance residual = 1
    if kind == "huber":
        return torch.where(u <= 2.5, torch.ones_like(u), 2.5 / u)
    if kind == "cauchy":
        return 1.0 / (1.0 + (u / 2.5) ** 2)
    raise InputError(f"robust: unknown loss {kind!r}; expected 'huber' or 'cauchy'")


def _generic_rank(model: CalibrationModel, ctx: Context, cand, rank_tol: float) -> int:
    """Number of parameters identifiable at random poses inside the joint limits (the
    data's payload / temperature values reused in turn): what enough poses would give."""
    from torchcal.effects import make_context
    from torchcal.robots.poses import random_poses

    robot = model.robot
    n = int(cand.sum()) + 16
    q = random_poses(robot, n, torch.Generator().manual_seed(0)).to(ctx.q)
    idx = torch.arange(n, device=ctx.q.device) % ctx.q.shape[0]
    temp = None if ctx.temp_c is None else ctx.temp_c[idx]
    payload = None if ctx.payload_kg is None else ctx.payload_kg[idx]
    g = make_context(robot, q, payload, temp)
    J = model.jacobian(model.zeros(), g)
    return identifiability(J, model.param_names(), cand, rank_tol).rank


def fit(model: CalibrationModel, ctx: Context, xyz: torch.Tensor, theta0=None, free=None,
        robust: str | None = None, max_iter: int = 60, rank_tol: float = RANK_TOL,
        pose=None) -> FitResult:
    """Fit model parameters to measured TCP positions xyz (N, 3) mm.

    pose: (N,) int pose ids; with repeats the standard errors are pose-level
    (`torchcal.calibration.uncertainty`).

    free: (P,) bool candidate parameters (default `model.default_free()`); the
    identifiability analysis at theta0 may hold more. robust: None, 'huber' or 'cauchy'.
    """
    model.check_context(ctx)
    theta0 = model.zeros() if theta0 is None else theta0
    cand = model.default_free() if free is None else free
    n_cand = int(cand.sum())
    J0 = model.jacobian(theta0, ctx)
    report = identifiability(J0, model.param_names(), cand, rank_tol)
    n_rows = xyz.shape[0]
    if 3 * n_rows <= report.rank:
        # the equations, not the model, bound the rank here: count the identifiable
        # parameters at generic poses (seeded, so the message is reproducible)
        k = _generic_rank(model, ctx, cand, rank_tol)
        need = k // 3 + 1
        raise InputError(f"too few poses: {n_rows} poses give {3 * n_rows} equations (3 per pose) "
                         f"but the model [{', '.join(model.specs()) or 'geometric only'}] has {k} "
                         f"identifiable parameters (of {n_cand}); need at least {need} poses, "
                         f"in practice {max(2 * need, need + 10)} or more spread over the workspace")
    if n_cand and report.rank == 0:
        raise InputError("no parameter is identifiable from these poses")

    def residual_fn(x):  # x (1, P) -> (1, 3N)
        return (model.predict(x[0], ctx) - xyz).reshape(1, -1)

    def jacobian_fn(x):
        return model.jacobian(x[0], ctx).reshape(1, -1, x.shape[-1])

    weights = torch.ones(n_rows, dtype=xyz.dtype, device=xyz.device)
    x = theta0.unsqueeze(0)
    rounds = 1 if robust is None else 8
    for _ in range(rounds):
        w = weights.repeat_interleave(3).unsqueeze(0)
        res = levenberg_marquardt(residual_fn, x, free=report.free, weights=w,
                                  jacobian_fn=jacobian_fn, max_iter=max_iter)
        x = res.x
        if robust is None:
            break
        dist = (model.predict(x[0], ctx) - xyz).norm(dim=-1)
        new = _robust_weights(dist, robust)
        if (new - weights).abs().max() < 1e-4:
            weights = new
            break
        weights = new
    theta = x[0]
    resid = xyz - model.predict(theta, ctx)
    covariance = parameter_covariance(model.jacobian(theta, ctx), resid, report.free, pose=pose,
                                      weights=weights if robust else None)
    std = covariance.std
    outliers = torch.nonzero(weights < 0.1).flatten().tolist() if robust else []
    return FitResult(model, theta, std, resid, weights, report, int(res.n_iter[0]), outliers, covariance,
                     res.status_labels()[0])
