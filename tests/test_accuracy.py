"""Predicted TCP accuracy over the workspace (torchcal.calibration.accuracy).

References, in numpy: sigma = sqrt(trace J C J^T) with J by forward-mode autodiff of the
model's `predict` (not the analytic Jacobian it uses), the region names from the joint-1
angle and numpy's tertiles, and the region table, median and 95th percentile regrouped
from the returned sigma by hand.
"""

import numpy as np
import pytest
import torch
from torch.testing import assert_close

import torchcal
from torchcal.calibration.accuracy import predicted_sigma, region_names, workspace_accuracy
from torchcal.calibration.model import CalibrationModel
from torchcal.effects import make_context
from torchcal.robots.poses import random_poses

ROBOT = torchcal.robot("ur5e")


def approx(v):
    return pytest.approx(float(v), rel=1e-12, abs=1e-15)

MODEL = CalibrationModel(ROBOT, ["base_frame", "joint_compliance:2"])


def covariance(seed=0):
    """A full, positive definite parameter covariance (P, P)."""
    g = torch.Generator().manual_seed(seed)
    A = torch.randn(MODEL.n_params, MODEL.n_params, generator=g, dtype=torch.float64) * 1e-3
    return A @ A.T + 1e-8 * torch.eye(MODEL.n_params, dtype=torch.float64)


def test_predicted_sigma_against_numpy():
    q = random_poses(ROBOT, 30, 1)
    payload = torch.linspace(0, ROBOT.payload_kg, 30, dtype=torch.float64)
    theta = MODEL.zeros() + 1e-4
    C = covariance()
    sigma = predicted_sigma(MODEL, theta, C, q, payload)
    ctx = make_context(ROBOT, q, payload)
    J = torch.func.jacfwd(lambda th: MODEL.predict(th, ctx))(theta).numpy()  # (N, 3, P)
    ref = np.sqrt([np.trace(Ji @ C.numpy() @ Ji.T) for Ji in J])
    assert_close(sigma, torch.from_numpy(ref), rtol=1e-9, atol=1e-12)


def test_region_names_by_hand():
    deg = np.array([0.0, 44.0, 46.0, 135.0, 136.0, -46.0, -135.0, -136.0, 180.0])
    q = torch.zeros(len(deg), ROBOT.n, dtype=torch.float64)
    q[:, 0] = torch.from_numpy(np.radians(deg))
    rng = np.random.default_rng(2)
    pos = torch.from_numpy(rng.normal(size=(len(deg), 3)) * 500)
    names = region_names(q, pos)
    sector = ["front", "front", "left", "left", "back", "right", "right", "back", "back"]
    reach = pos[:, :2].norm(dim=-1).numpy()
    z = pos[:, 2].numpy()

    def tert(v, words):
        lo, hi = np.quantile(v, [1 / 3, 2 / 3])
        return [words[0] if x < lo else words[1] if x < hi else words[2] for x in v]
    expected = [f"{s} / {r} / {h}" for s, r, h in zip(sector, tert(reach, ("near", "mid-reach", "far")),
                                                      tert(z, ("low", "mid-height", "high")))]
    assert names == expected


def test_workspace_accuracy_regions_and_figures_by_hand():
    theta = MODEL.zeros()
    C = covariance(3)
    acc = workspace_accuracy(MODEL, theta, C, n=300, seed=4, payload_kg=2.0, temp_c=25.0)
    N = acc.q.shape[0]
    assert N == 300 and acc.seed == 4 and acc.robot == "ur5e" and acc.effects == tuple(MODEL.specs())
    payload = torch.full((N,), 2.0, dtype=torch.float64)
    assert_close(acc.sigma, predicted_sigma(MODEL, theta, C, acc.q, payload), rtol=1e-12, atol=0)
    assert_close(acc.pos, MODEL.predict(theta, make_context(ROBOT, acc.q, payload)), rtol=0, atol=1e-9)
    sigma = acc.sigma.numpy()
    groups = {}
    for name, s in zip(region_names(acc.q, acc.pos), sigma):
        groups.setdefault(name, []).append(s)
    table = {k: (np.mean(v), np.max(v), len(v)) for k, v in groups.items() if len(v) >= 5}
    assert [r[0] for r in acc.regions] == sorted(table, key=lambda k: -table[k][0])
    for name, mean, mx, count in acc.regions:
        assert (mean, mx, count) == (approx(table[name][0]), table[name][1], table[name][2])
    d = acc.to_dict()["sigma_mm"]
    assert d["median"] == approx(np.median(sigma)) and d["p95"] == approx(np.percentile(sigma, 95))
    assert (d["min"], d["max"]) == (sigma.min(), sigma.max())


