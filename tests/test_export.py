"""`torchcal export`: the calibrated geometry of a fitted model as a robot file, URDF, table;
models are self-contained and refuse another robot's data."""

import json
import xml.etree.ElementTree as ET

import pytest
import torch

import torchcal
from torchcal.cli import main
from torchcal.effects import make_context
from torchcal.io import modelfile
from torchcal.io.measurement_csv import read_measurements
from torchcal.io.robot_file import load_robot_file
from torchcal.calibration.geometry_only import calibrated_robot
from torchcal.io.urdf import _origin, robot_from_urdf


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
    # the URDF keeps the robot's base and tool0; re-imported it gives the calibrated geometry, and
    # with its separate frames (tracker on base_link, reflector on tool0) the model's predictions
    own = calibrated_robot(model, theta, fold=False)[0]
    back = robot_from_urdf(d / "cal.urdf", "base_link", "tool0")
    assert (back.fk_pose(m.q) - own.fk_pose(m.q))[:, :3, 3].norm(dim=-1).max() < 1e-6
    assert (back.fk_pose(m.q) - own.fk_pose(m.q))[:, :3, :3].abs().max() < 1e-9
    assert (back.fk(m.q) - pred).norm(dim=-1).max() > 0.1  # the measuring frame is not folded in
    refl = robot_from_urdf(d / "cal.urdf", "base_link", "reflector")
    tracker = [j for j in ET.parse(d / "cal.urdf").getroot().findall("joint") if j.get("name") == "tracker_joint"]
    T = torch.linalg.inv(_origin(tracker[0].find("origin"), "tracker"))  # measuring <- base
    assert (refl.fk(m.q) @ T[:3, :3].T + T[:3, 3] - pred).norm(dim=-1).max() < 1e-6
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
    from torchcal.io.robot_file import write_robot_file
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


def test_export_never_replaces_what_the_model_came_from(tmp_path, capsys):
    from torchcal.io.urdf import minimal_urdf

    src = tmp_path / "arm.urdf"
    src.write_text(minimal_urdf(torchcal.robot("ur5e")))
    assert main(["robot", "import", str(src), "--base", "base_link", "--tip", "tool0",
                 "--out", str(tmp_path / "arm.json")]) == 0
    assert main(["simulate", "--robot", str(tmp_path / "arm.json"), "--effects", "base_frame", "--n", "40",
                 "--seed", "4", "--out", str(tmp_path / "s.csv")]) == 0
    assert main(["fit", str(tmp_path / "s.csv"), "--robot", str(tmp_path / "arm.json"), "--effects", "base_frame",
                 "--out", str(tmp_path / "m.json")]) == 0
    before = {p: p.read_bytes() for p in (src, tmp_path / "s.csv")}
    for opt, path in (("--urdf", src), ("--table", tmp_path / "s.csv")):  # the source URDF, the model's data
        capsys.readouterr()
        assert main(["export", str(tmp_path / "m.json"), opt, str(path), "--force"]) == 2
        err = capsys.readouterr().err
        assert f"{path}: refusing to write over the input file" in err and len(err.splitlines()) == 1
    assert all(p.read_bytes() == b for p, b in before.items())


def test_unwritable_output_is_found_before_the_work_with_the_users_path(fitted, capsys):
    capsys.readouterr()
    out = "/proc/torchcal_cal.urdf"  # no file can be created there, whoever runs the test
    assert main(["export", str(fitted / "m.json"), "--urdf", out, "--data", str(fitted / "s.csv")]) == 2
    cap = capsys.readouterr()
    assert cap.out == "" and len(cap.err.splitlines()) == 1  # nothing ran: no refit line
    assert f"{out}: cannot write in folder /proc" in cap.err and ".tmp" not in cap.err and "Errno" not in cap.err


