"""The sweep on any robot: 7 joints with prismatic ones, clearance models from a robot file
or --clearance (torchcal.reliability.uncertainty, torchcal.reliability.sweep, torchcal sweep).

What is checked, and against what:

- clearance -> MD-H deviations against an explicit chain that inserts each moved joint
  axis as an exact rigid transform (matrix exponential) where the model puts it: before
  the rotation / translation of joints 2..n (seats on the link before; for a slide, a rod
  in two bushings), after Rz Tz(d + q) for a prismatic joint 1 (a carriage on a rail),
  after Rz(q) for a revolute joint 1. Agreement to second order (10x smaller clearances,
  ~100x smaller gap), on a 7-joint robot with a prismatic joint 1 and a prismatic joint 4;
- the sweep kernel (in-place outer recursion) against brute force: Robot.fk of every
  (point, sampled deviation set) pair, min / max per axis and of the distance;
- the sampled envelope inside the linearised hull (prismatic Jacobian) up to second order;
- the CLI: a "clearance" section in the robot file, --clearance FILE.json, the CSV's q of a
  prismatic joint in mm; no model -> one line naming --clearance, exit 2, nothing written.
"""

from __future__ import annotations

import json

import pytest
import torch

from torchcal import cli
from torchcal.errors import InputError
from torchcal.io.sweep_csv import read_sweep
from torchcal.reliability.sweep import sweep
from torchcal.reliability.uncertainty import ClearanceModel, sample_states, states_to_deviations
from torchcal.io.robot_file import robot_from_dict, robot_to_dict


def _j(typ, th, d, a, al, lo, hi, **kw):
    return {"type": typ, "theta_offset_deg": th, "d_mm": d, "a_mm": a, "alpha_deg": al,
            "lower": lo, "upper": hi, **kw}


# a lift (prismatic joint 1), shoulder, elbow, telescoping forearm (prismatic joint 4), wrist
ROBOT = {"name": "lift7", "joints": [
    _j("prismatic", 0, 400, 150, 0, 0, 800),
    _j("revolute", 0, 200, 400, -90, -170, 170),
    _j("revolute", 0, 0, 500, 90, -120, 60, beta_deg=0.0),
    _j("prismatic", 0, 300, 0, -90, 0, 400),
    _j("revolute", 0, 0, 0, 90, -170, 170),
    _j("revolute", 0, 0, 0, -90, -120, 120),
    _j("revolute", 0, 150, 0, 0, -350, 350)],
    "tool": [[1, 0, 0, 10], [0, 1, 0, -20], [0, 0, 1, 120], [0, 0, 0, 1]]}
CLEARANCE = {"radii_mm": [40.0] * 14, "clearance_mm": [0.03, 0.02] * 7,
             "bearing_length_mm": [150.0, 120.0, 100.0, 90.0, 80.0, 60.0, 50.0]}


@pytest.fixture(scope="module")
def robot():
    return robot_from_dict({**ROBOT, "clearance": CLEARANCE}, "test robot")


def _q(robot, m, g):
    lo, hi = robot.limits[:, 0], robot.limits[:, 1]
    return lo + (hi - lo) * torch.rand(m, robot.n, generator=g, dtype=torch.float64)


def _rot(axis, angle):
    T = torch.eye(4, dtype=torch.float64)
    c, s = torch.cos(angle), torch.sin(angle)
    i, k = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    T[i, i], T[i, k], T[k, i], T[k, k] = c, -s, s, c
    return T


def _trans(axis, v):
    T = torch.eye(4, dtype=torch.float64)
    T["xyz".index(axis), 3] = v
    return T


def _axis_motion(u1, u2, L):
    """Exact rigid motion taking the nominal axis (z, seats at z = -+L/2) through the seat
    offsets u1, u2 (mm): rotation exp(w^) with w x e_z = (u2 - u1) / L, then the shift."""
    t, d = (u1 + u2) / 2, (u2 - u1) / L
    W = torch.zeros(4, 4, dtype=torch.float64)
    w = torch.stack([-d[1], d[0], torch.zeros((), dtype=torch.float64)])
    W[0, 1], W[0, 2], W[1, 2] = -w[2], w[1], -w[0]
    W[:3, :3] = W[:3, :3] - W[:3, :3].T
    E = torch.linalg.matrix_exp(W)
    E[:2, 3] = t
    return E


def _explicit_tcp(robot, model, q, states):
    """TCP with every joint axis moved as an exact rigid body where the model puts it."""
    T = robot.base.clone()
    for j in range(robot.n):
        th, d, a, al, be = robot.table[j]
        pris = bool(robot.prismatic[j])
        E = _axis_motion(states[2 * j], states[2 * j + 1], model.bearing_length_mm[j])
        turn = _rot("z", th + (0 if pris else q[j]))
        slide = _trans("z", d + (q[j] if pris else 0))
        rest = _trans("x", a) @ _rot("x", al) @ _rot("y", be)
        if j == 0 and pris:  # carriage: seats ride with the slide
            T = T @ turn @ slide @ E @ rest
        elif j == 0:  # revolute joint 1: frame turning with q1
            T = T @ turn @ E @ slide @ rest
        else:  # seats on link j-1: before joint j's rotation / translation
            T = T @ E @ turn @ slide @ rest
    return (T @ robot.tool)[:3, 3]


