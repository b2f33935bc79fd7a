"""`compensate` with payload_kg / temp_c target columns, per-target status and exit codes."""

from __future__ import annotations

import pytest
import torch

import torchcal
from torchcal.cli import main
from torchcal.io.measurement_csv import write_measurements
from torchcal.robots.poses import random_poses
from torchcal.simulation.virtual_robot import VirtualRobot


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    d = tmp_path_factory.mktemp("comp")
    rob = torchcal.robot("ur5e")
    m = VirtualRobot(rob, ["backlash:3", "thermal_expansion"], seed=2).measure(random_poses(rob, 50, 1), seed=3)
    write_measurements(d / "data.csv", m)
    assert main(["fit", str(d / "data.csv"), "--robot", "ur5e", "--effects", "backlash:3", "thermal_expansion",
                 "--out", str(d / "model.json")]) == 0
    q = random_poses(rob, 3, 8)
    xyz = rob.fk(q)
    return d, rob, q, xyz


def _targets(path, q, xyz, temp=True, far=False):
    head = "x,y,z,q1,q2,q3,q4,q5,q6" + (",temp_c" if temp else "")
    rows = []
    for i in range(q.shape[0]):
        p = xyz[i].tolist()
        if far and i == 1:
            p = [5000.0, 0.0, 0.0]  # out of reach of a ur5e
        cells = p + torch.rad2deg(q[i]).tolist() + ([25.0] if temp else [])
        rows.append(",".join(repr(float(c)) for c in cells))
    path.write_text("\n".join([head] + rows) + "\n")
    return path


def test_model_needing_temp_c_names_the_column(model, capsys):
    d, _, q, xyz = model
    t = _targets(d / "no_temp.csv", q, xyz, temp=False)
    capsys.readouterr()
    assert main(["compensate", str(t), "--model", str(d / "model.json"), "--out", str(d / "o1.csv")]) == 2
    err = capsys.readouterr().err
    assert "temp_c" in err and len(err.strip().splitlines()) == 1 and not (d / "o1.csv").exists()


def test_targets_with_temp_c_converge_and_report_status(model):
    d, rob, q, xyz = model
    t = _targets(d / "ok.csv", q, xyz)
    assert main(["compensate", str(t), "--model", str(d / "model.json"), "--out", str(d / "o2.csv")]) == 0
    lines = (d / "o2.csv").read_text().splitlines()
    assert lines[0].endswith("residual_mm,converged,within_limits")
    assert all(r.endswith("true,true") for r in lines[1:])


def test_failed_target_is_named_and_exits_non_zero(model, capsys):
    d, _, q, xyz = model
    t = _targets(d / "far.csv", q, xyz, far=True)
    capsys.readouterr()
    code = main(["compensate", str(t), "--model", str(d / "model.json"), "--out", str(d / "o3.csv")])
    err = capsys.readouterr().err
    assert code == 1 and "not converged: target(s) 2" in err and len(err.strip().splitlines()) == 1
    rows = (d / "o3.csv").read_text().splitlines()[1:]
    assert rows[1].split(",")[-2] == "false" and rows[0].split(",")[-2] == "true"


def test_targets_beyond_reach_get_one_start_only(monkeypatch):
    """`nominal_start(once=rows)`: the rows beyond the reach are solved from their nearest
    start only; the other rows are still retried from further starts until one lands inside
    the limits and the calibrated range (here: no q_range, so every reachable row is done
    after its first try unless it failed)."""
    from torchcal.calibration import compensate as comp
    from torchcal.calibration.model import CalibrationModel

    rob = torchcal.robot("ur5e")
    model = CalibrationModel(rob)
    reach = rob.fk(random_poses(rob, 6, 4))
    t = torch.cat([reach, torch.tensor([[9000.0, 0.0, 0.0], [0.0, -9000.0, 500.0]], dtype=reach.dtype)])
    calls = []
    solve = comp.compensate
    monkeypatch.setattr(comp, "compensate", lambda m, th, tt, q0, **kw: calls.append(tt.clone()) or solve(m, th, tt, q0, **kw))
    res = comp.nominal_start(model, model.zeros(), t, once=[6, 7])
    assert len(calls) >= 1 and calls[0].shape[0] == 8
    assert not res.converged[6:].any() and res.converged[:6].all()
    for c in calls[1:]:  # no later try holds a far target
        assert not (c.abs() > 5000).any()
    calls.clear()

    class Retried(Exception):
        pass

    def stop_at_a_retry(m, th, tt, q0, **kw):  # the first retry holding a far row is the answer
        calls.append(tt.clone())
        if len(calls) > 1 and (tt.abs() > 5000).any():
            raise Retried
        return solve(m, th, tt, q0, **kw)
    monkeypatch.setattr(comp, "compensate", stop_at_a_retry)
    with pytest.raises(Retried):  # without `once` the far rows are retried
        comp.nominal_start(model, model.zeros(), t)


