"""Robot files: round trip, presets by path, prismatic joints, any joint count, bad files."""

import json
import math
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