def test_no_uncertainty_no_predicted_error():
    q = random_poses(ROBOT, 10, 5)
    zero = torch.zeros(MODEL.n_params, MODEL.n_params, dtype=torch.float64)
    assert float(predicted_sigma(MODEL, MODEL.zeros(), zero, q).abs().max()) == 0.0
    one = torch.zeros_like(zero)
    one[1, 1] = 1.0  # dd1 (mm) with a 1 mm standard error moves every TCP by 1 mm
    assert_close(predicted_sigma(MODEL, MODEL.zeros(), one, q), torch.ones(10, dtype=torch.float64),
                 rtol=1e-12, atol=0)
    assert float(predicted_sigma(MODEL, MODEL.zeros(), -one, q).max()) == 0.0  # a negative variance clamps at 0


def _robot_with_base():
    """ur5e on a mount: the robot file's base (world <- joint-1 frame) turned 40 deg about z
    and raised 600 mm, 200 mm aside."""
    import dataclasses
    B = torch.eye(4, dtype=torch.float64)
    c, s = np.cos(np.radians(40.0)), np.sin(np.radians(40.0))
    B[:2, :2] = torch.tensor([[c, -s], [s, c]], dtype=torch.float64)
    B[:3, 3] = torch.tensor([200.0, -100.0, 600.0], dtype=torch.float64)
    return dataclasses.replace(ROBOT, base=B)


def test_regions_are_named_about_joint_1_not_about_the_tracker():
    """A tracker 3.6 m away (base_frame, as on the UR10 of examples/ur10) and a robot on a
    mount: reach is the distance from joint 1's axis and height along it, computed here in
    numpy from the plain MD-H chain (tests/npsim.py) in the robot's own frame; the model's
    positions in the tracker's frame name other regions (on the UR10 model of series C, 1351
    of 2000 poses got another reach or height tertile)."""
    from scipy.spatial.transform import Rotation
    from npsim import numpy_fk

    robot = _robot_with_base()
    model = CalibrationModel(robot, ["base_frame"])
    theta = model.zeros()
    names = model.param_names()
    rotvec = np.array([0.01, -0.02, 0.35])
    for k, v in zip(("base_tx", "base_ty", "base_tz", "base_rx", "base_ry", "base_rz"),
                    (500.0, -3500.0, -1200.0, *rotvec)):
        theta[names.index(k)] = v
    C = torch.diag(torch.full((model.n_params,), 1e-6, dtype=torch.float64))
    acc = workspace_accuracy(model, theta, C, n=400, seed=2)
    world = numpy_fk(robot, acc.q.numpy(), np.zeros((robot.n, 5)))  # the robot file's world frame
    W = Rotation.from_rotvec(rotvec).as_matrix()
    assert np.abs(world @ W.T + [500.0, -3500.0, -1200.0] - acc.pos.numpy()).max() < 1e-6  # pos: tracker frame
    B = robot.base.numpy()
    local = (world - B[:3, 3]) @ B[:3, :3]  # joint-1 frame: z along joint 1's axis
    sector = ["front" if abs(v) <= 45 else "left" if 45 < v <= 135 else "right" if -135 <= v < -45 else "back"
              for v in np.degrees(acc.q[:, 0].numpy())]

    def tert(v, words):
        lo, hi = np.quantile(v, [1 / 3, 2 / 3])
        return [words[0] if x < lo else words[1] if x < hi else words[2] for x in v]
    expected = [f"{s} / {r} / {h}" for s, r, h in zip(sector, tert(np.hypot(local[:, 0], local[:, 1]),
                                                                   ("near", "mid-reach", "far")),
                                                      tert(local[:, 2], ("low", "mid-height", "high")))]
    groups = {}
    for name, sg in zip(expected, acc.sigma.numpy()):
        groups.setdefault(name, []).append(sg)
    table = {k: (np.mean(v), len(v)) for k, v in groups.items() if len(v) >= 5}
    assert {r[0]: (approx(r[1]), r[3]) for r in acc.regions} == {k: (approx(m), c) for k, (m, c) in table.items()}


