"""The thread policy: how many CPU threads torch uses, and how idle ones wait.

Measured on the 2-core development machine (docs/performance.md): torch's OpenMP threads
spin at every barrier by default, so with other processes on the cores a 2-thread op
waits for a descheduled partner, and small problems (a fit, `discover`) ran 10-20x
slower than on a quiet machine. The policy:

- ``OMP_WAIT_POLICY=PASSIVE``: idle OpenMP threads sleep instead of spinning. OpenMP
  reads it once, when torch loads, so `torchcal/__init__.py` sets it (``setdefault``:
  the environment wins) before anything imports torch; a program that imports torch
  before torchcal should set it itself.
- Threads by problem size: `for_work(elements)` runs a block with one thread per
  `ELEMENTS_PER_THREAD` elements of its largest tensors, at most the current count, for
  torch and for numpy's / scipy's BLAS (threadpoolctl).
  The fit, `diagnose` and `discover` of a few thousand poses get one thread (their
  tensors are too small for a second to pay for its barrier); large FK sweeps keep all.
- ``TORCHCAL_THREADS=N`` sets torch's thread count when torchcal's public API is first
  used (`apply`); without it torch's default (the cores, or ``OMP_NUM_THREADS``) stays.

The command line, the public API (`torchcal.api`) and the test suite use this module.
"""

from __future__ import annotations

import os
from contextlib import contextmanager

#: elements of a block's largest tensors per extra thread: below this a second thread
#: costs more at its barriers than it saves (measured, docs/performance.md)
ELEMENTS_PER_THREAD = 1 << 20

_applied = False


def env_threads() -> int | None:
    """TORCHCAL_THREADS as a positive int, or None when unset or not a positive int."""
    text = os.environ.get("TORCHCAL_THREADS", "").strip()
    return int(text) if text.isdigit() and int(text) > 0 else None


def apply() -> None:
    """Once per process: TORCHCAL_THREADS (when set) becomes torch's thread count."""
    global _applied
    if _applied:
        return
    _applied = True
    n = env_threads()
    if n is not None:
        import torch

        torch.set_num_threads(n)


def threads_for(elements: int, available: int) -> int:
    """Threads for a block whose largest tensors hold `elements` elements: one per
    `ELEMENTS_PER_THREAD`, between 1 and `available`."""
    return max(1, min(int(available), int(elements) // ELEMENTS_PER_THREAD))


@contextmanager
def for_work(elements: int):
    """Run the block with `threads_for(elements)` threads (never more than torch has
    now): torch's, and those of numpy's and scipy's BLAS / LAPACK (threadpoolctl), whose
    threads busy-wait too (measured: a 1 664-row fit took 1.0 s with torch on one thread
    and scipy's QR on two, 0.07 s with both on one). Restores the counts after."""
    import torch
    from threadpoolctl import threadpool_limits

    before = torch.get_num_threads()
    n = threads_for(elements, before)
    with threadpool_limits(limits=n):
        if n != before:
            torch.set_num_threads(n)
        try:
            yield n
        finally:
            if n != before:
                torch.set_num_threads(before)
