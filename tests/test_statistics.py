"""`torchcal.statistics.t_quantile` against scipy's Student t quantile."""

from __future__ import annotations

import pytest
import scipy.stats

from torchcal.statistics import t_quantile


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 5, 7, 10, 29, 100, 199, 201, 1000, 9955, 100_000, 1e6, 1e7, 0.5, 2.5])
def test_t_quantile_is_scipys(dof):
    for p in (0.6, 0.9, 0.975, 0.995, 0.9995, 1 - 1e-9, 0.025, 0.3):
        want = float(scipy.stats.t.ppf(p, dof))
        assert t_quantile(p, dof) == pytest.approx(want, rel=1e-12 if dof <= 100_000 else 1e-10, abs=0), (p, dof)


def test_t_quantile_centre_and_refusals():
    assert t_quantile(0.5, 7) == 0.0
    for p, dof in ((0.0, 5), (1.0, 5), (0.9, 0), (0.9, -1.0), (float("nan"), 5)):
        with pytest.raises(ValueError, match="t_quantile"):
            t_quantile(p, dof)
