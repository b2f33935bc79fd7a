"""discover accepts only what the data determine.

- uncertainties include the prior: the posterior covariance against a numpy formula, and
  values the prior sets are labelled so (never listed as measured deviations);
- a candidate whose parameters only the prior sets is rejected in words, naming the
  parameter it is collinear with; an accepted effect is determined by the data;
- physical signs: backlash cannot end negative (projected steps, against scipy's bounded
  least squares);
- the step takes the largest refit gain, and what a round prints as accepted is in the
  final model;
- the residual stage only where its held-out gain is significant.

The refit rule's 2 % floor and the other pure acceptance rules: tests/test_selection.py.
"""

import json
import math

import numpy as np
import pytest
import scipy.optimize
import torch

import torchcal
from torchcal.calibration.covariance import parameter_covariance
from torchcal.calibration.fit import fit
from torchcal.calibration.lm import levenberg_marquardt
from torchcal.calibration.model import CalibrationModel
from torchcal.calibration.plausibility import determination, determination_words, plausible_scales
from torchcal.cli import main
from torchcal.diagnosis import discover
from torchcal.folds import fold_of_pose
from torchcal.diagnosis.candidates import Candidate
from torchcal.diagnosis.selection import REFIT_ALPHA
from torchcal.diagnosis.step import score_step
from torchcal.effects import context_of
from torchcal.effects.backlash import Backlash
from torchcal.io.measurement_csv import read_measurements
from torchcal.simulation.virtual_robot import VirtualRobot, random_poses

ROBOT = torchcal.robot("kr1000titan")


@pytest.fixture(scope="module")
def seed141(tmp_path_factory):
    """kr1000titan, gear_periodic:2 joint_compliance:3, 60 poses x 2 (the session of
    tests/test_discover.py)."""
    path = tmp_path_factory.mktemp("s141") / "s141.csv"
    assert main(["simulate", "--robot", "kr1000titan", "--effects", "gear_periodic:2", "joint_compliance:3",
                 "--n", "60", "--repeats", "2", "--seed", "141", "--out", str(path)]) == 0
    return path, read_measurements(path, robot=ROBOT)


def _csv(path, m):
    from torchcal.io.measurement_csv import write_measurements

    write_measurements(path, m)
    return path


# -- the posterior covariance ------------------------------------------------------------

