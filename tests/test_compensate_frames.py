"""`compensate --frame`: targets in the measuring frame or the robot base frame, checked by
driving an independent plain-numpy robot (tracker frame 3 m away, a 290 mm reflector and
an error the fitted model lacks) with the commands it writes."""

from __future__ import annotations

import csv
import io
from contextlib import redirect_stderr, redirect_stdout

import numpy as np
import pytest
import torch

from npsim import numpy_fk

import torchcal
from torchcal.cli import main
from torchcal.robots.poses import random_poses

# the robot as it really is: measuring frame <- base (rotation about z then x, translation)
C, S = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
R_WB = np.array([[C, -S, 0.0], [S, C, 0.0], [0.0, 0.0, 1.0]]) @ \
    np.array([[1.0, 0, 0], [0, np.cos(0.02), -np.sin(0.02)], [0, np.sin(0.02), np.cos(0.02)]])
T_WB = np.array([2600.0, -1500.0, -300.0])  # the tracker 3 m from the robot base
REFLECTOR = np.array([30.0, -20.0, 290.0])  # mm on the flange
KR = torchcal.robot("kr1000titan")


def _deviations(n: int) -> np.ndarray:
    """(n, 5) true MD-H deviations; joint 1's dtheta and dd are zero because they trade
    against the base frame's rotation about z and its z translation: with them the fitted
    base frame is the fit's choice, not this simulator's."""
    rng = np.random.default_rng(11)
    dev = np.column_stack([rng.uniform(-1, 1, n) * np.radians(0.05), rng.uniform(-1, 1, (n, 2)) * 0.8,
                           rng.uniform(-1, 1, n) * np.radians(0.05), np.zeros(n)])
    dev[0, :2] = 0.0
    dev[1, 4] = np.radians(0.03)  # joint 2 (parallel to 3) has a Hayati beta
    return dev