def test_seat_centers_land_on_the_seat_offsets():
    """The rigid motion's definition: seat centers (0, 0, -+L/2) -> (u1, -L/2), (u2, L/2)."""
    u1, u2 = torch.tensor([0.02, -0.01], dtype=torch.float64), torch.tensor([-0.015, 0.025], dtype=torch.float64)
    E = _axis_motion(u1, u2, 100.0)
    for u, z in ((u1, -50.0), (u2, 50.0)):
        p = E @ torch.tensor([0.0, 0.0, z, 1.0], dtype=torch.float64)
        torch.testing.assert_close(p[:2], u, rtol=0, atol=1e-7)  # second order in the tilt


def test_clearance_map_on_prismatic_joints_is_first_order_exact(robot):
    model = ClearanceModel.defaults(robot)  # from the robot file's "clearance" section
    assert model.clearance_mm == tuple(CLEARANCE["clearance_mm"])
    g = torch.Generator().manual_seed(3)
    worst = {}
    for scale in (1.0, 0.1):
        gaps, sizes = [], []
        for q in _q(robot, 10, g):
            st = sample_states(model, 1, g)[0] * scale
            exact = _explicit_tcp(robot, model, q, st)
            lin = robot.fk(q, states_to_deviations(robot, model, st))
            gaps.append((lin - exact).norm().item())
            sizes.append((exact - robot.fk(q)).norm().item())
        worst[scale] = max(gaps)
        assert min(sizes) > 1e-3 * scale  # the clearance moves the TCP
        assert max(gaps) < 1e-3 * max(sizes)  # first order right
    assert worst[0.1] < 0.02 * worst[1.0]  # the rest is second order


def test_a_base_fixed_joint1_motion_would_not_be_constant(robot):
    """Why the carriage: a motion fixed in the base, pushed through the slide, changes with q1
    (the tilt times the travel), which no constant deviation set can reproduce."""
    model = ClearanceModel.defaults(robot)
    st = torch.zeros(14, 2, dtype=torch.float64)
    st[0], st[1] = torch.tensor([0.03, 0.0]), torch.tensor([-0.03, 0.0])  # pure tilt of the track
    E = _axis_motion(st[0], st[1], model.bearing_length_mm[0])
    q = _q(robot, 1, torch.Generator().manual_seed(0))[0]
    dev = states_to_deviations(robot, model, st)
    gaps = []
    for travel in (0.0, 800.0):
        qq = q.clone()
        qq[0] = travel
        fixed = (E @ torch.cat([robot.fk(qq), torch.ones(1, dtype=torch.float64)]))[:3]
        gaps.append((fixed - robot.fk(qq, dev)).norm().item())
    # tilt 4e-4 rad x 800 mm of travel = 0.32 mm between the two ends
    assert abs(gaps[1] - gaps[0]) > 0.2


def test_sweep_envelope_equals_brute_force_on_prismatic_robot(robot):
    g = torch.Generator().manual_seed(5)
    q = _q(robot, 9, g)
    dev = ClearanceModel.defaults(robot).sample(robot, 40, g)
    for chunk in (None, 7):
        r = sweep(robot, q, deviations=dev, include_nominal=False, chunk=chunk, linear=False)
        err = robot.fk(q[:, None], dev[None]) - robot.fk(q)[:, None]  # (9, 40, 3) brute force
        torch.testing.assert_close(r.err_lower, err.amin(1), rtol=0, atol=1e-9)
        torch.testing.assert_close(r.err_upper, err.amax(1), rtol=0, atol=1e-9)
        torch.testing.assert_close(r.dist_lower, err.norm(dim=-1).amin(1), rtol=0, atol=1e-9)
        torch.testing.assert_close(r.dist_upper, err.norm(dim=-1).amax(1), rtol=0, atol=1e-9)
        torch.testing.assert_close(r.positions, robot.fk(q))


def test_sweep_inside_linear_hull_on_prismatic_robot(robot):
    q = _q(robot, 12, torch.Generator().manual_seed(6))
    r = sweep(robot, q, n_samples=200, seed=1)
    # the hull through the prismatic Jacobian: the sampled envelope inside, up to 2nd order
    slack = 1e-3 * (r.lin_upper - r.lin_lower).abs().amax()
    assert bool((r.err_lower >= r.lin_lower - slack).all() and (r.err_upper <= r.lin_upper + slack).all())
    # and the hull is not loose by orders of magnitude (the box ignores correlations)
    assert bool(((r.err_upper - r.err_lower) > 0.1 * (r.lin_upper - r.lin_lower)).all())