def test_posterior_covariance_matches_the_numpy_formula():
    """Rows: C = s^2 (A'A + Pp)^-1, Pp = diag(prior^2) on the free columns; pose-level:
    B (meat + (sb2 + se2) Pp) B. Written here in plain numpy from the formulas."""
    rng = np.random.default_rng(3)
    N, P = 40, 5
    J = rng.normal(size=(N, 3, P))
    J[:, :, 4] = J[:, :, 3] + 1e-4 * rng.normal(size=(N, 3))  # nearly collinear pair
    r = rng.normal(scale=0.05, size=(N, 3))
    free = np.array([True, True, False, True, True])
    prior = np.array([0.0, 0.2, 0.3, 0.05, 0.05])
    c = parameter_covariance(torch.from_numpy(J), torch.from_numpy(r), torch.from_numpy(free),
                             prior=torch.from_numpy(prior))
    A = J[:, :, free].reshape(-1, free.sum())
    s2 = (r ** 2).sum() / (3 * N - free.sum())
    ref = s2 * np.linalg.inv(A.T @ A + np.diag(prior[free] ** 2))
    got = c.cov.numpy()[np.ix_(free, free)]
    np.testing.assert_allclose(got, ref, rtol=1e-8)
    assert np.all(c.cov.numpy()[2] == 0)
    # the data alone put the collinear pair at a huge sd; the prior caps it near its scale
    data_only = parameter_covariance(torch.from_numpy(J), torch.from_numpy(r), torch.from_numpy(free)).std.numpy()
    assert data_only[4] > 10 * (s2 ** 0.5 / prior[4])
    assert c.std.numpy()[4] < 1.05 * s2 ** 0.5 / prior[4]

    pose = np.repeat(np.arange(N // 2), 2)  # each pose measured twice: pose-level
    c2 = parameter_covariance(torch.from_numpy(J), torch.from_numpy(r), torch.from_numpy(free),
                              pose=torch.from_numpy(pose), prior=torch.from_numpy(prior))
    G, K = N // 2, free.sum()
    rbar = r.reshape(G, 2, 3).mean(1)
    se2 = ((r - np.repeat(rbar, 2, axis=0)) ** 2).sum() / (3 * (N - G))
    sb2 = max(0.0, ((2 * rbar ** 2).sum() / (3 * G - K) - se2) / 2)
    S = J[:, :, free].reshape(G, 2, 3, K).sum(1).reshape(-1, K)
    Pp = np.diag(prior[free] ** 2)
    B = np.linalg.inv(A.T @ A + Pp)
    ref2 = B @ (sb2 * S.T @ S + se2 * A.T @ A + (sb2 + se2) * Pp) @ B
    np.testing.assert_allclose(c2.cov.numpy()[np.ix_(free, free)], ref2, rtol=1e-8)


def _narrow_q1_session(seed=5, n=80):
    """Random kr1000titan poses with joint 1 held within +-2 deg: every harmonic of q1 is
    then (nearly) a constant plus a slope, so any two are collinear."""
    g = torch.Generator().manual_seed(seed)
    q = random_poses(ROBOT, n, g)
    q[:, 0] = torch.deg2rad(torch.rand(n, generator=g, dtype=q.dtype) * 4 - 2)
    return VirtualRobot(ROBOT, [], seed=seed).measure(q, noise_mm=0.02)


def test_a_harmonic_collinear_with_another_parameter_is_not_determined_and_says_why():
    m = _narrow_q1_session()
    ctx = context_of(ROBOT, m)
    model = CalibrationModel(ROBOT, ["gear_periodic:1"])
    res = fit(model, ctx, m.xyz, pose=m.pose)
    names = model.param_names()
    gear = [n for n in names if n.startswith("gear_1_")]
    bad = determination(res, gear, ctx)
    scales = plausible_scales(model)
    assert bad and all(d["why"] == "prior" for d in bad), bad
    for d in bad:  # the posterior sd is at most about the prior's and at least half of it
        i = names.index(d["name"])
        assert 0.5 * float(scales[i]) <= float(res.std[i]) <= 1.05 * float(scales[i])
        assert d["name"] in res.set_by_prior
    words = determination_words(bad[:1])
    assert words.startswith(f"not determined: {bad[0]['name']} +- ") and "deg against a plausible 0.1 deg" in words
    assert f"collinear with {bad[0]['partner']} (R^2 " in words and bad[0]["r2"] > 0.999, bad[0]
    assert bad[0]["partner"].startswith("gear_1_")  # sin1 and sin4 are both nearly the slope q1


def test_values_set_by_the_prior_are_labelled_and_not_listed_as_measured(tmp_path, capsys):
    """fit on the narrow-q1 session with gear_periodic:1: the printed uncertainty lines
    and MODEL.json mark the prior-set values; "largest deviations" never names one."""
    path = _csv(tmp_path / "narrow.csv", _narrow_q1_session())
    out = tmp_path / "model.json"
    assert main(["fit", str(path), "--robot", "kr1000titan", "--effects", "gear_periodic:1",
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    obj = json.loads(out.read_text())
    prior_set = obj["plausibility"]["set_by_prior"]
    assert any(n.startswith("gear_1_") for n in prior_set)
    for p in obj["parameters"]:
        assert p["set_by_prior"] == (p["name"] in prior_set)
        line = next((ln for ln in text.splitlines() if ln.startswith(f"  {p['name']} ")), None)
        if p["identified"]:
            assert line is not None and line.endswith("set by the prior") == p["set_by_prior"], line
    largest = next(ln for ln in text.splitlines() if ln.startswith("largest deviations:"))
    assert not any(n + " " in largest for n in prior_set), (largest, prior_set)
    assert "set by the prior (not determined by these poses" in text


# -- physical signs ------------------------------------------------------------------------

def test_projected_lm_matches_scipy_bounded_least_squares():
    """A small nonlinear problem whose unconstrained minimum has x1 < 0, with x1 >= 0:
    the projected LM ends where scipy's bounded trust-region solver does."""
    def r_np(x):
        return np.array([x[0] - 1.0, x[1] + 2.0, 0.5 * x[0] * x[1] - 0.3, x[0] + x[1] - 0.4])

    def r_t(x):
        return torch.stack([x[:, 0] - 1.0, x[:, 1] + 2.0, 0.5 * x[:, 0] * x[:, 1] - 0.3, x[:, 0] + x[:, 1] - 0.4], -1)

    ref = scipy.optimize.least_squares(r_np, [0.5, 0.5], bounds=([-np.inf, 0.0], [np.inf, np.inf]),
                                       xtol=1e-15, ftol=1e-15, gtol=1e-15)
    free_min = scipy.optimize.least_squares(r_np, [0.5, 0.5]).x
    assert free_min[1] < -0.5  # the bound is active
    res = levenberg_marquardt(r_t, torch.tensor([[0.5, 0.5]], dtype=torch.float64),
                              lower=torch.tensor([-math.inf, 0.0], dtype=torch.float64))
    np.testing.assert_allclose(res.x[0].numpy(), ref.x, atol=1e-7)
    assert res.status_labels() == ["converged"] and float(res.x[0, 1]) == 0.0


def test_backlash_cannot_end_negative():
    """Data with a lost motion of -0.01 deg on joint 2 (unphysical; the truth is written
    with plain numpy from the approach directions): the fitted backlash_2 ends at 0, not
    below; without the bound the same fit goes negative (so the test can fail)."""
    vr = VirtualRobot(ROBOT, [], seed=8)
    q = random_poses(ROBOT, 60, torch.Generator().manual_seed(8))
    m = vr.measure(q, noise_mm=0.0)
    ctx = context_of(ROBOT, m)
    model = CalibrationModel(ROBOT, ["backlash:2"])
    assert model.lower_bounds()[-1] == 0.0 and torch.isinf(model.lower_bounds()[:-1]).all()
    # truth: joint 2 offset approach * b / 2 with b = -0.01 deg, as a position change through
    # the geometric model's own joint-2 column (finite difference of the nominal FK)
    b = math.radians(-0.01)
    dq = np.zeros(tuple(q.shape))
    dq[:, 1] = ctx.approach[:, 1].numpy() * b / 2
    moved = ROBOT.fk(m.q + torch.from_numpy(dq)).detach()
    rng = np.random.default_rng(8)
    xyz = m.xyz + (moved - ROBOT.fk(m.q).detach()) + torch.from_numpy(rng.normal(scale=0.005, size=(len(m), 3)))
    res = fit(model, ctx, xyz, pose=m.pose)
    assert float(res.theta[-1]) == 0.0 and res.converged
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(Backlash, "lower_bounds", lambda self: None)
        free = fit(CalibrationModel(ROBOT, ["backlash:2"]), ctx, xyz, pose=m.pose)
    assert math.degrees(float(free.theta[-1])) < -0.005


def test_joint_clearance_magnitudes_are_bounded_at_zero():
    model = CalibrationModel(ROBOT, ["joint_clearance:3"])
    lo = model.lower_bounds()
    names = model.param_names()
    assert lo[names.index("clear_tilt_3")] == 0.0 and lo[names.index("clear_shift_3")] == 0.0


# -- the step: determined, largest refit gain, what is printed is what is held --------------

@pytest.fixture(scope="module")
def seed141_one_round(seed141):
    """`discover` of seed141 with max_rounds 1 (read by the two tests below: its round 0's
    geometric fit and scored current model are those `fit` and `score_current` give with
    the defaults; no test changes them)."""
    return discover(ROBOT, seed141[1], max_rounds=1, report_rest=False)


def test_the_step_takes_the_largest_refit_gain_not_the_shortlist_order(seed141, seed141_one_round):
    """axis_tilt:4 shortlisted before gear_periodic:2, both pass: the larger refit gain wins."""
    _, m = seed141
    ctx = context_of(ROBOT, m)
    folds = fold_of_pose(m.pose, 0, 5)
    round0 = seed141_one_round.diagnoses[0]  # the geometric model fitted and scored as diagnose does
    base, current = round0.baseline_fit, round0.step.current
    assert base.model.specs() == [] and current.effects == []
    cands = [Candidate("axis_tilt", (4,), 0.0, 0.0, 0.0, 1e-9, 2, True, 0.1, deterministic=True),
             Candidate("gear_periodic", (2,), 0.0, 0.0, 0.0, 1e-9, 8, True, 0.1, deterministic=True)]
    step = score_step(current, cands, m, ctx, folds, alpha=REFIT_ALPHA)  # diagnose's refit level
    passed = [s for s in step.refits if s.passed]
    assert len(passed) == 2, [s.reason for s in step.refits]
    best = min(passed, key=lambda s: s.cv_rms_mm)
    assert best.spec == "gear_periodic:2" and step.accepted is best
    assert "gear_periodic:2 gains more" in step.refits[0].reason
    # the accepted effect is determined: what the prior alone set is held, the rest determined
    new = [n for n in best.fit.model.param_names() if n not in base.model.param_names()]
    assert determination(best.fit, new, ctx) == []
    held = [n for n in new if n in best.fit.report.held]
    if held:
        assert "the prior alone set them" in best.reason and all(n in best.reason for n in held)


def test_every_accepted_line_is_in_the_final_model(seed141_one_round):
    """max_rounds 1: round 1's winner is not taken (round limit), and says so."""
    res = seed141_one_round
    for d in res.diagnoses:
        for ln in d.step.lines():
            if ": accepted (" in ln:
                spec = ln.split("+", 1)[1].split()[0]
                assert spec in res.final_effects, (ln, res.final_effects)
    assert len(res.final_effects) <= 1
    last = res.diagnoses[-1].step
    if len(res.diagnoses) == 2:
        assert last.accepted is None
        assert any("round limit" in s.reason for s in last.refits if s.passed) or not any(s.passed for s in last.refits)


# -- the residual stage --------------------------------------------------------------------

def test_residual_stage_refused_without_a_significant_held_out_gain(tmp_path, capsys):
    """Geometric errors and noise only: nothing for the stage to learn; fit refuses it with the figures."""
    vr = VirtualRobot(ROBOT, [], seed=21)
    m = vr.measure(random_poses(ROBOT, 80, torch.Generator().manual_seed(21)), noise_mm=0.02)
    res = torchcal.fit(ROBOT, m, residual_model="kernel")
    assert res.residual_model is None and res.residual_test is not None and not res.residual_test["applied"]
    t = res.residual_test
    assert f"rms {t['cv_with_mm']:.4f} mm with the stage vs {t['cv_without_mm']:.4f} mm without" in t["reason"]


def test_residual_stage_applied_where_it_earns_its_place():
    """A smooth error the physical model lacks (0.2 mm sin(2 q3) along z, plain numpy): the
    stage passes the held-out test and is applied."""
    vr = VirtualRobot(ROBOT, [], seed=22)
    m = vr.measure(random_poses(ROBOT, 120, torch.Generator().manual_seed(22)), noise_mm=0.02)
    bend = np.zeros((len(m), 3))
    bend[:, 2] = 0.2 * np.sin(2 * m.q[:, 2].numpy())
    import dataclasses

    m = dataclasses.replace(m, xyz=m.xyz + torch.from_numpy(bend))
    res = torchcal.fit(ROBOT, m, residual_model="kernel")
    t = res.residual_test
    assert t["applied"] and res.residual_model is not None, t
    assert t["cv_with_mm"] < 0.98 * t["cv_without_mm"] and t["p_value"] < 0.05


def test_discover_residual_model_applies_the_same_test(tmp_path, capsys):
    vr = VirtualRobot(ROBOT, [], seed=23)
    path = _csv(tmp_path / "null.csv", vr.measure(random_poses(ROBOT, 60, torch.Generator().manual_seed(23)),
                                                  noise_mm=0.02))
    js = tmp_path / "d.json"
    assert main(["discover", str(path), "--robot", "kr1000titan", "--residual-model", "kernel",
                 "--json", str(js)]) == 0
    out = capsys.readouterr().out
    stage = json.loads(js.read_text())["residual_stage"]
    assert stage is not None and not stage["applied"]
    assert f"residual stage refused: held-out {stage['reason']}" in out
