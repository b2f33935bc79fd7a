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
lowest restart index). Points are streamed in chunks (about 256 KiB of memberships per
chunk on a CPU, so a chunk's scratch stays in a core's L2 cache; very large chunks on a
GPU). No (c, N) tensor is written while iterating (the starting memberships are read,
and their columns normalised chunk by chunk, in the first iteration): an iteration
computes each chunk's memberships from the current centers (eq. 28) and adds them into
the sums of eq. 27, and U is written once: during the last allowed iteration when one
restart is left then (and kept if that restart is the one returned), else at the end,
from the kept centers. The stopping rule needs
the previous memberships; they are recomputed from the previous centers (the same
values), and only while the rule can still fire: the squared norm is summed chunk by
chunk and, once every restart's partial sum has reached eps^2, the iteration cannot stop
and the rest of its chunks skip it (exact, not a bound; with eps = 0 it is never
computed). The fast path of eq. 28 is checked once per iteration: per chunk
sum_j S_j * (1 / S_j), which is NaN where some S is inf or 0; a failed check reruns the
iteration with each chunk checked and, where needed, done the careful way, and later
iterations stay checked. The sums over the clusters are one batched product with ones
(one read of the chunk, no fill).

Two kernels iterate. Where it applies (CPU, float64, m = 2, d <= 8, c <= 16) an
iteration is one fused pass in C (fcm_kernel.c, built once per machine at first use and
loaded by `torchcal.partition._native`; TORCHCAL_FCM_KERNEL=torch turns it off): per eight
points the squared distances, eq. 28 as the product form u_i = q_i / sum_l q_l with
q_i = prod_{k != i} d_k^2 (one division per point; a point on one center gets u = 1 there
exactly), eq. 26, the norm against the previous memberships when eps > 0, and eq. 27's
sums, reading x once and writing nothing but the memberships of the last iteration
(docs/performance.md: 1.8-4.9 ns per point and iteration in 3-D against about 15 for the
eager ops); the first centers from the starting memberships are one such pass too. A pass where some point's sum of products is 0 or inf (a point on two centers,
or products of c - 1 squared distances beyond the float64 range: above about
1e308^(1/(c-1)), 1e77 at c = 5) fails its check, and that iteration and all later ones
run on the eager kernel described above, checked. Everything else (GPUs, float32,
m != 2, `memberships`, `objective`) is the eager kernel.

Rounding: the results equal eqs. 26-28 to the last bits, not bit for bit any other
implementation (summation order over chunks and within the matrix-vector products; the
fused kernel sums per vector lane, over blocks of 4096 points, then over the blocks);
tests/test_partition.py compares memberships, centers and objective of both kernels with
a plain-numpy implementation of the formulas to 1e-12, and the iteration count exactly.
Among restarts that reach the same minimum, which one is kept depends on those last bits.

Randomness only through an explicit `torch.Generator` seeded with `seed`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch

from torchcal.errors import InputError
from torchcal.partition import _native

__all__ = ["FCMResult", "fcm", "memberships", "objective"]

_BAD_START = "init_u: expected finite, non-negative memberships"
_ZERO_COLUMN = "init_u: some point has all memberships 0; expected each column to sum > 0"


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


def _check_not_identical(xt: torch.Tensor) -> None:
    """xt (d, N), the points as rows of features: InputError if all N points are equal."""
    if all(bool(lo == hi) for lo, hi in map(torch.aminmax, xt)):  # row by row (aminmax(dim=1) is 8x slower)
        raise InputError(
            f"x: all {xt.shape[1]} points are identical ({xt[:, 0].tolist()}); "
            "no partition into clusters is possible, expected at least 2 distinct points")


