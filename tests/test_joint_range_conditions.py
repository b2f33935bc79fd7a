"""A model with an effect that reads a condition (temperature, payload) records the range
of it that its data spanned, and says (one `ConditionRangeWarning`) when evaluate,
compensate, accuracy or export use it outside that range; MODEL.json keeps the range
("calibrated_conditions"), and a file without it loads and says nothing. Measurements
built in memory get the unit checks a file's temp_c / payload_kg columns get.

Hidden physics: tests/npsim.py `thermal_session` (plain numpy link growth)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import torch

import torchcal
from torchcal.api import accuracy
from torchcal.calibration.joint_range import ConditionRangeWarning
from torchcal.measurements import ConditionWarning, Measurements
from torchcal.robots.poses import random_poses

from npsim import thermal_session

ROBOT = "ur5e"


def session(rob, n, lo, hi, seed):
    q = random_poses(rob, n, seed)
    temp = np.random.default_rng(seed + 100).uniform(lo, hi, n)
    xyz = thermal_session(rob, q.numpy(), temp, seed=7)
    return Measurements(torch.arange(n), q, torch.from_numpy(xyz), temp_c=torch.from_numpy(temp))


@pytest.fixture(scope="module")
def fitted():
    rob = torchcal.robot(ROBOT)
    train = session(rob, 80, 18.0, 26.0, seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ConditionRangeWarning)
        res = torchcal.fit(rob, train, ["thermal_expansion"])
    return rob, train, res


def caught(fn):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        out = fn()
    return out, [str(x.message) for x in w if issubclass(x.category, ConditionRangeWarning)]


def test_the_fit_records_the_temperature_range_only(fitted):
    _, train, res = fitted
    lo, hi = float(train.temp_c.min()), float(train.temp_c.max())
    assert res.conditions == {"temp_c": [lo, hi]}  # no effect reads the payload


def test_evaluate_warns_outside_the_fitted_temperatures_only(fitted):
    rob, train, res = fitted
    _, msgs = caught(lambda: torchcal.evaluate(res, train))  # the training data: silent
    assert msgs == []
    inside = session(rob, 30, 19.0, 25.0, seed=2)
    ev_in, msgs = caught(lambda: torchcal.evaluate(res, inside))
    assert msgs == []
    hot = session(rob, 30, 19.0, 25.0, seed=3)
    temp = hot.temp_c.clone()
    temp[:7] = torch.linspace(34.0, 40.0, 7, dtype=torch.float64)
    hot = Measurements(hot.pose, hot.q, torch.from_numpy(thermal_session(rob, hot.q.numpy(), temp.numpy(), seed=7)),
                       temp_c=temp)
    ev_hot, msgs = caught(lambda: torchcal.evaluate(res, hot))
    assert len(msgs) == 1, msgs
    lo, hi = res.conditions["temp_c"]
    assert f"temperature of 7 of 30 rows outside the fitted {lo:.4g} .. {hi:.4g} degC (farthest 40 degC)" in msgs[0]
    assert "payload" not in msgs[0]
    assert ev_hot.rms_mm > ev_in.rms_mm  # the warning is about a real loss: it extrapolates there


def test_compensate_and_accuracy_warn_at_a_temperature_outside(fitted):
    rob, train, res = fitted
    targets = torchcal.robot(ROBOT).fk(train.q[:5]).detach()
    _, msgs = caught(lambda: torchcal.compensate(res, targets, temp_c=torch.full((5,), 22.0)))
    assert msgs == []
    _, msgs = caught(lambda: torchcal.compensate(res, targets, temp_c=torch.full((5,), 45.0)))
    assert len(msgs) == 1 and "temperature of 5 of 5 targets" in msgs[0] and "farthest 45 degC" in msgs[0], msgs
    _, msgs = caught(lambda: accuracy(res, n=50, temp_c=22.0))
    assert msgs == []
    _, msgs = caught(lambda: accuracy(res, n=50, temp_c=45.0))
    assert len(msgs) == 1 and "workspace poses outside the fitted" in msgs[0] and "farthest 45 degC" in msgs[0], msgs


def test_model_file_keeps_the_range_and_an_older_file_says_nothing(fitted, tmp_path):
    rob, train, res = fitted
    path = tmp_path / "model.json"
    torchcal.save(res, path)
    obj = json.loads(path.read_text())
    assert obj["calibrated_conditions"] == {"temp_c": res.conditions["temp_c"]}
    assert torchcal.load(path).conditions == res.conditions
    hot = Measurements(train.pose, train.q, train.xyz, temp_c=train.temp_c + 15.0)
    _, msgs = caught(lambda: torchcal.evaluate(torchcal.load(path), hot))
    assert len(msgs) == 1
    del obj["calibrated_conditions"]
    old = tmp_path / "old.json"
    old.write_text(json.dumps(obj))
    assert torchcal.load(old).conditions is None
    _, msgs = caught(lambda: torchcal.evaluate(torchcal.load(old), hot))
    assert msgs == []


def test_cli_evaluate_names_the_range_in_one_line(fitted, tmp_path, capsys):
    from torchcal.cli import main
    from torchcal.io.measurement_csv import write_measurements

    rob, train, res = fitted
    torchcal.save(res, tmp_path / "model.json")
    write_measurements(tmp_path / "hot.csv", Measurements(train.pose, train.q, train.xyz, temp_c=train.temp_c + 15.0))
    assert main(["evaluate", str(tmp_path / "hot.csv"), "--model", str(tmp_path / "model.json")]) == 0
    err = [ln for ln in capsys.readouterr().err.splitlines() if "temperature" in ln]
    assert len(err) == 1 and err[0].startswith("torchcal: warning: temperature of ") and "degC" in err[0], err


def test_measurements_built_in_memory_in_kelvin_are_named(fitted):
    """The unit check of a file's temp_c column, for measurements built with the Python API."""
    rob, train, _ = fitted
    kelvin = Measurements(train.pose, train.q, train.xyz, temp_c=train.temp_c + 273.15)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        with pytest.raises(Exception):
            torchcal.evaluate(torchcal.fit(rob, kelvin, ["thermal_expansion"]), kelvin.subset(slice(0, 0)))
    msgs = [str(x.message) for x in w if issubclass(x.category, ConditionWarning)]
    assert msgs and "look like kelvin" in msgs[0] and "row 1" in msgs[0], msgs


