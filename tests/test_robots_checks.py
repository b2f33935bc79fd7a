"""A robot's own numbers and two robots (torchcal.robots.checks): a robot file in metres
is refused, a model given a robot file of the same name with another geometry names
what differs, and a model with gravity-driven effects given a robot mounted otherwise
gets one warning line (`warn_other_gravity`)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

import torchcal
from torchcal.api import compensate_targets
from torchcal.errors import InputError
from torchcal.io.measurement_csv import write_measurements
from torchcal.io.robot_file import robot_from_dict, robot_to_dict
from torchcal.measurements import Measurements
from torchcal.robots.poses import random_poses
from torchcal.simulation.virtual_robot import VirtualRobot

from npsim import physics_session

UR10 = Path(__file__).resolve().parents[1] / "examples" / "ur10" / "ur10.json"


def test_robot_file_in_metres_is_refused():
    obj = json.loads(UR10.read_text())
    for j in obj["joints"]:
        j["d_mm"], j["a_mm"] = j["d_mm"] / 1000, j["a_mm"] / 1000
    with pytest.raises(InputError, match="lengths look like metres"):
        robot_from_dict(obj, "ur10_m.json")
    robot_from_dict(json.loads(UR10.read_text()), "ur10.json")  # in mm: fine


@pytest.mark.parametrize("edit, words", [
    (lambda d: d["tool"][2].__setitem__(3, 120.0), "(the tool differs)"),
    (lambda d: d["joints"][1].__setitem__("a_mm", d["joints"][1]["a_mm"] + 5.0),
     "(the MD-H table differs at joint(s) 2)")])
def test_a_model_with_a_robot_file_of_the_same_name_names_what_differs(tmp_path, capsys, edit, words):
    """evaluate --robot with a robot file of the model's robot but another tool (a tool
    changed since the fit) was refused as 'another nominal geometry' without saying what
    differs; now the line names it."""
    from torchcal.cli import main
    from torchcal.io.robot_file import robot_to_dict

    rob = torchcal.robot("ur5e")
    m = VirtualRobot(rob, ["base_frame"], seed=3).measure(random_poses(rob, 30, 3), noise_mm=0.01)
    write_measurements(tmp_path / "d.csv", m)
    torchcal.save(torchcal.fit(rob, m, ["base_frame"]), tmp_path / "m.json")
    obj = robot_to_dict(rob)
    edit(obj)
    (tmp_path / "r.json").write_text(json.dumps(obj))
    capsys.readouterr()
    assert main(["evaluate", str(tmp_path / "d.csv"), "--model", str(tmp_path / "m.json"),
                 "--robot", str(tmp_path / "r.json"), "--json", str(tmp_path / "e.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and not (tmp_path / "e.json").exists()
    assert f"with another nominal geometry {words}; refusing" in err, err


def test_a_robot_mounted_otherwise_is_named_for_a_model_with_gravity_driven_effects(tmp_path, capsys):
    """A joint-compliance model of a floor-mounted ur5e (plain-numpy gravity sag) given with a
    ceiling-mounted robot file: one line naming both gravity directions; a geometric model
    with it, and the compliance model with the floor robot, say nothing."""
    from torchcal.cli import main
    from torchcal.robots.checks import RobotGravityWarning

    rob = torchcal.robot("ur5e")
    q = random_poses(rob, 60, 8)
    xyz, load = physics_session(rob, q.numpy(), seed=8, hidden=["joint_compliance:2"])
    write_measurements(tmp_path / "d.csv", Measurements(torch.arange(60), q, torch.from_numpy(xyz),
                                                        payload_kg=torch.from_numpy(load)), robot=rob)
    for name, effects in (("jc", ["--effects", "joint_compliance:2"]), ("geo", [])):
        assert main(["fit", str(tmp_path / "d.csv"), "--robot", "ur5e", *effects,
                     "--out", str(tmp_path / f"{name}.json")]) == 0
    ceiling = robot_to_dict(rob)
    ceiling["gravity"] = [0.0, 0.0, 1.0]
    (tmp_path / "ceiling.json").write_text(json.dumps(ceiling))
    for model, robot, lines in (("jc", "ceiling.json", 1), ("geo", "ceiling.json", 0), ("jc", "ur5e", 0)):
        capsys.readouterr()
        assert main(["evaluate", str(tmp_path / "d.csv"), "--model", str(tmp_path / f"{model}.json"),
                     "--robot", robot if robot == "ur5e" else str(tmp_path / robot)]) == 0
        err = capsys.readouterr().err
        assert err.count("the robot given has gravity [0, 0, 1]") == lines, err
    with pytest.warns(RobotGravityWarning, match=r"\(180 deg apart\).*joint_compliance:2"):
        compensate_targets(tmp_path / "jc.json", torch.tensor([[300.0, 200.0, 400.0]], dtype=torch.float64),
                           robot=tmp_path / "ceiling.json", payload_kg=torch.tensor([1.0], dtype=torch.float64))


def _gear_session(robot, ratio: float, n: int, seed: int):
    """(q (n, 6) rad, xyz (n, 3) mm): plain-numpy FK of `robot` whose joint 2 turns by
    q + s1 sin(r q) + c1 cos(r q) + s2 sin(2 r q) (r the reducer ratio, amplitudes of
    0.01..0.03 deg), 0.02 mm noise."""
    import numpy as np

    from npsim import numpy_fk
    rng = np.random.default_rng(seed)
    lo, hi = robot.limits[:, 0].numpy(), robot.limits[:, 1].numpy()
    q = rng.uniform(lo, hi, size=(n, robot.n))
    s1, c1, s2 = np.radians([0.02, -0.03, 0.01])
    qe = q.copy()
    qe[:, 1] += s1 * np.sin(ratio * q[:, 1]) + c1 * np.cos(ratio * q[:, 1]) + s2 * np.sin(2 * ratio * q[:, 1])
    xyz = numpy_fk(robot, qe, np.zeros((robot.n, 5))) + rng.normal(0.0, 0.02, (n, 3))
    return torch.from_numpy(q), torch.from_numpy(xyz)


def test_a_gear_ratio_written_inverted_is_named_and_valid_ratios_are_not():
    import warnings

    from torchcal.robots.checks import RobotUnitWarning
    obj = robot_to_dict(torchcal.robot("ur5e"))
    q, xyz = _gear_session(torchcal.robot("ur5e"), 101.0, 80, seed=7)
    m = Measurements(torch.arange(len(q)), q, xyz)
    effects = ["gear_transmission:2"]
    obj["gear_ratio"] = [101.0] * 6
    with warnings.catch_warnings():
        warnings.simplefilter("error", RobotUnitWarning)
        right = robot_from_dict(obj, "ur5e.json")
        for ratios in ([1, None, 121, 80.5, 1.0, 50], [220, 220, 180, 120, 120, 90]):  # direct drive, unknown
            robot_from_dict(dict(obj, gear_ratio=ratios), "ok.json")
    obj["gear_ratio"] = [1 / 101.0] * 6
    with pytest.warns(RobotUnitWarning, match=r"ur5e_inv.json: gear_ratio\[1\] = 0.009901 \(and 5 more joint\(s\)\) "
                                               r"is below 1.*inverted.*\(101 if so\)"):
        inverted = robot_from_dict(obj, "ur5e_inv.json")
    rms_right = torchcal.fit(right, m, effects).rms_mm
    rms_inverted = torchcal.fit(inverted, m, effects).rms_mm
    assert rms_right < 0.05 < 3 * rms_right < rms_inverted  # what the warning is about: the fit misses it


def _robot_on_a_mount(robot, z_mm: float):
    """`robot` with its base (world <- joint-1 frame) raised by z_mm."""
    import dataclasses
    B = torch.eye(4, dtype=torch.float64)
    B[2, 3] = z_mm
    return dataclasses.replace(robot, base=B)


def _heights_above_base(robot, q):
    """(N,) mm: plain-numpy TCP height above the robot's joint-1 frame (its base undone)."""
    import numpy as np

    from npsim import numpy_fk
    return numpy_fk(_robot_on_a_mount(robot, 0.0), np.asarray(q), np.zeros((robot.n, 5)))[:, 2]


