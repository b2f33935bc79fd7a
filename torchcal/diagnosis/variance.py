"""The random part of a residual: maximum-likelihood variance terms.

A residual row r (3,) mm has covariance ``S = sigma^2 I + sum_j tau_j^2 B_j B_j^T``: an
isotropic noise and, per random term j (e.g. the random clearance of a joint), the TCP
displacement B_j (3, 2) per mrad of random tilt of its axis. `fit_variances` finds the
log variances by a batched projected Newton method; `variance_loglik` is the per-row
Gaussian log-likelihood the diagnosis scores held-out rows with.
"""

from __future__ import annotations

import numpy as np
import torch


def variance_loglik(r3: np.ndarray, Bs: np.ndarray | None, logp: np.ndarray) -> np.ndarray:
    """Per-row Gaussian log-likelihood (M,) of residuals r3 (M, 3).

    Bs (M, 3, K): TCP displacement per mrad of random tilt; logp = [log sigma^2,
    log tau_1^2, ...]. Bs None: isotropic sigma^2 only.
    """
    if Bs is None or not Bs.shape[-1]:
        return isotropic_loglik(r3, logp[0], np.exp(logp[0]))
    tau = np.exp(logp[1:]).repeat(Bs.shape[-1] // (len(logp) - 1))
    S = np.exp(logp[0]) * np.eye(3)[None].repeat(len(r3), 0) + np.einsum("mik,k,mjk->mij", Bs, tau, Bs)
    sign, logdet = np.linalg.slogdet(S)
    quad = np.einsum("mi,mi->m", r3, np.linalg.solve(S, r3[..., None])[..., 0])
    return -0.5 * (logdet + quad + 3 * np.log(2 * np.pi))


def isotropic_loglik(r3: np.ndarray, log_s2, s2) -> np.ndarray:
    """Per-row Gaussian log-likelihood (M,) of residuals r3 (M, 3) mm with covariance
    sigma^2 I: log_s2 = log sigma^2 and s2 = sigma^2 mm^2, scalars or per row (M,)
    (log det S = 3 log sigma^2)."""
    return -0.5 * (3 * log_s2 + np.einsum("mi,mi->m", r3, r3) / s2 + 3 * np.log(2 * np.pi))


def _bmm(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Batched small matrix product a @ b by broadcasting (CPU matmul loops over tiny batches)."""
    return (a.unsqueeze(-1) * b.unsqueeze(-3)).sum(-2)


def _mv(a: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Batched small matrix-vector product a @ v, a (..., i, j), v (..., j)."""
    return (a * v.unsqueeze(-2)).sum(-1)


def _inv3(S: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Inverse (..., 3, 3) and determinant (...) of symmetric 3 x 3 matrices, closed form."""
    a, b, c = S[..., 0, 0], S[..., 0, 1], S[..., 0, 2]
    d, e, f = S[..., 1, 1], S[..., 1, 2], S[..., 2, 2]
    A, B, C = d * f - e * e, c * e - b * f, b * e - c * d
    det = a * A + b * B + c * C
    adj = torch.stack([A, B, C, B, a * f - c * c, b * c - a * e, C, b * c - a * e, a * d - b * b], -1)
    return (adj / det.unsqueeze(-1)).reshape(S.shape), det


def _variance_start(r3: torch.Tensor, Bs: torch.Tensor | None, w: torch.Tensor, K: int):
    """Start and bounds (G, 1 + K) of the log variances: log sigma^2 at the log mean
    square, within [-9, +5] of it; each log tau^2 where its rows' mean |B|_F^2 tau^2
    equals that mean square, within [-30, +10] of it."""
    n = w.sum(-1).clamp_min(1.0)
    ls2 = torch.log((((r3 ** 2).mean(-1) * w).sum(-1) / n).clamp_min(1e-300))  # (G,)
    if not K:
        return ls2[:, None], None, None
    bb = ((Bs ** 2).sum((-2, -1)) * w).sum(-1) / n  # (G,)
    lt = ls2 - 2 * torch.log(bb.sqrt().clamp_min(1e-12))
    x0 = torch.cat([ls2[:, None], lt[:, None].expand(-1, K)], -1)
    lo = torch.cat([(ls2 - 9)[:, None], (lt - 30)[:, None].expand(-1, K)], -1)
    hi = torch.cat([(ls2 + 5)[:, None], (lt + 10)[:, None].expand(-1, K)], -1)
    return x0, lo, hi


def fit_variances(r3: torch.Tensor, Bs: torch.Tensor | None, w: torch.Tensor | None = None,
                  iters: int = 100, tol: float = 1e-10) -> torch.Tensor:
    """Maximum-likelihood log variances (G, 1 + K) of G sets of residual rows at once.

    r3 (G, M, 3) mm; Bs (M, 3, 2K) or (G, M, 3, 2K), mm per mrad (None or no columns:
    isotropic only); w (G, M) row weights (1: the row counts, 0: it does not; default
    all 1). Row m has covariance ``S_m = exp(x_0) I + sum_j exp(x_j) B_j B_j^T``, B_j its
    j-th pair of columns. Isotropic: the closed form (log mean square). Else a projected
    Newton method on x within the bounds of `_variance_start`, with the analytic gradient
    and Hessian of ``0.5 sum_m w_m (log det S_m + r_m^T S_m^-1 r_m)`` (the expected,
    Fisher, Hessian where the exact one is not positive definite), a backtracking line
    search, and, for a tau^2 whose maximum is at zero, steps that double along its descent
    while they gain; batched over G, with the 3 x 3 algebra in closed form. A batch stops
    when its Newton decrement is below `tol` nats or no step along the Newton direction
    decreases its negative log-likelihood.
    """
    G, M, _ = r3.shape
    w = torch.ones(G, M, dtype=r3.dtype) if w is None else w.to(r3.dtype)
    K = 0 if Bs is None else Bs.shape[-1] // 2
    Bs_shared = Bs  # (M, 3, 2K) shared by the G sets: its per-row algebra once, not G times
    if K:
        Bs = Bs.expand(G, *Bs.shape[-3:]) if Bs.dim() == 3 else Bs
    x, lo, hi = _variance_start(r3, Bs, w, K)
    if not K:
        return x
    nll, parts = _one_term(r3, Bs_shared, w) if K == 1 else _terms(r3, Bs_shared, w, K)
    f, W = nll(x)
    done = torch.zeros(G, dtype=torch.bool)
    for _ in range(iters):
        v = x.exp()
        gv, Qs, Ts = parts(W)
        vv = v[:, :, None] * v[:, None, :]
        g = v * gv  # gradient in x
        Hv = 0.5 * (2 * Qs - Ts)
        H = vv * Hv + torch.diag_embed(g)
        F = vv * 0.5 * Ts
        free = ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))  # bounds that hold stay fixed
        keep = free.to(r3.dtype)
        mask, fixed = keep[:, :, None] * keep[:, None, :], torch.diag_embed(1 - keep)
        g = g * keep
        H, F = H * mask + fixed, F * mask + fixed
        bad = torch.linalg.cholesky_ex(H)[1] > 0
        H = torch.where(bad[:, None, None], F, H)
        dx = -torch.linalg.solve(H, g)
        dec = -(g * dx).sum(-1)  # Newton decrement, nats
        done = done | (dec < tol)
        if bool(done.all()):
            break
        t, searched, x_start = 1.0, done.clone(), x
        for k in range(50):
            xt = torch.minimum(torch.maximum(x + t * dx, lo), hi)
            ft, Wt = nll(xt)
            ok = ~searched & (ft <= f + 1e-4 * (g * (xt - x)).sum(-1))
            x, f = torch.where(ok[:, None], xt, x), torch.where(ok, ft, f)
            W = torch.where(ok.view(-1, *[1] * (W.dim() - 1)), Wt, W)
            searched = searched | ok
            if k == 0:
                full = ok  # the full step was taken
            if bool(searched.all()):
                break
            t /= 2
        done = done | ~searched  # no decrease along the Newton direction: optimal to rounding
        # a tau^2 heading for zero (its maximum at the lower bound) takes Newton steps of
        # about -1 in log tau^2 only: after a full step, go on down while it gains
        down = torch.where(dx < -0.5, dx, 0.0)
        down[:, 0] = 0.0
        grow = full & (down < 0).any(-1)
        t = 1.0
        while bool(grow.any()) and t <= 64:
            xt = torch.minimum(torch.maximum(x_start + dx + t * down, lo), hi)
            ft, Wt = nll(xt)
            grow = grow & (ft < f)
            x, f = torch.where(grow[:, None], xt, x), torch.where(grow, ft, f)
            W = torch.where(grow.view(-1, *[1] * (W.dim() - 1)), Wt, W)
            t *= 2
    return x


def _terms(r3: torch.Tensor, Bs: torch.Tensor, w: torch.Tensor, K: int):
    """(nll, parts) of `fit_variances` for K random terms, by the 3 x 3 algebra per row:
    nll(x) -> (negative log-likelihood (G,), W = S^-1 (G, M, 3, 3)); parts(W) -> (the
    gradient in the variances v = exp(x) (G, A), and over the rows, weighted, Q_ab =
    u^T D_a W D_b u and T_ab = tr(W D_a W D_b) (G, A, A)), u = W r, D_0 = I, D_j = B_j B_j^T;
    Bs (G, M, 3, 2K), or (M, 3, 2K): one basis for the G sets."""
    lead = Bs.shape[:-2]  # (G, M), or (M,) for a basis the G sets share (D once, broadcast)
    Bj = Bs.reshape(*lead, 3, K, 2).movedim(-2, -3)  # (..., M, K, 3, 2)
    D = torch.cat([torch.eye(3, dtype=r3.dtype).expand(*lead, 1, 3, 3), _bmm(Bj, Bj.transpose(-1, -2))], -3)

    def nll(x):
        W, det = _inv3((D * x.exp()[:, None, :, None, None]).sum(2))  # (G, M, 3, 3), (G, M)
        quad = (r3 * _mv(W, r3)).sum(-1)
        val = 0.5 * (w * (torch.log(det.clamp_min(1e-300)) + quad)).sum(-1)
        return torch.where((det <= 0).any(-1), torch.inf, val), W

    def parts(W):
        u = _mv(W, r3)  # S^-1 r (G, M, 3)
        WD = _bmm(W.unsqueeze(2), D)  # (G, M, A, 3, 3)
        Du = _mv(D, u.unsqueeze(2))  # (G, M, A, 3)
        T = (WD.unsqueeze(3) * WD.transpose(-1, -2).unsqueeze(2)).sum((-2, -1))  # tr(W D_a W D_b)
        Q = (Du.unsqueeze(3) * _mv(W.unsqueeze(2), Du).unsqueeze(2)).sum(-1)  # u^T D_a W D_b u
        gv = 0.5 * (w[..., None] * (torch.diagonal(WD, dim1=-2, dim2=-1).sum(-1) - (Du * u[:, :, None]).sum(-1))).sum(1)
        return gv, (w[..., None, None] * Q).sum(1), (w[..., None, None] * T).sum(1)

    return nll, parts


def _one_term(r3: torch.Tensor, Bs: torch.Tensor, w: torch.Tensor):
    """`_terms` for one random term (K = 1), in each row's eigenbasis of B B^T: with
    B B^T = U diag(lam) U^T and c = U^T r, S = U diag(e) U^T, e_i = v_0 + v_1 lam_i, so
    log det S = sum log e_i, r^T S^-1 r = sum c_i^2 / e_i, and with d_0 = 1, d_1 = lam:
    tr(W D_a) = sum d_a / e, u^T D_a u = sum d_a c^2 / e^2, T_ab = sum d_a d_b / e^2,
    Q_ab = sum d_a d_b c^2 / e^3 (the same function and derivatives, per row 3 scalars
    instead of 3 x 3 matrices). The state passed from nll to parts is e (G, M, 3)."""
    G, M, _ = r3.shape
    BBt = Bs @ Bs.transpose(-1, -2)  # (G, M, 3, 3) or (M, 3, 3)
    lam, U = torch.linalg.eigh(BBt)
    lam = lam.clamp_min(0.0).expand(G, M, 3)
    c2 = (U.transpose(-1, -2) @ r3.unsqueeze(-1)).squeeze(-1) ** 2  # (G, M, 3)
    lam2 = lam * lam

    def nll(x):
        v = x.exp()
        e = v[:, None, 0:1] + v[:, None, 1:2] * lam  # (G, M, 3)
        det = e.prod(-1)
        val = 0.5 * (w * (torch.log(det.clamp_min(1e-300)) + (c2 / e).sum(-1))).sum(-1)
        return torch.where((det <= 0).any(-1), torch.inf, val), e

    def parts(e):
        ie = 1.0 / e
        ie2 = ie * ie
        g0 = ie - c2 * ie2
        q0 = c2 * ie2 * ie
        # per row: [sum g0, sum lam g0, sum ie2, sum lam ie2, sum lam^2 ie2, the same of q0]
        per = torch.stack([g0.sum(-1), (lam * g0).sum(-1), ie2.sum(-1), (lam * ie2).sum(-1), (lam2 * ie2).sum(-1),
                           q0.sum(-1), (lam * q0).sum(-1), (lam2 * q0).sum(-1)], -1)  # (G, M, 8)
        s = (w.unsqueeze(-1) * per).sum(1)  # (G, 8)
        T = torch.stack([torch.stack([s[:, 2], s[:, 3]], -1), torch.stack([s[:, 3], s[:, 4]], -1)], -2)
        Q = torch.stack([torch.stack([s[:, 5], s[:, 6]], -1), torch.stack([s[:, 6], s[:, 7]], -1)], -2)
        return 0.5 * s[:, :2], Q, T

    return nll, parts


def fit_variance(r3: np.ndarray, Bs: np.ndarray | None) -> np.ndarray:
    """Maximum-likelihood log variances (1 + K,) for residual rows r3 (M, 3), Bs (M, 3, 2K)
    (see `fit_variances`)."""
    Bt = None if Bs is None or not Bs.shape[-1] else torch.from_numpy(Bs)
    return fit_variances(torch.from_numpy(r3)[None], Bt)[0].numpy(force=True)

