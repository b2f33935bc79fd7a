"""`torchcal.kinematics.mdh.fk_rotation`: the TCP rotation from the link axes alone."""

import dataclasses

import numpy as np
import pytest
import torch

import torchcal
from tests.npsim import numpy_frames
from torchcal.kinematics import mdh as K
from torchcal.rotations import rotvec_to_matrix


def _tilted(robot):
    """The robot on a tilted, shifted base with a rotated, offset tool."""
    base, tool = torch.eye(4, dtype=torch.float64), torch.eye(4, dtype=torch.float64)
    base[:3, :3] = rotvec_to_matrix(torch.tensor([0.03, -0.05, 0.5], dtype=torch.float64))
    base[:3, 3] = torch.tensor([150.0, -80.0, 400.0], dtype=torch.float64)
    tool[:3, :3] = rotvec_to_matrix(torch.tensor([0.0, 0.2, 0.1], dtype=torch.float64))
    tool[:3, 3] = torch.tensor([20.0, -15.0, 250.0], dtype=torch.float64)
    return dataclasses.replace(robot, base=base, tool=tool)


@pytest.mark.parametrize("slides", [(), (2,)], ids=["revolute", "slide-3"])
def test_fk_rotation_matches_numpy_chain_and_fk_pose(slides):
    robot = _tilted(torchcal.robot("kr1000titan"))
    prismatic = torch.zeros(robot.n, dtype=torch.bool)
    prismatic[list(slides)] = True
    robot = dataclasses.replace(robot, prismatic=prismatic)
    gen = torch.Generator().manual_seed(5)
    q = (torch.rand(30, robot.n, generator=gen, dtype=torch.float64) - 0.5) * 4.0
    dev = (torch.rand(robot.n, 5, generator=gen, dtype=torch.float64) - 0.5) * 0.02
    for chain, tool in ((robot.chain.flange, np.eye(4)), (robot.chain, robot.tool.numpy())):
        got = K.fk_rotation(q, chain, dev)
        assert got.shape == (30, 3, 3)
        want = np.array([(numpy_frames(robot, qq, dev.numpy())[-1] @ tool)[:3, :3] for qq in q.numpy()])
        np.testing.assert_allclose(got.numpy(), want, rtol=0, atol=1e-12)
        assert torch.equal(got, K.fk_pose(q, chain, dev)[..., :3, :3])  # the same numbers as the pose's
