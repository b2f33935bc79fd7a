"""Fold refits from the shared Jacobian (torchcal.calibration.refit) against the LM fold
refit they replace (`crossval.fold_fit`, `fit` on the training rows from the full fit).

The agreement asked: held-out predicted positions within 1e-6 mm (the LM's own stopping
rule leaves its fold refits within about that of the stationary point on extrapolating
split halves); a wrong algebra (the fold's rows kept, the prior counted twice) moves them
by far more (kept rows > 1e-3 mm, a doubled prior 5e-5 mm here), which the mutation
checks below show on the same data."""

import math
from pathlib import Path

import numpy as np
import pytest
import torch

import torchcal
import torchcal.calibration.refit as rf
import torchcal.diagnosis.step as step
from torchcal.calibration.fit import fit
from torchcal.calibration.model import CalibrationModel
from torchcal.calibration.prior import prior_factors
from torchcal.diagnosis.crossval import fold_fit, fold_refits, held_out_errors
from torchcal.diagnosis.stability import halves
from torchcal.effects import context_of
from torchcal.folds import fold_of_pose
from torchcal.io.measurement_csv import read_measurements
from torchcal.measurements import Measurements, split_by_pose
from torchcal.robots.poses import random_poses

from npsim import physics_session

UR10 = Path(__file__).resolve().parents[1] / "examples" / "ur10"
TOL_MM = 1e-6


def _split(series):
    """(robot, the training split (60 % of the poses, seed 0) of UR10 series `series`, its context)."""
    robot = torchcal.robot(UR10 / "ur10.json")
    m = read_measurements(UR10 / f"series_{series}.csv", robot=robot)
    m = m.subset(split_by_pose(m.pose, 0.6, 0))
    return robot, m, context_of(robot, m)


@pytest.fixture(scope="module")
def ur10_c():
    """UR10 series C's training split (positions and orientations), fitted with base_frame,
    tool_offset and joint_periodic:2@20+29 (nonlinear; the prior holds the periodic terms
    and the MD-H deviations)."""
    robot, m, ctx = _split("c")
    model = CalibrationModel.for_measurements(robot, ["base_frame", "tool_offset", "joint_periodic:2@20+29"], m)
    full = fit(model, ctx, m.xyz, pose=m.pose, rotation=m.rotation)
    assert full.plausible_limits is not None and m.rotation is not None
    return full, m, ctx


def _predicted(full, res, ctx, test):
    with torch.no_grad():
        return full.model.predict(res.theta, ctx.subset(test))


def _compare(full, m, ctx, folds, posterior, lm=None):
    """Largest held-out position difference (mm) and largest relative std difference of
    the shared refits against the LM fold fits, over the folds; asserts the shared path ran.
    lm: a dict that receives the LM fold fits, fold -> FitResult."""
    sh = rf.shared(full, ctx, m.rotation is not None)
    worst = worst_sd = 0.0
    for f in np.unique(folds):
        test = torch.from_numpy(folds == f)
        new = rf.refit(full, sh, m, ctx, ~test, sigma_mm=0.01, sigma_deg=0.01, posterior=posterior)
        assert new is not None  # the chord refit applied (no LM fallback)
        old = fold_fit(full, m, ctx, ~test, sigma_mm=0.01, sigma_deg=0.01, posterior=posterior)
        if lm is not None:
            lm[int(f)] = old
        assert torch.equal(new.report.free, old.report.free)
        moved = (_predicted(full, new, ctx, test) - _predicted(full, old, ctx, test)).norm(dim=-1)
        worst = max(worst, float(moved.max()))
        assert torch.allclose(new.residuals, old.residuals, atol=TOL_MM, rtol=0)
        if posterior:
            fr = new.report.free
            worst_sd = max(worst_sd, float(((new.std[fr] - old.std[fr]).abs() / old.std[fr]).max()))
    return worst, worst_sd


def test_shared_refit_equals_the_lm_fold_refit_with_orientations_and_the_prior(ur10_c):
    full, m, ctx = ur10_c
    worst, _ = _compare(full, m, ctx, fold_of_pose(m.pose, 0, 5), posterior=False)
    assert worst <= TOL_MM, worst