def test_export_never_writes_over_the_nominal_robot_file(fitted, tmp_path, capsys):
    """--robot-file naming the robot file the model was fitted with (a model does not record
    its path) is refused, --force or not, in one line, the file left as it was (it was
    replaced by the calibrated robot: the UR10 example's ur10.json); a file of a former
    export is still replaced with --force."""
    from torchcal.io.robot_file import robot_to_dict

    nominal = tmp_path / "ur5e.json"
    nominal.write_text(json.dumps(robot_to_dict(torchcal.robot("ur5e")), indent=1))
    before = nominal.read_bytes()
    capsys.readouterr()
    assert main(["export", str(fitted / "m.json"), "--robot-file", str(nominal), "--force"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and f"{nominal}: holds the nominal ur5e, the robot the model was fitted with" in err
    assert nominal.read_bytes() == before
    former = tmp_path / "cal.json"
    assert main(["export", str(fitted / "m.json"), "--robot-file", str(former)]) == 0
    assert main(["export", str(fitted / "m.json"), "--robot-file", str(former), "--force"]) == 0


def test_an_interrupted_export_leaves_none_of_its_new_files(fitted, tmp_path, monkeypatch):
    """Ctrl-C while the URDF is written after the robot file: the robot file used to stay
    behind alone; now neither is left."""
    import torchcal.io.files as files

    model = fitted / "m.json"

    real, calls = files.atomic_write, []

    def interrupted(path, *a, **kw):  # the robot file is written, then Ctrl-C at the URDF
        calls.append(path)
        if str(path).endswith(".urdf"):
            raise KeyboardInterrupt
        return real(path, *a, **kw)

    monkeypatch.setattr(files, "atomic_write", interrupted)
    with pytest.raises(KeyboardInterrupt):
        torchcal.api.export(model, robot_file=tmp_path / "cal.json", urdf=tmp_path / "cal.urdf")
    assert len(calls) == 2 and not (tmp_path / "cal.json").exists() and not (tmp_path / "cal.urdf").exists()


def test_table_says_that_base_and_tool_are_not_in_it(fitted, capsys):
    """The MD-H table holds the joint rows only. Of a model with a measuring frame and a
    tool offset its rows alone (plain-numpy MD-H chain, read from the CSV) miss the model
    (by 1.1 mm here, by metres on the UR10 of examples/ur10, its tracker 3.6 m away); with the base and tool of the exported robot file they reproduce it: export
    says so when it writes a table without them (it wrote only 'wrote PATH')."""
    import csv

    import numpy as np
    from npsim import _rx, _ry, _rz, _tr

    d = fitted
    capsys.readouterr()
    assert main(["export", str(d / "m.json"), "--table", str(d / "t.csv"), "--robot-file", str(d / "t.json"),
                 "--force"]) == 0
    out = capsys.readouterr().out
    fm = modelfile.load(d / "m.json")
    m = read_measurements(d / "s.csv", robot=fm.model.robot)
    pred = fm.model.predict(fm.theta, make_context(fm.model.robot, m.q, m.payload_kg, m.temp_c)).numpy()
    rows = list(csv.DictReader(open(d / "t.csv")))
    obj = json.loads((d / "t.json").read_text())

    def fk(base, tool):
        out = []
        for qq in np.degrees(m.q.numpy()):
            T = np.array(base, dtype=float)
            for r, qj in zip(rows, qq):
                T = T @ _rz(np.radians(float(r["theta_offset_deg"]) + qj)) @ _tr(0.0, float(r["d_mm"])) @ \
                    _tr(float(r["a_mm"]), 0.0) @ _rx(np.radians(float(r["alpha_deg"]))) @ _ry(np.radians(float(r["beta_deg"])))
            out.append((T @ np.array(tool, dtype=float))[:3, 3])
        return np.array(out)
    assert np.linalg.norm(fk(obj["base"], obj["tool"]) - pred, axis=1).max() < 1e-6
    assert np.linalg.norm(fk(np.eye(4), np.eye(4)) - pred, axis=1).max() > 0.3  # 1.1 mm here, metres on the UR10
    line = next(ln for ln in out.splitlines() if ln.startswith(f"{d / 't.csv'}:"))
    assert "not in it" in line and "base" in line and "tool" in line and "--robot-file" in line


def test_export_of_a_model_with_several_reflectors(tmp_path, capsys):
    """Two reflectors on the flange (the `point` column, one tool offset each), measured
    on a plain-numpy ur5e: export wrote nothing and ended in a RuntimeError traceback. Now
    the robot file keeps the nominal tool and lists each reflector's offset (flange frame)
    under "effects", the URDF has a frame per reflector, and one line says so; each
    offset on the robot file's chain (FK here in numpy from the JSON) and each URDF frame
    reach the true reflectors to the fit's accuracy."""
    import numpy as np
    from npsim import numpy_fk, reflectors_session
    from torchcal.robots.poses import random_poses

    rob = torchcal.robot("ur5e")
    pts = {1: [30.0, 0.0, 100.0], 2: [-20.0, 40.0, 80.0]}
    dev, q, _ = reflectors_session(tmp_path / "s.csv", rob, 60, pts)
    truth = {}
    for pid, off in pts.items():
        T = np.eye(4)
        T[:3, 3] = off
        truth[pid] = lambda qq, T=T: numpy_fk(rob, qq, dev, tool=T)
    assert main(["fit", str(tmp_path / "s.csv"), "--robot", "ur5e", "--effects", "tool_offset",
                 "--out", str(tmp_path / "m.json")]) == 0
    capsys.readouterr()
    assert main(["export", str(tmp_path / "m.json"), "--robot-file", str(tmp_path / "r.json"),
                 "--urdf", str(tmp_path / "r.urdf")]) == 0
    out = capsys.readouterr().out
    assert "2 reflectors" in out and "nominal tool" in out
    obj = json.loads((tmp_path / "r.json").read_text())
    listed = next(e for e in obj["effects"] if e["spec"] == "tool_offset")["parameters"]
    qv = random_poses(rob, 100, 8).numpy()
    for pid in pts:
        off = np.array([listed[f"tool_{c}@{pid}"]["value"] for c in "xyz"])
        tool = np.array(obj["tool"])
        tool[:3, 3] += off
        from npsim import _rx, _ry, _rz, _tr
        P = []
        for qq in qv:
            T = np.array(obj["base"])
            for j, qj in zip(obj["joints"], qq):
                T = T @ _rz(np.radians(j["theta_offset_deg"]) + qj) @ _tr(0.0, j["d_mm"]) @ _tr(j["a_mm"], 0.0) @ \
                    _rx(np.radians(j["alpha_deg"])) @ _ry(np.radians(j.get("beta_deg", 0.0)))
            P.append((T @ tool)[:3, 3])
        assert np.linalg.norm(np.array(P) - truth[pid](qv), axis=1).max() < 0.1
        back = robot_from_urdf(tmp_path / "r.urdf", "base_link", f"reflector_{pid}")
        assert np.linalg.norm(back.fk(torch.from_numpy(qv)).numpy() - truth[pid](qv), axis=1).max() < 0.1


def test_exported_robot_file_keeps_gravity_where_it_is(tmp_path):
    """A wall-mounted ur5e (robot file gravity [1, 0, 0] in its base frame) measured in a
    levelled tracker frame: export folds the measuring frame into the robot file's base, so
    the file's gravity must turn with it. Gravity torques on the joints (tests/npsim.py, a
    plain-numpy sum of moments) of the exported robot file must equal the real robot's;
    the file kept [1, 0, 0], now read in the tracker frame: joint 2's torque then differs
    by about its own size, and a compliance refit on that file would be wrong."""
    import dataclasses

    import numpy as np
    from npsim import gravity_torques
    from torchcal.robots.poses import random_poses

    ur = torchcal.robot("ur5e")
    wall = dataclasses.replace(ur, gravity=torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64), name="ur5e_wall")
    R = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])  # tracker <- robot base: its x is down
    q = random_poses(wall, 60, 4).numpy()
    from npsim import numpy_fk
    xyz = numpy_fk(wall, q, np.zeros((6, 5))) @ R.T + [1500.0, 200.0, 900.0]
    with open(tmp_path / "s.csv", "w") as fh:
        fh.write("pose," + ",".join(f"q{k}" for k in range(1, 7)) + ",x,y,z\n")
        for i, (qq, p) in enumerate(zip(np.degrees(q), xyz)):
            fh.write(",".join(map(repr, [i + 1, *qq.tolist(), *p.tolist()])) + "\n")
    from torchcal.io.robot_file import write_robot_file
    write_robot_file(tmp_path / "wall.json", wall)
    assert main(["fit", str(tmp_path / "s.csv"), "--robot", str(tmp_path / "wall.json"), "--effects", "base_frame",
                 "--out", str(tmp_path / "m.json")]) == 0
    assert main(["export", str(tmp_path / "m.json"), "--robot-file", str(tmp_path / "cal.json")]) == 0
    cal = load_robot_file(tmp_path / "cal.json")
    masses, centres = np.full(6, 3.0), np.tile([0.0, 0.0, 50.0], (6, 1))
    tau_real = gravity_torques(wall, q[:20], np.zeros((6, 5)), masses, centres, np.zeros(20))
    tau_file = gravity_torques(cal, q[:20], np.zeros((6, 5)), masses, centres, np.zeros(20))  # its table is calibrated
    assert np.abs(tau_file - tau_real).max() < 1e-3 * np.abs(tau_real).max(), np.abs(tau_file - tau_real).max()


