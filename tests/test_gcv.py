"""The damping of eq. 29 by generalised cross-validation (torchcal.calibration.gcv).

References, in plain numpy on small seeded ridge problems: the GCV score from the explicit
hat matrix H(mu) = J_f (J_f^T J_f + mu D^2)^-1 J_f^T (D the free columns' norms), and a
brute-force leave-one-out (each row left out, the damped problem re-solved without it),
which GCV estimates: the mu it picks leaves a leave-one-out error near the best of the grid.
"""

import numpy as np
import pytest
import torch

from torchcal.calibration.gcv import GCV_GRID, choose_damping, gcv_damping


def problem(seed, R=40, P=8, noise=0.5):
    """J (R, P) with columns of very different scales and a weak direction, r (R,) = J x + noise."""
    rng = np.random.default_rng(seed)
    J = rng.normal(size=(R, P)) * np.logspace(-2, 2, P)
    J[:, -1] = J[:, -2] * 1.001 + rng.normal(size=R) * 1e-2  # nearly collinear: damping matters
    r = J @ (rng.normal(size=P) / np.logspace(-2, 2, P)) + rng.normal(size=R) * noise
    return J, r


def damped(J, r, mu):
    """(J^T J + mu D^2)^-1 J^T r, D = diag of the column norms."""
    d2 = (J ** 2).sum(0)
    return np.linalg.solve(J.T @ J + mu * np.diag(d2), J.T @ r)


def gcv_by_hat_matrix(J, r, mu):
    d2 = (J ** 2).sum(0)
    H = J @ np.linalg.solve(J.T @ J + mu * np.diag(d2), J.T)
    R = len(r)
    dof = R - np.trace(H)
    return R * np.sum((r - H @ r) ** 2) / dof ** 2


def loo_by_refits(J, r, mu):
    """Mean squared error of each row predicted by the damped solution of the others (the
    column norms of the reduced problem)."""
    err = []
    for i in range(len(r)):
        keep = np.arange(len(r)) != i
        err.append(r[i] - J[i] @ damped(J[keep], r[keep], mu))
    return float(np.mean(np.square(err)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gcv_scores_equal_the_hat_matrix_formula(seed):
    J, r = problem(seed)
    free = np.ones(J.shape[1], dtype=bool)
    free[2] = False  # a held column takes no part
    Jt = torch.from_numpy(J.copy())
    Jt[:, 2] = 1e6  # whatever a held column holds
    mu, scores = gcv_damping(Jt, torch.from_numpy(r), torch.from_numpy(free))
    expected = [gcv_by_hat_matrix(J[:, free], r, m) for m in GCV_GRID]
    np.testing.assert_allclose(scores, expected, rtol=1e-8)
    assert mu == GCV_GRID[int(np.argmin(expected))]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_chosen_damping_is_near_the_best_leave_one_out(seed):
    J, r = problem(seed)
    mu, _ = gcv_damping(torch.from_numpy(J), torch.from_numpy(r), torch.ones(J.shape[1], dtype=torch.bool))
    loo = {m: loo_by_refits(J, r, m) for m in GCV_GRID}
    assert loo[mu] <= 1.1 * min(loo.values()), (mu, loo)
    assert loo[mu] < loo[GCV_GRID[-1]]  # and better than damping everything away


def test_choose_damping_per_zone_and_shared():
    zones = [problem(s, noise=n) for s, n in ((3, 0.1), (4, 2.0), (5, 0.5))]
    J = torch.from_numpy(np.stack([z[0] for z in zones]))
    r = torch.from_numpy(np.stack([z[1] for z in zones]))
    free = torch.ones(3, J.shape[2], dtype=torch.bool)
    own = [float(GCV_GRID[int(np.argmin([gcv_by_hat_matrix(Jb, rb, m) for m in GCV_GRID]))]) for Jb, rb in zones]
    assert choose_damping(J, r, free, "gcv") == own
    total = [sum(gcv_by_hat_matrix(Jb, rb, m) for Jb, rb in zones) for m in GCV_GRID]
    shared = choose_damping(J, r, free, "gcv_shared")
    assert shared == [float(GCV_GRID[int(np.argmin(total))])] * 3


def test_a_choice_at_the_top_of_the_grid_is_named():
    """A zone whose errors the parameters do not explain (pure noise: r independent of J)
    makes GCV choose the grid's largest damping, a bound: one warning names that zone and
    the bound (before: silently); a zone whose errors J explains is not named, and neither
    is a choice of 0 (no damping, the end of the range)."""
    import warnings

    from torchcal.calibration.gcv import DampingWarning

    rng = np.random.default_rng(7)
    Jn, _ = problem(7)
    noise = rng.normal(size=Jn.shape[0])
    Js, rs = problem(8, noise=0.01)
    J = [torch.from_numpy(Js), torch.from_numpy(Jn)]
    r = [torch.from_numpy(rs), torch.from_numpy(noise)]
    free = torch.ones(2, Js.shape[1], dtype=torch.bool)
    scores = [gcv_by_hat_matrix(Jn, noise, m) for m in GCV_GRID]
    assert int(np.argmin(scores)) == len(GCV_GRID) - 1  # the plain-numpy GCV: lowest at the top
    with pytest.warns(DampingWarning) as rec:
        mus = choose_damping(J, r, free, "gcv", labels=["zone 4", "zone 7"])
    assert mus[1] == GCV_GRID[-1] and mus[0] < GCV_GRID[-1]
    assert len(rec) == 1 and str(rec[0].message).startswith(
        "zone 7: the damping chosen by GCV is 10, the top of its grid (0..10): GCV would damp further")
    with warnings.catch_warnings():
        warnings.simplefilter("error", DampingWarning)
        assert choose_damping(J[:1], r[:1], free[:1], "gcv") == [mus[0]]
    with pytest.warns(DampingWarning, match=r"^zone 1: the damping shared by the zones chosen by GCV is 10, the top"):
        choose_damping(J[1:], r[1:], free[1:], "gcv_shared")
