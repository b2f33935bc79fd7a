"""The batched Newton fit of the residual variance model of `diagnose` (random clearance:
covariance sigma^2 I + sum_j tau_j^2 B_j B_j^T per row) against an independent
reference: scipy's L-BFGS-B on the numpy log-likelihood, with a numerical gradient."""

import numpy as np
import pytest
import torch

from torchcal.diagnosis.variance import fit_variances, isotropic_loglik, variance_loglik


def sample(K, tau, M, seed):
    rng = np.random.default_rng(seed)
    Bs = rng.normal(size=(M, 3, 2 * K)) * 0.5
    r = np.einsum("mik,mk->mi", Bs, rng.normal(size=(M, 2 * K)) * tau) + 0.02 * rng.normal(size=(M, 3))
    return r, Bs


def reference(r, Bs):
    """Maximum of the summed numpy log-likelihood by scipy (tau^2 may reach its lower bound)."""
    import scipy.optimize
    K = Bs.shape[-1] // 2
    s = np.log((r ** 2).mean())
    lt = s - np.log((Bs ** 2).sum((1, 2)).mean())
    res = scipy.optimize.minimize(lambda x: -variance_loglik(r, Bs, x).sum(), np.r_[s, [lt] * K],
                                  method="L-BFGS-B", bounds=[(s - 9, s + 5)] + [(lt - 30, lt + 10)] * K,
                                  options={"ftol": 1e-15, "gtol": 1e-10, "maxiter": 2000})
    return res.x, -res.fun


@pytest.mark.parametrize("K,tau,M", [(1, 0.3, 200), (2, 0.5, 300), (3, 0.2, 400), (1, 2.0, 40)])
def test_newton_matches_scipy_inside(K, tau, M):
    r, Bs = sample(K, tau, M, seed=K)
    x_ref, ll_ref = reference(r, Bs)
    x = fit_variances(torch.from_numpy(r)[None], torch.from_numpy(Bs))[0].numpy()
    assert variance_loglik(r, Bs, x).sum() >= ll_ref - 1e-7
    np.testing.assert_allclose(x, x_ref, atol=2e-3)


def test_residual_outside_the_random_directions_puts_tau_at_its_bound():
    """Residuals along the normal of span(B_m) only: any tau^2 > 0 adds variance where
    there is none, so the maximum is at tau^2's lower bound, with sigma^2 the maximum of
    the isotropic likelihood: 3 sigma^2 = mean |r|^2, i.e. the mean square per axis."""
    r, Bs = sample(1, 0.0, 300, seed=5)
    n = np.cross(Bs[:, :, 0], Bs[:, :, 1])
    r = n / np.linalg.norm(n, axis=1, keepdims=True) * np.random.default_rng(6).normal(size=(300, 1)) * 0.03
    x = fit_variances(torch.from_numpy(r)[None], torch.from_numpy(Bs))[0].numpy()
    _, ll_ref = reference(r, Bs)
    assert variance_loglik(r, Bs, x).sum() >= ll_ref - 1e-7
    s2 = (r ** 2).mean()
    assert abs(np.exp(x[0]) / s2 - 1) < 1e-6
    assert np.exp(x[1]) * (Bs ** 2).sum((1, 2)).mean() < 1e-9 * s2


def test_batches_and_row_weights_equal_separate_fits_of_the_subsets():
    """Batch g with weights w_g gives the fit of the rows where w_g = 1 alone."""
    r, Bs = sample(2, 0.4, 250, seed=7)
    folds = np.arange(250) % 3
    w = torch.from_numpy(folds[None] != np.arange(3)[:, None])
    R = torch.from_numpy(r)[None].expand(3, -1, -1)
    x = fit_variances(R, torch.from_numpy(Bs), w).numpy()
    for f in range(3):
        keep = folds != f
        x_f = fit_variances(torch.from_numpy(r[keep])[None], torch.from_numpy(Bs[keep]))[0].numpy()
        np.testing.assert_allclose(x[f], x_f, atol=1e-6)
        assert variance_loglik(r[keep], Bs[keep], x[f]).sum() >= reference(r[keep], Bs[keep])[1] - 1e-7


def test_one_basis_shared_by_the_sets_is_their_own_basis_each_bit_for_bit():
    """Bs (M, 3, 2) shared by G sets (one eigenbasis per row, not G) gives the same bits
    as the same basis repeated per set (G, M, 3, 2); both one term and two."""
    for K in (1, 2):
        r, Bs = sample(K, 0.4, 120, seed=11 + K)
        folds = np.arange(120) % 5
        w = torch.from_numpy(folds[None] != np.arange(5)[:, None])
        R = torch.from_numpy(r)[None] * torch.linspace(0.5, 1.5, 5, dtype=torch.float64)[:, None, None]
        B = torch.from_numpy(Bs)
        shared = fit_variances(R, B, w)
        assert torch.equal(shared, fit_variances(R, B.expand(5, -1, -1, -1).contiguous(), w))
        assert not torch.equal(shared[0], shared[1])  # the sets differ: a real comparison


def test_isotropic_loglik_with_a_variance_per_row_equals_the_per_set_calls():
    """`isotropic_loglik` of all rows with each row's set's variance equals
    `variance_loglik` of each set alone, bit for bit (the isotropic CV's batched form),
    and the Gaussian density by hand."""
    rng = np.random.default_rng(3)
    r = rng.normal(size=(90, 3)) * 0.05
    set_of_row = np.arange(90) % 4
    logs2 = np.log(rng.uniform(1e-3, 4e-3, size=4))
    s2 = np.array([np.exp(v) for v in logs2])
    ll = isotropic_loglik(r, logs2[set_of_row], s2[set_of_row])
    for g in range(4):
        rows = set_of_row == g
        assert np.array_equal(ll[rows], variance_loglik(r[rows], None, logs2[g:g + 1]))
    by_hand = np.log((2 * np.pi * s2[set_of_row]) ** -1.5 * np.exp(-(r ** 2).sum(-1) / (2 * s2[set_of_row])))
    np.testing.assert_allclose(ll, by_hand, rtol=1e-12)
