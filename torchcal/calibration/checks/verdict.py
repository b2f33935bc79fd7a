"""What an input check finds (`Mismatch`), the warning for data or targets that do not fit
where the command goes on (`MismatchWarning`), the refusal or warning of a verdict
(`enforce`), and the bounds the checks share.

Plausible bound ``B = max(GROSS_RATIO * training_rms, GROSS_MM)`` (`bound_mm`): held-out
errors a few times the training RMS are ordinary (other poses, another day); an order of
magnitude (GROSS_RATIO = 10) beyond it *and* beyond GROSS_MM = 10 mm, more than an
uncalibrated industrial arm is off by its nominal model (ISO 9283 absolute accuracy of data
sheets: 0.1 to a few mm), cannot come from a model of this robot. Without a training RMS
(a nominal robot) only GROSS_MM applies.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import torch

from torchcal.errors import InputError

GROSS_RATIO = 10.0
GROSS_MM = 10.0
OUTLIER_SHARE = 0.1  # at most this share of rows may be gross outliers (the rest must agree)


class MismatchWarning(UserWarning):
    """Data or targets that do not fit the model, where the command can still go on."""


@dataclass(frozen=True)
class Mismatch:
    """Result of `check_measurements`. rms_mm: model error as is; registered_rms_mm:
    after the best rigid motion; spread_ratio: measured / model spread; bound_mm: the
    plausible bound B; training_rms_mm (None when unknown); frame_mm / frame_deg: the
    rigid motion's translation and rotation angle; verdict: None (consistent), 'frame'
    (a rigid motion explains the data) or 'mismatch' (`check_robot_data` has more);
    message: one line (None when consistent); fix: what corrects it, or None."""

    rms_mm: float
    registered_rms_mm: float
    spread_ratio: float
    bound_mm: float
    training_rms_mm: float | None
    frame_mm: float
    frame_deg: float
    verdict: str | None
    message: str | None
    fix: tuple | None = None  # (keyword, value) of `InputError.fix`


def enforce(result: Mismatch, refuse_frame: bool = True, refuse_mismatch: bool = True) -> Mismatch:
    """Raise InputError (a refusal) or warn `MismatchWarning` (the command goes on) for a
    verdict; nothing when consistent. Returns `result`."""
    if result.verdict is None:
        return result
    refuse = refuse_frame if result.verdict == "frame" else refuse_mismatch
    if refuse:
        raise InputError(result.message, fix=result.fix)
    warnings.warn(result.message, MismatchWarning, stacklevel=3)
    return result


def bound_mm(training_rms_mm: float | None) -> float:
    """The plausible error bound B, mm (module docstring)."""
    if training_rms_mm is None or not math.isfinite(training_rms_mm):
        return GROSS_MM
    return max(GROSS_RATIO * training_rms_mm, GROSS_MM)


def listed(values, most: int = 10) -> str:
    """The first `most` values, comma-separated, with " ..." when there are more (a row or
    id list in a one-line message)."""
    values = list(values)
    return ", ".join(map(str, values[:most])) + (" ..." if len(values) > most else "")


def rms_of(d: torch.Tensor) -> float:
    """Root mean square of the values d (N,) (distances in mm, angles in rad)."""
    return float(d.pow(2).mean().sqrt())
