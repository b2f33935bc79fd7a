"""Each physical effect's signature (torchcal.effects), through its hooks or the model.

- compliance: deflection grows with the payload and vanishes without gravity load;
  params_from_physics equals a direct gravity-torque computation;
- backlash flips with the approach direction (from the row order);
- thermal expansion scales linearly with temp_c - 20;
- gear error is periodic in its joint and varies within a revolution;
- encoder scale is proportional to q;
- base_frame rotates and translates, tool_offset moves the TCP in the flange frame;
- clearance: repeated moves to one pose spread, within tilt x lever (+ noise);
- names/units match n_params; the model is differentiable with every effect.
"""

import dataclasses
import math

import numpy as np
import pytest
import torch
from torch.testing import assert_close

import torchcal
from torchcal.effects import REGISTRY, build, make_context
from torchcal.effects.context import approach_directions
from torchcal.effects.joint_clearance import load_directions
from torchcal.effects.joint_compliance import G_NM_PER_KG_MM, JointCompliance
from torchcal.errors import InputError
from torchcal.calibration.model import CalibrationModel
from torchcal.io.robot_file import robot
from torchcal.simulation.virtual_robot import VirtualRobot, default_masses, random_poses

DEG = math.pi / 180


def predict_with(model, ctx, spec_index, p):
    """TCP positions with the effect `spec_index` at p and everything else at zero."""
    theta = model.zeros()
    theta[model.slices[1 + spec_index]] = torch.as_tensor(p, dtype=theta.dtype)
    return model.predict(theta, ctx)


# -- joint_compliance ----------------------------------------------------------------------

def test_compliance_grows_with_payload(kr):
    """Same pose, payload 0 .. rated: the joint offsets are affine in the payload, their
    slope has the sign of the payload's gravity torque, and (arm stretched out
    horizontally, where link and payload torques agree) the TCP deflection grows."""
    masses, coms = default_masses(kr)
    p = JointCompliance.params_from_physics(kr, (2, 3), masses, coms, torch.full((6,), 1e9))
    q = torch.tensor([[0.0, 0.0, 90 * DEG, 0.0, 30 * DEG, 0.0]]).repeat(6, 1)  # stretched out
    payload = torch.linspace(0, kr.payload_kg, 6)
    ctx = make_context(kr, q, payload)
    eff = build("joint_compliance:2,3", kr)
    off = eff.joint_offset(p, ctx)[:, [1, 2]]  # (6, 2) rad
    steps = off.diff(dim=0)
    assert_close(steps, steps[:1].expand_as(steps), atol=1e-15, rtol=1e-9)  # affine
    assert (steps.abs() > 0).all()
    model = CalibrationModel(kr, [eff])
    defl = (predict_with(model, ctx, 0, p) - model.predict(model.zeros(), ctx)).norm(dim=-1)
    assert (defl.diff() > 0).all(), defl
    assert defl[-1] > 2 * defl[0]


def test_compliance_monotone_in_payload_everywhere(kr):
    """Only the payload loaded (no link masses): deflection proportional to payload_kg."""
    masses, coms = torch.zeros(6), torch.zeros(6, 3)
    p = JointCompliance.params_from_physics(kr, (2, 3, 5), masses, coms, torch.full((6,), 1e9))
    q = random_poses(kr, 5, 0)
    eff = build("joint_compliance:2,3,5", kr)
    offs = [eff.joint_offset(p, make_context(kr, q, torch.full((5,), m))) for m in (0.0, 250.0, 1000.0)]
    assert offs[0].abs().max() == 0
    assert_close(offs[2], 4 * offs[1], rtol=1e-12, atol=0)
    assert offs[2].abs().max() > 0


def test_compliance_vanishes_without_gravity_load(kr):
    """Gravity along joint 1's axis (the default: base z up, g = -z) loads joint 1 with
    no torque, whatever the masses; tilt the gravity and it is loaded. Zero masses and
    zero payload: no deflection at any joint."""
    masses, coms = default_masses(kr)
    q = random_poses(kr, 8, 1)
    payload = torch.linspace(0, 1000, 8)
    eff = build("joint_compliance:1", kr)
    p = JointCompliance.params_from_physics(kr, (1,), masses, coms, torch.full((6,), 1e9))
    assert eff.joint_offset(p, make_context(kr, q, payload)).abs().max() < 1e-18
    tilted = dataclasses.replace(kr, gravity=torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))
    assert eff.joint_offset(p, make_context(tilted, q, payload)).abs().max() > 1e-9

    all_j = build("joint_compliance", kr)
    p0 = JointCompliance.params_from_physics(kr, range(1, 7), torch.zeros(6), coms, torch.full((6,), 1e9))
    assert all_j.joint_offset(p0, make_context(kr, q)).abs().max() == 0


