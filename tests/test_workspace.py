"""The workspace sampler's Latin hypercube (torchcal.robots.workspace.LatinHypercube) against
scipy.stats.qmc.LatinHypercube, the reference it writes out: the same points bit for bit for
an int seed and for a block's SeedSequence, over successive rounds of different sizes."""

import numpy as np
import pytest

from torchcal.reliability.sweep_blocks import block_seed
from torchcal.robots.workspace import LatinHypercube


def _scipy(d, seed):
    from scipy.stats import qmc

    if isinstance(seed, np.random.SeedSequence):
        seed = np.random.default_rng(seed)
    try:
        return qmc.LatinHypercube(d=d, rng=seed)
    except TypeError:  # scipy < 1.15
        return qmc.LatinHypercube(d=d, seed=seed)


@pytest.mark.parametrize("d, seed", [(6, 0), (6, 5), (4, 123), (7, "block 3 of seed 5"), (6, "block 1 of seed 0")])
def test_points_are_scipys_bit_for_bit(d, seed):
    """Rounds as `sample_workspace` draws them (n, then larger top-ups): each one a Latin
    hypercube (one point per stratum and axis) and equal to scipy's, round after round."""
    if isinstance(seed, str):
        b, s = (int(w) for w in seed.split()[1::3])
        mine, ref = LatinHypercube(d, block_seed(s, b)), _scipy(d, block_seed(s, b))
    else:
        mine, ref = LatinHypercube(d, seed), _scipy(d, seed)
    for n in (40, 64, 1, 257):
        u = mine.random(n)
        assert u.shape == (n, d) and u.dtype == np.float64
        assert np.array_equal(u, ref.random(n))
        assert all(sorted(np.floor(u[:, j] * n).astype(int)) == list(range(n)) for j in range(d))

