"""Tests of the batched MD-H kinematics (torchcal.kinematics.mdh, torchcal.robots.robot).

What is checked, and against what:

- forward kinematics against pytorch-kinematics on a URDF of the same robot that the
  test writes from the MD-H table (URDF origins are parsed in float32, hence ~1e-3 mm),
  and against a float64 pytorch-kinematics chain built from the same frames (1e-9 mm);
- the analytic parameter and joint Jacobians against autograd (torch.func.jacrev, 1e-9
  relative in float64) and central finite differences;
- KR 1000 Titan TCP positions worked out by hand from docs/paper.md Table 1;
- consistency: fk == fk_pose translation == last frame, broadcasting == a loop,
  chunked == unchunked;
- bad input raises ValueError (InputError) naming what was expected; dtype and device
  are kept.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

import torchcal
from torchcal.kinematics import mdh as K
from torchcal.errors import InputError
from tests.npsim import numpy_frames
from torchcal.rotations import rotvec_to_matrix

PRESETS = ("kr1000titan", "ur5e", "puma560")
BATCHES = ((), (10,), (4, 5))
DTYPES = (torch.float64, torch.float32)
DEVICES = ("cpu",) + (("cuda",) if torch.cuda.is_available() else ())
DEG = math.pi / 180


# -- helpers -------------------------------------------------------------------------
def _gen(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _random_q(robot, batch, gen, dtype=torch.float64) -> torch.Tensor:
    """Joint angles (*batch, n) rad uniformly inside the robot's limits."""
    lo, hi = robot.limits[:, 0], robot.limits[:, 1]
    u = torch.rand(*batch, robot.n, generator=gen, dtype=torch.float64)
    return (lo + (hi - lo) * u).to(dtype)


def _random_params(robot, batch, gen, dtype=torch.float64, scale: float = 1.0) -> torch.Tensor:
    """MD-H deviations (*batch, n, 5): ~0.01 rad on angles, ~1 mm on lengths, every dbeta
    non-zero (also on joints whose table declares no beta: the kernels must not care)."""
    s = torch.tensor([0.01, 1.0, 1.0, 0.01, 0.01], dtype=torch.float64) * scale
    return (torch.randn(*batch, robot.n, 5, generator=gen, dtype=torch.float64) * s).to(dtype)


def _rt(rpy_deg, xyz_mm) -> torch.Tensor:
    """(4, 4) float64 homogeneous transform from URDF-style rpy (deg) and xyz (mm)."""
    from scipy.spatial.transform import Rotation
    T = torch.eye(4, dtype=torch.float64)
    T[:3, :3] = torch.from_numpy(Rotation.from_euler("xyz", rpy_deg, degrees=True).as_matrix())
    T[:3, 3] = torch.tensor(xyz_mm, dtype=torch.float64)
    return T


def _with_base_tool(robot):
    """The robot on a tilted, shifted base with a TCP off the flange axis."""
    return dataclasses.replace(robot, base=_rt((2.0, -3.0, 30.0), (150.0, -80.0, 400.0)),
                               tool=_rt((0.0, 10.0, 0.0), (20.0, -15.0, 250.0)))


def _rz(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=np.float64)


def _static(d, a, alpha, beta) -> np.ndarray:
    """Tz(d) Tx(a) Rx(alpha) Ry(beta), (4, 4), lengths mm."""
    from scipy.spatial.transform import Rotation
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("XY", [alpha, beta]).as_matrix()  # intrinsic: Rx then Ry
    T[:3, 3] = [a, 0.0, d]
    return T


def _joint_origins(robot, params=None) -> list[np.ndarray]:
    """Fixed origins (mm) of the serial chain that pytorch-kinematics is given.

    Joint i (revolute about z) sits at  S_{i-1} Rz(theta_offset_i)  in link i-1's frame,
    where S_i = Tz(d_i) Tx(a_i) Rx(alpha_i) Ry(beta_i) and S_0 = base; a last fixed joint
    carries S_n tool to the TCP. So T = base A_1 ... A_n tool with A_i = Rz(off_i + q_i) S_i.
    Returns n + 1 (4, 4) matrices.
    """
    eff = robot.table if params is None else robot.table + params
    eff = eff.numpy()
    prev = robot.base.numpy()
    origins = []
    for off, d, a, alpha, beta in eff:
        origins.append(prev @ _rz(off))
        prev = _static(d, a, alpha, beta)
    origins.append(prev @ robot.tool.numpy())
    return origins


