"""A probe of what is left: kernel ridge regression of a model's residual on the recorded
variables, held out by pose.

The residual r (N, 3) mm of a fitted model is regressed on the variables of each row:
each revolute joint angle as (sin q, cos q), each approach direction ``approach_qJ`` as
+-1, and temp_c, payload_kg and a prismatic joint as value over standard deviation. The
model is kernel ridge regression (the posterior mean of a Gaussian process) with the RBF
kernel ``k(x, x') = exp(-|x - x'|^2 / (2 l^2))``, one length scale l for the chosen
inputs, and the three components of r as three outputs that share the kernel:
``r_hat(x) = k(x, X) alpha``, ``alpha = (K + lam I)^-1 R``.

The inputs (an ARD that switches variables on or off) and the hyper-parameters (l in
`LENGTH_SCALES`, lam in `RIDGES`) are chosen by pose-grouped cross-validation (`choose`:
forward selection, on at most about MAX_ROWS rows), so that the held-out figure is
honest: poses are split into `FOLDS` folds and fold f is predicted by the model trained
on the other folds. With fewer than 2 MAX_ROWS rows the choice is nested: fold f's inputs
and hyper-parameters are those that predicted best *within* the other folds (each inner
fold from the other inner folds). With more, they are chosen once, on a subsample of about
MAX_ROWS rows (whole poses), and the test and the figures use only the rows of the other
poses (`Probe.tested`), which the choice never saw. All ridges of one (inputs, l,
training set) come from one eigendecomposition K = V diag(w) V^T: the held-out residual
of a block B of rows is exactly ``[(A^-1)_BB]^-1 (A^-1 R)_B`` with A = K + lam I (the
block leave-out identity of Gaussian-process regression), A^-1 = V diag(1 / (w + lam)) V^T.
The kernel of one variable is low-rank, and `kernel_factor` gives its nonzero eigenpairs
without an N x N eigendecomposition.

Figures:
- learnable_rms_mm: ``sqrt(rms^2 - mean_i g_i)``, g_i = |r_i|^2 - |r_i - r_hat_i|^2 the
  held-out gain of tested row i (every row tested: the distance RMS of r - r_hat): what
  the residual comes down to once the part that is learnable from the recorded variables
  is taken off. ``sqrt(rms^2 - learnable_rms^2)`` is the learnable part.
- p_value: one-sided paired t-test over the tested poses of the held-out gain
  ``g_p = sum_i |r_pi|^2 - |r_pi - r_hat_pi|^2`` (the rows i of pose p), mean(g) > 0. A
  pose's prediction never sees that pose, so with nothing learnable E[g_p] <= 0; repeats
  of a pose are one piece of evidence.
- relevance: for each variable, the share of the learnable part lost when that variable
  is dropped from the inputs (block-CV at the hyper-parameters chosen on all rows):
  ``(mse_without - mse) / (mean|r|^2 - mse)``; carried_by lists those >= `MIN_RELEVANCE`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.stats
import torch

FOLDS = 5
#: RBF length scales tried, in rad of joint angle (standard deviations for other variables).
LENGTH_SCALES = (0.1, 0.2, 0.4, 0.8, 1.6, 3.2)
#: ridge weights tried, relative to the kernel's diagonal (1): noise / signal variance.
RIDGES = (1e-3, 1e-2, 1e-1, 1.0, 10.0, 1e2, 1e4)
#: a variable carries the learnable error when dropping it loses this share of it.
MIN_RELEVANCE = 0.1
#: fewest poses the probe runs on (fewer: nothing is reported as learnable).
MIN_POSES = 10
#: hyper-parameters and inputs are chosen on at most about this many rows (whole poses).
MAX_ROWS = 400
#: an input is added while it lowers the cross-validated error by this share; at most MAX_INPUTS.
MIN_GAIN = 0.01
MAX_INPUTS = 4
#: the variables that did best alone, tried in later steps.
SHORTLIST = 5


@dataclass
class Probe:
    """Result of `probe`: learnable_rms_mm, rms_mm (distance RMS, mm); p_value of the
    held-out gain; inputs, length_scale (rad), ridge: the hyper-parameters chosen on all rows;
    relevance: variable -> share of the learnable part lost without it; prediction (N, 3) mm,
    the held-out prediction; tested (N,) bool: the rows whose poses the choice never saw
    (all rows when the choice is nested)."""

    rms_mm: float
    learnable_rms_mm: float
    p_value: float
    inputs: list
    length_scale: float
    ridge: float
    relevance: dict = field(default_factory=dict)
    prediction: np.ndarray | None = field(default=None, repr=False)
    tested: np.ndarray | None = field(default=None, repr=False)  # (N,) bool: the rows the test and figure use

    @property
    def learnable_mm(self) -> float:
        """Distance RMS of the learnable part, ``sqrt(rms^2 - learnable_rms^2)`` (0 when none)."""
        return float(np.sqrt(max(self.rms_mm ** 2 - self.learnable_rms_mm ** 2, 0.0)))

    def carried_by(self) -> list:
        """[(variable, relevance)] with relevance >= MIN_RELEVANCE, largest first."""
        return sorted(((k, v) for k, v in self.relevance.items() if v >= MIN_RELEVANCE), key=lambda t: -t[1])


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


def rbf(A: torch.Tensor, B: torch.Tensor, length_scale: float) -> torch.Tensor:
    """(M, N) RBF kernel exp(-|a - b|^2 / (2 l^2)) of rows A (M, d), B (N, d)."""
    return torch.exp(-_sqdist(A, B) / (2.0 * length_scale ** 2))


def block_cv(K: torch.Tensor, Y: torch.Tensor, blocks: list, ridges=RIDGES):
    """Exact block leave-out predictions of kernel ridge regression, all ridges at once.

    K (N, N) kernel, Y (N, k) targets, blocks: index tensors partitioning 0..N-1.
    Returns (pred (R, N, k): each block predicted from the other rows, alpha (R, N, k):
    the dual weights on all N rows), R = len(ridges)."""
    w, V = torch.linalg.eigh(K)
    return block_cv_eig(w, V, Y, blocks, ridges)


def block_cv_eig(w: torch.Tensor, V: torch.Tensor, Y: torch.Tensor, blocks: list, ridges=RIDGES):
    """`block_cv` of the kernel ``K = V diag(w) V^T``: V (N, p) orthonormal columns, w (p,);
    p < N: the other N - p eigenvalues are zero (a low-rank kernel, `kernel_factor`), so
    ``A^-1 = V diag(1 / (w + lam) - 1 / lam) V^T + I / lam``."""
    lam = torch.as_tensor(ridges, dtype=V.dtype)
    w = w.clamp_min(0.0)[None, :]
    thin = V.shape[1] < V.shape[0]
    d = -w / (lam[:, None] * (w + lam[:, None])) if thin else 1.0 / (w + lam[:, None])  # (R, p)
    alpha = (V[None] * d[:, None, :]) @ (V.T @ Y)  # (R, N, k) = A^-1 Y
    if thin:
        alpha = alpha + Y[None] / lam[:, None, None]
    pred = torch.empty_like(alpha)
    for B in blocks:
        VB = V[B]  # (b, p)
        QBB = (VB[None] * d[:, None, :]) @ VB.T  # (R, b, b) = (A^-1)_BB
        if thin:
            QBB = QBB + torch.diag_embed((1.0 / lam)[:, None].expand(-1, len(B)))
        pred[:, B] = Y[B][None] - torch.linalg.solve(QBB, alpha[:, B])
    return pred, alpha


#: a kernel factor keeps the terms down to this share of the kernel's diagonal.
FACTOR_TOL = 1e-12
#: a variable with at most this many distinct values gets the exact factor on its values.
FACTOR_VALUES = 64


def kernel_factor(x: torch.Tensor, length_scale: float, angle: bool):
    """(w (p,), V (N, p)): the nonzero eigenpairs of the RBF kernel of one variable's
    inputs x (N, d), found without an N x N eigendecomposition, or None (no such way).

    - at most FACTOR_VALUES distinct rows u: ``K = E C E^T`` with E (N, u) the rows'
      indicators and C (u, u) the kernel of the distinct rows (exact);
    - an angle (angle=True, x = (sin q, cos q)): ``k = exp((cos(q - q') - 1) / l^2) =
      sum_n c_n cos(n (q - q'))`` with ``c_0 = I_0(1/l^2) e^(-1/l^2)``, ``c_n = 2 I_n(1/l^2)
      e^(-1/l^2)`` (the von Mises series), features ``sqrt(c_n) (cos n q, sin n q)``,
      truncated where c_n < FACTOR_TOL c_0 (the dropped terms sum to about that share of
      the diagonal, 1).
    The eigenpairs come from a thin SVD of the (N, p) factor, p << N."""
    import scipy.special

    uniq, inv = torch.unique(x, dim=0, return_inverse=True)
    if len(uniq) <= FACTOR_VALUES:
        c, U = torch.linalg.eigh(rbf(uniq, uniq, length_scale))
        F = U[inv] * c.clamp_min(0.0).sqrt()
    elif angle:
        kappa = 1.0 / length_scale ** 2
        n = np.arange(0, 4 * int(np.sqrt(kappa) * 8 + 8))
        c = scipy.special.ive(n, kappa) * np.where(n > 0, 2.0, 1.0)
        n = n[c >= FACTOR_TOL * c[0]]
        if 2 * len(n) - 1 >= x.shape[0]:
            return None
        q = torch.atan2(x[:, 0], x[:, 1])[:, None] * torch.from_numpy(n[1:].astype(np.float64))
        sq = torch.from_numpy(np.sqrt(c[n]))
        F = torch.cat([sq[:1].expand(len(x), 1), torch.cos(q) * sq[1:], torch.sin(q) * sq[1:]], -1)
    else:
        return None
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
    d2 = {k: _sqdist(v, v) for k, v in x.items()}

    def score(names, scales):
        D = sum(d2[k] for k in names)
        out = None
        for ell in scales:
            factor = kernel_factor(x[names[0]], ell, feats[names[0]].shape[1] == 2) if len(names) == 1 else None
            pred, _ = (block_cv_eig(*factor, Yr, blocks) if factor is not None else
                       block_cv(torch.exp(-D / (2.0 * ell ** 2)), Yr, blocks))
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


def fold_of_pose(pose: np.ndarray, seed: int, folds: int = FOLDS) -> np.ndarray:
    """(N,) fold 0..folds-1 of each row, whole poses to one fold (random, `seed`)."""
    _, inverse = np.unique(pose, return_inverse=True)
    return (np.random.default_rng(seed).permutation(int(inverse.max()) + 1) % folds)[inverse]


def probe(values: dict, residuals: np.ndarray, pose: np.ndarray, *, seed: int = 0,
          prismatic=()) -> Probe:
    """Kernel-ridge probe of residual rows (N, 3) mm on the variables `values` (name -> (N,),
    as `unexplained.variables`; ``order`` is not used: it is not a recorded condition).
    pose (N,) pose ids (folds and the test are by pose). See the module doc."""
    r = np.ascontiguousarray(residuals, dtype=np.float64).reshape(-1, 3)
    rms = float(np.sqrt((r ** 2).sum(-1).mean()))
    pose = np.asarray(pose)
    _, pose_idx = np.unique(pose, return_inverse=True)
    P = int(pose_idx.max()) + 1 if len(r) else 0
    values = {k: v for k, v in values.items() if k != "order"}
    if P < MIN_POSES or not values:
        return Probe(rms, rms, 1.0, [], float("nan"), float("nan"), {}, np.zeros_like(r))
    feats = variable_features(values, prismatic)
    names = list(feats)
    Y = torch.from_numpy(r)
    fold = fold_of_pose(pose, seed)
    pred = np.zeros_like(r)
    rows = subsample(fold, np.ones(len(r), dtype=bool), pose, seed)
    split = len(r) >= 2 * MAX_ROWS  # choose once on `rows`, test the poses outside them
    if split:
        chosen = choose(feats, names, Y, fold, rows)
    for f in np.unique(fold):
        train = fold != f
        inputs, ell, lam, _ = chosen if split else \
            choose(feats, names, Y, fold, subsample(fold, train, pose, seed + 1 + int(f)))
        if inputs:
            X, T = stack_inputs(feats, inputs), torch.from_numpy(train)
            alpha = fit_dual(X[T], Y[T], ell, lam)
            pred[fold == f] = (rbf(X[torch.from_numpy(fold == f)], X[T], ell) @ alpha).numpy()
    tested = ~rows if split else np.ones(len(r), dtype=bool)
    gain_row = (r ** 2).sum(-1) - ((r - pred) ** 2).sum(-1)
    learn = float(np.sqrt(max(rms ** 2 - gain_row[tested].mean(), 0.0)))
    gain = np.bincount(pose_idx[tested], weights=gain_row[tested], minlength=P)[np.unique(pose_idx[tested])]
    sd = gain.std(ddof=1) if len(gain) > 1 else 0.0
    p = 1.0 if sd == 0 else float(scipy.stats.t.sf(gain.mean() / (sd / np.sqrt(len(gain))), len(gain) - 1))
    # inputs and hyper-parameters on all rows, and what each input carries at them
    inputs, ell, lam, mse = chosen if split else choose(feats, names, Y, fold, rows)
    Yr = Y[torch.from_numpy(rows)]
    total = float(Yr.pow(2).sum(-1).mean())
    blocks = [torch.from_numpy(np.flatnonzero(fold[rows] == g)) for g in np.unique(fold[rows])]
    relevance = {}
    for k in inputs:
        rest = [n for n in inputs if n != k]
        without = total
        if rest:
            X = stack_inputs(feats, rest)[torch.from_numpy(rows)]
            pr, _ = block_cv(rbf(X, X, ell), Yr, blocks, (lam,))
            without = float((pr[0] - Yr).pow(2).sum(-1).mean())
        relevance[k] = (without - mse) / (total - mse) if total - mse > 1e-12 * total else 0.0
    return Probe(rms, learn, p, inputs, float(ell), float(lam), relevance, pred, tested)
