"""Fixtures shared by the test modules; one torch thread for the session."""

import pytest
import torch

import torchcal

# The suite's tensors are small: torch's intra-op threads gain nothing on them, and on a
# machine whose cores are busy with other work they stall on their barriers (measured on
# the 2-core development machine under load: `diagnose` of an 80-row 7-joint session 0.9-1.0 s
# on one thread, 6.9-23.7 s on two). Tests that exercise threads set them themselves.
torch.set_num_threads(1)


@pytest.fixture(scope="module")
def kr():
    """The KR 1000 Titan preset (a fresh Robot per test module)."""
    return torchcal.robot("kr1000titan")


@pytest.fixture(scope="session")
def mdh_deviations():
    """draw(robot, generator) -> (n, 5) MD-H deviations [dtheta, dd, da, dalpha, dbeta]
    uniform in +-(0.02 deg, 0.5 mm, 0.5 mm, 0.02 deg, 0.02 deg), beta only on joints that
    carry one: realistic sizes for a small calibrated arm."""
    import math

    import torch

    size = torch.tensor([math.radians(0.02), 0.5, 0.5, math.radians(0.02), math.radians(0.02)], dtype=torch.float64)

    def draw(robot, generator):
        geo = (torch.rand(robot.n, 5, generator=generator, dtype=torch.float64) * 2 - 1) * size
        geo[:, 4] *= robot.has_beta
        return geo

    return draw
