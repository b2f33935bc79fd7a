"""Interval identification (torchcal.calibration.intervals) and compensation (torchcal.calibration.compensate).

- noise-free data -> the injected identifiable deviations come back, residual <= 1e-6 mm;
- unidentifiable parameters are held and named (dtheta6 / dalpha6 with the TCP on the
  z6 axis, one of dd2 / dd3 on the parallel axes 2-3);
- the interval hull contains the solutions of data sampled inside the error intervals
  (exactly for the linearised map, to second order for nonlinear refits) and is tight;
- a zone's identification is the one fit (`torchcal.calibration.fit.fit` with damping,
  no prior, no registration): the same numbers as calling it directly;
- compensation converges, with the analytic and with the autograd joint Jacobian.
"""

import pytest
import torch
from torch.testing import assert_close

from torchcal.calibration.compensate import compensate, nominal_inverse
from torchcal.effects import make_context
from torchcal.errors import InputError
from torchcal.calibration.intervals import (PoseIntervals, identify_intervals, identify_zones, parameter_intervals,
                                            pose_intervals, solution_map)
from torchcal.reliability.interval import Interval
from torchcal.measurements import Measurements
from torchcal.calibration.model import CalibrationModel
from torchcal.robots.poses import random_poses

DEG = torch.pi / 180


def exact_intervals(model, theta, q, half_width=None):
    """PoseIntervals whose centers are the model's exact positions at theta."""
    p = model.predict(theta, make_context(model.robot, q))
    hw = torch.zeros_like(p) if half_width is None else half_width
    m = q.shape[0]
    return PoseIntervals(torch.arange(m), q, p - hw, p + hw, torch.full((m,), 3))


def hull(fit) -> Interval:
    """(P,) parameter intervals [theta - radius, theta + radius] of an interval fit."""
    return Interval.from_center_radius(fit.theta, fit.radius)


def solution_map_of(model, data, fit, theta0=None):
    """S (P, 3m) of `fit` recomputed here: the damped map at the solution, D the column
    norms at theta0 (default nominal)."""
    ctx = data.context(model.robot)
    x0 = model.zeros() if theta0 is None else theta0
    J = model.jacobian(fit.theta, ctx).reshape(-1, model.n_params)
    D = model.jacobian(x0, ctx).reshape(-1, model.n_params).norm(dim=0)
    return solution_map(J, fit.report.free, fit.damping, scale=D)


def random_theta(model, free, seed, scale=1.0):
    """Random deviations on the free parameters only: 0.02 deg / 0.5 mm sized."""
    g = torch.Generator().manual_seed(seed)
    size = torch.tensor([0.02 * DEG if u == "rad" else 0.5 for u in model.param_units()], dtype=torch.float64)
    theta = (2 * torch.rand(model.n_params, generator=g, dtype=torch.float64) - 1) * size * scale
    return theta * free


def test_pose_intervals_are_intervals():
    """Center/radius are the Interval's (hand values); lower > upper is refused, naming the index."""
    lo = torch.tensor([[1.0, -2.0, 0.0]])
    data = PoseIntervals(torch.arange(1), torch.zeros(1, 6), lo, lo + torch.tensor([[2.0, 1.0, 0.0]]),
                         torch.tensor([2]))
    assert data.center.tolist() == [[2.0, -1.5, 0.0]] and data.radius.tolist() == [[1.0, 0.5, 0.0]]
    assert data.center.tolist() == data.center.tolist()  # the former name still works
    assert torch.equal(data.interval.lower, lo)
    with pytest.raises(InputError, match=r"lower must be <= upper.*index \[0, 1\]"):
        PoseIntervals(torch.arange(1), torch.zeros(1, 6), lo, lo - torch.tensor([[0.0, 1.0, 0.0]]),
                      torch.tensor([2]))


def test_noise_free_recovery(kr):
    model = CalibrationModel(kr)
    q = random_poses(kr, 25, 1)
    # the analysis runs at nominal: it does not depend on the data
    free = identify_intervals(model, exact_intervals(model, model.zeros(), q)).report.free
    truth = random_theta(model, free, 2, scale=4.0)  # only what the analysis keeps free
    fit = identify_intervals(model, exact_intervals(model, truth, q))
    assert fit.converged
    assert_close(fit.report.free, free)
    assert fit.residuals.abs().max() <= 1e-6
    assert_close(fit.theta, truth, atol=1e-9, rtol=0)  # rad and mm
    assert fit.radius.abs().max() == 0  # zero-width data, zero-width parameters