def test_shared_refit_equals_the_lm_on_split_halves_with_the_posterior(ur10_c):
    """The stability check's halves (half the rows removed, predictions extrapolated) and
    the posterior its determination rule reads."""
    full, m, ctx = ur10_c
    for name, half in list(halves(m).items())[:3]:
        worst, worst_sd = _compare(full, m, ctx, half, posterior=True)
        assert worst <= TOL_MM and worst_sd <= 1e-5, (name, worst, worst_sd)


def test_mutations_of_the_algebra_move_the_predictions_far_beyond_the_tolerance(ur10_c, monkeypatch):
    """The fold's rows kept in the fit, or the prior counted twice: the comparison above
    would fail by orders of magnitude."""
    full, m, ctx = ur10_c
    folds = fold_of_pose(m.pose, 0, 5)
    test = torch.from_numpy(folds == 0)
    sh = rf.shared(full, ctx, True)
    ref = _predicted(full, fold_fit(full, m, ctx, ~test, sigma_mm=0.01, sigma_deg=0.01), ctx, test)
    kept = rf.refit(full, sh, m, ctx, torch.ones_like(test), sigma_mm=0.01, sigma_deg=0.01)
    assert float((_predicted(full, kept, ctx, test) - ref).norm(dim=-1).max()) > 1e3 * TOL_MM
    # the prior rows' information rho^2 / s^2 counted twice
    monkeypatch.setattr(rf, "prior_factors", lambda rho, s: math.sqrt(2) * prior_factors(rho, s))
    twice = rf.refit(full, sh, m, ctx, ~test, sigma_mm=0.01, sigma_deg=0.01)
    assert float((_predicted(full, twice, ctx, test) - ref).norm(dim=-1).max()) > 10 * TOL_MM


def test_positions_only_refit_cv_equals_the_lm_fold_refits():
    """A simulated session (plain-numpy physics: gear error on joint 2, a moved base),
    positions only: held_out_errors through the shared refits against the LM's."""
    robot = torchcal.robot("kr1000titan")
    q = random_poses(robot, 80, torch.Generator().manual_seed(5)).numpy()
    xyz, _ = physics_session(robot, q, 5, ["gear_periodic:2", "base_frame"])
    m = Measurements(pose=torch.arange(80), q=torch.from_numpy(q), xyz=torch.from_numpy(xyz))
    ctx = context_of(robot, m)
    model = CalibrationModel.for_measurements(robot, ["base_frame", "gear_periodic:2"], m)
    full = fit(model, ctx, m.xyz, pose=m.pose)
    folds = fold_of_pose(m.pose, 0, 5)
    lm = {}
    worst, _ = _compare(full, m, ctx, folds, posterior=False, lm=lm)
    assert worst <= TOL_MM, worst
    new = held_out_errors(full, m, ctx, folds, sigma_mm=0.01, sigma_deg=0.01)
    old = np.zeros(len(m))
    for f in range(5):
        test = torch.from_numpy(folds == f)
        res = lm[f]  # the LM fold fit of the comparison above (the posterior changes no theta)
        old[test.numpy()] = (model.predict(res.theta, ctx.subset(test)) - m.xyz[test]).pow(2).sum(-1).numpy()
    assert new == pytest.approx(old, abs=1e-9)


