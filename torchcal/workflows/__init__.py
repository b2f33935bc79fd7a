"""Workflows that chain the library: the paper's experiment
(configuration, experiment, report), and the facts of a calibration report.
"""

from torchcal._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "torchcal.workflows.paper_config": ["MAIN_METHODS", "METHODS", "DemoConfig"],
    "torchcal.workflows.paper_experiment": ["MoveErrors", "PipelineResult", "build_virtual_robot", "error_intervals",
                                            "make_partition", "measured_sweep", "r_set_table", "run_demo",
                                            "run_pipeline", "sample_in_zones"],
    "torchcal.workflows.paper_report": ["DemoRun", "fit_json", "reduction_percent"],
    "torchcal.workflows.report": ["CalibrationReport", "calibration_report", "effect_physics", "file_facts",
                                  "zone_table"],
})