def _urdf(robot, params=None) -> str:
    """URDF (metres) of the robot with MD-H deviations `params` (n, 5) folded in."""
    from scipy.spatial.transform import Rotation
    origins = _joint_origins(robot, params)
    lim = robot.limits.numpy()
    links = ["base"] + [f"link{i + 1}" for i in range(robot.n)] + ["tcp"]
    out = [f'<robot name="{robot.name}">']
    out += [f'  <link name="{name}"/>' for name in links]
    for i, T in enumerate(origins):
        xyz = " ".join(repr(float(v) / 1000.0) for v in T[:3, 3])
        rpy = " ".join(repr(float(v)) for v in Rotation.from_matrix(T[:3, :3]).as_euler("xyz"))
        if i < robot.n:
            head = f'  <joint name="joint{i + 1}" type="revolute">'
            extra = ('    <axis xyz="0 0 1"/>\n'
                     f'    <limit lower="{float(lim[i, 0])!r}" upper="{float(lim[i, 1])!r}" effort="1" velocity="1"/>\n')
        else:
            head, extra = '  <joint name="tcp_joint" type="fixed">', ""
        out.append(f'{head}\n    <parent link="{links[i]}"/>\n    <child link="{links[i + 1]}"/>\n'
                   f'    <origin xyz="{xyz}" rpy="{rpy}"/>\n{extra}  </joint>')
    out.append("</robot>")
    return "\n".join(out)


def _pk_chain_float64(robot, params=None) -> pk.SerialChain:
    """The same serial chain built from pytorch-kinematics frames in float64 (mm),
    bypassing the URDF parser's float32 origins."""
    import pytorch_kinematics as pk
    from pytorch_kinematics import transforms as pk_tf
    origins = _joint_origins(robot, params)
    names = ["base"] + [f"link{i + 1}" for i in range(robot.n)] + ["tcp"]
    root = pk.Frame(names[0], link=pk.Link(names[0]), joint=pk.Joint(dtype=torch.float64))
    parent = root
    for i, T in enumerate(origins):
        kind = "revolute" if i < robot.n else "fixed"
        joint = pk.Joint(f"joint{i + 1}", offset=pk_tf.Transform3d(matrix=torch.from_numpy(T)),
                         joint_type=kind, axis=(0.0, 0.0, 1.0), dtype=torch.float64)
        child = pk.Frame(names[i + 1], link=pk.Link(names[i + 1]), joint=joint)
        parent.children = [child]
        parent = child
    chain = pk.Chain(root, dtype=torch.float64)
    return pk.SerialChain(chain, "tcp", dtype=torch.float64)


# -- forward kinematics against pytorch-kinematics -----------------------------------
@pytest.mark.parametrize("name", PRESETS)
@pytest.mark.parametrize("perturbed", [False, True], ids=["nominal", "perturbed+base+tool"])
def test_fk_matches_pytorch_kinematics_urdf(name, perturbed):
    import pytorch_kinematics as pk
    robot = torchcal.robot(name)
    gen = _gen(1)
    params = None
    if perturbed:
        robot = _with_base_tool(robot)
        params = _random_params(robot, (), gen)
    q = _random_q(robot, (64,), gen)
    chain = pk.build_serial_chain_from_urdf(_urdf(robot, params), "tcp").to(dtype=torch.float64)
    T_pk = chain.forward_kinematics(q).get_matrix()  # (64, 4, 4), metres
    # URDF origins go through float32 (rpy, xyz): ~1e-7 relative on metre-scale arms
    torch.testing.assert_close(robot.fk(q, params), T_pk[:, :3, 3] * 1000.0, atol=2e-3, rtol=0)
    torch.testing.assert_close(robot.fk_pose(q, params)[:, :3, :3], T_pk[:, :3, :3], atol=2e-6, rtol=0)


