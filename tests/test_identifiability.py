"""Identifiability (torchcal.calibration.identifiability) against numpy: the rank of the
unit-scaled Jacobian, which of two dependent columns is held (the gauge: the `first`
ones kept), the observability indices from its singular values, the recheck at a first
solution and the refusal of too few poses."""

import numpy as np
import pytest
import torch

from torchcal.calibration.identifiability import (RECHECK_TOL, check_enough_rows, identifiability, recheck)
from torchcal.calibration.model import CalibrationModel
from torchcal.effects import make_context
from torchcal.errors import InputError
from torchcal.robots.poses import random_poses

NAMES = ["a", "b", "c", "d", "e"]
ALL = torch.ones(5, dtype=torch.bool)


def _jacobian(seed=0, N=20):
    """(N, 3, 5): column d = 2 b - c exactly, the others generic with different scales."""
    rng = np.random.default_rng(seed)
    J = rng.normal(size=(N, 3, 5)) * np.array([1.0, 30.0, 0.01, 1.0, 5.0])
    J[:, :, 3] = 2 * J[:, :, 1] / 30.0 - J[:, :, 2] / 0.01
    return torch.from_numpy(J)


def test_rank_and_the_held_column_match_numpy():
    J = _jacobian()
    rep = identifiability(J, NAMES, ALL)
    A = J.reshape(-1, 5).numpy()
    unit = A / np.linalg.norm(A, axis=0)
    assert rep.rank == np.linalg.matrix_rank(unit) == 4
    assert rep.held == ["d"]  # the last of the dependent set, in column order
    assert np.linalg.matrix_rank(unit[:, rep.free.numpy()]) == 4


def test_the_first_columns_are_kept_the_others_held():
    """The gauge: with d pivoted first, one of b, c (the robot's side) is held instead."""
    rep = identifiability(_jacobian(), NAMES, ALL, first=torch.tensor([False, False, False, True, False]))
    assert rep.rank == 4 and "d" not in rep.held and len(rep.held) == 1 and rep.held[0] in ("b", "c")


def test_observability_indices_are_the_textbook_ones():
    """O1 = (prod s)^(1/L) / sqrt(m), O2 = s_min / s_max, O3 = s_min, O4 = s_min^2 / s_max,
    O5 = 1 / sum(1 / s) (Borm & Menq, Nahvi & Hollerbach), s the singular values of the
    unit-scaled identified columns, m the number of poses."""
    J = _jacobian()
    rep = identifiability(J, NAMES, ALL)
    A = J.reshape(-1, 5).numpy()[:, rep.free.numpy()]
    s = np.linalg.svd(A / np.linalg.norm(A, axis=0), compute_uv=False)
    ref = {"O1": np.prod(s) ** (1 / len(s)) / np.sqrt(20), "O2": s[-1] / s[0], "O3": s[-1],
           "O4": s[-1] ** 2 / s[0], "O5": 1 / np.sum(1 / s)}
    for k, v in ref.items():
        assert rep.observability[k] == pytest.approx(v, rel=1e-6), k
    assert rep.condition == pytest.approx(s[0] / s[-1], rel=1e-6)


def test_candidates_only_and_zero_columns():
    J = _jacobian()
    J[:, :, 4] = 0.0
    rep = identifiability(J, NAMES, torch.tensor([True, True, True, False, True]))
    assert rep.rank == 3 and rep.held == ["e"] and not bool(rep.free[3])


def test_recheck_frees_a_held_parameter_only_beyond_its_tolerance():
    """At a first solution d = 2 b - c + eps * noise: freed where eps reaches RECHECK_TOL
    (relative to the unit columns), held below; the parameters already free stay free."""
    J = _jacobian()
    held = identifiability(J, NAMES, ALL).free
    noise = torch.from_numpy(np.random.default_rng(1).normal(size=(20, 3)))
    for eps, freed in ((0.1, True), (1e-4, False)):
        Jx = J.clone()
        Jx[:, :, 3] += eps * noise / noise.norm() * Jx[:, :, 3].norm()
        rep = recheck(Jx, NAMES, ALL, held)
        assert bool(rep.free[3]) == freed and bool((rep.free | ~held).all()), eps
    assert RECHECK_TOL == 1e-2


def test_too_few_poses_are_refused_with_the_poses_needed(kr):
    model = CalibrationModel(kr)
    q = random_poses(kr, 5, torch.Generator().manual_seed(0))
    ctx = make_context(kr, q)
    rep = identifiability(model.jacobian(model.zeros(), ctx), model.param_names(), model.default_free())
    with pytest.raises(InputError, match=r"too few poses: 5 poses give 15 equations .* need at least \d+ poses"):
        check_enough_rows(rep, 15, model, ctx, model.default_free())


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


