"""torchcal: batched, GPU-optional calibration of industrial robots.

Millimetres and degrees at the edges (files, command line, reports); millimetres and
radians inside; float64 by default.

Importing torchcal is cheap: the public names (`fit`, `robot`, ...) load torch and the
rest on first use (module ``__getattr__``), so ``torchcal --version`` and ``--help`` start
at once. Before any torch import, torchcal sets ``OMP_WAIT_POLICY=PASSIVE`` unless the
environment sets it (`torchcal.threads`, docs/performance.md).
"""

import os

# OpenMP reads its wait policy once, when torch loads its runtime: this must run first.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"

_LAZY = {
    "InputError": "torchcal.errors",
    "PRESETS": "torchcal.robots.robot",
    "Robot": "torchcal.robots.robot",
    "robot": "torchcal.io.robot_file",
    "calibrate": "torchcal.api",
    "compensate": "torchcal.api",
    "diagnose": "torchcal.api",
    "discover": "torchcal.api",
    "evaluate": "torchcal.api",
    "fit": "torchcal.api",
    "load": "torchcal.api",
    "save": "torchcal.api",
    "register": "torchcal.api",
}
__all__ = ["InputError", "PRESETS", "Robot", "robot", "__version__",
           "fit", "load", "save", "evaluate", "diagnose", "discover", "calibrate", "compensate", "register"]


def __getattr__(name):
    """The public names, imported on first use (PEP 562)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'torchcal' has no attribute {name!r}")
    import importlib

    from torchcal import threads

    threads.apply()
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