@pytest.mark.parametrize("name", PRESETS)
@pytest.mark.parametrize("perturbed", [False, True], ids=["nominal", "perturbed+base+tool"])
def test_fk_matches_pytorch_kinematics_float64(name, perturbed):
    robot = torchcal.robot(name)
    gen = _gen(2)
    params = None
    if perturbed:
        robot = _with_base_tool(robot)
        params = _random_params(robot, (), gen, scale=5.0)
    q = _random_q(robot, (64,), gen)
    T_pk = _pk_chain_float64(robot, params).forward_kinematics(q).get_matrix()  # (64, 4, 4) mm
    torch.testing.assert_close(robot.fk(q, params), T_pk[:, :3, 3], atol=1e-9, rtol=0)
    torch.testing.assert_close(robot.fk_pose(q, params), T_pk, atol=1e-9, rtol=0)


def test_urdf_builder_agrees_with_float64_chain():
    """Guards the reference itself: parsed URDF and hand-built chain are one robot."""
    import pytorch_kinematics as pk
    robot = _with_base_tool(torchcal.robot("kr1000titan"))
    params = _random_params(robot, (), _gen(3))
    q = _random_q(robot, (16,), _gen(4))
    a = pk.build_serial_chain_from_urdf(_urdf(robot, params), "tcp").to(dtype=torch.float64)
    b = _pk_chain_float64(robot, params)
    torch.testing.assert_close(a.forward_kinematics(q).get_matrix()[:, :3, 3] * 1000.0,
                               b.forward_kinematics(q).get_matrix()[:, :3, 3], atol=2e-3, rtol=0)


# -- KR 1000 Titan by hand (docs/paper.md Table 1) ------------------------------------------
# q = 0: A1 puts joint 2 at (600, 0, 1100) with Rx(-90); a2 = 1400 and a3 = 65 run along
# +x to (2065, 0, 1100); Rx(-90) twice points z down, d4 = 1200 and d6 = 372 go down.
HAND = [
    ((0, 0, 0, 0, 0, 0), (2065.0, 0.0, -472.0)),
    # forearm horizontal: x = 600 + 1400 + 1200 + 372, z = 1100 + 65
    ((0, 0, -90, 0, 0, 0), (3572.0, 0.0, 1165.0)),
    # joint 1 about the vertical: the q = 0 point turned by 90 deg
    ((90, 0, 0, 0, 0, 0), (0.0, 2065.0, -472.0)),
    # joint 2 turns the arm about world y through (600, 0, 1100): link 2 points up to
    # (600, 0, 2500); the rest, (65, 0, -1572) from there, turns to (1572, 0, 65)
    ((0, -90, 0, 0, 0, 0), (2172.0, 0.0, 2565.0)),
    # wrist singular (q5 = 0): axes 4 and 6 on the TCP's vertical, q4 and q6 change nothing
    ((0, 0, 0, 37, 0, 50), (2065.0, 0.0, -472.0)),
    # q5 = 90 swings d6 = 372 about world y through the wrist center (2065, 0, -100): -z -> -x
    ((0, 0, 0, 0, 90, 0), (1693.0, 0.0, -100.0)),
    # the same swing with the forearm horizontal: +x -> -z from the wrist center (3200, 0, 1165)
    ((0, 0, -90, 0, 90, 0), (3200.0, 0.0, 793.0)),
]


@pytest.mark.parametrize("q_deg,expected", HAND, ids=[str(h[0]) for h in HAND])
def test_kr1000titan_hand_checked(q_deg, expected):
    robot = torchcal.robot("kr1000titan")
    q = torch.tensor(q_deg, dtype=torch.float64) * DEG
    torch.testing.assert_close(robot.fk(q), torch.tensor(expected, dtype=torch.float64),
                               atol=1e-9, rtol=0)


def test_kr1000titan_dbeta2_turns_the_arm_about_link2_y():
    """A Hayati dbeta on joint 2 turns everything after joint 2's end (2000, 0, 1100) about
    that frame's y axis, which at q = 0 is world -z: the TCP, straight below at
    (65, 0, -1572) from there, only moves by the 65 mm arm: y -> -65 sin(b) (x -> 65 cos b)."""
    robot = torchcal.robot("kr1000titan")
    b = 0.01
    params = torch.zeros(6, 5, dtype=torch.float64)
    params[1, 4] = b
    p = robot.fk(torch.zeros(6, dtype=torch.float64), params)
    expected = torch.tensor([2000.0 + 65.0 * math.cos(b), -65.0 * math.sin(b), -472.0],
                            dtype=torch.float64)
    torch.testing.assert_close(p, expected, atol=1e-9, rtol=0)


