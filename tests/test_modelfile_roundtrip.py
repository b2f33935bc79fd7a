"""One fitted-model type: a fit in memory and the same fit read back from its MODEL.json
(`torchcal.load`) agree field by field, and evaluate / compensate give the same answers
from either. Real UR10 rows with orientations, a robust fit with non-default
uncertainties and a residual stage, so that every optional field is filled."""

import dataclasses
import json
import math
from pathlib import Path

import pytest
import torch

import torchcal
from torchcal.io import modelfile
from torchcal.calibration.fit import FitResult, Identifiability
from torchcal.calibration.model import CalibrationModel
from torchcal.io.measurement_csv import read_measurements

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "ur10"
NOT_IN_FILE = {"residuals", "weights"}  # per-row arrays: None after load


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    robot = torchcal.robot(str(EXAMPLES / "ur10.json"))
    m = read_measurements(EXAMPLES / "series_d.csv", robot=robot)
    train, test = m.subset(slice(0, 120)), m.subset(slice(120, 180))
    res = torchcal.fit(robot, train, ["base_frame", "tool_offset"], robust="huber", sigma_mm=0.02, sigma_deg=0.05,
                       residual_model="kernel")
    path = tmp_path_factory.mktemp("fitted") / "m.json"
    torchcal.save(res, path, seed=7)
    return res, torchcal.load(path), path, test


def same(a, b, where):
    """a == b, tensors to rounding (the file writes full-precision floats, degrees)."""
    if isinstance(a, torch.Tensor):
        assert isinstance(b, torch.Tensor) and a.shape == b.shape, where
        assert torch.allclose(a.double().cpu(), b.double().cpu(), rtol=1e-9, atol=1e-12), where
    elif isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), (where, set(a) ^ set(b))
        for k in a:
            same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            same(x, y, f"{where}[{i}]")
    elif isinstance(a, float):
        assert isinstance(b, (int, float)) and b == pytest.approx(a, rel=1e-9, abs=1e-12), (where, a, b)
    elif dataclasses.is_dataclass(a) and not isinstance(a, type):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    else:
        assert a == b, (where, a, b)


def test_every_field_is_filled_by_this_fit(session):
    res, _, _, _ = session
    for f in dataclasses.fields(FitResult):
        if f.name != "provenance":  # written by to_dict from its arguments
            assert getattr(res, f.name) is not None, f.name
    assert res.robust == "huber" and res.sigma_mm == 0.02 and res.sigma_deg == 0.05
    assert res.orientation["sigma_deg"] == 0.05 and res.tool_rotation.shape == (3, 3)


def test_in_memory_and_loaded_agree_field_by_field(session):
    res, back, _, _ = session
    assert isinstance(back, FitResult)
    for f in dataclasses.fields(FitResult):
        a, b = getattr(res, f.name), getattr(back, f.name)
        if f.name in NOT_IN_FILE:
            assert b is None, f.name
        elif f.name == "model":
            assert b.specs() == a.specs() and b.param_names() == a.param_names() and b.points == a.points
            assert b.robot.name == a.robot.name and torch.allclose(b.robot.table, a.robot.table.cpu())
        elif f.name == "provenance":
            assert a is None and b["seed"] == 7 and b["torchcal_version"] == torchcal.__version__
        elif f.name == "residual_model":
            same(a.to_dict(), b.to_dict(), f.name)
        elif f.name == "report":
            assert isinstance(b, Identifiability)
            same(a, b, f.name)
        else:
            same(a, b, f.name)
    assert back.rms_mm == pytest.approx(res.rms_mm, rel=1e-12) and back.training_rms_mm == res.training_rms_mm


def test_loaded_model_writes_the_same_file(session):
    _, back, path, _ = session
    same(json.loads(path.read_text()), modelfile.to_dict(back), "MODEL.json")


@pytest.mark.parametrize("source", ["loaded", "path"])
def test_evaluate_and_compensate_agree_from_memory_and_from_the_file(session, source):
    res, back, path, test = session
    other = back if source == "loaded" else path
    ref = torchcal.evaluate(res, test)
    assert ref.orientation_rms_deg is not None and ref.outside_range is not None
    ev = torchcal.evaluate(other, test)
    same(ref.to_dict(), ev.to_dict(), "evaluate")
    same(ref.residuals_mm, ev.residuals_mm, "residuals")
    same(ref.orientation_deg, ev.orientation_deg, "orientation rows")
    # the orientation error by hand: model rotation times the fitted tool rotation vs measured
    from torchcal.effects import context_of
    from torchcal.rotations import so3_error
    R = back.model.predict_rotation(back.theta, context_of(back.model.robot, test)) @ back.tool_rotation
    by_hand = math.degrees(float(so3_error(R, test.rotation).norm(dim=-1).pow(2).mean().sqrt()))
    assert ref.orientation_rms_deg == pytest.approx(by_hand, rel=1e-9)
    targets = test.xyz[:10]
    a = torchcal.compensate(res, targets, q0=test.q[:10])
    b = torchcal.compensate(other, targets, q0=test.q[:10])
    assert bool(a.converged.all())
    same(a.q, b.q, "compensate q")
    same(a.residual_mm, b.residual_mm, "compensate residual")


def test_evaluate_on_the_fitted_rows_gives_the_fits_orientation_rms(session):
    res, back, _, _ = session
    robot = res.model.robot
    train = read_measurements(EXAMPLES / "series_d.csv", robot=robot).subset(slice(0, 120))
    for fitted in (res, back):
        assert torchcal.evaluate(fitted, train).orientation_rms_deg == pytest.approx(res.orientation["rms_deg"],
                                                                                     rel=1e-9)


def test_register_keeps_the_fitted_models_fields(session):
    res, back, _, test = session
    reg = torchcal.register(back, test)
    for name in ("orientation", "robust", "sigma_mm", "sigma_deg", "training", "q_range", "provenance"):
        same(getattr(back, name), getattr(reg, name), name)
    assert reg.residual_model is back.residual_model
    assert reg.rms_mm != reg.training_rms_mm  # rms on the new rows; the training rms kept


def test_a_calibration_model_holds_no_fitted_state(session):
    """Loading sets no attribute on the CalibrationModel beyond those of its class."""
    res, back, _, _ = session
    fresh = CalibrationModel(back.model.robot, back.model.specs())
    assert set(vars(back.model)) == set(vars(fresh)) == set(vars(res.model))
    for attr in ("tool_rotation", "calibrated_range", "training_rms_mm", "residual_model"):
        assert not hasattr(back.model, attr), attr


def test_evaluate_command_reports_what_the_fit_in_memory_gives(session, tmp_path):
    """`torchcal evaluate --json` on the MODEL.json = `torchcal.evaluate` of the fit in
    memory, orientation included."""
    from torchcal.cli import main

    res, _, path, _ = session
    lines = (EXAMPLES / "series_d.csv").read_text().splitlines()
    data = tmp_path / "test.csv"
    data.write_text("\n".join([lines[0], *lines[121:181]]) + "\n")  # held-out rows
    out = tmp_path / "ev.json"
    assert main(["evaluate", str(data), "--model", str(path), "--json", str(out)]) == 0
    with pytest.warns(Warning):  # rows outside the calibrated range
        ref = torchcal.evaluate(res, data).to_dict()
    got = json.loads(out.read_text())
    assert "orientation_rms_deg" in got
    same(ref, got, "evaluate --json")
