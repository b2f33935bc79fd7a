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
