"""`joint_periodic:J@K+K` and the held-out spectral search of its orders.

The simulated "real" robot here is plain numpy (its own FK from the MD-H table, not
torchcal's kinematics or effect classes): a UR10 with MD-H errors, an unmodelled
gravity-like compliance of joints 2 and 3, 0.03 mm noise, over joint ranges like those of
a real session (90-180 deg per joint), optionally with a periodic error of joint 2 at
17 and 31 cycles per turn (60 and 50 arcsec).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from npsim import numpy_fk

from torchcal.calibration.fit import fit
from torchcal.calibration.model import CalibrationModel
from torchcal.folds import fold_of_pose
from torchcal.diagnosis.spectral import order_limits, propose_orders, search_orders
from torchcal.effects import build, context_of, make_context
from torchcal.effects.spec import EffectSpec, parse_spec, parse_specs
from torchcal.errors import InputError
from torchcal.measurements import Measurements
from torchcal.io.robot_file import load_robot_file

ROOT = Path(__file__).resolve().parents[1]
UR10 = load_robot_file(ROOT / "examples" / "ur10" / "ur10.json")
ARCSEC = math.pi / 180 / 3600
HIDDEN = (2, [(17, 60.0, 0.3), (31, 50.0, 1.1)])  # joint, [(order, amplitude arcsec, phase rad)]


# -- an independent simulated robot (numpy) -----------------------------------------------
def _session(n, seed, periodic=None):
    rng = np.random.default_rng(seed)
    centre, half = np.array([-90, -90, 60, -90, 0, 0]), np.array([60, 45, 65, 90, 70, 90])
    q = np.radians(centre + rng.uniform(-1, 1, (n, 6)) * half)
    table = UR10.table.numpy().copy()
    table[:, 0] += rng.normal(0, math.radians(0.02), 6)  # MD-H errors
    table[:, 1:3] += rng.normal(0, 0.3, (6, 2))
    table[:, 3] += rng.normal(0, math.radians(0.02), 6)
    qa = q.copy()
    qa[:, 1] += 2e-4 * np.cos(q[:, 1])  # unmodelled: gravity-like compliance of joints 2, 3
    qa[:, 2] += 1e-4 * np.cos(q[:, 1] + q[:, 2])
    if periodic:
        j, terms = periodic
        for k, amp, phase in terms:
            qa[:, j - 1] += amp * ARCSEC * np.sin(k * q[:, j - 1] + phase)
    xyz = numpy_fk(UR10, qa, table - UR10.table.numpy()) + rng.normal(0, 0.03, (n, 3))
    return Measurements(pose=torch.arange(n), q=torch.from_numpy(q), xyz=torch.from_numpy(xyz))


def _searches(m, joints=range(1, 7)):
    ctx = context_of(UR10, m)
    model = CalibrationModel.for_measurements(UR10, [], m)
    res = fit(model, ctx, m.xyz, pose=m.pose)
    r = res.residuals.reshape(-1).numpy()
    A = model.jacobian(res.theta, ctx).reshape(-1, model.n_params)[:, res.report.free].detach().numpy()
    folds = fold_of_pose(m.pose, 0, 5)
    return {j: propose_orders(UR10, model, res.theta, ctx, r, A, folds, j) for j in joints}


# -- the spec -----------------------------------------------------------------------------
def test_spec_gives_orders_per_joint_and_round_trips():
    s = parse_spec("joint_periodic: 2@29+20 , 1@12,1@4", 6)
    assert s == EffectSpec("joint_periodic", (1, 2), ((4, 12), (20, 29)))
    assert str(s) == "joint_periodic:1@4+12,2@20+29" and parse_spec(str(s), 6) == s
    merged = parse_specs(["joint_periodic:2@20", "backlash:3", "joint_periodic:2@29,3@18"], 6)
    assert [str(x) for x in merged] == ["joint_periodic:2@20+29,3@18", "backlash:3"]
    assert build(str(s), UR10).spec() == str(s)


@pytest.mark.parametrize("text, msg", [
    ("joint_periodic", "give joints and their orders"),
    ("joint_periodic:2", "joint 2 needs its orders"),
    ("joint_periodic:2@", "integers >= 1 joined by"),
    ("joint_periodic:2@0", "integers >= 1 joined by"),
    ("joint_periodic:2@20,29", "joint 29 needs its orders"),
    ("joint_periodic:7@3", "out of range"),
    ("backlash:2@3", "takes no orders"),
])
def test_spec_refuses_with_one_line(text, msg):
    with pytest.raises(InputError, match=msg) as e:
        parse_spec(text, 6)
    assert "\n" not in str(e.value)


# -- the effect ---------------------------------------------------------------------------
def test_offset_against_numpy_and_jacobian_against_autodiff():
    e = build("joint_periodic:2@3+20,5@7", UR10)
    assert e.param_names() == ["jper_2_sin3", "jper_2_cos3", "jper_2_sin20", "jper_2_cos20",
                               "jper_5_sin7", "jper_5_cos7"]
    assert e.param_units() == ["rad"] * 6
    assert e.plausible_max() == pytest.approx([180 * ARCSEC] * 6)
    g = torch.Generator().manual_seed(3)
    q = (torch.rand(30, 6, generator=g, dtype=torch.float64) - 0.5) * 6
    ctx = make_context(UR10, q)
    p = torch.randn(6, generator=g, dtype=torch.float64) * 1e-4
    qn, pn = q.numpy(), p.numpy()
    want = np.zeros_like(qn)
    want[:, 1] = pn[0] * np.sin(3 * qn[:, 1]) + pn[1] * np.cos(3 * qn[:, 1]) \
        + pn[2] * np.sin(20 * qn[:, 1]) + pn[3] * np.cos(20 * qn[:, 1])
    want[:, 4] = pn[4] * np.sin(7 * qn[:, 4]) + pn[5] * np.cos(7 * qn[:, 4])
    np.testing.assert_allclose(e.joint_offset(p, ctx).numpy(), want, rtol=0, atol=1e-15)
    torch.testing.assert_close(e.joint_offset_jacobian(p, ctx),
                               torch.func.jacfwd(lambda t: e.joint_offset(t, ctx))(p), rtol=1e-12, atol=1e-15)
    assert float(e.joint_offset(torch.zeros(6, dtype=torch.float64), ctx).abs().max()) == 0.0


# -- what a range resolves ----------------------------------------------------------------
def test_order_limits_follow_the_range_and_the_spacing():
    q = np.linspace(0.0, 1.0, 2001)  # 1 rad, spacing 5e-4 rad
    lim = order_limits(q)
    assert lim.k_min == math.ceil(4 * math.pi) == 13  # two periods inside the range
    assert lim.k_max == 120 and lim.resolution == pytest.approx(2 * math.pi)
    assert order_limits(np.linspace(0, 1.0, 21)).k_max == math.floor(math.pi / 0.05)  # 2 samples a period
    narrow = order_limits(np.linspace(0.0, 0.05, 200))  # 2.9 deg: two periods need order >= 252
    assert narrow.empty and "resolves no periodic order" in narrow.text(3)


def test_search_on_a_linear_problem_finds_the_hidden_orders_only():
    """Independent of any robot: r = A a + sin/cos columns of orders 9 and 23 + noise."""
    rng = np.random.default_rng(4)
    n = 300
    q = rng.uniform(-1.5, 1.5, n)
    t = rng.normal(size=(n, 3))  # the joint's sensitivity per pose
    A = rng.normal(size=(3 * n, 5))
    grid = list(range(5, 61))
    C = np.stack([f(k * q)[:, None] * t for k in grid for f in (np.sin, np.cos)], -1).reshape(3 * n, -1)
    r = A @ rng.normal(size=5) + 0.3 * C[:, 2 * grid.index(9)] - 0.2 * C[:, 2 * grid.index(23) + 1] \
        + rng.normal(0, 0.05, 3 * n)
    idx, path, ps = search_orders(r, A, C, grid, rng.permutation(n) % 5)
    assert sorted(grid[i] for i in idx) == [9, 23]
    assert path[-1] < 0.06 * math.sqrt(3) < path[0] and all(p < 0.01 / len(grid) for p in ps)


def _linear_session(span_deg, dq_of_q, seed, n=300, noise=0.02):
    """Independent of any robot: one joint's angles q (n,) uniform over span_deg around 0,
    its sensitivity t (n, 3) mm/rad, base columns (a translation and the joint offset), the
    grid's sin/cos columns and the residual r = (dq_of_q(q) rad) t + noise (mm)."""
    rng = np.random.default_rng(seed)
    q = np.radians(rng.uniform(-span_deg / 2, span_deg / 2, n))
    t = rng.normal(0, 600, (n, 3))
    A = np.hstack([np.tile(np.eye(3), (n, 1)), t.reshape(3 * n, 1)])
    lim = order_limits(q)
    grid = list(range(lim.k_min, min(lim.k_max, 40) + 1))
    C = np.stack([f(k * q)[:, None] * t for k in grid for f in (np.sin, np.cos)], -1).reshape(3 * n, -1)
    r = (dq_of_q(q)[:, None] * t).reshape(-1) + rng.normal(0, noise, 3 * n)
    return r, A, C, grid, rng.permutation(n) % 5


