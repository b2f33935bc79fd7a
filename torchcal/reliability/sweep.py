"""Workspace sweep: interval envelopes of the TCP error and their reliability.

docs/paper.md section 6, "Latin hypercube sample of the workspace, repeated simulated moves to
each point, distance-error interval per point, R_set":

1. `sample_workspace`: a Latin hypercube (scipy.stats.qmc.LatinHypercube's points, explicit seed)
   of joint space inside the robot's limits, filtered by a `Workspace` (TCP above the
   floor, outside the base column, within reach); rounds of fresh hypercubes are drawn
   until N points pass, and the first N are kept. The sweep draws its points in blocks
   of `block` points (default DEFAULT_BLOCK), block b from its own seed
   (`torchcal.reliability.sweep_blocks`: 
   block 0 from `seed` itself, so a sweep of at most one block is the plain hypercube of
   `seed`); a block is then a function of (seed, b) alone, and a sweep computed block by
   block anywhere (`torchcal.workflows.distributed.sweep_block`) equals the in-process
   one bit for bit, whatever the number of workers.
2. M perturbed parameter sets: clearance states of a `ClearanceModel` turned into MD-H
   deviations (torchcal.reliability.uncertainty), the same M sets for every point (common random
   numbers: the envelope is a deterministic function of q for a given seed).
3. For every point the TCP error e = p(q, deviations) - p(q) of every set, by the
   backward position recursion of torchcal.kinematics.mdh run in place on (points x sets)
   blocks of at most `chunk` evaluations (7 fixed buffers per worker thread); min and
   max per axis and of |e| are reduced on the fly, so memory stays O(chunk + N) and an
   N x M x 3 tensor never exists. Point blocks are shared among `threads` workers.
   On a CPU in float64 or float32 the compiled kernel does this instead where it is built
   (`torchcal.kinematics.fk_native.error_extremes`, fk_kernel.c: one pass per (point, set)
   in registers, the extremes reduced on the fly; TORCHCAL_FK_KERNEL=torch turns it off);
   it agrees with the eager kernel to rounding (1e-12 mm in float64).
   With ``include_nominal`` (default) the zero-deviation
   state (every shaft centerd) belongs to the set, so each axis interval contains 0 and
   the distance interval is [0, s^u] as in the paper's Table 3. (The states form a
   connected set containing the nominal one, so every value between 0 and the largest
   distance is attained: [0, s^u] is the exact range of the sampled maximum.)
4. The linearised bound: `torchcal.reliability.interval.linear_hull` of the deviation box
   (`ClearanceModel.box`) through the parameter Jacobian (eq. 18) per point; the
   linearised distance bound is the farthest corner of that error box. The sampled
   envelope lies inside it up to second-order terms; the box ignores the correlations
   between deviations (one seat moves several of them), so it is wider, by the factor
   `SweepResult.linear_ratio` reports.
5. ``bounds="worst"`` (not the paper's; `torchcal.reliability.worst_case`): the bounds over
   the whole clearance set instead of the M sampled states, to first order: per axis the
   exact range (joined with the sampled one), the distance upper bound by coordinate ascent
   from the best sampled state (the larger of it and the sampled one, so never below that),
   and beside it `dist_upper_outer`, a guaranteed first-order upper bound (triangle
   inequality): the true worst case lies in [dist_upper, dist_upper_outer]. eta, R_set
   (and the linear ratio) are then those of these bounds. Needs the clearance model and
   the nominal state in the set (include_nominal: the lower bound stays 0).
6. eta (eq. 23) and R_set (eq. 24) of the distance interval for an allowed distance
   error [0, D] (torchcal.reliability.rset; eta with the upper limit only, see there), and,
   optionally, per axis for an allowed +-a.

Default simulated KR 1000 Titan (torchcal.reliability.uncertainty.ClearanceModel.defaults: docs/paper.md
Table 2 clearances, bearing length = shaft diameter, 200, 137, 99, 75.6, 60, 50 mm): at
D = 2.5 mm, 100 points x 300 sets (seed 0) give R_set from 0.72 to 1, about half the
points at 1, as in the paper's Table 3 (0.685 .. 1).

Units: q rad (mm for a prismatic joint) inside, degrees (mm) in the CSV (`torchcal.io.sweep_csv`
writes and reads it); positions and errors mm. Every tensor stays on `device`.
"""

from __future__ import annotations