@pytest.mark.parametrize("case", ["robust", "crawls"])
def test_where_the_chord_does_not_apply_the_lm_refits(case):
    """Where the chord refit does not apply, fold_refits gives fold_fit's result exactly:
    a robust full fit; gear_periodic:2 on series D (its training split), whose tool_z the folds move by 10 mm
    along a nearly flat direction (the chord crawls and hands over to the LM)."""
    robot, m, ctx = _split("d")
    if case == "robust":
        model = CalibrationModel.for_measurements(robot, ["base_frame", "tool_offset"], m)
        full = fit(model, ctx, m.xyz, pose=m.pose, robust="huber")
        assert not rf.applies(full)
    else:
        model = CalibrationModel.for_measurements(robot, ["base_frame", "tool_offset", "gear_periodic:2"], m)
        full = fit(model, ctx, m.xyz, pose=m.pose, rotation=m.rotation)
        sh = rf.shared(full, ctx, True)
        assert rf.refit(full, sh, m, ctx, torch.from_numpy(fold_of_pose(m.pose, 0, 3) != 0),
                        sigma_mm=0.01, sigma_deg=0.01) is None
    folds = fold_of_pose(m.pose, 0, 3)
    for test, res in fold_refits(full, m, ctx, folds, sigma_mm=0.01, sigma_deg=0.01, posterior=False):
        ref = fold_fit(full, m, ctx, ~test, sigma_mm=0.01, sigma_deg=0.01, posterior=False)
        assert torch.equal(res.theta, ref.theta)


@pytest.mark.parametrize("specs", [["base_frame", "tool_offset", "joint_periodic:2@20+21+29"],
                                   ["base_frame", "tool_offset", "joint_periodic:2@20"]])
def test_refit_from_a_per_fold_start_equals_the_lm_fold_fit(ur10_c, specs):
    """The per-fold models of the procedure CV (torchcal/diagnosis/procedure_cv.py): the
    fold's own orders, started from the full fit's values matched by name (an order the
    full fit lacks at zero), fitted by chord iterations from the start's own Jacobian
    (`refit_from`) against the LM fold fit from the same start: the same free set, the
    held-out positions within TOL_MM; the start is far from the fold's fit (the chord had
    work to do), and the fold's rows left in move the prediction by far more."""
    from torchcal.diagnosis.procedure_cv import fold_start

    full, m, ctx = ur10_c
    start = fold_start(full, full, specs, m)
    folds = fold_of_pose(m.pose, 0, 5)
    for f in range(3):
        test = torch.from_numpy(folds == f)
        new = rf.refit_from(start, m, ctx, ~test, sigma_mm=0.01, sigma_deg=0.01, posterior=False)
        assert new is not None  # the chord applied
        old = fold_fit(start, m, ctx, ~test, sigma_mm=0.01, sigma_deg=0.01, posterior=False)
        assert torch.equal(new.report.free, old.report.free)
        ref = _predicted(start, old, ctx, test)
        assert float((_predicted(start, new, ctx, test) - ref).norm(dim=-1).max()) <= TOL_MM
        assert float((_predicted(start, start, ctx, test) - ref).norm(dim=-1).max()) > 1e-3
    kept = rf.refit_from(start, m, ctx, torch.ones_like(test), sigma_mm=0.01, sigma_deg=0.01, posterior=False)
    assert float((_predicted(start, kept, ctx, test) - ref).norm(dim=-1).max()) > 1e3 * TOL_MM


# The warm-started full fits (`warm_fit`) of `discover` by chord iterations
# (`torchcal.calibration.refit.warm_fit`) against the LM `fit` they replace.
#
# `candidate_fit` (a candidate's full fit from the current fit's values) and
# `stability.without` (a reduced model's) call `warm_fit` and fall back to `fit`. The
# agreement asked: the same free set, fitted positions within 1e-6 mm of the LM's on every
# row (the LM stops at a relative cost change of 1e-12, which leaves it about that far from
# the stationary point), the prior's rho within 1e-8 and the posterior sd within 1e-5
# relative; the start is far from the fit (the chord had work to do), and a fit whose rho
# is not re-estimated moves the positions by far more.


@pytest.fixture(scope="module")
def ur10_c_periodic(ur10_c):
    """UR10 series C's training split (positions and orientations) and its fit with
    base_frame, tool_offset and joint_periodic:2@20+29: the current model of a step (the
    fit of `ur10_c`, which no test changes)."""
    return ur10_c


def _lm_candidate(monkeypatch, base, spec, m, ctx):
    """`candidate_fit` as it was: the LM `fit` (warm_fit switched off)."""
    with monkeypatch.context() as mp:
        mp.setattr(step, "warm_fit", lambda *a, **k: None)
        return step.candidate_fit(base, spec, m, ctx, sigma_mm=0.01, sigma_deg=0.01)


