"""One question, one answer: the library and the command line agree, and every way into a
fitted model reports the same facts.

References: `Robot.fk_pose` (and the fact that a slide never turns the tool) for the
prismatic orientation; the robot file's limits for the sampled slide positions; the
MODEL.json of the same fit for evaluate; the command line's own output files and error
lines, field by field, for fit (settings, unit refusal) and compensate.
"""

import csv
import json
import math
from pathlib import Path

import pytest
import torch
from torch.testing import assert_close

import torchcal
from torchcal.calibration.model import CalibrationModel
from torchcal.cli import main
from torchcal.effects import make_context
from torchcal.io.measurement_csv import write_measurements
from torchcal.measurements import Measurements
from torchcal.rotations import matrix_to_fixed_xyz
from torchcal.robots.poses import random_poses
from torchcal.io.robot_file import robot_from_dict
from torchcal.io import modelfile

SCARA = robot_from_dict(json.loads((Path(__file__).resolve().parents[1] / "examples" / "scara.json").read_text()))


def test_predict_rotation_of_a_prismatic_robot_is_the_robots_orientation():
    q = torch.tensor([[0.3, -0.5, 150.0, 0.7], [-1.0, 0.4, 0.0, 2.0], [0.3, -0.5, 0.0, 0.7]], dtype=torch.float64)
    model = CalibrationModel(SCARA)
    ctx = make_context(SCARA, q)
    R = model.predict_rotation(model.zeros(), ctx)
    T = SCARA.fk_pose(q)
    assert_close(R, T[:, :3, :3], rtol=0, atol=1e-12)
    assert_close(model.predict(model.zeros(), ctx), T[:, :3, 3], rtol=0, atol=1e-9)
    assert_close(R[0], R[2], rtol=0, atol=1e-12)  # the slide (q3 150 mm vs 0) never turns the tool


def test_random_poses_span_a_slides_own_limits():
    q = random_poses(SCARA, 400, 3, min_z_mm=None)
    lo, hi = 0.0 + 0.1 * 200.0, 200.0 - 0.1 * 200.0  # mm, the limits shrunk by the margin
    assert q.device == SCARA.device
    assert float(q[:, 2].min()) >= lo and float(q[:, 2].max()) <= hi
    assert float(q[:, 2].min()) < lo + 10 and float(q[:, 2].max()) > hi - 10  # uniform over 20..180 mm
    rev = q[:, [0, 1, 3]]
    assert float(rev.abs().max()) <= math.pi  # revolute joints stay inside +-180 deg


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_random_poses_draw_on_the_robots_device():
    robot = SCARA.to("cuda")
    q = random_poses(robot, 50, 3)
    assert q.device == robot.device and float(q[:, 2].max()) > 100.0  # a slide in mm, not rad
    g = torch.Generator().manual_seed(3)  # a CPU generator: its draws are moved
    assert random_poses(robot, 5, g).device == robot.device


def _with_orientation(robot, theta, q, model):
    ctx = make_context(robot, q)
    R = model.predict_rotation(theta, ctx)
    return Measurements(torch.arange(q.shape[0]), q, model.predict(theta, ctx), rxyz=matrix_to_fixed_xyz(R))


def test_evaluate_reports_orientation_for_a_fit_and_its_file(kr, tmp_path):
    model = CalibrationModel(kr)
    theta = model.zeros()
    theta[[1, 7, 13]] = torch.tensor([0.4, -0.3, 0.002], dtype=torch.float64)
    m = _with_orientation(kr, theta, random_poses(kr, 40, 5), model)
    test = _with_orientation(kr, theta, random_poses(kr, 20, 6), model)
    res = torchcal.fit(kr, m)
    assert res.orientation is not None
    path = tmp_path / "model.json"
    torchcal.save(res, path)
    in_memory, from_file = torchcal.evaluate(res, test), torchcal.evaluate(str(path), test)
    assert in_memory.orientation_rms_deg is not None
    assert in_memory.to_dict().keys() == from_file.to_dict().keys()
    assert in_memory.orientation_rms_deg == pytest.approx(from_file.orientation_rms_deg, abs=1e-9)
    # on the fitted rows, evaluate gives the fit's own orientation rms
    assert torchcal.evaluate(res, m).orientation_rms_deg == pytest.approx(res.orientation["rms_deg"], rel=1e-9)


def _csv(tmp_path, robot, n, seed, scale=1.0, name="m.csv"):
    q = random_poses(robot, n, seed)
    model = CalibrationModel(robot)
    theta = model.zeros()
    theta[[1, 7, 12]] = torch.tensor([0.4, -0.3, 0.2], dtype=torch.float64)
    xyz = model.predict(theta, make_context(robot, q))
    g = torch.Generator().manual_seed(seed + 1)
    xyz = xyz + 0.02 * torch.randn(xyz.shape, generator=g, dtype=torch.float64)
    xyz[3] += 5.0  # one gross outlier for the robust fit
    path = tmp_path / name
    write_measurements(path, Measurements(torch.arange(n), q, xyz * scale))
    return path


