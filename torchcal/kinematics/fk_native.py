"""The compiled perturbed-FK kernels of fk_kernel.c: positions of a (pose x parameter set)
grid, and the extremes of the position error over the sets per point (the sweep's envelope),
one pass per pair with everything in registers.

Built at first use and loaded with ctypes by `torchcal.native` (the build, the cache folder
and its naming are described there). `kernel()` is None where that is not possible or not
wanted (TORCHCAL_FK_KERNEL=torch, read at a process's first call; no C compiler), and the
callers run the eager torch kernels instead: `torchcal.kinematics.mdh.positions_into` (the
reference) and `outer_positions`, which also serve GPUs and autograd.

The callers make the factors (`torchcal.kinematics.mdh.pose_rows` and `link_rows`); this
module checks nothing but hands the pointers over and splits the work: pieces of `PIECE`
pairs (positions) or of points (extremes) taken in turn by worker threads, which run in
parallel because ctypes releases the GIL during a call.
"""

from __future__ import annotations

import ctypes
import functools
import math
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import NamedTuple

import torch

from torchcal import native

SOURCE = Path(__file__).with_name("fk_kernel.c")
SWITCH = "TORCHCAL_FK_KERNEL"
#: pairs per kernel call handed to a worker: about a quarter of a millisecond of one core's
#: work in float64, large against the call's overhead (some microseconds), small enough to
#: share the cores evenly
PIECE = 1 << 16
#: values each row of the factors ends in, copies of its last (a vector's lanes at most: the
#: kernel reads whole vectors and keeps the pairs it needs)
PAD = 16
_SUFFIX = {torch.float64: "f64", torch.float32: "f32"}


@functools.lru_cache(maxsize=1)
def kernel():
    """The loaded library (ctypes; `fk_positions_f64/_f32`, `error_extremes_f64/_f32`), or
    None: turned off, no compiler, a failed build or load. Built and loaded at most once per
    process."""
    lib = native.load(SOURCE, SWITCH)
    if lib is None:
        return None
    P, i, n = ctypes.c_void_p, ctypes.c_int, ctypes.c_long
    for s in _SUFFIX.values():
        fk, ext = getattr(lib, f"fk_positions_{s}"), getattr(lib, f"error_extremes_{s}")
        fk.argtypes = [P, n, n, i, P, n, n, i, i, P, P, n, n, n, P]
        ext.argtypes = [P, n, P, n, n, i, P, P, P, n, n, P]
        fk.restype = ext.restype = i
    return lib


def available(device, dtype):
    """The library when it serves tensors of `dtype` on `device` (a CPU, float64 or float32),
    else None."""
    if torch.device(device).type != "cpu" or dtype not in _SUFFIX:
        return None
    return kernel()


class Grid(NamedTuple):
    """A broadcast batch as a grid (A, B) of pairs k = a B + b: pose index a qa + b qv and set
    index a sa + b sv into the flattened pose and set batches (qv, sv: 0 or 1)."""

    A: int
    B: int
    qa: int
    qv: int
    sa: int
    sv: int


def grid(batch, q_batch, p_batch) -> Grid | None:
    """The grid of a broadcast `batch` whose poses have the batch dims `q_batch` and the
    parameter sets `p_batch` (both aligned to `batch`, 1 where they broadcast), with the
    largest inner size B; None where no split of the dims serves (the poses or the sets vary
    in some but not all dims on one side of every split)."""
    dims = [d for d in range(len(batch)) if batch[d] != 1]
    hq = [q_batch[d] != 1 for d in dims]
    hp = [p_batch[d] != 1 for d in dims]
    for s in range(len(dims) + 1):
        sides = []
        for has in (hq, hp):
            lead, trail = has[:s], has[s:]
            if (any(lead) and not all(lead)) or (any(trail) and not all(trail)):
                break
            sides.append((bool(lead) and all(lead), bool(trail) and all(trail)))
        else:
            A = math.prod(batch[d] for d in dims[:s])
            B = math.prod(batch[d] for d in dims[s:])
            (ql, qt), (pl, pt) = sides
            return Grid(A, B, (B if qt else 1) if ql else 0, int(qt), (B if pt else 1) if pl else 0, int(pt))
    return None


def fk_positions(lib, pose, link, lin, base, g: Grid, out, workers: int) -> torch.Tensor:
    """Positions of the grid `g` into out (A B, 3) contiguous, mm. pose (n, 3, Q + PAD) [cos q,
    sin q, travel], link (n + 1, 12, S + PAD) [R_i rows, t_i mm; the start] (rows padded with
    their last value: `torchcal.kinematics.mdh.pose_rows`, `link_rows`), lin (n,) int32 (1:
    prismatic), base (12,) [R_base rows, b mm] or None, all contiguous in out's dtype;
    `workers` threads take pieces of PIECE pairs in turn."""
    fn = getattr(lib, f"fk_positions_{_SUFFIX[out.dtype]}")
    n = pose.shape[0]
    bp = 0 if base is None else base.data_ptr()

    def run(k0):
        if fn(pose.data_ptr(), pose.shape[-1], g.qa, g.qv, link.data_ptr(), link.shape[-1], g.sa, g.sv, n,
              lin.data_ptr(), bp, g.B, k0, min(total, k0 + PIECE), out.data_ptr()):
            raise ValueError(f"fk_kernel.c: no joints (n = {n})")

    total = g.A * g.B
    _spread(run, range(0, total, PIECE), workers)
    return out


def error_extremes(lib, pose, link, lin, nominal, rot, a0: int, a1: int, res) -> None:
    """For the points a0 .. a1 - 1 of pose (n, 3, N + PAD) against every set of link
    (n + 1, 12, M + PAD): res[a] (8,) = min and max of each axis of e = p - nominal[:, a] (then
    turned by rot (3, 3) where given) and min and max of |e|^2 over the M sets (mm, mm^2); p
    in the joint-1 frame. nominal (3, N + PAD) mm, padded like pose (`nominal_rows`), res
    (N, 8); the rest as `fk_positions`."""
    fn = getattr(lib, f"error_extremes_{_SUFFIX[res.dtype]}")
    n = pose.shape[0]
    if fn(pose.data_ptr(), pose.shape[-1], link.data_ptr(), link.shape[-1], link.shape[-1] - PAD, n,
          lin.data_ptr(), nominal.data_ptr(), 0 if rot is None else rot.data_ptr(), a0, a1,
          res.data_ptr()):
        raise ValueError(f"fk_kernel.c: no joints (n = {n})")


def nominal_rows(nominal) -> torch.Tensor:
    """nominal (N, 3) mm -> (3, N + PAD) for `error_extremes`, rows padded with their last value."""
    N = nominal.shape[0]
    out = torch.empty(3, N + PAD, dtype=nominal.dtype, device=nominal.device)
    out[:, :N] = nominal.T
    if N:
        out[:, N:] = out[:, N - 1:N]
    return out


def _spread(fn, items, workers: int) -> None:
    """fn(item) for every item: inline on one worker, else on `workers` threads taking them in turn."""
    workers = min(workers, len(items))
    if workers <= 1:
        for item in items:
            fn(item)
        return
    with ThreadPoolExecutor(workers) as pool:
        for _ in pool.map(fn, items):
            pass
