"""Kernel ridge regression held out by pose (torchcal.kernel_ridge): the held-out block
predictions and dual weights of every ridge against explicit numpy solves, each block
left out in turn."""

import numpy as np
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
