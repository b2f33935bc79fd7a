"""The physics real arms show: cross_coupling, gear_transmission, axis_tilt,
base_compliance, link_bending.

Each effect: its value against an independent reference (numpy or a hand computation on
a simple pose), every analytic Jacobian companion against torch.func.jacfwd of its hook,
p = 0 does nothing, and `discover` names it on simulated data where it is hidden
(kr1000titan, 120 poses, 0.3 mm RMS effect, hidden MD-H errors, 0.02 mm noise) and names
none of them on data without them.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import torch

import torchcal
from torchcal.calibration.model import CalibrationModel
from torchcal.cli import main
from torchcal.diagnosis.diagnose import discover
from torchcal.effects import build, make_context
from torchcal.effects.axis_tilt import reference_moment_mm
from torchcal.errors import InputError
from torchcal.robots.poses import random_poses
from torchcal.robots.robot import Robot
from torchcal.io.robot_file import robot_from_dict, robot_to_dict
from torchcal.simulation.virtual_robot import VirtualRobot

RATIOS = (220.0, 220.0, 180.0, 120.0, 120.0, 90.0)
TITAN = dataclasses.replace(torchcal.robot("kr1000titan"), gear_ratio=RATIOS)
UR5E = dataclasses.replace(torchcal.robot("ur5e"), gear_ratio=(101.0,) * 6)
NEW = ("cross_coupling", "gear_transmission", "axis_tilt", "base_compliance", "link_bending")
SPECS = ["cross_coupling:3,5", "gear_transmission:2,4", "axis_tilt:2,4", "base_compliance", "link_bending:2,4"]


def _ctx(robot, n=9, seed=0):
    q = random_poses(robot, n, torch.Generator().manual_seed(seed))
    payload = torch.rand(n, generator=torch.Generator().manual_seed(seed + 1), dtype=torch.float64) * robot.payload_kg
    return make_context(robot, q, payload)


def _planar(alpha1_deg=0.0, tool_x=0.0) -> Robot:
    """Two revolute joints, links of 1000 mm along x; joint 1 vertical; payload 1 kg."""
    table = torch.tensor([[0, 0, 1000, math.radians(alpha1_deg), 0], [0, 0, 1000, 0, 0]], dtype=torch.float64)
    tool = torch.eye(4, dtype=torch.float64)
    tool[0, 3] = tool_x
    lim = torch.tensor([[-3.0, 3.0]] * 2, dtype=torch.float64)
    return Robot("planar", table, torch.zeros(2, dtype=torch.bool), lim, tool=tool, payload_kg=1.0)


# -- companions and p = 0 ---------------------------------------------------------------
@pytest.mark.parametrize("robot", [TITAN, UR5E], ids=["kr1000titan", "ur5e"])
@pytest.mark.parametrize("spec", SPECS)
def test_every_companion_matches_jacfwd_of_its_hook_and_zero_does_nothing(spec, robot):
    e = build(spec, robot)
    ctx = _ctx(robot)
    v = robot.fk(ctx.q)
    p = 1e-3 * torch.randn(e.n_params, generator=torch.Generator().manual_seed(5), dtype=torch.float64)
    used = 0
    for hook in ("joint_offset", "geometric_offset", "displacement"):
        args = (ctx, v) if hook == "displacement" else (ctx,)
        f = getattr(e, hook)
        if f(p, *args) is None:
            continue
        used += 1
        assert float(f(torch.zeros_like(p), *args).abs().max()) == 0.0
        J = getattr(e, hook + "_jacobian")(p, *args)
        Jp = torch.func.jacfwd(lambda pp: f(pp, *args))(p)
        if hook == "displacement":
            dp, dv = J
            torch.testing.assert_close(dp, Jp, rtol=1e-12, atol=1e-12)
            Jv = torch.func.jacfwd(lambda vv: f(p, ctx, vv))(v)  # (N, 3, N, 3)
            torch.testing.assert_close(dv, torch.stack([Jv[i, :, i] for i in range(len(v))]), rtol=1e-12, atol=1e-12)
        else:
            torch.testing.assert_close(J, Jp, rtol=1e-12, atol=1e-12)
    assert used == 1
    model = CalibrationModel(robot, [spec])
    theta = model.zeros()
    assert torch.equal(model.predict(theta, ctx), CalibrationModel(robot, []).predict(theta[: 5 * robot.n], ctx))


# -- values against independent references ----------------------------------------------
def test_cross_coupling_against_numpy():
    e = build("cross_coupling:3,5", UR5E)
    assert e.param_names() == ["coupling_1_3", "coupling_2_3", "coupling_1_5", "coupling_2_5", "coupling_3_5",
                               "coupling_4_5"]
    ctx = _ctx(UR5E)
    p = np.array([1e-3, -2e-3, 3e-3, 4e-3, -5e-3, 6e-3])
    q = ctx.q.numpy()
    want = np.zeros_like(q)
    want[:, 2] = p[0] * q[:, 0] + p[1] * q[:, 1]
    want[:, 4] = p[2] * q[:, 0] + p[3] * q[:, 1] + p[4] * q[:, 2] + p[5] * q[:, 3]
    np.testing.assert_allclose(e.joint_offset(torch.tensor(p), ctx).numpy(), want, rtol=0, atol=1e-15)


def test_gear_transmission_against_numpy_at_the_reducer_ratio():
    e = build("gear_transmission:2,4", TITAN)
    ctx = _ctx(TITAN)
    p = np.arange(1, 9) * 1e-4
    q = ctx.q.numpy()
    want = np.zeros_like(q)
    for i, j in enumerate((2, 4)):
        x = RATIOS[j - 1] * q[:, j - 1]
        s1, c1, s2, c2 = p[4 * i:4 * i + 4]
        want[:, j - 1] = s1 * np.sin(x) + c1 * np.cos(x) + s2 * np.sin(2 * x) + c2 * np.cos(2 * x)
    np.testing.assert_allclose(e.joint_offset(torch.tensor(p), ctx).numpy(), want, rtol=0, atol=1e-14)


def _tilted_tcp_numpy(robot, ctx, joint, tilt, moment_only=False):
    """TCP after tilting everything beyond joint `joint`'s bearing (numpy, first principles):
    equal masses at link midpoints J..n, payload (in rated payloads) at the TCP, moment about
    o_{J-1}, normalised by the joint's reference moment; rotation tilt x (perpendicular
    part) about o_{J-1} (scipy)."""
    from scipy.spatial.transform import Rotation
    f = ctx.frames.numpy()
    o = f[:, :, :3, 3]
    n = robot.n
    g = robot.gravity.numpy()
    out = []
    for r in range(len(o)):
        piv = o[r, joint - 1]
        arm = sum(0.5 * (o[r, k - 1] + o[r, k]) - piv for k in range(joint, n + 1))
        arm = arm + ctx.payload_kg[r].item() / max(robot.payload_kg, 1.0) * (o[r, -1] - piv)
        M = np.cross(arm, g) / reference_moment_mm(robot, joint)
        z = f[r, joint - 1, :3, 2]
        w = tilt * (M - (M @ z) * z)
        if moment_only == "rotvec":
            out.append(w)
            continue
        if moment_only:
            out.append(np.linalg.norm(w))
            continue
        out.append(piv + Rotation.from_rotvec(w).apply(o[r, -1] - piv))
    return np.array(out)


@pytest.mark.parametrize("joint", [2, 4, 5])
def test_axis_tilt_rotates_the_arm_beyond_the_bearing_like_numpy(joint):
    from scipy.spatial.transform import Rotation
    robot = TITAN
    ctx = _ctx(robot)
    # rad at the reference moment, sized so the largest tilt is 1e-4 rad (joint 2 of a
    # planar arm and the wrist carry little perpendicular moment)
    tilt = 1e-4 / np.abs(_tilted_tcp_numpy(robot, ctx, joint, 1.0, moment_only=True)).max()
    model = CalibrationModel(robot, [f"axis_tilt:{joint}"])
    theta = model.zeros()
    theta[-1] = tilt
    got = model.predict(theta, ctx).numpy()
    want = _tilted_tcp_numpy(robot, ctx, joint, tilt)
    moved = np.linalg.norm(want - robot.fk(ctx.q).numpy(), axis=-1)
    assert moved.max() > 0.01  # mm: the check is not vacuous
    # the row's Rx(dalpha) Ry(dbeta) is the rotation vector to first order (relative
    # difference of the order of the angle, < 1e-4); a wrong pivot or axis is O(1)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-3 * moved.max())
    # measured orientations see it: the TCP frame turns by the same rotation
    w = _tilted_tcp_numpy(robot, ctx, joint, tilt, moment_only="rotvec")
    rot = model.predict_rotation(theta, ctx).numpy()
    rot0 = model.predict_rotation(model.zeros(), ctx).numpy()
    turn = Rotation.from_matrix(rot @ np.swapaxes(rot0, -1, -2)).as_rotvec()
    np.testing.assert_allclose(turn, w, rtol=0, atol=1e-3 * np.abs(w).max())


def test_base_compliance_by_hand_anisotropic_and_follows_q1():
    """Planar arm, links 1000 + 1000 mm along x at q = 0, no payload: moment about the
    base (2000, 0, 0) x (0, 0, -1) = (0, 2000, 0), M_ref = (2 / 2 + 1) x 2000, so
    m = (0, 0.5, 0); the TCP (2000, 0, 0) drops by 1000 k_y. At q1 = 90 deg it drops by
    1000 k_x."""
    robot = _planar()
    kx, ky = 1e-4, 3e-4
    ctx = make_context(robot, torch.tensor([[0.0, 0.0], [math.pi / 2, 0.0]], dtype=torch.float64))
    v = robot.fk(ctx.q)
    dv = build("base_compliance", robot).displacement(torch.tensor([kx, ky], dtype=torch.float64), ctx, v)
    torch.testing.assert_close(dv, torch.tensor([[0, 0, -1000 * ky], [0, 0, -1000 * kx]], dtype=torch.float64),
                               rtol=0, atol=1e-12)


def test_link_bending_by_hand_tip_sag_and_slope_follow_cos_of_inclination():
    """Link 2 (1000 mm) of a planar arm whose joint 2 axis is horizontal (alpha1 = 90 deg),
    a 500 mm tool along it. Horizontal link: tip drops b L = 1000 b, the slope 1.5 b turns
    the tool down by 750 b: 1750 b. Raised by 60 deg: the sag is cos 60 of that, along
    g_perp (perpendicular to the link, in its vertical plane)."""
    robot = _planar(alpha1_deg=90.0, tool_x=500.0)
    b = 2e-4
    q = torch.tensor([[0.0, 0.0], [0.0, math.radians(60)]], dtype=torch.float64)
    ctx = make_context(robot, q)
    v = robot.fk(ctx.q)
    dv = build("link_bending:2", robot).displacement(torch.tensor([b], dtype=torch.float64), ctx, v)
    u = (ctx.frames[1, 2, :3, 3] - ctx.frames[1, 1, :3, 3]) / 1000
    assert abs(float(u[2]) - math.sin(math.radians(60))) < 1e-12  # the link points 60 deg up
    g = torch.tensor([0, 0, -1.0], dtype=torch.float64)
    gp = g - (g @ u) * u  # |gp| = cos 60
    torch.testing.assert_close(dv[0], torch.tensor([0, 0, -1750 * b], dtype=torch.float64), rtol=0, atol=1e-12)
    torch.testing.assert_close(dv[1], 1750 * b * gp, rtol=0, atol=1e-12)
    assert abs(float(gp.norm()) - 0.5) < 1e-12


# -- refusals and the robot file ----------------------------------------------------------
def test_refusals_are_one_clear_line():
    with pytest.raises(InputError, match=r"gives no gear_ratio for joint\(s\) 2") as ei:
        build("gear_transmission:2", torchcal.robot("kr1000titan"))
    assert "\n" not in str(ei.value)
    with pytest.raises(InputError, match="base_compliance"):
        build("axis_tilt:1", TITAN)
    # all joints: those where the effect exists
    assert build("axis_tilt", TITAN).param_names() == [f"tilt_{j}" for j in range(2, 7)]
    assert build("cross_coupling:1,2", TITAN).param_names() == ["coupling_1_2"]
    assert build("link_bending", TITAN).param_names() == ["bend_1", "bend_2", "bend_3", "bend_4", "bend_6"]
    with pytest.raises(InputError, match="no joint before it"):
        build("cross_coupling:1", TITAN)
    with pytest.raises(InputError, match="without length"):
        build("link_bending:5", TITAN)  # kr1000titan's wrist axes intersect


def test_robot_file_gear_ratio_round_trip_and_errors():
    obj = robot_to_dict(TITAN)
    assert obj["gear_ratio"] == list(RATIOS)
    back = robot_from_dict(json.loads(json.dumps(obj)))
    assert back.gear_ratio == RATIOS and back == TITAN
    obj["gear_ratio"] = [100, None, 80, 50, 50, 50]
    r = robot_from_dict(obj)
    assert r.gear_ratio[1] is None and build("gear_transmission:1", r).ratios == (100.0,)
    with pytest.raises(InputError, match="joint\\(s\\) 2"):
        build("gear_transmission:2", r)
    for bad, msg in (([1, 2], "list of 6"), ([100, 0, 1, 1, 1, 1], r"gear_ratio\[2\]: expected a ratio > 0"),
                     ([100, "x", 1, 1, 1, 1], r"gear_ratio\[2\]: expected a finite number")):
        obj["gear_ratio"] = bad
        with pytest.raises(InputError, match=msg):
            robot_from_dict(obj, "r.json")
    assert "gear_ratio" not in robot_to_dict(torchcal.robot("kr1000titan"))


def test_simulate_cli_builds_the_new_effects_and_refuses_without_ratio(tmp_path, capsys):
    robot_file = tmp_path / "titan.json"
    robot_file.write_text(json.dumps(robot_to_dict(TITAN)))
    out = tmp_path / "d.csv"
    assert main(["simulate", "--robot", str(robot_file), "--effects", "gear_transmission:2", "base_compliance",
                 "--n", "10", "--seed", "1", "--out", str(out)]) == 0
    assert out.is_file()
    capsys.readouterr()
    bad = tmp_path / "e.csv"
    assert main(["simulate", "--robot", "kr1000titan", "--effects", "gear_transmission:2", "--n", "10",
                 "--out", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "gear_ratio" in err and err.count("\n") == 1 and not bad.exists()


# -- discover -----------------------------------------------------------------------------
def _session(hidden, seed, n=120):
    vr = VirtualRobot(TITAN, hidden, seed=seed)
    return vr.measure(random_poses(TITAN, n, torch.Generator().manual_seed(seed + 100)), noise_mm=0.02)


@pytest.mark.parametrize("spec", ["cross_coupling:3", "gear_transmission:2", "axis_tilt:4", "base_compliance",
                                  "link_bending:2", "link_bending:4"])
def test_discover_names_the_hidden_effect(spec):
    d = discover(TITAN, _session([spec], seed=1), report_rest=False)
    assert d.final_effects == [spec], d.history
    assert d.absorbing == [], d.stability  # named as physics, not as an absorber
    assert d.history[-1]["cv_rms_mm"] < 1.25 * 0.02 * math.sqrt(3) < d.history[0]["cv_rms_mm"] / 2


@pytest.mark.parametrize("hidden", [[], ["joint_compliance:2"], ["joint_compliance:3"], ["gear_periodic:2"],
                                    ["backlash:2", "encoder_scale:3"], ["thermal_expansion"]])
def test_discover_names_none_of_them_without_them(hidden):
    d = discover(TITAN, _session(hidden, seed=2), report_rest=False)
    assert not [e for e in d.final_effects if e.split(":")[0] in NEW], d.history
    assert sorted(d.final_effects) == sorted(hidden)
    assert d.absorbing == [], d.stability