def test_compliance_params_from_physics_matches_direct_torque(kr):
    """p from physics through the regressor == G tau_J / K_J with
    tau_J = sum_k m_k ((c_k,world - o_J) x g) . z_J + m_payload ((tcp - o_J) x g) . z_J."""
    gen = torch.Generator().manual_seed(3)
    masses = 10 + 100 * torch.rand(6, generator=gen, dtype=torch.float64)
    coms = 300 * torch.randn(6, 3, generator=gen, dtype=torch.float64)
    stiff = 1e6 * (1 + torch.rand(6, generator=gen, dtype=torch.float64))
    q = random_poses(kr, 4, 7)
    payload = torch.tensor([0.0, 100.0, 500.0, 1000.0], dtype=torch.float64)
    tilted = dataclasses.replace(kr, gravity=torch.nn.functional.normalize(
        torch.tensor([0.3, -0.2, -1.0], dtype=torch.float64), dim=0))
    for r in (kr, tilted):
        ctx = make_context(r, q, payload)
        f, g = ctx.frames, ctx.gravity
        for joints in ((1,), (2, 3), (4, 5, 6)):
            p = JointCompliance.params_from_physics(r, joints, masses, coms, stiff)
            off = build(f"joint_compliance:{','.join(map(str, joints))}", r).joint_offset(p, ctx)
            for j in joints:
                z, o = f[:, j - 1, :3, 2], f[:, j - 1, :3, 3]
                tau = torch.zeros(4, dtype=torch.float64)
                for k in range(j, 7):
                    c_world = (f[:, k, :3, :3] @ coms[k - 1]) + f[:, k, :3, 3]
                    tau += masses[k - 1] * (torch.linalg.cross(c_world - o, g.expand_as(z)) * z).sum(-1)
                tcp = f[:, -1, :3, 3]
                tau += payload * (torch.linalg.cross(tcp - o, g.expand_as(z)) * z).sum(-1)
                assert_close(off[:, j - 1], G_NM_PER_KG_MM * tau / stiff[j - 1], rtol=1e-10, atol=1e-18)
            others = [i for i in range(6) if i + 1 not in joints]
            assert off[:, others].abs().max() == 0


# -- backlash ------------------------------------------------------------------------------

def test_backlash_flips_with_approach_direction(kr):
    """Joint 2 goes up 0.1 -> 0.3 then down to 0.1; joint 4 goes down then stays: the
    offset at one angle is +b/2 coming from below and -b/2 coming from above."""
    up_down = torch.tensor([0.1, 0.2, 0.3, 0.2, 0.1, 0.1])
    q = torch.zeros(6, 6, dtype=torch.float64)
    q[:, 1] = up_down
    q[:, 3] = torch.tensor([-0.1, -0.2, -0.2, -0.2, -0.2, -0.2])
    ctx = make_context(kr, q)
    expect_2 = torch.tensor([1.0, 1, 1, -1, -1, -1], dtype=torch.float64)  # last row: no move, keeps -1
    assert_close(ctx.approach[:, 1], expect_2)
    assert_close(ctx.approach[:, 3], -torch.ones(6, dtype=torch.float64))
    assert_close(ctx.approach[:, 0], torch.ones(6, dtype=torch.float64))  # never moved: +1
    assert_close(approach_directions(q), ctx.approach)
    b = torch.tensor([2e-3, 1e-3], dtype=torch.float64)
    off = build("backlash:2,4", kr).joint_offset(b, ctx)
    assert_close(off[:, 1], expect_2 * 1e-3)
    assert_close(off[1, 1], -off[3, 1])  # q2 = 0.2 on the way up vs. on the way down
    assert_close(off[0, 1], -off[4, 1])  # q2 = 0.1
    assert_close(off[:, 3], -0.5e-3 * torch.ones(6, dtype=torch.float64))
    assert off[:, [0, 2, 4, 5]].abs().max() == 0
    # the TCP lands at different places for the same command from the two sides
    model = CalibrationModel(kr, ["backlash:2,4"])
    v = predict_with(model, ctx, 0, b)
    assert (v[1] - v[3]).norm() > 1.0  # ~ 2e-3 rad x 1.4..2.6 m of lever


