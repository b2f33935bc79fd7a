"""The workspace sampler's Latin hypercube (torchcal.robots.workspace.LatinHypercube) against
scipy.stats.qmc.LatinHypercube, the reference it writes out: the same points bit for bit for
an int seed and for a block's SeedSequence, over successive rounds of different sizes."""

import numpy as np
import pytest

from torchcal.reliability.sweep_blocks import block_seed
from torchcal.robots.workspace import LatinHypercube


def _scipy(d, seed):
    from scipy.stats import qmc

    if isinstance(seed, np.random.SeedSequence):
        seed = np.random.default_rng(seed)
    try:
        return qmc.LatinHypercube(d=d, rng=seed)
    except TypeError:  # scipy < 1.15
        return qmc.LatinHypercube(d=d, seed=seed)


@pytest.mark.parametrize("d, seed", [(6, 0), (6, 5), (4, 123), (7, "block 3 of seed 5"), (6, "block 1 of seed 0")])
def test_points_are_scipys_bit_for_bit(d, seed):
    """Rounds as `sample_workspace` draws them (n, then larger top-ups): each one a Latin
    hypercube (one point per stratum and axis) and equal to scipy's, round after round."""
    if isinstance(seed, str):
        b, s = (int(w) for w in seed.split()[1::3])
        mine, ref = LatinHypercube(d, block_seed(s, b)), _scipy(d, block_seed(s, b))
    else:
        mine, ref = LatinHypercube(d, seed), _scipy(d, seed)
    for n in (40, 64, 1, 257):
        u = mine.random(n)
        assert u.shape == (n, d) and u.dtype == np.float64
        assert np.array_equal(u, ref.random(n))
        assert all(sorted(np.floor(u[:, j] * n).astype(int)) == list(range(n)) for j in range(d))



# -- the keep-out column scales with the arm ------------------------------------------------
def _removed_by_column(robot, n=1000):
    """Share of n Latin-hypercube joint vectors kept by the floor and reach that the default
    column removes."""
    import torch

    from torchcal.robots.workspace import Workspace

    u = torch.from_numpy(LatinHypercube(robot.n, 0).random(n))
    q = robot.limits[:, 0] + u * (robot.limits[:, 1] - robot.limits[:, 0])
    kept = Workspace(column_radius_mm=0.0).accept(robot, q)
    return 1 - float(Workspace().accept(robot, q).sum()) / float(kept.sum())


def test_default_column_scales_with_the_arm():
    """The default column (350 mm up to 1100 mm, the KR 1000's) removed 53 % of a UR5e's
    workspace points (62 % of a PUMA 560's). Now scaled by the arm's stretch: the KR 1000's
    exactly (its outputs bit for bit), a UR5e's 132 mm up to 416 mm, removing a few %."""
    import torchcal
    from torchcal.robots.workspace import Workspace

    assert Workspace().column(torchcal.robot("kr1000titan")) == (350.0, 1100.0)
    ur = torchcal.robot("ur5e")
    r, h = Workspace().column(ur)
    assert 120 < r < 145 and 380 < h < 450
    assert 0.01 < _removed_by_column(ur) < 0.2
    assert Workspace(column_radius_mm=350.0, column_height_mm=1100.0).column(ur) == (350.0, 1100.0)


@pytest.mark.parametrize("radius, warned", [(0.35, True), (0.0, False), (None, False), (350.0, False), (30.0, False)])
def test_a_column_radius_in_metres_warns(radius, warned):
    """`plan --column-radius 0.35` (metres for 350 mm) kept a column thinner than a wire, in
    silence. Now a radius above 0 and under 2 % of the arm's stretch (UR5e: 23 mm) warns
    once naming the value in mm; 0 (no column), the default and real radii are silent."""
    import warnings

    import torchcal
    from torchcal.robots.checks import RobotUnitWarning
    from torchcal.robots.workspace import Workspace, sample_workspace

    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        sample_workspace(torchcal.robot("ur5e"), 5, seed=0, workspace=Workspace(column_radius_mm=radius))
    mine = [x for x in w if issubclass(x.category, RobotUnitWarning)]
    if warned:
        assert len(mine) == 1 and "column radius 0.35 mm is thinner than any link of ur5e" in str(mine[0].message)
        assert "in metres? (350 mm)" in str(mine[0].message)
    else:
        assert mine == []


def test_plan_column_radius_in_metres_is_one_line(tmp_path, capsys):
    from torchcal.cli import main

    assert main(["plan", "--robot", "ur5e", "--n", "8", "--candidates", "60", "--random-plans", "2",
                 "--column-radius", "0.35", "--out", str(tmp_path / "p.csv")]) == 0
    err = [ln for ln in capsys.readouterr().err.splitlines() if "column radius" in ln]
    assert len(err) == 1 and err[0].startswith("torchcal: warning: workspace: column radius 0.35 mm"), err