def test_a_floor_above_the_robots_base_is_named(tmp_path):
    """A robot file written by `torchcal export` has the measuring frame as its world frame:
    a tracker 500 mm above the robot's base (tests/npsim.py) put the default floor z > 0
    500 mm above the base, and `plan` drew every pose above it in silence."""
    import warnings

    from npsim import tracker_session
    from torchcal.api import export
    from torchcal.planning.plan import plan
    from torchcal.robots.checks import FloorWarning
    from torchcal.robots.workspace import Workspace

    ur = torchcal.robot("ur5e")
    q = random_poses(ur, 60, 4)
    xyz = torch.from_numpy(tracker_session(ur, q.numpy(), seed=3))
    res = torchcal.fit(ur, Measurements(torch.arange(60), q, xyz), ["base_frame", "tool_offset"])
    export(res, robot_file=tmp_path / "cal.json")
    cal = torchcal.robot(str(tmp_path / "cal.json"))
    z = float(cal.base[2, 3])
    assert -520 < z < -480  # the tracker's frame, 500 mm above the base
    with pytest.warns(FloorWarning, match=rf"floor z > 0 mm lies {-z:.0f} mm above the robot's base.*"
                                          rf"a floor of {z:.0f} mm: plan's floor option"):
        slab = plan(cal, ["base_frame", "tool_offset"], n=20, candidates=400, seed=0)
    assert _heights_above_base(cal, slab.q).min() > -z - 30  # what it names: no pose below the tracker's height
    with warnings.catch_warnings():
        warnings.simplefilter("error", FloorWarning)
        fixed = plan(cal, ["base_frame", "tool_offset"], n=20, candidates=400, seed=0, workspace=Workspace(z))
        for robot in (ur, torchcal.robot(str(UR10)), torchcal.robot("kr1000titan"),
                      _robot_on_a_mount(ur, 600.0), _robot_on_a_mount(ur, -80.0)):
            plan(robot, ["base_frame", "tool_offset"], n=20, candidates=400, seed=1)
    assert _heights_above_base(cal, fixed.q).min() < 200



