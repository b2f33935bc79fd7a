"""Interval reliability: interval arithmetic, the reliability index R_set, joint-clearance
uncertainty and the workspace sweep of the paper.

`torchcal.reliability.sweep.sweep` is reached through its module (it shares its name).
"""

from torchcal._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "torchcal.reliability.interval": ["Interval", "linear_hull", "sample_hull"],
    "torchcal.reliability.rset": ["eta", "interference", "r_set"],
    "torchcal.reliability.sweep": ["SweepResult", "linear_bounds"],
    "torchcal.reliability.sweep_blocks": ["DEFAULT_BLOCK", "block_points", "block_range", "block_seed"],
    "torchcal.reliability.uncertainty": ["ClearanceModel", "clearance_from_dict", "deviation_map",
                                         "sample_deviations", "sample_states", "states_to_deviations"],
    "torchcal.reliability.worst_case": ["BOUNDS", "ClearanceSet", "check_bounds", "clearance_set", "worst_extremes"],
})
