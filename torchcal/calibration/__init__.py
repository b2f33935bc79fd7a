"""Calibration: the model (geometry + effects), its fit, covariance, plausibility checks,
interval identification per zone and compensation.

The functions named like their module (`fit.fit`, `compensate.compensate`) are reached
through the module (``torchcal.calibration.fit.fit``) or, with forgiving inputs, as
`torchcal.fit` / `torchcal.compensate`.
"""

from torchcal._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "torchcal.calibration.accuracy": ["Accuracy", "calibrated_box", "joint1_frame", "predicted_sigma", "region_names", "workspace_accuracy"],
    "torchcal.calibration.batched": ["batched_jacobian", "batched_predict"],
    "torchcal.calibration.compensate": ["Compensation", "nominal_inverse", "nominal_start", "predict_rows",
                                        "measuring_from_base", "frame_model", "FRAMES", "with_stage",
                                        "compensate_fitted", "TargetCompensation", "compensate_targets"],
    "torchcal.calibration.covariance": ["ParameterCovariance", "parameter_covariance", "row_covariance",
                                        "tcp_covariance", "tcp_sigma"],
    "torchcal.calibration.evaluation": ["Evaluation"],
    "torchcal.calibration.fit": ["SIGMA_DEG", "SIGMA_MM", "FitResult"],
    "torchcal.calibration.identifiability": ["Identifiability", "identifiability"],
    "torchcal.calibration.geometry_only": ["FOLDED", "GeometryRefit", "calibrated_robot", "geometry_model",
                                           "refit_geometry"],
    "torchcal.calibration.gcv": ["DampingWarning", "GCV_GRID", "choose_damping", "gcv_damping"],
    "torchcal.calibration.intervals": ["PoseIntervals", "identify_intervals", "identify_zones", "parameter_intervals",
                                       "pose_intervals", "solution_map"],
    "torchcal.calibration.joint_range": ["CalibratedRangeWarning", "joint_range", "outside_range"],
    "torchcal.calibration.lm": ["LMResult", "LMStatus", "levenberg_marquardt"],
    "torchcal.calibration.model": ["CalibrationModel"],
    "torchcal.calibration.checks.ranges": ["range_warning", "warn_outside_range"],
    "torchcal.calibration.checks.robot_data": ["check_robot_data_of", "check_diagnosis_data"],
    "torchcal.calibration.checks.units": ["check_units"],
    "torchcal.calibration.new_setup": ["register_model"],
    "torchcal.calibration.plausibility": ["MAX_ANGLE_DEG", "MAX_LENGTH_MM", "PlausibilityWarning", "beyond_plausible",
                                          "beyond_words", "plausible_scales"],
    "torchcal.calibration.prior": ["prior_factors", "prior_strength"],
    "torchcal.calibration.registration": ["base_frame_summary", "register_frame"],
    "torchcal.calibration.robust": ["ROBUST_K", "inliers", "robust_weights"],
    "torchcal.calibration.rows": ["Rows", "so3_error_jacobian", "tool_rotation"],
    "torchcal.calibration.zone_calibration": ["ZONE_METHODS", "ZonedFit", "calibrate", "fit_zones"],
})
