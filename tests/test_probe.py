"""The kernel probe of what is left (torchcal.diagnosis.probe): the low-rank kernel
factors give the same held-out predictions as the full kernel, and with many rows the
choice is made on a subsample whose poses the test never uses.

Data: plain numpy draws here (no robot)."""

import numpy as np
import pytest
import torch

from torchcal import kernel_ridge as KR
from torchcal.diagnosis import probe as P
from torchcal.folds import fold_of_pose


def blocks_of(n, folds=5):
    return [torch.from_numpy(np.flatnonzero(np.arange(n) % folds == f)) for f in range(folds)]


@pytest.mark.parametrize("name", ["q1", "approach_q1"])
def test_kernel_factor_gives_the_held_out_predictions_of_the_full_kernel(name):
    g = np.random.default_rng(11)
    n = 240
    values = {"q1": g.uniform(-np.pi, np.pi, n), "approach_q1": np.sign(g.normal(size=n))}
    x = torch.from_numpy(KR.variable_features(values)[name])
    Y = torch.from_numpy(g.normal(size=(n, 3)))
    blocks = blocks_of(n)
    for ell in KR.LENGTH_SCALES:
        w, V = KR.kernel_factors(x, (ell,), angle=name == "q1")[0]
        assert V.shape[1] < n  # low rank: no N x N eigendecomposition
        K = KR.rbf(x, x, ell).numpy()
        np.testing.assert_allclose((V * w) @ V.T, K, atol=1e-9)
        thin, alpha = KR.block_cv_eig(w, V, Y, blocks)
        # by hand: each block from a kernel ridge solve on the other rows
        for i, lam in enumerate(KR.RIDGES[:4]):
            np.testing.assert_allclose(alpha[i].numpy(), np.linalg.solve(K + lam * np.eye(n), Y.numpy()),
                                       atol=1e-6 * max(1.0, 1 / lam))
            for B in blocks:
                b = B.numpy()
                rest = np.setdiff1d(np.arange(n), b)
                a = np.linalg.solve(K[np.ix_(rest, rest)] + lam * np.eye(len(rest)), Y.numpy()[rest])
                np.testing.assert_allclose(thin[i, B].numpy(), K[np.ix_(b, rest)] @ a, atol=1e-6)


def test_kernel_factor_declines_a_continuous_non_angle_variable():
    x = torch.from_numpy(np.random.default_rng(3).normal(size=(200, 1)))
    assert KR.kernel_factors(x, (0.4,), angle=False)[0] is None


@pytest.fixture(scope="module")
def large():
    """2 MAX_ROWS + 100 poses, one row each: q1, q2 uniform; a 0.1 sin(2 q1) error along x
    and 0.05 noise per axis."""
    g = np.random.default_rng(12)
    n = 2 * KR.MAX_ROWS + 100
    q = g.uniform(-np.pi, np.pi, size=(n, 2))
    noise = 0.05 * g.normal(size=(n, 3))
    signal = np.zeros((n, 3))
    signal[:, 0] = 0.1 * np.sin(2 * q[:, 0])
    return {"q1": q[:, 0], "q2": q[:, 1]}, signal, noise, np.arange(n)


def test_with_many_rows_the_choice_never_sees_the_tested_poses(large):
    values, signal, noise, pose = large
    a = P.probe(values, signal + noise, pose)
    assert a.tested.sum() >= len(pose) / 2 and not a.tested.all()
    moved = signal + noise
    moved[a.tested] *= -3.0  # what the test uses: the choice must not change
    b = P.probe(values, moved, pose)
    assert (a.inputs, a.length_scale, a.ridge) == (b.inputs, b.length_scale, b.ridge)
    np.testing.assert_array_equal(a.tested, b.tested)
    assert a.p_value < 1e-6 and [v for v, _ in a.carried_by()] == ["q1"], (a.p_value, a.relevance)
    truth = float(np.sqrt((noise ** 2).sum(-1).mean()))  # what is left once sin(2 q1) is learnt
    assert a.learnable_rms_mm < 1.1 * truth and a.learnable_rms_mm > 0.9 * truth, (a.learnable_rms_mm, truth)


def test_with_many_rows_and_nothing_to_learn_the_probe_is_not_significant(large):
    values, _, noise, pose = large
    assert P.probe(values, noise, pose).p_value > 0.01


def test_probe_prediction_of_a_fold_never_sees_that_fold():
    g = np.random.default_rng(6)
    q = g.uniform(-3, 3, size=(120, 2))
    r = np.stack([np.sin(2 * q[:, 0]), np.zeros(120), 0.1 * g.normal(size=120)], -1)
    pose = np.arange(120)
    fold = fold_of_pose(pose, 0)
    a = P.probe({"q1": q[:, 0], "q2": q[:, 1]}, r, pose)
    moved = r.copy()
    moved[fold == 1] += 5.0
    b = P.probe({"q1": q[:, 0], "q2": q[:, 1]}, moved, pose)
    np.testing.assert_allclose(a.prediction[fold == 1], b.prediction[fold == 1], atol=1e-12)
    assert np.abs(a.prediction[fold != 1] - b.prediction[fold != 1]).max() > 1e-3
    assert a.p_value < 1e-6 and [v for v, _ in a.carried_by()] == ["q1"], (a.p_value, a.relevance)
    assert a.learnable_rms_mm < 0.5 * a.rms_mm
