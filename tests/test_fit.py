"""`fit` as a composition (torchcal.calibration.fit): the statistics inside it pinned
against independent references.

- the prior: the fitted parameters are the maximum a posteriori estimate of the
  documented objective (measurement rows plus rows rho * theta_i / s_i, rho the per-axis
  RMS of the fit's own residual), solved here by scipy; a prior twice or half as strong
  moves the prior-set parameters by 0.2-0.5 posterior sd;
- the covariance: degrees of freedom 3N - K (6N - K with orientations) and s^2 the
  residual sum of squares over them, recomputed from the residuals;
- IRLS: the robust solve is a fixed point of its kernel (scipy weighted least squares);
- the start: the registration of a model with a base frame; keyword-only options.
"""

import math
from pathlib import Path

import numpy as np
import pytest
import torch

import torchcal
from torchcal.calibration.fit import fit, start
from torchcal.calibration.model import CalibrationModel
from torchcal.calibration.plausibility import plausible_scales
from torchcal.calibration.rows import Rows
from torchcal.effects import context_of
from torchcal.io.measurement_csv import read_measurements
from torchcal.simulation.virtual_robot import VirtualRobot, random_poses

ROBOT = torchcal.robot("kr1000titan")
UR10 = Path(__file__).resolve().parents[1] / "examples" / "ur10"


@pytest.fixture(scope="module")
def narrow():
    """60 kr1000titan poses with joint 1 within +-2 deg (its harmonics collinear with
    dtheta1, so the prior sets some of them), geometric errors and 0.02 mm noise; the fit
    with gear_periodic:1."""
    g = torch.Generator().manual_seed(5)
    q = random_poses(ROBOT, 60, g)
    q[:, 0] = torch.deg2rad(torch.rand(60, generator=g, dtype=q.dtype) * 4 - 2)
    m = VirtualRobot(ROBOT, [], seed=5).measure(q, noise_mm=0.02)
    model = CalibrationModel(ROBOT, ["gear_periodic:1"])
    ctx = context_of(ROBOT, m)
    return model, ctx, m, fit(model, ctx, m.xyz)


def _map(model, ctx, m, res, strength):
    """scipy's solution of the documented objective: rows model - measured and
    strength * theta_i / s_i, over the parameters res identified, from res.theta."""
    import scipy.optimize
    s = plausible_scales(model).numpy()
    fin = np.isfinite(s)
    factor = np.where(fin, strength / np.where(fin, s, 1.0), 0.0)
    free = res.report.free

    def f(t):
        th = res.theta.clone()
        th[free] = torch.from_numpy(t)
        return np.concatenate([(model.predict(th, ctx) - m.xyz).reshape(-1).numpy(), factor * th.numpy()])
    return scipy.optimize.least_squares(f, res.theta[free].numpy(), method="lm", xtol=1e-15, ftol=1e-15,
                                        gtol=1e-15).x


def test_the_prior_strength_is_the_fits_own_per_axis_rms(narrow):
    _, _, _, res = narrow
    rho = res.plausible_limits["prior_sigma_mm"]
    per_axis = float(res.residuals.pow(2).mean().sqrt())
    assert rho == pytest.approx(per_axis, rel=0.1)  # settled within 10 % (prior.rho_settled)
    assert rho < 0.7 * float(res.residuals.norm(dim=-1).pow(2).mean().sqrt())  # not the distance RMS


def test_the_fit_is_the_map_estimate_of_the_documented_prior(narrow):
    model, ctx, m, res = narrow
    assert res.converged and res.set_by_prior  # the prior matters here
    rho = res.plausible_limits["prior_sigma_mm"]
    sd = res.std[res.report.free].numpy()
    th = res.theta[res.report.free].numpy()
    assert np.max(np.abs(th - _map(model, ctx, m, res, rho)) / sd) < 1e-3
    for other in (2 * rho, 0.5 * rho):  # a prior of another strength ends measurably elsewhere
        assert np.max(np.abs(th - _map(model, ctx, m, res, other)) / sd) > 0.1


def test_covariance_degrees_of_freedom_from_the_residuals(narrow):
    _, _, m, res = narrow
    K = int(res.report.free.sum())
    assert res.covariance.method == "rows" and res.covariance.dof == 3 * len(m) - K
    ssr = float(res.residuals.pow(2).sum())
    assert res.covariance.sigma_mm ** 2 == pytest.approx(ssr / (3 * len(m) - K), rel=1e-12)


