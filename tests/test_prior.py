"""The plausibility prior's rows (torchcal.calibration.prior): row i is
``rho * theta_i / s_i``, i.e. the prior theta_i ~ N(0, s_i^2) for rows of per-axis
scale rho, rho the per-axis RMS of the fit's own (inlier) residual."""

import math

import numpy as np
import pytest
import torch

from torchcal.calibration.prior import RHO_EXACT, RHO_RTOL, prior_factors, prior_strength, rho_settled


def test_prior_rows_weigh_rho_over_the_scale():
    scales = torch.tensor([5.0, math.radians(1.0), math.inf, 0.25], dtype=torch.float64)
    f = prior_factors(0.03, scales).numpy()
    np.testing.assert_allclose(f, [0.03 / 5.0, 0.03 / math.radians(1.0), 0.0, 0.03 / 0.25], rtol=1e-15)
    # the prior's information in the fit's row units is rho^2 / s^2: a parameter at one
    # plausible scale costs as much as one row of one rho
    theta = scales.clone()
    theta[2] = 123.0  # no scale: no prior
    np.testing.assert_allclose((f * theta.numpy()) ** 2, [0.03 ** 2, 0.03 ** 2, 0.0, 0.03 ** 2], rtol=1e-14)


def test_prior_strength_is_the_per_axis_rms():
    rng = np.random.default_rng(4)
    r = rng.normal(scale=0.05, size=(200, 3))
    assert prior_strength(torch.from_numpy(r)) == pytest.approx(np.sqrt((r ** 2).mean()), rel=1e-14)
    # not the distance RMS, which is sqrt(3) larger
    assert prior_strength(torch.from_numpy(r)) < 0.7 * np.sqrt((r ** 2).sum(1).mean())


def test_robust_prior_strength_leaves_gross_rows_out():
    rng = np.random.default_rng(5)
    r = rng.normal(scale=0.05, size=(200, 3))
    clean = np.sqrt((r ** 2).mean())
    r[:6] += 5.0  # gross rows, beyond 2.5 median distances
    d = np.linalg.norm(r, axis=1)
    keep = d <= 2.5 * np.median(d)
    assert keep.sum() == 194
    got = prior_strength(torch.from_numpy(r), robust=True)
    assert got == pytest.approx(np.sqrt((r[keep] ** 2).mean()), rel=1e-14)
    assert got == pytest.approx(clean, rel=0.05)
    assert prior_strength(torch.from_numpy(r)) > 10 * clean  # the plain one is inflated


def test_prior_strength_of_an_exact_fit_is_tiny_not_zero():
    assert prior_strength(torch.zeros(5, 3, dtype=torch.float64)) == 1e-12


def test_rho_settles_within_ten_percent_or_at_an_exact_fit():
    assert RHO_RTOL == 0.1
    assert rho_settled(1.09, 1.0) and rho_settled(0.91, 1.0)
    assert not rho_settled(1.11, 1.0) and not rho_settled(0.89, 1.0)
    assert rho_settled(0.5 * RHO_EXACT, 1.0)