def test_parameters_beyond_their_plausible_size_are_named_on_export(fitted, tmp_path, capsys):
    """A MODEL.json whose dtheta2 reads 20 deg and dd3 250 mm (edited by hand; within what
    the reader refuses as corrupt) was exported into a robot file in silence; now one
    warning names both with their plausible sizes, and the file is still written (the
    geometry it holds is checked against the model's: dd3 is there). The fitted model as
    written exports without a word."""
    obj = json.loads((fitted / "m.json").read_text())
    for p in obj["parameters"]:
        if p["name"] in ("dtheta2", "dd3"):
            p["value"] = {"dtheta2": 20.0, "dd3": 250.0}[p["name"]]
    (tmp_path / "bad.json").write_text(json.dumps(obj))
    capsys.readouterr()
    assert main(["export", str(tmp_path / "bad.json"), "--robot-file", str(tmp_path / "r.json")]) == 0
    err = capsys.readouterr().err
    assert err == (f"torchcal: warning: {tmp_path / 'bad.json'}: exported parameters beyond their plausible size: "
                   "dtheta2 +20 deg (plausible 1 deg), dd3 +250 mm (plausible 5 mm); the exported robot carries them "
                   "(a value edited by hand, or a fit that absorbed something else: check before a controller "
                   "uses it)\n")
    nominal, cal = torchcal.robot("ur5e"), load_robot_file(tmp_path / "r.json")
    assert float(cal.table[2, 1] - nominal.table[2, 1]) == pytest.approx(250.0)
    assert main(["export", str(fitted / "m.json"), "--robot-file", str(tmp_path / "ok.json")]) == 0
    assert capsys.readouterr().err == ""


