"""The calibration model for B zones at once (torchcal.calibration.batched).

References: a loop of single-zone `CalibrationModel.predict` calls, the plain-numpy MD-H
chain of tests/npsim.py for a geometric-only model, and forward-mode autodiff
(torch.func.jacfwd) of each zone's `predict` for the Jacobians; geometric-only, with
payload-driven and temperature-driven effects, on the KR 1000 Titan and the UR5e.
"""

import pytest
import torch
from torch.testing import assert_close

from npsim import numpy_fk

import torchcal
from torchcal.calibration.batched import batched_jacobian, batched_predict
from torchcal.calibration.model import CalibrationModel
from torchcal.effects import make_context
from torchcal.robots.poses import random_poses

CASES = [("kr1000titan", ()), ("ur5e", ()), ("kr1000titan", ("base_frame", "joint_compliance:2,3")),
         ("ur5e", ("thermal_expansion", "backlash:2", "gear_periodic:1"))]


def zones(robot_name, effects, B=3, m=12, seed=0):
    """(model, x (B, P), contexts): B zones of m rows each, their own parameters and conditions."""
    robot = torchcal.robot(robot_name)
    model = CalibrationModel(robot, list(effects))
    g = torch.Generator().manual_seed(seed)
    x = (torch.rand(B, model.n_params, generator=g, dtype=torch.float64) - 0.5) * 1e-3
    ctxs = []
    for b in range(B):
        q = random_poses(robot, m, seed + 10 + b)
        payload = torch.rand(m, generator=g, dtype=torch.float64) * robot.payload_kg
        temp = 15 + 15 * torch.rand(m, generator=g, dtype=torch.float64)
        ctxs.append(make_context(robot, q, payload, temp))
    return model, x, ctxs


@pytest.mark.parametrize("robot_name, effects", CASES)
def test_batched_predict_is_the_loop_of_single_zones(robot_name, effects):
    model, x, ctxs = zones(robot_name, effects)
    out = batched_predict(model, x, ctxs)
    assert out.shape == (3, 12, 3)
    for b, ctx in enumerate(ctxs):
        assert_close(out[b], model.predict(x[b], ctx), rtol=0, atol=1e-9)


@pytest.mark.parametrize("robot_name", ["kr1000titan", "ur5e"])
def test_batched_geometric_predict_against_numpy(robot_name):
    model, x, ctxs = zones(robot_name, ())
    out = batched_predict(model, x, ctxs)
    n = model.robot.n
    for b, ctx in enumerate(ctxs):
        ref = numpy_fk(model.robot, ctx.q.numpy(), x[b, : 5 * n].reshape(n, 5).numpy())
        assert_close(out[b], torch.from_numpy(ref), rtol=0, atol=1e-8)


@pytest.mark.parametrize("robot_name, effects", CASES)
def test_batched_jacobian_is_autodiff_of_each_zone(robot_name, effects):
    model, x, ctxs = zones(robot_name, effects)
    J = batched_jacobian(model, x, ctxs)
    assert J.shape == (3, 12, 3, model.n_params)
    for b, ctx in enumerate(ctxs):
        ref = torch.func.jacfwd(lambda th: model.predict(th, ctx))(x[b])
        assert_close(J[b], ref, rtol=1e-7, atol=1e-8)