# -- Jacobians ---------------------------------------------------------------------------
def _jac_case(name, batch, dtype, seed=5):
    robot = _with_base_tool(torchcal.robot(name))
    gen = _gen(seed)
    q = _random_q(robot, batch, gen, dtype)
    params = _random_params(robot, batch, gen, dtype)
    return robot, q, params, robot.chain.to(dtype)


def _per_sample(fn, q, params, n):
    """vmap `fn(q_i, params_i)` over the flattened batch and restore it."""
    batch = q.shape[:-1]
    out = torch.func.vmap(fn)(q.reshape(-1, n), params.reshape(-1, n, 5))  # (B, 3, ...)
    return out.reshape(*batch, *out.shape[1:])


def _assert_close_rel(actual, expected, rel):
    """Close to `rel` times the largest entry (the Jacobians mix mm/rad and mm/mm)."""
    torch.testing.assert_close(actual, expected, rtol=rel, atol=rel * expected.abs().max().item())


@pytest.mark.parametrize("dtype", DTYPES, ids=["f64", "f32"])
@pytest.mark.parametrize("batch", BATCHES, ids=str)
@pytest.mark.parametrize("name", PRESETS)
def test_param_jacobian_matches_autograd(name, batch, dtype):
    robot, q, params, chain = _jac_case(name, batch, dtype)
    n = robot.n

    def fk(qi, pi):  # the strict kernel: Robot.fk's input checks are data-dependent
        return K.fk_positions(qi, chain, pi)

    auto = _per_sample(lambda qi, pi: torch.func.jacrev(fk, argnums=1)(qi, pi), q, params, n)
    auto = auto.reshape(*batch, 3, 5 * n)  # (..., 3, n, 5) -> joint-major columns
    ana = K.param_jacobian(q, chain, params)
    assert ana.shape == (*batch, 3, 5 * n) and ana.dtype == dtype
    _assert_close_rel(ana, auto, 1e-9 if dtype == torch.float64 else 2e-5)
    # the Robot entry point gives the same
    torch.testing.assert_close(robot.to(dtype=dtype).param_jacobian(q, params), ana, rtol=0, atol=0)


@pytest.mark.parametrize("dtype", DTYPES, ids=["f64", "f32"])
@pytest.mark.parametrize("batch", BATCHES, ids=str)
@pytest.mark.parametrize("name", PRESETS)
def test_joint_jacobian_matches_autograd(name, batch, dtype):
    robot, q, params, chain = _jac_case(name, batch, dtype, seed=6)

    def fk(qi, pi):
        return K.fk_positions(qi, chain, pi)

    auto = _per_sample(lambda qi, pi: torch.func.jacrev(fk, argnums=0)(qi, pi), q, params, robot.n)
    ana = K.joint_jacobian(q, chain, params)
    assert ana.shape == (*batch, 3, robot.n) and ana.dtype == dtype
    _assert_close_rel(ana, auto, 1e-9 if dtype == torch.float64 else 2e-5)


@pytest.mark.parametrize("batch", BATCHES, ids=str)
@pytest.mark.parametrize("name", PRESETS)
def test_jacobians_match_central_differences(name, batch):
    robot, q, params, chain = _jac_case(name, batch, torch.float64, seed=7)
    n, h = robot.n, 1e-6  # rad or mm

    def fk(q_, p_):
        return K.fk_positions(q_, chain, p_)

    # parameters: all 5n perturbations as one leading batch dim
    E = torch.eye(5 * n, dtype=torch.float64).reshape(5 * n, *(1,) * len(batch), n, 5) * h
    fd = (fk(q, params + E) - fk(q, params - E)) / (2 * h)  # (5n, ..., 3)
    _assert_close_rel(K.param_jacobian(q, chain, params), fd.movedim(0, -1), 1e-6)
    # joints
    E = torch.eye(n, dtype=torch.float64).reshape(n, *(1,) * len(batch), n) * h
    fd = (fk(q + E, params) - fk(q - E, params)) / (2 * h)  # (n, ..., 3)
    _assert_close_rel(K.joint_jacobian(q, chain, params), fd.movedim(0, -1), 1e-6)


def test_param_jacobian_without_params_is_at_nominal():
    robot = torchcal.robot("ur5e")
    q = _random_q(robot, (7,), _gen(8))
    zeros = torch.zeros(7, robot.n, 5, dtype=torch.float64)
    torch.testing.assert_close(robot.param_jacobian(q), robot.param_jacobian(q, zeros), rtol=0, atol=1e-12)