def test_noise_free_recovery_with_effect(kr):
    model = CalibrationModel(kr, ["base_frame"])
    q = random_poses(kr, 25, 3)
    free = identify_intervals(model, exact_intervals(model, model.zeros(), q)).report.free
    truth = random_theta(model, free, 4, scale=2.0)
    fit = identify_intervals(model, exact_intervals(model, truth, q))
    assert fit.residuals.abs().max() <= 1e-6
    assert_close(fit.theta, truth, atol=1e-8, rtol=0)
    # base z translation and rotation about z trade off against joint 1's dd and dtheta: the
    # gauge of `fit` keeps the frame's and holds (names) joint 1's
    assert {"dd1", "dtheta1"} <= set(fit.report.held)
    assert not {"base_tz", "base_rz"} & set(fit.report.held)


def test_unidentifiable_flagged_by_name(kr):
    model = CalibrationModel(kr)
    fit = identify_intervals(model, exact_intervals(model, model.zeros(), random_poses(kr, 20, 5)))
    held = set(fit.report.held)
    # TCP on the z6 axis: turning or twisting the last link does not move it
    assert {"dtheta6", "dalpha6"} <= held
    # joints 2 and 3 are parallel: dd2 and dd3 both shift along the same direction
    assert len({"dd2", "dd3"} & held) == 1
    # held parameters stay at nominal and have zero radius
    idx = [model.param_names().index(n) for n in held]
    assert fit.theta[idx].abs().max() == 0 and fit.radius[idx].abs().max() == 0
    # every declared-absent beta is not even a candidate
    assert "dbeta1" not in held and "dbeta1" not in [r["name"] for r in parameter_intervals(fit)]


@pytest.fixture(scope="module")
def noisy_zone(kr):
    model = CalibrationModel(kr)
    q = random_poses(kr, 12, 7)
    g = torch.Generator().manual_seed(8)
    truth = random_theta(model, model.default_free(), 9, scale=3.0)
    p = model.predict(truth, make_context(kr, q))
    center = p + 0.05 * torch.randn(p.shape, generator=g, dtype=torch.float64)
    radius = 0.02 + 0.1 * torch.rand(p.shape, generator=g, dtype=torch.float64)
    data = PoseIntervals(torch.arange(12), q, center - radius, center + radius, torch.full((12,), 10))
    return model, data, identify_intervals(model, data)


def test_hull_contains_linear_solutions_and_is_tight(noisy_zone):
    model, data, fit = noisy_zone
    g = torch.Generator().manual_seed(10)
    ec, er = data.center.reshape(-1), data.radius.reshape(-1)
    u = 2 * torch.rand(500, ec.numel(), generator=g, dtype=torch.float64) - 1
    de = u * er  # (500, 3m) inside the box, relative to the center
    S = solution_map_of(model, data, fit)
    sols = fit.theta + de @ S.T
    iv = hull(fit)
    assert iv.contains(sols, atol=1e-12).all()
    # tight: the box vertex sign(S_k) * e_r reaches the upper bound of parameter k
    for k in fit.report.free.nonzero().flatten()[:5].tolist():
        vert = torch.sign(S[k]) * er
        assert_close(fit.theta[k] + S[k] @ vert, iv.upper[k])


def test_hull_contains_nonlinear_refits(noisy_zone):
    """Refitting data sampled inside the intervals (nonlinear LM) lands inside the hull,
    up to second-order terms (1e-3 of the radius)."""
    model, data, fit = noisy_zone
    g = torch.Generator().manual_seed(11)
    zones = []
    for s in range(6):
        u = 2 * torch.rand(data.center.shape, generator=g, dtype=torch.float64) - 1
        if s < 2:
            u = torch.sign(u)  # vertices of the box, the hardest case
        e = data.center + u * data.radius
        zones.append(PoseIntervals(data.pose, data.q, e, e, data.count))
    fits = identify_zones(model, zones)
    iv = hull(fit)
    for f in fits:
        assert_close(f.report.free, fit.report.free)
        inside = iv.contains(f.theta, atol=1e-3 * fit.radius + 1e-12)
        assert inside.all(), f"outside: {[model.param_names()[k] for k in (~inside).nonzero().flatten()]}"


