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


def _projector_and_heldout(U, Z):
    """(T, T) projector U U^T on the training rows and (V, T) map Z U^T that predicts the
    held-out rows from the training rows (both independent of the basis chosen)."""
    return U @ U.T, Z @ U.T


def test_extend_basis_matches_qr_svd_of_the_grown_columns():
    """`_extend_basis` against `_pinv_parts` of [X, pair] from scratch: the same span on the
    training rows, the same held-out predictions, the same rank by the RANK_TOL rule."""
    from torchcal.diagnosis.spectral import _extend_basis, _pinv_parts

    rng = np.random.default_rng(7)
    T, V, p = 300, 80, 6
    X = rng.standard_normal((T + V, p)) * np.array([1.0, 1e-2, 3.0, 1.0, 0.5, 1.0])
    X[:, 5] = X[:, 0] - 2 * X[:, 3]  # a rank-deficient base: the cut drops one direction
    t = np.arange(T + V) < T
    BT, M = _pinv_parts(X[t])
    assert BT.shape[1] == p - 1
    BV, R = X[~t] @ M, BT.T @ X[t]
    independent = rng.standard_normal((T + V, 2))
    half = np.column_stack([X @ rng.standard_normal(p), rng.standard_normal(T + V)])  # one column in span(X)
    inside = X @ rng.standard_normal((p, 2))  # both in span(X)
    for pair, k_expected in ((independent, 2), (half, 1), (inside, 0)):
        Q, QV, R1, W, Mn = _extend_basis(BT, BV, R, pair[t], pair[~t])
        np.testing.assert_allclose(Q, (pair[t] - BT @ W) @ Mn, atol=1e-12)
        assert Q.shape[1] == k_expected
        U1, M1 = _pinv_parts(np.hstack([X, pair])[t])
        assert U1.shape[1] == BT.shape[1] + k_expected  # the same rank as the rule from scratch
        B, BVn = np.hstack([BT, Q]), np.hstack([BV, QV])
        np.testing.assert_allclose(B.T @ B, np.eye(B.shape[1]), atol=1e-12)  # orthonormal
        ref_P, ref_H = _projector_and_heldout(U1, np.hstack([X, pair])[~t] @ M1)
        P, H = _projector_and_heldout(B, BVn)
        np.testing.assert_allclose(P, ref_P, atol=1e-10)
        np.testing.assert_allclose(H, ref_H, atol=1e-9 * np.abs(ref_H).max())
        np.testing.assert_allclose(R1, B.T @ np.hstack([X, pair])[t], atol=1e-10)


def test_search_updates_equal_the_sums_from_scratch():
    """`_Projected.extended` (what `search_orders` does as X grows) gives the held-out sums
    that `held_out_sums` computes from scratch on the grown X."""
    from torchcal.diagnosis.spectral import _fold_sums, _with_columns, held_out_sums, search_base

    rng = np.random.default_rng(11)
    n3, p, K = 600, 5, 9
    X, C, r = rng.standard_normal((n3, p)), rng.standard_normal((n3, 2 * K)), rng.standard_normal(n3)
    rows = np.repeat(rng.permutation(n3 // 3) % 4, 3)
    base = search_base(r, X, rows[::3])
    Cs = C[base.order]  # the folds hold their rows sorted by fold
    folds = _with_columns(base, Cs)
    for k in (3, 7):
        pair = Cs[:, 2 * k:2 * k + 2]
        folds = [fp.extended(pair, pair.T @ Cs) for fp in folds]
        X = np.hstack([X, C[:, 2 * k:2 * k + 2]])
        base, per = _fold_sums(folds)
        ref_base, ref_per = held_out_sums(r, X, C, rows)
        np.testing.assert_allclose(base, ref_base, rtol=1e-10)
        ok = np.ones(K, dtype=bool)
        ok[[3, 7]] = False  # pairs already in X: 0/0 fits, not compared
        np.testing.assert_allclose(per[ok], ref_per[ok], rtol=1e-10)


def test_held_out_sums_equal_plain_least_squares_per_fold_and_pair():
    """`held_out_sums` (the Gram form: sums over rows, no pass over C per fold) against
    plain least squares: per fold, X and [X, pair k] fitted on the other folds' rows by
    lstsq, their held-out squared errors summed over the folds."""
    from torchcal.diagnosis.spectral import held_out_sums

    rng = np.random.default_rng(5)
    n3, p, K = 450, 4, 6
    X = rng.standard_normal((n3, p)) * np.array([1.0, 1e-2, 5.0, 1.0])
    C = rng.standard_normal((n3, 2 * K)) + 0.5 * X[:, :1]  # partly inside span(X)
    r = X @ rng.standard_normal(p) + C[:, 4:6] @ np.array([0.3, -0.2]) + 0.1 * rng.standard_normal(n3)
    rows = np.repeat(rng.permutation(n3 // 3) % 3, 3)
    base, per = held_out_sums(r, X, C, rows)
    ref_base, ref_per = 0.0, np.zeros(K)
    for f in np.unique(rows):
        t = rows != f
        e = r[~t] - X[~t] @ np.linalg.lstsq(X[t], r[t], rcond=None)[0]
        ref_base += e @ e
        for k in range(K):
            Z = np.hstack([X, C[:, 2 * k:2 * k + 2]])
            e = r[~t] - Z[~t] @ np.linalg.lstsq(Z[t], r[t], rcond=None)[0]
            ref_per[k] += e @ e
    np.testing.assert_allclose(base, ref_base, rtol=1e-10)
    np.testing.assert_allclose(per, ref_per, rtol=1e-9)
    assert np.argmin(per) == 2  # the pair in r predicts best