def test_revolute_limits_beyond_two_turns_are_named():
    """Limits in tenths of a degree (the UR10's +-360 deg written +-3600): plan drew every
    pose with a joint beyond +-360 deg (30 of 30) in silence; now one warning names the
    joint and its turns. The presets, the UR10's and the SCARA example's files (+-360 deg)
    and a joint of exactly two turns say nothing."""
    import warnings

    import numpy as np

    from torchcal.planning.plan import plan
    from torchcal.robots.checks import RobotUnitWarning

    obj = json.loads(UR10.read_text())
    with warnings.catch_warnings():
        warnings.simplefilter("error", RobotUnitWarning)
        for name in ("kr1000titan", "ur5e", "puma560"):
            robot_from_dict(robot_to_dict(torchcal.robot(name)), name)
        robot_from_dict(obj, "ur10.json")
        robot_from_dict(json.loads((UR10.parents[1] / "scara.json").read_text()), "scara.json")
        two = json.loads(UR10.read_text())
        two["joints"][5].update(lower=-720.0, upper=720.0)
        robot_from_dict(two, "two_turns.json")
    for j in obj["joints"]:
        j["lower"], j["upper"] = 10 * j["lower"], 10 * j["upper"]
    with pytest.warns(RobotUnitWarning, match=r"tenths.json: joints\[1\] limits -3600..3600 deg \(and 5 more "
                                               r"joint\(s\)\) turn 10 turns, beyond the 2 turns"):
        tenths = robot_from_dict(obj, "tenths.json")
    q = np.degrees(plan(tenths, n=30, candidates=500, seed=0).q.numpy())
    assert (np.abs(q) > 360).any(axis=1).mean() > 0.9  # what it names: poses the robot cannot take


def test_parallel_axes_without_a_hayati_beta_are_named(tmp_path):
    """A ur5e robot file copied from a D-H data sheet, without the betas of joints 2 and 3
    (their next axes are parallel to their own): a tilt between the parallel axes has no
    parameter, so on a plain-numpy session with such tilts (up to 0.02 deg) the fit is
    left about twice the noise (it was read in silence; discover then named nothing and
    left it 'unexplained'). One ParallelAxesWarning names joint 2 (and joint 3); the
    robot files of examples/ and the presets written out are silent."""
    import warnings

    from torchcal.robots.checks import ParallelAxesWarning

    ur = torchcal.robot("ur5e")
    obj = robot_to_dict(ur)
    for j in obj["joints"]:
        j.pop("beta_deg", None)
    path = tmp_path / "ur5e_dh.json"
    path.write_text(json.dumps(obj))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        bare = torchcal.robot(path)
    msgs = [str(x.message) for x in w if issubclass(x.category, ParallelAxesWarning)]
    assert len(msgs) == 1 and msgs[0].startswith(f"{path}: joints[2] has no beta_deg while joints[3]'s axis is "
                                                 "parallel to its own (joints[2].alpha_deg 0) (so has joints[3])"), msgs
    assert 'add "beta_deg": 0 to joints[2] and the others' in msgs[0]
    q = random_poses(ur, 40, 3)
    xyz, _ = physics_session(ur, q.numpy(), 4, [], noise_mm=0.02)  # dbeta2, dbeta3 within +-0.02 deg
    m = Measurements(pose=torch.arange(1, 41), q=q, xyz=torch.tensor(xyz))
    with_beta, without = (torchcal.fit(r, m).rms_mm for r in (ur, bare))
    assert without > 1.5 * with_beta, (without, with_beta)
    (tmp_path / "ur5e.json").write_text(json.dumps(robot_to_dict(ur)))
    with warnings.catch_warnings():
        warnings.simplefilter("error", ParallelAxesWarning)
        for p in (UR10, UR10.parents[1] / "scara.json", tmp_path / "ur5e.json"):
            torchcal.robot(p)


