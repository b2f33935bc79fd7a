"""Parameter standard errors, 95 % intervals and the predicted TCP sigma, checked against
Monte Carlo refits (batched LM, analytic Jacobian) on simulated data."""

import json

import torch

import torchcal
from torchcal.calibration.fit import fit
from torchcal.calibration.lm import levenberg_marquardt
from torchcal.calibration.model import CalibrationModel
from torchcal.calibration.covariance import parameter_covariance, tcp_sigma
from torchcal.effects import make_context
from torchcal.robots.poses import random_poses
from torchcal.simulation.virtual_robot import VirtualRobot

ROBOT = "puma560"
MC = 200


def _refit(robot, q, xyz, free, x0):
    """Batched LM refits: xyz (B, N, 3) -> theta (B, P), each from x0 (P,)."""
    B, n = xyz.shape[0], robot.n

    def res(x):
        return (robot.fk(q, params=x.view(B, 1, n, 5)) - xyz).reshape(B, -1)

    def jac(x):
        return robot.param_jacobian(q, params=x.view(B, 1, n, 5)).reshape(B, -1, 5 * n)

    out = levenberg_marquardt(res, x0.expand(B, -1).clone(), free=free, jacobian_fn=jac,
                              max_iter=4)
    return out.x  # 4 Gauss-Newton-like steps from the first fit: within ~1e-7 of the optimum


def _setup(n_poses, seed):
    robot = torchcal.robot(ROBOT)
    vr = VirtualRobot(robot, seed=seed)
    q = random_poses(robot, n_poses, seed + 100)
    model = CalibrationModel(robot)
    return robot, vr, q, model


def test_standard_errors_match_monte_carlo_spread():
    robot, vr, q, model = _setup(40, 0)
    g = torch.Generator().manual_seed(1)
    truth = vr.positions(q)
    xyz = truth + 0.05 * torch.randn(MC, *truth.shape, generator=g, dtype=torch.float64)
    # the least-squares covariance against least-squares refits: no plausibility prior
    first = fit(model, make_context(robot, q), xyz[0], max_length_mm=None, max_angle_deg=None)
    free = first.report.free
    theta = _refit(robot, q, xyz, free, first.theta)
    assert torch.allclose(theta[0], first.theta, atol=1e-6)  # the batched refit is the same fit
    spread = theta[:, free].std(dim=0)
    # predicted standard errors of every refit (the formula's expectation, not one draw)
    J = robot.param_jacobian(q, params=theta.view(MC, 1, robot.n, 5))
    resid = xyz - robot.fk(q, params=theta.view(MC, 1, robot.n, 5))
    pred = torch.stack([parameter_covariance(J[b], resid[b], free).std[free] for b in range(MC)])
    ratio = spread / pred.mean(0)
    assert ((ratio > 0.8) & (ratio < 1.2)).all(), ratio
    # the fit's own (one-draw) standard errors are those of the formula on its data
    assert torch.allclose(first.std[free], pred[0], rtol=1e-6)
    # 95 % intervals hold the estimator's center for about 95 % of the refits and
    # parameters (the center, not vr.theta: puma560's held deviations are absorbed by the
    # identified ones, so these estimate a combination of the true values)
    center = theta.mean(0)
    cover = []
    for b in range(MC):
        lo, hi = parameter_covariance(J[b], resid[b], free).interval95(theta[b])
        cover.append(((lo <= center) & (center <= hi))[free].double().mean())
    assert 0.90 < float(torch.stack(cover).mean()) < 0.99


def test_pose_level_standard_errors_with_repeats():
    """Each pose measured 3 times; a pose-level error (what the model misses at a pose)
    is shared by the repeats. Row-level errors understate the spread, pose-level ones match."""
    robot, vr, q, model = _setup(30, 3)
    reps, P = 3, q.shape[0]
    g = torch.Generator().manual_seed(2)
    pose = torch.arange(P).repeat(reps)
    qr = q[pose]
    truth = vr.positions(qr)
    b = 0.05 * torch.randn(MC, P, 3, generator=g, dtype=torch.float64)
    xyz = truth + b[:, pose] + 0.02 * torch.randn(MC, len(pose), 3, generator=g, dtype=torch.float64)
    # identifiability judged at nominal only (theta0 given: no recheck at the first solution,
    # which would free nearly dependent parameters whose spread is not linear)
    first = fit(model, make_context(robot, qr), xyz[0], pose=pose, max_length_mm=None, max_angle_deg=None,
                theta0=model.zeros())
    assert first.covariance.method == "pose-level"
    free = first.report.free
    theta = _refit(robot, qr, xyz, free, first.theta)
    spread = theta[:, free].std(dim=0)
    J = robot.param_jacobian(qr, params=theta.view(MC, 1, robot.n, 5))
    resid = xyz - robot.fk(qr, params=theta.view(MC, 1, robot.n, 5))
    pose_level = torch.stack([parameter_covariance(J[k], resid[k], free, pose=pose).std[free]
                              for k in range(MC)]).mean(0)
    rows = torch.stack([parameter_covariance(J[k], resid[k], free).std[free]
                        for k in range(MC)]).mean(0)
    r_pose, r_rows = spread / pose_level, spread / rows
    assert ((r_pose > 0.8) & (r_pose < 1.2)).all(), r_pose
    assert (r_rows > 1.3).all(), r_rows  # ignoring the repeats' shared error understates