def test_robot_file_clearance_round_trip_and_errors(robot):
    back = robot_from_dict(robot_to_dict(robot), "round trip")
    assert back.clearance == robot.clearance and back.clearance["mode"] == "contact"
    bad = [({**CLEARANCE, "bearing_length_mm": [100.0] * 6}, "clearance: bearing_length_mm: expected one length per joint \\(7\\), got 6"),
           ({**CLEARANCE, "clearance_mm": [0.01] * 13}, "clearance: ClearanceModel: expected 2n = 14"),
           ({**CLEARANCE, "clearance_mm": [-0.01] * 14}, "clearance: ClearanceModel.clearance_mm: must be >= 0"),
           ({**CLEARANCE, "gap": 1}, "clearance: unknown key\\(s\\) gap"),
           ({"radii_mm": [1.0] * 14}, "clearance: missing key 'clearance_mm'"),
           ({**CLEARANCE, "clearance_mm": "0.01"}, "clearance: clearance_mm: expected a list of numbers")]
    for sec, msg in bad:
        with pytest.raises(InputError, match=msg):
            robot_from_dict({**ROBOT, "clearance": sec}, "r.json")
    # radii are informative and may be left out
    no_radii = {k: v for k, v in CLEARANCE.items() if k != "radii_mm"}
    assert ClearanceModel.defaults(robot_from_dict({**ROBOT, "clearance": no_radii})).clearance_mm \
        == tuple(CLEARANCE["clearance_mm"])


def _one_line(err):
    return err.count("\n") == 1


def test_cli_sweep_on_a_robot_file(tmp_path, capsys):
    plain = tmp_path / "lift7.json"
    plain.write_text(json.dumps(ROBOT))
    with_cl = tmp_path / "lift7_cl.json"
    with_cl.write_text(json.dumps({**ROBOT, "clearance": CLEARANCE}))
    cl = tmp_path / "cl.json"
    cl.write_text(json.dumps(CLEARANCE))
    # no clearance model: one line naming the option, exit 2, nothing written
    out = tmp_path / "s0.csv"
    assert cli.main(["sweep", "--robot", str(plain), "--n", "5", "--samples", "10", "--out", str(out),
                     "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert _one_line(err) and "--clearance" in err and "'lift7'" in err and not out.exists()
    # the section in the robot file and the same model as --clearance give the same CSV
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    assert cli.main(["sweep", "--robot", str(with_cl), "--n", "12", "--samples", "30", "--seed", "2",
                     "--out", str(a), "--no-progress"]) == 0
    assert cli.main(["sweep", "--robot", str(plain), "--clearance", str(cl), "--n", "12", "--samples", "30",
                     "--seed", "2", "--out", str(b), "--no-progress"]) == 0
    assert "R_set min" in capsys.readouterr().out
    assert a.read_text() == b.read_text()
    # q of a prismatic joint is mm in the CSV (inside its mm limits), revolute ones degrees
    res = read_sweep(a, prismatic=[True, False, False, True, False, False, False])
    assert res.q.shape == (12, 7)
    r = robot_from_dict(ROBOT)
    assert bool(r.within_limits(res.q).all())
    torch.testing.assert_close(r.fk(res.q), res.positions, rtol=0, atol=1e-6)
    # a bad --clearance file: one line naming it
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({**CLEARANCE, "bearing_length_mm": [1.0] * 3}))
    assert cli.main(["sweep", "--robot", str(plain), "--clearance", str(bad), "--n", "5",
                     "--out", str(tmp_path / "c.csv"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert _one_line(err) and "bad.json" in err and "bearing_length_mm" in err


def test_coincident_axes_are_refused():
    """A lift and a rotation about the same line (parallel, a = 0): a sideways shift of the
    second axis has no MD-H deviation; refused with one line, not mapped wrongly."""
    joints = [dict(ROBOT["joints"][0], a_mm=0)] + ROBOT["joints"][1:]
    r = robot_from_dict({**ROBOT, "joints": joints, "clearance": CLEARANCE})
    with pytest.raises(InputError, match="joint 1's axis has no MD-H deviation of link 1 \\(axes 1 and 2 coincide"):
        ClearanceModel.defaults(r).sample(r, 3)


def test_simulated_clearance_takes_the_robot_files_model(robot):
    """VirtualRobot's joint_clearance: the tilt of the robot file's clearance section, (c1 + c2) / L."""
    from torchcal.simulation.virtual_robot import VirtualRobot

    vr = VirtualRobot(robot, ["joint_clearance:2,5"], seed=0)
    for j in (2, 5):
        c = CLEARANCE["clearance_mm"][2 * j - 2] + CLEARANCE["clearance_mm"][2 * j - 1]
        assert vr.clearance_tilt_max[j] == pytest.approx(c / CLEARANCE["bearing_length_mm"][j - 1], rel=1e-12)
