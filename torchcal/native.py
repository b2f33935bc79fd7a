"""C kernels compiled on this machine at first use and loaded with ctypes (`load`).

Used by the fused kernels of `torchcal.partition` (fcm_kernel.c) and `torchcal.kinematics`
(fk_kernel.c); each keeps its eager torch kernel as the reference and as the path for
GPUs, autograd and a machine without a C compiler, where `load` returns None.

A source is built once per machine with the C compiler found as $CC, `cc` or `gcc`
(-O3 -march=native: vector code for this CPU) into the user's cache folder
($TORCHCAL_CACHE, else $XDG_CACHE_HOME/torchcal, else ~/.cache/torchcal), named by the
source's stem and a hash of the source, the compiler (path, size and date), the flags and
the CPU's feature flags, so that a cache shared by different machines never loads code
built for another CPU. It is written to a temporary name and renamed, so concurrent first
uses do not see half a file. 0.4 s (fk_kernel.c) to 3 s (fcm_kernel.c) of CPU, once. Each kernel has an
environment switch (`switch`): set to ``torch``, the kernel is not loaded and the eager
code runs.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
from pathlib import Path

FLAGS = ["-O3", "-march=native", "-fno-math-errno", "-shared", "-fPIC"]


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


def cache_dir() -> Path:
    """$TORCHCAL_CACHE, else $XDG_CACHE_HOME/torchcal, else ~/.cache/torchcal."""
    root = os.environ.get("TORCHCAL_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "torchcal")
    return Path(root)


def _flags() -> list:
    flags = list(FLAGS)
    if platform.machine().lower() in ("x86_64", "amd64"):
        flags.insert(2, "-mprefer-vector-width=512")  # 512-bit registers where AVX-512 is there
    return flags


def _build(cc: str, flags: list, source: Path, out: Path) -> None:
    """Compile `source` into `out`, atomically (a temporary file in the same folder, renamed)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=".so", dir=out.parent)
    os.close(fd)
    try:
        subprocess.run([cc, *flags, str(source), "-o", tmp], check=True, capture_output=True, timeout=120)
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def load(source: Path, switch: str) -> ctypes.CDLL | None:
    """The shared library of the C file `source` (built into `cache_dir()` if not there), or
    None: the environment variable `switch` is ``torch`` (any case), no compiler, a failed
    build or load. Not cached: the caller keeps the library (one build per process)."""
    if os.environ.get(switch, "").lower() == "torch":
        return None
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if not cc:
        return None
    flags = _flags()
    source = Path(source).resolve()
    try:
        st = os.stat(shutil.which(cc) or cc)  # the compiler's identity without running it
        key = hashlib.sha256("\0".join([source.read_text(), cc, str(st.st_size), str(st.st_mtime_ns), *flags,
                                         _cpu_flags()]).encode()).hexdigest()
        path = cache_dir() / f"{source.stem}-{key[:20]}.so"
        if not path.exists():
            _build(cc, flags, source, path)
        return ctypes.CDLL(str(path))
    except (OSError, subprocess.SubprocessError):
        return None
