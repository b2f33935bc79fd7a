"""Damped least squares / Levenberg-Marquardt (docs/paper.md eq. 29), batched.

Solves ``min_x 0.5 |w * r(x)|^2`` for a batch of independent problems at once (one per
zone): ``x (B, P)``, ``r (B, R)``. Each batch element keeps its own damping mu and its
own step acceptance. The step is

    dx = -(J^T W J + mu D)^-1 J^T W r,     D = diag(J^T W J)  (Marquardt's column scaling)

with mu starting at 1e-3 (the paper's value), divided by 10 after an accepted step and
multiplied by 10 after a rejected one. Parameters outside `free` never move (their
columns are dropped from the normal equations, not damped). Stops per element:

- CONVERGED: an accepted step lowered the cost by less than `ftol` (relative) or was
  shorter than `xtol` relative to x, *and* x is stationary: the largest cosine between
  the weighted residual and a Jacobian column, ``|g_k| / sqrt(A_kk * 2 cost)`` with
  ``g = J^T W r``, ``A = J^T W J``, is at most `gtol` (scale-free first-order
  optimality, as MINPACK's gtol), or the undamped Gauss-Newton step is below
  sqrt(eps) relative to x (residuals at rounding level, where the cosine means
  nothing). The stationarity test keeps a vanishing step forced by a huge mu (in
  float32 it rounds to no step at all) from counting as convergence; an equal cost
  is accepted as a step only at a stationary x.
- STALLED: mu exceeded `MU_MAX` (1e10) without a step that lowers the cost (a wrong
  Jacobian, a non-finite cost). Never reported as converged.
- MAX_ITERATIONS: `max_iter` iterations first.

Lower bounds (`lower`, a parameter that cannot be negative): a projected step with an
active set. A free parameter at its bound whose gradient pushes it below is held for
that iteration (its column dropped, its cosine not counted in the stationarity test,
the KKT condition of a bounded minimum); the trial point is clipped to the bounds.
The Jacobian is the model's own: the bound changes the step, not the derivatives.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import torch

#: damping above which a batch element stops as STALLED
MU_MAX = 1e10
#: smallest damping (and the one of the Gauss-Newton step in the stationarity test)
MU_MIN = 1e-15


class LMStatus(IntEnum):
    """Why a batch element stopped.

    CONVERGED: an accepted step met the ftol / xtol rule. STALLED: the damping passed
    `MU_MAX` without a step that lowers the cost (a wrong Jacobian, a non-finite cost,
    or a point the solver cannot improve on). MAX_ITERATIONS: `max_iter` reached first.
    """

    CONVERGED = 0
    STALLED = 1
    MAX_ITERATIONS = 2

    @property
    def label(self) -> str:
        """'converged', 'stalled' or 'max_iterations' (the text files and the CLI show)."""
        return self.name.lower()


@dataclass(frozen=True)
class LMResult:
    """Batched solver result.

    x (B, P) solution; cost (B,) 0.5 |w r|^2 at x; n_iter (B,) iterations;
    status (B,) int64 `LMStatus` values per batch element.
    """

    x: torch.Tensor
    cost: torch.Tensor
    n_iter: torch.Tensor
    status: torch.Tensor

    @property
    def converged(self) -> torch.Tensor:
        """(B,) bool: status CONVERGED (a stalled solve is never converged)."""
        return self.status == LMStatus.CONVERGED

    def status_labels(self) -> list[str]:
        """Per batch element 'converged', 'stalled' or 'max_iterations'."""
        return [LMStatus(int(s)).label for s in self.status.tolist()]


def batched_jacobian(residual_fn, x: torch.Tensor) -> torch.Tensor:
    """dr/dx per batch element by forward mode: x (B, P) -> (B, R, P).

    One jvp per parameter column, shared by all batch elements (the problems are
    independent, so the cross terms of a full jacfwd would be zeros).
    """
    P = x.shape[-1]
    basis = torch.eye(P, dtype=x.dtype, device=x.device)[:, None, :].expand(P, *x.shape)
    cols = torch.func.vmap(lambda t: torch.func.jvp(residual_fn, (x,), (t,))[1])(basis)  # (P, B, R)
    return cols.permute(1, 2, 0)


def levenberg_marquardt(residual_fn, x0, free=None, weights=None, jacobian_fn=None,
                        mu0: float = 1e-3, max_iter: int = 100, ftol: float = 1e-12,
                        xtol: float = 1e-12, gtol: float = 1e-3, lower=None) -> LMResult:
    """Batched damped least squares.

    residual_fn: x (B, P) -> r (B, R). x0 (B, P), any float dtype and device (the result
    stays on them). free: (P,) or (B, P) bool, default all.
    weights: (B, R) non-negative row weights (IRLS), default ones.
    jacobian_fn: x (B, P) -> (B, R, P); default forward-mode autodiff of residual_fn.
    mu0, max_iter, ftol, xtol, gtol: as in the module docstring. lower: (P,) or (B, P)
    lower bounds (-inf: none; default none); x0 is clipped to them.
    Returns an `LMResult` with a per-element `LMStatus`.
    """
    x = x0.clone()
    B, P = x.shape
    free = torch.ones(B, P, dtype=torch.bool, device=x.device) if free is None \
        else torch.as_tensor(free, device=x.device).expand(B, P)
    jac = jacobian_fn or (lambda z: batched_jacobian(residual_fn, z))
    lo = None if lower is None else torch.as_tensor(lower, dtype=x.dtype, device=x.device).expand(B, P)
    if lo is not None:
        x = torch.where(free, torch.maximum(x, lo), x)
    r = residual_fn(x)
    w = torch.ones_like(r) if weights is None else weights
    cost = 0.5 * (w * r * r).sum(-1)
    mu = torch.full((B,), mu0, dtype=x.dtype, device=x.device)
    done = torch.zeros(B, dtype=torch.bool, device=x.device)
    status = torch.full((B,), int(LMStatus.MAX_ITERATIONS), dtype=torch.long, device=x.device)
    n_iter = torch.zeros(B, dtype=torch.long, device=x.device)
    eye = torch.eye(P, dtype=x.dtype, device=x.device)
    fmask0 = free.to(x.dtype)
    # unit weights (every fit that is not robust) leave J as it is: no weighted copy of it
    unit = weights is None or bool((w == 1).all())
    held_any = not bool(free.all())
    tiny = torch.finfo(x.dtype).tiny
    root_eps = torch.finfo(x.dtype).eps ** 0.5
    for _ in range(max_iter):
        if done.all():
            break
        # held columns dropped: their rows and columns of J^T W J and their entries of g
        # are zeroed after the products (the same numbers as products of a masked J,
        # without a masked copy of J)
        J = jac(x)
        JtW = J.transpose(1, 2) if unit else (J * w[:, :, None]).transpose(1, 2)  # (B, P, R), a view
        g = (JtW @ r.unsqueeze(-1)).squeeze(-1) * fmask0  # (B, P)
        fmask = fmask0
        if lo is not None:  # at the bound and pushed below it: held this iteration
            fmask = fmask0 * ~((x <= lo) & (g > 0))
            g = g * fmask
        A = JtW @ J  # (B, P, P)
        if held_any or lo is not None:
            A = A * (fmask[:, :, None] * fmask[:, None, :])
        diag = torch.diagonal(A, dim1=1, dim2=2).clamp_min(1e-30)
        # a held parameter gets a unit row so the system stays regular and its step is 0
        A_held = eye * (1 - fmask)[:, None, :]
        cosine = g.abs() / (diag.sqrt() * (2 * cost).sqrt()[:, None]).clamp_min(tiny)  # (B, P)
        gn = torch.linalg.solve(A + MU_MIN * torch.diag_embed(diag * fmask) + A_held, g.unsqueeze(-1))
        gn_small = gn.squeeze(-1).norm(dim=-1) <= root_eps * (x.norm(dim=-1) + root_eps)
        stationary = (cosine.amax(-1) <= gtol) | gn_small  # (B,)
        while True:
            M = A + mu[:, None, None] * torch.diag_embed(diag * fmask) + A_held
            step = -torch.linalg.solve(M, g.unsqueeze(-1)).squeeze(-1) * fmask
            step = torch.where(done[:, None], torch.zeros_like(step), step)
            if lo is not None:  # projected onto the bounds
                step = torch.maximum(x + step, torch.where(fmask > 0, lo, -torch.inf)) - x
            x_new = x + step
            r_new = residual_fn(x_new)
            cost_new = 0.5 * (w * r_new * r_new).sum(-1)
            # an equal cost counts only at a stationary x: a step that rounds to nothing
            # away from a minimum is no progress
            ok = ((cost_new < cost) | ((cost_new == cost) & stationary)) & torch.isfinite(cost_new)
            if (ok | done | (mu > MU_MAX)).all():
                break
            mu = torch.where(ok | done, mu, mu * 10)
        accept = ok & ~done
        rel = (cost - cost_new) / cost.clamp_min(tiny)
        small_step = step.norm(dim=-1) <= xtol * (x.norm(dim=-1) + xtol)
        x = torch.where(accept[:, None], x_new, x)
        r = torch.where(accept[:, None], r_new, r)
        n_iter = n_iter + (~done).long()
        converged_now = accept & stationary & ((rel < ftol) | small_step)
        cost = torch.where(accept, cost_new, cost)
        mu = torch.where(accept, (mu / 10).clamp_min(MU_MIN), mu)
        stalled_now = ~done & ~converged_now & (mu > MU_MAX)
        status = torch.where(converged_now & ~done, int(LMStatus.CONVERGED), status)
        status = torch.where(stalled_now, int(LMStatus.STALLED), status)
        done = done | converged_now | stalled_now
    return LMResult(x, cost, n_iter, status)