def test_solution_map_is_damped_pseudo_inverse():
    g = torch.Generator().manual_seed(0)
    J = torch.randn(30, 6, generator=g, dtype=torch.float64) * torch.tensor([1, 10, 100, 1e3, 1, 1.0])
    free = torch.tensor([True, True, True, True, False, True])
    S = solution_map(J, free)
    assert_close(S[free], torch.linalg.pinv(J[:, free]))
    assert S[4].abs().max() == 0
    Sd = solution_map(J, free, mu=1e-3)
    d = J[:, free].norm(dim=0)
    A = J[:, free].T @ J[:, free] + 1e-3 * torch.diag(d ** 2)
    assert_close(Sd[free], torch.linalg.solve(A, J[:, free].T))


@pytest.mark.parametrize("effects", [(), ("base_frame",)], ids=["geometric", "base_frame"])
def test_zones_are_the_one_fit(kr, effects):
    """Each zone of `identify_zones` is `fit` itself (damping towards theta0, no prior, no
    registration, on the parameters identifiable at nominal): the same numbers, and the
    zones do not depend on each other."""
    from torchcal.calibration.fit import fit

    model = CalibrationModel(kr, list(effects))
    g = torch.Generator().manual_seed(12)
    truth = random_theta(model, model.default_free(), 13, scale=3.0)
    zones = []
    for z in range(3):
        q = random_poses(kr, 11, 20 + z)
        p = model.predict(truth, make_context(kr, q))
        c = p + 0.05 * torch.randn(p.shape, generator=g, dtype=torch.float64)
        r = 0.1 * torch.rand(p.shape, generator=g, dtype=torch.float64)
        zones.append(PoseIntervals(torch.arange(11), q, c - r, c + r, torch.full((11,), 5)))
    zones.append(zones[0].subset(slice(0, 10)))  # a zone of another size
    theta0 = random_theta(model, model.default_free(), 14, scale=0.5)
    together = identify_zones(model, zones, damping=0.01, theta0=theta0)
    for z, data in enumerate(zones):
        single = identify_intervals(model, data, damping=0.01, theta0=theta0)
        assert single.report.held == together[z].report.held
        assert torch.equal(together[z].theta, single.theta) and torch.equal(together[z].radius, single.radius)
        direct = fit(model, data.context(kr), data.center, theta0=theta0, free=single.report.free, register=False,
                     prior=False, damping=0.01, max_iter=100)
        assert torch.equal(direct.theta, single.theta) and direct.n_iter == single.n_iter


def test_pose_intervals_groups_repeats(kr):
    q = random_poses(kr, 3, 30)
    pose = torch.tensor([2, 0, 1, 0, 2, 1])
    xyz = torch.arange(18, dtype=torch.float64).reshape(6, 3)
    m = Measurements(pose, q[[2, 0, 1, 0, 2, 1]], xyz)
    pi = pose_intervals(m)
    assert pi.pose.tolist() == [2, 0, 1]
    assert_close(pi.lower[0], xyz[0])
    assert_close(pi.upper[0], xyz[4])
    assert_close(pi.q, q[[2, 0, 1]])
    assert pi.count.tolist() == [2, 2, 2]
    with pytest.raises(InputError, match="at least 3 repetitions"):
        pose_intervals(m, min_repeats=3)
    bad = Measurements(pose, q[[2, 0, 1, 1, 2, 1]], xyz)
    with pytest.raises(InputError, match="^measurements: rows of pose 0 have different joint angles"):
        pose_intervals(bad)
    # a file's rows: the message names the file (calibrate DATA printed 'measurements:')
    named = Measurements(pose, q[[2, 0, 1, 0, 2, 1]], xyz, source="series.csv")
    with pytest.raises(InputError, match=r"^series\.csv: pose 2 has 2 row\(s\); interval identification needs at least 3"):
        pose_intervals(named, min_repeats=3)


def test_too_few_poses_is_an_error(kr):
    model = CalibrationModel(kr)
    data = exact_intervals(model, model.zeros(), random_poses(kr, 4, 31))
    with pytest.raises(InputError, match="4 poses give 12 equations"):
        identify_intervals(model, data)


