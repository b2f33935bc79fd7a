"""Analytic Jacobians against forward-mode autodiff (torch.func.jacfwd) of the same maps:
the MD-H kernel, every built-in effect's hook companions, the whole model (positions and
orientations), a prismatic robot, and the autodiff fallback of a user effect."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

import torchcal
from torchcal.calibration.rows import so3_error_jacobian as _so3_error_jacobian
from torchcal.rotations import so3_error as _so3_error
from torchcal.calibration.model import CalibrationModel
from torchcal.effects import build, make_context
from torchcal.effects.base import Effect
from torchcal.effects.registry import lookup
from torchcal.kinematics import mdh as K
from torchcal.robots.poses import random_poses
from torchcal.io.robot_file import load_robot_file

ROOT = Path(__file__).resolve().parents[1]
RTOL = 1e-9

BUILT_IN = ("backlash:1,3", "base_frame", "encoder_scale:2,5", "gear_periodic:1,2", "joint_clearance:2,3", "joint_periodic:2@5+17,4@3",
            "joint_compliance:2,3", "thermal_expansion", "tool_offset")


def assert_close(analytic, reference):
    """Equal to RTOL relative to the largest entry of the reference (columns of mm and
    of rad/mm differ by orders of magnitude, so a per-entry rtol would test nothing for
    the entries that are zero in exact arithmetic)."""
    assert analytic.shape == reference.shape
    scale = reference.abs().max().clamp_min(1e-300)
    err = (analytic - reference).abs().max() / scale
    assert err <= RTOL, f"relative error {float(err):.3g}"


def _context(robot, n_rows=40, seed=0, points=None):
    g = torch.Generator().manual_seed(seed)
    q = random_poses(robot, n_rows, g)
    payload = torch.rand(n_rows, generator=g, dtype=torch.float64) * 10
    temp = 15 + 10 * torch.rand(n_rows, generator=g, dtype=torch.float64)
    pt = None if points is None else torch.tensor(points)[torch.randint(len(points), (n_rows,), generator=g)]
    return make_context(robot, q, payload, temp, point=pt)


def _theta(model, seed=1, size=1e-2):
    """Non-zero parameters: every term of the chain rule is exercised."""
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(model.n_params, generator=g, dtype=torch.float64) * 2 - 1) * size


@pytest.fixture(scope="module")
def ur10():
    return load_robot_file(ROOT / "examples" / "ur10" / "ur10.json")


@pytest.fixture(scope="module")
def scara():
    return load_robot_file(ROOT / "examples" / "scara.json")


@pytest.mark.parametrize("name", ["kr1000titan", "ur10"])
def test_chain_jacobians_match_autodiff(name, ur10):
    robot = ur10 if name == "ur10" else torchcal.robot(name)
    ctx = _context(robot, 12)
    geo = (torch.rand(robot.n, 5, generator=torch.Generator().manual_seed(3), dtype=torch.float64) - 0.5) * 0.02
    chain, tp = robot.chain, torch.tensor([10.0, -20.0, 130.0], dtype=torch.float64)

    def pos(q, params, t):
        return K.positions(q, chain, params.reshape(robot.n, 5), tool_point=t)

    cj = K.chain_jacobians(ctx.q, chain, geo, tool_point=tp)
    assert_close(cj.position, pos(ctx.q, geo, tp))
    jq = torch.func.vmap(torch.func.jacfwd(lambda q: pos(q, geo, tp)))(ctx.q)
    assert_close(cj.dq, jq)
    jp = torch.func.jacfwd(lambda p: pos(ctx.q, p, tp))(geo.reshape(-1))
    assert_close(cj.dparams, jp)
    jt = torch.func.jacfwd(lambda t: pos(ctx.q, geo, t))(tp)
    assert_close(cj.rotation, jt)
    # angular velocity: dR/dx R^T = [w]x
    rot = lambda p: K.fk_pose(ctx.q, chain.flange, p.reshape(robot.n, 5))[..., :3, :3]  # noqa: E731
    dR = torch.func.jacfwd(rot)(geo.reshape(-1))  # (N, 3, 3, 5n)
    Om = torch.einsum("nijk,nlj->nkil", dR, rot(geo.reshape(-1)))
    assert_close(cj.wparams, torch.stack([Om[..., 2, 1], Om[..., 0, 2], Om[..., 1, 0]], dim=1))


@pytest.mark.parametrize("spec", BUILT_IN)
def test_effect_companions_match_autodiff(spec, ur10):
    points = (1, 2, 5) if spec == "tool_offset" else None
    ctx = _context(ur10, 30, points=points)
    model = CalibrationModel(ur10, [spec], points=points)
    e = model.effects[0]
    p = _theta(model, 2, 0.05)[model.slices[1]]
    v = torch.randn(ctx.n_rows, 3, generator=torch.Generator().manual_seed(4), dtype=torch.float64) * 500
    checked = 0
    for hook in ("joint_offset", "geometric_offset", "tool_point", "chain_scale", "world_rotation"):
        if getattr(e, hook)(p, ctx) is None:
            continue
        companion = getattr(type(e), hook + "_jacobian")
        assert companion is not getattr(Effect, hook + "_jacobian"), f"{spec}: {hook} has no analytic companion"
        ref = torch.func.jacfwd(lambda t: getattr(e, hook)(t, ctx))(p)
        assert_close(companion(e, p, ctx), ref)
        checked += 1
    for hook in ("displacement", "world"):
        if getattr(e, hook)(p, ctx, v) is None:
            continue
        companion = getattr(type(e), hook + "_jacobian")
        assert companion is not getattr(Effect, hook + "_jacobian"), f"{spec}: {hook} has no analytic companion"
        dp, dv = companion(e, p, ctx, v)
        assert_close(dp, torch.func.jacfwd(lambda t: getattr(e, hook)(t, ctx, v))(p))
        full = torch.func.jacfwd(lambda u: getattr(e, hook)(p, ctx, u))(v)  # (N, 3, N, 3)
        rows = torch.arange(ctx.n_rows)
        ref_dv = full[rows, :, rows, :]
        if dv is None:
            assert ref_dv.abs().max() == 0
        else:
            assert_close(dv, ref_dv)
        checked += 1
    assert checked >= 1


def test_base_frame_at_large_and_zero_rotation(ur10):
    """The Rodrigues derivative on both sides of its series switch."""
    e = build("base_frame", ur10)
    ctx = _context(ur10, 5)
    for r in ([0.0, 0.0, 0.0], [1e-9, -2e-9, 5e-10], [0.3, -1.2, 2.5]):
        p = torch.tensor([1.0, 2.0, 3.0] + r, dtype=torch.float64)
        ref = torch.func.jacfwd(lambda t: e.world_rotation(t, ctx))(p)
        assert_close(e.world_rotation_jacobian(p, ctx), ref)


def _all_effects_model(robot, points=None):
    specs = ["backlash:1,3", "encoder_scale:2,5", "gear_periodic:1,2", "joint_clearance:2,3", "joint_periodic:2@5+17,4@3",
             "joint_compliance:2,3", "thermal_expansion", "tool_offset", "base_frame"]
    return CalibrationModel(robot, specs, points=points)


@pytest.mark.parametrize("points", [None, (1, 2, 5)])
def test_model_jacobian_every_effect(ur10, points):
    model = _all_effects_model(ur10, points)
    ctx = _context(ur10, 25, points=points)
    theta = _theta(model)
    ref = torch.func.jacfwd(lambda t: model.predict(t, ctx))(theta)
    J, W = model.jacobians(theta, ctx, rotation=True)
    assert_close(J, ref)
    assert_close(model.jacobian(theta, ctx), ref)
    R = model.predict_rotation(theta, ctx)
    dR = torch.func.jacfwd(lambda t: model.predict_rotation(t, ctx))(theta)  # (N, 3, 3, P)
    Om = torch.einsum("nijk,nlj->nkil", dR, R)
    assert_close(W, torch.stack([Om[..., 2, 1], Om[..., 0, 2], Om[..., 1, 0]], dim=1))


def test_model_jacobian_kr1000_with_beta():
    robot = torchcal.robot("kr1000titan")
    model = CalibrationModel(robot, ["base_frame", "tool_offset", "joint_compliance:2"])
    ctx = _context(robot, 20)
    theta = _theta(model, 5)
    assert_close(model.jacobian(theta, ctx), torch.func.jacfwd(lambda t: model.predict(t, ctx))(theta))


def test_prismatic_robot(scara):
    specs = ["base_frame", "tool_offset", "encoder_scale:1,3", "backlash:2", "joint_clearance:1"]
    model = CalibrationModel(scara, specs)
    ctx = _context(scara, 30)
    theta = _theta(model, 6)
    J, W = model.jacobians(theta, ctx, rotation=True)
    assert_close(J, torch.func.jacfwd(lambda t: model.predict(t, ctx))(theta))
    R = model.predict_rotation(theta, ctx)
    dR = torch.func.jacfwd(lambda t: model.predict_rotation(t, ctx))(theta)
    Om = torch.einsum("nijk,nlj->nkil", dR, R)
    assert_close(W, torch.stack([Om[..., 2, 1], Om[..., 0, 2], Om[..., 1, 0]], dim=1))


class _UserEffect(Effect):
    """A user effect with no companions: every hook kind, nonlinear in p and v."""

    name = "test_user_effect"

    def param_names(self):
        return ["u0", "u1", "u2"]

    def param_units(self):
        return ["1", "1", "1"]

    def joint_offset(self, p, ctx):
        return torch.sin(ctx.q) * p[0] + p[1] ** 2

    def tool_point(self, p, ctx):
        return torch.stack([p[0], p[1] * p[2], p[2]])

    def chain_scale(self, p, ctx):
        return 1 + p[2] * torch.tanh(ctx.q[:, 0])

    def displacement(self, p, ctx, v):
        return p[0] * torch.sin(v / 300.0) + p[1] * v[:, [1, 2, 0]]

    def world(self, p, ctx, v):
        return v + p[2] * v.roll(1, dims=-1) * 1e-3


def test_user_effect_falls_back_to_autodiff_of_its_hooks(ur10):
    model = CalibrationModel(ur10, [build("base_frame", ur10), _UserEffect(ur10), build("tool_offset", ur10)])
    ctx = _context(ur10, 15)
    theta = _theta(model, 7, 0.05)
    assert_close(model.jacobian(theta, ctx), torch.func.jacfwd(lambda t: model.predict(t, ctx))(theta))


def test_so3_error_jacobian(ur10):
    model = CalibrationModel(ur10, ["base_frame", "encoder_scale:4"])
    ctx = _context(ur10, 10)
    theta = _theta(model, 8)
    Rm = model.predict_rotation(_theta(model, 9), ctx)
    ref = torch.func.jacfwd(lambda t: _so3_error(model.predict_rotation(t, ctx), Rm))(theta)
    Rp = model.predict_rotation(theta, ctx)
    assert_close(_so3_error_jacobian(Rp, Rm, model.rotation_jacobian(theta, ctx)), ref)


def test_lookup_sees_every_built_in():
    for spec in BUILT_IN:
        assert lookup(spec.split(":")[0]) is not None


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not torch.cuda.is_available(), reason="no CUDA device"))])
def test_model_jacobian_on_device(ur10, device):
    """The analytic Jacobian (positions and orientation) on the robot's device equals the
    CPU one and autodiff on that device; nothing falls back to the CPU."""
    points = (1, 2, 5)
    cpu_ctx = _context(ur10, 20, points=points)
    robot = ur10.to(device)
    ctx = make_context(robot, cpu_ctx.q.to(device), cpu_ctx.payload_kg.to(device), cpu_ctx.temp_c.to(device),
                       point=cpu_ctx.point.to(device))
    model, cpu_model = _all_effects_model(robot, points), _all_effects_model(ur10, points)
    theta = _theta(cpu_model)
    J, W = model.jacobians(theta.to(device), ctx, rotation=True)
    assert J.device.type == device and W.device.type == device
    Jc, Wc = cpu_model.jacobians(theta, cpu_ctx, rotation=True)
    assert_close(J.cpu(), Jc)
    assert_close(W.cpu(), Wc)
    ref = torch.func.jacfwd(lambda t: model.predict(t, ctx))(theta.to(device))
    assert_close(J, ref)


def _pose_models(ur10, scara):
    """(model, ctx, theta): every built-in effect (UR10), a KR 1000 with beta deviations, a
    prismatic SCARA, a user effect with every hook kind."""
    kr = torchcal.robot("kr1000titan")
    yield _all_effects_model(ur10, None), _context(ur10, 25), 0
    yield CalibrationModel(kr, ["base_frame", "tool_offset", "joint_compliance:2"]), _context(kr, 20), 5
    yield CalibrationModel(scara, ["base_frame", "tool_offset", "encoder_scale:1,3", "backlash:2"]), _context(scara, 30), 6
    yield (CalibrationModel(ur10, [build("base_frame", ur10), _UserEffect(ur10), build("tool_offset", ur10)]),
           _context(ur10, 15), 7)


def test_predict_pose_and_the_jacobians_position_are_predicts(ur10, scara):
    """One walk for positions and orientations (`predict_pose`) and the positions of the
    Jacobian's walk (`jacobians(position=True)`), against `predict` / `predict_rotation`
    (two walks, other orders of the products): equal to rounding; and a fit's rows give
    their residual with the Jacobian (`Rows.jacobian(residual=True)`) and by one walk
    as `Rows.residual` does by two."""
    from torchcal.calibration.rows import Rows

    for model, ctx, seed in _pose_models(ur10, scara):
        theta = _theta(model, seed, 0.05)
        v, R = model.predict_pose(theta, ctx)
        assert_close(v, model.predict(theta, ctx))
        assert_close(R, model.predict_rotation(theta, ctx))
        J, W, Rf, vj = model.jacobians(theta, ctx, rotation=True, frame=True, position=True)
        assert_close(vj, model.predict(theta, ctx))
        for rotation in (None, model.predict_rotation(_theta(model, seed + 1, 0.05), ctx)):
            xyz = model.predict(_theta(model, seed + 2, 0.05), ctx)
            rows = Rows(model, ctx, xyz, rotation, 2.0)
            if rotation is not None:
                rows = rows.with_tool_rotation(theta)
            ref = rows.residual(theta)
            Jr, r = rows.jacobian(theta, residual=True)
            assert torch.equal(Jr, rows.jacobian(theta))  # the same Jacobian either way
            assert torch.equal(Jr[:, :3], model.jacobian(theta, ctx))  # written into the rows' buffer
            assert_close(r, ref)
            assert_close(rows.residual(theta, walk_once=True), ref)
