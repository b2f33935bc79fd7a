"""Random poses (torchcal.robots.poses): inside each joint's own limits, a slide's in mm,
drawn on the robot's device.
Reference: the limits of examples/scara.json, shrunk by the documented 10 % margin."""

import json
import math
from pathlib import Path

import pytest
import torch

from torchcal.io.robot_file import robot_from_dict
from torchcal.robots.poses import random_poses

SCARA = robot_from_dict(json.loads((Path(__file__).resolve().parents[1] / "examples" / "scara.json").read_text()))


def test_random_poses_span_a_slides_own_limits():
    q = random_poses(SCARA, 400, 3, min_z_mm=None)
    lo, hi = 0.0 + 0.1 * 200.0, 200.0 - 0.1 * 200.0  # mm, the limits shrunk by the margin
    assert q.device == SCARA.device
    assert float(q[:, 2].min()) >= lo and float(q[:, 2].max()) <= hi
    assert float(q[:, 2].min()) < lo + 10 and float(q[:, 2].max()) > hi - 10  # uniform over 20..180 mm
    rev = q[:, [0, 1, 3]]
    assert float(rev.abs().max()) <= math.pi  # revolute joints stay inside +-180 deg


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_random_poses_draw_on_the_robots_device():
    robot = SCARA.to("cuda")
    q = random_poses(robot, 50, 3)
    assert q.device == robot.device and float(q[:, 2].max()) > 100.0  # a slide in mm, not rad
    g = torch.Generator().manual_seed(3)  # a CPU generator: its draws are moved
    assert random_poses(robot, 5, g).device == robot.device