def _moved(a, b, ctx) -> float:
    """Largest distance (mm) between the fitted positions of the fits a and b on ctx's rows."""
    with torch.no_grad():
        return float((a.model.predict(a.theta, ctx) - b.model.predict(b.theta, ctx)).norm(dim=-1).max())


@pytest.mark.parametrize("spec", ["joint_periodic:3@18+30", "joint_periodic:2@21", "gear_periodic:2"])
def test_candidate_fit_by_chord_equals_the_lm_fit(ur10_c_periodic, monkeypatch, spec):
    base, m, ctx = ur10_c_periodic
    calls = []
    with monkeypatch.context() as mp:  # the chord applied (no fallback to the LM)
        mp.setattr(step, "warm_fit", lambda *a, **k: calls.append(rf.warm_fit(*a, **k)) or calls[-1])
        new = step.candidate_fit(base, spec, m, ctx, sigma_mm=0.01, sigma_deg=0.01)
    assert calls and calls[0] is not None
    old = _lm_candidate(monkeypatch, base, spec, m, ctx)
    assert torch.equal(new.report.free, old.report.free) and new.report.held == old.report.held
    assert _moved(new, old, ctx) <= TOL_MM
    assert abs(new.plausible_limits["prior_sigma_mm"] / old.plausible_limits["prior_sigma_mm"] - 1) <= 1e-8
    fr = old.report.free
    assert float(((new.std[fr] - old.std[fr]).abs() / old.std[fr]).max()) <= 1e-5
    assert float((new.tool_rotation - old.tool_rotation).abs().max()) <= 1e-9
    assert _moved(base, old, ctx) > 1e-2  # the start is far from the fit


def test_a_rho_left_at_the_first_solve_moves_the_fit_far_beyond_the_tolerance(ur10_c_periodic, monkeypatch):
    """rho held at sigma_mm (the first solve's) instead of the fit's own residual RMS: the
    comparison above would fail by orders of magnitude."""
    base, m, ctx = ur10_c_periodic
    old = _lm_candidate(monkeypatch, base, "joint_periodic:3@18+30", m, ctx)
    monkeypatch.setattr(rf, "prior_strength", lambda resid, robust=False: 0.01)
    new = step.candidate_fit(base, "joint_periodic:3@18+30", m, ctx, sigma_mm=0.01, sigma_deg=0.01)
    assert _moved(new, old, ctx) > 10 * TOL_MM  # measured 6.5e-5 mm


def test_positions_only_warm_fit_equals_the_lm_fit():
    """A simulated session (plain-numpy physics: lost motion on joint 3, gear error on joint
    2; positions only, so no tool-rotation step and the first solve certified as well):
    gear_periodic:2 added at zero to the backlash:3 fit, its held parameters held, as
    `candidate_fit` does."""
    robot = torchcal.robot("kr1000titan")
    q = random_poses(robot, 240, torch.Generator().manual_seed(1)).numpy()
    xyz, _ = physics_session(robot, q, 1, ["backlash:3", "gear_periodic:2"])
    m = Measurements(pose=torch.arange(240), q=torch.from_numpy(q), xyz=torch.from_numpy(xyz))
    ctx = context_of(robot, m)
    base = fit(CalibrationModel.for_measurements(robot, ["backlash:3"], m), ctx, m.xyz, pose=m.pose)
    model = CalibrationModel.for_measurements(robot, ["backlash:3", "gear_periodic:2"], m)
    names = base.model.param_names()
    theta0 = torch.stack([base.theta[names.index(n)] if n in names else base.theta.new_zeros(())
                          for n in model.param_names()])
    free = model.default_free() & torch.tensor([n not in base.report.held for n in model.param_names()])
    new = rf.warm_fit(model, ctx, m.xyz, theta0, free, pose=m.pose, sigma_mm=0.01, sigma_deg=0.01)
    assert new is not None and new.orientation is None
    old = fit(model, ctx, m.xyz, theta0=theta0, free=free, pose=m.pose)
    assert torch.equal(new.report.free, old.report.free)
    assert _moved(new, old, ctx) <= TOL_MM and _moved(base, old, ctx) > 1e-2
    assert abs(new.plausible_limits["prior_sigma_mm"] / old.plausible_limits["prior_sigma_mm"] - 1) <= 1e-8
    fr = old.report.free
    assert float(((new.std[fr] - old.std[fr]).abs() / old.std[fr]).max()) <= 1e-5


