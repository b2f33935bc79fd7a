"""Held-out spectral search: the orders of a periodic joint error that the residual shows.

A periodic error of joint J at order k (cycles per joint turn) moves the TCP by
``(s sin(k q_J) + c cos(k q_J)) t_J`` with t_J (N, 3) mm/rad joint J's column of the
position Jacobian (its dtheta column). The search scans the orders the joint's measured
range resolves and keeps those that predict held-out poses (`search_orders`):

1. Columns: C (3N, 2K) = sin(k q_J) t_J, cos(k q_J) t_J for each order k of the grid,
   the derivative of `joint_periodic:J@k...` at zero (one forward pass for the grid).
2. One step, vectorised over the grid: for each fold (by pose; the folds of `discover`),
   the base columns X = [A, chosen orders] and the order's pair of columns are fitted to
   the residual r on the other folds and predicted on the held-out one. Each order's fit
   is a batched 2x2 solve, and the held-out sums of squares of all K orders come from
   sums over rows: X^T C, C^T r and each pair's Gram matrix on each fold's rows (one pass
   over C for all folds; a fold's training sums are the totals minus its own) and C's
   coefficients on the fold's orthonormal basis of X (`_Projected.sums`), so no step
   passes over C's rows per fold. As X grows by the pair chosen, each fold's basis of X
   and these coefficients are updated by the pair's new directions (`_extend_basis`,
   `_Projected.extended`), not recomputed.
3. The order with the smallest held-out sum of squares is added when it cuts the held-out
   RMS by at least `MIN_ORDER_GAIN` and its F-test on all training rows (2 new columns
   beyond X) passes ``alpha / K`` (Bonferroni over the grid); repeat from 2 with it in X,
   at most `MAX_ORDERS` times.
4. Determined by the data (`determined_orders`): an order is kept only when, fitted on all
   rows with the base columns and the orders already kept, every coefficient of the
   joint's orders (the kept ones and the new pair) would be determined by the data as the
   fit's plausibility judges it (`torchcal.calibration.plausibility.undetermined`: with
   the fit's prior N(0, s^2) on each coefficient, s = the effect's plausible size, the
   posterior sd below half of s and the value within s). Two orders whose columns are
   nearly collinear on THESE poses (neighbours over a narrow range: their phases drift
   apart by less than a turn across it) get large, opposite coefficients set by each
   other, not by the data, and the plausibility would refuse the whole candidate; over a
   wide range the same two orders are separated and both may stay. An order that fails
   is not offered again and the next best (by held-out error) is tried in the same step.
   The rule and its figures are the plausibility's; no threshold of its own.

What a joint's measured range R (rad) resolves (`order_limits`):

- a term with fewer than two periods inside the range is, there, a smooth curve that a
  joint offset, a linear trend or another low-order effect (`gear_periodic`, compliance)
  reproduces: the lowest order searched is ``k_min = ceil(2 * 2 pi / R)``;
- two orders k and k' are nearly orthogonal over the range when their phases drift
  apart by a full turn across it, ``|k - k'| R >= 2 pi``: the resolution is
  ``2 pi / R`` orders. Below a full joint turn neighbouring orders are not well
  separated: an order found is the centre of a band that wide; whether a second order
  of the band is kept is step 4's decision, on the poses' own design (the resolution is
  printed, not enforced);
- the samples must see each period: with g90 the 90th percentile of the gaps between
  the sorted measured angles, at least two samples per period over most of the range
  gives ``k_max = floor(pi / g90)``, at most `MAX_GRID_ORDER`.

A joint whose range resolves no order (k_min > k_max) is not searched and warned about.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from torchcal.calibration.plausibility import undetermined
from torchcal.diagnosis.crossval import RANK_TOL
from torchcal.effects.joint_periodic import ARCSEC, MAX_AMPLITUDE_ARCSEC
from torchcal.statistics import f_sf

MAX_GRID_ORDER = 120  # highest order searched (cycles per joint turn)
MIN_PERIODS = 2  # periods of the lowest order inside the measured range
MAX_ORDERS = 8  # orders kept per joint at most
MIN_ORDER_GAIN = 0.005  # relative held-out RMS gain an order must bring
ALPHA = 0.01  # family level of one joint's search (split over the grid)


class NarrowRangeWarning(UserWarning):
    """A joint's measured range resolves no periodic order (the command line prints one line)."""


