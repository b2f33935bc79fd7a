"""Robust row weights (torchcal.calibration.robust) against the textbook definitions.

Huber's weight is psi(u) / u of Huber's loss with threshold k: 1 inside |u| <= k,
k / |u| outside; Cauchy's is 1 / (1 + (u / k)^2); u is the distance residual over its
median, k = 2.5. The references are written here from those formulas, in numpy."""

import numpy as np
import pytest
import torch

from torchcal.calibration.robust import ROBUST_K, inliers, robust_weights
from torchcal.errors import InputError


def _dist(u, median=0.4):
    """Distance residuals whose median is `median` and whose ratios to it are u."""
    u = np.asarray(u, dtype=float)
    assert np.median(u) == 1.0
    return torch.as_tensor(u * median)


# points inside, at and outside the threshold 2.5, the median (1.0) in the middle
U = [0.0, 0.2, 0.3, 0.5, 1.0, 1.0, 1.0, 2.4, 2.5, 2.6, 4.0, 10.0, 100.0]


def huber_reference(u, k=2.5):
    """psi(u) / u for Huber's rho(u) = u^2 / 2 (|u| <= k), k |u| - k^2 / 2 beyond."""
    psi = np.where(np.abs(u) <= k, u, k * np.sign(u))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(u == 0, 1.0, psi / u)


def test_the_threshold_is_two_and_a_half_medians():
    assert ROBUST_K == 2.5


def test_huber_weight_matches_the_textbook_definition():
    w = robust_weights(_dist(U), "huber").numpy()
    np.testing.assert_allclose(w, huber_reference(np.array(U)), rtol=1e-15)
    # spelled out at a point inside and two outside
    assert w[7] == 1.0 and w[8] == 1.0 and w[9] == pytest.approx(2.5 / 2.6) and w[-1] == pytest.approx(0.025)


def test_cauchy_weight_matches_the_textbook_definition():
    u = np.array(U)
    w = robust_weights(_dist(U), "cauchy").numpy()
    np.testing.assert_allclose(w, 1.0 / (1.0 + (u / 2.5) ** 2), rtol=1e-15)
    assert w[8] == pytest.approx(0.5)  # at the threshold, half weight


def test_weights_do_not_depend_on_the_unit_of_the_residual():
    for kind in ("huber", "cauchy"):
        np.testing.assert_allclose(robust_weights(_dist(U, 0.01), kind).numpy(),
                                   robust_weights(_dist(U, 7.0), kind).numpy(), rtol=1e-14)


def test_inliers_are_the_rows_within_the_threshold():
    assert inliers(_dist(U)).tolist() == [x <= 2.5 for x in U]


def test_unknown_loss_is_refused_in_words():
    with pytest.raises(InputError, match="unknown loss 'l1'"):
        robust_weights(_dist(U), "l1")
