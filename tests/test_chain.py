"""`Chain`, the kinematic structure the MD-H kernels take.

References: the kernels' signatures (a Chain and nothing loose); numpy products of the
MD-H link matrices written out here (a prismatic q adds to d) for the orientation and
position of a prismatic robot, which `Robot.fk_pose`, `CalibrationModel.predict_rotation`
/ `predict` and the position kernel must all give.
"""

import dataclasses
import inspect
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.testing import assert_close

import torchcal
from torchcal.calibration.model import CalibrationModel
from torchcal.effects import make_context
from torchcal.kinematics import Chain, mdh as K
from torchcal.io.robot_file import robot_from_dict

SCARA = robot_from_dict(json.loads((Path(__file__).resolve().parents[1] / "examples" / "scara.json").read_text()))
KERNELS = ("link_transforms", "fk_frames", "fk_pose", "positions", "fk_positions", "chain_jacobians",
           "param_jacobian", "joint_jacobian", "outer_factors", "outer_angles", "outer_positions")


@pytest.mark.parametrize("name", KERNELS)
def test_kernels_take_only_a_chain(name):
    params = inspect.signature(getattr(K, name)).parameters
    assert "chain" in params
    assert not {"table", "base", "tool", "prismatic", "tz"} & set(params), list(params)


def test_a_table_is_not_a_chain():
    q = torch.zeros(2, 6, dtype=torch.float64)
    with pytest.raises(AttributeError):
        K.positions(q, torchcal.robot("ur5e").table)


def test_chain_is_the_robots_structure():
    c = SCARA.chain
    assert c.table is SCARA.table and c.base is SCARA.base and c.tool is SCARA.tool
    assert torch.equal(c.prismatic, SCARA.prismatic) and c.linear == (2,)
    assert c.plain_base and c.plain_tool and c.to(torch.float64) is c
    c32 = c.to(torch.float32)
    assert c32.table.dtype == c32.base.dtype == c32.tool.dtype == torch.float32 and c32.linear == (2,)
    assert not hasattr(SCARA, "pris")
    with pytest.raises(ValueError, match="prismatic"):
        Chain(SCARA.table, torch.zeros(3, dtype=torch.bool), SCARA.base, SCARA.tool)


def _mdh(theta, d, a, alpha, beta):
    """Rz(theta) Tz(d) Tx(a) Rx(alpha) Ry(beta), numpy (4, 4)."""
    ct, st, ca, sa, cb, sb = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta)
    Rz = np.array([[ct, -st, 0, 0], [st, ct, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    T = np.eye(4)
    T[0, 3], T[2, 3] = a, d
    Rx = np.array([[1, 0, 0, 0], [0, ca, -sa, 0], [0, sa, ca, 0], [0, 0, 0, 1]])
    Ry = np.array([[cb, 0, sb, 0], [0, 1, 0, 0], [-sb, 0, cb, 0], [0, 0, 0, 1]])
    return Rz @ T @ Rx @ Ry


def _reference(robot, q, geo):
    """World <- TCP (N, 4, 4) by numpy: a prismatic q adds to d, a revolute one to theta."""
    eff = (robot.table + geo).numpy()
    pris = robot.prismatic.numpy()
    out = []
    for qi in q.numpy():
        T = robot.base.numpy().copy()
        for j, (off, d, a, alpha, beta) in enumerate(eff):
            T = T @ _mdh(off + (0.0 if pris[j] else qi[j]), d + (qi[j] if pris[j] else 0.0), a, alpha, beta)
        out.append(T @ robot.tool.numpy())
    return torch.from_numpy(np.stack(out))


def test_a_prismatic_robot_has_one_orientation_and_position():
    """Robot.fk_pose, predict_rotation / predict and the position kernel against numpy, with
    deviations, a base and a tool that turn the frames (so a wrong slide convention shows)."""
    g = torch.Generator().manual_seed(4)
    base = torch.eye(4, dtype=torch.float64)
    base[:3, :3] = torch.linalg.matrix_exp(torch.tensor([[0, -0.3, 0.2], [0.3, 0, -0.1], [-0.2, 0.1, 0]],
                                                        dtype=torch.float64))
    base[:3, 3] = torch.tensor([100.0, -50.0, 20.0])
    tool = torch.eye(4, dtype=torch.float64)
    tool[:3, :3] = torch.linalg.matrix_exp(torch.tensor([[0, 0.4, 0], [-0.4, 0, 0.5], [0, -0.5, 0]],
                                                        dtype=torch.float64))
    tool[:3, 3] = torch.tensor([10.0, 5.0, 80.0])
    robot = dataclasses.replace(SCARA, base=base, tool=tool)
    assert not robot.chain.plain_base and not robot.chain.plain_tool
    q = (torch.rand(20, 4, generator=g, dtype=torch.float64) - 0.5) * 4
    q[:, 2] = torch.rand(20, generator=g, dtype=torch.float64) * 200  # the slide, mm
    geo = (torch.rand(4, 5, generator=g, dtype=torch.float64) - 0.5) * 0.02
    ref = _reference(robot, q, geo)

    T = robot.fk_pose(q, geo)
    assert_close(T, ref, rtol=0, atol=1e-9)
    model = CalibrationModel(robot)
    theta = model.zeros()
    theta[: 5 * robot.n] = geo.reshape(-1)
    ctx = make_context(robot, q)
    assert_close(model.predict_rotation(theta, ctx), ref[:, :3, :3], rtol=0, atol=1e-12)
    assert_close(model.predict(theta, ctx), ref[:, :3, 3], rtol=0, atol=1e-9)
    assert_close(K.positions(q, robot.chain, geo), ref[:, :3, 3], rtol=0, atol=1e-9)
    assert_close(robot.fk(q, geo), ref[:, :3, 3], rtol=0, atol=1e-9)
    # the slide never turns the tool
    q2 = q.clone()
    q2[:, 2] = 0.0
    assert_close(model.predict_rotation(theta, make_context(robot, q2)), T[:, :3, :3], rtol=0, atol=1e-12)
