"""Kernel ridge regression held out by pose (torchcal.kernel_ridge): the held-out block
predictions and dual weights of every ridge against explicit numpy solves, each block
left out in turn."""

import numpy as np
import pytest
import torch

from torchcal import kernel_ridge as KR


def test_block_cv_matches_explicit_kernel_ridge_solves():
    g = np.random.default_rng(5)
    X, Y = torch.from_numpy(g.normal(size=(30, 2))), torch.from_numpy(g.normal(size=(30, 3)))
    K = KR.rbf(X, X, 0.8)
    blocks = [torch.arange(0, 10), torch.arange(10, 30)]
    pred, alpha = KR.block_cv(K, Y, blocks, (0.01, 1.0))
    Kn, Yn = K.numpy(), Y.numpy()
    for i, lam in enumerate((0.01, 1.0)):
        np.testing.assert_allclose(alpha[i].numpy(), np.linalg.solve(Kn + lam * np.eye(30), Yn), atol=1e-9)
        for B in blocks:
            b = B.numpy()
            rest = np.setdiff1d(np.arange(30), b)
            a = np.linalg.solve(Kn[np.ix_(rest, rest)] + lam * np.eye(len(rest)), Yn[rest])
            np.testing.assert_allclose(pred[i, B].numpy(), Kn[np.ix_(b, rest)] @ a, atol=1e-9)


def held_out_by_hand(K, Y, blocks, lam):
    """(N, k): each block predicted by a kernel ridge solve on the other rows (numpy)."""
    out = np.zeros_like(Y)
    for b in blocks:
        rest = np.setdiff1d(np.arange(len(K)), b)
        out[b] = K[np.ix_(b, rest)] @ np.linalg.solve(K[np.ix_(rest, rest)] + lam * np.eye(len(rest)), Y[rest])
    return out


@pytest.mark.parametrize("p", [3, 40])
def test_blocks_of_one_size_batched_and_both_low_rank_routes_match_explicit_solves(p):
    """Blocks of equal and unequal sizes (one batched solve per size); a rank-p kernel
    V diag(w) V^T: p = 3 < every block (ridge regression on the features, p x p systems),
    p = 40 > every block (the b x b blocks of A^-1); and the full-rank kernel."""
    g = np.random.default_rng(8)
    n = 60
    blocks = [np.arange(0, 12), np.arange(12, 24), np.arange(24, 36), np.arange(36, 51), np.arange(51, 60)]
    V, _ = np.linalg.qr(g.normal(size=(n, p)))
    w = g.uniform(0.5, 20.0, p)
    X = g.normal(size=(n, 2))
    Y = g.normal(size=(n, 3))
    ridges = (1e-2, 1.0, 10.0)
    Kfull = KR.rbf(torch.from_numpy(X), torch.from_numpy(X), 0.7)
    thin, _ = KR.block_cv_eig(torch.from_numpy(w), torch.from_numpy(V), torch.from_numpy(Y),
                              [torch.from_numpy(b) for b in blocks], ridges)
    full, _ = KR.block_cv(Kfull, torch.from_numpy(Y), [torch.from_numpy(b) for b in blocks], ridges)
    for i, lam in enumerate(ridges):
        np.testing.assert_allclose(thin[i].numpy(), held_out_by_hand((V * w) @ V.T, Y, blocks, lam), atol=1e-9)
        np.testing.assert_allclose(full[i].numpy(), held_out_by_hand(Kfull.numpy(), Y, blocks, lam), atol=1e-9)


def test_kernel_factors_at_all_length_scales_are_the_factors_one_by_one():
    """The distinct rows found once serve every length scale: each factor reproduces the
    RBF kernel at its own scale."""
    g = np.random.default_rng(9)
    values = {"q1": g.uniform(-np.pi, np.pi, 150), "approach_q1": np.sign(g.normal(size=150)),
              "temp_c": g.choice([20.0, 21.5, 23.0], 150)}
    feats = KR.variable_features(values)
    for name in values:
        x = torch.from_numpy(feats[name])
        factors = KR.kernel_factors(x, KR.LENGTH_SCALES, angle=name == "q1")
        assert len(factors) == len(KR.LENGTH_SCALES)
        for ell, f in zip(KR.LENGTH_SCALES, factors):
            if f is None:  # the angle series would need as many terms as rows
                assert name == "q1" and KR.kernel_factors(x, (ell,), angle=True)[0] is None
                continue
            w, V = f
            np.testing.assert_allclose(((V * w) @ V.T).numpy(), KR.rbf(x, x, ell).numpy(), atol=1e-9)