def _approach_loop(q, q_prev=None):
    """Plain-numpy reference: row by row, the sign of the move, the last one carried."""
    q = np.asarray(q)
    prev = np.vstack([np.zeros_like(q[:1]), q[:-1]]) if q_prev is None else np.asarray(q_prev)
    out, last = np.empty_like(q), np.ones(q.shape[1])
    for i in range(q.shape[0]):
        s = np.sign(q[i] - prev[i])
        last = np.where(s != 0, s, last)
        out[i] = last
    return out


@pytest.mark.parametrize("with_prev", [False, True])
def test_approach_directions_match_a_row_by_row_loop(with_prev):
    """The vectorised carry (running max of the last moving row) is the row loop's answer,
    on steps that often repeat an angle (no move) so the carry matters."""
    g = np.random.default_rng(3)
    q = g.integers(-2, 3, size=(300, 6)) * 0.1
    q_prev = g.integers(-2, 3, size=(300, 6)) * 0.1 if with_prev else None
    got = approach_directions(torch.as_tensor(q), None if q_prev is None else torch.as_tensor(q_prev))
    assert np.array_equal(got.numpy(), _approach_loop(q, q_prev))
    assert approach_directions(torch.zeros(0, 6, dtype=torch.float64)).shape == (0, 6)


# -- thermal_expansion --------------------------------------------------------------------


def test_thermal_expansion_linear_in_temperature(kr):
    q = random_poses(kr, 3, 2).repeat_interleave(4, dim=0)
    temp = torch.tensor([20.0, 25.0, 30.0, 40.0], dtype=torch.float64).repeat(3)
    ctx = make_context(kr, q, temp_c=temp)
    model = CalibrationModel(kr, ["thermal_expansion"])
    disp = (predict_with(model, ctx, 0, [1.2e-5]) - model.predict(model.zeros(), ctx)).view(3, 4, 3)
    assert disp[:, 0].abs().max() < 1e-9  # reference temperature: no change
    dt = torch.tensor([0.0, 5.0, 10.0, 20.0], dtype=torch.float64)
    per_k = disp[:, 1:] / dt[1:, None]
    assert_close(per_k, per_k[:, :1].expand_as(per_k), rtol=1e-6, atol=1e-12)
    nominal = kr.fk(q.view(3, 4, 6)[:, 0])
    assert_close(per_k[:, 0], 1.2e-5 * nominal, rtol=1e-6, atol=1e-12)  # scales about the base
    with pytest.raises(InputError, match="temp_c"):
        model.check_context(make_context(kr, q))


# -- gear_periodic ------------------------------------------------------------------------

def test_gear_periodic_in_its_joint(kr):
    eff = build("gear_periodic:4", kr)
    p = torch.randn(eff.n_params, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 1e-4
    q = random_poses(kr, 16, 4)
    shifted = q.clone()
    shifted[:, 3] += 2 * math.pi
    other = q.clone()
    other[:, [0, 1, 2, 4, 5]] = random_poses(kr, 16, 5)[:, [0, 1, 2, 4, 5]]  # other joints move
    a = eff.joint_offset(p, make_context(kr, q))
    assert_close(eff.joint_offset(p, make_context(kr, shifted)), a, rtol=0, atol=1e-15)
    assert_close(eff.joint_offset(p, make_context(kr, other)), a, rtol=0, atol=0)
    assert a[:, 3].std() > 1e-5  # varies within a revolution
    assert a[:, [0, 1, 2, 4, 5]].abs().max() == 0
    # harmonic 2 alone: period pi
    p2 = torch.zeros_like(p)
    p2[eff.param_names().index("gear_4_sin2")] = 1e-4
    half = q.clone()
    half[:, 3] += math.pi
    assert_close(eff.joint_offset(p2, make_context(kr, half)), eff.joint_offset(p2, make_context(kr, q)),
                 rtol=0, atol=1e-15)


# -- encoder_scale ------------------------------------------------------------------------

def test_encoder_scale_proportional_to_q(kr):
    eff = build("encoder_scale:1,3", kr)
    p = torch.tensor([1e-3, -2e-3], dtype=torch.float64)
    q = random_poses(kr, 6, 6)
    off = eff.joint_offset(p, make_context(kr, q))
    assert_close(off[:, 0], 1e-3 * q[:, 0])
    assert_close(off[:, 2], -2e-3 * q[:, 2])
    assert off[:, [1, 3, 4, 5]].abs().max() == 0
    assert_close(eff.joint_offset(p, make_context(kr, 2 * q)), 2 * off)


# -- base_frame / tool_offset -------------------------------------------------------------

def test_base_frame_translation_and_rotation(kr):
    q = random_poses(kr, 5, 8)
    ctx = make_context(kr, q)
    model = CalibrationModel(kr, ["base_frame"])
    v = model.predict(model.zeros(), ctx)
    assert_close(predict_with(model, ctx, 0, [1.0, -2.0, 3.0, 0, 0, 0]), v + torch.tensor([1.0, -2.0, 3.0]))
    rz = predict_with(model, ctx, 0, [0, 0, 0, 0, 0, math.pi / 2])  # x -> y, y -> -x
    assert_close(rz, torch.stack([-v[:, 1], v[:, 0], v[:, 2]], -1))
    rx = predict_with(model, ctx, 0, [10.0, 0, 0, math.pi, 0, 0])  # y -> -y, z -> -z, then +10 x
    assert_close(rx, torch.stack([v[:, 0] + 10, -v[:, 1], -v[:, 2]], -1))
    r = torch.tensor([0.3, -0.2, 0.5], dtype=torch.float64)  # a rotation vector: exp([r]x)
    skew = torch.tensor([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]], dtype=torch.float64)
    general = predict_with(model, ctx, 0, [1.0, 2.0, 3.0, *r.tolist()])
    assert_close(general, v @ torch.linalg.matrix_exp(skew).T + torch.tensor([1.0, 2.0, 3.0]))


