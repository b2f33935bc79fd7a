"""Measurement planning: selection criteria, ordering, the plan and accuracy commands."""

import csv
import itertools

import numpy as np
import pytest
import torch

import torchcal
from torchcal.calibration.model import CalibrationModel
from torchcal.cli import main
from torchcal.planning import design
from torchcal.planning.order import order_poses, path_length
from torchcal.robots.poses import random_poses


def _blocks(M=400, seed=0):
    robot = torchcal.robot("puma560")
    q = random_poses(robot, M, seed)
    model = CalibrationModel(robot)
    J = design.candidate_jacobian(model, q)
    free, A = design.scaled_columns(J, model)
    return robot, model, q, J, free, A


def test_candidate_jacobian_analytic_equals_autodiff():
    robot = torchcal.robot("puma560")
    q = random_poses(robot, 5, 1)
    model = CalibrationModel(robot)
    from torchcal.effects import make_context
    ref = model.jacobian(model.zeros(), make_context(robot, q))
    assert torch.allclose(design.candidate_jacobian(model, q), ref, atol=1e-9)


def test_criterion_against_numpy():
    _, _, _, _, _, A = _blocks(60)
    B = A.numpy().reshape(-1, A.shape[-1])
    s = np.linalg.svd(B, compute_uv=False)
    assert design.criterion(A, "D") == pytest.approx(2 * np.log(s).sum(), rel=1e-9)
    assert design.criterion(A, "E") == pytest.approx(s[-1] ** 2, rel=1e-6)
    assert design.criterion(A, "O1") == pytest.approx(np.exp(np.log(s).mean()) / np.sqrt(60), rel=1e-9)


@pytest.mark.parametrize("kind", ["D", "E"])
def test_planned_beats_random_plans(kind):
    _, _, _, _, _, A = _blocks()
    plan = design.select(A, 15, kind)
    assert len(set(plan.index.tolist())) == 15
    assert plan.value == pytest.approx(design.criterion(A[plan.index], kind))
    g = torch.Generator().manual_seed(3)
    rand = [design.criterion(A[torch.randperm(A.shape[0], generator=g)[:15]], kind) for _ in range(50)]
    assert plan.value > max(rand)


def test_exchange_is_a_local_optimum_for_d():
    """No single swap of a chosen pose for a candidate raises log det (checked exhaustively
    on a small candidate set)."""
    _, _, _, _, _, A = _blocks(60, seed=2)
    plan = design.select(A, 8, "D", exchange_passes=20)
    chosen = plan.index.tolist()
    best = design.criterion(A[chosen], "D")
    for pos, c in itertools.product(range(8), range(60)):
        if c in chosen:
            continue
        trial = chosen[:pos] + [c] + chosen[pos + 1:]
        assert design.criterion(A[trial], "D") <= best + 1e-9


def test_order_is_a_permutation_and_optimal_on_small_sets():
    g = torch.Generator().manual_seed(0)
    q = torch.rand(7, 3, generator=g, dtype=torch.float64) * 4 - 2
    perm = order_poses(q)
    assert sorted(perm.tolist()) == list(range(7))
    z = torch.zeros(3, dtype=torch.float64)
    brute = min(path_length(q[list(p)], z) for p in itertools.permutations(range(7)))
    got = path_length(q[perm], z)
    assert got <= 1.1 * brute  # NN + 2-opt: near the exhaustive optimum
    assert got <= path_length(q, z)


def test_plan_cli_writes_poses_inside_limits_and_prints_indices(tmp_path, capsys):
    out = tmp_path / "plan.csv"
    assert main(["plan", "--robot", "puma560", "--n", "12", "--candidates", "500", "--seed", "1",
                 "--out", str(out), "--plots", str(tmp_path / "p")]) == 0
    text = capsys.readouterr().out
    for k in ("O1", "O2", "O3", "O4", "O5", "criterion D", "random plans"):
        assert k in text
    rows = list(csv.reader(out.open()))
    robot = torchcal.robot("puma560")
    assert rows[0] == ["pose"] + [f"q{j + 1}" for j in range(robot.n)]
    q = torch.deg2rad(torch.tensor([[float(v) for v in r[1:]] for r in rows[1:]], dtype=torch.float64))
    assert q.shape == (12, robot.n) and bool(robot.within_limits(q).all())
    assert [int(r[0]) for r in rows[1:]] == list(range(12))
    assert (tmp_path / "p" / "plan_poses.png").stat().st_size > 10_000
    assert (tmp_path / "p" / "plan_criterion.png").stat().st_size > 10_000