# -- consistency: fk, fk_pose, frames, broadcasting, chunking --------------------------
@pytest.mark.parametrize("name", PRESETS)
def test_fk_equals_fk_pose_and_frames(name):
    robot = _with_base_tool(torchcal.robot(name))
    gen = _gen(9)
    q = _random_q(robot, (4, 5), gen)
    params = _random_params(robot, (4, 5), gen)
    pose = robot.fk_pose(q, params)
    assert pose.shape == (4, 5, 4, 4)
    torch.testing.assert_close(robot.fk(q, params), pose[..., :3, 3], atol=1e-9, rtol=0)
    frames = robot.frames(q, params)
    assert frames.shape == (4, 5, robot.n + 2, 4, 4)
    torch.testing.assert_close(frames[..., -1, :, :], pose, atol=1e-9, rtol=0)
    torch.testing.assert_close(frames[..., 0, :, :], robot.base.expand(4, 5, 4, 4), atol=0, rtol=0)
    # rotations stay orthonormal
    R = pose[..., :3, :3]
    torch.testing.assert_close(R @ R.transpose(-1, -2), torch.eye(3, dtype=R.dtype).expand_as(R),
                               atol=1e-12, rtol=0)


@pytest.mark.parametrize("name", PRESETS)
def test_broadcast_params_by_poses_equals_loop(name):
    robot = _with_base_tool(torchcal.robot(name))
    gen = _gen(10)
    M, P = 3, 4
    params = _random_params(robot, (M, 1), gen)  # (M, 1, n, 5)
    q = _random_q(robot, (P,), gen)  # (P, n)
    out = robot.fk(q, params)
    assert out.shape == (M, P, 3)
    loop = torch.stack([torch.stack([robot.fk(q[p], params[m, 0]) for p in range(P)])
                        for m in range(M)])
    torch.testing.assert_close(out, loop, atol=1e-9, rtol=0)


@pytest.mark.parametrize("q_batch,p_batch", [
    ((23,), (37, 1)),  # cut along the parameter sets
    ((41,), (7, 1)),  # cut along the poses
    ((300,), None),  # no parameters
    ((), (130,)),  # one pose, many parameter sets
    ((5, 29), (5, 1)),  # two batch dims, the larger held by q
], ids=str)
@pytest.mark.parametrize("dtype", DTYPES, ids=["f64", "f32"])
def test_chunked_equals_unchunked(q_batch, p_batch, dtype):
    robot = _with_base_tool(torchcal.robot("kr1000titan"))
    gen = _gen(11)
    q = _random_q(robot, q_batch, gen, dtype)
    params = None if p_batch is None else _random_params(robot, p_batch, gen, dtype)
    chain = robot.chain.to(dtype)
    whole = K.fk_positions(q, chain, params, chunk=10 ** 9)
    pieces = K.fk_positions(q, chain, params, chunk=64)
    expected_shape = torch.broadcast_shapes(q_batch, () if p_batch is None else p_batch) + (3,)
    assert whole.shape == pieces.shape == expected_shape
    # equal up to rounding (vectorised and scalar-tail trig paths differ in the last bit)
    eps = torch.finfo(dtype).eps
    torch.testing.assert_close(pieces, whole, atol=16 * eps * whole.abs().max().item(), rtol=0)
    # and the position kernel agrees with the 4x4 chain
    pose = K.fk_pose(q, chain, params)
    atol = 1e-9 if dtype == torch.float64 else 5e-3
    torch.testing.assert_close(whole, pose[..., :3, 3].expand_as(whole), atol=atol, rtol=0)


# -- bad input -----------------------------------------------------------------------------
METHODS = ("fk", "fk_pose", "frames", "param_jacobian", "joint_jacobian")


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("shape", [(5,), (3, 7), ()], ids=str)
def test_wrong_joint_count_is_rejected(method, shape):
    robot = torchcal.robot("kr1000titan")
    q = torch.zeros(shape, dtype=torch.float64)
    with pytest.raises(ValueError, match=r"q: expected joint angles of shape \(\.\.\., 6\) "
                                         r"for kr1000titan, got shape"):
        getattr(robot, method)(q)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")], ids=str)