def _default_chunk(x: torch.Tensor, rc: int) -> int:
    """Points per chunk: on a CPU about 256 KiB per (restarts, c, chunk) float64 buffer
    (32768 memberships), so the scratch buffers of a chunk stay in a core's L2 cache;
    very large on a GPU."""
    if x.device.type == "cpu":
        return max(1024, (1 << 15) // rc)
    return max(1 << 16, (1 << 26) // rc)


# --------------------------------------------------------------------------- kernels
#
# Points travel as chunks ((s, e), rows): rows = (x_k[s:e] for each feature k), and centers
# as columns: cols = (V[..., k, None] for each feature k), each (R, c, 1); both are made
# once (per call, per iteration) so that the per-chunk loop indexes nothing. Chunk scratch
# comes from `_Scratch`, whose views are made once per (restarts, chunk length).

def _columns(V: torch.Tensor) -> list:
    """Centers V (R, c, d) -> [V[..., k, None] (R, c, 1) for each feature k]."""
    return [V[..., k, None] for k in range(V.shape[-1])]


def _chunked(xt: torch.Tensor, chunk: int) -> list:
    """Points xt (d, N) -> [((s, e), (xt[k, s:e] for each k))], chunks of `chunk` points."""
    N = xt.shape[1]
    return [((s, min(s + chunk, N)), xt[:, s:s + chunk].unbind(0)) for s in range(0, N, chunk)]


class _Scratch:
    """Chunk scratch for R restarts of c clusters and chunks of at most nmax points: three
    (R, c, n) buffers, two (R, 1, n) ones for the sums over the clusters S and 1/S, ones
    (R, 1, c) (the sums over the clusters as one batched product) and ones (n,) (the row
    sums of eq. 27 as a matrix-vector product). `views(Ra, n)` gives them for Ra <= R
    restarts and n points, made once per (Ra, n)."""

    def __init__(self, R: int, c: int, nmax: int, dtype, device):
        self.c = c
        self.flat = [torch.empty(R * c * nmax, dtype=dtype, device=device) for _ in range(3)]
        self.sums = torch.empty(2, R * nmax, dtype=dtype, device=device)
        self.ones_c = torch.ones(R, 1, c, dtype=dtype, device=device)
        self.ones_n = torch.ones(nmax, dtype=dtype, device=device)
        self._views = {}

    def views(self, R: int, n: int) -> tuple:
        """-> (w, t, t2 (R, c, n), Si, ones_c (R, 1, c), ones_n (n,)); Si = (S, inv (R, 1, n),
        the same flat (R n,))."""
        v = self._views.get((R, n))
        if v is None:
            c = self.c
            S, inv = (b[:R * n] for b in self.sums)
            v = tuple(b[:R * c * n].view(R, c, n) for b in self.flat) + (
                (S.view(R, 1, n), inv.view(R, 1, n), S, inv), self.ones_c[:R], self.ones_n[:n])
            self._views[(R, n)] = v
        return v


def _sq_dist(rows, V: torch.Tensor) -> torch.Tensor:
    """Squared distances of the points of a chunk (rows, as `_chunked`) to centers V (R, c, d)
    -> (R, c, n). Direct differences (no |x|^2 - 2x.v + |v|^2 cancellation), so d = 0 is exact.
    """
    out = torch.empty(V.shape[0], V.shape[1], rows[0].shape[0], dtype=V.dtype, device=V.device)
    return _sq_dist_into(rows, _columns(V), out, torch.empty_like(out))


def _sq_dist_into(rows, cols, out, tmp):
    """out (R, c, n) = squared distances of a chunk's points (rows) to centers (cols); tmp: scratch like out.

    The first feature's (x - v)^2 is one pass (`_sq_diff`: bit for bit the rounded
    difference times itself); each further feature adds (x - v)^2 by a fused multiply-add
    (addcmul)."""
    _sq_diff(rows[0], cols[0], out)  # (R, c, n)
    for xk, vk in zip(rows[1:], cols[1:]):
        torch.sub(xk, vk, out=tmp)
        out.addcmul_(tmp, tmp)
    return out


def _sq_diff(xk: torch.Tensor, vk: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
    """out (R, c, n) = (xk - vk)^2 in one pass: xk (n,) one feature of a chunk's points, vk
    (R, c, 1) the centers'. aten's unreduced `mse_loss` computes (a - b) * (a - b), the
    value of a subtraction followed by a multiplication (9 us against 14 us for the two
    ops on 32768 values); its operands broadcast (expanded to the shape of out it ran 1.6x
    slower)."""
    return torch._C._nn.mse_loss(xk, vk, 0, out=out)  # reduction 0: none


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


def _w_and_S(rows, cols, m, w, t, S, ones_c):
    """The fast path's w = (d^2)^(-1/(m-1)) into w (R, c, n) (t: scratch like w) and
    S = sum_k w into S (R, 1, n) (a batched product with ones_c (R, 1, c): one read of w, no
    fill); returns S. S is inf for a point on a center (w = inf), and 0 or inf where w
    under- or overflows: the caller checks."""
    if len(rows) == 1 and m == 2.0:
        torch.sub(rows[0], cols[0], out=t)
        torch.pow(t, -2, out=w)  # w = 1 / d^2 in one pass
    else:
        _sq_dist_into(rows, cols, w, t)  # d^2
        if m == 2.0:
            w.reciprocal_()
        else:
            w.pow_(-1.0 / (m - 1.0))
    return torch.bmm(ones_c, w, out=S)


def _j_fast(inv, m):
    """This chunk's part of eq. 26, (R,), from inv = 1 / S (R, 1, n): sum_j S_j^(1-m)
    (u^m d^2 = w / S^m, summed over the clusters)."""
    return (inv if m == 2.0 else inv.pow(m - 1.0)).sum(dim=(1, 2))


def _memberships_unchecked(rows, cols, m, w, t, Si, ones_c, checks, out=None):
    """Eq. 28, fast path, for one chunk: memberships into w (R, c, n), or into `out` (same
    shape, may be strided) when given, with t (like w) and Si (as `_Scratch.views`) as
    scratch and ones_c (R, 1, c); appends sum_j S_j * (1 / S_j) to `checks` (finite iff
    every S is finite and > 0: inf * 0 and 0 * inf are NaN; the caller tests them all at
    once). Returns inv = 1 / S (R, 1, n)."""
    S, inv, S_flat, inv_flat = Si
    _w_and_S(rows, cols, m, w, t, S, ones_c)
    torch.reciprocal(S, out=inv)
    checks.append(torch.dot(S_flat, inv_flat))
    if out is None:
        w.mul_(inv)
    else:
        torch.mul(w, inv, out=out)
    return inv


def _memberships_checked(rows, cols, m, w, t, Si, ones_c, want_j):
    """Eq. 28 for one chunk, checked: memberships into w (R, c, n) (t like w, Si as
    `_Scratch.views`: scratch; ones_c (R, 1, c)) by the fast path if every S is finite and
    > 0, else the careful way (`_u_from_sq_dist_`). Returns this chunk's part of eq. 26
    (R,) when want_j, else None. Equal, bit for bit, to `_memberships_unchecked` wherever
    that one passes its check."""
    S, inv = Si[:2]
    torch.reciprocal(_w_and_S(rows, cols, m, w, t, S, ones_c), out=inv)  # (R, 1, n) 1 / S
    lo, hi = torch.aminmax(inv)
    if lo.item() > 0 and hi.item() < math.inf:
        w.mul_(inv)
        return _j_fast(inv, m) if want_j else None
    _sq_dist_into(rows, cols, w, t)  # careful path for this chunk
    d2 = w.clone()
    _u_from_sq_dist_(w, m)
    return (w.pow(m) * d2).sum(dim=(1, 2)) if want_j else None


def _accumulate(acc, um, rows, ones):
    """acc (d+1, Rc) += [um @ x_k for each feature k; row sums of um]; um (Rc, n), rows as
    `_chunked`, ones (n,)."""
    for a, xk in zip(acc, rows):
        a.addmv_(um, xk)
    acc[-1].addmv_(um, ones)


def _row_dots(t: torch.Tensor) -> torch.Tensor:
    """(R, k) -> (R,) squared norms of the rows, without a temporary."""
    return torch.stack([torch.dot(row, row) for row in t])


def _start_u(U0c: torch.Tensor, out: torch.Tensor, Si, ones_c) -> torch.Tensor:
    """Starting memberships of one chunk: U0c (R, c, n) with each column divided by its sum,
    into out (R, c, n) (Si, ones_c: scratch as `_Scratch.views`). Raises InputError for a
    column that sums to 0."""
    S = torch.bmm(ones_c, U0c, out=Si[0])  # (R, 1, n) column sums
    if not bool(S.amin() > 0):
        raise InputError(_ZERO_COLUMN)
    return torch.div(U0c, S, out=out)


def _pass(chunks, V, V_prev, U0, m, eps, last, scratch, checked, out_u=None):
    """One FCM iteration over all points, chunk by chunk; no (c, N) tensor is written.

    chunks: as `_chunked`; V (R, c, d) the centers; V_prev (R, c, d) those of the previous
    iteration, or None in the first, where U0 (R, c, N) (the starting memberships, columns
    not yet normalised: `_start_u`) stands for U(V_prev); last: whether this is the last
    allowed iteration; scratch: a `_Scratch`; checked: every chunk checked on its own
    (`_memberships_checked`), else all at once at the end; out_u: None, or (when R = 1 in
    the last allowed iteration) a (c, N) tensor that receives the memberships U(V), and
    then no sums for the next centers are made (acc stays 0).
    Returns (diff2 (R,), J (R,), acc (d+1, R*c)): ||U(V) - U(V_prev)||_F^2, eq. 26 for
    (U(V), V), and [sum_j u^m x_j ; sum_j u^m] for the next centers (eq. 27); or None when
    unchecked and some chunk failed its check (the caller runs the pass again, checked).

    The stopping rule ||U(V) - U(V_prev)|| < eps is evaluated exactly, lazily: the squared
    norm is summed chunk by chunk, and once every restart's partial sum has a square root
    >= eps (the sum only grows) none of them can stop in this iteration, so the remaining
    chunks skip the old memberships (recomputed from V_prev: the values the previous
    iteration had), the norm and J. diff2 is then a partial sum and J incomplete; neither
    is used. With eps = 0 no restart can stop before max_iter: no norm is computed.
    """
    R, c, d = V.shape
    Rc = R * c
    cols = _columns(V)
    cols_prev = None if V_prev is None else _columns(V_prev)
    acc = torch.zeros(d + 1, Rc, dtype=V.dtype, device=V.device)
    acc_rows = acc.unbind(0)
    diff2 = torch.zeros(R, dtype=V.dtype, device=V.device)
    J = torch.zeros(R, dtype=V.dtype, device=V.device)
    checks = []
    undecided = eps > 0  # some restart's ||dU|| may still turn out < eps
    square = m == 2.0
    for (s, e), rows in chunks:
        w, t, t2, Si, ones_c, ones_n = scratch.views(R, e - s)
        want_j = undecided or last
        u = w if out_u is None else out_u[None, :, s:e]  # where the memberships go
        if checked:
            Jc = _memberships_checked(rows, cols, m, w, t, Si, ones_c, want_j)
            if out_u is not None:
                u.copy_(w)
        else:
            inv = _memberships_unchecked(rows, cols, m, w, t, Si, ones_c, checks,
                                         out=None if out_u is None else u)
            Jc = _j_fast(inv, m) if want_j else None
        if Jc is not None:
            J += Jc
        if undecided:
            if cols_prev is None:
                _start_u(U0[..., s:e], t2, Si, ones_c)
            elif checked:
                _memberships_checked(rows, cols_prev, m, t2, t, Si, ones_c, False)
            else:
                _memberships_unchecked(rows, cols_prev, m, t2, t, Si, ones_c, checks)
            diff2 += _row_dots(torch.sub(t2, u, out=t).view(R, c * (e - s)))
            undecided = any(math.sqrt(v) < eps for v in diff2.tolist())
        if out_u is None:
            um = torch.mul(w, w, out=t) if square else torch.pow(w, m, out=t)
            _accumulate(acc_rows, um.view(Rc, e - s), rows, ones_n)
    if not checked and not bool(torch.isfinite(torch.stack(checks)).all() & torch.isfinite(acc).all()):
        return None
    return diff2, J, acc


def _final_memberships(chunks, V, m, scratch, N):
    """Eq. 28 for centers V (1, c, d) over all points -> (c, N), written straight into the
    result (the fast path, checked once at the end; the careful way for a chunk only where
    some S fails: `_memberships_checked`)."""
    c = V.shape[1]
    U = torch.empty(c, N, dtype=V.dtype, device=V.device)
    cols = _columns(V)
    checks = []
    for (s, e), rows in chunks:
        w, t, _, Si, ones_c, _ = scratch.views(1, e - s)
        _memberships_unchecked(rows, cols, m, w, t, Si, ones_c, checks, out=U[None, :, s:e])
    if not bool(torch.isfinite(torch.stack(checks)).all()):
        for (s, e), rows in chunks:
            w, t, _, Si, ones_c, _ = scratch.views(1, e - s)
            _memberships_checked(rows, cols, m, w, t, Si, ones_c, False)
            U[:, s:e] = w[0]
    return U


def _iterate(xt, U0, m, eps, max_iter, chunk):
    """Run FCM from memberships U0 (R, c, N) (each column is divided by its sum: `_start_u`).
    Returns (J, U (c, N), V (c, d), n_iter) of the restart with the lowest objective (first
    of ties), V being the centers its U was computed from. The returned U is computed from V
    (eq. 28: the values its last iteration had) during that iteration when it was the last
    allowed one and one restart was left, else at the end.
    """
    R, c, N = U0.shape
    chunks = _chunked(xt, chunk)
    scratch = _Scratch(R, c, chunks[0][0][1], xt.dtype, xt.device)
    fused = _fused_kernel(xt, m, c)
    V = None if fused is None else _fused_start(fused, xt, U0)
    if V is None:
        V = _start_centers(chunks, U0, m, scratch)  # (R, c, d)
    d = V.shape[-1]
    V_prev = None
    checked = False  # becomes True for good once a pass fails its check
    ids = list(range(R))  # restart id of each row of V
    best = None
    U_last = None  # memberships of the last allowed iteration when one restart is left
    for it in range(1, max_iter + 1):
        Ra = len(ids)
        last = it == max_iter
        if last and Ra == 1:
            U_last = torch.empty(c, N, dtype=xt.dtype, device=xt.device)
        if checked:
            out = None
        elif fused is not None:
            out = _fused_pass(fused, xt, V, V_prev, U0 if eps > 0 else None, eps > 0, U_last)
        else:
            out = _pass(chunks, V, V_prev, U0, m, eps, last, scratch, False, U_last)
        if out is None:
            checked = True
            out = _pass(chunks, V, V_prev, U0, m, eps, last, scratch, True, U_last)
        diff2, J, acc = out
        U0 = None  # the starting memberships are needed in the first iteration only
        done = ((diff2.sqrt() < eps) | (it == max_iter)).tolist()
        Jl = J.tolist()
        for j in range(Ra):
            if done[j] and (best is None or (Jl[j], ids[j]) < best[:2]):
                best = (Jl[j], ids[j], V[j].clone(), it)
        keep = [j for j in range(Ra) if not done[j]]
        if not keep:
            break
        V_prev, V = V, (acc[:d] / acc[d:]).T.reshape(Ra, c, d)  # eq. 27
        if len(keep) < Ra:
            kt = torch.tensor(keep, device=xt.device)
            V, V_prev = V.index_select(0, kt), V_prev.index_select(0, kt)
            ids = [ids[j] for j in keep]
    J, _, V_best, n_iter = best
    if U_last is not None and n_iter == max_iter:  # the kept restart is the one U_last is of
        return J, U_last, V_best, n_iter
    if fused is not None:
        U = torch.empty(c, N, dtype=xt.dtype, device=xt.device)
        if _fused_pass(fused, xt, V_best[None], None, None, False, U) is not None:
            return J, U, V_best, n_iter
    return J, _final_memberships(chunks, V_best[None], m, scratch, N), V_best, n_iter


def _fused_kernel(xt: torch.Tensor, m: float, c: int):
    """The compiled fused kernels (`torchcal.partition._native`: a ctypes library) when they
    apply to points xt (d, N): CPU, float64, m = 2, d and c within the kernel's limits;
    else None."""
    if xt.device.type != "cpu" or xt.dtype != torch.float64 or m != 2.0:
        return None
    if xt.shape[0] > _native.DMAX or c > _native.CMAX:
        return None
    return _native.kernel()


def _fused_start(lib, xt, U0) -> torch.Tensor | None:
    """Eq. 27 from the starting memberships U0 (R, c, N) (columns not normalised) by the
    compiled kernel (`fcm_start_m2`): points xt (d, N) contiguous -> centers (R, c, d), or
    None where a sum is not finite (the caller then starts the eager way). Raises InputError
    as `_start_centers` for a negative, NaN or inf value (first) or a column that sums to 0."""
    R, c, N = U0.shape
    d = xt.shape[0]
    na = (d + 1) * c
    U0 = U0.contiguous()
    out = torch.empty(R, na + 2, dtype=xt.dtype)
    for r in range(R):
        lib.fcm_start_m2(xt.data_ptr(), N, d, c, U0[r].data_ptr(), out[r].data_ptr())
    if bool((out[:, na] > 0).any()):
        raise InputError(_BAD_START)
    if bool((out[:, na + 1] > 0).any()):
        raise InputError(_ZERO_COLUMN)
    acc = out[:, :na].view(R, d + 1, c)
    if not bool(torch.isfinite(acc).all()):
        return None
    return (acc[:, :d] / acc[:, d:]).transpose(1, 2).contiguous()  # (R, c, d)


def _fused_pass(lib, xt, V, V_prev, U0, want_diff, out_u):
    """One FCM iteration (m = 2) by the compiled kernel (`fcm_pass_m2`), restart by restart:
    points xt (d, N) contiguous, centers V (R, c, d), V_prev (R, c, d) or None, U0 (R, c, N)
    (the starting memberships, columns not normalised) or None; want_diff: sum
    ||U(V) - U(prev)||^2 (prev: V_prev, else U0); out_u: None or (c, N) (R = 1) that
    receives U(V), and then no sums for eq. 27 are made. Returns (diff2 (R,), J (R,), acc (d+1, R*c)) as `_pass`, or None when
    some point failed the kernel's check (S = 0 or inf: a point on two centers, products that
    under- or overflow) or a sum is not finite: the caller redoes the iteration checked.
    diff2 is 0 unless want_diff."""
    R, c, d = V.shape
    N = xt.shape[1]
    na = (d + 1) * c
    out = torch.empty(R, na + 3, dtype=xt.dtype)
    V = V.contiguous()
    V_prev = V_prev.contiguous() if (want_diff and V_prev is not None) else None
    U0 = U0.contiguous() if (want_diff and V_prev is None and U0 is not None) else None
    for r in range(R):
        lib.fcm_pass_m2(xt.data_ptr(), N, d, c, V[r].data_ptr(), 0 if V_prev is None else V_prev[r].data_ptr(),
                        0 if U0 is None else U0[r].data_ptr(), 0 if out_u is None else out_u.data_ptr(),
                        out[r].data_ptr())
    if not bool(torch.isfinite(out).all()):
        return None
    acc = out[:, :na].view(R, d + 1, c).transpose(0, 1).reshape(d + 1, R * c)
    return out[:, na + 1], out[:, na], acc


def _start_centers(chunks, U0: torch.Tensor, m: float, scratch: _Scratch) -> torch.Tensor:
    """Eq. 27 from the starting memberships: points in chunks (as `_chunked`), U0 (R, c, N)
    (columns normalised chunk by chunk: `_start_u`) -> centers (R, c, d). Raises InputError
    where U0 holds a negative value, NaN or inf (checked chunk by chunk, while it is read)."""
    d = len(chunks[0][1])
    R, c, _ = U0.shape
    acc = torch.zeros(d + 1, R * c, dtype=U0.dtype, device=U0.device)
    for (s, e), rows in chunks:
        w, t, _, Si, ones_c, ones = scratch.views(R, e - s)
        lo, hi = torch.aminmax(U0[..., s:e])
        if not bool((lo >= 0) & (hi < math.inf)):
            raise InputError(_BAD_START)
        u = _start_u(U0[..., s:e], w, Si, ones_c)
        um = torch.mul(u, u, out=t) if m == 2.0 else torch.pow(u, m, out=t)
        _accumulate(acc.unbind(0), um.view(R * c, e - s), rows, ones)
    return (acc[:d] / acc[d:]).T.reshape(R, c, d)


def _objective(xt, U, V, m, chunk) -> torch.Tensor:
    """Eq. 26 per restart: xt (d, N), U (R, c, N), V (R, c, d) -> (R,)."""
    J = torch.zeros(U.shape[0], dtype=U.dtype, device=U.device)
    for (s, e), rows in _chunked(xt, chunk):
        J += (U[:, :, s:e].pow(m) * _sq_dist(rows, V)).sum(dim=(1, 2))
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
        chunk_size: points per streamed chunk of the eager kernel (default: about 256 KiB
            of memberships per chunk on a CPU, 64 Mi memberships on a GPU; the fused C
            kernel streams its own 4096-point blocks). Results do not depend on it beyond
            rounding (which, among restarts that reach the same minimum, can change the
            one kept).

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
    xt = x.T.contiguous()  # (d, N)
    _check_not_identical(xt)
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

    J, U_best, V_best, n_iter = _iterate(xt, U, m, float(eps), int(max_iter), chunk)
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
    return U  # values are checked and columns normalised chunk by chunk (_start_centers)


def memberships(x, centers, m: float = 2.0) -> torch.Tensor:
    """Eq. 28 for given centers: x (N,) or (N, d), centers (c, d) -> (c, N).

    A point on a center gets membership 1 there (split equally among coinciding centers).
    """
    x = as_points(x)
    centers = _as_centers(centers, x)
    if not float(m) > 1:
        raise InputError(f"m: expected a fuzzifier m > 1, got {m!r}")
    xt = x.T.contiguous()  # (d, N)
    out = [_u_from_sq_dist_(_sq_dist(rows, centers[None]), float(m))[0]
           for _, rows in _chunked(xt, _default_chunk(x, centers.shape[0]))]
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
