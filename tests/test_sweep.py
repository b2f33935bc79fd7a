"""Tests of the workspace sweep (torchcal.reliability.sweep), the clearance model behind it
(torchcal.reliability.uncertainty) and the `torchcal sweep` command.

What is checked, and against what:

- clearance -> MD-H deviations against an explicit chain that inserts the shifted and
  tilted joint axes as rigid transforms: equal up to second order (the difference falls
  100x for clearances 10x smaller), for the KR 1000 Titan and for robots with parallel
  axes (UR5e, PUMA 560); the deviation box is attained by a clearance state; Table 2 as
  transcribed is self-consistent (limits = nominal + tolerance);
- the sampled envelope lies inside the linearised interval hull up to O(|box|^2), and the
  hull is attained (to second order) by the box vertex that the Jacobian's signs pick;
- the default KR 1000 Titan sweep gives R_set from about 0.7 to 1 (the paper's Table 3);
- determinism by seed, chunked == unchunked, the CSV round trip and its errors;
- the command line: a bad option or value -> exit 2 with one line on stderr.
"""

from __future__ import annotations

import json
import math
import re

import pytest
import torch

import torchcal
from torchcal import cli
from torchcal.kinematics import mdh as K
from torchcal.kinematics.chain import Chain
from torchcal.errors import InputError
from torchcal.reliability.interval import Interval
from torchcal.io.sweep_csv import read_sweep, sweep_columns, write_sweep
from torchcal.reliability.sweep import linear_bounds, sweep
from torchcal.robots.workspace import Workspace, sample_workspace
from torchcal.reliability.uncertainty import (KR1000_BEARING_LENGTH_MM, KR1000_CLEARANCE_MM, KR1000_LIMITS_MM,
                                  KR1000_RADII_MM, KR1000_TOLERANCE_MM, ClearanceModel, box,
                                  deviation_map, sample_states, states_to_deviations)

DEVICES = ("cpu",) + (("cuda",) if torch.cuda.is_available() else ())


def _generic_model(robot, clearance=0.03, length=80.0):
    n = robot.n
    return ClearanceModel((50.0,) * 2 * n, (clearance,) * 2 * n, (length,) * n)


def _rotvec(w):
    W = torch.zeros(3, 3, dtype=torch.float64)
    W[0, 1], W[0, 2], W[1, 2] = -w[2], w[1], -w[0]
    W = W - W.T
    return torch.linalg.matrix_exp(W)


def _explicit_tcp(robot, model, q, states):
    """TCP with each joint axis moved as a rigid body (the model's definition, exact)."""
    table = robot.table
    A = K.link_transforms(q, robot.chain)  # (n, 4, 4)
    L = model.bearing_length_mm
    T = torch.eye(4, dtype=torch.float64)
    for j in range(robot.n):
        u1, u2 = states[2 * j], states[2 * j + 1]
        t, d = (u1 + u2) / 2, (u2 - u1) / L[j]
        E = torch.eye(4, dtype=torch.float64)
        E[:3, :3] = _rotvec(torch.stack([-d[1], d[0], torch.zeros((), dtype=torch.float64)]))
        E[:2, 3] = t
        if j == 0:  # joint 1: pivot at the base origin, in the frame turning with q1
            Rz = torch.eye(4, dtype=torch.float64)
            c, s = torch.cos(q[0] + table[0, 0]), torch.sin(q[0] + table[0, 0])
            Rz[0, 0], Rz[0, 1], Rz[1, 0], Rz[1, 1] = c, -s, s, c
            S = K.link_transforms(-table[:1, 0], Chain.revolute(table[:1]))[0]
            T = T @ Rz @ E @ S
        else:  # joint j: pivot at the origin of frame j-1, fixed to link j-1
            T = T @ E @ A[j]
    return (T @ robot.tool)[:3, 3]


# -- clearance model ------------------------------------------------------------------------
def test_table2_constants_are_consistent():
    assert len(KR1000_RADII_MM) == len(KR1000_CLEARANCE_MM) == len(KR1000_TOLERANCE_MM) == 12
    for r, tol, (lo, hi) in zip(KR1000_RADII_MM, KR1000_TOLERANCE_MM, KR1000_LIMITS_MM):
        assert hi - lo == pytest.approx(tol, abs=1e-9)
        assert r in (lo, hi)
    assert KR1000_CLEARANCE_MM[10] == 0.0  # DV11 as printed
    assert len(KR1000_BEARING_LENGTH_MM) == 6
    # default bearing length = shaft diameter
    assert KR1000_BEARING_LENGTH_MM == pytest.approx([2 * r for r in KR1000_RADII_MM[::2]])


@pytest.mark.parametrize("name", ("kr1000titan", "ur5e", "puma560"))
def test_deviations_match_the_moved_axes_to_second_order(name):
    robot = torchcal.robot(name)
    model = ClearanceModel.defaults(robot) if name == "kr1000titan" else _generic_model(robot)
    g = torch.Generator().manual_seed(11)
    lo, hi = robot.limits[:, 0], robot.limits[:, 1]
    worst = {}
    for scale in (1.0, 0.1):
        gaps, sizes = [], []
        for _ in range(8):
            q = lo + (hi - lo) * torch.rand(robot.n, generator=g, dtype=torch.float64)
            st = sample_states(model, 1, g)[0] * scale
            p0 = robot.fk(q)
            exact = _explicit_tcp(robot, model, q, st)
            lin = robot.fk(q, states_to_deviations(robot, model, st))
            gaps.append((lin - exact).norm().item())
            sizes.append((exact - p0).norm().item())
        worst[scale] = max(gaps)
        assert max(gaps) < 1e-3 * max(sizes)  # first order right
    assert worst[0.1] < 0.02 * worst[1.0]  # the rest is second order