def test_non_finite_angles_are_rejected(method, bad):
    robot = torchcal.robot("puma560")
    q = torch.zeros(2, 6, dtype=torch.float64)
    q[1, 3] = bad
    with pytest.raises(InputError, match=r"q: joint angles must be finite, got .* at index \[1, 3\]"):
        getattr(robot, method)(q)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("shape", [(6, 4), (5, 5), (30,), (2, 6, 6)], ids=str)
def test_wrong_params_shape_is_rejected(method, shape):
    robot = torchcal.robot("ur5e")
    with pytest.raises(ValueError, match=r"params: expected MD-H deviations of shape \(\.\.\., 6, 5\) "
                                         r"\[dtheta, dd, da, dalpha, dbeta\], got shape"):
        getattr(robot, method)(torch.zeros(6, dtype=torch.float64), torch.zeros(shape))


def test_non_finite_params_are_rejected():
    robot = torchcal.robot("ur5e")
    params = torch.zeros(6, 5, dtype=torch.float64)
    params[2, 1] = float("nan")
    with pytest.raises(ValueError, match="params: MD-H deviations must be finite"):
        robot.fk(torch.zeros(6, dtype=torch.float64), params)


@pytest.mark.parametrize("name", ["kr1000", "", None, 3])
def test_unknown_preset_is_rejected(name):
    with pytest.raises(ValueError, match=r"unknown robot .*; expected one of kr1000titan, puma560, ur5e"):
        torchcal.robot(name)


def test_preset_names_are_case_insensitive():
    assert torchcal.robot("KR1000Titan").name == "kr1000titan"


def test_non_broadcasting_batches_are_rejected():
    robot = torchcal.robot("kr1000titan")
    with pytest.raises(ValueError, match="broadcast"):
        robot.fk(torch.zeros(3, 6, dtype=torch.float64), torch.zeros(4, 6, 5, dtype=torch.float64))


# -- dtype and device ------------------------------------------------------------------------
@pytest.mark.parametrize("device", DEVICES)
def test_float32_stays_float32_and_device_is_kept(device):
    robot = torchcal.robot("kr1000titan").to(device=device)
    gen = _gen(12)
    q64 = _random_q(robot.to("cpu"), (50,), gen)
    p64 = _random_params(robot.to("cpu"), (50,), gen)
    q32, p32 = q64.float().to(device), p64.float().to(device)
    for method, shape in (("fk", (50, 3)), ("fk_pose", (50, 4, 4)), ("frames", (50, 8, 4, 4)),
                          ("param_jacobian", (50, 3, 30)), ("joint_jacobian", (50, 3, 6))):
        out = getattr(robot, method)(q32, p32)
        assert out.dtype == torch.float32, method
        assert out.device.type == device, method
        assert out.shape == shape, method
    # float32 is accurate to the float32 resolution of metre-scale positions
    ref = robot.fk(q64.to(device), p64.to(device))
    assert ref.dtype == torch.float64 and ref.device.type == device
    torch.testing.assert_close(robot.fk(q32, p32), ref.float(), atol=5e-3, rtol=0)
    # mixed inputs promote: float32 q with float64 params is float64
    assert robot.fk(q32, p64.to(device)).dtype == torch.float64
    # plain lists and integer tensors are accepted and come out in the robot's dtype
    assert robot.fk([0, 0, 0, 0, 0, 0]).dtype == torch.float64


def test_outer_positions_equals_fk_positions():
    """The in-place (points x sets) layout used by the sweep is the same recursion."""
    from torchcal.kinematics import mdh as K
    robot = torchcal.robot("kr1000titan")
    g = torch.Generator().manual_seed(3)
    q = torch.rand(7, 6, generator=g, dtype=torch.float64) * 2 - 1
    dev = torch.randn(5, 6, 5, generator=g, dtype=torch.float64) * 1e-3
    tool = torch.eye(4, dtype=torch.float64)
    tool[:3, 3] = torch.tensor([10.0, -20.0, 150.0], dtype=torch.float64)
    chain = K.Chain(robot.table, robot.prismatic, torch.eye(4, dtype=torch.float64), tool)
    F = K.outer_factors(chain, dev)
    bufs = [torch.empty(7, 5, dtype=torch.float64) for _ in range(7)]
    got = torch.stack(K.outer_positions(K.outer_angles(q, chain), chain, F, bufs), -1)
    want = K.fk_positions(q[:, None, :], chain, dev[None])
    torch.testing.assert_close(got, want, rtol=0, atol=1e-9)


