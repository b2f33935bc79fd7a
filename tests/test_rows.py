"""The fit's measurement rows (torchcal.calibration.rows): the tool-rotation step against
a numpy Procrustes (SVD of sum A_i^T B_i with the determinant correction) and a known
rotation; the orientation rows' weight sigma_mm / radians(sigma_deg); the rows'
analytic Jacobian against central differences."""

import math

import numpy as np
import pytest
import torch
from torch.testing import assert_close

from torchcal.calibration.model import CalibrationModel
from torchcal.calibration.rows import Rows, orientation_weight, tool_rotation
from torchcal.effects import make_context
from torchcal.robots.poses import random_poses
from torchcal.rotations import rotvec_to_matrix


@pytest.fixture(scope="module")
def setup(kr):
    model = CalibrationModel(kr)
    q = random_poses(kr, 25, torch.Generator().manual_seed(3))
    ctx = make_context(kr, q)
    theta = torch.from_numpy(np.random.default_rng(3).normal(scale=1e-3, size=model.n_params))
    X = rotvec_to_matrix(torch.tensor([0.02, -0.05, 0.3], dtype=torch.float64))
    return model, ctx, theta, X


def _procrustes_numpy(A, B):
    U, _, Vt = np.linalg.svd(np.einsum("nji,njk->ik", A, B))
    D = np.diag([1.0, 1.0, np.linalg.det(U @ Vt)])
    return U @ D @ Vt


def test_tool_rotation_recovers_a_known_rotation(setup):
    model, ctx, theta, X = setup
    Rp = model.predict_rotation(theta, ctx)
    assert_close(tool_rotation(model, theta, ctx, Rp @ X), X, atol=1e-12, rtol=0)


def test_tool_rotation_is_the_least_squares_rotation(setup):
    """Noisy measured frames: the numpy Procrustes solution, and no small rotation of it
    fits better."""
    model, ctx, theta, X = setup
    Rp = model.predict_rotation(theta, ctx)
    noise = torch.stack([rotvec_to_matrix(v) for v in torch.from_numpy(np.random.default_rng(4).normal(scale=0.01,
                                                                                                    size=(25, 3)))])
    Rm = Rp @ X @ noise
    got = tool_rotation(model, theta, ctx, Rm)
    assert_close(got, torch.from_numpy(_procrustes_numpy(Rp.numpy(), Rm.numpy())), atol=1e-12, rtol=0)

    def cost(Y):
        return float(((Rp @ Y - Rm) ** 2).sum())
    for v in np.eye(3):
        for sign in (1, -1):
            assert cost(got @ rotvec_to_matrix(torch.from_numpy(sign * 1e-3 * v))) > cost(got)


def test_orientation_rows_weigh_as_their_stated_uncertainty(setup):
    """0.01 mm and 0.01 deg: 57.3 mm per rad; a 0.01 deg turn of every measured frame about
    its own z gives orientation rows of length about 0.01 mm (sin of the angle times the
    weight)."""
    model, ctx, theta, X = setup
    w = orientation_weight(0.01, 0.01)
    assert w == pytest.approx(0.01 / math.radians(0.01))
    turn = rotvec_to_matrix(torch.tensor([0.0, 0.0, math.radians(0.01)], dtype=torch.float64))
    Rm = model.predict_rotation(theta, ctx) @ X @ turn
    rows = Rows(model, ctx, model.predict(theta, ctx), Rm, w, X)
    r = rows.residual(theta)
    assert r.shape == (25, 6) and float(r[:, :3].abs().max()) == 0.0
    assert_close(r[:, 3:].norm(dim=-1), torch.full((25,), w * math.sin(math.radians(0.01)), dtype=torch.float64))


def test_rows_jacobian_against_central_differences(setup):
    model, ctx, theta, X = setup
    Rm = model.predict_rotation(theta, ctx) @ X
    xyz = model.predict(theta, ctx) + 0.3
    for rot in (None, Rm):
        rows = Rows(model, ctx, xyz, rot, 57.3, X if rot is not None else None)
        J = rows.jacobian(theta)
        h = 1e-6
        fd = torch.stack([(rows.residual(theta + h * e) - rows.residual(theta - h * e)) / (2 * h)
                          for e in torch.eye(model.n_params, dtype=torch.float64)], dim=-1)
        assert J.shape == fd.shape == (25, rows.k, model.n_params)
        assert_close(J, fd, atol=1e-6, rtol=1e-6)
