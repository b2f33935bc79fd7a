"""Validity indices and the choice of c (torchcal.partition.validity), against the
formulas written out in numpy."""

import math

import numpy as np
import pytest
import torch

from torchcal.partition.fcm import fcm
from torchcal.partition.validity import choose_c, partition_coefficient, partition_entropy, xie_beni


def _blobs(n_per, centers, std, seed):
    """n_per Gaussian points around each center -> x (n_per * c, d), labels (n_per * c,)."""
    rng = np.random.default_rng(seed)
    centers = np.asarray(centers, dtype=np.float64)
    x = np.concatenate([c + std * rng.standard_normal((n_per, centers.shape[1])) for c in centers])
    return x, np.repeat(np.arange(len(centers)), n_per)


def test_validity_indices():
    crisp = torch.tensor([[1.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    flat = torch.full((4, 10), 0.25)
    assert partition_coefficient(crisp) == pytest.approx(1.0)
    assert partition_entropy(crisp) == pytest.approx(0.0)
    assert partition_coefficient(flat) == pytest.approx(0.25)
    assert partition_entropy(flat) == pytest.approx(math.log(4))
    x, _ = _blobs(40, [[0, 0], [5, 0]], 0.4, 3)
    res = fcm(x, 2)
    u, v = res.memberships.numpy(), res.centers.numpy()
    d2 = ((x[None] - v[:, None]) ** 2).sum(-1)
    xb = (u ** 2 * d2).sum() / (len(x) * ((v[0] - v[1]) ** 2).sum())
    assert xie_beni(x, res.centers, res.memberships) == pytest.approx(xb, rel=1e-12)


def test_number_of_clusters_chosen_by_xie_beni():
    from sklearn.metrics import adjusted_rand_score  # here: scikit-learn is slow to import for one check

    x, y = _blobs(60, [[0, 0], [8, 0], [0, 8], [8, 8]], 0.6, 4)
    c, res, scores = choose_c(x, (2, 6))
    assert c == 4 and set(scores) == {2, 3, 4, 5, 6}
    assert scores[4] == min(scores.values())
    assert adjusted_rand_score(y, res.memberships.argmax(dim=0).numpy()) == 1.0
    with pytest.raises(ValueError, match=r"c_range: expected 2 <= low <= high"):
        choose_c(x, (1, 3))
