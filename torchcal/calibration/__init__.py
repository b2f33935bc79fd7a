"""Calibration: the model (geometry + effects), its fit, covariance, plausibility checks,
interval identification per zone and compensation.

The functions named like their module (`fit.fit`, `compensate.compensate`) are reached
through the module (``torchcal.calibration.fit.fit``) or, with forgiving inputs, as
`torchcal.fit` / `torchcal.compensate`.
"""

from torchcal.calibration.batched import batched_jacobian, batched_predict
from torchcal.calibration.compensate import Compensation, nominal_inverse, nominal_start, predict_rows
from torchcal.calibration.covariance import ParameterCovariance, parameter_covariance, tcp_covariance, tcp_sigma
from torchcal.calibration.fit import SIGMA_DEG, SIGMA_MM, FitResult, Identifiability, identifiability
from torchcal.calibration.gcv import GCV_GRID, choose_damping, gcv_damping
from torchcal.calibration.intervals import (IntervalFit, IntervalModel, PoseIntervals, identify_intervals,
                                            identify_zones, pose_intervals, solution_map)
from torchcal.calibration.joint_range import CalibratedRangeWarning, joint_range, outside_range, range_warning
from torchcal.calibration.lm import LMResult, LMStatus, levenberg_marquardt
from torchcal.calibration.model import CalibrationModel
from torchcal.calibration.plausibility import MAX_ANGLE_DEG, MAX_LENGTH_MM, beyond_plausible, check_units, plausible_scales
from torchcal.calibration.registration import base_frame_summary, register_frame

__all__ = ["batched_jacobian", "batched_predict", "Compensation", "nominal_inverse", "nominal_start", "predict_rows",
           "ParameterCovariance", "parameter_covariance", "tcp_covariance", "tcp_sigma", "SIGMA_DEG", "SIGMA_MM",
           "FitResult", "Identifiability", "identifiability", "GCV_GRID", "choose_damping", "gcv_damping", "IntervalFit",
           "IntervalModel", "PoseIntervals", "identify_intervals", "identify_zones", "pose_intervals",
           "solution_map", "CalibratedRangeWarning", "joint_range", "outside_range", "range_warning", "LMResult",
           "LMStatus", "levenberg_marquardt", "CalibrationModel", "MAX_ANGLE_DEG", "MAX_LENGTH_MM", "check_units",
           "beyond_plausible", "plausible_scales", "base_frame_summary", "register_frame"]