def test_predicted_sigma_is_the_error_where_the_model_was_calibrated(tmp_path, capsys):
    """A ur5e calibrated on 60 poses within +-25 deg of one pose (plain-numpy truth, 0.05 mm
    noise, the model complete): `torchcal accuracy` predicts the error the model makes there,
    against the true robot at 300 fresh poses of that range. Drawn from the whole +-360 deg
    joint limits it said median 0.407 mm against a true median 0.027 mm; `--range limits`
    still gives that, and says that every pose lies beyond the calibrated range."""
    from npsim import numpy_fk
    from torchcal.cli import main
    from torchcal.measurements import Measurements

    n = ROBOT.n
    rng = np.random.default_rng(7)
    dev = np.column_stack([rng.uniform(-1, 1, n) * np.radians(0.05), rng.uniform(-1, 1, (n, 2)) * 0.5,
                           rng.uniform(-1, 1, n) * np.radians(0.05), np.zeros(n)])
    q0 = np.radians([30.0, -60.0, 80.0, -100.0, -90.0, 20.0])

    def poses(k, seed):
        return q0 + np.radians(np.random.default_rng(seed).uniform(-25, 25, (k, n)))
    q = poses(60, 1)
    m = Measurements(q=torch.from_numpy(q), xyz=torch.from_numpy(numpy_fk(ROBOT, q, dev) + rng.normal(0, 0.05, (60, 3))),
                     pose=torch.arange(60))
    torchcal.save(torchcal.fit(ROBOT, m), tmp_path / "m.json")
    fitted = torchcal.load(tmp_path / "m.json")
    qt = poses(300, 2)
    err = np.linalg.norm(fitted.model.predict(fitted.theta, make_context(ROBOT, torch.from_numpy(qt))).numpy()
                         - numpy_fk(ROBOT, qt, dev), axis=1)
    capsys.readouterr()
    assert main(["accuracy", str(tmp_path / "m.json"), "--n", "500"]) == 0
    line = capsys.readouterr().out.splitlines()[0]
    median = float(line.split("median ")[1].split(",")[0])
    assert 0.5 < median / np.median(err) < 2.0, (median, np.median(err))
    assert "inside the joint range the model was calibrated on" in line
    acc = torchcal.api.accuracy(tmp_path / "m.json", n=500)
    assert (acc.q.numpy() >= q.min(0) - 1e-12).all() and (acc.q.numpy() <= q.max(0) + 1e-12).all()
    assert main(["accuracy", str(tmp_path / "m.json"), "--n", "500", "--range", "limits"]) == 0
    assert "500 of them beyond the joint range the model was calibrated on" in capsys.readouterr().out