import math
import os
import sys
import threading
import warnings
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, fields, replace

import numpy as np
import torch
from tqdm import tqdm

from torchcal import threads as policy
from torchcal.kinematics import fk_native
from torchcal.kinematics import mdh as K
from torchcal.reliability import rset as reliability
from torchcal.errors import InputError
from torchcal.reliability.interval import Interval, linear_hull
from torchcal.reliability.uncertainty import ClearanceModel, sample_deviations
from torchcal.reliability.sweep_blocks import DEFAULT_BLOCK, block_points, block_range
from torchcal.reliability.worst_case import ClearanceSet, check_bounds, clearance_set, worst_extremes
from torchcal.robots.workspace import Workspace


def _l2_chunk(l2_bytes: int | None, buffers: int = 7, lo: int = 1 << 12, hi: int = 1 << 16) -> int:
    """(point, set) evaluations per CPU kernel call for a core's L2 cache of `l2_bytes`: the
    largest power of two whose `buffers` float64 buffers fit in it, within [lo, hi];
    16384 where the size is unknown (None)."""
    if not l2_bytes:
        return 1 << 14
    n = lo
    while n * 2 <= hi and n * 2 * 8 * buffers <= l2_bytes:
        n *= 2
    return n


def _l2_bytes(path: str = "/sys/devices/system/cpu/cpu0/cache") -> int | None:
    """Size of cpu0's level-2 data or unified cache in bytes from Linux's sysfs; None where
    it cannot be read (other systems)."""
    try:
        for idx in sorted(os.listdir(path)):
            d = os.path.join(path, idx)
            with open(os.path.join(d, "level")) as fh:
                level = fh.read().strip()
            with open(os.path.join(d, "type")) as fh:
                kind = fh.read().strip()
            if level == "2" and kind in ("Data", "Unified"):
                with open(os.path.join(d, "size")) as fh:
                    size = fh.read().strip().upper()
                unit = {"K": 1 << 10, "M": 1 << 20}.get(size[-1:], 1)
                return int(size.rstrip("KM")) * unit
    except (OSError, ValueError):
        return None
    return None