def test_eq14_twist_columns_match_autograd():
    """G of docs/paper.md eq. 14 = A^-1 dA/dp (body twist in the link's end frame), any theta."""
    from torchcal.reliability.uncertainty import _link_twist_columns
    g = torch.Generator().manual_seed(0)
    scale = torch.tensor([1.0, 300.0, 300.0, 1.0, 0.3], dtype=torch.float64)
    for _ in range(5):
        row = torch.randn(5, generator=g, dtype=torch.float64) * scale
        q = torch.randn(1, generator=g, dtype=torch.float64)

        def A(p):
            return K.link_transforms(q, Chain.revolute(row[None]), p[None])[0]

        p0 = torch.zeros(5, dtype=torch.float64)
        dA = torch.autograd.functional.jacobian(A, p0)  # (4, 4, 5)
        D = torch.einsum("ij,jkp->ikp", torch.linalg.inv(A(p0)), dA)
        G = torch.cat([D[:3, 3, :], torch.stack([D[2, 1], D[0, 2], D[1, 0]])])
        torch.testing.assert_close(_link_twist_columns(row), G, rtol=1e-12, atol=1e-12)


def test_kr1000_mapping_uses_the_documented_parameters(kr):
    model = ClearanceModel.defaults(kr)
    D = deviation_map(kr, model).reshape(6, 5, 12, 2)
    # joint 4 (host link 3): tilt -> dalpha3 / dbeta3, shift -> da3 / dd3, no dtheta3
    c7, c8, L4 = KR1000_CLEARANCE_MM[6], KR1000_CLEARANCE_MM[7], KR1000_BEARING_LENGTH_MM[3]
    u = torch.zeros(12, 2, dtype=torch.float64)
    u[6, 0], u[7, 0] = -c7, c8  # opposite contact: the largest tilt
    dev = states_to_deviations(kr, model, u)
    tilt = dev[2, 3:].norm().item()
    assert tilt == pytest.approx((c7 + c8) / L4)
    assert tilt == pytest.approx(model.max_tilt_rad()[3].item())
    assert D[2, 0, 6:8].abs().max().item() == 0.0  # dtheta-free
    # joint 3's host link 2 has alpha = 0 (parallel axes 2, 3): its y-shift needs dtheta2
    assert D[1, 0, 4:6].abs().max().item() > 0


def test_box_is_attained_and_contains_samples(kr):
    model = ClearanceModel.defaults(kr)
    b = box(kr, model)
    D = deviation_map(kr, model).reshape(30, 12, 2)
    c = torch.tensor(KR1000_CLEARANCE_MM, dtype=torch.float64)
    for k in range(30):
        norm = D[k].norm(dim=-1, keepdim=True)
        u = torch.where(norm > 0, D[k] / norm.clamp_min(1e-300), torch.zeros_like(D[k])) * c[:, None]
        dev = states_to_deviations(kr, model, u).reshape(30)
        assert dev[k].item() == pytest.approx(b.upper.reshape(30)[k].item(), abs=1e-15)
    for mode in ("contact", "disc"):
        m = ClearanceModel(KR1000_RADII_MM, KR1000_CLEARANCE_MM, KR1000_BEARING_LENGTH_MM, mode=mode)
        st = sample_states(m, 500, torch.Generator().manual_seed(0))
        r = st.norm(dim=-1)
        if mode == "contact":
            torch.testing.assert_close(r, c.expand(500, 12))
        else:
            assert bool((r <= c + 1e-15).all()) and r.min() < 0.5 * c.max()
        assert bool(b.contains(states_to_deviations(kr, m, st), atol=1e-15).all())


def test_tolerance_box_adds_to_the_box(kr):
    tol = ((1e-5, 0.01, 0.01, 1e-5, 1e-5),) * 6
    m = ClearanceModel(KR1000_RADII_MM, KR1000_CLEARANCE_MM, KR1000_BEARING_LENGTH_MM, tolerance=tol)
    plain = box(kr, ClearanceModel.defaults(kr))
    torch.testing.assert_close(box(kr, m).upper, plain.upper + torch.tensor(tol, dtype=torch.float64))
    dev = m.sample(kr, 200, torch.Generator().manual_seed(1))
    assert bool(box(kr, m).contains(dev, atol=1e-15).all())


def test_clearance_model_errors(kr):
    with pytest.raises(InputError, match=r"expected 2n = 12 seat radii and clearances for 6 joints, got 10"):
        ClearanceModel((1.0,) * 10, (0.01,) * 10, (100.0,) * 6)
    with pytest.raises(InputError, match="clearance_mm: must be >= 0"):
        ClearanceModel((1.0,) * 12, (-0.01,) * 12, (100.0,) * 6)
    with pytest.raises(InputError, match="bearing_length_mm: must be > 0"):
        ClearanceModel((1.0,) * 12, (0.01,) * 12, (0.0,) * 6)
    with pytest.raises(InputError, match="mode: expected one of contact, disc, got 'loose'"):
        ClearanceModel((1.0,) * 12, (0.01,) * 12, (1.0,) * 6, mode="loose")
    with pytest.raises(InputError, match="no default clearance model for robot 'ur5e'"):
        ClearanceModel.defaults(torchcal.robot("ur5e"))
    with pytest.raises(InputError, match="clearance model has 6 joints but robot 'x' has"):
        deviation_map(torchcal.Robot("x", kr.table[:5], kr.has_beta[:5], kr.limits[:5]), ClearanceModel.defaults(kr))