@pytest.fixture(scope="module")
def ur10_rows():
    robot = torchcal.robot(UR10 / "ur10.json")
    m = read_measurements(UR10 / "series_d.csv", robot=robot)
    return robot, m.subset(torch.arange(80))


def test_covariance_degrees_of_freedom_with_orientations(ur10_rows):
    """Six rows per pose: dof 6N - K, s^2 = sum of the squared position and weighted
    orientation rows over it (the rows recomputed from the fitted tool rotation)."""
    robot, m = ur10_rows
    model = CalibrationModel.for_measurements(robot, ["base_frame", "tool_offset"], m)
    ctx = context_of(robot, m)
    res = fit(model, ctx, m.xyz, rotation=m.rotation)
    K = int(res.report.free.sum())
    assert res.covariance.dof == 6 * len(m) - K
    rows = Rows(model, ctx, m.xyz, m.rotation, res.orientation["weight_mm_per_rad"], res.tool_rotation)
    ssr = float(rows.residual(res.theta).pow(2).sum())
    assert res.covariance.sigma_mm ** 2 == pytest.approx(ssr / (6 * len(m) - K), rel=1e-10)
    assert res.orientation["weight_mm_per_rad"] == pytest.approx(0.01 / math.radians(0.01))


def test_the_start_of_a_model_with_a_base_frame_is_its_registration(ur10_rows):
    robot, m = ur10_rows
    model = CalibrationModel(robot, ["base_frame", "tool_offset"])
    ctx = context_of(robot, m)
    theta, info = start(model, ctx, m.xyz)
    assert info is not None and info["rms_after_mm"] < 0.05 * info["rms_before_mm"]
    given = model.zeros() + 1.0
    assert start(model, ctx, m.xyz, given) == (given, None)
    assert start(model, ctx, m.xyz, register=False)[1] is None
    assert start(CalibrationModel(robot), ctx, m.xyz)[1] is None  # no frame to register


def test_a_fit_without_its_posterior_has_the_same_parameters(narrow):
    """posterior=False (the fold refits of a cross-validation): the same theta to the bit,
    no covariance, std NaN, nothing named as set by the prior."""
    model, ctx, m, res = narrow
    lean = fit(model, ctx, m.xyz, posterior=False)
    assert torch.equal(lean.theta, res.theta) and lean.covariance is None
    assert bool(torch.isnan(lean.std).all()) and lean.set_by_prior == []
    assert res.covariance is not None and bool(torch.isfinite(res.std).all())


def test_options_are_keyword_only(narrow):
    model, ctx, m, _ = narrow
    with pytest.raises(TypeError):
        fit(model, ctx, m.xyz, model.zeros())


