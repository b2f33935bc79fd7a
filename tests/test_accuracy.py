"""Predicted TCP accuracy over the workspace (torchcal.calibration.accuracy).

References, in numpy: sigma = sqrt(trace J C J^T) with J by forward-mode autodiff of the
model's `predict` (not the analytic Jacobian it uses), the region names from the joint-1
angle and numpy's tertiles, and the region table, median and 95th percentile regrouped
from the returned sigma by hand.
"""

import numpy as np
import pytest
import torch
from torch.testing import assert_close

import torchcal
from torchcal.calibration.accuracy import predicted_sigma, region_names, workspace_accuracy
from torchcal.calibration.model import CalibrationModel
from torchcal.effects import make_context
from torchcal.robots.poses import random_poses

ROBOT = torchcal.robot("ur5e")


def approx(v):
    return pytest.approx(float(v), rel=1e-12, abs=1e-15)

MODEL = CalibrationModel(ROBOT, ["base_frame", "joint_compliance:2"])


def covariance(seed=0):
    """A full, positive definite parameter covariance (P, P)."""
    g = torch.Generator().manual_seed(seed)
    A = torch.randn(MODEL.n_params, MODEL.n_params, generator=g, dtype=torch.float64) * 1e-3
    return A @ A.T + 1e-8 * torch.eye(MODEL.n_params, dtype=torch.float64)


def test_predicted_sigma_against_numpy():
    q = random_poses(ROBOT, 30, 1)
    payload = torch.linspace(0, ROBOT.payload_kg, 30, dtype=torch.float64)
    theta = MODEL.zeros() + 1e-4
    C = covariance()
    sigma = predicted_sigma(MODEL, theta, C, q, payload)
    ctx = make_context(ROBOT, q, payload)
    J = torch.func.jacfwd(lambda th: MODEL.predict(th, ctx))(theta).numpy()  # (N, 3, P)
    ref = np.sqrt([np.trace(Ji @ C.numpy() @ Ji.T) for Ji in J])
    assert_close(sigma, torch.from_numpy(ref), rtol=1e-9, atol=1e-12)


def test_region_names_by_hand():
    deg = np.array([0.0, 44.0, 46.0, 135.0, 136.0, -46.0, -135.0, -136.0, 180.0])
    q = torch.zeros(len(deg), ROBOT.n, dtype=torch.float64)
    q[:, 0] = torch.from_numpy(np.radians(deg))
    rng = np.random.default_rng(2)
    pos = torch.from_numpy(rng.normal(size=(len(deg), 3)) * 500)
    names = region_names(q, pos)
    sector = ["front", "front", "left", "left", "back", "right", "right", "back", "back"]
    reach = pos[:, :2].norm(dim=-1).numpy()
    z = pos[:, 2].numpy()

    def tert(v, words):
        lo, hi = np.quantile(v, [1 / 3, 2 / 3])
        return [words[0] if x < lo else words[1] if x < hi else words[2] for x in v]
    expected = [f"{s} / {r} / {h}" for s, r, h in zip(sector, tert(reach, ("near", "mid-reach", "far")),
                                                      tert(z, ("low", "mid-height", "high")))]
    assert names == expected


def test_workspace_accuracy_regions_and_figures_by_hand():
    theta = MODEL.zeros()
    C = covariance(3)
    acc = workspace_accuracy(MODEL, theta, C, n=300, seed=4, payload_kg=2.0, temp_c=25.0)
    N = acc.q.shape[0]
    assert N == 300 and acc.seed == 4 and acc.robot == "ur5e" and acc.effects == tuple(MODEL.specs())
    payload = torch.full((N,), 2.0, dtype=torch.float64)
    assert_close(acc.sigma, predicted_sigma(MODEL, theta, C, acc.q, payload), rtol=1e-12, atol=0)
    assert_close(acc.pos, MODEL.predict(theta, make_context(ROBOT, acc.q, payload)), rtol=0, atol=1e-9)
    sigma = acc.sigma.numpy()
    groups = {}
    for name, s in zip(region_names(acc.q, acc.pos), sigma):
        groups.setdefault(name, []).append(s)
    table = {k: (np.mean(v), np.max(v), len(v)) for k, v in groups.items() if len(v) >= 5}
    assert [r[0] for r in acc.regions] == sorted(table, key=lambda k: -table[k][0])
    for name, mean, mx, count in acc.regions:
        assert (mean, mx, count) == (approx(table[name][0]), table[name][1], table[name][2])
    d = acc.to_dict()["sigma_mm"]
    assert d["median"] == approx(np.median(sigma)) and d["p95"] == approx(np.percentile(sigma, 95))
    assert (d["min"], d["max"]) == (sigma.min(), sigma.max())


def test_no_uncertainty_no_predicted_error():
    q = random_poses(ROBOT, 10, 5)
    zero = torch.zeros(MODEL.n_params, MODEL.n_params, dtype=torch.float64)
    assert float(predicted_sigma(MODEL, MODEL.zeros(), zero, q).abs().max()) == 0.0
    one = torch.zeros_like(zero)
    one[1, 1] = 1.0  # dd1 (mm) with a 1 mm standard error moves every TCP by 1 mm
    assert_close(predicted_sigma(MODEL, MODEL.zeros(), one, q), torch.ones(10, dtype=torch.float64),
                 rtol=1e-12, atol=0)
    assert float(predicted_sigma(MODEL, MODEL.zeros(), -one, q).max()) == 0.0  # a negative variance clamps at 0
