"""The fused FCM iteration and start of fcm_kernel.c, compiled on this machine at first use
and loaded with ctypes by `torchcal.native` (the build, the cache folder and its naming are
described there); `kernel()` is None where that is not possible or not wanted, and fcm.py
then runs its eager torch kernel (the reference, and the path for GPUs, float32 and m != 2).
TORCHCAL_FCM_KERNEL=torch turns it off (the eager kernel runs); the environment is read at a
process's first FCM call.
"""

from __future__ import annotations

import ctypes
import functools
from pathlib import Path

from torchcal import native

SOURCE = Path(__file__).with_name("fcm_kernel.c")
DMAX, CMAX = 8, 16  # fcm_kernel.c's limits


@functools.lru_cache(maxsize=1)
def kernel():
    """The loaded library (ctypes; its `fcm_pass_m2` and `fcm_start_m2`), or None: turned
    off, no compiler, a failed build or load. Built and loaded at most once per process."""
    lib = native.load(SOURCE, "TORCHCAL_FCM_KERNEL")
    if lib is None:
        return None
    P, i = ctypes.c_void_p, ctypes.c_int
    lib.fcm_pass_m2.argtypes = [P, ctypes.c_long, i, i, P, P, P, P, P]
    lib.fcm_start_m2.argtypes = [P, ctypes.c_long, i, i, P, P]
    lib.fcm_pass_m2.restype = lib.fcm_start_m2.restype = i
    return lib
