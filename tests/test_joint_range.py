"""A fitted model records the joint range of its calibration data; evaluate and compensate
count (and warn about) rows / targets beyond it.

Reference: the simulated session covers joint 1 only in [-60, 30] deg; the test moves
chosen rows beyond that span (by hand, in degrees) and counts them itself with the
documented tolerance max(1 % of the span, 0.5 deg / 0.5 mm); the range written to
MODEL.json is compared with numpy's min / max of the commanded q in file units.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
import warnings

import numpy as np
import pytest
import torch
from torch.testing import assert_close

import torchcal
from torchcal.calibration.joint_range import CalibratedRangeWarning, joint_range
from torchcal.cli import main
from torchcal.effects import make_context
from torchcal.io.measurement_csv import write_measurements
from torchcal.io.modelfile import load
from torchcal.measurements import Measurements
from torchcal.robots.poses import random_poses
from torchcal.io.robot_file import robot_from_dict
from torchcal.simulation.virtual_robot import VirtualRobot
from torchcal.io import modelfile

LO, HI = -60.0, 30.0  # deg: joint 1 of the calibration session


@pytest.fixture(scope="module")
def session():
    robot = torchcal.robot("ur5e")
    real = VirtualRobot(robot, ["gear_periodic:1"], seed=3)  # an effect the fitted model lacks
    g = torch.Generator().manual_seed(11)
    q = random_poses(robot, 40, 4)
    q[:, 0] = torch.deg2rad(LO + (HI - LO) * torch.rand(40, generator=g, dtype=torch.float64))
    m = real.measure(q, seed=5)
    return robot, real, m, torchcal.fit(robot, m, effects=["base_frame"])


def _expected_outside(q_deg: np.ndarray, train_deg: np.ndarray) -> int:
    """Rows beyond the training min / max by more than max(1 % span, 0.5 deg) (all revolute)."""
    lo, hi = train_deg.min(0), train_deg.max(0)
    tol = np.maximum(0.01 * (hi - lo), 0.5)
    return int(((q_deg < lo - tol) | (q_deg > hi + tol)).any(1).sum())


def _moved(robot, real, m, q1_deg: dict[int, float]) -> Measurements:
    """The training poses with joint 1 of rows `q1_deg` set (deg), measured on the real robot."""
    q = m.q.clone()
    for i, v in q1_deg.items():
        q[i, 0] = math.radians(v)
    return real.measure(q, seed=7)


def test_evaluate_inside_no_warning_outside_counted(session):
    robot, real, m, res = session
    train = np.degrees(m.q.numpy())
    hi1 = train[:, 0].max()
    tol1 = max(0.01 * (hi1 - train[:, 0].min()), 0.5)
    assert_close(res.q_range, torch.stack([m.q.amin(0), m.q.amax(0)]))
    # inside: joint 1 anywhere within the span (and just inside the tolerance)
    g = torch.Generator().manual_seed(2)
    inside = {i: float(train[:, 0].min() + (hi1 - train[:, 0].min()) * torch.rand(1, generator=g))
              for i in range(0, 40, 3)}
    inside[1] = hi1 + 0.5 * tol1
    with warnings.catch_warnings():
        warnings.simplefilter("error", CalibratedRangeWarning)
        ev = torchcal.evaluate(res, _moved(robot, real, m, inside))
    assert ev.outside_range == 0 and ev.to_dict()["outside_range"] == 0
    # outside: three rows far beyond, one just beyond the tolerance
    out = {2: 90.0, 5: 120.0, 9: -170.0, 12: hi1 + 2.0 * tol1}
    mo = _moved(robot, real, m, out)
    want = _expected_outside(np.degrees(mo.q.numpy()), train)
    assert want == 4
    with pytest.warns(CalibratedRangeWarning) as rec:
        ev = torchcal.evaluate(res, mo)
    assert ev.outside_range == want and ev.n == 40
    assert len(rec) == 1
    msg = str(rec[0].message)
    assert msg.startswith(f"{want} of 40 rows lie outside the calibrated joint range (joint 1: ")
    assert "joint 1: -170.0 deg" in msg and "joint 2" not in msg  # the farthest value
    assert f"calibrated {train[:, 0].min():.1f} .. {hi1:.1f} deg" in msg


def test_cli_writes_range_and_warns_old_file_does_not(session, tmp_path, capsys):
    robot, real, m, _ = session
    data = tmp_path / "train.csv"
    write_measurements(data, m)
    model = tmp_path / "model.json"
    assert main(["fit", str(data), "--robot", "ur5e", "--effects", "base_frame", "--out", str(model)]) == 0
    obj = json.loads(model.read_text())
    train = np.degrees(m.q.numpy())
    rng = obj["calibrated_range"]
    assert rng["unit"] == ["deg"] * 6
    np.testing.assert_allclose(rng["q_min"], train.min(0), rtol=0, atol=1e-9)
    np.testing.assert_allclose(rng["q_max"], train.max(0), rtol=0, atol=1e-9)
    val = tmp_path / "val.csv"
    write_measurements(val, _moved(robot, real, m, {0: 100.0}))
    capsys.readouterr()
    rep = tmp_path / "rep.json"
    assert main(["evaluate", str(val), "--model", str(model), "--json", str(rep)]) == 0
    cap = capsys.readouterr()
    assert cap.out.startswith("40 rows: rms ") and cap.out.strip().splitlines()[1:] == [f"wrote {rep}"]
    lines = [ln for ln in cap.err.splitlines() if "calibrated joint range" in ln]
    assert lines == [lines[0]] and lines[0].startswith("torchcal: warning: 1 of 40 rows lie outside")
    assert "joint 1: 100.0 deg" in lines[0]
    assert json.loads(rep.read_text())["outside_range"] == 1
    # a model file written before the range was recorded: loads, evaluates, no warning
    del obj["calibrated_range"]
    old = tmp_path / "old.json"
    old.write_text(json.dumps(obj))
    assert load(old).q_range is None
    assert main(["evaluate", str(val), "--model", str(old), "--json", str(tmp_path / "old_rep.json")]) == 0
    cap = capsys.readouterr()
    assert "calibrated joint range" not in cap.err and cap.out.startswith("40 rows: rms ")
    old_rep = json.loads((tmp_path / "old_rep.json").read_text())
    assert "outside_range" not in old_rep and old_rep["n"] == 40
    with warnings.catch_warnings():
        warnings.simplefilter("error", CalibratedRangeWarning)
        assert torchcal.evaluate(str(old), val).outside_range is None


SCARA = json.loads((Path(__file__).resolve().parents[1] / "examples" / "scara.json").read_text())


def test_prismatic_range_in_mm_round_trip_and_compensate(tmp_path, capsys):
    robot = robot_from_dict(SCARA)
    g = torch.Generator().manual_seed(1)
    user = torch.stack([torch.empty(30, dtype=torch.float64).uniform_(-120, 120, generator=g),
                        torch.empty(30, dtype=torch.float64).uniform_(-130, 130, generator=g),
                        torch.empty(30, dtype=torch.float64).uniform_(40, 120, generator=g),  # mm
                        torch.empty(30, dtype=torch.float64).uniform_(-170, 170, generator=g)], 1)
    q = robot.q_from_user(user)
    m = Measurements(torch.arange(30), q, robot.fk(q))
    res = torchcal.fit(robot, m)
    rng = modelfile.to_dict(res)["calibrated_range"]
    assert rng["unit"] == ["deg", "deg", "mm", "deg"]
    assert rng["q_min"][2] == pytest.approx(float(user[:, 2].min()), abs=1e-12)  # mm, not rad->deg
    assert rng["q_max"][2] == pytest.approx(float(user[:, 2].max()), abs=1e-12)
    assert rng["q_max"][0] == pytest.approx(float(user[:, 0].max()), abs=1e-12)  # deg
    path = tmp_path / "scara_model.json"
    torchcal.save(res, path)
    fitted = load(path)
    model, theta = fitted.model, fitted.theta
    assert_close(fitted.q_range, joint_range(q), rtol=0, atol=1e-12)
    # compensate: the solved slide position, not the seed, is what is checked
    hi3 = float(user[:, 2].max())
    tq = user[:4].clone()
    tq[1, 2], tq[3, 2] = hi3 + 4.0, float(user[:, 2].min()) - 3.0  # mm, beyond the 0.8 mm tolerance
    tq[2, 2] = hi3 + 0.3  # inside the tolerance
    tq[0, 2] = hi3 - 1.0  # inside, but seeded outside
    seeds = tq.clone()
    seeds[0, 2] = hi3 + 2.0
    t = model.predict(theta, make_context(robot, robot.q_from_user(tq)))
    with pytest.warns(CalibratedRangeWarning, match=rf"2 of 4 converged targets .*joint 3: {hi3 + 4.0:.1f} mm"):
        comp = torchcal.compensate(str(path), t, q0=robot.q_from_user(seeds))
    assert comp.converged.all() and comp.outside_range == 2
    assert_close(robot.q_to_user(comp.q)[:, 2], tq[:, 2], rtol=0, atol=1e-6)
    # the command line says the same on stderr and writes its file as before
    rows = ["x,y,z,q1,q2,q3,q4"] + [",".join(repr(float(v)) for v in [*t[i].tolist(), *seeds[i].tolist()])
                                     for i in range(4)]
    (tmp_path / "targets.csv").write_text("\n".join(rows) + "\n")
    capsys.readouterr()
    assert main(["compensate", str(tmp_path / "targets.csv"), "--model", str(path),
                 "--out", str(tmp_path / "q.csv")]) == 0
    err = capsys.readouterr().err
    assert "torchcal: warning: 2 of 4 converged targets lie outside the calibrated joint range (joint 3: " in err


def test_interval_model_keeps_the_range(session, tmp_path):
    robot, real, m, _ = session
    q = m.q[:20]
    mm = real.measure(q, repeats=2, seed=9)
    im = torchcal.calibrate(robot, mm, effects=["base_frame"])
    assert_close(im.q_range, torch.stack([q.amin(0), q.amax(0)]), rtol=0, atol=0)
    torchcal.save(im, tmp_path / "im.json")
    d = json.loads((tmp_path / "im.json").read_text())
    np.testing.assert_allclose(d["calibrated_range"]["q_max"], np.degrees(q.numpy()).max(0), rtol=0, atol=1e-9)
    back = torchcal.load(tmp_path / "im.json")
    assert_close(back.q_range, im.q_range, rtol=0, atol=1e-12)
    # one target whose nominal inverse turns joint 1 to 100 deg (calibrated -60 .. 30 deg)
    tq = q[:3].clone()
    tq[0, 0] = math.radians(100.0)
    t = back.model.predict(back.theta, make_context(robot, tq))
    with pytest.warns(CalibratedRangeWarning, match=r"1 of 3 converged targets .*joint 1: 100\.0 deg"):
        comp = torchcal.compensate(back, t, q0=tq)
    assert comp.converged.all() and comp.outside_range == 1
    del d["calibrated_range"]
    (tmp_path / "old.json").write_text(json.dumps(d))
    assert torchcal.load(tmp_path / "old.json").q_range is None