@pytest.mark.parametrize("span_deg", [90, 360])
def test_close_orders_the_data_determine_are_both_kept_over_any_range(span_deg):
    """60 and 50 arcsec at orders 10 and 11: over 90 deg (a resolution of 4 orders) as over
    a full turn the data determine both pairs of coefficients, and both are kept."""
    r, A, C, grid, folds = _linear_session(span_deg, lambda q: (60 * np.sin(10 * q) + 50 * np.cos(11 * q)) * ARCSEC, 0)
    idx, _, _ = search_orders(r, A, C, grid, folds, scale=180 * ARCSEC)
    assert sorted(grid[i] for i in idx) == [10, 11]


def test_close_orders_only_implausible_coefficients_explain_are_not_both_kept():
    """Over 90 deg, 400 arcsec/rad x q cos(10.5 q) (an order between two of the grid whose
    amplitude grows across the range): orders 10 and 11 together fit it only with large,
    opposite coefficients beyond the plausible 180 arcsec. Without the check the search
    keeps both; with it, not both, and every coefficient of the orders kept (refitted by
    plain least squares) stays near the plausible size."""
    r, A, C, grid, folds = _linear_session(90, lambda q: 400 * ARCSEC * q * np.cos(10.5 * q), 0)

    def kept_and_largest(scale):
        idx, _, _ = search_orders(r, A, C, grid, folds, scale=scale)
        X = np.hstack([A] + [C[:, 2 * i:2 * i + 2] for i in idx])
        coef = np.linalg.lstsq(X, r, rcond=None)[0][A.shape[1]:]
        return {grid[i] for i in idx}, float(np.abs(coef).max()) / ARCSEC

    free, free_max = kept_and_largest(None)
    assert {10, 11} <= free and free_max > 180 * 1.5  # the failure the check prevents
    kept, kept_max = kept_and_largest(180 * ARCSEC)
    assert not {10, 11} <= kept and kept_max < 180 * 1.1


