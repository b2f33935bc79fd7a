"""Units named from the spread (torchcal.calibration.checks.units): a gross mismatch whose
spread ratio is a unit's factor names the unit and its direction."""

from __future__ import annotations

import dataclasses

import pytest
import torch

import torchcal
from torchcal.calibration.checks.model_data import check_points
from torchcal.errors import InputError


def test_units_hint_from_the_spread(ur10_fitted):
    _, _, fitted, val = ur10_fitted
    with pytest.raises(InputError, match="points at mm read as metres"):  # numbers 1000x too large
        torchcal.evaluate(fitted, dataclasses.replace(val, xyz=val.xyz * 1000))


@pytest.mark.parametrize("k, cause", [(1e-3, "metres read as mm"), (1000.0, "mm read as metres"),
                                      (1 / 25.4, "inches read as mm")])
def test_units_hint_names_the_direction(k, cause):
    """Measured numbers k times the model's: 1/1000 are metres read as mm, 1000 mm read as
    metres, 1/25.4 inches (the hint had metres and mm the wrong way round)."""
    p = torch.randn(50, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 500
    r = check_points(p, p * k, training_rms_mm=0.1)
    assert r.verdict == "mismatch" and f"points at {cause}" in r.message