@dataclass
class OrderLimits:
    """What joint angles q resolve: orders k_min..k_max (cycles per turn), resolution
    (orders closer than this are not separated), range_deg (the measured range)."""

    k_min: int
    k_max: int
    resolution: float
    range_deg: float

    @property
    def empty(self) -> bool:
        return self.k_min > self.k_max

    def text(self, joint: int) -> str:
        if self.empty:
            return (f"joint {joint}: its measured range ({self.range_deg:.1f} deg) resolves no periodic order "
                    f"<= {MAX_GRID_ORDER} (two periods inside it need order >= {self.k_min}; the angle "
                    f"spacing allows <= {self.k_max}); not searched")
        return (f"joint {joint}: orders {self.k_min}-{self.k_max} searched (range {self.range_deg:.1f} deg; "
                f"orders closer than {self.resolution:.1f} are not separated)")


def order_limits(q: np.ndarray, max_order: int = MAX_GRID_ORDER) -> OrderLimits:
    """The orders that joint angles q (N,) rad resolve (module doc)."""
    q = np.unique(np.asarray(q, dtype=float))
    span = float(q[-1] - q[0]) if len(q) > 1 else 0.0
    if span <= 0:
        return OrderLimits(max_order + 1, 0, math.inf, 0.0)
    k_min = math.ceil(MIN_PERIODS * 2 * math.pi / span - 1e-9)
    g90 = float(np.quantile(np.diff(q), 0.9))
    k_max = min(max_order, math.floor(math.pi / g90)) if g90 > 0 else max_order
    return OrderLimits(k_min, k_max, 2 * math.pi / span, math.degrees(span))


@dataclass
class Search:
    """The result for one joint: orders chosen (in the order found), amplitudes_arcsec
    (sqrt(s^2 + c^2) of each, fitted with the base columns on all rows), cv_rms_mm
    (held-out RMS before and after each order), p_values (each order's F-test), limits."""

    joint: int
    orders: tuple
    amplitudes_arcsec: tuple
    cv_rms_mm: list
    p_values: list
    limits: OrderLimits = field(repr=False)


def _pinv_parts(X: np.ndarray):
    """Orthonormal basis U of span(X) and the map M with X M = U U^T (rank cut RANK_TOL)."""
    Q, R = np.linalg.qr(X)  # tall X: the SVD of the small R gives X's
    u, s, vt = np.linalg.svd(R)
    keep = s > RANK_TOL * (s[0] if len(s) else 1.0)
    return Q @ u[:, keep], vt[keep].T / s[keep]


def _pair_grams(D: np.ndarray) -> np.ndarray:
    """(K, 2, 2) the Gram matrix of each pair of columns of D (T, K, 2): sum over t of
    D[t, k, a] D[t, k, b] (einsum "tka,tkb->kab", as three einsums "tk,tk->k" of column
    pairs: several times faster than the one einsum, 2.5x faster than the products summed,
    with no (T, K) temporaries)."""
    d0, d1 = D[..., 0], D[..., 1]
    g00, g01, g11 = (np.einsum("tk,tk->k", a, b) for a, b in ((d0, d0), (d0, d1), (d1, d1)))
    return np.stack([np.stack([g00, g01], -1), np.stack([g01, g11], -1)], -2)


