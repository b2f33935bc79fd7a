"""`torchcal.calibration.fit.identifiability`: its torch pivoting chooses the columns that a
plain-numpy Gram-Schmidt with the same rule chooses (the rule: the largest remaining
norm, the lowest index among norms equal to 1e-9, rounded unit columns, earlier columns
favoured by 1e-8; the `first` columns before the others)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchcal.calibration.fit import identifiability


def _numpy_free(J: np.ndarray, cand: np.ndarray, tol: float, first: np.ndarray) -> np.ndarray:
    """The rule in plain numpy: (P,) bool kept columns of J (R, P)."""
    def pivot(Js, Q):
        P = Js - Q @ (Q.T @ Js) if Q.shape[1] else Js.copy()
        kept = []
        for _ in range(P.shape[1]):
            norms = np.linalg.norm(P, axis=0)
            norms[kept] = -1.0
            best = norms.max(initial=-1.0)
            if best <= tol:
                break
            i = int(np.flatnonzero(norms >= best * (1 - 1e-9))[0])
            q = P[:, i] / norms[i]
            for _ in range(2):
                P = P - np.outer(q, q @ P)
            kept.append(i)
        return np.array(kept, dtype=int)

    c = np.flatnonzero(cand)
    norms = np.linalg.norm(J[:, c], axis=0)
    live = c[norms > 1e-12 * norms.max()]
    Js = np.round(J[:, live] / np.linalg.norm(J[:, live], axis=0), 10)
    Js = Js * (1 + 1e-8 * np.arange(len(live), 0, -1) / len(live))
    pri = first[live]
    a = np.flatnonzero(pri)[pivot(Js[:, pri], np.zeros((Js.shape[0], 0)))]
    Qa = np.linalg.qr(Js[:, a])[0] if a.size else np.zeros((Js.shape[0], 0))
    b = np.flatnonzero(~pri)[pivot(Js[:, ~pri], Qa)]
    free = np.zeros(J.shape[1], dtype=bool)
    free[live[np.concatenate([a, b])]] = True
    return free


@pytest.mark.parametrize("seed", range(6))
def test_identifiability_keeps_what_the_numpy_rule_keeps(seed):
    rng = np.random.default_rng(seed)
    R, P = 60, 14
    J = rng.normal(size=(R, P)) * rng.uniform(0.01, 100, size=P)
    J[:, 3] = 2.5 * J[:, 7]  # exactly dependent: one of them is held
    J[:, 9] = J[:, 1] - 0.5 * J[:, 12]  # a dependent triple
    J[:, 5] = 0.0  # no effect at all
    J[:, 11] = J[:, 2] + 1e-9 * rng.normal(size=R)  # dependent to below the rank tolerance
    cand = rng.uniform(size=P) < 0.9
    first = rng.uniform(size=P) < 0.3
    want = _numpy_free(J, cand, 1e-6, first)
    got = identifiability(torch.from_numpy(J), [f"p{i}" for i in range(P)], torch.from_numpy(cand),
                          first=torch.from_numpy(first))
    assert got.free.tolist() == want.tolist()
    assert got.rank == int(want.sum()) < int(cand.sum())
    assert set(got.held) == {f"p{i}" for i in np.flatnonzero(cand & ~want)}
    s = np.linalg.svd(J[:, want] / np.linalg.norm(J[:, want], axis=0), compute_uv=False)
    assert got.condition == pytest.approx(s[0] / s[-1], rel=1e-6)