# (point, set) evaluations per kernel call: on a CPU the 7 buffers fill (not spill) a core's
# L2 cache (32768 with 2 MiB of L2, 16384 with 1 MiB; each op runs on one core: the CPU
# sweep sets torch's intra-op threads to 1, its own workers use the cores); on a GPU large
# enough to fill it. Results do not depend on it.
DEFAULT_CHUNK = _l2_chunk(_l2_bytes())
DEFAULT_CHUNK_GPU = 1 << 22
@dataclass(frozen=True, eq=False)
class SweepResult:
    """Per workspace point: TCP error envelopes and reliability (N points, n joints).

    Attributes:
        q: (N, n) joint values, rad (revolute) / mm (prismatic).
        positions: (N, 3) mm nominal TCP positions.
        err_lower, err_upper: (N, 3) mm bounds of the error e = perturbed - nominal per axis.
        dist_lower, dist_upper: (N,) mm bounds of |e|.
        eta: (N,) eq. 23 of the distance interval vs the allowed distance error.
        r_set: (N,) eq. 24, the same.
        lin_lower, lin_upper: (N, 3) mm linearised hull of the error (None if not computed
            or read from a CSV: `torchcal.io.sweep_csv`).
        lin_dist_upper: (N,) mm farthest corner of the linearised error box (or None).
        allowed_mm: the allowed distance error D (None if unknown).
        n_samples: M, number of perturbed parameter sets (None if unknown).
        r_set_axis, eta_axis: (N, 3) per axis against an allowed +-a (None unless asked).
        point: (N,) int64 point ids (None: the row index 0..N-1, as the CSV writes them).
        prismatic: (n,) bool prismatic joints, whose q is mm (in the CSV too), not an
            angle (None: all revolute).
        robot: the nominal `Robot` swept (as `sweep` was given it), which the sweep CSV
            records (`torchcal.io.sweep_csv`); None where unknown.
        bounds: "sampled" (extremes over the M states, the paper's) or "worst" (over the
            whole clearance set, `torchcal.reliability.worst_case`): what err_*, dist_*,
            eta and r_set are.
        dist_upper_outer: (N,) mm with bounds "worst": a guaranteed first-order upper bound
            of |e| (never below dist_upper); None otherwise.
    """

    q: torch.Tensor
    positions: torch.Tensor
    err_lower: torch.Tensor
    err_upper: torch.Tensor
    dist_lower: torch.Tensor
    dist_upper: torch.Tensor
    eta: torch.Tensor
    r_set: torch.Tensor
    lin_lower: torch.Tensor | None = None
    lin_upper: torch.Tensor | None = None
    lin_dist_upper: torch.Tensor | None = None
    allowed_mm: float | None = None
    n_samples: int | None = None
    r_set_axis: torch.Tensor | None = None
    eta_axis: torch.Tensor | None = None
    point: torch.Tensor | None = None
    prismatic: torch.Tensor | None = None
    robot: object = None
    bounds: str = "sampled"
    dist_upper_outer: torch.Tensor | None = None

    def __len__(self) -> int:
        return self.q.shape[0]

    @property
    def err(self) -> Interval:
        """Interval (N, 3) of the sampled error per axis (mm)."""
        return Interval(self.err_lower, self.err_upper)

    @property
    def dist(self) -> Interval:
        """Interval (N,) of the sampled distance error (mm)."""
        return Interval(self.dist_lower, self.dist_upper)

    @property
    def linear(self) -> Interval | None:
        """Interval (N, 3) of the linearised hull (mm), or None."""
        return None if self.lin_lower is None else Interval(self.lin_lower, self.lin_upper)

    def linear_ratio(self) -> torch.Tensor | None:
        """(N, 3) sampled half-width / linearised half-width per axis (<= 1 up to 2nd order)."""
        if self.lin_lower is None:
            return None
        return (self.err_upper - self.err_lower) / (self.lin_upper - self.lin_lower).clamp_min(1e-300)

    def to(self, device) -> "SweepResult":
        kw = {f.name: getattr(self, f.name) for f in fields(self)}
        for k, v in kw.items():
            if isinstance(v, torch.Tensor):
                kw[k] = v.to(device)
        return SweepResult(**kw)

    def summary(self) -> dict:
        """R_set min / median / max, share of points with R_set = 1, linear-hull ratio."""
        r = self.r_set.double().cpu()
        out = {
            "points": len(self),
            "r_set_min": float(r.min()), "r_set_median": float(r.median()), "r_set_max": float(r.max()),
            "share_r_set_1": float((r >= 1.0).double().mean()),
            "dist_upper_min_mm": float(self.dist_upper.min()), "dist_upper_max_mm": float(self.dist_upper.max()),
        }
        ratio = self.linear_ratio()
        if ratio is not None:
            out["linear_ratio_median"] = float(ratio.double().median())
            out["linear_ratio_max"] = float(ratio.double().max())
        return out