def test_tool_offset_moves_tcp_in_flange_frame(kr):
    q = random_poses(kr, 5, 9)
    ctx = make_context(kr, q)
    model = CalibrationModel(kr, ["tool_offset"])
    t = torch.tensor([5.0, -3.0, 20.0], dtype=torch.float64)
    disp = predict_with(model, ctx, 0, t) - model.predict(model.zeros(), ctx)
    flange_R = ctx.frames[:, -1, :3, :3]  # tool frame is the flange (identity tool)
    assert_close(disp, flange_R @ t)


# -- joint_clearance ----------------------------------------------------------------------

def test_clearance_spread_within_what_the_clearances_allow(kr):
    """One pose, 20 repeated moves, no noise: the positions spread, and each lies within
    sum_j |tilt_j| x share x |TCP - o_j| of the mean (load-driven) position."""
    vr = VirtualRobot(kr, ["joint_clearance:2,3"], seed=1, clearance_random=0.5)
    q0 = random_poses(kr, 1, 11)
    q = torch.cat([q0, random_poses(kr, 1, 12)])  # a neighbour, so moves alternate between two poses
    m = vr.measure(q, repeats=20, noise_mm=0.0)
    at0 = m.pose == 0
    xyz = m.xyz[at0]
    mean = vr.positions(m.q, m.payload_kg)[at0]  # seed=None: the load-driven mean
    dev = (xyz - mean).norm(dim=-1)
    ctx = make_context(kr, m.q[at0], m.payload_kg[at0])
    sl = vr.model.slices[1]
    tilts = vr.theta[sl][0::2].abs()
    share = vr.clearance_random / (1 - vr.clearance_random)
    bound = sum(t * share * (mean - load_directions(ctx, j)[3]).norm(dim=-1) for j, t in zip((2, 3), tilts))
    assert xyz.std(dim=0).norm() > 1e-3  # spreads
    assert (dev <= bound * (1 + 1e-6) + 1e-9).all(), (dev, bound)
    assert dev.max() > 0.2 * bound.max()  # and the spread uses a fair share of the room
    # with noise, the bound widens by the noise (4 sigma per axis)
    noisy = vr.measure(q, repeats=20, noise_mm=0.01)
    dev_n = (noisy.xyz[noisy.pose == 0] - mean).norm(dim=-1)
    assert (dev_n <= bound + 4 * 0.01 * math.sqrt(3)).all()


