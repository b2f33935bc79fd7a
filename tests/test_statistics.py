"""`torchcal.statistics`: the Student t quantile and the upper tails of t, F and chi-square against scipy.stats."""

from __future__ import annotations

import math

import pytest

from torchcal.statistics import t_quantile


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 5, 7, 10, 29, 100, 199, 201, 1000, 9955, 100_000, 1e6, 1e7, 0.5, 2.5])
def test_t_quantile_is_scipys(dof):
    import scipy.stats
    for p in (0.6, 0.9, 0.975, 0.995, 0.9995, 1 - 1e-9, 0.025, 0.3):
        want = float(scipy.stats.t.ppf(p, dof))
        assert t_quantile(p, dof) == pytest.approx(want, rel=1e-12 if dof <= 100_000 else 1e-10, abs=0), (p, dof)


def test_t_quantile_centre_and_refusals():
    assert t_quantile(0.5, 7) == 0.0
    for p, dof in ((0.0, 5), (1.0, 5), (0.9, 0), (0.9, -1.0), (float("nan"), 5)):
        with pytest.raises(ValueError, match="t_quantile"):
            t_quantile(p, dof)


def test_upper_tails_are_scipy_stats_bit_for_bit():
    """t_sf, f_sf and chi2_sf (scipy.special underneath) return scipy.stats' floats exactly,
    at the support's edges and beyond it, at infinities, nan and bad degrees of freedom."""
    import itertools

    import numpy as np
    import scipy.stats

    from torchcal.statistics import chi2_sf, f_sf, t_sf

    xs = [-math.inf, -50.0, -3.2, -1e-300, -0.0, 0.0, 1e-300, 1e-8, 0.3, 1.0, 2.5, 17.0, 1e4, math.inf, math.nan]
    dofs = [-1, 0, 0.5, 1, 2, 3, 7, 30, 117, 1e6, math.nan]

    def same(a, b):
        return (math.isnan(a) and math.isnan(b)) or a == b

    for x, d in itertools.product(xs, dofs):
        assert same(t_sf(x, d), float(scipy.stats.t.sf(x, d))), (x, d)
        assert same(chi2_sf(x, d), float(scipy.stats.chi2.sf(x, d))), (x, d)
        for d2 in (1, 4, 55, 0, math.nan):
            assert same(f_sf(x, d, d2), float(scipy.stats.f.sf(x, d, d2))), (x, d, d2)
    assert same(t_sf(np.float64(1.7), 9), float(scipy.stats.t.sf(np.float64(1.7), 9)))
