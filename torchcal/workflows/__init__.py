"""Workflows that chain the library: calibration per zone, and the paper's experiment
(configuration, experiment, report)."""

from torchcal.workflows.paper_config import MAIN_METHODS, METHODS, DemoConfig
from torchcal.workflows.paper_experiment import (MoveErrors, PipelineResult, build_virtual_robot, error_intervals,
                                                 make_partition, measured_sweep, r_set_table, run_demo, run_pipeline,
                                                 sample_in_zones)
from torchcal.workflows.paper_report import DemoRun, fit_json, reduction_percent
from torchcal.workflows.zone_calibration import ZONE_METHODS, calibrate, fit_zones

__all__ = ["MAIN_METHODS", "METHODS", "DemoConfig", "MoveErrors", "PipelineResult", "build_virtual_robot",
           "error_intervals", "make_partition", "measured_sweep", "r_set_table", "run_demo", "run_pipeline",
           "sample_in_zones", "DemoRun", "fit_json", "reduction_percent", "ZONE_METHODS", "calibrate", "fit_zones"]
