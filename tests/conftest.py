"""Fixtures shared by the test modules; the thread policy of torchcal.threads (one intra-op
torch and BLAS thread for the session)."""

import torchcal  # first: sets OMP_WAIT_POLICY=PASSIVE before torch loads (torchcal.threads)

import gc
from pathlib import Path

import pytest

from torchcal import threads


def _runs_tests(config) -> bool:
    """False only in pytest-xdist's controller (-n N): it hands the tests to its workers and
    needs no torch (whose import is about 1 s of CPU there, and more at its exit)."""
    return hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None)


def pytest_configure(config):
    if not _runs_tests(config):
        return
    # The suite's tensors are small: by the policy's size rule (torchcal.threads.threads_for)
    # none of them earns a second thread, and on a machine whose cores are busy with other
    # work a second one stalls at its barriers (measured on the 2-core development machine
    # under load: `diagnose` of an 80-row 7-joint session 0.9-1.0 s on one thread, 6.9-23.7 s
    # on two). Tests that exercise threads set them themselves.
    threads.apply()  # torch and numpy's / scipy's BLAS on one intra-op thread
    # What the imports made lives until the process ends: frozen (gc.freeze), the cyclic
    # collector's full collections, the ones at exit included, no longer scan it again, as
    # `torchcal.threads.apply_importing` does for a command. Here once torch is loaded, and again
    # once the test modules are collected (below).
    gc.freeze()


@pytest.hookimpl(trylast=True)
def pytest_collection_finish(session):
    gc.freeze()
    # The tests allocate many short-lived objects (tensors, matplotlib artists): a young
    # collection every 10 000 net allocations instead of 700, and the older generations
    # 20 times rarer than theirs, cut the collector's CPU in the two test processes of
    # `pytest -n 2` from 4.1 to 2.7 s (measured with gc.callbacks, one run each).
    # Cycles are still collected, a little later; nothing else changes.
    gc.set_threshold(10_000, 20, 20)


@pytest.hookimpl(tryfirst=True)
def pytest_cmdline_main(config):
    """With pytest-xdist workers (-n) and no --dist given: `--dist worksteal`. xdist's
    default (`load`) hands out the first quarter of the tests one by one, alternating
    workers, so a module's tests are split and its module fixtures (a simulated session,
    a discover run) are computed on both; `worksteal` gives each worker a contiguous half
    and lets an idle one take the other's tail, so neither waits at the end."""
    opt = config.option
    if getattr(opt, "numprocesses", None) and getattr(opt, "dist", None) == "no" and not getattr(opt, "distload", False):
        opt.dist = "worksteal"


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


UR10_FILE = Path(__file__).resolve().parents[1] / "examples" / "ur10" / "ur10.json"


@pytest.fixture(scope="session")
def ur10_fitted():
    """(UR10, the "real" UR10: a VirtualRobot in a tracker frame with compliance its model
    lacks, the model base_frame tool_offset fitted on 60 of its poses, 40 other poses
    measured): the data-against-a-model checks' case (tests change copies, never these)."""
    from torchcal.robots.poses import random_poses
    from torchcal.simulation.virtual_robot import VirtualRobot

    rob = torchcal.robot(UR10_FILE)
    # the "real" UR10 sits in a tracker frame and carries compliance its model lacks
    vr = VirtualRobot(rob, ["base_frame", "joint_compliance:2,3"], seed=1)
    fitted = torchcal.fit(rob, vr.measure(random_poses(rob, 60, 3), seed=4), ["base_frame", "tool_offset"])
    val = vr.measure(random_poses(rob, 40, 5), seed=6)
    return rob, vr, fitted, val


@pytest.fixture(scope="session")
def ur10_series_d():
    """(UR10, UR10 series D, the model fitted on its odd rows): read by the column and row
    mix-up tests (they change copies, never these)."""
    from torchcal.io.measurement_csv import read_measurements

    rob = torchcal.robot(UR10_FILE)
    m = read_measurements(UR10_FILE.parent / "series_d.csv", robot=rob)
    return rob, m, torchcal.fit(rob, m.subset(slice(1, None, 2)), ["base_frame", "tool_offset"])


@pytest.fixture(scope="session")
def titan_data():
    """40 poses of a kr1000titan measured in its base frame (data of another robot than a UR10)."""
    from torchcal.robots.poses import random_poses
    from torchcal.simulation.virtual_robot import VirtualRobot

    ti = torchcal.robot("kr1000titan")
    return VirtualRobot(ti, [], seed=2).measure(random_poses(ti, 40, 7), seed=8)