# a Franka Panda's Craig (modified, proximal) D-H table as its data sheet gives it, one row a
# joint: theta_offset, d, a, alpha (a and alpha of the link before the joint), limits, deg / mm
PANDA_CRAIG = [(0, 333, 0, 0), (0, 0, 0, -90), (0, 316, 0, 90), (0, 0, 82.5, 90), (0, 384, -82.5, -90),
               (0, 0, 0, 90), (0, 0, 88, 90)]
PANDA_LIMITS = [(-166, 166), (-101, 101), (-166, 166), (-176, -4), (-166, 166), (-1, 215), (-166, 166)]


def panda_file(rows) -> dict:
    """A robot-file dict of a 7-joint Panda from rows (theta_offset, d, a, alpha), flange 107 mm."""
    return {"name": "panda", "payload_kg": 3, "tool": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 107], [0, 0, 0, 1]],
            "joints": [{"type": "revolute", "theta_offset_deg": t, "d_mm": d, "a_mm": a, "alpha_deg": al,
                        "lower": lo, "upper": hi} for (t, d, a, al), (lo, hi) in zip(rows, PANDA_LIMITS)]}


def panda_distal() -> list:
    """PANDA_CRAIG rewritten by hand in torchcal's rows (a, alpha of the link after the joint)."""
    return [(t, d, *(PANDA_CRAIG[i + 1][2:] if i < 6 else (0, 0))) for i, (t, d, _, _) in enumerate(PANDA_CRAIG)]


def test_a_table_in_craigs_convention_is_named(tmp_path):
    """A Panda's Craig D-H table typed into a robot file reads as joints 1 and 2 turning
    about one line (row 1's a and alpha are a_0 = 0, alpha_0 = 0): one ParallelAxesWarning
    names them and the convention (before: read in silence, as another arm). The table
    rewritten by hand is silent, and `distal_from_proximal` of the typed one is that arm:
    the same points as the plain-numpy chain of the hand-written table, to 1e-9 mm."""
    import warnings

    import numpy as np

    from npsim import numpy_fk
    from torchcal.robots.checks import ParallelAxesWarning, distal_from_proximal

    (tmp_path / "craig.json").write_text(json.dumps(panda_file(PANDA_CRAIG)))
    (tmp_path / "panda.json").write_text(json.dumps(panda_file(panda_distal())))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        typed = torchcal.robot(tmp_path / "craig.json")
        right = torchcal.robot(tmp_path / "panda.json")
    msgs = [str(x.message) for x in w if issubclass(x.category, ParallelAxesWarning)]
    assert len(msgs) == 1 and msgs[0].startswith(f"{tmp_path / 'craig.json'}: joints[1] and joints[2] turn about "
                                                 "one line (joints[1].a_mm 0, alpha_deg 0)"), msgs
    assert "Craig's modified D-H convention" in msgs[0] and "move each row's a_mm and alpha_deg up one row" in msgs[0]
    q = random_poses(right, 50, 4).numpy()
    assert np.abs(numpy_fk(distal_from_proximal(typed), q, np.zeros((7, 5)))
                  - numpy_fk(right, q, np.zeros((7, 5)))).max() < 1e-9
    # the first row's a and alpha (a_0, alpha_0) go into the base: a chain written out in numpy
    from npsim import _rx, _rz, _tr

    rows = [(10.0, 200.0, 50.0, 30.0), (-20.0, 0.0, 0.0, -90.0), (0.0, 120.0, 300.0, 90.0), (5.0, 80.0, -40.0, 90.0)]
    obj = panda_file(rows)
    obj["joints"] = obj["joints"][:4]
    tool = np.array(obj["tool"], dtype=float)
    craig = [np.linalg.multi_dot([*(_rx(np.radians(al)) @ _tr(a, 0.0) @ _rz(np.radians(t) + qj) @ _tr(0.0, d)
                                    for (t, d, a, al), qj in zip(rows, qq)), tool])[:3, 3] for qq in q[:, :4]]
    assert np.abs(numpy_fk(distal_from_proximal(robot_from_dict(obj)), q[:, :4], np.zeros((4, 5)))
                  - np.array(craig)).max() < 1e-9
