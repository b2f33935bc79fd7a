"""The determined-by-the-data rule (torchcal.calibration.plausibility.undetermined): a
parameter is set by the prior when its posterior sd is at least half its plausible
scale (the data then carry less than three times the prior's information), beyond its
plausible size when |value| exceeds the scale; set_by_prior applies the same rule to a
fit's parameters."""

import math

import pytest
import torch

from torchcal.calibration.plausibility import DETERMINED_RATIO, set_by_prior, undetermined


def test_half_the_scale_separates_measured_from_set_by_the_prior():
    assert DETERMINED_RATIO == 0.5
    s = math.radians(0.1)
    assert undetermined(0.0, 0.49 * s, s) is None
    assert undetermined(0.0, 0.51 * s, s) == "prior"
    # posterior variance 1 / (data + prior information), prior information 1 / s^2: at the
    # threshold the data carry exactly three times the prior's
    data_info = 1 / (0.5 * s) ** 2 - 1 / s ** 2
    assert data_info == pytest.approx(3 / s ** 2)


def test_beyond_the_plausible_size():
    assert undetermined(1.01, 0.1, 1.0) == "beyond" and undetermined(-1.01, 0.1, 1.0) == "beyond"
    assert undetermined(0.99, 0.1, 1.0) is None
    assert undetermined(5.0, 0.6, 1.0) == "prior"  # set by the prior is said first


class _Model:
    def param_names(self):
        return ["a", "b", "c", "frame"]


def test_set_by_prior_names_the_free_parameters_with_a_wide_posterior():
    scales = torch.tensor([1.0, 1.0, 1.0, math.inf], dtype=torch.float64)
    std = torch.tensor([0.49, 0.5, 0.9, 100.0], dtype=torch.float64)
    free = torch.tensor([True, True, False, True])
    assert set_by_prior(_Model(), std, free, scales) == ["b"]
