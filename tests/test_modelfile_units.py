"""MODEL.json and the printed tables in degrees and mm (radians inside), format version 2;
files of version 1 (radians) still load."""

import json
import math

import pytest
import torch

import torchcal
from torchcal.cli import main
from torchcal.io import modelfile
from torchcal.io.measurement_csv import write_measurements
from torchcal.simulation.virtual_robot import VirtualRobot, random_poses

EFFECTS = ["base_frame", "joint_compliance:2"]


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    d = tmp_path_factory.mktemp("units")
    robot = torchcal.robot("ur5e")
    vr = VirtualRobot(robot, EFFECTS, seed=3)
    m = vr.measure(random_poses(robot, 60, 4), repeats=2, noise_mm=0.01)
    write_measurements(d / "d.csv", m)
    res = torchcal.fit(robot, d / "d.csv", effects=EFFECTS)
    return d, res


def _params(path) -> dict:
    return {p["name"]: p for p in json.loads(path.read_text())["parameters"]}


def test_model_file_in_degrees_round_trips_to_radians(fitted, tmp_path, capsys):
    d, res = fitted
    out = tmp_path / "m.json"
    assert main(["fit", str(d / "d.csv"), "--robot", "ur5e", "--effects", *EFFECTS, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    obj = json.loads(out.read_text())
    assert obj["format"] == "torchcal-model/2"
    p = _params(out)
    names, units = res.model.param_names(), res.model.param_units()
    theta = res.theta.tolist()
    seen = set()
    for n, u, v in zip(names, units, theta):  # the independent conversion, by hand
        want_unit, want = {"rad": ("deg", v * 180 / math.pi), "rad/mm": ("deg/mm", v * 180 / math.pi),
                           "rad/(kg mm)": ("deg/(N m)", v * 180 / math.pi / (9.80665 / 1000))}.get(u, (u, v))
        assert p[n]["unit"] == want_unit and p[n]["value"] == pytest.approx(want, rel=1e-9, abs=1e-15), n
        seen.add(want_unit)
    assert {"deg", "mm", "deg/mm", "deg/(N m)"} <= seen and "rad" not in json.dumps(obj["parameters"])
    assert p["base_rz"]["unit"] == "deg" and abs(p["base_rz"]["value"]) > 1e-3
    fitted = modelfile.load(out)
    model, back = fitted.model, fitted.theta
    torch.testing.assert_close(back, res.theta, rtol=1e-13, atol=1e-15)
    # the printed table: every angle in deg, every parameter with its unit
    rows = [ln.split() for ln in text.splitlines() if ln.startswith("  ") and "+-" in ln]
    assert rows and all(r[4] in ("mm", "deg", "deg/mm", "deg/(N", "1") for r in rows)
    assert any(r[0].startswith("dtheta") and r[4] == "deg" for r in rows)
    assert " rad" not in text and "rad/" not in text
    # evaluate on the loaded model: the fit's own RMS
    capsys.readouterr()
    assert main(["evaluate", str(d / "d.csv"), "--model", str(out)]) == 0
    assert f"rms {res.rms_mm:.4f} mm" in capsys.readouterr().out


def test_covariance_in_file_units_loads_back_in_radians(fitted, tmp_path, capsys):
    d, res = fitted
    out = tmp_path / "m.json"
    modelfile_obj = modelfile.to_dict(res)
    out.write_text(json.dumps(modelfile_obj))
    fitted = modelfile.load(out)
    model, _ = fitted.model, fitted.theta
    cov = modelfile.load_covariance(out, model)
    torch.testing.assert_close(cov, res.covariance.cov.to(cov), rtol=1e-10, atol=1e-30)
    c = modelfile_obj["covariance"]
    i = c["parameters"].index("dtheta2")
    assert c["units"][i] == "deg"
    assert math.sqrt(c["matrix"][i][i]) == pytest.approx(_std(modelfile_obj, "dtheta2"), rel=1e-12)


def _std(obj, name):
    return next(p["std"] for p in obj["parameters"] if p["name"] == name)


def test_version_1_file_in_radians_still_loads(fitted, tmp_path):
    d, res = fitted
    obj = modelfile.to_dict(res)
    units = res.model.param_units()
    k = modelfile.file_units(res.model)[1]
    obj["format"] = "torchcal-model/1"  # as written before degrees: values and covariance in radians
    for p, u, v, f in zip(obj["parameters"], units, res.theta.tolist(), k.tolist()):
        p["unit"], p["value"], p["std"] = u, v, p["std"] / f
    c = obj["covariance"]
    idx = [res.model.param_names().index(n) for n in c["parameters"]]
    c["matrix"] = [[c["matrix"][a][b] / (k[i] * k[j]).item() for b, j in enumerate(idx)] for a, i in enumerate(idx)]
    old = tmp_path / "old.json"
    old.write_text(json.dumps(obj))
    fitted = modelfile.load(old)
    model, theta = fitted.model, fitted.theta
    torch.testing.assert_close(theta, res.theta, rtol=0, atol=0)
    torch.testing.assert_close(modelfile.load_covariance(old, model), res.covariance.cov.to(theta), rtol=1e-10,
                               atol=1e-30)


def test_radians_under_a_degree_unit_are_caught(fitted, tmp_path):
    """A version-2 file whose unit says rad (a file written with the bug) is refused, not
    read as degrees."""
    d, res = fitted
    obj = modelfile.to_dict(res)
    for p, u, v in zip(obj["parameters"], res.model.param_units(), res.theta.tolist()):
        if u == "rad":
            p["unit"], p["value"] = "rad", v
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(obj))
    with pytest.raises(torchcal.InputError, match="unit"):
        modelfile.load(bad)


def test_compliance_units_are_those_of_their_formula():
    """A parameter's unit is the deflection (rad) over its regressor column's unit. Scaling
    every length of the robot by 2 leaves the link-moment columns (mx, my, mz: unit vectors)
    unchanged, so those parameters are angles ('rad', 'deg' in files), and doubles the
    lever columns (m: mm -> 'rad/mm') and the payload column (kg mm -> 'rad/(kg mm)',
    the compliance 'deg/(N m)' in files)."""
    import dataclasses

    from torchcal.effects import make_context
    from torchcal.effects.joint_compliance import JointCompliance, gravity_regressor

    robot = torchcal.robot("ur5e")
    big = dataclasses.replace(robot, table=robot.table * torch.tensor([1.0, 2, 2, 1, 1], dtype=torch.float64),
                              base=robot.base.clone(), tool=robot.tool.clone())
    big.base[:3, 3] *= 2
    big.tool[:3, 3] *= 2
    q = random_poses(robot, 20, 1)
    payload = torch.full((20,), 3.0, dtype=torch.float64)
    a = gravity_regressor(make_context(robot, q, payload), 2)
    b = gravity_regressor(make_context(big, q, payload), 2)
    units = JointCompliance(robot, [2]).param_units()
    for col, unit in enumerate(units):
        ratio = float(b[:, col].abs().sum() / a[:, col].abs().sum().clamp_min(1e-300))
        if float(a[:, col].abs().max()) < 1e-9:
            continue  # a column that is zero for this robot says nothing
        assert ratio == pytest.approx(1.0 if unit == "rad" else 2.0, rel=1e-9), (col, unit)
    assert [modelfile.file_unit(u)[0] for u in units[:5]] == ["deg", "deg", "deg", "deg/mm", "deg"]
    assert modelfile.file_unit(units[-1])[0] == "deg/(N m)"


def test_joint_stiffness_from_the_payload_term():
    from torchcal.effects.joint_compliance import JointCompliance

    robot = torchcal.robot("ur5e")
    n = robot.n
    stiff = torch.tensor([1e5, 2.5e5, 1.2e5, 3e4, 3e4, 1e4], dtype=torch.float64)
    p = JointCompliance.params_from_physics(robot, [2, 3], torch.ones(n), torch.zeros(n, 3), stiff)
    got = JointCompliance(robot, [2, 3]).stiffness_nm_per_rad(p)
    assert got == pytest.approx({2: 2.5e5, 3: 1.2e5}, rel=1e-12)


def test_old_compliance_labels_still_load(fitted, tmp_path):
    """Files that labelled the link-moment terms 'deg/mm' hold the same values in degrees."""
    d, res = fitted
    obj = modelfile.to_dict(res)
    for p in obj["parameters"]:
        if p["name"].endswith(("_mx", "_my", "_mz")):
            assert p["unit"] == "deg"
            p["unit"] = "deg/mm"
    (tmp_path / "old.json").write_text(json.dumps(obj))
    back = modelfile.load(tmp_path / "old.json")
    assert torch.allclose(back.theta, res.theta, rtol=1e-12, atol=0)


def test_fit_prints_the_joint_stiffness(tmp_path, capsys):
    """A simulated KR 1000 Titan with joint_compliance:2 (payload varied per pose): `fit`
    prints the stiffness K_2 in N m/rad of its payload term, near the simulated one."""
    from torchcal.effects.joint_compliance import JointCompliance
    from torchcal.robots.poses import random_poses as poses

    robot = torchcal.robot("kr1000titan")
    vr = VirtualRobot(robot, ["joint_compliance:2"], seed=1)
    write_measurements(tmp_path / "d.csv", vr.measure(poses(robot, 200, torch.Generator().manual_seed(2)),
                                                      noise_mm=0.01))
    truth = JointCompliance(robot, [2]).stiffness_nm_per_rad(vr.theta[vr.model.slices[1]])[2]
    assert main(["fit", str(tmp_path / "d.csv"), "--robot", "kr1000titan", "--effects", "joint_compliance:2",
                 "--out", str(tmp_path / "m.json")]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("joint stiffness"))
    k = float(line.split("joint 2 ", 1)[1].split(" N m/rad")[0])
    assert k == pytest.approx(truth, rel=0.05)
