"""Robot files: round trip, presets by path, prismatic joints, any joint count, bad files."""

import json
import math
import re
from pathlib import Path

import pytest
import torch

import torchcal
from torchcal.cli import main
from torchcal.errors import InputError
from torchcal.io.robot_file import load_robot_file, robot_from_dict, robot_to_dict, write_robot_file

ARM7 = {"name": "arm7", "joints": [
    {"type": "revolute", "theta_offset_deg": 0, "d_mm": 340, "a_mm": 0, "alpha_deg": -90, "lower": -170, "upper": 170},
    {"type": "revolute", "theta_offset_deg": 0, "d_mm": 0, "a_mm": 0, "alpha_deg": 90, "lower": -120, "upper": 120},
    {"type": "revolute", "theta_offset_deg": 0, "d_mm": 400, "a_mm": 0, "alpha_deg": 90, "lower": -170, "upper": 170},
    {"type": "revolute", "theta_offset_deg": 0, "d_mm": 0, "a_mm": 0, "alpha_deg": -90, "lower": -120, "upper": 120},
    {"type": "revolute", "theta_offset_deg": 0, "d_mm": 400, "a_mm": 0, "alpha_deg": -90, "lower": -170, "upper": 170},
    {"type": "revolute", "theta_offset_deg": 0, "d_mm": 0, "a_mm": 0, "alpha_deg": 90, "lower": -120, "upper": 120},
    {"type": "revolute", "theta_offset_deg": 0, "d_mm": 126, "a_mm": 0, "alpha_deg": 0, "lower": -175, "upper": 175}],
    "tool": [[1, 0, 0, 10], [0, 1, 0, 0], [0, 0, 1, 50], [0, 0, 0, 1]], "payload_kg": 7}
SCARA = json.loads((Path(__file__).resolve().parents[1] / "examples" / "scara.json").read_text())


def test_round_trip_and_presets():
    for name in torchcal.PRESETS:
        r = torchcal.robot(name)
        back = robot_from_dict(json.loads(json.dumps(robot_to_dict(r))))
        assert back.same_geometry(r) and back.has_beta.tolist() == r.has_beta.tolist()
        assert torch.allclose(back.limits, r.limits, atol=1e-15)
    assert torchcal.robot("ur5e") == torchcal.robot("ur5e") and torchcal.robot("ur5e") != torchcal.robot("puma560")


def test_prismatic_robot_file(tmp_path):
    p = tmp_path / "scara.json"
    p.write_text(json.dumps(SCARA))
    r = torchcal.robot(str(p))
    assert r.prismatic.tolist() == [False, False, True, False]
    assert r.limits[2].tolist() == [0.0, 200.0]  # mm, not converted
    # hand computation: q1 = 90 deg, q2 = 0, q3 = 30 mm: x = 0, y = 600, z = 200 - (50 + 30) (alpha 180 flips z)
    q = torch.tensor([math.pi / 2, 0.0, 30.0, 0.0], dtype=torch.float64)
    assert r.fk(q).tolist() == pytest.approx([0.0, 600.0, 120.0], abs=1e-9)


@pytest.mark.parametrize("spec", [ARM7, SCARA])
def test_every_command_on_other_joint_counts(tmp_path, capsys, spec):
    rf = tmp_path / "robot.json"
    rf.write_text(json.dumps(spec))
    data, model = tmp_path / "s.csv", tmp_path / "m.json"
    assert main(["simulate", "--robot", str(rf), "--effects", "joint_compliance:2", "--n", "40", "--repeats", "2",
                 "--seed", "1", "--out", str(data)]) == 0
    header = data.read_text().splitlines()[0]
    assert header.startswith("pose," + ",".join(f"q{k}" for k in range(1, len(spec["joints"]) + 1)) + ",x")
    assert main(["fit", str(data), "--robot", str(rf), "--effects", "joint_compliance:2", "--out", str(model)]) == 0
    assert main(["evaluate", str(data), "--model", str(model), "--robot", str(rf)]) == 0
    assert main(["calibrate", str(data), "--robot", str(rf), "--out", str(tmp_path / "im.json")]) == 0
    assert main(["diagnose", str(data), "--robot", str(rf), "--folds", "2"]) == 0
    assert main(["robot", "show", str(rf)]) == 0
    out = capsys.readouterr().out
    assert ("prismatic" in out) == (spec is SCARA)
    # compensate: targets the calibrated model reaches, seeded with the commands
    from torchcal.io.measurement_csv import read_measurements
    robot = torchcal.robot(str(rf))
    m = read_measurements(data, robot=robot)
    seeds = robot.q_to_user(m.q[:3])
    t = tmp_path / "t.csv"
    t.write_text("x,y,z," + ",".join(f"q{k}" for k in range(1, robot.n + 1)) + "\n" + "".join(
        ",".join(repr(v) for v in [*m.xyz[i].tolist(), *seeds[i].tolist()]) + "\n" for i in range(3)))
    assert main(["compensate", str(t), "--model", str(model), "--out", str(tmp_path / "q.csv")]) == 0
    rows = (tmp_path / "q.csv").read_text().splitlines()
    assert len(rows) == 4 and all(r.endswith("true") for r in rows[1:])