def test_robot_equality_never_raises():
    """Robot == Robot compares name and tensors (a dataclass __eq__ on tensors would raise)."""
    a, b = torchcal.robot("kr1000titan"), torchcal.robot("kr1000titan")
    assert a == b and a != torchcal.robot("ur5e") and a != "kr1000titan"
    moved = dataclasses.replace(a, tool=a.tool.clone())
    moved.tool[2, 3] += 1.0
    assert a != moved


@pytest.mark.parametrize("slides", [(), (2,), (0, 5)], ids=["revolute", "slide-3", "slides-1-6"])
def test_in_place_kernel_matches_numpy_chain_and_autograd_kernel(slides):
    """`positions_into` (Robot.fk without gradients): an outer (sets x poses) batch with a
    tilted base, an off-axis tool and prismatic joints equals the plain-numpy chain of
    tests/npsim.py and the differentiable kernel `positions`."""
    from tests.npsim import numpy_fk
    robot = _with_base_tool(torchcal.robot("kr1000titan"))
    prismatic = torch.zeros(robot.n, dtype=torch.bool)
    prismatic[list(slides)] = True
    robot = dataclasses.replace(robot, prismatic=prismatic)
    gen = _gen(12)
    q = _random_q(robot, (40,), gen)  # slides: the same numbers read as mm
    params = _random_params(robot, (6, 1), gen, scale=5.0)  # (6, 1, n, 5)
    out = robot.fk(q, params, chunk=64)  # (6, 40, 3), chunked, in place
    assert not out.requires_grad
    for m in range(6):
        want = numpy_fk(robot, q.numpy(), params[m, 0].numpy())
        np.testing.assert_allclose(out[m].numpy(), want, rtol=0, atol=1e-9)
    ref = K.positions(q, robot.chain, params)
    torch.testing.assert_close(out, ref, rtol=0, atol=1e-12 * ref.abs().max().item())
    # with a gradient asked for, the differentiable kernel runs and the values agree
    leaf = params.clone().requires_grad_(True)
    graded = robot.fk(q, leaf, chunk=64)
    assert graded.requires_grad
    torch.testing.assert_close(graded.detach(), out, rtol=0, atol=1e-12 * ref.abs().max().item())


# -- fk_rotation -------------------------------------------------------------------------

def _tilted(robot):
    """The robot on a tilted, shifted base with a rotated, offset tool."""
    base, tool = torch.eye(4, dtype=torch.float64), torch.eye(4, dtype=torch.float64)
    base[:3, :3] = rotvec_to_matrix(torch.tensor([0.03, -0.05, 0.5], dtype=torch.float64))
    base[:3, 3] = torch.tensor([150.0, -80.0, 400.0], dtype=torch.float64)
    tool[:3, :3] = rotvec_to_matrix(torch.tensor([0.0, 0.2, 0.1], dtype=torch.float64))
    tool[:3, 3] = torch.tensor([20.0, -15.0, 250.0], dtype=torch.float64)
    return dataclasses.replace(robot, base=base, tool=tool)


@pytest.mark.parametrize("slides", [(), (2,)], ids=["revolute", "slide-3"])
def test_fk_rotation_matches_numpy_chain_and_fk_pose(slides):
    robot = _tilted(torchcal.robot("kr1000titan"))
    prismatic = torch.zeros(robot.n, dtype=torch.bool)
    prismatic[list(slides)] = True
    robot = dataclasses.replace(robot, prismatic=prismatic)
    gen = torch.Generator().manual_seed(5)
    q = (torch.rand(30, robot.n, generator=gen, dtype=torch.float64) - 0.5) * 4.0
    dev = (torch.rand(robot.n, 5, generator=gen, dtype=torch.float64) - 0.5) * 0.02
    for chain, tool in ((robot.chain.flange, np.eye(4)), (robot.chain, robot.tool.numpy())):
        got = K.fk_rotation(q, chain, dev)
        assert got.shape == (30, 3, 3)
        want = np.array([(numpy_frames(robot, qq, dev.numpy())[-1] @ tool)[:3, :3] for qq in q.numpy()])
        np.testing.assert_allclose(got.numpy(), want, rtol=0, atol=1e-12)
        assert torch.equal(got, K.fk_pose(q, chain, dev)[..., :3, :3])  # the same numbers as the pose's
