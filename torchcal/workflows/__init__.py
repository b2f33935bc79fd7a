"""Workflows that chain the library: calibration per zone, and the paper's experiment
(configuration, experiment, report).
"""

from torchcal._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "torchcal.workflows.paper_config": ["MAIN_METHODS", "METHODS", "DemoConfig"],
    "torchcal.workflows.paper_experiment": ["MoveErrors", "PipelineResult", "build_virtual_robot", "error_intervals",
                                            "make_partition", "measured_sweep", "r_set_table", "run_demo",
                                            "run_pipeline", "sample_in_zones"],
    "torchcal.workflows.paper_report": ["DemoRun", "fit_json", "reduction_percent"],
    "torchcal.workflows.zone_calibration": ["ZONE_METHODS", "calibrate", "fit_zones"],
})