def real_robot(table: np.ndarray, q: np.ndarray, frame: str) -> np.ndarray:
    """The true robot (MD-H `table`, the plain-numpy chain of tests/npsim.py) with a 0.01 deg
    gear error on joint 2 (sin 3 q2) that no fitted model here holds; q (N, n) rad ->
    reflector positions (N, 3) mm in the measuring or base frame."""
    q = np.array(q, dtype=float)
    q[:, 1] += np.radians(0.01) * np.sin(3 * q[:, 1])
    reflector = np.eye(4)
    reflector[:3, 3] = REFLECTOR
    p = numpy_fk(KR, q, table - KR.table.numpy(), tool=reflector)  # KR's base is the identity
    return p @ R_WB.T + T_WB if frame == "measuring" else p


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    d = tmp_path_factory.mktemp("frames")
    rob = torchcal.robot("kr1000titan")
    table = rob.table.numpy() + _deviations(rob.n)
    q = random_poses(rob, 80, 5).numpy()
    xyz = real_robot(table, q, "measuring") + np.random.default_rng(3).normal(0, 0.01, (len(q), 3))
    with open(d / "data.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["pose", *(f"q{k}" for k in range(1, 7)), "x", "y", "z"])
        for i, (qq, p) in enumerate(zip(np.degrees(q), xyz)):
            w.writerow([i + 1, *map(repr, qq.tolist()), *map(repr, p.tolist())])
    assert main(["fit", str(d / "data.csv"), "--robot", "kr1000titan", "--effects", "base_frame", "tool_offset",
                 "--out", str(d / "model.json")]) == 0
    q_goal = random_poses(rob, 12, 9).numpy()  # where the targets come from; never given to compensate
    return d, table, q_goal


def _write_targets(path, xyz):
    path.write_text("x,y,z\n" + "".join(",".join(repr(float(v)) for v in p) + "\n" for p in xyz))
    return path


def _commands(path) -> tuple[np.ndarray, list]:
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return np.radians([[float(r[f"q{k}"]) for k in range(1, 7)] for r in rows]), rows


def _compensate(d, table, q_goal, frame: str):
    """`torchcal compensate --frame frame` of the true robot's positions at q_goal (M, 6) rad,
    no seeds: (exit status, stdout, commands (M, 6) rad, the output's rows, goal (M, 3) mm)."""
    goal = real_robot(table, q_goal, frame)
    t = _write_targets(d / f"targets_{frame}.csv", goal)
    out = d / f"q_{frame}.csv"
    printed = io.StringIO()
    with redirect_stdout(printed), redirect_stderr(io.StringIO()):
        code = main(["compensate", str(t), "--model", str(d / "model.json"), "--frame", frame, "--out", str(out)])
    return (code, printed.getvalue(), *_commands(out), goal)


@pytest.fixture(scope="module")
def unseeded(cell):
    """The cell's 12 goals compensated in the measuring frame without seeds (asserted on by
    two tests: they reach the goals; their orientation is not the goals')."""
    return _compensate(*cell, "measuring")


@pytest.mark.parametrize("frame", ["measuring", "base"])
def test_real_robot_reaches_targets_given_in_either_frame(cell, unseeded, frame):
    d, table, q_goal = cell
    code, printed, q, rows, goal = unseeded if frame == "measuring" else _compensate(d, table, q_goal, frame)
    assert code == 0 and f"in the {frame} frame" in printed
    assert all(r["converged"] == "true" and r["within_limits"] == "true" for r in rows)
    err = np.linalg.norm(real_robot(table, q, frame) - goal, axis=1)
    # left: the gear error no model here holds (0.01 deg at up to 3 m: about 0.5 mm), the
    # fit's error and, in the base frame, the fitted base frame's own error (its z offset
    # trades with the d of the parallel joints); a frame mixed up misses by metres, a
    # wrong rotation by tens of mm, the nominal inverse by 1.5 mm rms here
    assert err.max() < 1.0, err


def test_base_frame_targets_read_as_measuring_are_named(cell, capsys):
    """The first 4 goals in the base frame given as measuring-frame targets: 2 lie beyond
    the reach read in the wrong frame (they were listed as not reached, exit 1, an output
    written); read in the base frame all 4 lie within it: one line naming the frame."""
    d, table, q_goal = cell
    t = _write_targets(d / "targets_b2.csv", real_robot(table, q_goal[:4], "base"))
    capsys.readouterr()
    code = main(["compensate", str(t), "--model", str(d / "model.json"), "--out", str(d / "q_wrong.csv")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "; 2 of 4 beyond it), but read in the robot " \
        "base frame they would lie within its reach: they look like coordinates in the robot base frame; pass " \
        "--frame base" in err and not (d / "q_wrong.csv").exists()


def test_unreachable_rows_are_listed_and_the_others_solved(cell, capsys):
    d, table, q_goal = cell
    goal = real_robot(table, q_goal, "measuring")
    far = goal.copy()
    far[[2, 7]] = goal[[2, 7]] + np.array([9000.0, 0.0, 0.0])  # far beyond the reach
    t = _write_targets(d / "targets_far.csv", far)
    out = d / "q_far.csv"
    capsys.readouterr()
    assert main(["compensate", str(t), "--model", str(d / "model.json"), "--out", str(out)]) == 1
    err = [line for line in capsys.readouterr().err.splitlines() if "compensate: error" in line]
    assert len(err) == 1 and "not converged: target(s) 3, 8" in err[0]
    q, rows = _commands(out)
    ok = [i for i in range(len(rows)) if i not in (2, 7)]
    assert [r["converged"] for r in rows].count("false") == 2 and all(rows[i]["converged"] == "true" for i in ok)
    assert np.linalg.norm(real_robot(table, q[ok], "measuring") - goal[ok], axis=1).max() < 1.0


def test_metres_are_refused_in_the_measuring_frame(cell, capsys):
    d, table, q_goal = cell
    t = _write_targets(d / "targets_m.csv", real_robot(table, q_goal, "measuring") / 1000.0)
    out = d / "q_m.csv"
    capsys.readouterr()
    assert main(["compensate", str(t), "--model", str(d / "model.json"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "metres" in err and "--length-unit m" in err and not out.exists()


def test_model_keeps_calibration_poses_to_seed_compensate(cell):
    d, _, _ = cell
    fm = torchcal.load(d / "model.json")
    assert fm.seed_poses is not None and fm.seed_poses.shape == (32, 6)
    data = torch.deg2rad(torch.as_tensor(np.loadtxt(d / "data.csv", delimiter=",", skiprows=1)[:, 1:7]))
    assert torch.cdist(fm.seed_poses, data).min(dim=1).values.max() < 1e-6  # each one is a calibration pose


def test_start_stays_inside_the_calibrated_joint_range(cell):
    d, table, _ = cell
    fm = torchcal.load(d / "model.json")
    q_cal = torch.deg2rad(torch.as_tensor(np.loadtxt(d / "data.csv", delimiter=",", skiprows=1)[:40, 1:7]))
    goal = torch.as_tensor(real_robot(table, q_cal.numpy(), "measuring"))  # places the robot was calibrated at
    comp = torchcal.compensate(fm, goal)
    assert bool(comp.converged.all()) and comp.outside_range == 0


def test_the_models_own_calibration_positions_are_within_its_reach(cell):
    """The reach counts the fitted 290 mm reflector: every position the model was fitted
    on is reachable (before, the nominal TCP's reach flagged one pose, 4442 mm from the
    base, as beyond it, and compensate then gave that target one start only)."""
    import warnings

    from torchcal.calibration.checks.targets import check_targets
    from torchcal.io.measurement_csv import read_measurements

    d, _, _ = cell
    fitted = torchcal.load(d / "model.json")
    xyz = read_measurements(d / "data.csv", robot=KR).xyz
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert check_targets(fitted.model, fitted.theta, xyz) == []
    far = xyz.clone()
    far[3] += torch.tensor([9000.0, 0.0, 0.0], dtype=far.dtype)
    with pytest.warns(UserWarning, match="row\\(s\\) 4;"):
        assert check_targets(fitted.model, fitted.theta, far) == [3]


@pytest.fixture(scope="module")
def zoned(tmp_path_factory):
    """A per-zone model (`torchcal calibrate --partition`) of the same cell: 40 poses moved to
    3 times each, measured by the plain-numpy robot in the tracker frame 3 m away."""
    from torchcal.io.sweep_csv import write_sweep
    from torchcal.reliability.sweep import sweep
    from torchcal.robots.workspace import sample_workspace

    d = tmp_path_factory.mktemp("zoned")
    write_sweep(sweep(KR, sample_workspace(KR, 60, seed=6), n_samples=50), d / "sweep.csv")
    assert main(["partition", str(d / "sweep.csv"), "--levels", "2", "--zones", "2,1",
                 "--out", str(d / "part.json")]) == 0
    table = KR.table.numpy() + _deviations(KR.n)
    q = np.repeat(random_poses(KR, 40, 7).numpy(), 3, axis=0)
    xyz = real_robot(table, q, "measuring") + np.random.default_rng(4).normal(0, 0.01, (len(q), 3))
    with open(d / "data.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["pose", *(f"q{k}" for k in range(1, 7)), "x", "y", "z"])
        for i, (qq, p) in enumerate(zip(np.degrees(q), xyz)):
            w.writerow([i // 3 + 1, *map(repr, qq.tolist()), *map(repr, p.tolist())])
    assert main(["calibrate", str(d / "data.csv"), "--robot", "kr1000titan", "--effects", "base_frame",
                 "tool_offset", "--partition", str(d / "part.json"), "--out", str(d / "model.json")]) == 0
    return d, table


@pytest.fixture(scope="module")
def zoned_measuring(zoned):
    """30 targets in the tracker frame compensated with the per-zone model (asserted on by two
    tests): (exit status, stderr, commands (30, 6) rad, the output's rows, goal (30, 3) mm)."""
    d, table = zoned
    goal = real_robot(table, random_poses(KR, 30, 9).numpy(), "measuring")
    t = _write_targets(d / "targets.csv", goal)
    err = io.StringIO()
    with redirect_stdout(io.StringIO()), redirect_stderr(err):
        code = main(["compensate", str(t), "--model", str(d / "model.json"), "--out", str(d / "q.csv")])
    return (code, err.getvalue(), *_commands(d / "q.csv"), goal)


def test_a_zoned_model_solves_each_target_in_the_zone_of_its_command(zoned, zoned_measuring):
    """Zones belong to the robot base frame (calibrate assigns each pose by its nominal TCP
    position); targets are in the tracker frame, 3 m and 30 deg away. Each target must be
    solved with the parameters of the zone its command lands in, so that the model meets
    the target at the command and Q.csv names that zone. (Assigned by the targets' tracker
    coordinates, half the zones were another zone's here.)"""
    from torchcal.calibration.compensate import approach_directions, _context

    d, table = zoned
    code, err, q, rows, goal = zoned_measuring
    assert code == 0
    assert "sweep point" not in err  # every command lands among the sweep's points
    model = torchcal.load(d / "model.json")
    qt = torch.as_tensor(q)
    zone_of_command = model.partition.assign(KR.fk(qt)).tolist()
    assert [int(r["zone"]) for r in rows] == zone_of_command
    assert len(set(zone_of_command)) > 1  # the targets span several zones
    ok = [r["converged"] == "true" for r in rows]
    pred = model.predict(_context(model.model, qt, approach_directions(qt), torch.zeros(len(qt)), None)).numpy()
    assert np.linalg.norm(pred - goal, axis=1)[ok].max() < 1e-5


def test_commands_far_from_every_sweep_point_are_named():
    """A sweep of one region (a 5 x 5 x 5 grid, 100 mm apart): positions among its points
    pass; one 1 m outside it (10 spacings) is named by row with its distance."""
    import warnings

    from torchcal.calibration.checks.partition import warn_far_from_sweep
    from torchcal.calibration.checks.verdict import MismatchWarning
    from torchcal.partition.zones import partition_workspace

    g = torch.arange(5, dtype=torch.float64) * 100.0
    grid = torch.cartesian_prod(g, g, g) + torch.tensor([1000.0, 0.0, 500.0])
    part = partition_workspace(grid, torch.linspace(0.5, 1.0, 125, dtype=torch.float64), 2, [1, 1])
    inside = grid[[3, 60, 124]] + 20.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert warn_far_from_sweep(part, inside) == []
    outside = torch.cat([inside, torch.tensor([[2400.0, 200.0, 700.0]])])
    with pytest.warns(MismatchWarning, match=r"1 command\(s\) reach nominal TCP positions up to 1000 mm from the "
                      r"nearest sweep point of the partition \(spaced a median 100 mm apart\): row\(s\) 4; "):
        assert warn_far_from_sweep(part, outside, "targets") == [3]


@pytest.mark.parametrize("frame", ["measuring", "base"])
def test_real_robot_reaches_targets_with_a_zoned_model(zoned, zoned_measuring, frame):
    """The per-zone model of `calibrate --effects base_frame tool_offset` drives the plain-numpy
    robot onto targets given in either frame: its base frame holds the tracker's rotation
    about z and its height (the gauge `fit` keeps: the frames before joint 1's dtheta and
    dd), so base-frame targets are mapped by the tracker frame, not by a rotation left in
    joint 1 (before: 30 deg and 300 mm put in joint 1, base-frame targets missed by metres).
    Measuring frame: the 30 targets of the test above; base frame: the first 12 of them."""
    d, table = zoned
    code, _, q, rows, goal = zoned_measuring if frame == "measuring" else \
        _compensate(d, table, random_poses(KR, 12, 9).numpy(), frame)
    assert code == 0
    assert all(r["converged"] == "true" and r["within_limits"] == "true" for r in rows)
    assert np.linalg.norm(real_robot(table, q, frame) - goal, axis=1).max() < 1.0  # as the fit's test above


def _tool_rotation(table, q):
    """(N, 3, 3) the flange rotation of the true robot at q (N, 6) rad (plain numpy)."""
    from npsim import numpy_frames
    return np.array([numpy_frames(KR, qq, table - KR.table.numpy())[-1][:3, :3] for qq in q])


def test_without_seeds_the_output_says_the_orientation_is_not_the_users(cell, unseeded, capsys):
    """x,y,z fix 3 of the 6 joints: without seeds each command keeps the configuration of
    the nearest calibration pose, so the true robot reaches the point with another tool
    orientation than the goal's (178 deg at worst here); with the nominal commands as seeds
    it keeps the goal's. Only the seeded run may be silent about it."""
    d, table, q_goal = cell
    goal = real_robot(table, q_goal, "measuring")
    runs = {}
    for seeded in (False, True):
        if seeded:
            t = d / "targets_seeded.csv"
            t.write_text("x,y,z," + ",".join(f"q{k}" for k in range(1, 7)) + "\n" + "".join(
                ",".join(repr(float(v)) for v in [*p, *np.degrees(qq)]) + "\n" for p, qq in zip(goal, q_goal)))
            capsys.readouterr()
            assert main(["compensate", str(t), "--model", str(d / "model.json"), "--out", str(d / "q_seeded.csv")]) == 0
            q, _ = _commands(d / "q_seeded.csv")
            printed = capsys.readouterr().out
        else:  # the goals as they are (x,y,z only), compensated once for this test and the one above
            code, printed, q, _, unseeded_goal = unseeded
            assert code == 0 and np.array_equal(unseeded_goal, goal)
        R = _tool_rotation(table, q) @ _tool_rotation(table, q_goal).transpose(0, 2, 1)
        angle = np.degrees(np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1)))
        runs[seeded] = (angle.max(), printed)
    assert runs[True][0] < 0.5 and runs[False][0] > 5.0, runs
    assert "orientation" in runs[False][1] and "orientation" not in runs[True][1]


def test_base_frame_targets_say_that_joint_1s_zero_is_in_the_fitted_frame(tmp_path, capsys):
    """Tracker data cannot tell joint 1's zero offset and d1 from the base frame's rotation
    about z and z shift: the fitted base frame absorbs them. A ur5e (plain numpy) with
    dtheta1 0.05 deg and dd1 0.5 mm: measuring-frame targets are reached to the fit's
    accuracy, base-frame targets miss by dtheta1 x reach and dd1 (0.65 mm here against 0.004), and
    the output said nothing of it; now one line does, for --frame base only."""
    from npsim import numpy_fk

    ur = torchcal.robot("ur5e")
    dev = np.zeros((6, 5))
    dev[0, :2] = [np.radians(0.05), 0.5]
    dev[2, 2], dev[3, 3] = 0.3, np.radians(0.03)
    q = random_poses(ur, 60, 2).numpy()
    xyz = numpy_fk(ur, q, dev) @ R_WB.T + T_WB + np.random.default_rng(1).normal(0, 0.005, (60, 3))
    with open(tmp_path / "d.csv", "w") as fh:
        fh.write("pose," + ",".join(f"q{k}" for k in range(1, 7)) + ",x,y,z\n")
        for i, (qq, p) in enumerate(zip(np.degrees(q), xyz)):
            fh.write(",".join(map(repr, [i + 1, *qq.tolist(), *p.tolist()])) + "\n")
    assert main(["fit", str(tmp_path / "d.csv"), "--robot", "ur5e", "--effects", "base_frame",
                 "--out", str(tmp_path / "m.json")]) == 0
    qg = random_poses(ur, 10, 5).numpy()
    world = numpy_fk(ur, qg, dev)
    err, out = {}, {}
    for frame, goal in (("measuring", world @ R_WB.T + T_WB), ("base", world)):
        t = tmp_path / f"t_{frame}.csv"
        t.write_text("x,y,z," + ",".join(f"q{k}" for k in range(1, 7)) + "\n" + "".join(
            ",".join(repr(float(v)) for v in [*p, *np.degrees(qq)]) + "\n" for p, qq in zip(goal, qg)))
        capsys.readouterr()
        assert main(["compensate", str(t), "--model", str(tmp_path / "m.json"), "--frame", frame,
                     "--out", str(tmp_path / f"q_{frame}.csv")]) == 0
        out[frame] = capsys.readouterr().out
        qc, _ = _commands(tmp_path / f"q_{frame}.csv")
        err[frame] = np.linalg.norm(numpy_fk(ur, qc, dev) - world, axis=1).max()
    assert err["measuring"] < 0.05 and err["base"] > 0.3, err
    assert "joint 1" in out["base"] and "joint 1" not in out["measuring"]