@pytest.mark.parametrize("effects", [(), ("base_frame", "joint_clearance")], ids=["analytic", "autograd"])
def test_compensation_converges(kr, effects):
    model = CalibrationModel(kr, list(effects))
    q_nom = random_poses(kr, 16, 40)
    targets = kr.fk(q_nom)
    thetas = torch.stack([random_theta(model, model.default_free(), 41 + z, scale=4.0) for z in range(3)])
    if effects:  # clearance: realistic size (tilt 1e-4 rad, shift 0.02 mm)
        thetas[:, -12:] = torch.tensor([1e-4, 0.02] * 6, dtype=torch.float64)
    zone = torch.arange(16) % 3
    comp = compensate(model, thetas, targets, q_nom, zone=zone)
    assert comp.converged.all() and comp.iterations.max() <= 6
    assert comp.residual_mm.norm(dim=-1).max() <= 1e-6
    for z in range(3):  # the calibrated model, evaluated independently, reaches the targets
        rows = (zone == z).nonzero().flatten()
        p = model.predict(thetas[z], make_context(kr, comp.q[rows]))
        assert (p - targets[rows]).norm(dim=-1).max() <= 1e-6
    assert comp.correction_rad.abs().max() < 0.05  # mm on a 3 m arm: small corrections


def test_nominal_inverse_and_errors(kr):
    q = random_poses(kr, 5, 50)
    t = kr.fk(q)
    ni = nominal_inverse(kr, t, q + 0.05)
    assert ni.converged.all()
    assert_close(kr.fk(ni.q), t, atol=1e-6, rtol=0)
    model = CalibrationModel(kr)
    with pytest.raises(InputError, match=r"targets: expected \(5, 3\) mm"):
        compensate(model, model.zeros(), t[:4], q)
    with pytest.raises(InputError, match="zone: indices must lie in 0..1"):
        compensate(model, torch.zeros(2, model.n_params, dtype=torch.float64), t, q, zone=[0, 1, 2, 0, 1])


def test_damped_zone_is_the_ridge_solution_and_hull_holds(noisy_zone):
    """damping mu > 0 around theta0: the LM solution is stationary for
    |r(x)|^2 + mu |D (x - theta0)|^2 (D: column norms at theta0), and the hull of its own
    map contains sampled refits."""
    model, data, fit = noisy_zone
    theta0 = fit.theta + 1e-4 * torch.sign(fit.theta) * fit.report.free  # a nearby prior
    mu = 0.3
    damped = identify_intervals(model, data, damping=mu, theta0=theta0)
    ctx = data.context(model.robot)
    D = model.jacobian(theta0, ctx).reshape(-1, model.n_params).norm(dim=0)
    x = damped.theta
    J = model.jacobian(x, ctx).reshape(-1, model.n_params)
    r = (data.center - model.predict(x, ctx)).reshape(-1)
    free = damped.report.free
    grad = (-J.T @ r + mu * D ** 2 * (x - theta0))[free]
    assert (grad.abs() / (D[free] * r.norm())).max() < 1e-6
    assert (x - theta0)[free].abs().max() > 0  # it did move
    assert damped.damping == mu and (damped.radius <= fit.radius + 1e-12).all()  # damping narrows
    g = torch.Generator().manual_seed(12)
    zones = []
    for _ in range(3):
        u = torch.sign(2 * torch.rand(data.center.shape, generator=g, dtype=torch.float64) - 1)
        e = data.center + u * data.radius
        zones.append(PoseIntervals(data.pose, data.q, e, e, data.count))
    for f in identify_zones(model, zones, damping=mu, theta0=theta0):
        assert hull(damped).contains(f.theta, atol=1e-3 * damped.radius + 1e-12).all()
    gcv = identify_zones(model, [data, data.subset(slice(0, 11))], damping="gcv_shared", theta0=theta0)
    assert gcv[0].damping == gcv[1].damping and gcv[0].damping >= 0  # one mu for zones of any size
    with pytest.raises(InputError, match="damping: expected a number >= 0, 'gcv' or 'gcv_shared'"):
        identify_intervals(model, data, damping="lots")


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not torch.cuda.is_available(), reason="no CUDA device"))])
def test_compensation_stays_on_device(kr, device):
    """Every tensor compensate builds lives on the robot's device (none is made on the CPU)."""
    robot = kr.to(device)
    model = CalibrationModel(robot)
    q_nom = random_poses(kr, 6, 60).to(device)
    theta = random_theta(CalibrationModel(kr), CalibrationModel(kr).default_free(), 61, scale=4.0).to(device)
    comp = compensate(model, theta, robot.fk(q_nom), q_nom)
    for t in (comp.q, comp.residual_mm, comp.iterations, comp.converged):
        assert t.device.type == device
    assert comp.converged.all()
    assert (model.predict(theta, make_context(robot, comp.q)) - robot.fk(q_nom)).norm(dim=-1).max() <= 1e-6
    ni = nominal_inverse(robot, robot.fk(q_nom), q_nom + 0.05)
    assert ni.q.device.type == device and ni.converged.all()
