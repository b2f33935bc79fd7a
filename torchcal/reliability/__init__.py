"""Interval reliability: interval arithmetic, the reliability index R_set, joint-clearance
uncertainty and the workspace sweep of the paper.

`torchcal.reliability.sweep.sweep` is reached through its module (it shares its name)."""

from torchcal.reliability.interval import Interval, linear_hull, sample_hull
from torchcal.reliability.rset import eta, interference, r_set
from torchcal.reliability.sweep import SweepResult, Workspace, linear_bounds, sample_workspace
from torchcal.reliability.uncertainty import (ClearanceModel, clearance_from_dict, deviation_map, sample_deviations,
                                              sample_states, states_to_deviations)

__all__ = ["Interval", "linear_hull", "sample_hull", "eta", "interference", "r_set", "SweepResult", "Workspace",
           "linear_bounds", "sample_workspace", "ClearanceModel", "clearance_from_dict", "deviation_map",
           "sample_deviations", "sample_states", "states_to_deviations"]
