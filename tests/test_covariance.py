"""Parameter covariance (torchcal.calibration.covariance) against the textbook
linear least-squares covariance: for y = X b + e fitted by least squares,
``C = sigma^2 (X^T X)^-1`` with ``sigma^2 = SSR / (n - K)`` (n rows, K parameters);
weighted rows: ``X^T W X`` and ``sum w r^2``. The references are numpy / scipy."""

import numpy as np
import pytest
import torch

from torchcal.calibration.covariance import parameter_covariance, row_covariance


def _linear_problem(N=12, P=4, seed=0):
    """A small linear problem with 3 rows per pose: X (N, 3, P), y, the lstsq residual."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(N, 3, P))
    y = X.reshape(-1, P) @ rng.normal(size=P) + rng.normal(scale=0.1, size=3 * N)
    b, *_ = np.linalg.lstsq(X.reshape(-1, P), y, rcond=None)
    r = y - X.reshape(-1, P) @ b
    return X, r


def _textbook(A, r, w=None):
    import scipy.linalg
    w = np.ones(len(r)) if w is None else w
    K = A.shape[1]
    s2 = (w * r ** 2).sum() / (len(r) - K)
    return s2, s2 * scipy.linalg.inv(A.T @ (A * w[:, None]))


def test_row_covariance_is_the_textbook_one():
    X, r = _linear_problem()
    A = X.reshape(-1, X.shape[-1])
    s2, ref = _textbook(A, r)
    c = row_covariance(torch.from_numpy(A), torch.from_numpy(r), torch.ones(4, dtype=torch.bool))
    assert c.dof == 36 - 4 and c.method == "rows"
    assert c.sigma_mm ** 2 == pytest.approx(s2, rel=1e-12)
    np.testing.assert_allclose(c.cov.numpy(), ref, rtol=1e-10)
    # 3N instead of 3N - K would understate every variance by (3N - K) / 3N = 0.89
    assert not np.allclose(c.cov.numpy(), ref * 32 / 36, rtol=1e-3)


def test_parameter_covariance_is_the_textbook_one_per_pose_rows():
    """Positions (N, 3, P) with distinct poses: the same formula, 3N - K degrees of freedom."""
    X, r = _linear_problem()
    s2, ref = _textbook(X.reshape(-1, 4), r)
    c = parameter_covariance(torch.from_numpy(X), torch.from_numpy(r.reshape(-1, 3)), torch.ones(4, dtype=torch.bool))
    assert c.dof == 3 * 12 - 4
    assert c.sigma_mm ** 2 == pytest.approx(s2, rel=1e-12)
    np.testing.assert_allclose(c.cov.numpy(), ref, rtol=1e-10)


def test_weighted_and_held_columns():
    """Robust row weights enter as X^T W X and sum w r^2; a held column has zero variance,
    the others the covariance of the fit without it (K = 3)."""
    X, r = _linear_problem(seed=1)
    w = np.random.default_rng(2).uniform(0.1, 1.0, size=12)
    free = np.array([True, False, True, True])
    A = X[:, :, free].reshape(-1, 3)
    s2, ref = _textbook(A, r, np.repeat(w, 3))
    c = parameter_covariance(torch.from_numpy(X), torch.from_numpy(r.reshape(-1, 3)), torch.from_numpy(free),
                             weights=torch.from_numpy(w))
    assert c.dof == 36 - 3
    np.testing.assert_allclose(c.cov.numpy()[np.ix_(free, free)], ref, rtol=1e-10)
    assert np.all(c.cov.numpy()[1] == 0) and np.all(c.cov.numpy()[:, 1] == 0)


def test_prior_rows_give_the_gaussian_posterior():
    """With prior factors f_i (rows f_i theta_i): C = s^2 (X^T X + diag f^2)^-1, the
    posterior covariance of a Gaussian prior of sd s / f_i, s^2 = SSR / (3N - K)."""
    import scipy.linalg
    X, r = _linear_problem(seed=3)
    A = X.reshape(-1, 4)
    f = np.array([0.0, 0.5, 2.0, 0.1])
    s2 = (r ** 2).sum() / (36 - 4)
    ref = s2 * scipy.linalg.inv(A.T @ A + np.diag(f ** 2))
    c = row_covariance(torch.from_numpy(A), torch.from_numpy(r), torch.ones(4, dtype=torch.bool),
                       prior=torch.from_numpy(f))
    np.testing.assert_allclose(c.cov.numpy(), ref, rtol=1e-10)


def test_ninety_five_percent_interval_uses_students_t_with_the_dof():
    import scipy.stats

    X, r = _linear_problem(N=4)  # 12 rows, 4 parameters: 8 degrees of freedom
    c = row_covariance(torch.from_numpy(X.reshape(-1, 4)), torch.from_numpy(r), torch.ones(4, dtype=torch.bool))
    lo, hi = c.interval95(torch.zeros(4, dtype=torch.float64))
    np.testing.assert_allclose(hi.numpy(), scipy.stats.t.ppf(0.975, 8) * np.sqrt(np.diag(c.cov.numpy())), rtol=1e-10)
