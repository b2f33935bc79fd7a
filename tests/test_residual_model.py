"""The optional residual stage (torchcal.calibration.residual_model): a non-physical
kernel correction on top of the physical model.

Data: the project's simulator (UR5e, geometric deviations as the "real" robot), 0.02 mm
noise per axis, plus a smooth error the physical model cannot hold, injected here by hand:
0.3 mm * sin(2 q2) along x and 0.2 mm * cos(q3) along z.
"""

import json
import warnings

import numpy as np
import pytest
import torch

import torchcal
from torchcal.calibration.joint_range import CalibratedRangeWarning
from torchcal.cli import main
from torchcal import kernel_ridge as KR
from torchcal.io import modelfile
from torchcal.io.measurement_csv import write_measurements
from torchcal.measurements import Measurements
from torchcal.robots.poses import random_poses
from torchcal.simulation.virtual_robot import VirtualRobot

ROBOT = torchcal.robot("ur5e")
pytestmark = pytest.mark.filterwarnings("ignore::torchcal.calibration.joint_range.CalibratedRangeWarning")


def hidden(m: Measurements) -> Measurements:
    e = torch.zeros(len(m), 3, dtype=torch.float64)
    e[:, 0] = 0.3 * torch.sin(2 * m.q[:, 1])
    e[:, 2] = 0.2 * torch.cos(m.q[:, 2])
    return Measurements(m.pose, m.q, m.xyz + e, m.payload_kg, m.temp_c, q_prev=m.q_prev)


@pytest.fixture(scope="module")
def sessions():
    vr = VirtualRobot(ROBOT, [], seed=61)
    train = hidden(vr.measure(random_poses(ROBOT, 200, torch.Generator().manual_seed(62)), noise_mm=0.02, seed=63))
    test = hidden(vr.measure(random_poses(ROBOT, 100, torch.Generator().manual_seed(64)), noise_mm=0.02, seed=65))
    return train, test, torchcal.fit(ROBOT, train, residual_model="kernel")


def test_stage_improves_held_out_error_of_a_hidden_smooth_effect(sessions):
    train, test, res = sessions
    stage = res.residual_model
    assert stage is not None and "q2" in stage.inputs, stage
    with_stage = torchcal.evaluate(res, test).rms_mm
    res.residual_model = None
    try:
        without = torchcal.evaluate(res, test).rms_mm
    finally:
        res.residual_model = stage
    assert with_stage < 0.6 * without, (with_stage, without)


def test_stage_prediction_is_kernel_ridge_by_hand(sessions):
    """predict(q) = k(x(q), X) (K + lam I)^-1 R with the fit's residuals R, in numpy."""
    train, test, res = sessions
    s = res.residual_model
    x = lambda q: np.hstack([np.sin(q), np.cos(q)])  # noqa: E731
    Xt, Xs = x(train.q.numpy()[:, s.joints]), x(test.q.numpy()[:, s.joints])
    k = lambda a, b: np.exp(-((a[:, None] - b[None]) ** 2).sum(-1) / (2 * s.length_scale ** 2))  # noqa: E731
    alpha = np.linalg.solve(k(Xt, Xt) + s.ridge * np.eye(len(Xt)), res.residuals.numpy())
    np.testing.assert_allclose(s.predict(test.q).numpy(), k(Xs, Xt) @ alpha, atol=1e-9)


def test_model_file_round_trip_gives_identical_predictions(sessions, tmp_path):
    train, test, res = sessions
    obj = modelfile.to_dict(res)
    text = json.dumps(obj)
    assert obj["residual_model"]["non_physical"] is True
    (tmp_path / "m.json").write_text(text)
    back = modelfile.load(tmp_path / "m.json")
    torch.testing.assert_close(back.residual_model.predict(test.q), res.residual_model.predict(test.q),
                               rtol=0, atol=1e-12)
    a, b = torchcal.evaluate(res, test), torchcal.evaluate(tmp_path / "m.json", test)
    assert a.rms_mm == pytest.approx(b.rms_mm, rel=1e-12) and a.max_mm == pytest.approx(b.max_mm, rel=1e-12)