@pytest.mark.parametrize("edit, must", [
    (lambda o: o.update(colour="red"), "unknown key(s) colour"),
    (lambda o: o["joints"][1].update(lenght=3), "joints[2]: unknown key(s) lenght"),
    (lambda o: o["joints"][0].pop("d_mm"), "joints[1]: missing key(s) d_mm"),
    (lambda o: o["joints"][2].update(type="spherical"), "joints[3].type: expected 'revolute' or 'prismatic'"),
    (lambda o: o["joints"][0].update(lower=200), "joints[1]: lower (200) must be below upper"),
    (lambda o: o["joints"][0].update(a_mm="12"), "joints[1].a_mm: expected a finite number"),
    (lambda o: o.update(tool=[[1, 0, 0], [0, 1, 0]]), "tool: expected a 4x4 matrix"),
    (lambda o: o.update(base=[[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]), "base: the upper-left 3x3 is not a rotation"),
    (lambda o: o.update(gravity=[0, 0, -9.81]), "gravity: expected a unit vector"),
    (lambda o: o.pop("joints"), "missing key 'joints'"),
])
def test_bad_robot_file_one_line_exit_2_nothing_written(tmp_path, capsys, edit, must):
    obj = json.loads(json.dumps(SCARA))
    edit(obj)
    rf = tmp_path / "bad.json"
    rf.write_text(json.dumps(obj))
    out = tmp_path / "out.csv"
    assert main(["simulate", "--robot", str(rf), "--n", "5", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and str(rf) in err and must in err
    assert not out.exists()
    with pytest.raises(InputError, match="bad.json"):
        load_robot_file(rf)


def test_write_is_atomic_and_refuses_overwrite(tmp_path):
    p = tmp_path / "r.json"
    write_robot_file(p, torchcal.robot("ur5e"))
    with pytest.raises(InputError, match="output exists"):
        write_robot_file(p, torchcal.robot("puma560"))
    assert load_robot_file(p).name == "ur5e"


# -- the record of the robot a sweep or partition file was made for ---------------------------
def test_fingerprint_is_the_sweep_manifests_and_tells_robots_apart():
    """One fingerprint: the digest the partial-sweep manifest records (its bytes: table,
    limits, base, tool, joint types as float64), which changes with each of them."""
    import dataclasses
    import hashlib

    from torchcal.io.robot_file import robot_fingerprint
    from torchcal.workflows.distributed import plan_sweep

    kr = torchcal.robot("kr1000titan")
    h = hashlib.sha256()
    for t in (kr.table, kr.limits, kr.base, kr.tool, kr.prismatic):
        h.update(t.to(torch.float64).numpy().tobytes())
    assert robot_fingerprint(kr) == h.hexdigest()
    assert plan_sweep(kr, n_points=3, n_samples=2).manifest()["robot_parameters_sha256"] == h.hexdigest()
    lim = kr.limits.clone()
    lim[2, 1] -= 1e-3
    tool = kr.tool.clone()
    tool[2, 3] += 1.0
    others = [dataclasses.replace(kr, limits=lim), dataclasses.replace(kr, tool=tool), torchcal.robot("ur5e")]
    assert len({robot_fingerprint(r) for r in [kr, *others]}) == 4
    assert robot_fingerprint(dataclasses.replace(kr, name="titan_cell_3")) == h.hexdigest()  # names do not count


def _not_exact_degrees() -> float:
    """A value in degrees that does not come back bit for bit through radians -> degrees -> radians."""
    return next(d / 1000 for d in range(1, 100000)
                if math.radians(math.degrees(math.radians(d / 1000))) != math.radians(d / 1000))


def test_check_record_passes_the_same_robot_and_names_what_differs():
    from torchcal.io.robot_file import (UnrecordedRobotWarning, check_record, record_from_dict, robot_fingerprint,
                                        robot_record)

    arm = robot_from_dict({**ARM7, "joints": [{**ARM7["joints"][0], "theta_offset_deg": _not_exact_degrees()},
                                              *ARM7["joints"][1:]]})
    record = record_from_dict(json.loads(json.dumps(robot_record(arm))), "f.json: made_for")
    assert record["name"] == "arm7" and record["fingerprint"] == robot_fingerprint(arm)
    check_record(record, arm, "f.json", "sweep")  # the same robot
    back = robot_from_dict(record["nominal_robot"])  # the same robot read back from a file: not bit for bit
    assert robot_fingerprint(back) != record["fingerprint"] and back.same_geometry(arm)
    check_record(record, back, "f.json", "sweep")
    # another robot: one line naming the file, both robots and fingerprints, what differs
    with pytest.raises(InputError) as e:
        check_record(record, torchcal.robot("ur5e"), "f.json", "sweep")
    msg = str(e.value)
    assert msg == (f"f.json: made for robot 'arm7' (fingerprint {record['fingerprint'][:12]}), not 'ur5e' "
                   f"(fingerprint {robot_fingerprint(torchcal.robot('ur5e'))[:12]}): 7 joints in the file, 6 given; "
                   f"make the sweep again for this robot")
    # the same robot with other joint limits, or another tool
    joints = [dict(j) for j in ARM7["joints"]]
    joints[0]["theta_offset_deg"] = _not_exact_degrees()
    joints[3]["lower"] = -110
    with pytest.raises(InputError, match=r"^f\.json: made for robot 'arm7' \(fingerprint [0-9a-f]{12}\), not 'arm7' "
                                         r"\(fingerprint [0-9a-f]{12}\): joint 4 limits -120\.\.120 deg in the file, "
                                         r"-110\.\.120 deg given; make the sweep again for this robot$"):
        check_record(record, robot_from_dict({**ARM7, "joints": joints}), "f.json", "sweep")
    joints[3]["lower"] = -120
    with pytest.raises(InputError, match=r": the tool differs; make"):
        check_record(record, robot_from_dict({**ARM7, "joints": joints, "tool": torch.eye(4).tolist()}), "f.json",
                     "sweep")
    with pytest.warns(UnrecordedRobotWarning, match=r"^f\.json: records no robot .* robot 'arm7'$"):
        check_record(None, arm, "f.json", "sweep")


@pytest.mark.parametrize("edit, match", [
    (lambda r: {**r, "fingerprint": "ab12"}, r"made_for: fingerprint: expected a SHA-256 digest"),
    (lambda r: {k: v for k, v in r.items() if k != "name"}, r"made_for: missing keys \['name'\]"),
    (lambda r: {**r, "nominal_robot": {**r["nominal_robot"], "joints": []}},
     r"made_for: nominal_robot: joints: expected a non-empty list"),
    (lambda r: ["arm7"], r"made_for: expected an object \{name, fingerprint, nominal_robot\}, got list"),
])
def test_a_bad_record_is_one_line(edit, match):
    from torchcal.io.robot_file import record_from_dict, robot_record

    with pytest.raises(InputError, match=match):
        record_from_dict(edit(robot_record(robot_from_dict(ARM7))), "f.json: made_for")


@pytest.mark.parametrize("edit, words", [
    (lambda j: j.update(alpha_deg=math.radians(j["alpha_deg"])),
     r"joints\[1\]\.alpha_deg = -1\.5708: pi/2 or pi written in radians .*robot files take degrees \(e\.g\. 90"),
    (lambda j: j.update(lower=math.radians(j["lower"]), upper=math.radians(j["upper"])),
     r"every revolute joint's limits lie within \+-3\.054 deg: they look like radians; robot files take degrees")])
def test_angles_in_radians_are_refused(tmp_path, edit, words):
    """Twists or limits written in radians were read as degrees: a twist of 1.57 deg gave
    'cannot come from arm7' at the fit; limits of +-3 deg only a warning per data row."""
    obj = json.loads(json.dumps(ARM7))
    for j in obj["joints"]:
        edit(j)
    (tmp_path / "rad.json").write_text(json.dumps(obj))
    with pytest.raises(InputError, match=rf"^{re.escape(str(tmp_path / 'rad.json'))}: {words}"):
        torchcal.robot(tmp_path / "rad.json")
    torchcal.robot("ur5e"), robot_from_dict(SCARA)  # degrees: fine


def test_one_joints_limits_in_radians_warn_once(tmp_path, capsys):
    """One joint's limits copied from a URDF (radians) into a file in degrees: joint 7 read
    as +-3.05 deg, and plan sampled its poses there in silence (each data row only warns at
    the fit). Now one warning names the joint and its limits in degrees if they are
    radians; a joint that truly turns +-10 deg says nothing."""
    import warnings

    from torchcal.robots.checks import RobotUnitWarning

    obj = json.loads(json.dumps(ARM7))
    obj["joints"][6].update(lower=-3.0543, upper=3.0543)
    path = tmp_path / "mixed.json"
    path.write_text(json.dumps(obj))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        torchcal.robot(path)
    msgs = [str(x.message) for x in w if issubclass(x.category, RobotUnitWarning)]
    assert msgs == [f"{path}: joints[7] limits -3.0543..3.0543 deg look like radians (-175..175 deg if they are), "
                    "while the other joints turn up to 170 deg; robot files take degrees (lower, upper)"]
    capsys.readouterr()
    assert main(["plan", "--robot", str(path), "--n", "12", "--out", str(tmp_path / "p.csv")]) == 0
    err = [ln for ln in capsys.readouterr().err.splitlines() if "look like radians" in ln]
    assert len(err) == 1 and err[0].startswith("torchcal: warning: ")
    obj["joints"][6].update(lower=-10, upper=10)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RobotUnitWarning)
        robot_from_dict(obj), torchcal.robot("ur5e"), robot_from_dict(SCARA)


def test_a_robot_file_in_micrometres_is_refused(tmp_path):
    """Lengths in micrometres (the KR-size arm7 at 1000 x) read as a 1.8 km arm; refused
    in one line, as lengths in metres are; a 60 m linear track passes."""
    obj = json.loads(json.dumps(ARM7))
    for j in obj["joints"]:
        j.update(d_mm=1000 * j["d_mm"], a_mm=1000 * j["a_mm"])
    (tmp_path / "um.json").write_text(json.dumps(obj))
    with pytest.raises(InputError, match=r"um.json: the links reach 1266 m in all "
                                         r".*look like micrometres; robot files take millimetres"):
        torchcal.robot(tmp_path / "um.json")
    track = json.loads(json.dumps(ARM7))
    track["joints"].insert(0, {"type": "prismatic", "theta_offset_deg": 0, "d_mm": 0, "a_mm": 0, "alpha_deg": 0,
                               "lower": 0, "upper": 60000})
    assert robot_from_dict(track).n == 8


def test_a_slide_in_metres_warns_once(tmp_path):
    """The SCARA's lift written 0..0.2 (metres) travelled 0.2 mm in silence (its links in
    mm reach far enough for the file-wide metres check); now one warning names it."""
    import warnings

    from torchcal.robots.checks import RobotUnitWarning

    obj = json.loads(json.dumps(SCARA))
    k = next(i for i, j in enumerate(obj["joints"]) if j["type"] == "prismatic")
    lo, hi = obj["joints"][k]["lower"], obj["joints"][k]["upper"]
    obj["joints"][k].update(lower=lo / 1000, upper=hi / 1000)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        robot_from_dict(obj, "s.json")
    msgs = [str(x.message) for x in w if issubclass(x.category, RobotUnitWarning)]
    assert len(msgs) == 1 and msgs[0].startswith(f"s.json: joints[{k + 1}] (prismatic) travels only "), msgs
    assert f"look like metres ({1000 * lo / 1000:g}..{1000 * hi / 1000:g} mm if they are)" in msgs[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error", RobotUnitWarning)
        robot_from_dict(SCARA)