def _extend_basis(BT: np.ndarray, BV: np.ndarray, R: np.ndarray, pT: np.ndarray, pV: np.ndarray):
    """The directions a pair of columns adds to an orthonormal basis of X's training rows.

    BT (T, m): orthonormal basis of span(X_T), X's training rows (``X_T M = BT``, as from
    `_pinv_parts`); BV (V, m) = X_V M, the same combinations of X's held-out rows;
    R (m, p) = BT^T X_T. pT (T, 2), pV (V, 2): the pair's training and held-out rows.
    Returns (Q (T, k), QV (V, k), R' (m + k, p + 2), W (m, 2), Mn (2, k)): the pair's
    component orthogonal to BT (one Gram-Schmidt step, then once more against the
    rounding), orthonormalised, so that [BT, Q] spans what `_pinv_parts([X_T, pT])` spans,
    [BV, QV] its held-out combinations, and R' = [BT, Q]^T [X_T, pT]; Q = (pT - BT W) Mn,
    QV = (pV - BV W) Mn. The same rank rule: k = the number of singular values of
    [X_T, pT] (those of R' before the cut) above RANK_TOL times the largest, minus m; 0,
    1 (the remainder's dominant direction) or 2."""
    W = BT.T @ pT
    nT, nV = pT - BT @ W, pV - BV @ W
    W2 = BT.T @ nT  # re-orthogonalisation
    nT, nV, W = nT - BT @ W2, nV - BV @ W2, W + W2
    _, s, vt = np.linalg.svd(nT, full_matrices=False)  # nT = (nT vt^T / s) diag(s) vt
    Rn = np.block([[R, W], [np.zeros((len(s), R.shape[1])), s[:, None] * vt]])
    sv = np.linalg.svd(Rn, compute_uv=False)
    rank = int((sv > RANK_TOL * (sv[0] if len(sv) else 1.0)).sum())
    k = min(max(rank - R.shape[0], 0), len(s))
    Mn = vt[:k].T / s[:k]
    return nT @ Mn, nV @ Mn, Rn[:R.shape[0] + k], W, Mn


@dataclass
class _Grams:
    """What one fold's search needs of the candidate columns C (3N, 2K): sums over its
    training rows T and its held-out rows V (`_fold_grams`), so that no step passes over
    C's rows per fold. C (3N, 2K) with its rows sorted by fold, V (slice) the fold's
    rows in it; XC_T, XC_V (p, 2K): X^T C on T and on V; G_T, G_V (K, 2, 2): each pair's
    Gram matrix there; cr_T, cr_V (2K,): C^T r there."""

    C: np.ndarray
    V: slice
    XC_T: np.ndarray
    XC_V: np.ndarray
    G_T: np.ndarray
    G_V: np.ndarray
    cr_T: np.ndarray
    cr_V: np.ndarray


def _appended(B: np.ndarray, Q: np.ndarray, room: int = 2 * MAX_ORDERS) -> np.ndarray:
    """[B, Q] (n, m + k) for B (n, m), Q (n, k): written into the columns after B's when
    B is the leading columns of a buffer with room for Q (a view, no copy: those columns
    are then the result's), else copied into a new buffer with `room` more columns."""
    n, m = B.shape
    k = Q.shape[1]
    buf = B.base
    if (isinstance(buf, np.ndarray) and buf.ndim == 2 and buf.shape[0] == n and buf.shape[1] >= m + k
            and B.ctypes.data == buf.ctypes.data and B.strides == buf.strides):
        buf[:, m:m + k] = Q
        return buf[:, :m + k]
    buf = np.empty((n, m + k + room))
    buf[:, :m], buf[:, m:m + k] = B, Q
    return buf[:, :m + k]


def _fold_order(rows: np.ndarray):
    """(order (3N,), bounds [(start, end)] per fold): the permutation that sorts the
    stacked rows by their fold label `rows` (3N,) (stable), and each fold's slice of the
    sorted rows."""
    order = np.argsort(rows, kind="stable")
    _, starts = np.unique(rows[order], return_index=True)
    return order, list(zip(starts.tolist(), starts[1:].tolist() + [len(rows)]))


def _fold_grams(X: np.ndarray, r: np.ndarray, C: np.ndarray, bounds: list) -> list:
    """`_Grams` of each fold for X (3N, p), r (3N,), C (3N, 2K), their rows sorted by fold
    and the folds' rows the slices `bounds` (`_fold_order`): one pass over C (each fold's
    rows once), the training sums as the totals minus the fold's."""
    K = C.shape[1] // 2
    parts = [(X[a:b].T @ C[a:b], _pair_grams(C[a:b].reshape(b - a, K, 2)), C[a:b].T @ r[a:b]) for a, b in bounds]
    XC, G, cr = (sum(p[i] for p in parts) for i in range(3))
    return [_Grams(C, slice(a, b), XC - xc, xc, G - g, g, cr - c, c) for (a, b), (xc, g, c) in zip(bounds, parts)]