def test_where_the_chord_does_not_apply_candidate_fit_is_the_lm_fit(monkeypatch):
    """Series D's training split, gear_periodic:2 on the geometric fit: the chord crawls
    (its folds move tool_z by 10 mm along a nearly flat direction, tests/test_refit.py),
    warm_fit says so, and candidate_fit is the LM fit exactly."""
    robot, m, ctx = _split("d")
    model = CalibrationModel.for_measurements(robot, ["base_frame", "tool_offset"], m)
    base = fit(model, ctx, m.xyz, pose=m.pose, rotation=m.rotation)
    calls = []
    with monkeypatch.context() as mp:
        mp.setattr(step, "warm_fit", lambda *a, **k: calls.append(rf.warm_fit(*a, **k)) or calls[-1])
        new = step.candidate_fit(base, "gear_periodic:2", m, ctx, sigma_mm=0.01, sigma_deg=0.01)
    assert calls == [None]
    old = _lm_candidate(monkeypatch, base, "gear_periodic:2", m, ctx)
    assert torch.equal(new.theta, old.theta) and torch.equal(new.std, old.std)


def test_consecutive_fold_refits_of_one_model_share_its_jacobian(monkeypatch):
    """The stability check refits one model on the halves of every split in turn: one
    shared Jacobian for them (`crossval._shared`), the same refits as with a fresh one
    each time; another model, or the same one with its theta changed, gets its own."""
    import numpy as np

    import torchcal.diagnosis.crossval as cv

    robot = torchcal.robot("kr1000titan")
    q = random_poses(robot, 120, torch.Generator().manual_seed(2)).numpy()
    xyz, _ = physics_session(robot, q, 2, ["backlash:3"])
    m = Measurements(pose=torch.arange(120), q=torch.from_numpy(q), xyz=torch.from_numpy(xyz))
    ctx = context_of(robot, m)
    full = fit(CalibrationModel.for_measurements(robot, ["backlash:3"], m), ctx, m.xyz, pose=m.pose)
    splits = [(np.arange(120) % 2), (np.arange(120) < 60).astype(np.int64)]
    calls = []
    monkeypatch.setattr(rf, "shared", lambda *a: calls.append(a[0]) or rf.Shared(*_fresh(*a)))
    monkeypatch.setattr(cv, "_LAST_SHARED", [])

    def refits(f, fresh=False):
        out = []
        for s in splits:
            if fresh:  # the reference: a Jacobian of its own for every call
                cv._LAST_SHARED.clear()
            out += [res.theta for _, res in cv.fold_refits(f, m, ctx, s, sigma_mm=0.01, sigma_deg=0.01)]
        return out

    reference = refits(full, fresh=True)
    assert len(calls) == 2
    cv._LAST_SHARED.clear()
    assert all(torch.equal(a, b) for a, b in zip(refits(full), reference)) and len(calls) == 3
    other = fit(full.model, ctx, m.xyz, pose=m.pose)  # equal values, another object
    refits(other)
    assert len(calls) == 4
    full.theta[0] += 1e-3  # changed in place: evaluated again
    refits(full)
    assert len(calls) == 5


def _fresh(full, ctx, orientation):
    """The fields of `refit.shared` (evaluated by the model, as it does)."""
    with torch.no_grad():
        if not orientation:
            return full.theta, full.model.jacobians(full.theta, ctx)[0]
        J, W, R = full.model.jacobians(full.theta, ctx, rotation=True, frame=True)
    return full.theta, J, W, R
