"""torchcal: batched, GPU-optional calibration of industrial robots.

Millimetres and degrees at the edges (files, command line, reports); millimetres and
radians inside; float64 by default.
"""

from torchcal.errors import InputError
from torchcal.robots.robot import PRESETS, Robot, robot
from torchcal.api import calibrate, compensate, diagnose, discover, evaluate, fit, register

__version__ = "0.1.0"
__all__ = ["InputError", "PRESETS", "Robot", "robot", "__version__",
           "fit", "evaluate", "diagnose", "discover", "calibrate", "compensate", "register"]
