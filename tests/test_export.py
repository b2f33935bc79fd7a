"""`torchcal export`: the calibrated geometry of a fitted model as a robot file, URDF, table;
models are self-contained and refuse another robot's data."""

import json

import pytest

import torchcal
from torchcal.cli import main
from torchcal.effects import make_context
from torchcal.io import modelfile
from torchcal.io.measurement_csv import read_measurements
from torchcal.robots.robot_file import load_robot_file
from torchcal.robots.urdf import robot_from_urdf


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    d = tmp_path_factory.mktemp("export")
    assert main(["simulate", "--robot", "ur5e", "--effects", "base_frame", "tool_offset", "--n", "60",
                 "--seed", "3", "--out", str(d / "s.csv")]) == 0
    assert main(["fit", str(d / "s.csv"), "--robot", "ur5e", "--effects", "base_frame", "tool_offset",
                 "--out", str(d / "m.json")]) == 0
    return d


def test_exported_robot_file_reproduces_model_predictions(fitted, capsys):
    d = fitted
    assert main(["export", str(d / "m.json"), "--robot-file", str(d / "cal.json"), "--urdf", str(d / "cal.urdf"),
                 "--table", str(d / "cal.csv"), "--force"]) == 0
    fitted = modelfile.load(d / "m.json")
    model, theta = fitted.model, fitted.theta
    m = read_measurements(d / "s.csv", robot=model.robot)
    pred = model.predict(theta, make_context(model.robot, m.q, m.payload_kg, m.temp_c))
    cal = load_robot_file(d / "cal.json")
    assert (cal.fk(m.q) - pred).norm(dim=-1).max() < 1e-6
    # the URDF re-imported gives the same calibrated FK
    back = robot_from_urdf(d / "cal.urdf", "base_link", "tcp")
    assert (back.fk(m.q) - pred).norm(dim=-1).max() < 1e-3
    # the table holds the calibrated rows in degrees and mm
    rows = (d / "cal.csv").read_text().splitlines()
    assert rows[0] == "joint,type,theta_offset_deg,d_mm,a_mm,alpha_deg,beta_deg,lower,upper"
    d1 = float(rows[1].split(",")[3])
    assert d1 == pytest.approx(float(cal.table[0, 1]), abs=1e-12)
    # geometric-only model on the exported robot, zero deviations: evaluate gives the fit's rms
    assert main(["fit", str(d / "s.csv"), "--robot", str(d / "cal.json"), "--out", str(d / "m0.json")]) == 0
    obj = json.loads((d / "m0.json").read_text())
    for p in obj["parameters"]:
        p["value"] = 0.0
    (d / "m0.json").write_text(json.dumps(obj))
    capsys.readouterr()
    assert main(["evaluate", str(d / "s.csv"), "--model", str(d / "m0.json")]) == 0
    rms_cal = float(capsys.readouterr().out.split("rms ")[1].split()[0])
    assert main(["evaluate", str(d / "s.csv"), "--model", str(d / "m.json")]) == 0
    rms_fit = float(capsys.readouterr().out.split("rms ")[1].split()[0])
    assert rms_cal == pytest.approx(rms_fit, abs=1e-4)


def test_export_lists_effects_it_cannot_hold(tmp_path, capsys):
    assert main(["simulate", "--robot", "ur5e", "--effects", "joint_compliance:2", "--n", "40",
                 "--out", str(tmp_path / "s.csv")]) == 0
    assert main(["fit", str(tmp_path / "s.csv"), "--robot", "ur5e", "--effects", "joint_compliance:2",
                 "--out", str(tmp_path / "m.json")]) == 0
    capsys.readouterr()
    assert main(["export", str(tmp_path / "m.json"), "--robot-file", str(tmp_path / "r.json")]) == 0
    assert "joint_compliance:2" in capsys.readouterr().err
    obj = json.loads((tmp_path / "r.json").read_text())
    assert [e["spec"] for e in obj["effects"]] == ["joint_compliance:2"]
    assert load_robot_file(tmp_path / "r.json").n == 6


def test_model_is_self_contained_and_refuses_another_robot(tmp_path, capsys):
    rf = tmp_path / "arm.json"
    from torchcal.robots.robot_file import write_robot_file
    write_robot_file(rf, torchcal.robot("puma560"))
    assert main(["simulate", "--robot", str(rf), "--n", "30", "--out", str(tmp_path / "s.csv")]) == 0
    assert main(["fit", str(tmp_path / "s.csv"), "--robot", str(rf), "--out", str(tmp_path / "m.json")]) == 0
    rf.unlink()  # the model file needs no robot file
    capsys.readouterr()
    assert main(["evaluate", str(tmp_path / "s.csv"), "--model", str(tmp_path / "m.json")]) == 0
    assert main(["evaluate", str(tmp_path / "s.csv"), "--model", str(tmp_path / "m.json"), "--robot", "ur5e",
                 "--json", str(tmp_path / "e.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "'puma560'" in err and "'ur5e'" in err
    assert not (tmp_path / "e.json").exists()
    # data of a 7-joint robot
    (tmp_path / "d7.csv").write_text("pose,q1,q2,q3,q4,q5,q6,q7,x,y,z\n0,0,0,0,0,0,0,0,1,2,3\n")
    assert main(["evaluate", str(tmp_path / "d7.csv"), "--model", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err
    assert "found 7 joint columns" in err and "'puma560' with 6 joints" in err


def test_old_model_file_with_preset_name_loads(fitted):
    obj = json.loads((fitted / "m.json").read_text())
    del obj["nominal_robot"]
    old = fitted / "old.json"
    old.write_text(json.dumps(obj))
    fitted = modelfile.load(old)
    model, theta = fitted.model, fitted.theta
    assert model.robot == torchcal.robot("ur5e")