def test_compensate_inverts_physical_model_plus_stage(sessions):
    train, test, res = sessions
    targets = test.xyz[:20]
    comp = torchcal.compensate(res, targets, q0=test.q[:20])
    assert bool(comp.converged.all())
    from torchcal.effects import make_context
    phys = res.model.predict(res.theta, make_context(ROBOT, comp.q))
    reached = phys + res.residual_model.predict(comp.q)
    assert float((reached - targets).norm(dim=-1).max()) < 1e-5


def test_stage_warns_once_outside_the_calibrated_range(sessions):
    train, test, res = sessions
    q = test.q.clone()
    q[:5, 1] = res.q_range[1, 1] + 0.3  # joint 2 beyond what the fit saw
    from torchcal.effects import make_context
    moved = res.model.predict(res.theta, make_context(ROBOT, q)) - res.model.predict(res.theta, make_context(ROBOT, test.q))
    far = Measurements(test.pose, q, test.xyz + moved, test.payload_kg, test.temp_c)  # what the arm would measure there
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        torchcal.evaluate(res, far)
    ours = [w for w in caught if issubclass(w.category, CalibratedRangeWarning)]
    assert len(ours) == 1 and "residual stage extrapolates" in str(ours[0].message)


def test_export_drops_the_stage_with_one_line(sessions, tmp_path, capsys):
    train, test, res = sessions
    (tmp_path / "m.json").write_text(json.dumps(modelfile.to_dict(res)))
    assert main(["export", str(tmp_path / "m.json"), "--robot-file", str(tmp_path / "cal.json")]) == 0
    out = capsys.readouterr().out
    assert sum("residual stage is dropped" in line for line in out.splitlines()) == 1
    assert "residual" not in (tmp_path / "cal.json").read_text()


def test_fit_cli_stores_the_stage_and_evaluate_applies_it(sessions, tmp_path, capsys):
    train, test, res = sessions
    write_measurements(tmp_path / "tr.csv", train)
    write_measurements(tmp_path / "te.csv", test)
    assert main(["fit", str(tmp_path / "tr.csv"), "--robot", "ur5e", "--residual-model", "kernel",
                 "--out", str(tmp_path / "m.json")]) == 0
    assert "non-physical" in capsys.readouterr().out
    assert main(["evaluate", str(tmp_path / "te.csv"), "--model", str(tmp_path / "m.json"),
                 "--json", str(tmp_path / "e.json")]) == 0
    got = json.loads((tmp_path / "e.json").read_text())["rms_mm"]
    assert got == pytest.approx(torchcal.evaluate(res, test).rms_mm, rel=1e-6)


def test_compensate_cli_applies_the_stage(sessions, tmp_path):
    train, test, res = sessions
    (tmp_path / "m.json").write_text(json.dumps(modelfile.to_dict(res)))
    q0 = torch.rad2deg(test.q[:10]).numpy()
    xyz = test.xyz[:10].numpy()
    head = "x,y,z," + ",".join(f"q{j + 1}" for j in range(ROBOT.n))
    np.savetxt(tmp_path / "t.csv", np.hstack([xyz, q0]), delimiter=",", header=head, comments="", fmt="%.12g")
    assert main(["compensate", str(tmp_path / "t.csv"), "--model", str(tmp_path / "m.json"),
                 "--out", str(tmp_path / "q.csv")]) == 0
    out = np.genfromtxt(tmp_path / "q.csv", delimiter=",", names=True)
    q_cli = np.stack([out[f"q{j + 1}"] for j in range(ROBOT.n)], -1)
    lib = torchcal.compensate(res, test.xyz[:10], q0=test.q[:10])
    np.testing.assert_allclose(q_cli, torch.rad2deg(lib.q).numpy(), atol=1e-6)


