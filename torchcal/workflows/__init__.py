"""Workflows that chain the library: calibration per zone, the paper's demonstration."""

from torchcal.workflows.zone_calibration import ZONE_METHODS, calibrate, fit_zones

__all__ = ["ZONE_METHODS", "calibrate", "fit_zones"]