def test_beyond_doubt_frees_every_candidate_only_where_the_pivoting_would():
    """`beyond_doubt` (the refits' shortcut): on independent columns the same free set as
    `identifiability` (every candidate, none held) and its condition number and
    observability to 1e-7 (the pivoting rounds its unit columns to 1e-10 and scales them
    by up to 1 + 1e-8); None, so that the caller pivots, for an exactly dependent
    column and for one whose distance from the others' span is only a few rank_tol."""
    from torchcal.calibration.identifiability import RANK_TOL, SAFE_RANK, beyond_doubt

    J = _jacobian()
    A = J.reshape(-1, 5)
    some = torch.tensor([True, True, True, False, True])  # d = 2 b - c left out: independent
    Ac = A[:, some]
    rep, ref = beyond_doubt(Ac.T @ Ac, some, 20), identifiability(J, NAMES, some)
    assert rep is not None and torch.equal(rep.free, ref.free) and rep.held == ref.held == []
    assert rep.rank == ref.rank == 4 and rep.n_rows == ref.n_rows
    assert rep.condition == pytest.approx(ref.condition, rel=1e-7)
    for k, v in ref.observability.items():
        assert rep.observability[k] == pytest.approx(v, rel=1e-7), k
    assert beyond_doubt(A.T @ A, ALL, 20) is None  # d dependent: the pivoting holds it
    # e close to b: its distance from span(b) (unit columns) a few rank_tol, under SAFE_RANK of them
    rng = np.random.default_rng(3)
    near = J.clone()
    unit_b = near[:, :, 1] / near[:, :, 1].norm()
    noise = torch.from_numpy(rng.normal(size=(20, 3)))
    noise = noise - (noise * unit_b).sum() * unit_b
    near[:, :, 4] = unit_b + 3 * RANK_TOL * noise / noise.norm()
    B = near.reshape(-1, 5)[:, some]
    assert beyond_doubt(B.T @ B, some, 20) is None
    assert identifiability(near, NAMES, some).rank == 4  # kept by the pivoting: above rank_tol, below the margin
    assert 3 < SAFE_RANK


def _thermal(temp_c, seed=1, n=40, still=None):
    """A plain-numpy ur5e session (tests/npsim.py) at temperatures temp_c (n,) degC; joint
    `still` (1-based) held at 0.3 rad."""
    import torchcal
    from npsim import thermal_session
    from torchcal.measurements import Measurements

    ur = torchcal.robot("ur5e")
    q = random_poses(ur, n, 3)
    if still is not None:
        q[:, still - 1] = 0.3
    t = torch.as_tensor(temp_c, dtype=torch.float64)
    return ur, Measurements(torch.arange(n), q, torch.from_numpy(thermal_session(ur, q.numpy(), t.numpy(), seed)),
                            temp_c=t)


def test_an_effect_the_data_cannot_identify_is_named_with_why():
    """thermal_expansion fitted on a session at one temperature: every parameter is held,
    so the effect changes nothing (`discover --effects thermal_expansion` listed it under
    'final effects' as physics); `unidentified_effects` names it and `unidentified_reason`
    the constant temp_c. On a session whose temperature varies it is identified; backlash
    on a joint that never moves is named with the joint."""
    import torchcal
    from torchcal.calibration.identifiability import unidentified_effects, unidentified_reason

    ur, m = _thermal(torch.full((40,), 25.0))
    res = torchcal.fit(ur, m, ["thermal_expansion"])
    assert unidentified_effects(res.model, res.report.held) == ["thermal_expansion"]
    assert unidentified_reason(res.model.effects[0], m) == "temp_c is 25 degC on every row"
    _, warm = _thermal(torch.linspace(18.0, 35.0, 40))
    res = torchcal.fit(ur, warm, ["thermal_expansion"])
    assert unidentified_effects(res.model, res.report.held) == []
    _, still = _thermal(torch.full((40,), 20.0), still=4)
    res = torchcal.fit(ur, still, ["backlash:2,4"])
    assert unidentified_effects(res.model, res.report.held) == []  # joint 2's lost motion is identified
    res = torchcal.fit(ur, still, ["backlash:4"])
    assert unidentified_effects(res.model, res.report.held) == ["backlash:4"]
    assert unidentified_reason(res.model.effects[0], still) == "q4 never moves"


def test_a_fit_of_fewer_than_two_equations_per_parameter_warns():
    """A ur5e (plain-numpy session, tests/npsim.py) fitted with joint_compliance:2,3 and
    gear_periodic:2,3 on 20 poses: about 50 parameters on 60 equations printed an rms below
    the noise with no word; its error on 100 new poses is several times that. One
    FewEquationsWarning says so; the geometric fit of the same poses, and 5 repeats of 8
    poses counted as 8 poses, are judged by their distinct poses."""
    import re
    import warnings

    import torchcal
    from npsim import physics_session
    from torchcal.calibration.identifiability import FewEquationsWarning
    from torchcal.measurements import Measurements

    ur = torchcal.robot("ur5e")
    q = random_poses(ur, 120, 3)
    xyz, pay = physics_session(ur, q.numpy(), 1, ["joint_compliance:2"], effect_mm=0.1)
    m = Measurements(torch.arange(120), q, torch.from_numpy(xyz), torch.from_numpy(pay))
    train, new = m.subset(torch.arange(20)), m.subset(torch.arange(20, 120))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        res = torchcal.fit(ur, train, ["joint_compliance:2,3", "gear_periodic:2,3"])
    said = [str(x.message) for x in w if issubclass(x.category, FewEquationsWarning)]
    assert len(said) == 1 and re.match(r"data: 20 distinct poses give 60 equations for \d+ identified parameters, "
                                       r"fewer than 2 per parameter: the fit's rms understates", said[0]), said
    assert torchcal.evaluate(res, new).rms_mm > 2 * res.rms_mm  # what it is about
    with warnings.catch_warnings():
        warnings.simplefilter("error", FewEquationsWarning)
        torchcal.fit(ur, train)
    eight = train.subset(torch.arange(8).repeat_interleave(5))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        torchcal.fit(ur, eight)
    said = [str(x.message) for x in w if issubclass(x.category, FewEquationsWarning)]
    assert len(said) == 1 and said[0].startswith("data: 8 distinct poses give 24 equations (40 rows; repeats of a "
                                                 "pose add none)"), said
