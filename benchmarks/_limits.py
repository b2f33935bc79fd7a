"""The rates a CPU kernel's work is held to, measured in the calling run.

`rates` times a float matmul on `threads` torch threads (flop/s) and one in-place fused
element-wise op (``addcmul_`` with a broadcast operand) on chunk-sized buffers on one
thread, times `threads` workers (element ops/s). A kernel doing F flops and E element ops
per evaluation cannot beat rate / F (compute) nor, as a sequence of eager torch ops,
rate / E (element-wise); the benchmarks print both next to the measured rate.
"""

from __future__ import annotations

import statistics
import timeit

import torch


def _median_s(fn, repeats: int) -> float:
    """Median wall seconds of fn() over `repeats` runs after one warm-up."""
    fn()
    return statistics.median(timeit.repeat(fn, number=1, repeat=repeats))


def rates(dtype, threads: int, chunk: int, repeats: int = 5) -> tuple[float, float]:
    """(matmul flop/s on `threads` torch threads, fused element ops/s: one thread's rate on
    a (3, chunk) buffer times `threads`)."""
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(threads)
        a = torch.randn(1024, 1024, dtype=dtype)
        t_mm = _median_s(lambda: a @ a, repeats)
        torch.set_num_threads(1)
        u = torch.randn(3, max(1, chunk // 64), 64, dtype=dtype)
        col = torch.randn(3, u.shape[1], 1, dtype=dtype)
        z = torch.randn(u.shape[1], 64, dtype=dtype)
        ops = 50
        t_op = _median_s(lambda: [u.addcmul_(col, z) for _ in range(ops)], repeats)
    finally:
        torch.set_num_threads(before)
    return 2 * 1024 ** 3 / t_mm, threads * ops * u.numel() / t_op


def print_limits(rate: float, flops: int, elems: int, dtype, threads: int, chunk: int, repeats: int = 5,
                 unit: str = "pair", label: str = "measured") -> tuple[float, float]:
    """Print the compute and element-wise limits of a kernel measured at `rate` evaluations/s
    (named `label`); returns them (evaluations/s)."""
    mm, op = rates(dtype, threads, chunk, repeats)
    lim_c, lim_e = mm / flops, op / elems
    print(f"  limit, compute: {flops} flops per {unit} at the matmul rate {mm / 1e9:.1f} GFLOP/s "
          f"({threads} threads) = {lim_c / 1e6:.0f} M/s; {label} {rate / 1e6:.1f} M/s = {100 * rate / lim_c:.0f} %")
    print(f"  limit, element-wise: {elems} element ops per {unit} at {op / 1e9:.2f} G/s (one fused op per "
          f"worker, {threads} workers) = {lim_e / 1e6:.0f} M/s; {label} = {100 * rate / lim_e:.0f} %")
    return lim_c, lim_e