def test_clearance_deterministic_part_is_load_driven(kr):
    """The fit-role displacement: tilt about the perpendicular gravity moment and shift
    along the perpendicular gravity force; joint 1 (axis along gravity) gets no shift."""
    q = random_poses(kr, 6, 13)
    ctx = make_context(kr, q)
    eff = build("joint_clearance:1,2", kr)
    model = CalibrationModel(kr, [eff])
    v = model.predict(model.zeros(), ctx)
    shift = eff.displacement(torch.tensor([0.0, 1.0, 0.0, 0.0], dtype=torch.float64), ctx, v)
    assert shift.abs().max() < 1e-12  # joint 1: no perpendicular gravity force
    shift2 = eff.displacement(torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64), ctx, v)
    assert_close(shift2, torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64).expand_as(v), atol=2e-3, rtol=0)  # smooth unit: 1/sqrt(1 + 0.05^2)


# -- every effect ----------------------------------------------------------------------------

@pytest.mark.parametrize("name", sorted(REGISTRY))
@pytest.mark.parametrize("robot_name", ["kr1000titan", "ur5e"])
def test_names_units_match_n_params(name, robot_name):
    r = robot(robot_name)
    if name == "gear_transmission":  # needs the robot file's reducer ratios
        r = dataclasses.replace(r, gear_ratio=(100.0,) * r.n)
    specs = [name] if not REGISTRY[name].takes_joints else [name, f"{name}:2", f"{name}:1,4,6"]
    if name == "joint_periodic":  # orders per joint
        specs = [f"{name}:2@20", f"{name}:1@4+12,4@7,6@3+5+9"]
    for spec in specs:
        e = build(spec, r)
        names, units = e.param_names(), e.param_units()
        assert len(names) == len(units) == e.n_params > 0
        assert len(set(names)) == len(names)
        assert all(isinstance(u, str) and u for u in units)
        assert parse_back(e.spec(), r) == e.spec()


def parse_back(text, r):
    return build(text, r).spec()