# -- on an independent simulated robot ----------------------------------------------------
def test_search_names_the_hidden_joint_and_orders():
    found = _searches(_session(400, 1, HIDDEN))
    assert found[2].orders in ((17, 31), (31, 17))
    assert found[2].amplitudes_arcsec == pytest.approx([60.0, 50.0] if found[2].orders[0] == 17 else [50, 60],
                                                       rel=0.1)
    assert found[2].cv_rms_mm[-1] < found[2].cv_rms_mm[0] / 3


def test_discover_names_the_hidden_periodic_error_and_none_without(tmp_path):
    from torchcal.diagnosis.diagnose import discover

    d = discover(UR10, _session(400, 1, HIDDEN), report_rest=False)
    assert [s for s in d.final_effects if s.startswith("joint_periodic")] == ["joint_periodic:2@17+31"], d.history
    assert "joint_periodic:2@17+31" not in d.absorbing, d.stability
    d0 = discover(UR10, _session(400, 2), report_rest=False)
    assert not [s for s in d0.final_effects if s.startswith("joint_periodic")], d0.history


def test_a_narrow_joint_is_not_searched_and_warned_about_once(capsys):
    import warnings

    from torchcal.cli._args import warnings_to_stderr
    from torchcal.diagnosis.spectral import NarrowRangeWarning

    q = torch.zeros(50, 6, dtype=torch.float64)
    q[:, 2] = torch.linspace(0.0, 0.05, 50)  # 2.9 deg
    ctx = make_context(UR10, q)
    with pytest.warns(NarrowRangeWarning, match=r"joint 3: its measured range \(2.9 deg\) resolves no periodic order"):
        assert propose_orders(UR10, None, None, ctx, None, None, None, 3).orders == ()
    with warnings_to_stderr(NarrowRangeWarning):
        for _ in range(2):  # discover searches again every round
            propose_orders(UR10, None, None, ctx, None, None, None, 3)
            warnings.warn("joint_periodic: joint 3: ...", NarrowRangeWarning)
    err = capsys.readouterr().err
    assert err.count("\n") == 2 and err.startswith("torchcal: warning: joint_periodic: joint 3: its measured range")