def test_pose_level_equals_fit_to_pose_means():
    """Independent reference: with equal repeats the pose-level covariance is the ordinary
    covariance of a least-squares fit to the pose means."""
    g = torch.Generator().manual_seed(5)
    G, reps, K = 12, 4, 5
    Jg = torch.randn(G, 3, K, generator=g, dtype=torch.float64)
    pose = torch.arange(G).repeat_interleave(reps)
    J = Jg[pose]
    r = torch.randn(G * reps, 3, generator=g, dtype=torch.float64)
    free = torch.ones(K, dtype=torch.bool)
    rbar = r.reshape(G, reps, 3).mean(1)
    A = Jg.reshape(-1, K)
    # residual of the pose means after projecting out the columns (least squares on means)
    Pm = torch.eye(3 * G, dtype=torch.float64) - A @ torch.linalg.pinv(A)
    # c uses the given residuals; build those residuals so that they are LS residuals:
    r_ls = (Pm @ rbar.reshape(-1)).reshape(G, 3)
    r2 = 0.3 * (r - rbar[pose]) + r_ls[pose]  # small scatter about the pose means
    c = parameter_covariance(J, r2, free, pose=pose)
    s2_means = float((r_ls ** 2).sum()) / (3 * G - K)
    ref = s2_means * torch.linalg.inv(A.T @ A)
    # sb2 clipped at 0 would break the identity; this draw keeps it positive
    assert c.pose_mm > 0
    assert torch.allclose(c.cov, ref, rtol=1e-10, atol=1e-14)
    assert c.dof == 3 * G - K


def test_tcp_sigma_predicts_the_error_of_the_fitted_model():
    """Over 60 simulated robots (hidden geometry, 0.05 mm noise), the RMS error of the
    fitted model against the true one at held-out poses matches the RMS predicted sigma."""
    robot = torchcal.robot(ROBOT)
    B = 60
    q = random_poses(robot, 30, 7)
    q_test = random_poses(robot, 200, 8)
    thetas = torch.stack([VirtualRobot(robot, seed=s).theta for s in range(B)])
    g = torch.Generator().manual_seed(9)
    truth = robot.fk(q, params=thetas.view(B, 1, robot.n, 5))
    xyz = truth + 0.05 * torch.randn(truth.shape, generator=g, dtype=torch.float64)
    first = fit(CalibrationModel(robot), make_context(robot, q), xyz[0], max_length_mm=None, max_angle_deg=None)
    free = first.report.free
    theta = _refit(robot, q, xyz, free, first.theta)
    J = robot.param_jacobian(q, params=theta.view(B, 1, robot.n, 5))
    resid = xyz - robot.fk(q, params=theta.view(B, 1, robot.n, 5))
    err, pred = [], []
    for b in range(B):
        cov = parameter_covariance(J[b], resid[b], free).cov
        Jt = robot.param_jacobian(q_test, params=theta[b].view(robot.n, 5))
        pred.append(tcp_sigma(Jt, cov))
        err.append((robot.fk(q_test, params=theta[b].view(robot.n, 5))
                    - robot.fk(q_test, params=thetas[b].view(robot.n, 5))).norm(dim=-1))
    ratio = torch.cat(err).pow(2).mean().sqrt() / torch.cat(pred).pow(2).mean().sqrt()
    assert 0.7 < float(ratio) < 1.4, ratio


def test_tcp_sigma_against_numpy_reference():
    g = torch.Generator().manual_seed(0)
    J = torch.randn(7, 3, 4, generator=g, dtype=torch.float64)
    L = torch.randn(4, 4, generator=g, dtype=torch.float64)
    C = L @ L.T
    ref = [float(torch.trace(J[i] @ C @ J[i].T)) ** 0.5 for i in range(7)]
    assert torch.allclose(tcp_sigma(J, C), torch.tensor(ref, dtype=torch.float64))


def test_model_json_has_std_intervals_and_covariance(tmp_path, capsys):
    from torchcal.cli import main
    from torchcal.io import modelfile

    robot = torchcal.robot(ROBOT)
    vr = VirtualRobot(robot, seed=4)
    m = vr.measure(random_poses(robot, 25, 4), repeats=2, noise_mm=0.05)
    from torchcal.io.measurement_csv import write_measurements
    write_measurements(tmp_path / "m.csv", m)
    out = tmp_path / "model.json"
    assert main(["fit", str(tmp_path / "m.csv"), "--robot", ROBOT, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "pose-level over 25 poses" in text and "95% interval" in text
    obj = json.loads(out.read_text())
    assert obj["covariance"]["method"] == "pose-level"
    from scipy.stats import t
    k = float(t.ppf(0.975, obj["covariance"]["dof"]))
    names = obj["covariance"]["parameters"]
    mat = torch.tensor(obj["covariance"]["matrix"], dtype=torch.float64)
    for p in obj["parameters"]:
        lo, hi = p["ci95"]
        if p["identified"]:
            i = names.index(p["name"])
            assert abs(mat[i, i].sqrt() - p["std"]) <= 1e-12 + 1e-9 * p["std"]
            assert abs(hi - p["value"] - k * p["std"]) <= 1e-9 * max(1.0, abs(p["value"]))
            assert abs(p["value"] - lo - k * p["std"]) <= 1e-9 * max(1.0, abs(p["value"]))
            assert f"{p['name']:<16}" in text
        else:
            assert lo == hi == p["value"] and p["name"] not in names
    fitted = modelfile.load(out)
    model, _ = fitted.model, fitted.theta
    cov = modelfile.load_covariance(out, model)  # radians inside, degrees in the file
    k = modelfile.file_units(model)[1]
    assert torch.allclose(cov.diagonal().sqrt() * k, torch.tensor([p["std"] for p in obj["parameters"]],
                                                                 dtype=torch.float64))
