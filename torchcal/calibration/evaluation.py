"""The errors of a fitted model on measurements (``torchcal evaluate``): `Evaluation`.

Distance errors measured - model (the residual stage's correction subtracted when the model
has one), their summary (`torchcal.metrics.error_summary`), the orientation error when the
data carry rx, ry, rz and the model was fitted to orientations, and the rows outside the
calibrated joint range (`torchcal.calibration.joint_range`). Data that cannot come from
the model are refused first (`torchcal.calibration.checks.model_data.check_measurements`).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import torch

from torchcal.calibration.fit import FitResult
from torchcal.errors import InputError
from torchcal.measurements import Measurements


@dataclass(frozen=True)
class Evaluation:
    """Distance errors measured - model: n rows; rms_mm, mean_mm, max_mm; per_axis_rms_mm
    [x, y, z]; orientation_rms_deg when the data carry rx, ry, rz and the model was fitted
    to orientations (else None); outside_range: rows whose commanded q lie outside the
    joint range the model was calibrated on (`torchcal.calibration.joint_range`), None
    when the model does not record it (a MODEL.json written before it existed).

    Per row (not in `to_dict`): residuals_mm (N, 3) measured - model; orientation_deg
    (N,) orientation error angle, deg (None as for orientation_rms_deg); outside (N,)
    bool, the row lies outside the calibrated range (None as for outside_range)."""

    n: int
    rms_mm: float
    mean_mm: float
    max_mm: float
    per_axis_rms_mm: list
    orientation_rms_deg: float | None = None
    outside_range: int | None = None
    residuals_mm: torch.Tensor | None = field(default=None, compare=False, repr=False)
    orientation_deg: torch.Tensor | None = field(default=None, compare=False, repr=False)
    outside: torch.Tensor | None = field(default=None, compare=False, repr=False)
    p95_mm: float | None = None

    def to_dict(self) -> dict:
        """{"n", "rms_mm", "mean_mm", "p95_mm", "max_mm", "per_axis_rms_mm"[, "orientation_rms_deg"]
        [, "outside_range"]}: the JSON of ``torchcal evaluate --json`` (`torchcal.metrics.error_summary`)."""
        out = {"n": self.n, "rms_mm": self.rms_mm, "mean_mm": self.mean_mm, "p95_mm": self.p95_mm,
               "max_mm": self.max_mm, "per_axis_rms_mm": list(self.per_axis_rms_mm)}
        if self.orientation_rms_deg is not None:
            out["orientation_rms_deg"] = self.orientation_rms_deg
        if self.outside_range is not None:
            out["outside_range"] = self.outside_range
        return out


def evaluate(fm: FitResult, m: Measurements, stacklevel: int = 1) -> Evaluation:
    """Errors of the fitted model `fm` on measurements `m` (module doc): InputError for data
    that cannot come from the model (another robot, a moved measuring frame, units); one
    `CalibratedRangeWarning` (at `stacklevel`, counted from the caller) for rows outside
    the calibrated range, one `ConditionRangeWarning` for rows at a temperature / payload
    outside the range the model was fitted on (`fm.conditions`), one `PayloadAssumedWarning`
    for data without payload_kg given to a model fitted on loads
    (`torchcal.calibration.checks.ranges.payload_conditions`). Rows of one point that fit far
    better with a tool offset of their own, or of several points with their ids read
    otherwise (`torchcal.calibration.checks.model_data.moved_tool`, `swapped_points`): one
    `ReflectorWarning`; else with a measuring frame of their own (`moved_frame`, a motion
    within the gross-mismatch bound): one
    `MismatchWarning`. Data of a point id the model was not fitted on
    (`torchcal.calibration.checks.model_data.point_ids_differ`): InputError for a model with one tool
    offset per point, else one `PointIdWarning`. Orientations (rx, ry, rz) that disagree
    with the nominal tool (`torchcal.calibration.checks.orientation.orientation_mismatch`): one
    `MismatchWarning` naming the reading that fits. A per-zone model: rows whose nominal TCP
    lies beyond its partition's swept region (their zone is extrapolated) named in one
    `MismatchWarning` (`torchcal.calibration.checks.partition.warn_far_from_sweep`)."""
    from torchcal.calibration.joint_range import outside_range
    from torchcal.calibration.registration import FAR_FACTOR
    from torchcal.calibration.checks.model_data import (PointIdWarning, ReflectorWarning, check_measurements,
                                                        moved_frame, moved_tool, point_ids_differ, swapped_points)
    from torchcal.calibration.checks.orientation import orientation_mismatch
    from torchcal.calibration.checks.partition import warn_far_from_sweep
    from torchcal.calibration.checks.ranges import payload_conditions, warn_outside_conditions, warn_outside_range
    from torchcal.calibration.checks.conditions import check_conditions
    from torchcal.calibration.checks.verdict import MismatchWarning, enforce
    from torchcal.effects import context_of
    from torchcal.metrics import error_summary
    from torchcal.rotations import so3_error

    cm = fm.model
    other = point_ids_differ(cm, m)
    if other is not None and cm.points:  # one tool offset per point: none for this one
        raise InputError(other)
    if other is not None:
        warnings.warn(other, PointIdWarning, stacklevel=stacklevel + 1)
    check_conditions(cm, m)  # a missing column (temp_c), naming the file
    ctx = context_of(cm.robot, m)
    theta = fm.theta.to(m.xyz)
    enforce(check_measurements(cm, theta, m, fm.training_rms_mm, q_range=fm.q_range))  # another robot, frame, units
    stage = fm.residual_model
    err = m.xyz - fm.predict(ctx)  # (N, 3) mm (each row in its zone); minus the residual stage's correction
    if stage is not None:
        err = err - stage.predict(m.q).to(err)
    fig = error_summary(err)
    train, tool = fm.training_rms_mm, None
    far = other is None and train is not None and fig["rms_mm"] > FAR_FACTOR * train  # far above training: why?
    if far and (m.point is None or len(set(m.point.tolist())) == 1):  # one point, not named: its own tool?
        tool = moved_tool(fig["rms_mm"], err, cm.predict_rotation(theta, ctx), train, m.source or "data")
    elif far:  # several points: their ids swapped?
        tool = swapped_points(fm, m, fig["rms_mm"], stage)
    if tool is not None:
        warnings.warn(tool, ReflectorWarning, stacklevel=stacklevel + 1)
    if far and tool is None:  # the instrument moved a little since the fit?
        frame = moved_frame(fig["rms_mm"], err, m.xyz, fm.training_rms_mm, m.source or "data")
        if frame is not None:
            warnings.warn(frame, MismatchWarning, stacklevel=stacklevel + 1)
    orient = orient_rows = None
    tool_r = fm.tool_rotation
    bad_rotations = orientation_mismatch(cm, m)  # rx, ry, rz in another unit or convention
    if bad_rotations is not None:
        warnings.warn(bad_rotations, MismatchWarning, stacklevel=stacklevel + 1)
    if m.rxyz is not None and tool_r is not None:
        e = so3_error(cm.predict_rotation(theta, ctx) @ tool_r.to(theta), m.rotation)  # (N, 3) rad
        orient = math.degrees(float(e.norm(dim=-1).pow(2).mean().sqrt()))
        orient_rows = torch.rad2deg(e.norm(dim=-1)).detach()
    partition = getattr(fm, "partition", None)  # a per-zone model: rows beyond the swept region, zone extrapolated
    if partition is not None:
        warn_far_from_sweep(partition, cm.robot.fk(m.q).detach(), m.source or "data", stacklevel=stacklevel + 1)
    ranges = payload_conditions(fm, m.payload_kg, m.source or "data", "evaluated at", stacklevel=stacklevel + 1)
    warn_outside_conditions(ranges, {"temp_c": ctx.temp_c, "payload_kg": ctx.payload_kg}, "rows",
                            stacklevel=stacklevel + 1)
    q_range = fm.q_range
    outside = rows_out = None
    if q_range is not None:
        outside = warn_outside_range(m.q, q_range, cm.robot, "rows", stage, stacklevel=stacklevel + 1)
        rows_out = outside_range(m.q, q_range, cm.robot.prismatic).any(dim=-1)
    return Evaluation(len(m), fig["rms_mm"], fig["mean_mm"], fig["max_mm"], [fig["axes"][a]["rms_mm"] for a in "xyz"],
                      orient, outside, err.detach(), orient_rows, rows_out, fig["p95_mm"])