# -- workspace sampling -----------------------------------------------------------------------
def test_workspace_sample_is_inside_limits_and_filters(kr):
    ws = Workspace()
    q = sample_workspace(kr, 300, seed=5, workspace=ws)
    assert q.shape == (300, 6) and q.dtype == torch.float64
    assert bool(kr.within_limits(q).all())
    assert bool(ws.accept(kr, q).all())
    p = kr.fk(q)
    assert bool((p[:, 2] > 0).all())
    assert bool(((p[:, :2].norm(dim=-1) >= 350) | (p[:, 2] >= 1100)).all())
    torch.testing.assert_close(q, sample_workspace(kr, 300, seed=5), rtol=0, atol=0)
    assert not torch.equal(q, sample_workspace(kr, 300, seed=6))


def test_workspace_errors(kr):
    with pytest.raises(InputError, match="positive integer, got 0"):
        sample_workspace(kr, 0)
    with pytest.raises(InputError, match="workspace filter too strict"):
        sample_workspace(kr, 10, workspace=Workspace(floor_z_mm=1e6), max_rounds=3)


# -- the sweep --------------------------------------------------------------------------------
def test_default_kr1000_reliability_spread_as_in_table3(kr):
    """docs/paper.md Table 3: R_set from 0.685 to 1 at an allowed distance error of 2.5 mm."""
    r = sweep(kr, n_points=100, n_samples=300, allowed_mm=2.5, seed=0)
    assert 0.65 <= r.r_set.min().item() <= 0.8
    assert r.r_set.max().item() == 1.0
    assert 0.2 <= (r.r_set == 1).double().mean().item() <= 0.8
    torch.testing.assert_close(r.r_set, (2.5 / r.dist_upper).clamp(max=1.0))
    assert bool((r.dist_lower == 0).all())  # the nominal state belongs to the set
    assert bool((r.err_lower <= 0).all() and (r.err_upper >= 0).all())
    # eta > 1 exactly where the whole interval is safe
    assert torch.equal(r.eta > 1, r.dist_upper < 2.5)