@dataclass
class _Projected:
    """The residual r and the candidate columns C with X projected out, fitted on the
    training rows t (3N,) bool of one fold (all rows for the F-test; then V = 0).

    BT (T, m), BV (V, m): X's orthonormal training basis and its held-out combinations
    (`_extend_basis`); R (m, p) = BT^T X_T; a (m,) = BT^T r_T, r's coefficients on the
    basis; eT (T,) = r_T - BT a, eV (V,) = r_V - BV a: r minus its fit on X (fitted on
    the training rows). With C (g None when not needed): g, the fold's `_Grams` of C
    (the rows of C, X and r sorted by fold, t False on the fold's slice); PT = BT^T C_T,
    PV = BV^T C_V (m, 2K): C's coefficients on the basis. D = C minus its fit on X enters
    only through these and g (`sums`)."""

    t: np.ndarray
    BT: np.ndarray
    BV: np.ndarray
    R: np.ndarray
    a: np.ndarray
    eT: np.ndarray
    eV: np.ndarray
    M: np.ndarray | None = None
    g: _Grams | None = None
    PT: np.ndarray | None = None
    PV: np.ndarray | None = None

    @classmethod
    def start(cls, X: np.ndarray, r: np.ndarray, t: np.ndarray) -> "_Projected":
        """From scratch, without C: X (3N, p) by QR + SVD (`_pinv_parts`, X_T M = BT; M
        (p, m) kept for `with_columns`) on rows t."""
        v = ~t
        Xt = X[t]
        BT, M = _pinv_parts(Xt)
        BV = X[v] @ M
        a = BT.T @ r[t]
        return cls(t, BT, BV, BT.T @ Xt, a, r[t] - BT @ a, r[v] - BV @ a, M)

    def with_columns(self, g: _Grams) -> "_Projected":
        """The same fold with C (its `_Grams` g) as `start` left it: PT = M^T X_T^T C_T,
        PV = M^T X_V^T C_V."""
        return dataclasses.replace(self, g=g, PT=self.M.T @ g.XC_T, PV=self.M.T @ g.XC_V)

    def extended(self, pair: np.ndarray, pair_c: np.ndarray | None = None) -> "_Projected":
        """The same with the columns pair (3N, 2) added to X (`_extend_basis`); pair_c
        (2, 2K): pair^T C on all rows (needed when C is held). The new directions Q (T, k)
        are orthonormal and orthogonal to BT, Q = (pT - BT W) Mn, so Q^T C_T =
        Mn^T (pT^T C_T - W^T PT), and the same on the held-out rows: no pass over C.
        The bases grow in place (`_appended`): extend a `_Projected` once (its successor
        then owns the columns after its own)."""
        t, v = self.t, ~self.t
        Q, QV, R, W, Mn = _extend_basis(self.BT, self.BV, self.R, pair[t], pair[v])
        a = Q.T @ self.eT
        out = _Projected(t, _appended(self.BT, Q), _appended(self.BV, QV), R, np.concatenate([self.a, a]),
                         self.eT - Q @ a, self.eV - QV @ a)  # (no M: `with_columns` is for a start)
        if self.g is not None:
            g = self.g
            pcV = pair[v].T @ g.C[g.V]  # the held-out rows of pair are the fold's slice
            out.g = g
            out.PT = np.vstack([self.PT, Mn.T @ (pair_c - pcV - W.T @ self.PT)])
            out.PV = np.vstack([self.PV, Mn.T @ (pcV - W.T @ self.PV)])
        return out

    def sums(self):
        """Held-out sum of squares of r on X alone (float) and on [X, pair k] for every
        pair of C's columns (K,), the pair's coefficients fitted on the training rows.

        From Gram matrices, per pair (D = C minus its fit on X): the training Gram
        D_T^T D_T = G_T - PT^T PT and D_T^T eT = cr_T - PT^T a give beta; on the held-out
        rows D_V^T eV = (cr_V - PV^T a) - PT^T BV^T eV and D_V^T D_V = G_V - PV^T PT -
        PT^T PV + PT^T (BV^T BV) PT give |eV - D_V beta|^2."""
        g, PT, PV, eV, BV = self.g, self.PT, self.PV, self.eV, self.BV
        K, m = len(g.G_T), len(PT)

        def pairs(Z):  # (m, 2K) -> (K, 2, m): each pair's two rows of Z^T
            return Z.reshape(m, K, 2).transpose(1, 2, 0)

        P2 = pairs(PT)
        G = g.G_T - P2 @ P2.transpose(0, 2, 1)
        b = (g.cr_T - PT.T @ self.a).reshape(K, 2)
        h = ((g.cr_V - PV.T @ self.a) - PT.T @ (BV.T @ eV)).reshape(K, 2)
        cross = pairs(PV) @ P2.transpose(0, 2, 1)
        S = g.G_V - cross - cross.transpose(0, 2, 1) + P2 @ pairs((BV.T @ BV) @ PT).transpose(0, 2, 1)
        beta = np.linalg.solve(G + 1e-12 * np.eye(2), b[..., None])  # (K, 2, 1)
        ee = float(eV @ eV)
        return ee, ee - 2 * (beta[..., 0] * h).sum(-1) + (beta.transpose(0, 2, 1) @ S @ beta)[:, 0, 0]