def test_stage_is_sklearns_kernel_ridge_on_the_chosen_joints():
    """`fit_residual_model` on a residual of q2 alone (plain numpy draws, no robot fit): it
    keeps q2, and its dual weights and predictions at new poses are those of scikit-learn's
    KernelRidge (RBF, gamma = 1 / (2 l^2), alpha = the ridge) on (sin q2, cos q2)."""
    from sklearn.kernel_ridge import KernelRidge

    from torchcal.calibration.residual_model import fit_residual_model

    rng = np.random.default_rng(71)
    q = torch.from_numpy(rng.uniform(-2.5, 2.5, (150, ROBOT.n)))
    Y = np.stack([0.3 * np.sin(2 * q[:, 1].numpy()), np.zeros(150), 0.2 * np.cos(q[:, 1].numpy())], -1)
    Y = Y + rng.normal(0, 0.01, Y.shape)
    m = Measurements(torch.arange(150), q, torch.zeros(150, 3, dtype=torch.float64))
    stage = fit_residual_model(ROBOT, m, torch.from_numpy(Y), seed=0)
    assert stage is not None and stage.inputs[0] == "q2"
    X = np.concatenate([np.sin(q[:, stage.joints].numpy()), np.cos(q[:, stage.joints].numpy())], -1)
    ref = KernelRidge(alpha=stage.ridge, kernel="rbf", gamma=1 / (2 * stage.length_scale ** 2)).fit(X, Y)
    np.testing.assert_allclose(stage.alpha.numpy(), ref.dual_coef_, rtol=1e-6, atol=1e-9)
    q_new = torch.from_numpy(rng.uniform(-2.5, 2.5, (40, ROBOT.n)))
    X_new = np.concatenate([np.sin(q_new[:, stage.joints].numpy()), np.cos(q_new[:, stage.joints].numpy())], -1)
    np.testing.assert_allclose(stage.predict(q_new).numpy(), ref.predict(X_new), rtol=0, atol=1e-9)
    # what it learns is the residual: held-out rms well under the signal's
    truth = np.stack([0.3 * np.sin(2 * q_new[:, 1].numpy()), np.zeros(40), 0.2 * np.cos(q_new[:, 1].numpy())], -1)
    assert np.sqrt(np.mean(np.sum((stage.predict(q_new).numpy() - truth) ** 2, -1))) < 0.2 * np.sqrt(
        np.mean(np.sum(truth ** 2, -1)))


def test_stage_of_too_few_poses_is_none_and_of_noise_gains_nothing():
    from torchcal.calibration.residual_model import fit_residual_model

    rng = np.random.default_rng(72)
    q = torch.from_numpy(rng.uniform(-2.5, 2.5, (120, ROBOT.n)))
    m = Measurements(torch.arange(120), q, torch.zeros(120, 3, dtype=torch.float64))
    few = Measurements(torch.arange(KR.MIN_POSES - 1), q[:KR.MIN_POSES - 1], torch.zeros(KR.MIN_POSES - 1, 3,
                                                                                       dtype=torch.float64))
    assert fit_residual_model(ROBOT, few, torch.ones(KR.MIN_POSES - 1, 3, dtype=torch.float64)) is None
    noise = torch.from_numpy(rng.normal(0, 0.02, (120, 3)))
    stage = fit_residual_model(ROBOT, m, noise)  # may keep a joint (the choice has no significance test) ...
    floor = float(noise.pow(2).sum(-1).mean().sqrt())
    assert stage is None or stage.cv_rms_mm >= 0.95 * floor  # ... but claims no held-out gain on noise


@pytest.mark.parametrize("change, match", [
    ({"kind": "spline"}, "kind 'spline'"),
    ({"inputs": ["q9"]}, "not revolute joints"),
    ({"ridge": 0.0}, "not > 0"),
    ({"dual_weights_mm": [[0.0, 0.0, 0.0]]}, "differ in length"),
    ({"q_train_deg": [[float("nan")], [0.0]]}, "non-finite"),
])
def test_a_malformed_stage_in_a_file_is_one_line_naming_where(change, match):
    from torchcal.calibration.residual_model import from_dict

    good = {"kind": "kernel", "inputs": ["q2"], "length_scale_rad": 0.4, "ridge": 0.1, "cv_rms_mm": 0.01,
            "q_train_deg": [[10.0], [20.0]], "dual_weights_mm": [[0.1, 0.0, 0.0], [0.0, 0.1, 0.0]]}
    assert from_dict(good, ROBOT, "m.json").inputs == ("q2",)
    with pytest.raises(torchcal.InputError, match=match) as exc:
        from_dict({**good, **change}, ROBOT, "m.json")
    assert str(exc.value).startswith("m.json: bad 'residual_model': ") and "\n" not in str(exc.value)