def _envelope(robot, q, dev, include_nominal, chunk, bar, threads):
    """Min / max of e and |e| over the sets, chunk by chunk. q (N, n), dev (M, n, 5).
    On a CPU where the compiled kernel is built, `_envelope_native` (about chunk // M points per
    call, a multiple of 16).

    Point chunks are independent: `threads` Python workers take them in turn (each op
    on a chunk of <= 32768 elements runs on one core, so the workers do not fight over
    the cores the way intra-op threads of large ops do on a busy machine).
    """
    chain = robot.chain.to(q)
    N, M = q.shape[0], dev.shape[0]
    R = chain.base[:3, :3]
    rotate = not torch.equal(R, torch.eye(3, dtype=R.dtype, device=R.device))
    # nominal positions of all points in one call (element-wise per point: the same values
    # as chunk by chunk), not one call of the general kernel per chunk of a few points
    nominal = K.positions(q, chain.local, tool_point=chain.tool[:3, 3])  # (N, 3), joint-1 frame
    lib = fk_native.available(q.device, q.dtype)
    if lib is not None:
        step = fk_native.PAD * max(1, chunk // M // fk_native.PAD)  # whole vectors of points
        return _envelope_native(lib, chain, q, dev, nominal, R if rotate else None, include_nominal, step, bar,
                                threads)
    F = K.outer_factors(chain, dev)
    e_lo = torch.empty(N, 3, dtype=q.dtype, device=q.device)
    e_hi = torch.empty_like(e_lo)
    d_lo = torch.empty(N, dtype=q.dtype, device=q.device)
    d_hi = torch.empty_like(d_lo)
    m_step = min(M, chunk)
    n_step = max(1, chunk // m_step)
    local = threading.local()
    # the per-joint rows of the factors, per block of sets, made once: outer_positions only
    # indexes them by joint (F[k][i]), and indexing a tuple is no torch op (a select is one,
    # some 100 per kernel call otherwise); the same tensors, so the same results
    set_blocks = [(b0, min(M, b0 + m_step), [f[:, b0:b0 + m_step].unbind(0) for f in F]) for b0 in range(0, M, m_step)]

    def work(a0):
        bufs = getattr(local, "bufs", None)
        if bufs is None:
            bufs = local.bufs = [torch.empty(n_step, m_step, dtype=q.dtype, device=q.device) for _ in range(7)]
            local.views = {}  # (points, sets) -> the 7 buffers' views, made once per shape
        a1 = min(N, a0 + n_step)
        qc = q[a0:a1]
        nom = nominal[a0:a1]  # (Nc, 3)
        angles = K.outer_angles(qc, chain)
        lo = hi = dlo = dhi = None
        for b0, b1, Fc in set_blocks:
            views = local.views.get((a1 - a0, b1 - b0))
            if views is None:
                views = local.views[a1 - a0, b1 - b0] = [t[:a1 - a0, :b1 - b0] for t in bufs]
            ex, ey, ez = K.outer_positions(angles, chain, Fc, views)
            ex.sub_(nom[:, 0:1]), ey.sub_(nom[:, 1:2]), ez.sub_(nom[:, 2:3])
            if rotate:  # error vectors into the world frame
                ex, ey, ez = (R[k, 0] * ex + R[k, 1] * ey + R[k, 2] * ez for k in range(3))
            # (amin and amax, not aminmax: that one is ~10x slower on a CPU and runs
            # intra-op parallel, which stalls on a busy machine)
            clo = torch.stack([e.amin(dim=1) for e in (ex, ey, ez)], dim=1)  # (Nc, 3)
            chi = torch.stack([e.amax(dim=1) for e in (ex, ey, ez)], dim=1)
            sq_d = torch.mul(ex, ex, out=views[0]).addcmul_(ey, ey).addcmul_(ez, ez)  # |e|^2
            cdlo, cdhi = sq_d.amin(dim=1), sq_d.amax(dim=1)
            if lo is None:
                lo, hi, dlo, dhi = clo, chi, cdlo, cdhi
            else:
                lo, hi = torch.minimum(lo, clo), torch.maximum(hi, chi)
                dlo, dhi = torch.minimum(dlo, cdlo), torch.maximum(dhi, cdhi)
        dlo, dhi = dlo.sqrt(), dhi.sqrt()
        if include_nominal:
            lo, hi, dlo = lo.clamp_max(0), hi.clamp_min(0), torch.zeros_like(dlo)
        e_lo[a0:a1], e_hi[a0:a1], d_lo[a0:a1], d_hi[a0:a1] = lo, hi, dlo, dhi
        return a1 - a0

    for done in _map_chunks(work, range(0, N, n_step), threads):
        if bar is not None:
            bar.update(done)
    return e_lo, e_hi, d_lo, d_hi


def _envelope_native(lib, chain, q, dev, nominal, rot, include_nominal, step, bar, threads):
    """`_envelope` by the compiled kernel (`torchcal.kinematics.fk_native.error_extremes`):
    one pass per (point, set) in registers, the extremes reduced on the fly; `threads`
    workers take blocks of `step` points in turn. rot (3, 3) or None: the base rotation."""
    N = q.shape[0]
    pose, link = K.pose_rows(q, chain), K.link_rows(chain, dev)
    lin, _ = K.native_frames(chain)
    rot = None if rot is None else rot.contiguous()
    nominal = fk_native.nominal_rows(nominal)  # (3, N + PAD)
    res = torch.empty(N, 8, dtype=q.dtype)  # min e (3), max e (3), min |e|^2, max |e|^2

    def work(a0):
        a1 = min(N, a0 + step)
        fk_native.error_extremes(lib, pose, link, lin, nominal, rot, a0, a1, res)
        return a1 - a0

    for done in _map_chunks(work, range(0, N, step), threads):
        if bar is not None:
            bar.update(done)
    lo, hi, dlo, dhi = res[:, 0:3], res[:, 3:6], res[:, 6].sqrt(), res[:, 7].sqrt()
    if include_nominal:
        lo, hi, dlo = lo.clamp_max(0), hi.clamp_min(0), torch.zeros_like(dlo)
    return lo.contiguous(), hi.contiguous(), dlo, dhi


def linear_bounds(robot, q: torch.Tensor, dev_box: Interval, chunk: int = 1024, threads: int = 1):
    """Linearised error hull per point: Interval (N, 3) mm and the farthest-corner distance (N,).

    q (N, n) rad, dev_box Interval (n, 5) of MD-H deviations; chunks of `chunk` points
    shared among `threads` workers.
    """
    chain = robot.chain.to(q)
    flat = Interval(dev_box.lower.reshape(-1), dev_box.upper.reshape(-1)).to(q.device, q.dtype)
    N = q.shape[0]
    lo = torch.empty(N, 3, dtype=q.dtype, device=q.device)
    hi, far = torch.empty_like(lo), torch.empty(N, dtype=q.dtype, device=q.device)

    def work(a):
        J = K.param_jacobian(q[a:a + chunk], chain)  # (Nc, 3, 5n)
        h = linear_hull(J, flat)
        lo[a:a + chunk], hi[a:a + chunk] = h.lower, h.upper
        far[a:a + chunk] = torch.maximum(h.lower.abs(), h.upper.abs()).square().sum(-1).sqrt()

    for _ in _map_chunks(work, range(0, N, chunk), threads):
        pass
    return Interval(lo, hi), far


def _map_chunks(fn, starts, threads: int):
    """fn(start) for every start, in order, on `threads` worker threads (inline for 1)."""
    if threads <= 1:
        for a in starts:
            yield fn(a)
        return
    with ThreadPoolExecutor(max_workers=threads) as ex:
        yield from ex.map(fn, starts)


@contextmanager
def _serial_ops(enabled: bool):
    """Run torch ops on one core each while the sweep's own workers share the cores.

    torch.set_num_threads is process-wide: it is set to 1 for the duration of the CPU
    sweep and restored afterwards. Small ops split over intra-op threads (and batched
    4x4 matmuls over BLAS threads) gain nothing and, on a busy machine, stall for
    milliseconds on their barriers; the sweep's workers take the cores instead.
    """
    if not enabled:
        yield
        return
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def sweep(robot, q=None, *, n_points: int = 100, n_samples: int = 300, allowed_mm: float = 2.5,
          seed: int = 0, model: ClearanceModel | None = None, workspace: Workspace | None = None,
          deviations: torch.Tensor | None = None, include_nominal: bool = True, linear: bool = True,
          allowed_axis_mm: float | None = None, chunk: int | None = None, threads: int | None = None,
          block: int = DEFAULT_BLOCK, device=None, dtype=torch.float64, progress: bool = False,
          bounds: str = "sampled"):
    """Sweep the workspace: error envelopes, linearised hull, eta and R_set per point.

    Args:
        robot: a `torchcal.Robot`.
        q: optional (N, n) rad points; default N = n_points points drawn block by block
            (`block_points`: block b from `block_seed(seed, b)`).
        n_points: N when q is None.
        n_samples: M perturbed parameter sets (clearance states), drawn with a
            torch.Generator seeded with `seed`.
        allowed_mm: allowed distance error D: R_set against [0, D], eta against D.
        seed: seeds both the Latin hypercube and the clearance states.
        model: ClearanceModel (default `ClearanceModel.defaults(robot)`).
        workspace: Workspace filter (default `Workspace()`).
        deviations: optional (M, n, 5) deviation sets to use instead of sampling.
        include_nominal: the zero-deviation state is part of the set (see module doc).
        linear: also compute the linearised hull (needs the deviation box: from `model`,
            or the sample hull of `deviations` when those are given without a model).
        allowed_axis_mm: optional allowed +-a (mm) per axis: fills `r_set_axis` and
            `eta_axis` (N, 3) (docs/paper.md Table 5 uses +-1 mm).
        chunk: (point, set) evaluations per kernel call; the working memory is 7 buffers
            of `chunk` floats per thread. Default DEFAULT_CHUNK on a CPU (sized for its L2
            cache: 32768 with 2 MiB a core, 16384 with 1 MiB or where unknown),
            DEFAULT_CHUNK_GPU on a GPU. Results do not depend on it.
        threads: worker threads over point chunks (default: `torchcal.threads.workers()`
            on a CPU, 1 on a GPU). On a CPU torch's own intra-op threads are set to 1 while the
            sweep runs (and restored after): the workers use the cores instead. Results do
            not depend on it.
        block: points per block (default DEFAULT_BLOCK): the points of block b are drawn
            from `block_seed(seed, b)`, so the result depends on `block` (not on chunk,
            threads or on how many machines compute the blocks:
            `torchcal.workflows.distributed.sweep_block`).
        device, dtype: where and in which float type to compute (float64 default).
        progress: tqdm progress bar on stderr (only when stderr is a terminal).
        bounds: "sampled" (default, the paper's: the extremes of the M states) or "worst":
            the extremes over the whole clearance set (module doc, step 5; needs `model`
            or the robot's default one, not `deviations`, and include_nominal).

    Returns:
        SweepResult (tensors on `device`).
    """
    for name, v in (("chunk", chunk), ("threads", threads)):
        if v is not None and (not isinstance(v, int) or v < 1):
            raise InputError(f"{name} must be a positive integer, got {v!r}")
    _check_count(block, "points per block")
    _check_allowed(allowed_mm, allowed_axis_mm)
    check_bounds(bounds)
    if bounds == "worst" and deviations is not None:
        raise InputError("bounds='worst' needs the clearance model the states are drawn from, not deviations")
    device = torch.device(device) if device is not None else robot.device
    rb = robot.to(device, dtype)
    if q is not None:
        q = rb.check_q(q).to(device=device, dtype=dtype)
        if q.ndim != 2:
            raise InputError(f"q: expected workspace points of shape (N, {robot.n}), got {tuple(q.shape)}")
        n_points = q.shape[0]
        _check_count(n_points, "number of workspace points")
    else:
        _check_count(n_points, "number of workspace points")
    deviations, dev_box = sweep_states(robot, n_samples=n_samples, seed=seed, model=model,
                                       deviations=deviations, linear=linear)
    cset = worst_set(robot, bounds, model, deviations, seed, include_nominal)
    deviations = deviations.to(device=device, dtype=dtype)
    gpu = rb.table.device.type != "cpu"
    chunk = chunk or (DEFAULT_CHUNK_GPU if gpu else DEFAULT_CHUNK)
    threads = threads or (1 if gpu else policy.workers())
    parts = []
    with _serial_ops(not gpu):
        with tqdm(total=n_points, unit="pt", desc="sweep", file=sys.stderr, disable=None if progress else True,
                  dynamic_ncols=True) as bar:
            for b in range(-(-n_points // block)):
                a0, a1 = block_range(b, n_points=n_points, block=block)
                if q is None:
                    qb = block_points(robot, b, n_points=n_points, block=block, seed=seed, workspace=workspace)
                    qb = rb.check_q(qb).to(device=device, dtype=dtype)
                else:
                    qb = q[a0:a1]
                parts.append(_sweep_points(rb, qb, deviations, dev_box, include_nominal=include_nominal,
                                           linear=linear, allowed_mm=allowed_mm, allowed_axis_mm=allowed_axis_mm,
                                           chunk=chunk, threads=threads, bar=bar, clearance=cset))
    return replace(parts[0] if len(parts) == 1 else _concat(parts), robot=robot)


def _check_count(v, what: str) -> None:
    if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1:
        raise InputError(f"{what} must be a positive integer, got {v!r}")


def _check_allowed(allowed_mm, allowed_axis_mm) -> None:
    if not (isinstance(allowed_mm, (int, float)) and math.isfinite(allowed_mm) and allowed_mm > 0):
        raise InputError(f"allowed distance error must be a positive number of mm, got {allowed_mm!r}")
    if allowed_axis_mm is not None and not (isinstance(allowed_axis_mm, (int, float))
                                            and math.isfinite(allowed_axis_mm) and allowed_axis_mm > 0):
        raise InputError(f"allowed axis error must be a positive number of mm, got {allowed_axis_mm!r}")


class AllowedErrorWarning(UserWarning):
    """The allowed distance error of a sweep leaves R_set nil or 1 at every point: likely
    in another unit (metres, micrometres)."""


R_SET_NIL = 0.01  # R_set at most this at every point: the allowed error is below every point's bound


def warn_allowed(summary: dict, allowed_mm: float, stacklevel: int = 2) -> None:
    """One `AllowedErrorWarning` when the sweep's R_set (`SweepResult.summary()` keys) is
    at most R_SET_NIL at every point (the allowed error `allowed_mm` far below every
    point's distance bound: metres?) or 1 at every point with the allowed error beyond
    every bound (micrometres?)."""
    lo, hi = summary["dist_upper_min_mm"], summary["dist_upper_max_mm"]
    if summary["r_set_max"] <= R_SET_NIL:
        warnings.warn(f"allowed distance error {allowed_mm:g} mm: R_set is at most {summary['r_set_max']:.3g} at "
                      f"every point (distance error bounds {lo:.4g} .. {hi:.4g} mm): far below every point's bound, "
                      f"no point is near reliable; in metres? ({1000 * allowed_mm:g} mm)", AllowedErrorWarning,
                      stacklevel=stacklevel)
    elif summary["share_r_set_1"] >= 1.0 and allowed_mm > 10 * hi:
        warnings.warn(f"allowed distance error {allowed_mm:g} mm: R_set is 1 at every point (distance error "
                      f"bounds {lo:.4g} .. {hi:.4g} mm), so no partition can tell the points apart; in "
                      f"micrometres? ({allowed_mm / 1000:g} mm)", AllowedErrorWarning, stacklevel=stacklevel)


class SampleCountWarning(UserWarning):
    """A sweep of so few clearance states that its distance-error bounds fall well short of
    what the states allow (`warn_samples`)."""


#: `torchcal sweep --samples` below this warns (`warn_samples`). The sampled bound at a point
#: is the largest |e| of M states, a sample maximum over a 2n-dimensional torus of seat
#: directions, which converges slowly. Measured (benchmarks/study_sweep_samples.py, 200
#: points of the kr1000titan, ur5e and puma560 presets, 5 seeds) against the largest error
#: the states allow (coordinate ascent): the median point's bound lies 21-31 % under it with
#: the default 300 states (12-20 % with 3000), 30-40 % with 50, 36-45 % with 30, 38-51 % with
#: 20 and 65-74 % with 1. Below 50 it is more than 10 points further under than with the
#: default on all three robots (at 50: 1.3, 0.8 and 0.9 points less than that).
MIN_SAMPLES = 50


def warn_samples(n_samples: int, stacklevel: int = 2) -> None:
    """One `SampleCountWarning` when n_samples (M) is below MIN_SAMPLES (figures there).
    The library's `sweep` does not call it (tests and studies sweep a few states on purpose);
    `torchcal sweep` does, before the work."""
    if n_samples < MIN_SAMPLES:
        warnings.warn(f"{n_samples} clearance states are too few for the distance-error bounds: on three "
                      f"robots the median point's bound lies 36-45 % under the largest error the clearance "
                      f"allows with 30 states, 65-74 % with 1, against 21-31 % with the default 300; use "
                      f"{MIN_SAMPLES} or more (docs/scale.md)", SampleCountWarning, stacklevel=stacklevel)


def sweep_states(robot, *, n_samples: int = 300, seed: int = 0, model: ClearanceModel | None = None,
                 deviations: torch.Tensor | None = None, linear: bool = True):
    """The M deviation sets of a sweep and their box: ((M, n, 5) float64 CPU, Interval (n, 5) or None).

    Drawn with a torch.Generator seeded with `seed` from `model` (default
    `ClearanceModel.defaults(robot)`) unless `deviations` are given; the box (None unless
    `linear`) is `model.box(robot)`, or the sample hull of `deviations` given without a model.
    """
    if deviations is None:
        _check_count(n_samples, "number of samples")
        model = ClearanceModel.defaults(robot) if model is None else model
        gen = torch.Generator().manual_seed(int(seed))
        deviations = sample_deviations(robot, model, int(n_samples), gen)
    else:
        deviations = robot.to("cpu", torch.float64).check_params(deviations, "deviations")
        if deviations.ndim != 3:
            raise InputError(f"deviations: expected shape (M, {robot.n}, 5), got {tuple(deviations.shape)}")
    dev_box = None
    if linear:
        dev_box = model.box(robot) if model is not None else Interval(*torch.aminmax(deviations, dim=0))
    return deviations, dev_box


def worst_set(robot, bounds: str, model, deviations, seed: int, include_nominal: bool) -> ClearanceSet | None:
    """The `ClearanceSet` of the sweep states `deviations` (M, n, 5) for bounds "worst"
    (model None: the robot's default), None for "sampled"; one InputError without the
    nominal state (the worst-case lower bound is then not computed)."""
    if check_bounds(bounds) == "sampled":
        return None
    if not include_nominal:
        raise InputError("bounds='worst' keeps the nominal state in the set (include_nominal=True): "
                         "its distance lower bound is 0")
    model = ClearanceModel.defaults(robot) if model is None else model
    return clearance_set(robot, model, deviations, seed)


def _worst(rb, q, deviations, cset: ClearanceSet, threads: int, chunk: int = 2048):
    """`worst_extremes` at the points q (N, n) in chunks of `chunk` points shared among
    `threads` workers: axis (N, 3), ascent (N,), outer (N,) mm."""
    N = q.shape[0]
    axis = torch.empty(N, 3, dtype=q.dtype, device=q.device)
    ascent, outer = torch.empty(N, dtype=q.dtype, device=q.device), torch.empty(N, dtype=q.dtype, device=q.device)

    def work(a):
        J = K.param_jacobian(q[a:a + chunk], rb.chain)  # (Nc, 3, 5n)
        axis[a:a + chunk], ascent[a:a + chunk], outer[a:a + chunk] = worst_extremes(J, deviations, cset)

    for _ in _map_chunks(work, range(0, N, chunk), threads):
        pass
    return axis, ascent, outer


def _sweep_points(rb, q, deviations, dev_box, *, include_nominal, linear, allowed_mm, allowed_axis_mm,
                  chunk, threads, bar, clearance: ClearanceSet | None = None) -> SweepResult:
    """The sweep of the points q (N, n) against deviations (M, n, 5), both on rb's device;
    with `clearance` (`worst_set`) its worst-case bounds (module doc, step 5)."""
    gpu = q.device.type != "cpu"
    lin_lo = lin_hi = lin_far = rs_axis = et_axis = d_out = None
    e_lo, e_hi, d_lo, d_hi = _envelope(rb, q, deviations, include_nominal, chunk, bar, threads)
    if clearance is not None:
        axis, ascent, outer = _worst(rb, q, deviations, clearance, threads, chunk=4096 if gpu else 2048)
        e_lo, e_hi = torch.minimum(e_lo, -axis), torch.maximum(e_hi, axis)
        d_hi = torch.maximum(d_hi, ascent)
        d_out = torch.maximum(outer, d_hi)
    if linear:
        hull, lin_far = linear_bounds(rb, q, dev_box, chunk=1 << 16 if gpu else 1024, threads=threads)
        lin_lo, lin_hi = hull.lower, hull.upper
    positions = K.positions(q, rb.chain)  # (N, 3) mm
    rs, et = torch.empty_like(d_lo), torch.empty_like(d_lo)
    piece = 1 << 16  # in pieces: the temporaries of eta and R_set stay small
    for a in range(0, d_lo.shape[0], piece):
        dist = (d_lo[a:a + piece], d_hi[a:a + piece])
        rs[a:a + piece] = reliability.r_set((0.0, float(allowed_mm)), dist)
        et[a:a + piece] = reliability.eta((None, float(allowed_mm)), dist)
    if allowed_axis_mm is not None:
        a = float(allowed_axis_mm)
        rs_axis = reliability.r_set((-a, a), (e_lo, e_hi))
        et_axis = reliability.eta((-a, a), (e_lo, e_hi))
    return SweepResult(q=q, positions=positions, err_lower=e_lo, err_upper=e_hi, dist_lower=d_lo,
                       dist_upper=d_hi, eta=et, r_set=rs, lin_lower=lin_lo, lin_upper=lin_hi,
                       lin_dist_upper=lin_far, allowed_mm=float(allowed_mm), n_samples=deviations.shape[0],
                       r_set_axis=rs_axis, eta_axis=et_axis, prismatic=rb.prismatic if rb.chain.linear else None,
                       bounds="sampled" if clearance is None else "worst", dist_upper_outer=d_out)


def _concat(parts: list[SweepResult]) -> SweepResult:
    """The rows of several sweeps of the same robot, states and allowed error, in order."""
    kw = {}
    for f in fields(SweepResult):
        v = getattr(parts[0], f.name)
        if isinstance(v, torch.Tensor) and f.name != "prismatic":
            v = torch.cat([getattr(p, f.name) for p in parts])
        kw[f.name] = v
    return SweepResult(**kw)