def test_a_model_with_several_reflectors():
    """One tool offset per reflector (points 3 and 7): accuracy ended in an AttributeError
    traceback (no point ids at the workspace poses). Now each pose's sigma is the larger
    of the two reflectors', each from forward-mode autodiff and numpy."""
    model = CalibrationModel(ROBOT, ["tool_offset"])
    model.effects[0].set_points([3, 7])
    model = CalibrationModel(ROBOT, model.effects)
    g = torch.Generator().manual_seed(1)
    A = torch.randn(model.n_params, model.n_params, generator=g, dtype=torch.float64) * 1e-3
    C = A @ A.T
    theta = model.zeros()
    theta[-6:] = torch.tensor([30.0, 0.0, 100.0, -20.0, 40.0, 80.0], dtype=torch.float64)
    acc = workspace_accuracy(model, theta, C, n=50, seed=3)
    ref = []
    for pid in (3, 7):
        ctx = make_context(ROBOT, acc.q, torch.full((50,), ROBOT.payload_kg / 2, dtype=torch.float64),
                           torch.full((50,), 20.0, dtype=torch.float64), point=torch.full((50,), pid))
        J = torch.func.jacfwd(lambda th: model.predict(th, ctx))(theta).numpy()
        ref.append(np.sqrt([np.trace(Ji @ C.numpy() @ Ji.T) for Ji in J]))
    assert_close(acc.sigma, torch.from_numpy(np.maximum(*ref)), rtol=1e-9, atol=1e-12)
    assert acc.points == (3, 7) and np.abs(ref[0] - ref[1]).max() > 1e-4  # the two differ


def test_a_negative_variance_in_the_model_file_is_refused(tmp_path, capsys):
    """A variance below zero in MODEL.json's covariance (a hand edit, a broken copy):
    accuracy printed 'predicted TCP sigma ... min 0.0000, median 0.0000, max 0.0000'
    (the clamp in the propagation), a perfect robot. Now one line, exit 2."""
    import json

    from torchcal.cli import main

    assert main(["simulate", "--robot", "ur5e", "--n", "30", "--seed", "4", "--out", str(tmp_path / "s.csv")]) == 0
    assert main(["fit", str(tmp_path / "s.csv"), "--robot", "ur5e", "--out", str(tmp_path / "m.json")]) == 0
    obj = json.loads((tmp_path / "m.json").read_text())
    M = obj["covariance"]["matrix"]
    for i in range(len(M)):
        M[i][i] = -abs(M[i][i])
    (tmp_path / "neg.json").write_text(json.dumps(obj))
    capsys.readouterr()
    assert main(["accuracy", str(tmp_path / "neg.json"), "--n", "50"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "negative variance" in err


@pytest.mark.parametrize("temp_c, payload_kg, words", [
    (293.0, None, r"^accuracy: temperature 293 degC is outside -30..60 degC: it looks like kelvin"),
    (70.0, None, r"^accuracy: temperature 70 degC is outside -30..60 degC: it looks like degrees Fahrenheit"),
    (20.0, 5000.0, r"^accuracy: payload 5000 kg is above 3 times the rated payload of ur5e \(5 kg\): grams read as kg"),
])
def test_conditions_in_another_unit_are_named(temp_c, payload_kg, words):
    """`accuracy --temp 293` (kelvin for degC) printed a predicted sigma 20 times the one at
    20 degC for a thermal model, in silence (0.41 vs 0.019 mm median on a UR5e fit); now one
    ConditionWarning names the unit, as a measurement file's temp_c column gets. Conditions
    a cell sees pass without a word; `plan` judges its options the same way."""
    import warnings

    from torchcal.measurements import ConditionWarning
    from torchcal.planning.plan import plan

    model = CalibrationModel(ROBOT, ["base_frame", "joint_compliance:2", "thermal_expansion"])
    C = 1e-8 * torch.eye(model.n_params, dtype=torch.float64)
    with pytest.warns(ConditionWarning, match=words) as rec:
        workspace_accuracy(model, model.zeros(), C, n=50, seed=1, payload_kg=payload_kg, temp_c=temp_c)
    assert len(rec) == 1
    with pytest.warns(ConditionWarning, match=words.replace("^accuracy", "^plan")):
        plan(ROBOT, ["thermal_expansion"], n=10, candidates=200, payload_kg=payload_kg, temp_c=temp_c,
             random_plans=2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ConditionWarning)
        workspace_accuracy(model, model.zeros(), C, n=50, seed=1, payload_kg=5.0, temp_c=35.0)