def test_sweep_is_deterministic_by_seed(kr):
    before = torch.get_num_threads()  # 1 in the suite (conftest): try with 2 so a leak would show
    torch.set_num_threads(2)
    try:
        a = sweep(kr, n_points=20, n_samples=40, seed=3)
        assert torch.get_num_threads() == 2  # the sweep's serial-ops switch is undone
    finally:
        torch.set_num_threads(before)
    b = sweep(kr, n_points=20, n_samples=40, seed=3)
    c = sweep(kr, n_points=20, n_samples=40, seed=4)
    for name in ("q", "err_lower", "err_upper", "dist_upper", "r_set", "eta", "lin_upper"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name
    assert not torch.equal(a.q, c.q) and not torch.equal(a.dist_upper, c.dist_upper)


@pytest.mark.parametrize("chunk", (13, 64, 120, 1000))
def test_chunked_equals_unchunked(kr, chunk):
    q = sample_workspace(kr, 7, seed=1)
    ref = sweep(kr, q, n_samples=50, seed=2, chunk=1 << 20)
    got = sweep(kr, q, n_samples=50, seed=2, chunk=chunk)
    for name in ("err_lower", "err_upper", "dist_lower", "dist_upper", "r_set", "eta"):
        torch.testing.assert_close(getattr(got, name), getattr(ref, name), rtol=1e-12, atol=1e-12)


def test_cpu_chunk_sizes_give_the_same_csv_bit_for_bit(kr):
    # 40 x 500 pairs: 2 calls of the kernel at 16384 (1 MiB of L2), 1 at 32768 (2 MiB)
    from torchcal.io.sweep_csv import sweep_csv_text

    q = sample_workspace(kr, 40, seed=3)
    texts = {ch: sweep_csv_text(sweep(kr, q, n_samples=500, seed=4, chunk=ch, threads=2)) for ch in (1 << 14, 1 << 15)}
    assert texts[1 << 14] == texts[1 << 15]


def test_default_cpu_chunk_follows_the_l2_cache(tmp_path):
    from torchcal.reliability.sweep import _l2_bytes, _l2_chunk

    assert _l2_chunk(None) == 1 << 14  # unknown cache: the old default
    assert _l2_chunk(1 << 20) == 1 << 14 and _l2_chunk(2 << 20) == 1 << 15  # 7 x 8 B x chunk <= L2
    assert _l2_chunk(256 << 10) == 1 << 12 and _l2_chunk(64 << 20) == 1 << 16  # clamped
    for idx, (level, kind, size) in enumerate((("1", "Data", "48K"), ("1", "Instruction", "32K"),
                                              ("2", "Unified", "2048K"), ("3", "Unified", "105M"))):
        d = tmp_path / f"index{idx}"
        d.mkdir()
        for name, text in (("level", level), ("type", kind), ("size", size)):
            (d / name).write_text(text + "\n")
    assert _l2_bytes(str(tmp_path)) == 2 << 20
    assert _l2_bytes(str(tmp_path / "missing")) is None


def test_envelope_equals_brute_force(kr):
    q = sample_workspace(kr, 5, seed=8)
    dev = ClearanceModel.defaults(kr).sample(kr, 30, torch.Generator().manual_seed(0))
    r = sweep(kr, q, deviations=dev, include_nominal=False)
    err = kr.fk(q[:, None], dev[None]) - kr.fk(q)[:, None]  # (5, 30, 3)
    torch.testing.assert_close(r.err_lower, err.amin(1))
    torch.testing.assert_close(r.err_upper, err.amax(1))
    torch.testing.assert_close(r.dist_lower, err.norm(dim=-1).amin(1))
    torch.testing.assert_close(r.dist_upper, err.norm(dim=-1).amax(1))


def _with_frames(kr, **more):
    """`kr` with a rotated, shifted base and a tool offset (and any other fields in `more`)."""
    import dataclasses
    base = torch.eye(4, dtype=torch.float64)
    base[:3, :3] = torch.linalg.matrix_exp(torch.tensor([[0.0, -0.3, 0.2], [0.3, 0.0, -0.1],
                                                          [-0.2, 0.1, 0.0]], dtype=torch.float64))
    base[:3, 3] = torch.tensor([100.0, -50.0, 20.0])
    tool = torch.eye(4, dtype=torch.float64)
    tool[:3, 3] = torch.tensor([30.0, -20.0, 250.0])
    return dataclasses.replace(kr, base=base, tool=tool, **more)


@pytest.mark.parametrize("threads", (1, 3))
def test_envelope_with_base_and_tool_frames_and_threads(kr, threads):
    """The in-place chain kernel against Robot.fk, with a rotated base and a tool offset."""
    robot = _with_frames(kr)
    q = sample_workspace(kr, 9, seed=8)
    dev = ClearanceModel.defaults(kr).sample(kr, 40, torch.Generator().manual_seed(0))
    r = sweep(robot, q, deviations=dev, include_nominal=False, chunk=100, threads=threads)
    err = robot.fk(q[:, None], dev[None]) - robot.fk(q)[:, None]  # (9, 40, 3)
    torch.testing.assert_close(r.err_lower, err.amin(1))
    torch.testing.assert_close(r.err_upper, err.amax(1))
    torch.testing.assert_close(r.dist_upper, err.norm(dim=-1).amax(1))


def test_envelope_inside_linear_hull_up_to_second_order(kr):
    """Deviation box of half-widths s x (1e-3 rad, 1 mm): the sampled envelope (box
    vertices that maximise each axis plus random points) lies inside the linearised hull
    up to C s^2, and touches it to within C s^2 (the hull is attained)."""
    q = sample_workspace(kr, 4, seed=3)
    rad = torch.tensor([1e-3, 1.0, 1.0, 1e-3, 1e-3], dtype=torch.float64).expand(6, 5)
    g = torch.Generator().manual_seed(0)
    C = 0.1  # mm per unit s^2 (observed: 0.036)
    gaps = {}
    for s in (1.0, 0.1, 0.01):
        b = Interval(-rad * s, rad * s)
        worst = 0.0
        for i in range(q.shape[0]):
            sg = torch.sign(kr.param_jacobian(q[i])).reshape(3, 6, 5)
            verts = torch.cat([sg, -sg]) * rad * s  # the maximising / minimising vertices
            rnd = (2 * torch.rand(200, 6, 5, generator=g, dtype=torch.float64) - 1) * rad * s
            r = sweep(kr, q[i:i + 1], deviations=torch.cat([verts, rnd]), linear=False)
            hull, _ = linear_bounds(kr, q[i:i + 1], b)
            assert bool(hull.contains(r.err_lower, atol=C * s * s).all())
            assert bool(hull.contains(r.err_upper, atol=C * s * s).all())
            gap = torch.cat([(r.err_upper - hull.upper).abs(), (r.err_lower - hull.lower).abs()]).max()
            worst = max(worst, gap.item())
        assert worst <= C * s * s
        gaps[s] = worst
    assert gaps[0.1] < 0.02 * gaps[1.0]  # quadratic, not linear
    # and the default clearance model, whose box hull is loose: envelope strictly inside
    r = sweep(kr, n_points=30, n_samples=200, seed=1)
    assert bool(r.linear.contains(r.err_lower).all() and r.linear.contains(r.err_upper).all())
    assert bool((r.dist_upper <= r.lin_dist_upper).all())
    assert 0.2 < r.linear_ratio().median().item() < 1.0


def test_per_axis_reliability(kr):
    r = sweep(kr, n_points=10, n_samples=30, seed=0, allowed_axis_mm=1.0)
    assert r.r_set_axis.shape == (10, 3) and r.eta_axis.shape == (10, 3)
    from torchcal.reliability.rset import r_set
    torch.testing.assert_close(r.r_set_axis, r_set((-1.0, 1.0), (r.err_lower, r.err_upper)))


@pytest.mark.parametrize("device", DEVICES)
def test_device_and_dtype(kr, device):
    r = sweep(kr, n_points=6, n_samples=20, seed=0, device=device, dtype=torch.float32)
    for name in ("q", "positions", "err_lower", "dist_upper", "r_set", "eta", "lin_upper"):
        t = getattr(r, name)
        assert t.device.type == device and t.dtype == torch.float32, name
    ref = sweep(kr, n_points=6, n_samples=20, seed=0)
    torch.testing.assert_close(r.dist_upper.double().cpu(), ref.dist_upper, rtol=0, atol=2e-3)


def test_sweep_argument_errors(kr):
    with pytest.raises(InputError, match="allowed distance error must be a positive number"):
        sweep(kr, n_points=2, allowed_mm=-1.0)
    with pytest.raises(InputError, match="number of samples must be a positive integer"):
        sweep(kr, n_points=2, n_samples=0)
    with pytest.raises(InputError, match=r"deviations: expected shape \(M, 6, 5\)"):
        sweep(kr, n_points=2, deviations=torch.zeros(6, 5))
    with pytest.raises(InputError, match=r"q: expected workspace points of shape \(N, 6\)"):
        sweep(kr, torch.zeros(2, 3, 6))


# -- CSV --------------------------------------------------------------------------------------
def test_csv_round_trip(kr, tmp_path):
    r = sweep(kr, n_points=12, n_samples=20, seed=0)
    path = tmp_path / "sweep.csv"
    write_sweep(r, path)
    record, header = path.read_text().splitlines()[:2]  # the robot it was made for, then the columns
    assert record.startswith("# torchcal-sweep/2 {") and '"name":"kr1000titan"' in record
    assert header == ("point,q1,q2,q3,q4,q5,q6,x,y,z,ex_lo,ex_hi,ey_lo,ey_hi,ez_lo,ez_hi,"
                      "dist_lo,dist_hi,eta,r_set")
    back = read_sweep(path)
    torch.testing.assert_close(back.q, r.q, rtol=1e-15, atol=1e-15)
    for name in ("positions", "err_lower", "err_upper", "dist_lower", "dist_upper", "eta", "r_set"):
        assert torch.equal(getattr(back, name), getattr(r, name)), name
    assert back.lin_lower is None
    with pytest.raises(InputError, match="output exists$"):  # the library names no CLI flag
        write_sweep(r, path)
    write_sweep(r, path, force=True)


def test_csv_errors(tmp_path):
    with pytest.raises(InputError, match="sweep CSV does not exist"):
        read_sweep(tmp_path / "nope.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("point,q1,x\n0,1,2\n")
    with pytest.raises(InputError, match="header must be point,q1,"):
        read_sweep(bad)
    cols = "point,q1,q2,x,y,z,ex_lo,ex_hi,ey_lo,ey_hi,ez_lo,ez_hi,dist_lo,dist_hi,eta,r_set"
    bad.write_text(cols + "\n0," + ",".join(["1"] * 14) + ",abc\n")
    with pytest.raises(InputError, match="row 2, column r_set: not a number: 'abc'"):
        read_sweep(bad)
    bad.write_text(cols + "\n0,1,2\n")
    with pytest.raises(InputError, match="row 2: expected 16 columns, got 3"):
        read_sweep(bad)


# -- command line -----------------------------------------------------------------------------
def _one_line(text: str) -> bool:
    return len(text.strip().splitlines()) == 1


@pytest.mark.parametrize("argv", (
    ["sweep", "--bogus", "--out", "x.csv"],
    ["sweep", "--n", "0", "--out", "x.csv"],
    ["sweep", "--samples", "many", "--out", "x.csv"],
    ["sweep", "--allowed", "-2", "--out", "x.csv"],
    ["sweep", "--n", "5"],  # --out missing
))
def test_cli_bad_option_exits_2_with_one_line(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert _one_line(err) and err.startswith("torchcal sweep: error:")


def test_cli_runs_and_refuses_to_overwrite(tmp_path, capsys):
    out = tmp_path / "s.csv"
    argv = ["sweep", "--robot", "kr1000titan", "--n", "15", "--samples", "50", "--allowed", "2.5",
            "--seed", "1", "--out", str(out), "--no-progress"]
    assert cli.main(argv) == 0
    captured = capsys.readouterr()
    assert "R_set min" in captured.out and "R_set = 1 at" in captured.out
    assert captured.err == ""
    assert len(out.read_text().splitlines()) == 17  # the robot record, the header, 15 rows
    first = out.read_text()
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert _one_line(err) and "output exists; pass --force" in err
    assert cli.main(argv + ["--force"]) == 0
    assert out.read_text() == first  # same seed, same file
    assert cli.main(["sweep", "--robot", "ur5e", "--n", "3", "--out", str(tmp_path / "u.csv"),
                     "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert _one_line(err) and "no default clearance model" in err
    assert not math.isnan(read_sweep(out).r_set.sum().item())


# -- the robot a sweep CSV was made for -------------------------------------------------------
def test_read_sweep_checks_the_robot_it_was_made_for(kr, tmp_path):
    """The first line records the robot; `read_sweep(robot=...)` refuses another robot or
    other joint limits with one line, reads the file of an older torchcal (no record) with
    one warning, and a record line that is not one is an error naming line 1."""
    import dataclasses
    import warnings

    from torchcal.io.robot_file import UnrecordedRobotWarning, robot_fingerprint
    from torchcal.io.sweep_csv import sweep_record

    r = sweep(kr, n_points=6, n_samples=10, seed=2)
    assert r.robot is kr
    path = tmp_path / "sweep.csv"
    write_sweep(r, path)
    assert sweep_record(path)["fingerprint"] == robot_fingerprint(kr)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = read_sweep(path, robot=kr)  # the same robot: no warning
    assert back.robot.same_geometry(kr) and back.robot.name == "kr1000titan"
    assert torch.equal(back.positions, r.positions)
    with pytest.raises(InputError, match=rf"^{path}: made for robot 'kr1000titan' \(fingerprint [0-9a-f]{{12}}\), "
                                         r"not 'ur5e' \(fingerprint [0-9a-f]{12}\): the MD-H table differs at joint"):
        read_sweep(path, robot=torchcal.robot("ur5e"))
    lim = kr.limits.clone()
    lim[0] = torch.deg2rad(torch.tensor([-170.0, 170.0], dtype=torch.float64))
    with pytest.raises(InputError, match=r"not 'kr1000titan' .*: joint 1 limits -150\.\.150 deg in the file, "
                                         r"-170\.\.170 deg given; make the sweep again for this robot$"):
        read_sweep(path, robot=dataclasses.replace(kr, limits=lim))
    # the file of an older torchcal: the same rows without the record line
    old = tmp_path / "old.csv"
    old.write_text("".join(path.read_text().splitlines(keepends=True)[1:]))
    assert sweep_record(old) is None
    with pytest.warns(UnrecordedRobotWarning, match=rf"^{old}: records no robot .*robot 'ur5e'$"):
        back = read_sweep(old, robot=torchcal.robot("ur5e"))
    assert back.robot is None and torch.equal(back.positions, r.positions)
    # a record line that lost its JSON, or is some other comment
    lines = path.read_text().splitlines(keepends=True)
    bad = tmp_path / "bad.csv"
    bad.write_text(lines[0][:200] + "\n" + "".join(lines[1:]))
    with pytest.raises(InputError, match=rf"^{bad}: line 1: the robot record is not valid JSON"):
        read_sweep(bad)
    bad.write_text("# my notes\n" + "".join(lines[1:]))
    with pytest.raises(InputError, match=rf"^{bad}: line 1: expected the robot record \(# torchcal-sweep/2 "):
        read_sweep(bad)
    bad.write_text(lines[0] + ",".join(sweep_columns(5)) + "\n")
    with pytest.raises(InputError, match=rf"^{bad}: line 1 records robot 'kr1000titan' with 6 joints, but the header "
                                         r"has 5 joint columns"):
        read_sweep(bad)


def test_the_record_gives_a_prismatic_joints_unit(tmp_path):
    """A sweep of a robot with a prismatic joint reads back its q in mm without being told."""
    from pathlib import Path

    scara = torchcal.robot(str(Path(__file__).resolve().parents[1] / "examples" / "scara.json"))
    from torchcal.robots.poses import random_poses

    q = random_poses(scara, 5, seed=1)
    r = sweep(scara, q, n_samples=10, seed=2, deviations=1e-2 * torch.randn(3, scara.n, 5, dtype=torch.float64,
                                                              generator=torch.Generator().manual_seed(3)))
    path = tmp_path / "s.csv"
    write_sweep(r, path)
    back = read_sweep(path)
    assert back.prismatic.tolist() == scara.prismatic.tolist()
    torch.testing.assert_close(back.q, r.q, rtol=1e-12, atol=1e-12)


def test_a_record_line_saved_back_by_a_spreadsheet_is_named(kr, tmp_path):
    """A spreadsheet splits the record line at its commas and saves it back quoted: one
    line saying so, not a header error quoting the whole record."""
    import csv

    path, bad = tmp_path / "sweep.csv", tmp_path / "saved.csv"
    write_sweep(sweep(kr, n_points=4, n_samples=10, seed=2), path)
    with open(path, newline="") as src, open(bad, "w", newline="") as dst:
        csv.writer(dst).writerows(csv.reader(src))
    assert bad.read_text().startswith('"# torchcal-sweep/2 {""made_for""')
    with pytest.raises(InputError, match=rf"^{bad}: line 1: the robot record was saved back as quoted CSV cells"):
        read_sweep(bad)


@pytest.mark.parametrize("dtype", (torch.float64, torch.float32))
def test_compiled_envelope_equals_the_eager_one(kr, monkeypatch, dtype):
    """The envelope by the compiled kernel (fk_kernel.c: `fk_native.error_extremes`) and by the
    eager torch kernel (`outer_positions`, where the kernel is off), with a rotated base, a tool
    offset, a prismatic joint, a ragged last vector of sets and several workers."""
    from torchcal.kinematics import fk_native
    if fk_native.kernel() is None:
        pytest.skip("no C compiler here: fk_kernel.c is not built")
    prismatic = torch.zeros(kr.n, dtype=torch.bool)
    prismatic[2] = True
    robot = _with_frames(kr, prismatic=prismatic)
    q = sample_workspace(kr, 23, seed=8)
    dev = ClearanceModel.defaults(kr).sample(kr, 37, torch.Generator().manual_seed(0)) * 20  # mm-sized errors
    runs = []
    run = fk_native.error_extremes
    monkeypatch.setattr(fk_native, "error_extremes", lambda *a: runs.append(a[-3:-1]) or run(*a))
    compiled = sweep(robot, q, deviations=dev, include_nominal=False, chunk=200, threads=2, dtype=dtype)
    assert sorted(runs) == [(0, 16), (16, 23)]  # 200 // 37 points per call, rounded to a multiple of 16
    monkeypatch.setattr(fk_native, "available", lambda *a: None)
    eager = sweep(robot, q, deviations=dev, include_nominal=False, chunk=200, threads=2, dtype=dtype)
    assert len(runs) == 2
    tol = 1e-9 if dtype == torch.float64 else 2e-3  # float32: rounding of positions of some 3000 mm
    assert float(compiled.dist_upper.min()) > 0.5
    for f in ("err_lower", "err_upper", "dist_lower", "dist_upper"):
        torch.testing.assert_close(getattr(compiled, f), getattr(eager, f), rtol=0, atol=tol)
    if dtype == torch.float64:  # and both against Robot.fk's pairs
        err = robot.fk(q[:, None], dev[None]) - robot.fk(q)[:, None]  # (23, 37, 3)
        torch.testing.assert_close(compiled.err_lower, err.amin(1), rtol=0, atol=1e-9)
        torch.testing.assert_close(compiled.dist_upper, err.norm(dim=-1).amax(1), rtol=0, atol=1e-9)


@pytest.mark.parametrize("edit, words", [
    (lambda c: c.update(clearance_mm=[0.0] * 12),
     r"clearance_mm: every seat.s clearance is 0 \(and no tolerance box\)"),
    (lambda c: c.update(clearance_mm=[1000 * v for v in c["clearance_mm"]]),  # micrometres
     r"joint 1: clearances 30 \+ 20 mm over a bearing length of 80 mm tilt its axis by up to 0.625 rad"),
    (lambda c: c.update(bearing_length_mm=[v / 1000 for v in c["bearing_length_mm"]]),  # metres
     r"joint 1: clearances 0.03 \+ 0.02 mm over a bearing length of 0.08 mm tilt its axis by up to 0.625 rad")])
def test_a_clearance_of_no_size_or_in_other_units_is_refused(tmp_path, capsys, edit, words):
    """`sweep --clearance`: all clearances 0 wrote a sweep with R_set = 1 everywhere (and a
    half-width ratio of 1e+290); clearances in micrometres or bearing lengths in metres
    wrote distance bounds of 200 .. 540 mm on a UR5e. Now one line, exit 2, nothing written."""
    from torchcal.cli import main

    obj = {"clearance_mm": [0.03, 0.02] * 6, "bearing_length_mm": [80.0] * 6}
    edit(obj)
    (tmp_path / "c.json").write_text(json.dumps(obj))
    out = tmp_path / "s.csv"
    capsys.readouterr()
    assert main(["sweep", "--robot", "ur5e", "--clearance", str(tmp_path / "c.json"), "--n", "10",
                 "--samples", "10", "--allowed", "0.5", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and re.search(words, err) and not out.exists(), err
    ok = {"clearance_mm": [0.03, 0.02] * 6, "bearing_length_mm": [80.0] * 6}
    (tmp_path / "ok.json").write_text(json.dumps(ok))
    assert main(["sweep", "--robot", "ur5e", "--clearance", str(tmp_path / "ok.json"), "--n", "10",
                 "--samples", "10", "--allowed", "0.5", "--out", str(out)]) == 0


@pytest.mark.parametrize("allowed, words", [
    ("0.0025", r"allowed distance error 0.0025 mm: R_set is at most 0.00\d+ at every point .*in metres\? \(2.5 mm\)"),
    ("2.5", None),
    ("2500", r"allowed distance error 2500 mm: R_set is 1 at every point .*in micrometres\? \(2.5 mm\)")])
def test_an_allowed_error_in_another_unit_warns_once(tmp_path, capsys, allowed, words):
    """`sweep --allowed` in metres (0.0025 for 2.5 mm) left R_set near 0 at every point and
    in micrometres at 1, in silence (the partition of the first splits noise-level values,
    of the second is refused only later). Now one warning line; the README's 2.5 mm none."""
    capsys.readouterr()
    assert cli.main(["sweep", "--robot", "kr1000titan", "--n", "20", "--samples", "20", "--allowed", allowed,
                     "--no-progress", "--out", str(tmp_path / "s.csv")]) == 0
    err = [ln for ln in capsys.readouterr().err.splitlines() if "allowed distance error" in ln]
    if words is None:
        assert err == []
    else:
        assert len(err) == 1 and err[0].startswith("torchcal: warning: ") and re.search(words, err[0]), err


# -- R_set that does not follow from eta -----------------------------------------------------
def _with_r_set(src, dst, r_of):
    """Copy sweep CSV `src` to `dst` with its r_set column replaced by r_of(row index, r_set)."""
    lines = src.read_text().splitlines()
    out = []
    for i, line in enumerate(lines):
        if line.startswith("#") or line.startswith("point"):
            out.append(line)
            continue
        cells = line.split(",")
        cells[-1] = repr(r_of(len(out) - 2, float(cells[-1])))
        out.append(",".join(cells))
    dst.write_text("\n".join(out) + "\n")
    return dst


@pytest.mark.parametrize("kind", ["inverted", "another sweep"])
def test_an_r_set_column_that_is_not_its_etas_is_refused(kr, tmp_path, capsys, kind):
    """R_set is clip((1 + eta) / 2, 0, 1) for the sweep's distance limit. An r_set column of
    1 - R_set or pasted from another sweep's rows (before: read, partitioned, exit 0: the
    least reliable points became level 1) is refused by read_sweep and `torchcal partition`
    in one line naming the file and row; nothing is written."""
    src = tmp_path / "s.csv"
    write_sweep(sweep(kr, sample_workspace(kr, 60, seed=6), n_samples=50), src)
    other = sweep(kr, sample_workspace(kr, 60, seed=7), n_samples=50).r_set.tolist()
    bad = _with_r_set(src, tmp_path / "bad.csv", (lambda i, r: 1.0 - r) if kind == "inverted"
                      else (lambda i, r: other[i]))
    with pytest.raises(InputError, match=r"bad\.csv: row \d+, column r_set: .* is not the R_set of its eta"):
        read_sweep(bad)
    out = tmp_path / "p.json"
    assert cli.main(["partition", str(bad), "--levels", "2", "--zones", "2,1", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert _one_line(err) and "is not the R_set of its eta" in err and str(bad) in err, err
    assert ("1 - R_set in that column" in err) == (kind == "inverted"), err
    assert not out.exists()


@pytest.mark.parametrize("name,n,seed,allowed", [("kr1000titan", 200, 1, 2.5), ("kr1000titan", 100, 3, 1.0),
                                                 ("ur5e", 200, 2, 0.03), ("puma560", 150, 3, 0.05),
                                                 ("ur5e", 100, 4, 100.0)])
def test_sweeps_of_several_robots_read_back(tmp_path, name, n, seed, allowed):
    """Sweeps at R_set near 0, between and at 1 everywhere: each reads back (r_set and eta agree
    to 1e-16 as written) and so does a copy with r_set rounded to 4 digits."""
    import torchcal
    from torchcal.reliability.uncertainty import ClearanceModel

    rob = torchcal.robot(name)
    cl = None if name == "kr1000titan" else ClearanceModel([20.0] * (2 * rob.n), [0.01] * (2 * rob.n),
                                                          [100.0] * rob.n)
    sw = sweep(rob, sample_workspace(rob, n, seed=seed), n_samples=50, model=cl, allowed_mm=allowed)
    write_sweep(sw, tmp_path / "s.csv")
    assert torch.equal(read_sweep(tmp_path / "s.csv").r_set, sw.r_set)
    read_sweep(_with_r_set(tmp_path / "s.csv", tmp_path / "r.csv", lambda i, r: round(r, 4)))


def test_rows_of_sweeps_with_another_allowed_error_are_refused(kr, tmp_path, capsys):
    """Two sweeps (--allowed 2.5 and 2 mm) in one file, points renumbered: each row's r_set
    follows from its eta, but the rows imply two allowed errors D = centre + eta x half-width
    (before: read and partitioned, exit 0, R_set of two scales ranked together). Refused
    naming the file, two rows and both D; each sweep alone reads back."""
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    write_sweep(sweep(kr, sample_workspace(kr, 40, seed=6), n_samples=50, allowed_mm=2.5), a)
    write_sweep(sweep(kr, sample_workspace(kr, 30, seed=3), n_samples=50, allowed_mm=2.0), b)
    rows_b = [line.split(",", 1) for line in b.read_text().splitlines()[2:]]
    merged = tmp_path / "merged.csv"
    merged.write_text(a.read_text() + "".join(f"{40 + int(p)},{rest}\n" for p, rest in rows_b))
    read_sweep(a), read_sweep(b)
    with pytest.raises(InputError, match=r"merged\.csv: rows \d+ and \d+: .* of 2 mm and 2\.5 mm"):
        read_sweep(merged)
    out = tmp_path / "p.json"
    assert cli.main(["partition", str(merged), "--levels", "2", "--zones", "2,1", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert _one_line(err) and "different allowed errors" in err, err
    assert not out.exists()


def test_a_sweep_appended_twice_is_refused(kr, tmp_path, capsys):
    """The rows of a sweep appended to its own file: every point twice (before: read and
    partitioned, exit 0, every zone's point count doubled: 22, 32, 6 became 44, 64, 12, so
    the warning on zones of fewer than 5 points falls silent). Refused naming the file, the
    row and the row it repeats."""
    src = tmp_path / "s.csv"
    write_sweep(sweep(kr, sample_workspace(kr, 60, seed=6), n_samples=50), src)
    twice = tmp_path / "twice.csv"
    twice.write_text(src.read_text() + "\n".join(src.read_text().splitlines()[2:]) + "\n")
    with pytest.raises(InputError, match=r"twice\.csv: row 63, column point: id 0 repeats row 3 \(60 ids repeat\)"):
        read_sweep(twice)
    out = tmp_path / "p.json"
    assert cli.main(["partition", str(twice), "--levels", "2", "--zones", "2,1", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert _one_line(err) and "appended twice" in err, err
    assert not out.exists()


@pytest.mark.parametrize("samples, warned", [("3", True), ("49", True), ("50", False)])
def test_too_few_clearance_states_warn_once(tmp_path, capsys, samples, warned):
    """`sweep --samples 1..3` wrote distance bounds of 0.32-2.04 mm against 1.45-2.81 mm with
    50 states, in silence: each bound is a sample maximum over the states, which converges
    slowly (benchmarks/study_sweep_samples.py). Below MIN_SAMPLES = 50 one warning line
    names the shortfall; 50 and more (the README's 300, docs/scale.md's 1000) none."""
    capsys.readouterr()
    out = tmp_path / "s.csv"
    assert cli.main(["sweep", "--n", "4", "--samples", samples, "--no-progress", "--out", str(out)]) == 0
    err = [ln for ln in capsys.readouterr().err.splitlines() if "clearance states" in ln]
    if warned:
        assert len(err) == 1 and err[0].startswith(f"torchcal: warning: {samples} clearance states are too few"), err
        assert re.search(r"36-45 % under .* 30 states.* 21-31 % with the default 300; use 50 or more", err[0])
    else:
        assert err == []
    assert out.is_file()