def test_model_is_differentiable_with_every_effect(kr):
    specs = ["base_frame", "tool_offset", "joint_compliance:2,3", "gear_periodic:1", "backlash:2",
             "encoder_scale:3", "thermal_expansion", "joint_clearance:2,3"]
    model = CalibrationModel(kr, specs)
    q = random_poses(kr, 6, 14)
    ctx = make_context(kr, q, torch.linspace(0, 1000, 6), torch.linspace(20, 30, 6))
    theta = 1e-4 * torch.randn(model.n_params, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    J = model.jacobian(theta, ctx)
    assert J.shape == (6, 3, model.n_params)
    assert torch.isfinite(J).all()
    assert torch.isfinite(model.jacobian(model.zeros(), ctx)).all()  # where fits start (rotvec 0)
    # every effect has some parameter that moves the TCP
    for sl in model.slices[1:]:
        assert J[..., sl].abs().max() > 0
    # an independent reference: central differences of predict, every column
    # (steps that move the TCP by ~1e-4 mm: parameters in rad, mm and 1/K differ by 1e9)
    hs = 1e-4 / J.abs().amax((0, 1)).clamp_min(1.0)  # (P,)
    eye = torch.eye(model.n_params, dtype=torch.float64)
    fd = torch.stack([(model.predict(theta + h * e, ctx) - model.predict(theta - h * e, ctx)) / (2 * h)
                      for h, e in zip(hs, eye)], dim=-1)  # (6, 3, P)
    scale = J.abs().amax((0, 1)).clamp_min(1.0)  # (P,) per-column size, mm per unit
    assert_close(J / scale, fd / scale, rtol=0, atol=1e-5)


def test_a_periodic_basis_kept_per_context_follows_the_context_and_pickles(kr):
    """`per_context` (the joint-angle basis of joint_periodic / gear_periodic kept across a
    solve's evaluations): the offset of a second context is that context's, returning to
    the first gives the first's again, a context whose q requires grad keeps its graph
    (two backward passes), and a model that used it pickles (the cache is not state)."""
    import pickle

    model = CalibrationModel(kr, ["joint_periodic:2@3+5", "gear_periodic:4"])
    p = torch.randn(model.n_params, generator=torch.Generator().manual_seed(1), dtype=torch.float64) * 1e-4
    qa, qb = random_poses(kr, 12, 7), random_poses(kr, 12, 8)
    ca, cb = make_context(kr, qa), make_context(kr, qb)
    fresh = [CalibrationModel(kr, model.specs()).predict(p, c) for c in (ca, cb)]  # never cached before
    for c, ref in ((ca, fresh[0]), (cb, fresh[1]), (ca, fresh[0])):
        assert torch.equal(model.predict(p, c), ref)
    assert not torch.equal(fresh[0], fresh[1])
    qg = qa.clone().requires_grad_(True)
    cg = make_context(kr, qg)
    for _ in range(2):  # a kept graph would be freed by the first backward
        model.predict(p, cg).sum().backward()
    back = pickle.loads(pickle.dumps(model))
    assert torch.equal(back.predict(p, cb), fresh[1])


def test_a_single_tool_offset_refuses_data_of_several_points():
    """A model fitted on one reflector (one tool offset) given data of several point ids was
    applied silently, every reflector predicted with the one offset (evaluate, register);
    it is one InputError naming the ids. One id, or no point column, passes."""
    from torchcal.calibration.model import CalibrationModel
    from torchcal.effects import make_context
    from torchcal.errors import InputError

    robot = torchcal.robot("ur5e")
    model = CalibrationModel(robot, ["base_frame", "tool_offset"])  # one offset
    q = torch.zeros(4, robot.n, dtype=torch.float64)
    with pytest.raises(InputError, match=r"the data have 2 point ids \(1, 2\), but the model has one tool offset"):
        model.check_context(make_context(robot, q, point=torch.tensor([1, 1, 2, 2])))
    model.check_context(make_context(robot, q, point=torch.tensor([3, 3, 3, 3])))
    model.check_context(make_context(robot, q))


def test_a_base_frame_rotation_kept_per_value_follows_theta_changed_in_place(kr):
    """`per_value` (the base frame's rotation and its derivative, kept for the last rotation
    vector): theta changed in place after an evaluation gives the new positions, rotations
    and Jacobians (those of a model that never cached), forward-mode autodiff through the
    hook neither uses nor leaves a cached value, and a model that used it pickles without it."""
    import pickle

    model = CalibrationModel(kr, ["base_frame", "tool_offset"])
    ctx = make_context(kr, random_poses(kr, 10, 4))
    theta = model.zeros()
    theta[5 * kr.n:5 * kr.n + 6] = torch.tensor([10.0, -5.0, 3.0, 0.02, -0.01, 0.3], dtype=theta.dtype)

    def outputs(mod, th):
        return (mod.predict(th, ctx), mod.predict_rotation(th, ctx)) + tuple(mod.jacobians(th, ctx, rotation=True))

    first = outputs(model, theta)
    theta[5 * kr.n + 3:5 * kr.n + 6] += torch.tensor([0.05, 0.02, -0.1], dtype=theta.dtype)  # in place
    moved = outputs(model, theta)
    fresh = outputs(CalibrationModel(kr, model.specs()), theta)
    for a, b, c in zip(moved, fresh, first):
        assert torch.equal(a, b) and not torch.equal(a, c)
    J = torch.func.jacfwd(lambda t: model.predict(t, ctx))(theta + 1e-3)
    torch.testing.assert_close(J, CalibrationModel(kr, model.specs()).jacobian(theta + 1e-3, ctx), rtol=0, atol=1e-9)
    for a, b in zip(outputs(model, theta), fresh):
        assert torch.equal(a, b)
    back = pickle.loads(pickle.dumps(model))
    assert not any(k.startswith("_per_value_") for e in back.effects for k in vars(e))
    for a, b in zip(outputs(back, theta), fresh):
        assert torch.equal(a, b)


def test_clearance_directions_kept_per_context_are_those_of_the_context_at_hand(kr):
    """joint_clearance keeps its load directions for the last context: its displacement
    and Jacobian on contexts taken in turn (another context, then the first again) equal
    a fresh effect's, bit for bit, and differ between the contexts."""
    ctx1, ctx2 = (make_context(kr, random_poses(kr, 7, s)) for s in (21, 22))
    eff = build("joint_clearance:2,3", kr)
    p = torch.tensor([1e-3, 0.2, 2e-3, 0.1], dtype=torch.float64)
    v1, v2 = torch.full((7, 3), 500.0, dtype=torch.float64), torch.full((7, 3), 800.0, dtype=torch.float64)
    for ctx, v in ((ctx1, v1), (ctx2, v2), (ctx1, v1)):
        fresh = build("joint_clearance:2,3", kr)
        assert torch.equal(eff.displacement(p, ctx, v), fresh.displacement(p, ctx, v))
        for a, b in zip(eff.displacement_jacobian(p, ctx, v), fresh.displacement_jacobian(p, ctx, v)):
            assert torch.equal(a, b)
    assert not torch.equal(eff.displacement(p, ctx1, v1), eff.displacement(p, ctx2, v1))