@dataclass
class SearchBase:
    """What the searches of every joint on the same residual, base columns and folds
    share (`search_base`): X (3N, p) the base columns scaled to unit norm and r (3N,),
    their rows sorted by fold (order (3N,) the permutation, bounds the folds' slices,
    `_fold_order`); folds, each fold's `_Projected` of r on X (without C); whole, the
    same on all rows (the F-test's and the determination's)."""

    X: np.ndarray
    r: np.ndarray
    order: np.ndarray
    bounds: list
    folds: list
    whole: _Projected


def search_base(r: np.ndarray, A: np.ndarray, folds: np.ndarray) -> SearchBase:
    """The `SearchBase` of residual r (3N,) on base columns A (3N, p) with the folds (N,)
    by pose: one QR per fold for every joint searched on them."""
    order, bounds = _fold_order(np.repeat(np.asarray(folds), 3))
    X = (A / np.linalg.norm(A, axis=0).clip(1e-300))[order]
    r = r[order]
    out = []
    for a, b in bounds:
        t = np.ones(len(r), dtype=bool)
        t[a:b] = False
        out.append(_Projected.start(X, r, t))
    return SearchBase(X, r, order, bounds, out, _Projected.start(X, r, np.ones(len(r), dtype=bool)))


def _with_columns(base: SearchBase, Cs: np.ndarray) -> list:
    """Each fold of `base` with the columns Cs (3N, 2K) (rows in base's order)."""
    return [fp.with_columns(g) for fp, g in zip(base.folds, _fold_grams(base.X, base.r, Cs, base.bounds))]


def held_out_sums(r: np.ndarray, X: np.ndarray, C: np.ndarray, rows: np.ndarray):
    """Held-out sums of squares of r on X alone (float) and on [X, pair k] for every pair
    of columns of C (K,), over the folds `rows` (3N,) (fold of each stacked row, a
    pose's three rows in one fold); from scratch (`search_orders` updates the folds'
    projections as X grows). X is taken with unit columns (the same span)."""
    base = search_base(r, X, rows[::3])
    return _fold_sums(_with_columns(base, C[base.order]))


def _fold_sums(folds: list):
    """Sum over the folds' `_Projected.sums`: (float, (K,))."""
    base, per = 0.0, 0.0
    for p in folds:
        b, k = p.sums()
        base, per = base + b, per + k
    return base, per


def determined_orders(r_perp: np.ndarray, C_perp: np.ndarray, dof: int, scale: float) -> bool:
    """Whether the data determine every coefficient of the orders whose columns C_perp
    (3N, 2m) (sin, cos per order, the coefficients' unit: rad) are, with the base columns
    projected out of them and of the residual r_perp (3N,) mm (module doc, step 4).

    The linear fit with the prior N(0, scale^2) of the effect's parameters (noise variance
    from the unregularised fit's residual, dof = rows - base rank - 2m): posterior
    covariance (C^T C / s2 + I / scale^2)^-1, its mean the shrunk coefficients; each
    judged by `undetermined` (posterior sd < DETERMINED_RATIO * scale, |value| <= scale)."""
    if dof < 1:
        return False
    ls = np.linalg.lstsq(C_perp, r_perp, rcond=None)[0]
    e = r_perp - C_perp @ ls
    s2 = max(float(e @ e) / dof, 1e-300)
    H = C_perp.T @ C_perp / s2 + np.eye(C_perp.shape[1]) / scale ** 2
    cov = np.linalg.inv(H)
    mean = cov @ (C_perp.T @ r_perp) / s2
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return all(undetermined(float(v), float(d), scale) is None for v, d in zip(mean, sd))