@pytest.mark.parametrize("argv, words", [
    (["--n", "2"], "; pass --n "),
    (["--n", "20", "--candidates", "10"], "--candidates"),
    (["--n", "10", "--effects", "nosuch"], "nosuch"),
])
def test_plan_bad_input_one_line_exit_2_nothing_written(tmp_path, capsys, argv, words):
    out = tmp_path / "plan.csv"
    few = [] if "--candidates" in argv else ["--candidates", "300"]  # an option is given once
    rc = main(["plan", "--robot", "puma560", *few, "--out", str(out)] + argv)
    err = capsys.readouterr().err
    assert rc == 2 and words in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_accuracy_cli(tmp_path, capsys):
    from torchcal.io.measurement_csv import write_measurements
    from torchcal.simulation.virtual_robot import VirtualRobot

    robot = torchcal.robot("puma560")
    m = VirtualRobot(robot, seed=1).measure(random_poses(robot, 30, 1), noise_mm=0.05)
    write_measurements(tmp_path / "m.csv", m)
    model = tmp_path / "model.json"
    assert main(["fit", str(tmp_path / "m.csv"), "--robot", "puma560", "--out", str(model)]) == 0
    capsys.readouterr()
    assert main(["accuracy", str(model), "--n", "300", "--plots", str(tmp_path / "p"),
                 "--rrd", str(tmp_path / "a.rrd")]) == 0
    text = capsys.readouterr().out
    assert "worst regions" in text and "median" in text
    assert (tmp_path / "p" / "accuracy_map.png").exists() and (tmp_path / "a.rrd").exists()
    # bad input: a model file without covariance -> one line, exit 2, no recording
    import json
    obj = json.loads(model.read_text())
    del obj["covariance"]
    old = tmp_path / "old.json"
    old.write_text(json.dumps(obj))
    rc = main(["accuracy", str(old), "--n", "50", "--rrd", str(tmp_path / "b.rrd")])
    err = capsys.readouterr().err
    assert rc == 2 and "covariance" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "b.rrd").exists()


def test_plan_keeps_out_of_the_column_about_joint_1_of_a_robot_on_a_moved_base(tmp_path, capsys):
    """A ur5e whose robot file's base stands 1.7 m from the cell origin (and 400 mm up):
    planned poses keep the TCP out of the keep-out column about joint 1's axis (350 mm, up to
    1100 mm above joint 1's frame), checked with the plain-numpy chain of tests/npsim.py.
    The column was taken about the cell's z axis: 1047 of 2000 workspace poses of this robot
    lay inside the column about joint 1."""
    import json

    from npsim import numpy_fk

    base = [[1, 0, 0, 1500.0], [0, 1, 0, 800.0], [0, 0, 1, 400.0], [0, 0, 0, 1]]
    ur = torchcal.robot("ur5e")
    joints = [{"type": "revolute", "theta_offset_deg": float(np.degrees(t[0])), "d_mm": float(t[1]),
               "a_mm": float(t[2]), "alpha_deg": float(np.degrees(t[3])), "lower": float(np.degrees(lo)),
               "upper": float(np.degrees(hi))} for t, (lo, hi) in zip(ur.table.tolist(), ur.limits.tolist())]
    (tmp_path / "r.json").write_text(json.dumps({"name": "ur5e_moved", "joints": joints, "base": base}))
    out = tmp_path / "plan.csv"
    assert main(["plan", "--robot", str(tmp_path / "r.json"), "--n", "40", "--candidates", "2000",
                 "--column-radius", "350", "--column-height", "1100", "--out", str(out)]) == 0  # (default: scaled)
    rows = list(csv.DictReader(out.open()))
    robot = torchcal.robot(str(tmp_path / "r.json"))
    q = np.radians([[float(r[f"q{k}"]) for k in range(1, 7)] for r in rows])
    local = numpy_fk(robot, q, np.zeros((6, 5))) - np.array(base)[:3, 3]  # base: a pure translation
    inside = (np.hypot(local[:, 0], local[:, 1]) < 350.0) & (local[:, 2] < 1100.0)
    assert inside.sum() == 0, inside.sum()


def test_plan_holds_what_the_fit_of_its_poses_holds(tmp_path, capsys):
    """The held parameters a plan prints are those `fit` holds on data measured at its poses:
    the same gauge (a frame kept, the robot deviation it cannot be told from held). Before,
    the plan held the frames' tool_x, tool_z, base_tz, base_rz and printed them as 'not
    identifiable from any pose', while the fit identifies them and holds dd1, dtheta1,
    dd6, da6 instead."""
    import npsim
    from torchcal.measurements import Measurements
    from torchcal.planning.plan import plan

    robot = torchcal.robot("ur5e")
    res = plan(robot, ["base_frame", "tool_offset"], n=30, candidates=2000, seed=3, random_plans=2)
    xyz = npsim.tracker_session(robot, res.q.numpy(), seed=4, sag_deg=0.0)
    m = Measurements(torch.arange(30), res.q, torch.as_tensor(xyz))
    fitted = torchcal.fit(robot, m, ["base_frame", "tool_offset"])
    assert res.held == fitted.report.held and any(h.startswith("tool_") for h in res.held) is False
    assert main(["plan", "--robot", "ur5e", "--effects", "base_frame", "tool_offset", "--n", "30", "--candidates",
                 "2000", "--seed", "3", "--random-plans", "2", "--out", str(tmp_path / "p.csv")]) == 0
    line = [ln for ln in capsys.readouterr().out.splitlines() if "held at nominal" in ln]
    assert line == [f"held at nominal (no candidate pose tells them from the parameters kept; fit holds them "
                    f"too): {', '.join(res.held)}"]
