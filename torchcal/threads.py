"""The thread policy: how many CPU threads torch uses, and how idle ones wait.

Measured on the 2-core development machine (docs/performance.md): torch's intra-op
threads and numpy's / scipy's BLAS threads meet at a barrier at the end of every
parallel op. With other processes on the cores a 2-thread op waits for a descheduled
partner, and torchcal's ops are small (a fit of a few thousand rows, the demo's zone
fits and candidate screens): there a second intra-op thread costs more at its barriers
than it saves: one seed of `torchcal demo` took 37.1 s wall with torch's default 2
threads and 21.5 s on one (quiet machine). The policy:

- ``OMP_WAIT_POLICY=PASSIVE``: idle OpenMP threads sleep instead of spinning. OpenMP
  reads it once, when torch loads, so `torchcal/__init__.py` sets it (``setdefault``:
  the environment wins) before anything imports torch; a program that imports torch
  before torchcal should set it itself.
- One intra-op thread: `apply` (the command line, the public API) sets torch's thread
  count and numpy's / scipy's BLAS (threadpoolctl) to 1. The cores are used by
  *workers* instead: the large kernels (perturbed FK `Robot.fk`, the sweeps) cut their
  batch into chunks and hand them one at a time to `workers()` Python threads, each
  with one torch thread; they meet once, at the end, not at every op.
- Threads by problem size: `for_work(elements)` runs a block with one intra-op thread
  per `ELEMENTS_PER_THREAD` elements of its largest tensors, at most `workers()` (a fit
  of a hundred thousand rows gets them all; one of a few thousand keeps one).
- ``TORCHCAL_THREADS=N``: the number of cores torchcal uses (`workers`); without it,
  the cores this process may run on.
- The heap (glibc, `heap_policy`): blocks below 16 MiB from the heap, whose top is given
  back to the system only beyond 32 MiB free. A fit's Jacobians and residuals are
  temporaries of a few MiB each, allocated and freed hundreds of times: with glibc's
  defaults each came from fresh pages (about 3 000 page faults per Jacobian and residual
  of a 1 664-row fit with orientations: 11.2 -> 8.3 ms CPU with this policy, the same
  peak RSS; `discover` on UR10 series C's training split about 7 % less CPU,
  docs/performance.md). Not applied where the environment sets any ``MALLOC_*``
  variable (the user's choice), nor where the C library has no ``mallopt``.

The command line, the public API (`torchcal.api`) and the test suite use this module.
"""

from __future__ import annotations

import os
from contextlib import contextmanager

#: elements of a block's largest tensors per extra thread: below this a second thread
#: costs more at its barriers than it saves (measured, docs/performance.md)
ELEMENTS_PER_THREAD = 1 << 20

_limits = None  # threadpoolctl's process-wide BLAS limit, once `apply` has run


def env_threads() -> int | None:
    """TORCHCAL_THREADS as a positive int, or None when unset or not a positive int."""
    text = os.environ.get("TORCHCAL_THREADS", "").strip()
    return int(text) if text.isdigit() and int(text) > 0 else None


def workers() -> int:
    """Cores torchcal uses for chunked kernels: TORCHCAL_THREADS, else the CPUs this
    process may run on (its affinity mask, not the machine's count)."""
    n = env_threads()
    if n is not None:
        return n
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # no affinity call on this platform
        return max(1, os.cpu_count() or 1)


#: glibc's mallopt parameters (malloc.h) and the values `heap_policy` sets
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD_BYTES = 16 << 20
TRIM_THRESHOLD_BYTES = 32 << 20


def heap_policy() -> bool:
    """Set the heap policy of the module doc (glibc's ``mallopt``: M_MMAP_THRESHOLD 16 MiB,
    M_TRIM_THRESHOLD 32 MiB); False where it was not set (another C library, or a
    ``MALLOC_*`` variable in the environment). Setting them turns glibc's own adaptive
    thresholds off, which on this workload did not keep the pages (measured, module doc)."""
    import sys

    if not sys.platform.startswith("linux") or any(k.startswith("MALLOC_") for k in os.environ):
        return False
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and \
        bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))


def apply() -> None:
    """Once per process: torch and numpy's / scipy's BLAS on one intra-op thread (the
    cores go to `workers`; `for_work` raises the count for large blocks)."""
    global _limits
    if _limits is not None:
        return
    import torch
    from threadpoolctl import threadpool_limits

    torch.set_num_threads(1)
    _limits = threadpool_limits(limits=1)
    heap_policy()


def apply_importing() -> None:
    """`apply`, which imports torch, with the cyclic garbage collector off, then what the
    import made frozen (`gc.freeze`): torch's import leaves about 170 000 objects that live
    until the process ends, and every full collection after it, the ones at interpreter
    exit included, would scan them again: 0.4-0.5 s of CPU in a `torchcal fit` of 1.3 s
    (docs/performance.md). The start of the command line (`torchcal.cli.main`) and of the
    processes of `torchcal demo` and `torchcal sweep --processes` (their pools' initializer). Only where this call imports torch: a process that already has
    it (the test suite, a program calling `torchcal.cli.main`) keeps its collector as it is."""
    import gc
    import sys

    if "torch" in sys.modules:
        apply()
        return
    enabled = gc.isenabled()
    gc.disable()
    try:
        apply()
    finally:
        gc.freeze()
        if enabled:
            gc.enable()


def dask_setup(worker) -> None:
    """Dask's preload hook (``preload=["torchcal.threads"]``, `torchcal.workflows.distributed.connect`'s
    local cluster): a worker process starts by `apply_importing`, as the processes of
    `torchcal sweep --processes` do, before a task's unpickling imports torch with the
    collector on; importing this module first also sets OMP_WAIT_POLICY before torch loads."""
    apply_importing()


def threads_for(elements: int, available: int) -> int:
    """Threads for a block whose largest tensors hold `elements` elements: one per
    `ELEMENTS_PER_THREAD`, between 1 and `available`."""
    return max(1, min(int(available), int(elements) // ELEMENTS_PER_THREAD))


@contextmanager
def for_work(elements: int):
    """Run the block with `threads_for(elements, workers())` intra-op threads: torch's,
    and those of numpy's and scipy's BLAS / LAPACK (threadpoolctl), whose threads
    busy-wait too (measured: a 1 664-row fit took 1.0 s with torch on one thread and
    scipy's QR on two, 0.07 s with both on one). Restores the counts after."""
    import torch
    from threadpoolctl import threadpool_limits

    before = torch.get_num_threads()
    n = threads_for(elements, workers())
    with threadpool_limits(limits=n):
        if n != before:
            torch.set_num_threads(n)
        try:
            yield n
        finally:
            if n != before:
                torch.set_num_threads(before)
