"""Validity of a fuzzy partition and the choice of the number of clusters.

Bezdek's partition coefficient and entropy (of the memberships alone) and the Xie-Beni
index (compactness over separation, of points, centers and memberships), and `choose_c`,
which runs `torchcal.partition.fcm.fcm` for each c of a range and keeps the lowest Xie-Beni
index. Memberships are ``(c, N)``, centers ``(c, d)``, points ``(N,)`` or ``(N, d)``.
"""

from __future__ import annotations

import torch

from torchcal.errors import InputError
from torchcal.partition.fcm import _as_centers, as_points, fcm, objective

__all__ = ["partition_coefficient", "partition_entropy", "xie_beni", "choose_c"]


def partition_coefficient(u) -> float:
    """Bezdek's partition coefficient PC = (1/N) sum_ij u_ij^2, in [1/c, 1]; higher is crisper."""
    u = torch.as_tensor(u)
    return float((u * u).sum() / u.shape[-1])


def partition_entropy(u) -> float:
    """Bezdek's partition entropy PE = -(1/N) sum_ij u_ij ln u_ij (0 ln 0 = 0), in [0, ln c];
    lower is crisper."""
    u = torch.as_tensor(u)
    return float(-torch.special.xlogy(u, u).sum() / u.shape[-1])


def xie_beni(x, centers, u, m: float = 2.0) -> float:
    """Xie-Beni index XB = J_m(U, V) / (N min_{i != k} ||v_i - v_k||^2); lower is better.

    J_m is eq. 26 with the same fuzzifier m (Xie & Beni's original uses m = 2). Coinciding
    centers give inf.
    """
    x = as_points(x)
    centers = _as_centers(centers, x)
    J = objective(x, centers, u, m)
    sep = torch.cdist(centers, centers).square_()  # (c, c)
    sep.fill_diagonal_(float("inf"))
    smin = float(sep.min())
    return float("inf") if smin == 0 else J / (x.shape[0] * smin)


def choose_c(x, c_range=(2, 6), m: float = 2.0, eps: float = 1e-6, max_iter: int = 300,
             seed: int = 0, restarts: int = 1, min_size: int = 0):
    """Pick the number of clusters in c_range (inclusive) with the lowest Xie-Beni index.

    The upper end is clipped to N - 1; ties go to the smaller c. A c whose hard labels
    (largest membership) leave a cluster with fewer than `min_size` points is not chosen
    (its score is still reported).
    Returns (c, result FCMResult for that c, scores {c: xie_beni}); (None, None, scores)
    when every c leaves such a cluster.
    """
    x = as_points(x)
    lo, hi = _check_range(c_range, "c_range")
    hi = min(hi, x.shape[0] - 1)
    if lo > hi:
        raise InputError(f"c_range: ({lo}, {c_range[1]}) leaves no c with 2 <= c < N for {x.shape[0]} points")
    best = None
    scores = {}
    for c in range(lo, hi + 1):
        res = fcm(x, c, m=m, eps=eps, max_iter=max_iter, seed=seed, restarts=restarts)
        scores[c] = xie_beni(x, res.centers, res.memberships, m)
        if min_size and int(torch.bincount(res.memberships.argmax(dim=0), minlength=c).min()) < min_size:
            continue
        if best is None or scores[c] < scores[best[0]]:
            best = (c, res)
    return (None, None, scores) if best is None else (best[0], best[1], scores)


def _check_range(c_range, name):
    try:
        lo, hi = (int(v) for v in c_range)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected (low, high) integers, got {c_range!r}") from None
    if lo < 2 or hi < lo:
        raise InputError(f"{name}: expected 2 <= low <= high, got {c_range!r}")
    return lo, hi
