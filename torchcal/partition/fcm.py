"""Fuzzy c-means in torch (docs/paper.md section 4, eqs. 26-28): `fcm` fits, `memberships`
applies eq. 28 to new points, `objective` is eq. 26. The validity indices and the choice of
c are `torchcal.partition.validity`.

The maths. Points x_j (N of them, d features), c centers v_i, memberships u_ij with
sum_i u_ij = 1, fuzzifier m > 1:

    J(U, V) = sum_i sum_j u_ij^m ||x_j - v_i||^2                                    (26)
    v_i     = sum_j u_ij^m x_j / sum_j u_ij^m                                        (27)
    u_ij    = 1 / sum_k (d_ij / d_kj)^(2/(m-1))                                      (28)

Eq. 28 is evaluated as u_ij = w_ij / S_j with w_ij = (d_ij^2)^(-1/(m-1)) and
S_j = sum_k w_kj: the same value with no (c, c, N) ratio tensor, and then eq. 26 for the
pair comes for free as J = sum_j S_j^(1-m) (because u_ij^m d_ij^2 = w_ij / S_j^m).
Where that is not exact (a point on a center, d_ij = 0, gives w = inf; or w under- or
overflows) the chunk is recomputed the careful way: w_ij = (dmin_j^2 / d_ij^2)^(1/(m-1))
with dmin_j the distance to the nearest center, so every w is in [0, 1] and S in [1, c];
a point that lies exactly on one or more centers gets membership 1 split equally among
them and 0 elsewhere (the limit of eq. 28), and J is summed directly. Distances are
direct differences (no |x|^2 - 2 x.v + |v|^2 cancellation), so d = 0 is exact.

Layout: memberships are ``(c, N)`` (cluster first, as u_ij in the paper and as
scikit-fuzzy), centers ``(c, d)``. One iteration is: memberships from the current centers
(eq. 28), then new centers from those memberships (eq. 27). It stops when the Frobenius
norm ||U(t+1) - U(t)|| < eps (the paper's and scikit-fuzzy's rule) or after max_iter
iterations. The returned centers are the ones the returned memberships were computed from
(as scikit-fuzzy returns them), and the objective is eq. 26 for that pair.

Restarts run as one batched ``(restarts, c, N)`` computation; a restart that has
converged drops out of the batch, and the one with the lowest objective is kept (ties: the
lowest restart index). Points are streamed in chunks (about 2 MiB of memberships per chunk
on a CPU, so the ~10 element-wise passes of an iteration mostly run in cache and memory
sees one read and one write of U; very large chunks on a GPU); buffers are preallocated.
Randomness only through an explicit `torch.Generator` seeded with `seed`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch

from torchcal.errors import InputError

__all__ = ["FCMResult", "fcm", "memberships", "objective"]


class FCMResult(NamedTuple):
    """Result of `fcm`.

    Attributes:
        centers: (c, d) cluster centers v_i, in the units of x.
        memberships: (c, N) u_ij, each column sums to 1.
        objective: J(U, V) of eq. 26 for the returned pair (float).
        n_iter: iterations run by the kept restart (int).
    """

    centers: torch.Tensor
    memberships: torch.Tensor
    objective: float
    n_iter: int


# --------------------------------------------------------------------------- inputs

def as_points(x, name: str = "x") -> torch.Tensor:
    """Convert `x` (N,) or (N, d) (tensor, array, list) to a (N, d) floating tensor.

    Floating tensors keep their dtype and device; anything else becomes float64 on the CPU.
    Raises InputError for a wrong shape, no points, or a NaN/inf (naming the first row).
    """
    if not isinstance(x, torch.Tensor):
        try:
            x = torch.as_tensor(np.asarray(x, dtype=np.float64))
        except (TypeError, ValueError) as exc:
            raise InputError(f"{name}: expected numbers of shape (N,) or (N, d), got {type(x).__name__} ({exc})") from None
    if not x.is_floating_point():
        x = x.to(torch.float64)
    if x.ndim == 1:
        x = x[:, None]  # (N,) -> (N, 1)
    if x.ndim != 2:
        raise InputError(f"{name}: expected shape (N,) or (N, d), got {tuple(x.shape)}")
    if x.shape[0] == 0 or x.shape[1] == 0:
        raise InputError(f"{name}: expected at least one point with at least one feature, got shape {tuple(x.shape)}")
    lo, hi = torch.aminmax(x)  # one pass; NaN propagates and fails both tests
    if not bool((lo > -math.inf) & (hi < math.inf)):
        row = int(torch.nonzero(~torch.isfinite(x).all(dim=1))[0, 0])
        raise InputError(f"{name}: contains NaN or inf (first at row {row}: {x[row].tolist()}); expected finite numbers")
    return x


def _check_fcm_args(n_points: int, c, m, eps, max_iter, restarts) -> None:
    if isinstance(c, bool) or not isinstance(c, (int, np.integer)):
        raise InputError(f"c: expected an integer number of clusters, got {c!r}")
    if c < 2:
        raise InputError(f"c: expected at least 2 clusters, got {c}")
    if c >= n_points:
        raise InputError(f"c: {c} clusters need more points than clusters (c < N); x has {n_points} points")
    if not isinstance(m, (int, float, np.floating, np.integer)) or not math.isfinite(m) or m <= 1:
        raise InputError(f"m: expected a fuzzifier m > 1, got {m!r}")
    if not isinstance(eps, (int, float, np.floating, np.integer)) or not eps >= 0:
        raise InputError(f"eps: expected a tolerance >= 0, got {eps!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise InputError(f"max_iter: expected an integer >= 1, got {max_iter!r}")
    if isinstance(restarts, bool) or not isinstance(restarts, (int, np.integer)) or restarts < 1:
        raise InputError(f"restarts: expected an integer >= 1, got {restarts!r}")


def _check_not_identical(x: torch.Tensor) -> None:
    lo, hi = torch.aminmax(x, dim=0)  # (d,), (d,)
    if torch.equal(lo, hi):
        raise InputError(
            f"x: all {x.shape[0]} points are identical ({x[0].tolist()}); "
            "no partition into clusters is possible, expected at least 2 distinct points")


def _default_chunk(x: torch.Tensor, rc: int) -> int:
    """Points per chunk: ~2 MiB per (restarts, c, chunk) float64 buffer on a CPU (measured
    best for 1-2 threads; 1-4 MiB are within 10%), very large on a GPU."""
    if x.device.type == "cpu":
        return max(4096, (1 << 18) // rc)
    return max(1 << 16, (1 << 26) // rc)


# --------------------------------------------------------------------------- kernels

def _sq_dist(xt: torch.Tensor, V: torch.Tensor, s: int, e: int) -> torch.Tensor:
    """Squared distances of points s:e to the centers.

    xt (d or d+1, N) points transposed (extra rows ignored); V (R, c, d) -> (R, c, e - s).
    Direct differences (no |x|^2 - 2x.v + |v|^2 cancellation), so d = 0 is exact.
    """
    n = e - s
    out = torch.empty(V.shape[0], V.shape[1], n, dtype=V.dtype, device=V.device)
    return _sq_dist_into(xt, V, s, e, out, torch.empty_like(out))


def _sq_dist_into(xt, V, s, e, out, tmp):
    """out (R, c, n) = squared distances of points s:e (xt (d(+1), N)) to centers V (R, c, d)."""
    d = V.shape[-1]
    torch.sub(xt[0, s:e], V[..., 0, None], out=tmp)  # (R, c, n)
    torch.mul(tmp, tmp, out=out)
    for k in range(1, d):
        torch.sub(xt[k, s:e], V[..., k, None], out=tmp)
        out.addcmul_(tmp, tmp)
    return out


def _u_from_sq_dist_(d2: torch.Tensor, m: float) -> torch.Tensor:
    """Eq. 28 in place, the careful way: squared distances (..., c, n) -> memberships.

    w = (dmin^2 / d^2)^(1/(m-1)) lies in [0, 1] and sum_k w in [1, c], so nothing under- or
    overflows; u = w / sum_k w. A zero distance gives 0/0 = NaN in w, which marks the
    centers a point lies on: those share membership 1 equally (the limit of eq. 28).
    """
    dmin = d2.amin(dim=-2, keepdim=True)  # (..., 1, n)
    w = torch.div(dmin, d2, out=d2)  # (..., c, n), NaN where d2 == dmin == 0
    if m != 2.0:
        w.pow_(1.0 / (m - 1.0))
    S = w.sum(dim=-2, keepdim=True)  # (..., 1, n), in [1, c] or NaN
    bad = torch.isnan(S)
    if bool(bad.any()):
        on = torch.isnan(w).to(w.dtype)  # (..., c, n), 1 on the centers the point lies on
        on = on / on.sum(dim=-2, keepdim=True).clamp_min(1.0)
        w.div_(S)
        return torch.where(bad, on, w, out=w)
    return w.div_(S)


def _pass(xt, V, blocks, m, bounds, buf):
    """One FCM iteration over all points, streamed in chunks.

    xt (d, N) points transposed; V (R, c, d) centers; blocks: views (R, c, n_b) of the
    memberships, one per (s, e) in `bounds`, replaced in place by the eq. 28 memberships
    for V; buf: scratch of 2 * R * c * max(n_b) elements.
    Returns diff2 (R,) = ||U_new - U_old||_F^2, J (R,) = J(U_new, V) of eq. 26, and
    acc (d+1, R*c) = [sum_j u^m x_j ; sum_j u^m] for the next centers (eq. 27).

    Fast path: w = (d^2)^(-1/(m-1)), S = sum_k w, u = w / S, and eq. 26 for this pair is
    sum_j S_j^(1-m) (since u^m d^2 = w / S^m). A chunk where some S is 0 or inf (a point on
    a center gives w = inf; or w under/overflows) is done by `_u_from_sq_dist_` instead.
    """
    R, c, d = V.shape
    Rc = R * c
    nmax = buf.numel() // (2 * Rc)
    acc = torch.zeros(d + 1, Rc, dtype=V.dtype, device=V.device)
    diff2 = torch.zeros(R, dtype=V.dtype, device=V.device)
    J = torch.zeros(R, dtype=V.dtype, device=V.device)
    for (s, e), blk in zip(bounds, blocks):
        n = e - s
        w = buf[:Rc * n].view(R, c, n)  # scratch
        t = buf[Rc * nmax:Rc * (nmax + n)].view(R, c, n)  # scratch
        if d == 1 and m == 2.0:
            torch.sub(xt[0, s:e], V[..., 0, None], out=t)
            torch.pow(t, -2, out=w)  # w = 1 / d^2 in one pass
        else:
            _sq_dist_into(xt, V, s, e, w, t)  # d^2
            if m == 2.0:
                w.reciprocal_()
            else:
                w.pow_(-1.0 / (m - 1.0))
        inv = w.sum(dim=1, keepdim=True).reciprocal_()  # (R, 1, n) 1 / S
        lo, hi = torch.aminmax(inv)
        if bool((lo > 0) & (hi < math.inf)):  # every S finite and > 0
            Jc = (inv if m == 2.0 else inv.pow(m - 1.0)).sum(dim=(1, 2))  # (R,) sum_j S_j^(1-m)
            torch.addcmul(blk, w, inv, value=-1.0, out=t)  # U_old - U_new
            dc = _row_dots(t.view(R, c * n))  # (R,)
            torch.mul(w, inv, out=blk)  # U_new, eq. 28
        else:  # careful path for this chunk
            _sq_dist_into(xt, V, s, e, w, t)
            d2 = w.clone()
            u = _u_from_sq_dist_(w, m)
            Jc = (u.pow(m) * d2).sum(dim=(1, 2))
            dc = _row_dots(torch.sub(blk, u, out=t).view(R, c * n))
            blk.copy_(u)
        diff2 += dc
        J += Jc
        um = torch.mul(blk, blk, out=w) if m == 2.0 else torch.pow(blk, m, out=w)
        _accumulate(acc, um.view(Rc, n), xt, s, e)
    return diff2, J, acc


def _accumulate(acc, um, xt, s, e):
    """acc (d+1, Rc) += [um @ x_k for each feature k; row sums of um]; um (Rc, n)."""
    d = xt.shape[0]
    for k in range(d):
        acc[k].addmv_(um, xt[k, s:e])
    acc[d] += um.sum(dim=1)


def _row_dots(t: torch.Tensor) -> torch.Tensor:
    """(R, k) -> (R,) squared norms of the rows, without a temporary."""
    return torch.stack([torch.dot(row, row) for row in t])


def _iterate(xt, U, m, eps, max_iter, chunk):
    """Run FCM from memberships U (R, c, N) (a fresh tensor, overwritten; its columns must
    sum to 1). Returns (J, U (c, N), V (c, d), n_iter) of the restart with the lowest
    objective (first of ties), V being the centers its U was computed from.
    """
    R, c, N = U.shape
    bounds = [(s, min(s + chunk, N)) for s in range(0, N, chunk)]
    nmax = bounds[0][1] - bounds[0][0]
    buf = torch.empty(2 * R * c * nmax, dtype=xt.dtype, device=xt.device)
    V = _centers(xt, U, bounds, m)  # (R, c, d)
    d = V.shape[-1]
    ids = list(range(R))  # restart id of each row of U
    best = None
    for it in range(1, max_iter + 1):
        Ra = len(ids)
        blocks = [U[..., s:e] for s, e in bounds]  # views (Ra, c, n_b)
        diff2, J, acc = _pass(xt, V, blocks, m, bounds, buf)
        done = ((diff2.sqrt() < eps) | (it == max_iter)).tolist()
        Jl = J.tolist()
        for j in range(Ra):
            if done[j] and (best is None or (Jl[j], ids[j]) < best[:2]):
                best = (Jl[j], ids[j], V[j].clone(), it)
                best_U = U[j] if Ra == 1 else U[j].clone()
        keep = [j for j in range(Ra) if not done[j]]
        if not keep:
            break
        V = (acc[:d] / acc[d:]).T.reshape(Ra, c, d)  # eq. 27
        if len(keep) < Ra:
            kt = torch.tensor(keep, device=xt.device)
            U, V = U.index_select(0, kt), V.index_select(0, kt)
            ids = [ids[j] for j in keep]
    return best[0], best_U, best[2], best[3]


def _normalised(U: torch.Tensor) -> torch.Tensor:
    """Memberships U (R, c, N) -> a new tensor with each column divided by its sum."""
    col = U.sum(dim=1, keepdim=True)  # (R, 1, N)
    if not bool(col.amin() > 0):
        raise InputError("init_u: some point has all memberships 0; expected each column to sum > 0")
    return U / col


def _centers(xt: torch.Tensor, U: torch.Tensor, bounds, m: float) -> torch.Tensor:
    """Eq. 27: xt (d, N), memberships U (R, c, N) -> centers (R, c, d)."""
    d = xt.shape[0]
    R, c, _ = U.shape
    acc = torch.zeros(d + 1, R * c, dtype=xt.dtype, device=xt.device)
    for s, e in bounds:
        um = U[..., s:e].pow(m).view(R * c, e - s)
        _accumulate(acc, um, xt, s, e)
    return (acc[:d] / acc[d:]).T.reshape(R, c, d)


def _objective(xt, U, V, m, chunk) -> torch.Tensor:
    """Eq. 26 per restart: xt (d(+1), N), U (R, c, N), V (R, c, d) -> (R,)."""
    J = torch.zeros(U.shape[0], dtype=U.dtype, device=U.device)
    for s in range(0, xt.shape[1], chunk):
        e = min(s + chunk, xt.shape[1])
        J += (U[:, :, s:e].pow(m) * _sq_dist(xt, V, s, e)).sum(dim=(1, 2))
    return J


# --------------------------------------------------------------------------- public

def fcm(x, c: int, m: float = 2.0, eps: float = 1e-6, max_iter: int = 300, seed: int = 0,
        restarts: int = 1, init_u=None, chunk_size: int | None = None) -> FCMResult:
    """Fuzzy c-means (eqs. 26-28) on any device, restarts batched.

    Args:
        x: (N,) or (N, d) points (tensor, array or list). A floating tensor keeps its dtype
            and device; other input becomes float64 on the CPU.
        c: number of clusters, 2 <= c < N.
        m: fuzzifier, m > 1 (default 2.0).
        eps: stop when the Frobenius norm ||U(t+1) - U(t)|| < eps (default 1e-6); 0 runs
            exactly max_iter iterations.
        max_iter: most iterations per restart (default 300).
        seed: seed of the `torch.Generator` (on x's device) that draws the random initial
            memberships (uniform, columns normalised). Unused when init_u is given.
        restarts: independent random starts, run as one batched computation; the one with
            the lowest objective is returned (default 1).
        init_u: optional initial memberships (c, N) or (restarts, c, N), non-negative; each
            column is normalised to sum 1 (as scikit-fuzzy does).
        chunk_size: points per streamed chunk (default: about 2 MiB of memberships per
            chunk on a CPU, 64 Mi memberships on a GPU). Results do not depend on it beyond
            rounding.

    Returns:
        FCMResult(centers (c, d), memberships (c, N), objective float, n_iter int).

    Raises:
        InputError: c < 2, c >= N, m <= 1, NaN/inf in x, all points identical, bad init_u.

    Example:
        >>> res = fcm(torch.tensor([0.0, 0.1, 0.2, 5.0, 5.1, 5.2]), 2, restarts=4)
        >>> res.memberships.shape, res.centers.shape
        (torch.Size([2, 6]), torch.Size([2, 1]))
    """
    x = as_points(x)
    N, d = x.shape
    _check_fcm_args(N, c, m, eps, max_iter, restarts)
    m = float(m)
    _check_not_identical(x)
    dtype, device = x.dtype, x.device

    if init_u is not None:
        U = _check_init_u(init_u, c, N, restarts, dtype, device)
    else:
        g = torch.Generator(device=device).manual_seed(int(seed))
        U = torch.rand((restarts, c, N), generator=g, dtype=dtype, device=device)
    R = U.shape[0]
    chunk = int(chunk_size) if chunk_size else _default_chunk(x, R * c)
    if chunk < 1:
        raise InputError(f"chunk_size: expected a positive integer, got {chunk_size!r}")

    xt = x.T.contiguous()  # (d, N)
    J, U_best, V_best, n_iter = _iterate(xt, _normalised(U), m, float(eps), int(max_iter), chunk)
    return FCMResult(V_best, U_best, J, n_iter)


def _check_init_u(init_u, c, N, restarts, dtype, device) -> torch.Tensor:
    if isinstance(init_u, torch.Tensor):
        if init_u.device != device:
            raise InputError(f"init_u: on device {init_u.device}, but x is on {device}; expected the same device")
        U = init_u.to(dtype)
    else:
        U = torch.as_tensor(np.asarray(init_u, dtype=np.float64), dtype=dtype, device=device)
    if U.ndim == 2:
        U = U[None]  # (c, N) -> (1, c, N)
    if U.ndim != 3 or U.shape[1:] != (c, N):
        raise InputError(f"init_u: expected shape ({c}, {N}) or (restarts, {c}, {N}), got {tuple(U.shape)}")
    if restarts != 1 and U.shape[0] != restarts:
        raise InputError(f"init_u: holds {U.shape[0]} starts but restarts={restarts}; expected them equal")
    lo, hi = torch.aminmax(U)
    if not bool((lo >= 0) & (hi < math.inf)):
        raise InputError("init_u: expected finite, non-negative memberships")
    return U  # columns are normalised by _normalised


def memberships(x, centers, m: float = 2.0) -> torch.Tensor:
    """Eq. 28 for given centers: x (N,) or (N, d), centers (c, d) -> (c, N).

    A point on a center gets membership 1 there (split equally among coinciding centers).
    """
    x = as_points(x)
    centers = _as_centers(centers, x)
    if not float(m) > 1:
        raise InputError(f"m: expected a fuzzifier m > 1, got {m!r}")
    xt = x.T.contiguous()  # (d, N)
    chunk = _default_chunk(x, centers.shape[0])
    out = [_u_from_sq_dist_(_sq_dist(xt, centers[None], s, min(s + chunk, x.shape[0])), float(m))[0]
           for s in range(0, x.shape[0], chunk)]
    return torch.cat(out, dim=1)


def _as_centers(centers, x: torch.Tensor) -> torch.Tensor:
    if not isinstance(centers, torch.Tensor):
        centers = torch.as_tensor(np.asarray(centers, dtype=np.float64))
    if centers.ndim == 1:
        centers = centers[:, None]  # (c,) -> (c, 1)
    if centers.ndim != 2 or centers.shape[1] != x.shape[1]:
        raise InputError(f"centers: expected shape (c, {x.shape[1]}) to match x (N, {x.shape[1]}), got {tuple(centers.shape)}")
    if centers.device != x.device:
        raise InputError(f"centers: on device {centers.device}, but x is on {x.device}; expected the same device")
    return centers.to(x.dtype)


def objective(x, centers, u, m: float = 2.0) -> float:
    """Eq. 26: J = sum_ij u_ij^m ||x_j - v_i||^2 for x (N, d), centers (c, d), u (c, N)."""
    x = as_points(x)
    centers = _as_centers(centers, x)
    xt = x.T.contiguous()
    return float(_objective(xt, torch.as_tensor(u, dtype=x.dtype, device=x.device)[None], centers[None],
                            float(m), _default_chunk(x, centers.shape[0]))[0])
