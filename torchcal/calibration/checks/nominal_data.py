"""Measurements that are the nominal robot itself: `warn_nominal_data`.

A real arm is 0.1 mm to a few mm off its nominal model (data-sheet absolute accuracy, ISO
9283), and a laser tracker reads with noise of 0.005 mm or more. Positions that agree with
the nominal robot (in its best measuring frame when the model has ``base_frame``) to
NOMINAL_FLOOR_MM rms were computed, not measured: typically the controller's own TCP
positions (its forward kinematics of the commanded joints) exported in place of the
tracker's. A fit on them finds the nominal robot, with a tiny rms, and calibrates nothing.
"""

from __future__ import annotations

import math
import warnings

import torch

NOMINAL_FLOOR_MM = 0.01  # rms (mm) of the nominal robot on the data below which they were not measured


class NominalDataWarning(UserWarning):
    """The measured positions are the nominal robot's own to within NOMINAL_FLOOR_MM."""


def nominal_rms_mm(model, m) -> float:
    """RMS distance (mm) between the positions of measurements `m` (`Measurements`) and the
    nominal robot of `model` (`CalibrationModel`, every parameter zero: the robot file's
    tool), after the closed-form rigid motion when the model has ``base_frame``."""
    from torchcal.rotations import kabsch
    from torchcal.effects import context_of

    xyz = m.xyz.detach().to(torch.float64)
    with torch.no_grad():
        p = model.predict(model.zeros().to(xyz), context_of(model.robot, m)).to(xyz)
    if any(e.name == "base_frame" for e in model.effects) and p.shape[0] >= 3:
        R, t = kabsch(p, xyz)
        p = p @ R.T + t
    return math.sqrt(float((p - xyz).pow(2).sum(-1).mean()))


def warn_nominal_data(model, m, stacklevel: int = 1) -> float | None:
    """One `NominalDataWarning` (at `stacklevel`, counted from the caller) when the nominal
    robot of `model` meets the positions of `m` within NOMINAL_FLOOR_MM rms (module doc);
    returns that rms then, else None. Fewer than 6 rows are not judged."""
    if len(m) < 6:
        return None
    rms = nominal_rms_mm(model, m)
    if rms >= NOMINAL_FLOOR_MM:
        return None
    frame = " in its best measuring frame" if any(e.name == "base_frame" for e in model.effects) else ""
    warnings.warn(f"{m.source or 'measurements'}: x, y, z agree with the nominal {model.robot.name}{frame} to rms "
                  f"{rms:.3g} mm over {len(m)} rows, but a real arm is 0.1 mm or more off its nominal model and a "
                  f"tracker reads with noise: positions computed (the controller's TCP, its own forward kinematics) "
                  f"rather than measured? A fit on them finds the nominal robot and calibrates nothing",
                  NominalDataWarning, stacklevel=stacklevel + 1)
    return rms
