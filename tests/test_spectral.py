"""`torchcal.diagnosis.spectral._pair_grams`: the Gram matrix of each pair of columns."""

import numpy as np

from torchcal.diagnosis.spectral import _pair_grams


def test_pair_grams_match_per_pair_products():
    rng = np.random.default_rng(3)
    D = rng.standard_normal((500, 7, 2)) * np.array([1.0, 1e3])  # columns of unequal scale
    G = _pair_grams(D)
    assert G.shape == (7, 2, 2)
    for k in range(7):
        ref = D[:, k, :].T @ D[:, k, :]  # an independent product per pair
        np.testing.assert_allclose(G[k], ref, rtol=1e-12, atol=0)
    assert np.array_equal(G, G.transpose(0, 2, 1))  # symmetric by construction
