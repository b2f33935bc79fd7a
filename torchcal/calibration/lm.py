"""Damped least squares / Levenberg-Marquardt (docs/paper.md eq. 29), batched.

Solves ``min_x 0.5 |w * r(x)|^2`` for a batch of independent problems at once (one per
zone): ``x (B, P)``, ``r (B, R)``. Each batch element keeps its own damping mu and its
own step acceptance. The step is

    dx = -(J^T W J + mu D)^-1 J^T W r,     D = diag(J^T W J)  (Marquardt's column scaling)

with mu starting at 1e-3 (the paper's value), divided by 10 after an accepted step and
multiplied by 10 after a rejected one. Parameters outside `free` never move (their
columns are dropped from the normal equations, not damped). Stops per element when the
relative cost decrease of an accepted step is below `ftol` and the step is below `xtol`
relative to x, when mu exceeds 1e10, or after `max_iter` iterations.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class LMResult:
    """x (B, P) solution; cost (B,) 0.5 |w r|^2; n_iter (B,); converged (B,) bool."""

    x: torch.Tensor
    cost: torch.Tensor
    n_iter: torch.Tensor
    converged: torch.Tensor


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
                        xtol: float = 1e-12) -> LMResult:
    """Batched damped least squares.

    residual_fn: x (B, P) -> r (B, R). x0 (B, P). free: (P,) or (B, P) bool, default all.
    weights: (B, R) non-negative row weights (IRLS), default ones.
    jacobian_fn: x (B, P) -> (B, R, P); default forward-mode autodiff of residual_fn.
    """
    x = x0.clone()
    B, P = x.shape
    free = torch.ones(B, P, dtype=torch.bool, device=x.device) if free is None \
        else torch.as_tensor(free, device=x.device).expand(B, P)
    jac = jacobian_fn or (lambda z: batched_jacobian(residual_fn, z))
    r = residual_fn(x)
    w = torch.ones_like(r) if weights is None else weights
    cost = 0.5 * (w * r * r).sum(-1)
    mu = torch.full((B,), mu0, dtype=x.dtype, device=x.device)
    done = torch.zeros(B, dtype=torch.bool, device=x.device)
    n_iter = torch.zeros(B, dtype=torch.long, device=x.device)
    eye = torch.eye(P, dtype=x.dtype, device=x.device)
    fmask = free.to(x.dtype)
    for _ in range(max_iter):
        if done.all():
            break
        J = jac(x) * fmask[:, None, :]  # held columns dropped
        JtW = J.transpose(1, 2) * w[:, None, :]
        A = JtW @ J  # (B, P, P)
        g = (JtW @ r.unsqueeze(-1)).squeeze(-1)  # (B, P)
        diag = torch.diagonal(A, dim1=1, dim2=2).clamp_min(1e-30)
        # a held parameter gets a unit row so the system stays regular and its step is 0
        A_held = eye * (1 - fmask)[:, None, :]
        while True:
            M = A + mu[:, None, None] * torch.diag_embed(diag * fmask) + A_held
            step = -torch.linalg.solve(M, g.unsqueeze(-1)).squeeze(-1) * fmask
            step = torch.where(done[:, None], torch.zeros_like(step), step)
            x_new = x + step
            r_new = residual_fn(x_new)
            cost_new = 0.5 * (w * r_new * r_new).sum(-1)
            ok = (cost_new <= cost) & torch.isfinite(cost_new)
            if (ok | done | (mu > 1e10)).all():
                break
            mu = torch.where(ok | done, mu, mu * 10)
        accept = ok & ~done
        rel = (cost - cost_new) / cost.clamp_min(1e-300)
        small_step = step.norm(dim=-1) <= xtol * (x.norm(dim=-1) + xtol)
        x = torch.where(accept[:, None], x_new, x)
        r = torch.where(accept[:, None], r_new, r)
        n_iter = n_iter + (~done).long()
        converged_now = accept & ((rel < ftol) | small_step)
        cost = torch.where(accept, cost_new, cost)
        mu = torch.where(accept, (mu / 10).clamp_min(1e-15), mu)
        done = done | converged_now | (mu > 1e10)
    return LMResult(x, cost, n_iter, done)
