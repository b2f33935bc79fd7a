"""Kernel ridge regression held out by pose: the machinery that the probe of what is left
(`torchcal.diagnosis.probe`) and the residual stage (`torchcal.calibration.residual_model`)
share.

RBF kernel ``k(x, x') = exp(-|x - x'|^2 / (2 l^2))`` on variable features (`variable_features`),
dual weights ``alpha = (K + lam I)^-1 Y`` (`fit_dual`), inputs and hyper-parameters chosen
by forward selection with pose-grouped block cross-validation (`choose`); all ridges of one
kernel from one eigendecomposition, held-out block residuals by the block leave-out
identity ``[(A^-1)_BB]^-1 (A^-1 R)_B`` (`block_cv`, `block_cv_eig`; the blocks of one size
in one batched solve); the kernel of one variable is low-rank and `kernel_factors` gives
its eigenpairs at every length scale without an N x N eigendecomposition, and a block of
more rows than the rank p is predicted from p x p systems (ridge regression on the
factor) instead (the method is described in full in `torchcal.diagnosis.probe`).
Shapes: rows first, float64; Y (N, k) targets (mm for residuals).
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from torchcal.folds import FOLDS

#: RBF length scales tried, in rad of joint angle (standard deviations for other variables).
LENGTH_SCALES = (0.1, 0.2, 0.4, 0.8, 1.6, 3.2)
#: ridge weights tried, relative to the kernel's diagonal (1): noise / signal variance.
RIDGES = (1e-3, 1e-2, 1e-1, 1.0, 10.0, 1e2, 1e4)
#: fewest poses the probe runs on (fewer: nothing is reported as learnable).
MIN_POSES = 10
#: hyper-parameters and inputs are chosen on at most about this many rows (whole poses).
MAX_ROWS = 400
#: an input is added while it lowers the cross-validated error by this share; at most MAX_INPUTS.
MIN_GAIN = 0.01
MAX_INPUTS = 4
#: the variables that did best alone, tried in later steps.
SHORTLIST = 5


def variable_features(values: dict, prismatic=()) -> dict:
    """name -> (N, d) float64 kernel inputs of each variable: (sin, cos) of a revolute joint
    angle ``qJ`` (rad), +-1 for ``approach_qJ``, value / std for the others (``temp_c``,
    ``payload_kg``, a prismatic joint); `values` as `unexplained.variables` gives them."""
    out = {}
    for k, v in values.items():
        v = np.asarray(v, dtype=np.float64)
        if k.startswith("approach_"):
            out[k] = v[:, None]
        elif k.startswith("q") and k[1:].isdigit() and int(k[1:]) - 1 not in set(prismatic):
            out[k] = np.stack([np.sin(v), np.cos(v)], -1)
        else:
            out[k] = ((v - v.mean()) / max(v.std(), 1e-300))[:, None]
    return out


def _sqdist(A: torch.Tensor, B: torch.Tensor) -> torch.Tensor:
    """(M, N) squared distances of rows A (M, d), B (N, d)."""
    return torch.cdist(A, B, compute_mode="donot_use_mm_for_euclid_dist").pow(2)


def _gauss(D: torch.Tensor, length_scale: float) -> torch.Tensor:
    """The RBF kernel exp(-D / (2 l^2)) of squared distances D (any shape)."""
    return torch.exp(-D / (2.0 * length_scale ** 2))


def rbf(A: torch.Tensor, B: torch.Tensor, length_scale: float) -> torch.Tensor:
    """(M, N) RBF kernel exp(-|a - b|^2 / (2 l^2)) of rows A (M, d), B (N, d)."""
    return _gauss(_sqdist(A, B), length_scale)


def block_cv(K: torch.Tensor, Y: torch.Tensor, blocks: list, ridges=RIDGES):
    """Exact block leave-out predictions of kernel ridge regression, all ridges at once.

    K (N, N) kernel, Y (N, k) targets, blocks: index tensors partitioning 0..N-1.
    Returns (pred (R, N, k): each block predicted from the other rows, alpha (R, N, k):
    the dual weights on all N rows), R = len(ridges)."""
    w, V = torch.linalg.eigh(K)
    return block_cv_eig(w, V, Y, blocks, ridges)


def block_cv_eig(w: torch.Tensor, V: torch.Tensor, Y: torch.Tensor, blocks: list, ridges=RIDGES):
    """`block_cv` of the kernel ``K = V diag(w) V^T``: V (N, p) orthonormal columns, w (p,);
    p < N: the other N - p eigenvalues are zero (a low-rank kernel, `kernel_factors`), so
    ``A^-1 = V diag(1 / (w + lam) - 1 / lam) V^T + I / lam``. Blocks of b > p rows are
    predicted by ridge regression on the features instead (`_held_out_primal`: p x p
    systems, the same predictions)."""
    lam = torch.as_tensor(ridges, dtype=V.dtype)
    w = w.clamp_min(0.0)
    thin = V.shape[1] < V.shape[0]
    d = -w / (lam[:, None] * (w + lam[:, None])) if thin else 1.0 / (w + lam[:, None])  # (R, p)
    alpha = (V[None] * d[:, None, :]) @ (V.T @ Y)  # (R, N, k) = A^-1 Y
    if thin:
        alpha = alpha + Y[None] / lam[:, None, None]
    pred = torch.empty_like(alpha)
    for idx in _same_size(blocks):  # (G, b): one batched solve for all blocks of b rows
        if thin and V.shape[1] < idx.shape[1]:
            pred[:, idx] = _held_out_primal(V * w.sqrt(), Y, idx, lam)
            continue
        VB = V[idx]  # (G, b, p)
        QBB = (VB[None] * d[:, None, None, :]) @ VB.transpose(-1, -2)  # (R, G, b, b) = (A^-1)_BB
        if thin:
            QBB.diagonal(dim1=-2, dim2=-1).add_((1.0 / lam)[:, None, None])
        pred[:, idx] = Y[idx][None] - torch.linalg.solve(QBB, alpha[:, idx])
    return pred, alpha


def _held_out_primal(Phi: torch.Tensor, Y: torch.Tensor, idx: torch.Tensor, lam: torch.Tensor) -> torch.Tensor:
    """(R, G, b, k) predictions of the blocks idx (G, b) of the N rows, each from the other
    rows T, by ridge regression on features Phi (N, p) (the kernel ``Phi Phi^T``):
    ``Phi_B (Phi_T^T Phi_T + lam I)^-1 Phi_T^T Y_T``, one batched (R, G, p, p) solve; Y (N, k),
    lam (R,)."""
    G, N = len(idx), Phi.shape[0]
    other = torch.ones(G, N, dtype=torch.bool)
    other[torch.arange(G)[:, None], idx] = False
    T = torch.arange(N).expand(G, N)[other].reshape(G, -1)  # (G, N - b) the other rows
    gram = Phi[T].transpose(-1, -2) @ Phi[T]  # (G, p, p)
    h = Phi[T].transpose(-1, -2) @ Y[T]  # (G, p, k)
    A = gram[None] + lam[:, None, None, None] * torch.eye(Phi.shape[1], dtype=Phi.dtype)  # (R, G, p, p)
    return Phi[idx][None] @ torch.linalg.solve(A, h[None].expand(len(lam), -1, -1, -1))


def _same_size(blocks: list) -> list:
    """The blocks (index tensors) stacked by size: [(G, b) long tensor], one per size b."""
    sizes = sorted({len(B) for B in blocks})
    return [torch.stack([B for B in blocks if len(B) == b]) for b in sizes]


#: a kernel factor keeps the terms down to this share of the kernel's diagonal.
FACTOR_TOL = 1e-12
#: a variable with at most this many distinct values gets the exact factor on its values.
FACTOR_VALUES = 64


def kernel_factors(x: torch.Tensor, length_scales, angle: bool) -> list:
    """[(w (p,), V (N, p)) or None for each length scale]: the nonzero eigenpairs of the RBF
    kernel of one variable's inputs x (N, d), found without an N x N eigendecomposition, or
    None (no such way).

    - at most FACTOR_VALUES distinct rows u: ``K = E C E^T`` with E (N, u) the rows'
      indicators and C (u, u) the kernel of the distinct rows (exact);
    - an angle (angle=True, x = (sin q, cos q)): ``k = exp((cos(q - q') - 1) / l^2) =
      sum_n c_n cos(n (q - q'))`` with ``c_0 = I_0(1/l^2) e^(-1/l^2)``, ``c_n = 2 I_n(1/l^2)
      e^(-1/l^2)`` (the von Mises series), features ``sqrt(c_n) (cos n q, sin n q)``,
      truncated where c_n < FACTOR_TOL c_0 (the dropped terms sum to about that share of
      the diagonal, 1).
    The eigenpairs come from a thin SVD of the (N, p) factor, p << N. The distinct rows
    (and the angles) do not depend on the length scale: they are found once."""
    uniq, inv = torch.unique(x, dim=0, return_inverse=True)
    if len(uniq) <= FACTOR_VALUES:
        D = _sqdist(uniq, uniq)  # (u, u)
        factors = []
        for ell in length_scales:
            c, U = torch.linalg.eigh(_gauss(D, ell))
            factors.append(U[inv] * c.clamp_min(0.0).sqrt())
    elif angle:
        q = torch.atan2(x[:, 0], x[:, 1])[:, None]  # (N, 1) rad
        factors = [_von_mises_features(q, ell) for ell in length_scales]
    else:
        return [None] * len(length_scales)
    return [None if F is None else _eigenpairs(F) for F in factors]


def _von_mises_features(q: torch.Tensor, length_scale: float):
    """(N, p) features ``sqrt(c_n) (1, cos n q, sin n q)`` of the angle kernel (`kernel_factors`)
    of angles q (N, 1) rad, or None when p would not be below N."""
    import scipy.special

    kappa = 1.0 / length_scale ** 2
    n = np.arange(0, 4 * int(np.sqrt(kappa) * 8 + 8))
    c = scipy.special.ive(n, kappa) * np.where(n > 0, 2.0, 1.0)
    n = n[c >= FACTOR_TOL * c[0]]
    if 2 * len(n) - 1 >= q.shape[0]:
        return None
    nq = q * torch.from_numpy(n[1:].astype(np.float64))  # (N, len(n) - 1)
    sq = torch.from_numpy(np.sqrt(c[n]))
    return torch.cat([sq[:1].expand(len(q), 1), torch.cos(nq) * sq[1:], torch.sin(nq) * sq[1:]], -1)


def _eigenpairs(F: torch.Tensor):
    """(w (p,), V (N, p)): the nonzero eigenpairs of ``F F^T`` of a factor F (N, p), thin SVD."""
    U, S, _ = torch.linalg.svd(F, full_matrices=False)
    keep = S > S.amax() * 1e-10 if len(S) else S > 0
    return S[keep] ** 2, U[:, keep]


def stack_inputs(feats: dict, names) -> torch.Tensor:
    return torch.from_numpy(np.hstack([feats[k] for k in names]))


def subsample(fold: np.ndarray, rows: np.ndarray, pose: np.ndarray, seed: int) -> np.ndarray:
    """Bool (N,): the rows of `rows` if there are at most MAX_ROWS, else whole poses drawn
    at random (`seed`) up to about MAX_ROWS rows: what hyper-parameters are chosen on."""
    if rows.sum() <= MAX_ROWS:
        return rows
    ids = np.unique(pose[rows])
    keep = np.random.default_rng(seed).permutation(ids)[: max(int(len(ids) * MAX_ROWS / rows.sum()), FOLDS)]
    return rows & np.isin(pose, keep)


def choose(feats: dict, candidates: list, Y: torch.Tensor, fold: np.ndarray, rows: np.ndarray):
    """Forward selection of the inputs and the (length scale, ridge) by block CV of the rows
    `rows` (bool (N,)), blocks their `fold` values. Start from no input (r_hat = 0); step
    1 tries every candidate alone at every length scale; each later step tries the
    SHORTLIST candidates that did best alone, at the current length scale and its grid
    neighbours. The best addition is taken while it lowers the CV mean squared error by at
    least MIN_GAIN of the current error, up to MAX_INPUTS inputs. Returns (names, length
    scale, ridge, mse)."""
    R = torch.from_numpy(rows)
    Yr = Y[R]
    fr = fold[rows]
    blocks = [torch.from_numpy(np.flatnonzero(fr == g)) for g in np.unique(fr)]
    x = {k: torch.from_numpy(feats[k])[R] for k in candidates}
    d2 = functools.cache(lambda k: _sqdist(x[k], x[k]))  # (n, n) squared distances of variable k

    def score(names, scales):
        factors = (kernel_factors(x[names[0]], scales, feats[names[0]].shape[1] == 2) if len(names) == 1
                   else [None] * len(scales))
        D = sum(d2(k) for k in names) if any(f is None for f in factors) else None  # (n, n)
        out = None
        for ell, factor in zip(scales, factors):
            pred, _ = block_cv_eig(*factor, Yr, blocks) if factor is not None else block_cv(_gauss(D, ell), Yr, blocks)
            mse = (pred - Yr[None]).pow(2).sum(-1).mean(-1)
            i = int(mse.argmin())
            if out is None or float(mse[i]) < out[0]:
                out = (float(mse[i]), list(names), ell, RIDGES[i])
        return out

    cur = (float(Yr.pow(2).sum(-1).mean()), [], float("nan"), float("nan"))  # mse, names, l, lam
    alone = sorted((score([k], LENGTH_SCALES) for k in candidates), key=lambda t: t[0])
    shortlist = [t[1][0] for t in alone[:SHORTLIST]]
    while alone and len(cur[1]) < MAX_INPUTS:
        if not cur[1]:
            best = alone[0]
        else:
            i = LENGTH_SCALES.index(cur[2])
            near = LENGTH_SCALES[max(i - 1, 0): i + 2]
            tries = [score(cur[1] + [k], near) for k in shortlist if k not in cur[1]]
            if not tries:
                break
            best = min(tries, key=lambda t: t[0])
        if best[0] > (1.0 - MIN_GAIN) * cur[0]:
            break
        cur = best
    return cur[1], cur[2], cur[3], cur[0]


def fit_dual(X: torch.Tensor, Y: torch.Tensor, length_scale: float, ridge: float) -> torch.Tensor:
    """(N, k) dual weights alpha = (K + ridge I)^-1 Y of inputs X (N, d), targets Y (N, k)."""
    K = rbf(X, X, length_scale)
    K.diagonal().add_(ridge)
    return torch.cholesky_solve(Y, torch.linalg.cholesky(K))
