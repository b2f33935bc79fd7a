"""The fused FCM iteration and start of fcm_kernel.c, compiled on this machine at first use
and loaded with ctypes; `kernel()` is None where that is not possible or not wanted, and fcm.py then
runs its eager torch kernel (the reference, and the path for GPUs, float32 and m != 2).

The shared library is built once per machine with the C compiler found as $CC, `cc` or
`gcc` (-O3 -march=native: vector code for this CPU) into the user's cache folder
($TORCHCAL_CACHE, else $XDG_CACHE_HOME/torchcal, else ~/.cache/torchcal), named by a hash
of the source, the compiler (path, size and date), the flags and the CPU's feature flags, so that a
cache shared by different machines never loads code built for another CPU. It is written
to a temporary name and renamed, so concurrent first uses do not see half a file. About
2-3 s of CPU, once. TORCHCAL_FCM_KERNEL=torch turns it off (the eager kernel runs); the
environment is read at a process's first FCM call.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
from pathlib import Path

SOURCE = Path(__file__).with_name("fcm_kernel.c")
DMAX, CMAX = 8, 16  # fcm_kernel.c's limits


def _cpu_flags() -> str:
    """The CPU's feature flags (Linux), else the processor's name."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith(("flags", "Features")):
                    return line
    except OSError:
        pass
    return platform.processor()


def _cache_dir() -> Path:
    root = os.environ.get("TORCHCAL_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "torchcal")
    return Path(root)


def _build(cc: str, flags: list, out: Path) -> None:
    """Compile SOURCE into `out`, atomically (a temporary file in the same folder, renamed)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=".so", dir=out.parent)
    os.close(fd)
    try:
        subprocess.run([cc, *flags, str(SOURCE), "-o", tmp], check=True, capture_output=True, timeout=120)
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


@functools.lru_cache(maxsize=1)
def kernel():
    """The loaded library (ctypes; its `fcm_pass_m2` and `fcm_start_m2`), or None: turned
    off, no compiler, a failed build or load. Built and loaded at most once per process."""
    if os.environ.get("TORCHCAL_FCM_KERNEL", "").lower() == "torch":
        return None
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if not cc:
        return None
    flags = ["-O3", "-march=native", "-fno-math-errno", "-shared", "-fPIC"]
    if platform.machine().lower() in ("x86_64", "amd64"):
        flags.insert(2, "-mprefer-vector-width=512")  # one register per 8 points where AVX-512 is there
    try:
        st = os.stat(shutil.which(cc) or cc)  # the compiler's identity without running it
        key = hashlib.sha256("\0".join([SOURCE.read_text(), cc, str(st.st_size), str(st.st_mtime_ns), *flags,
                                         _cpu_flags()]).encode()).hexdigest()
        path = _cache_dir() / f"fcm_kernel-{key[:20]}.so"
        if not path.exists():
            _build(cc, flags, path)
        lib = ctypes.CDLL(str(path))
    except (OSError, subprocess.SubprocessError):
        return None
    P, i = ctypes.c_void_p, ctypes.c_int
    lib.fcm_pass_m2.argtypes = [P, ctypes.c_long, i, i, P, P, P, P, P]
    lib.fcm_start_m2.argtypes = [P, ctypes.c_long, i, i, P, P]
    lib.fcm_pass_m2.restype = lib.fcm_start_m2.restype = i
    return lib