def test_fit_records_its_settings_and_the_cli_writes_the_api_model(kr, tmp_path):
    data = _csv(tmp_path, kr, 40, 11)
    res = torchcal.fit("kr1000titan", data, robust="huber", sigma_mm=0.02, sigma_deg=0.03)
    assert (res.robust, res.sigma_mm, res.sigma_deg) == ("huber", 0.02, 0.03)
    api = json.loads(json.dumps(modelfile.to_dict(res, source=data)))
    assert api["fit"]["robust"] == "huber" and api["fit"]["sigma_mm"] == 0.02
    out = tmp_path / "model.json"
    assert main(["fit", str(data), "--robot", "kr1000titan", "--robust", "huber", "--sigma-mm", "0.02",
                 "--sigma-deg", "0.03", "--out", str(out)]) == 0
    cli = json.loads(out.read_text())
    api["provenance"]["input"] = cli["provenance"]["input"]
    assert cli.keys() == api.keys()
    for key in cli:
        assert cli[key] == api[key], key


def test_fit_refuses_metres_with_the_cli_line(kr, tmp_path, capsys):
    data = _csv(tmp_path, kr, 30, 21, scale=1e-3)  # metres written in an mm file
    for limits in ({}, {"max_length_mm": None, "max_angle_deg": None}):
        with pytest.raises(torchcal.InputError) as exc:
            torchcal.fit("kr1000titan", data, **limits)
        assert "look like metres read as mm" in str(exc.value)
    capsys.readouterr()
    out = tmp_path / "model.json"
    assert main(["fit", str(data), "--robot", "kr1000titan", "--out", str(out)]) == 2
    # the same finding and the same fix, each in its own words: a keyword for the library, the option for the CLI
    assert exc.value.fix == ("length_unit", "m") and str(exc.value).endswith("; pass length_unit='m'")
    assert "--" not in str(exc.value)
    assert capsys.readouterr().err == f"torchcal fit: error: {exc.value.message}; pass --length-unit m\n"
    assert not out.exists()
    # read in the right unit, both accept it and agree
    res = torchcal.fit("kr1000titan", data, length_unit="m")
    assert main(["fit", str(data), "--robot", "kr1000titan", "--length-unit", "m", "--out", str(out)]) == 0
    cli = json.loads(out.read_text())
    from torchcal.io.modelfile import file_units
    _, k = file_units(res.model)  # the file's units (deg, mm) per parameter
    assert [p["value"] for p in cli["parameters"]] == pytest.approx((res.theta * k).tolist(), abs=1e-10)


def _targets(tmp_path, rows, name="targets.csv"):
    path = tmp_path / name
    path.write_text("x,y,z\n" + "".join(",".join(repr(float(v)) for v in r) + "\n" for r in rows))
    return path


def test_compensate_cli_and_api_give_the_same_commands(kr, tmp_path, capsys):
    data = _csv(tmp_path, kr, 40, 31)
    model = tmp_path / "model.json"
    assert main(["fit", str(data), "--robot", "kr1000titan", "--out", str(model)]) == 0
    t = kr.fk(random_poses(kr, 60, 32))
    targets = _targets(tmp_path, t.tolist())
    out = tmp_path / "q.csv"
    code = main(["compensate", str(targets), "--model", str(model), "--out", str(out)])
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    comp = torchcal.compensate(str(model), t)
    q_deg = torch.tensor([[float(r[f"q{k}"]) for k in range(1, 7)] for r in rows], dtype=torch.float64)
    assert_close(q_deg, kr.q_to_user(comp.q), rtol=0, atol=1e-9)
    assert [r["converged"] == "true" for r in rows] == comp.converged.tolist()
    assert [r["within_limits"] == "true" for r in rows] == comp.within_limits.tolist()
    assert code == (0 if bool((comp.converged & comp.within_limits).all()) else 1)
    res = torch.tensor([float(r["residual_mm"]) for r in rows], dtype=torch.float64)
    assert_close(res, comp.residual_mm.norm(dim=-1), rtol=0, atol=1e-12)
    # a target out of reach: the same answer from both, the others still solved
    far = _targets(tmp_path, [*t[:2].tolist(), [1e5, 0.0, 0.0]], "far.csv")
    comp = torchcal.compensate(str(model), torch.tensor([*t[:2].tolist(), [1e5, 0.0, 0.0]], dtype=torch.float64))
    assert comp.converged.tolist() == [True, True, False]
    capsys.readouterr()
    assert main(["compensate", str(far), "--model", str(model), "--out", str(tmp_path / "q2.csv")]) == 1
    assert "not converged: target(s) 3" in capsys.readouterr().err
    with open(tmp_path / "q2.csv", newline="") as fh:
        assert [r["converged"] == "true" for r in csv.DictReader(fh)] == comp.converged.tolist()


def test_residuals_are_measured_minus_model(kr):
    """The sign every consumer relies on (viz draws measured - residual as the model; the
    direction tests of unexplained read it): FitResult.residuals = measured - model, checked
    against the model's prediction computed here, on noisy data so the sign shows."""
    model = CalibrationModel(kr, ["base_frame"])
    q = random_poses(kr, 40, 41)
    g = torch.Generator().manual_seed(42)
    xyz = model.predict(model.zeros(), make_context(kr, q))
    xyz = xyz + 0.05 * torch.randn(xyz.shape, generator=g, dtype=torch.float64)
    for robust in (None, "huber"):
        res = torchcal.fit(model, Measurements(torch.arange(40), q, xyz), robust=robust)
        expected = xyz - res.model.predict(res.theta, make_context(kr, q))
        assert float(expected.abs().max()) > 0.02  # the noise is there
        assert_close(res.residuals, expected, rtol=0, atol=1e-9)