def test_the_api_gives_far_targets_one_start_as_the_command_line(model, monkeypatch):
    """`torchcal.compensate` seeds as `torchcal compensate` does: the rows `check_targets`
    finds beyond the reach go to `nominal_start` as `once` (before, the API retried them
    from every start); with check=False nothing is found and nothing is passed."""
    from torchcal.calibration import compensate as comp

    d, _, q, xyz = model
    t = xyz[:3].clone()
    t[1] += torch.tensor([9000.0, 0.0, 0.0], dtype=t.dtype)
    temp = torch.full((3,), 25.0, dtype=t.dtype)  # the model has thermal_expansion
    seen = []
    start = comp.nominal_start
    monkeypatch.setattr(comp, "nominal_start", lambda *a, **kw: seen.append(list(kw.get("once", ()))) or start(*a, **kw))
    with pytest.warns(UserWarning, match="beyond the reach"):
        res = torchcal.compensate(d / "model.json", t, temp_c=temp)
    assert seen == [[1]] and not bool(res.converged[1]) and bool(res.converged[0]) and bool(res.converged[2])
    seen.clear()

    class Started(Exception):  # what nominal_start is given is the answer: no need to solve
        pass

    monkeypatch.setattr(comp, "nominal_start", lambda *a, **kw: seen.append(list(kw.get("once", ()))) or _raise(Started))
    with pytest.raises(Started):
        torchcal.compensate(d / "model.json", t, temp_c=temp, check=False)
    assert seen == [[]]


def _raise(exc):
    raise exc