def test_register_keeps_the_fitted_range_not_the_registration_datas(fitted):
    """A registered model (a new frame on new rows) was still fitted on the old rows'
    temperatures: it keeps their range (before: the registration rows' range, 30..34 degC)."""
    rob, _, res = fitted
    warm = session(rob, 30, 30.0, 34.0, seed=5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reg = torchcal.register(res, warm)
    assert reg.conditions == res.conditions


def test_a_payload_beyond_the_fitted_payloads_is_named():
    """joint_compliance reads the payload: hidden gravity deflection (tests/npsim.py
    `physics_session`, payloads 0..rated); rows at twice the rated payload are named."""
    from npsim import physics_session

    rob = torchcal.robot(ROBOT)
    q = random_poses(rob, 80, 8)
    xyz, payload = physics_session(rob, q.numpy(), seed=9, hidden=["joint_compliance:2"])
    m = Measurements(torch.arange(80), q, torch.from_numpy(xyz), payload_kg=torch.from_numpy(payload))
    res = torchcal.fit(rob, m, ["joint_compliance:2"])
    assert res.conditions == {"payload_kg": [float(payload.min()), float(payload.max())]}
    _, msgs = caught(lambda: torchcal.evaluate(res, m))
    assert msgs == []
    heavy = Measurements(m.pose, m.q, m.xyz, payload_kg=torch.full((80,), 2.0 * rob.payload_kg, dtype=torch.float64))
    _, msgs = caught(lambda: torchcal.evaluate(res, heavy))
    assert len(msgs) == 1 and msgs[0].startswith("payload of 80 of 80 rows outside the fitted ") and \
        f"(farthest {2.0 * rob.payload_kg:.4g} kg)" in msgs[0], msgs


def test_export_with_data_outside_the_fitted_temperatures_is_named(fitted, tmp_path):
    """export --data refits the geometry at the data's conditions: rows beyond the fitted
    temperatures are named (inside: nothing)."""
    from torchcal.api import export

    rob, train, res = fitted
    _, msgs = caught(lambda: export(res, table=tmp_path / "a.csv", data=train))
    assert msgs == []
    hot = Measurements(train.pose, train.q, train.xyz, temp_c=train.temp_c + 15.0)
    _, msgs = caught(lambda: export(res, table=tmp_path / "b.csv", data=hot))
    assert len(msgs) == 1 and msgs[0].startswith("temperature of ") and "80 rows" in msgs[0], msgs