def search_orders(r: np.ndarray, A: np.ndarray, C: np.ndarray, grid, folds: np.ndarray, *,
                  alpha: float = ALPHA, max_orders: int = MAX_ORDERS, min_gain: float = MIN_ORDER_GAIN,
                  scale: float | None = None, base: SearchBase | None = None):
    """Greedy held-out search (module doc) of residual r (3N,) mm on base columns A (3N, p)
    over the orders `grid` (K,) with columns C (3N, 2K) (sin, cos per order), folds (N,).
    scale: the plausible size of one coefficient in C's coefficient unit (rad): an order
    is kept only when the data determine the joint's coefficients with it (step 4,
    `determined_orders`); None: no such check. base: `search_base`(r, A, folds) when the
    caller already has it (the searches of several joints share it).

    Returns (indices into grid, in the order chosen; held-out RMS mm before and after each;
    F-test p-values).
    """
    n_rows = len(r) // 3
    base = search_base(r, A, folds) if base is None else base  # every row below in base's order
    order = base.order
    Cs = C[order]
    Cs /= np.linalg.norm(Cs, axis=0).clip(1e-300)  # unit columns
    level = alpha / max(len(grid), 1)
    folds_p = _with_columns(base, Cs)
    whole = base.whole  # all rows: the F-test
    if scale is not None:
        UA, perp = whole.BT, {}
        r_perp = whole.eT

        def c_perp(j: int) -> np.ndarray:
            """(3N, 2) order j's columns C with the base columns projected out (once)."""
            if j not in perp:
                c = C[order, 2 * j:2 * j + 2]
                perp[j] = c - UA @ (UA.T @ c)
            return perp[j]
    chosen, path, ps = [], [], []
    refused = np.zeros(len(grid), dtype=bool)  # not determined beside the orders kept
    while len(chosen) < max_orders:
        ss0, per = _fold_sums(folds_p)
        if not path:
            path.append(math.sqrt(ss0 / n_rows))
        per[chosen] = np.inf
        per[refused] = np.inf
        best = None
        for i in np.argsort(per, kind="stable"):
            i = int(i)
            if not np.isfinite(per[i]) or math.sqrt(max(per[i], 0.0) / n_rows) > path[-1] * (1 - min_gain):
                break  # this and every later one gains too little
            if scale is None:
                best = i
                break
            dof = len(r) - UA.shape[1] - 2 * (len(chosen) + 1)
            if determined_orders(r_perp, np.hstack([c_perp(j) for j in chosen + [i]]), dof, scale):
                best = i
                break
            refused[i] = True
        if best is None:
            break
        cv = math.sqrt(max(per[best], 0.0) / n_rows)
        pair = Cs[:, 2 * best:2 * best + 2]
        whole1 = whole.extended(pair)
        e0, e1 = whole.eT, whole1.eT
        k_new = whole1.BT.shape[1] - whole.BT.shape[1]
        dof = len(r) - whole1.BT.shape[1]
        if k_new < 1 or dof < 1:
            break
        F = ((e0 @ e0 - e1 @ e1) / k_new) / max(e1 @ e1 / dof, 1e-300)
        p = f_sf(F, k_new, dof)
        if p >= level:
            break
        chosen.append(best)
        path.append(cv)
        ps.append(p)
        pair_c = pair.T @ Cs
        whole, folds_p = whole1, [fp.extended(pair, pair_c) for fp in folds_p]
    return chosen, path, ps


def grid_columns(robot, model, theta, ctx, joint: int, grid) -> np.ndarray:
    """(3N, 2K) the columns sin(k q_J) t_J, cos(k q_J) t_J of `joint_periodic:joint` at the
    orders `grid` (K,), the derivative of the effect at zero on `model` at theta (step 1)."""
    from torchcal.diagnosis.candidates import all_candidate_columns

    key = ("joint_periodic", (joint,))
    return all_candidate_columns(robot, model, theta, ctx, [key], {key: (tuple(grid),)})[key]