def test_seeds_in_radians_in_the_degree_columns_are_refused(model, capsys):
    """Seeds q1..qN written in radians under degrees (every seed within +-2 pi 'deg', the
    model there a median > SEED_MM from the targets) are one line naming --angle-unit rad
    and nothing is written: they converged, exit 0, in another arm configuration than the
    seeds'. The same file with --angle-unit rad compensates."""
    d, _, q, xyz = model
    t = _targets(d / "rad.csv", q, xyz)
    lines = t.read_text().splitlines()
    cells = [ln.split(",") for ln in lines[1:]]
    for c in cells:
        c[3:9] = [repr(float(v) * torch.pi / 180) for v in c[3:9]]  # the radians, in the degree columns
    t.write_text("\n".join([lines[0]] + [",".join(c) for c in cells]) + "\n")
    capsys.readouterr()
    assert main(["compensate", str(t), "--model", str(d / "model.json"), "--out", str(d / "o_rad.csv")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "look like radians read as degrees; pass --angle-unit rad" in err
    assert not (d / "o_rad.csv").exists()
    assert main(["compensate", str(t), "--model", str(d / "model.json"), "--out", str(d / "o_rad.csv"),
                 "--angle-unit", "rad"]) == 0


def test_a_seed_far_from_its_target_is_named(model, capsys):
    """A seed whose model point lies more than SEED_MM from its target (here the next
    target's seed) is one warning line naming its row; the command goes on."""
    d, _, q, xyz = model
    t = _targets(d / "swapped_seed.csv", q, xyz)
    lines = t.read_text().splitlines()
    a, b = lines[1].split(","), lines[2].split(",")
    a[3:9], b[3:9] = b[3:9], a[3:9]
    t.write_text("\n".join([lines[0], ",".join(a), ",".join(b), lines[3]]) + "\n")
    far = float((xyz[0] - xyz[1]).norm())
    assert far > 100.0  # the poses' points lie apart (random_poses seed 8)
    capsys.readouterr()
    assert main(["compensate", str(t), "--model", str(d / "model.json"), "--out", str(d / "o_sw.csv")]) in (0, 1)
    err = capsys.readouterr().err
    warn = [ln for ln in err.splitlines() if "seed(s) lie more than 100 mm from their targets" in ln]
    assert len(warn) == 1 and "2 seed(s)" in warn[0] and "row(s) 1, 2;" in warn[0]


@pytest.fixture(scope="module")
def tracker_model(tmp_path_factory):
    """A UR5e fitted with base_frame on noise-free points seen from a tracker 2500 mm away
    (turned 30 deg about z), and 12 reachable targets: base frame and tracker frame, mm."""
    import math

    from torchcal.measurements import Measurements

    d = tmp_path_factory.mktemp("tracker")
    rob = torchcal.robot("ur5e")
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    R = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    o = torch.tensor([2500.0, -400.0, 300.0], dtype=torch.float64)
    q = random_poses(rob, 40, 11)
    write_measurements(d / "data.csv", Measurements(torch.arange(40), q, rob.fk(q) @ R.T + o))
    assert main(["fit", str(d / "data.csv"), "--robot", "ur5e", "--effects", "base_frame",
                 "--out", str(d / "model.json")]) == 0
    base = rob.fk(random_poses(rob, 12, 12))
    return d, base, base @ R.T + o


@pytest.mark.parametrize("frame", ["measuring", "base"])
def test_targets_in_another_unit_or_frame_are_named_and_converge_in_their_own(tracker_model, capsys, frame):
    """The same 12 reachable targets given in a wrong unit or frame, each refused in one line
    naming it, exit 2, nothing written; as they are they converge (exit 0).

    - In inches or metres in an mm file they ended as 20 'beyond the reach' rows (measuring
      frame) or 'inside the base ... wrong unit or wrong frame?' (base frame), exit 1 with an
      output written: now one line naming the unit.
    - In mm with --length-unit m (read 1000 times too far) they ended as 'target(s) failed
      ... beyond the reach ... (--frame base for the other)', exit 1 with an output written:
      now one line naming the unit and the option; in metres with --length-unit m they
      converge.
    - In the other frame (base-frame targets given as measuring-frame ones, the default) they
      ended as rows 'beyond the reach' and exit 1 with an output written: now one line naming
      the frame and the option."""
    d, base, tracker = tracker_model
    xyz = tracker if frame == "measuring" else base
    other_frame = "base" if frame == "measuring" else "measuring"
    other = "measuring frame" if frame == "measuring" else "robot base frame"  # where the targets are

    def write(name, scale):
        path = d / f"t_{name}_{frame}.csv"
        path.write_text("\n".join(["x,y,z"] + [",".join(repr(float(v) / scale) for v in p) for p in xyz.tolist()]) + "\n")
        return path

    mm, metres = write("mm", 1.0), write("m", 1000.0)
    out = d / f"q_{frame}.csv"

    def refused(argv, path):
        """stderr of the refusal of path, after checking exit 2 and nothing written."""
        capsys.readouterr()
        assert main(["compensate", str(path), *argv, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and not out.exists()
        return err

    for unit, path, words in (("in", write("in", 25.4), "they look like inches read as mm; convert them to mm (x 25.4)"),
                              ("m", metres, "they look like metres read as mm; pass --length-unit m")):
        err = refused(["--model", str(d / "model.json"), "--frame", frame], path)
        assert err.startswith(f"torchcal compensate: error: {path}: ") and err.endswith(words + "\n"), unit
    err = refused(["--model", str(d / "model.json"), "--frame", frame, "--length-unit", "m"], mm)
    assert err.startswith(f"torchcal compensate: error: {mm}: read in metres, the targets lie a median ")
    assert err.endswith("a thousandth of them within its reach: they look like mm read as metres; pass "
                        "--length-unit mm\n")
    err = refused(["--model", str(d / "model.json"), "--frame", other_frame], mm)
    assert err.startswith(f"torchcal compensate: error: {mm}: as given the targets lie ")
    assert err.endswith(f"but read in the {other} they would lie within its reach: they look like coordinates in "
                        f"the {other}; pass --frame {frame}\n")
    assert main(["compensate", str(mm), "--model", str(d / "model.json"), "--frame", frame, "--out", str(out)]) == 0
    out.unlink()
    assert main(["compensate", str(metres), "--model", str(d / "model.json"), "--frame", frame, "--length-unit", "m",
                 "--out", str(out)]) == 0


def test_the_stall_stop_leaves_reachable_targets_bit_for_bit_and_stops_far_ones_early(monkeypatch):
    """`compensate` stops a row whose residual fell by less than STALL_FRACTION over its last
    STALL_ITERS iterations. Reachable targets started from a poor seed (the middle of the
    joint limits: tens of iterations of short steps) come out bit for bit as with the rule
    off, iteration counts included; targets beyond the reach, started from the pose that
    reaches nearest them (as `nominal_start` does), stop long before max_iter, their
    residual within 1e-4 of where all 100 iterations leave it with the rule off."""
    from torchcal.calibration import compensate as comp
    from torchcal.calibration.model import CalibrationModel

    rob = torchcal.robot("puma560")  # of the presets, the one whose slow rows came nearest the rule
    model = CalibrationModel(rob)  # MD-H deviations only: the analytic joint Jacobian (the rule is the same)
    theta = (torch.rand(model.n_params, generator=torch.Generator().manual_seed(1), dtype=torch.float64) - 0.5) * 1e-3
    q = random_poses(rob, 60, 7)
    reach = rob.fk(q)
    far = reach[:2] / reach[:2].norm(dim=-1, keepdim=True) * 5000.0  # 5 m from the base: beyond the reach
    t = torch.cat([reach, far])
    # reachable rows from the middle of the limits; far rows from the pose nearest them (as nominal_start)
    q0 = torch.cat([rob.limits.mean(-1).expand(len(reach), rob.n), q[:2]])
    on = comp.compensate(model, theta, t, q0, max_iter=100)
    monkeypatch.setattr(comp, "STALL_ITERS", 10**9)  # the rule off
    off = comp.compensate(model, theta, t, q0, max_iter=100)
    assert off.converged[:60].sum() >= 20 and not off.converged[60:].any()  # a third or more converge in 100
    done = off.converged
    assert torch.equal(on.q[done], off.q[done]) and torch.equal(on.iterations[done], off.iterations[done])
    assert torch.equal(on.converged, off.converged)
    assert (off.iterations[60:] == 100).all() and (on.iterations[60:] < 60).all()
    e_on, e_off = on.residual_mm[60:].norm(dim=-1), off.residual_mm[60:].norm(dim=-1)
    assert ((e_on - e_off) / e_off).abs().max() < 1e-4


def test_compensate_names_the_reflector_a_multi_point_model_lacks(tmp_path, capsys):
    """Targets carry no point column: a model with one tool offset per reflector cannot
    tell which reflector a target is for. The refusal said 'needs the model has one tool
    offset per measured point (2 points) but the data have no point column in the targets,
    which they lack'; now one line that names the points and what to do."""
    assert main(["simulate", "--robot", "ur5e", "--n", "20", "--seed", "2", "--out", str(tmp_path / "s.csv")]) == 0
    rows = (tmp_path / "s.csv").read_text().splitlines()
    two = [rows[0] + ",point"] + [r + ",1" for r in rows[1:]] + [r + ",2" for r in rows[1:]]
    (tmp_path / "p.csv").write_text("\n".join(two) + "\n")
    assert main(["fit", str(tmp_path / "p.csv"), "--robot", "ur5e", "--effects", "tool_offset",
                 "--out", str(tmp_path / "m.json")]) == 0
    (tmp_path / "t.csv").write_text("x,y,z\n" + "\n".join(",".join(r.split(",")[7:10]) for r in rows[1:4]) + "\n")
    capsys.readouterr()
    code = main(["compensate", str(tmp_path / "t.csv"), "--model", str(tmp_path / "m.json"), "--out",
                 str(tmp_path / "q.csv")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and not (tmp_path / "q.csv").exists() and len(err.splitlines()) == 1
    assert "one tool offset per reflector (points 1, 2)" in err and "fitted on the rows of one point" in err


def test_the_point_that_reaches_the_targets_is_named(tmp_path, capsys):
    """A tracker model with a reflector 290 mm off the flange (plain-numpy session): the
    targets are reached by the reflector, not the robot file's TCP, and a line says so with
    the fitted offset; a model without a tool offset prints no such line."""
    import re

    from npsim import tracker_session
    from torchcal.measurements import Measurements

    rob = torchcal.robot("ur5e")
    q = random_poses(rob, 60, 21)
    write_measurements(tmp_path / "d.csv", Measurements(torch.arange(60), q,
                                                        torch.from_numpy(tracker_session(rob, q.numpy(), seed=2))))
    assert main(["fit", str(tmp_path / "d.csv"), "--robot", "ur5e", "--effects", "base_frame", "tool_offset",
                 "--out", str(tmp_path / "m.json")]) == 0
    t = rob.fk(random_poses(rob, 5, 22))
    (tmp_path / "t.csv").write_text("x,y,z\n" + "".join(",".join(repr(float(v)) for v in r) + "\n" for r in t.tolist()))
    capsys.readouterr()
    assert main(["compensate", str(tmp_path / "t.csv"), "--model", str(tmp_path / "m.json"), "--frame", "base",
                 "--out", str(tmp_path / "q.csv")]) == 0
    out = capsys.readouterr().out
    found = re.search(r"reached by the measured point of the calibration \(the reflector\): the model's tool offset "
                      r"\[(\S+), (\S+), (\S+)\] mm", out)
    assert found and abs(float(found.group(3)) - 290.0) < 1.0, out
    from npsim import physics_session

    xyz, _ = physics_session(rob, q.numpy(), 2, [])  # the robot base frame, the robot file's tool
    write_measurements(tmp_path / "b.csv", Measurements(torch.arange(60), q, torch.from_numpy(xyz)))
    assert main(["fit", str(tmp_path / "b.csv"), "--robot", "ur5e", "--out", str(tmp_path / "g.json")]) == 0
    capsys.readouterr()
    assert main(["compensate", str(tmp_path / "t.csv"), "--model", str(tmp_path / "g.json"),
                 "--out", str(tmp_path / "q2.csv")]) == 0
    assert "measured point of the calibration" not in capsys.readouterr().out