def test_robust_solve_is_a_fixed_point_of_its_kernel():
    """IRLS (`solve` with robust='huber'): the solution is scipy's weighted least-squares
    solution for the weights it reports, and those weights are the Huber weights of its
    own distance residuals (to the IRLS tolerance); the gross rows end down-weighted.
    The free set is an identifiable one, as `fit` passes to `solve`: with unidentifiable
    columns free the least-squares minimum is a valley, and two solvers end at different
    points of it (2e-3 apart along near-null directions, equal cost to 1e-6)."""
    import scipy.optimize
    from torchcal.calibration.fit import WEIGHT_TOL, solve
    from torchcal.calibration.identifiability import identifiability
    from torchcal.calibration.robust import robust_weights

    m = VirtualRobot(ROBOT, [], seed=11).measure(random_poses(ROBOT, 80, torch.Generator().manual_seed(12)),
                                                 noise_mm=0.02)
    xyz = m.xyz.clone()
    xyz[[3, 40, 77]] += torch.tensor([4.0, -3.0, 5.0], dtype=torch.float64)
    model = CalibrationModel(ROBOT)
    ctx = context_of(ROBOT, m)
    rows = Rows(model, ctx, xyz)
    cand = model.default_free()
    cand[[0, 1]] = False  # any fixed subset: solve moves the others only
    free = identifiability(rows.jacobian(model.zeros()), model.param_names(), cand).free
    assert not bool(free[[0, 1]].any()) and int(free.sum()) >= 15
    s = solve(rows, model.zeros()[None], free, torch.zeros(model.n_params, dtype=torch.float64), robust="huber")
    dist = (model.predict(s.x[0], ctx) - xyz).norm(dim=-1)
    assert float((robust_weights(dist, "huber") - s.weights).abs().max()) < WEIGHT_TOL
    assert s.weights[[3, 40, 77]].max() < 0.1 and s.weights.min() == s.weights[[3, 40, 77]].min()
    sw = s.weights.sqrt().repeat_interleave(3).numpy()

    def f(t):
        th = model.zeros()
        th[free] = torch.from_numpy(t)
        return sw * (model.predict(th, ctx) - xyz).reshape(-1).numpy()
    ref = scipy.optimize.least_squares(f, s.x[0, free].numpy(), method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    np.testing.assert_allclose(s.x[0, free].numpy(), ref, atol=1e-8)
    assert bool((s.x[0, ~free] == 0).all())


def test_the_rank_shortcut_of_a_fold_refit_gives_the_same_fit(narrow, monkeypatch):
    """`fit(rank_shortcut=True)` (the fold refits of `crossval.fold_fit`): from a warm start
    whose candidates are identifiable beyond doubt it skips the pivoting and gives the
    same fit to the bit (theta, free set, nothing held); where they are not (every
    parameter a candidate, the gauge among them), it pivots as before and holds the same
    parameters."""
    import torchcal.calibration.fit as fit_module

    model, ctx, m, res = narrow
    pivots = []
    real = fit_module.identifiability
    monkeypatch.setattr(fit_module, "identifiability", lambda *a, **k: pivots.append(1) or real(*a, **k))
    train = torch.arange(len(m.xyz)) % 5 != 0
    sub = ctx.subset(train)
    rho = res.plausible_limits["prior_sigma_mm"]
    kw = dict(pose=m.pose[train], register=False, prior_sigma_mm=rho, posterior=False)
    for cand, doubt in ((model.default_free(), True), (res.report.free, False)):
        pivots.clear()
        plain = fit(model, sub, m.xyz[train], theta0=res.theta, free=cand, **kw)
        assert len(pivots) == 1
        quick = fit(model, sub, m.xyz[train], theta0=res.theta, free=cand, rank_shortcut=True, **kw)
        assert torch.equal(quick.theta, plain.theta) and torch.equal(quick.report.free, plain.report.free)
        assert quick.report.held == plain.report.held
        assert len(pivots) == (2 if doubt else 1)  # pivoted again only where in doubt
        assert (quick.report.held != []) == doubt  # all candidates: the gauge and harmonics held


def test_the_solvers_jacobian_buffer_is_rewritten_at_every_iteration(narrow):
    """`solve` writes every LM iteration's Jacobian into one buffer per solve: its solution
    is, to the bit, the LM's with a freshly allocated Jacobian per iteration (a stale
    buffer would step along an old Jacobian and stop elsewhere)."""
    from torchcal.calibration.fit import solve
    from torchcal.calibration.lm import levenberg_marquardt
    from torchcal.calibration.prior import prior_factors

    model, ctx, m, res = narrow
    rows = Rows(model, ctx, m.xyz)
    prior = prior_factors(res.plausible_limits["prior_sigma_mm"], plausible_scales(model))
    x0 = model.zeros()[None]
    s = solve(rows, x0, res.report.free, prior)
    P = model.n_params
    ref = levenberg_marquardt(lambda z: torch.cat([rows.residual(z[0]).reshape(-1), prior * z[0]])[None], x0,
                              free=res.report.free, max_iter=60,
                              jacobian_fn=lambda z: torch.cat([rows.jacobian(z[0]).reshape(-1, P),
                                                               torch.diag(prior)])[None])
    assert s.n_iter == int(ref.n_iter[0]) >= 3
    assert torch.equal(s.x, ref.x)


def test_cli_fit_names_an_effect_the_data_cannot_identify(tmp_path, capsys):
    """`torchcal fit --effects thermal_expansion` on a session at one temperature listed its
    parameters among the held ones only; one line now says the effect changes nothing and
    why (the temperature the same on every row)."""
    from test_identifiability import _thermal
    from torchcal.cli import main
    from torchcal.io.measurement_csv import write_measurements

    ur, m = _thermal(torch.full((40,), 25.0))
    write_measurements(tmp_path / "d.csv", m, robot=ur)
    assert main(["fit", str(tmp_path / "d.csv"), "--robot", "ur5e", "--effects", "thermal_expansion",
                 "--out", str(tmp_path / "m.json")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert ("thermal_expansion: none of its parameters is identifiable from these data (all held at nominal: "
            "temp_c is 25 degC on every row): it changes nothing") in lines