def fold_orders(robot, model, theta, ctx, r: np.ndarray, A: np.ndarray, folds: np.ndarray, joint: int,
                bases: dict | None = None, **kw) -> dict:
    """{fold: orders} per fold of folds (N,): the orders of `joint_periodic:joint` that the
    same search (`propose_orders`: alpha, order limits, determination) finds on the OTHER
    folds' rows alone, for the refit CV of a searched candidate
    (`torchcal.diagnosis.procedure_cv`), so that the fold that tests the orders took no
    part in choosing them.

    Restricted to the training rows T of fold f: the residual r (3N,) and base columns A
    (3N, p) of the current full fit (not refitted on T), the order limits of T's own
    measured range (the procedure run on T: its range and spacing are what T resolves),
    and as inner folds T's own fold labels (K - 1 inner folds). The held-out rows enter r
    only through the full fit's parameters: refitted on T, r_T would change by A_T delta
    (first order, delta the parameter change), a vector in span(A_T); every figure of the
    search (held-out sums over inner folds, F-test, determination) regresses on A
    restricted to the rows it uses, so it is unchanged by adding A_T delta to r_T: the
    leak is zero to first order (only the curvature of the model, and the columns taken
    at the full fit, carry the held-out rows). A fold whose rows resolve no order gives
    () without a warning (`propose_orders` warns for the data as a whole). bases: fold ->
    the `search_base` of T's rows, filled here as needed: a dict the caller keeps for
    the searches of several joints on the same r, A and folds."""
    q = ctx.q[:, joint - 1].detach().cpu().numpy()
    folds = np.asarray(folds)
    labels = [int(f) for f in np.unique(folds)]
    lims = {f: order_limits(q[folds != f]) for f in labels}
    used = [lim for lim in lims.values() if not lim.empty]
    if not used:
        return {f: () for f in labels}
    lo, hi = min(lim.k_min for lim in used), max(lim.k_max for lim in used)
    C = grid_columns(robot, model, theta, ctx, joint, range(lo, hi + 1))  # every fold's grid at once
    kw.setdefault("scale", MAX_AMPLITUDE_ARCSEC * ARCSEC)
    out = {}
    for f in labels:
        lim = lims[f]
        if lim.empty:
            out[f] = ()
            continue
        grid = tuple(range(lim.k_min, lim.k_max + 1))
        cols = np.arange(2 * (lim.k_min - lo), 2 * (lim.k_max - lo + 1))
        t3 = np.repeat(folds != f, 3)
        bases = {} if bases is None else bases
        if f not in bases:
            bases[f] = search_base(r[t3], A[t3], folds[folds != f])
        idx, _, _ = search_orders(r[t3], A[t3], C[t3][:, cols], grid, folds[folds != f], base=bases[f], **kw)
        out[f] = tuple(grid[i] for i in idx)
    return out


def propose_orders(robot, model, theta, ctx, r: np.ndarray, A: np.ndarray, folds: np.ndarray, joint: int,
                   base: SearchBase | None = None, **kw) -> Search:
    """The orders of `joint_periodic:joint` that the residual r (3N,) of `model` at theta
    (base columns A (3N, p), folds (N,) by pose) shows; module doc. Warns when the joint's
    measured range resolves no order. base: `search_base`(r, A, folds), shared by the
    caller's searches of several joints (made here when None)."""
    q = ctx.q[:, joint - 1].detach().cpu().numpy()
    lim = order_limits(q)
    if lim.empty:
        warnings.warn(f"joint_periodic: {lim.text(joint)}", NarrowRangeWarning, stacklevel=2)
        return Search(joint, (), (), [], [], lim)
    grid = tuple(range(lim.k_min, lim.k_max + 1))
    C = grid_columns(robot, model, theta, ctx, joint, grid)
    kw.setdefault("scale", MAX_AMPLITUDE_ARCSEC * ARCSEC)  # the effect's plausible size (rad)
    idx, path, ps = search_orders(r, A, C, grid, folds, base=base, **kw)
    amps = ()
    if idx:
        cols = np.hstack([C[:, 2 * i:2 * i + 2] for i in idx])
        X = np.hstack([A, cols])
        norms = np.linalg.norm(X, axis=0).clip(1e-300)
        U, M = _pinv_parts(X / norms)
        coef = (M @ (U.T @ r) / norms)[A.shape[1]:]  # rad
        amps = tuple(float(np.hypot(*coef[2 * i:2 * i + 2]) / ARCSEC) for i in range(len(idx)))
    return Search(joint, tuple(grid[i] for i in idx), amps, path, ps, lim)
