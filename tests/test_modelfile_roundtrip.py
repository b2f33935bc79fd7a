"""One fitted-model type: a fit in memory and the same fit read back from its MODEL.json
(`torchcal.load`) agree field by field, and evaluate / compensate give the same answers
from either. Real UR10 rows with orientations, a robust fit with non-default
uncertainties and a residual stage, so that every optional field is filled.

The interval calibration of ``calibrate`` is the same type: its global fit a `FitResult`
with intervals, per zone a `ZonedFit`; both go through `torchcal.save` / `torchcal.load`
with equal predictions, and a file of the older interval-model format (written by the
earlier writer, tests/data) still loads and predicts what it predicted then."""

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
        # provenance: written by to_dict from its arguments; radius: calibrate's intervals; conditions:
        # only with an effect that reads temp_c / payload_kg (its round trip: tests/test_joint_range_conditions.py)
        if f.name not in ("provenance", "radius", "conditions"):
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


# ----------------------------------------------------------------------------- interval calibration
DATA = Path(__file__).resolve().parent / "data"


@pytest.fixture(scope="module")
def zoned(tmp_path_factory):
    """`torchcal.calibrate` of a simulated UR5e (3 repeats per pose) globally and per zone of a
    3-zone partition, each saved and loaded back."""
    from torchcal.partition.zones import partition_workspace
    from torchcal.robots.poses import random_poses
    from torchcal.robots.workspace import sample_workspace
    from torchcal.simulation.virtual_robot import VirtualRobot

    rob = torchcal.robot("ur5e")
    m = VirtualRobot(rob, ["base_frame"], seed=6).measure(random_poses(rob, 36, 6), repeats=3, seed=7)
    pos = rob.fk(sample_workspace(rob, 40, seed=1))
    r = torch.rand(40, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    part = partition_workspace(pos, r, levels=2, zones=[2, 1], seed=0)
    d = tmp_path_factory.mktemp("zoned")
    out = {}
    for name, p in (("global", None), ("zones", part)):
        res = torchcal.calibrate(rob, m, ["base_frame"], partition=p)
        torchcal.save(res, d / f"{name}.json")
        out[name] = (res, torchcal.load(d / f"{name}.json"), d / f"{name}.json")
    return rob, m, out


def test_calibrate_returns_the_fitted_model_type(zoned):
    from torchcal.calibration.zone_calibration import ZonedFit

    _, m, out = zoned
    glob, zones = out["global"][0], out["zones"][0]
    assert type(glob) is FitResult and glob.radius is not None and (glob.radius >= 0).all()
    assert isinstance(zones, ZonedFit) and zones.method == "damped" and zones.partition.n_zones == 3
    assert zones.zone_theta.shape == (3, glob.theta.shape[0]) and sum(zones.zone_poses) == 36
    same(zones.theta, glob.theta, "the global fit of the zoned model")  # its own fields: the global calibration
    for f in zones.zones:  # each zone: a fit damped towards the global one, with its intervals
        assert type(f) is FitResult and f.damping > 0 and f.radius is not None
        assert bool((f.theta - f.radius <= f.theta + f.radius).all())
    assert not torch.equal(zones.zone_theta[0], zones.zone_theta[1])


@pytest.mark.parametrize("kind", ["global", "zones"])
def test_save_load_round_trip_of_an_interval_calibration(zoned, kind):
    """Equal parameters, intervals and zones, and equal predictions to 1e-9 mm."""
    from torchcal.effects import context_of

    rob, m, out = zoned
    res, back, path = out[kind]
    assert type(back) is type(res)
    same(res.theta, back.theta, "theta")
    same(res.radius, back.radius, "radius")
    assert back.damping == res.damping and back.report.held == res.report.held
    same(res.zone_theta, back.zone_theta, "zone_theta")
    for a, b in zip(getattr(res, "zones", []), getattr(back, "zones", [])):
        same(a.radius, b.radius, "zone radius")
        assert a.report.held == b.report.held and a.damping == b.damping and a.status == b.status
        assert b.rms_mm == pytest.approx(a.rms_mm, rel=1e-12)
    ctx = context_of(rob, m)
    assert float((res.predict(ctx) - back.predict(ctx)).abs().max()) <= 1e-9
    probe = rob.fk(m.q)
    assert torch.equal(res.assign(probe), back.assign(probe))
    ev_a, ev_b = torchcal.evaluate(res, m), torchcal.evaluate(path, m)
    assert float((ev_a.residuals_mm - ev_b.residuals_mm).abs().max()) <= 1e-9
    same(modelfile.to_dict(back), json.loads(path.read_text()), "the file written back")


def test_a_broken_zone_entry_is_one_clear_error(zoned, tmp_path):
    from torchcal.errors import InputError

    _, _, out = zoned
    d = json.loads(out["zones"][2].read_text())
    P = len(d["parameters"])
    d["zones"][1]["value"] = d["zones"][1]["value"][:-1]
    (tmp_path / "bad.json").write_text(json.dumps(d))
    with pytest.raises(InputError, match=rf"bad.json: zone 2: value has {P - 1} values, expected {P}"):
        torchcal.load(tmp_path / "bad.json")
    d = json.loads(out["zones"][2].read_text())
    del d["partition"]
    (tmp_path / "bad.json").write_text(json.dumps(d))
    with pytest.raises(InputError, match="bad.json: partition"):
        torchcal.load(tmp_path / "bad.json")


@pytest.mark.parametrize("key, value, words", [
    ("value", float("nan"), r"zone 2: value\[0\] is nan, expected a finite number"),
    ("upper", float("inf"), r"zone 2: upper\[0\] is inf, expected a finite number"),
    ("lower", 1e9, r"zone 2: parameter 1: interval lower 1e\+09 > upper .*, expected lower <= upper")])
def test_a_zone_value_that_is_not_finite_or_an_inverted_interval_is_refused(zoned, tmp_path, key, value, words):
    """Before: NaN or inf zone values loaded in silence (every prediction in that zone NaN)."""
    from torchcal.errors import InputError

    _, _, out = zoned
    d = json.loads(out["zones"][2].read_text())
    d["zones"][1][key][0] = value
    (tmp_path / "bad.json").write_text(json.dumps(d))
    with pytest.raises(InputError, match=r"bad.json: " + words):
        torchcal.load(tmp_path / "bad.json")


def test_a_global_interval_that_is_not_finite_is_refused(zoned, tmp_path):
    from torchcal.errors import InputError

    _, _, out = zoned
    d = json.loads(out["global"][2].read_text())
    d["parameters"][2]["interval"][1] = float("nan")
    (tmp_path / "bad.json").write_text(json.dumps(d))
    with pytest.raises(InputError, match=r"bad.json: parameter 'interval': expected \[lower, upper\], two finite"):
        torchcal.load(tmp_path / "bad.json")


def test_a_zoned_model_predicts_each_row_with_its_zones_parameters(zoned):
    """evaluate of a ZonedFit = by hand: the partition's zone of each row's nominal TCP
    position, that zone's parameters in the model."""
    from torchcal.effects import make_context

    rob, m, out = zoned
    res = out["zones"][0]
    zone = res.partition.assign(rob.fk(m.q))
    assert len(set(zone.tolist())) == 3
    by_hand = torch.stack([res.model.predict(res.zones[int(z) - 1].theta, make_context(rob, m.q[i:i + 1]))[0]
                           for i, z in enumerate(zone)])
    ev = torchcal.evaluate(res, m)
    assert float((ev.residuals_mm - (m.xyz - by_hand)).abs().max()) <= 1e-9
    comp = torchcal.compensate(res, rob.fk(m.q[:6]), q0=m.q[:6])
    assert bool(comp.converged.all())
    for i in range(6):  # each target reached by its zone's model
        z = int(res.assign(rob.fk(m.q[i:i + 1]))[0]) - 1
        p = res.model.predict(res.zones[z].theta, make_context(rob, comp.q[i:i + 1]))[0]
        assert float((p - rob.fk(m.q[i:i + 1])[0]).norm()) <= 1e-6


def test_a_file_of_the_older_interval_format_still_loads(tmp_path):
    """tests/data/old_interval_model.json: written by the earlier `torchcal-interval-model/1`
    writer (UR5e + base_frame, 36 poses x 3, a 3-zone partition, damped zones); its
    predictions then, per zone, are in old_interval_model_predictions.json."""
    from torchcal.calibration.zone_calibration import ZonedFit
    from torchcal.effects import make_context

    old = json.loads((DATA / "old_interval_model.json").read_text())
    ref = json.loads((DATA / "old_interval_model_predictions.json").read_text())
    res = torchcal.load(DATA / "old_interval_model.json")
    assert isinstance(res, ZonedFit) and res.method == "damped" and res.zone_poses == [10, 16, 10]
    assert [f.report.held for f in res.zones] == [z["held"] for z in old["zones"]]
    same(res.theta, res.zones[0].theta, "the older format stores no global fit: zone 1 stands in")
    for f, z in zip(res.zones, old["zones"]):
        same(f.theta, torch.tensor(z["theta"], dtype=torch.float64), "theta (radians in that file)")
        width = torch.tensor(z["upper"], dtype=torch.float64) - torch.tensor(z["lower"], dtype=torch.float64)
        same(2 * f.radius, width, "interval width")
    q = torch.deg2rad(torch.tensor(ref["q_deg"], dtype=torch.float64))
    assert res.assign(res.model.robot.fk(q)).tolist() == ref["zone"]
    pred = res.predict(make_context(res.model.robot, q))
    assert float((pred - torch.tensor(ref["predicted_mm"], dtype=torch.float64)).abs().max()) <= 1e-9
    # saved again, in today's layout: the same predictions
    torchcal.save(res, tmp_path / "again.json")
    again = torchcal.load(tmp_path / "again.json")
    assert json.loads((tmp_path / "again.json").read_text())["format"] == modelfile.FORMAT
    assert float((again.predict(make_context(res.model.robot, q)) - pred).abs().max()) <= 1e-9


def test_effects_that_are_not_a_list_are_one_clear_error(session, tmp_path):
    """A hand-edited ``"effects": "base_frame"`` is named as a bad field (a string was read
    letter by letter: "unknown effect 'b'")."""
    from torchcal.errors import InputError

    d = json.loads(session[2].read_text())
    d["effects"] = "base_frame"
    (tmp_path / "bad.json").write_text(json.dumps(d))
    with pytest.raises(InputError, match=r"bad.json: model file is missing or has a bad field: 'effects' must be a "
                                         r"list of effect names, got str"):
        torchcal.load(tmp_path / "bad.json")


@pytest.mark.parametrize("key, value, must", [
    ("value", float("nan"), r"parameter dalpha1: 'value' must be finite, got nan"),  # was a traceback in evaluate
    ("value", "0.01", r"parameter dalpha1: 'value' must be a number, got '0.01' \(str\)"),
    ("value", None, r"parameter dalpha1: 'value' must be a number, got None"),
    ("std", "abc", r"parameter dalpha1: 'std' must be a number, got 'abc'"),
    ("value", 1e30, r"parameter dalpha1 = 1e\+30 deg is beyond any robot \(\|value\| <= 360 deg\)"),
    ("value", 500.0, r"parameter dalpha1 = 500 deg is beyond"),
])
def test_a_hand_edited_parameter_is_one_line_naming_it(session, tmp_path, key, value, must):
    """A parameter's value or std that is no finite number, or a size no robot or set-up has
    (modelfile.MAX_FILE_SIZE), is one InputError naming the file and the parameter: a NaN
    value gave an SVD traceback in evaluate, 1e30 deg was read as 'data of another robot'."""
    from torchcal.errors import InputError

    d = json.loads(session[2].read_text())
    i = next(k for k, p in enumerate(d["parameters"]) if p["name"] == "dalpha1")
    d["parameters"][i][key] = value
    (tmp_path / "edited.json").write_text(json.dumps(d))
    with pytest.raises(InputError, match=r"edited.json: " + must):
        torchcal.load(tmp_path / "edited.json")
    d["parameters"][i][key] = 359.0 if key == "value" else 0.5  # inside the bounds: loads
    (tmp_path / "edited.json").write_text(json.dumps(d))
    assert torchcal.load(tmp_path / "edited.json").theta.isfinite().all()


def test_a_measuring_frame_far_away_loads(session, tmp_path):
    """The size bound applies to parameters the prior holds: a base frame 150 m away (data
    in a site frame; `fit` writes it) loads and predicts there."""
    d = json.loads(session[2].read_text())
    i = next(k for k, p in enumerate(d["parameters"]) if p["name"] == "base_tx")
    d["parameters"][i]["value"] += 150e3
    (tmp_path / "far.json").write_text(json.dumps(d))
    far = torchcal.load(tmp_path / "far.json")
    assert float(far.theta[far.model.param_names().index("base_tx")]) > 1e5