def test_export_data_without_a_payload_for_a_model_fitted_on_loads_is_named(tmp_path, capsys):
    """`export --data` of a joint-compliance model fitted on loads (plain-numpy gravity sag,
    tests/npsim.py): data without payload_kg get one line (its full-model figure is of an
    unloaded arm), data with it none."""
    from npsim import physics_session
    from torchcal.io.measurement_csv import write_measurements
    from torchcal.measurements import Measurements
    from torchcal.robots.poses import random_poses

    rob = torchcal.robot("ur5e")
    q = random_poses(rob, 60, 7)
    xyz, load = physics_session(rob, q.numpy(), seed=7, hidden=["joint_compliance:2"])
    m = Measurements(torch.arange(60), q, torch.from_numpy(xyz), payload_kg=torch.from_numpy(load))
    write_measurements(tmp_path / "loaded.csv", m)
    write_measurements(tmp_path / "bare.csv", Measurements(m.pose, m.q, m.xyz))
    assert main(["fit", str(tmp_path / "loaded.csv"), "--robot", "ur5e", "--effects", "joint_compliance:2",
                 "--out", str(tmp_path / "m.json")]) == 0
    for data, lines in (("loaded", 0), ("bare", 1)):
        capsys.readouterr()
        assert main(["export", str(tmp_path / "m.json"), "--data", str(tmp_path / f"{data}.csv"),
                     "--robot-file", str(tmp_path / f"{data}.json")]) == 0
        err = capsys.readouterr().err
        assert err.count("no payload_kg column: evaluated at 0 kg") == lines and "outside the fitted" not in err, err
