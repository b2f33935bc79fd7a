"""The compiled perturbed-FK kernel (torchcal/kinematics/fk_kernel.c, `fk_native`) behind
`Robot.fk` without gradients on a CPU: against the eager torch kernel (`positions_into`, the
reference) and the plain-numpy MD-H chain of tests/npsim.py, on 6- and 7-joint robots (a
preset, URDF imports, prismatic joints, base and tool frames), odd and non-contiguous
batches and its piece boundaries; the grid it reads a broadcast batch as; its build, its
switch and the eager fallback; and gradients, which go through torch."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

import torchcal
from tests.npsim import numpy_fk
from torchcal.io.urdf import robot_from_urdf
from torchcal.kinematics import fk_native
from torchcal.kinematics import mdh as K
from torchcal.rotations import rotvec_to_matrix

pytestmark = pytest.mark.skipif(fk_native.kernel() is None, reason="no C compiler here: fk_kernel.c is not built")


@pytest.fixture
def calls(monkeypatch):
    """The grids the compiled kernel was run on (a spy on fk_native.fk_positions)."""
    seen = []
    run = fk_native.fk_positions

    def spy(lib, pose, link, lin, base, g, out, workers):
        seen.append(g)
        return run(lib, pose, link, lin, base, g, out, workers)

    monkeypatch.setattr(fk_native, "fk_positions", spy)
    return seen


def _framed(robot):
    """The robot on a tilted, shifted base with a rotated, offset tool."""
    base, tool = torch.eye(4, dtype=torch.float64), torch.eye(4, dtype=torch.float64)
    base[:3, :3] = rotvec_to_matrix(torch.tensor([0.04, -0.03, 0.7], dtype=torch.float64))
    base[:3, 3] = torch.tensor([120.0, -60.0, 300.0], dtype=torch.float64)
    tool[:3, :3] = rotvec_to_matrix(torch.tensor([0.1, 0.2, -0.1], dtype=torch.float64))
    tool[:3, 3] = torch.tensor([15.0, -25.0, 210.0], dtype=torch.float64)
    return dataclasses.replace(robot, base=base, tool=tool)


def _urdf_robot(tmp_path, key):
    from tests.test_urdf import _write  # the test URDFs: a tilted 7-axis arm, a slide with fixed joints
    path, base, tip = _write(tmp_path, key)
    return robot_from_urdf(path, base, tip)


def _robot(name, tmp_path):
    if name == "kr1000titan":
        return torchcal.robot("kr1000titan")
    if name == "puma560+frames+slide":
        r = _framed(torchcal.robot("puma560"))
        prismatic = torch.zeros(r.n, dtype=torch.bool)
        prismatic[2] = True
        return dataclasses.replace(r, prismatic=prismatic)
    return _urdf_robot(tmp_path, name)


def _q(robot, shape, gen):
    lo, hi = robot.limits[:, 0], robot.limits[:, 1]
    return lo + (hi - lo) * torch.rand(*shape, robot.n, generator=gen, dtype=torch.float64)


def _params(robot, shape, gen, scale=1.0):
    s = torch.tensor([1e-3, 0.5, 0.5, 1e-3, 1e-3], dtype=torch.float64) * scale
    return torch.randn(*shape, robot.n, 5, generator=gen, dtype=torch.float64) * s


def _eager(robot, q, params):
    """The eager torch kernel into a fresh output of the broadcast batch."""
    qb, pb = q.shape[:-1], () if params is None else params.shape[:-2]
    out = torch.empty(*torch.broadcast_shapes(qb, pb), 3, dtype=q.dtype)
    return K.positions_into(q, robot.chain.to(q), params, out)


@pytest.mark.parametrize("name", ["kr1000titan", "puma560+frames+slide", "arm7", "pris"])
def test_native_equals_eager_kernel_and_numpy_chain(name, tmp_path, calls):
    robot = _robot(name, tmp_path)
    assert robot.n == {"arm7": 7, "pris": 3}.get(name, 6)
    gen = torch.Generator().manual_seed(3)
    q = _q(robot, (37,), gen)  # (P, n)
    params = _params(robot, (5, 1), gen, scale=4.0)  # (M, 1, n, 5)
    got = robot.fk(q, params)  # (M, P, 3)
    assert calls and calls[-1] == fk_native.Grid(5, 37, 0, 1, 1, 0)
    for m in range(5):
        want = numpy_fk(robot, q.numpy(), params[m, 0].numpy())
        np.testing.assert_allclose(got[m].numpy(), want, rtol=0, atol=1e-9)
    torch.testing.assert_close(got, _eager(robot, q, params), rtol=0, atol=1e-9)
    # float32: the same kernel in single precision, within its rounding of metre-sized arms
    got32 = robot.to(dtype=torch.float32).fk(q.float(), params.float())
    assert got32.dtype == torch.float32 and calls[-1].B == 37
    scale = max(1.0, float(got.abs().max()))
    torch.testing.assert_close(got32.double(), got, rtol=0, atol=2e-6 * scale)
    torch.testing.assert_close(got32, _eager(robot.to(dtype=torch.float32), q.float(), params.float()),
                               rtol=0, atol=1e-6 * scale)


@pytest.mark.parametrize("case", ["P=1", "M=1", "one pose", "no params", "zip", "sets inner", "3-d", "no grid"])
def test_odd_shapes_equal_the_eager_kernel(case, calls):
    robot = _framed(torchcal.robot("ur5e"))
    gen = torch.Generator().manual_seed(7)
    q, params, grid = {
        "P=1": (_q(robot, (1,), gen), _params(robot, (9, 1), gen), fk_native.Grid(1, 9, 0, 0, 0, 1)),
        "M=1": (_q(robot, (11,), gen), _params(robot, (1, 1), gen), fk_native.Grid(1, 11, 0, 1, 0, 0)),
        "one pose": (_q(robot, (), gen), None, fk_native.Grid(1, 1, 0, 0, 0, 0)),
        "no params": (_q(robot, (4, 6), gen), None, fk_native.Grid(1, 24, 0, 1, 0, 0)),
        "zip": (_q(robot, (23,), gen), _params(robot, (23,), gen), fk_native.Grid(1, 23, 0, 1, 0, 1)),
        "sets inner": (_q(robot, (6, 1), gen), _params(robot, (19,), gen), fk_native.Grid(6, 19, 1, 0, 0, 1)),
        "3-d": (_q(robot, (1, 4, 5), gen), _params(robot, (3, 1, 1), gen), fk_native.Grid(3, 20, 0, 1, 1, 0)),
        "no grid": (_q(robot, (3, 1, 5), gen), _params(robot, (1, 4, 5), gen), None),
    }[case]
    got = robot.fk(q, params)
    want = _eager(robot, q, params)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-9)
    if case == "no grid":  # poses vary in dims 0, 2 and sets in 1, 2: no split serves, the eager kernel ran
        assert calls == []
    else:
        assert calls[-1] == grid
    if params is not None:  # each (pose, set) pair: the plain-numpy chain
        qb, pb = np.broadcast_arrays(q.numpy()[..., None], params.numpy())
        for k in np.ndindex(got.shape[:-1]):
            np.testing.assert_allclose(got[k].numpy(), numpy_fk(robot, qb[k][None, :, 0], pb[k])[0],
                                       rtol=0, atol=1e-9)


def test_grid_reads_a_broadcast_batch():
    G = fk_native.Grid
    assert fk_native.grid((7, 5), (1, 5), (7, 1)) == G(7, 5, 0, 1, 1, 0)  # sets outer, poses inner
    assert fk_native.grid((7, 5), (7, 1), (1, 5)) == G(7, 5, 1, 0, 0, 1)  # poses outer, sets inner
    assert fk_native.grid((7, 5), (7, 5), (1, 1)) == G(1, 35, 0, 1, 0, 0)  # all poses, one set
    assert fk_native.grid((7, 5), (7, 5), (7, 1)) == G(7, 5, 5, 1, 1, 0)  # poses everywhere, sets per row
    assert fk_native.grid((7, 1, 5), (1, 1, 5), (7, 1, 1)) == G(7, 5, 0, 1, 1, 0)  # size-1 dims dropped
    assert fk_native.grid((2, 3, 4), (2, 1, 4), (2, 3, 1)) is None
    assert fk_native.grid((), (), ()) == G(1, 1, 0, 0, 0, 0)


def test_pieces_and_threads_give_the_same_bits(monkeypatch, calls):
    """Across the kernel's pieces (PIECE pairs, here not a multiple of the inner size) and
    any number of worker threads, every pair is computed the same way."""
    robot = _framed(torchcal.robot("kr1000titan"))
    gen = torch.Generator().manual_seed(5)
    q = _q(robot, (301,), gen)
    params = _params(robot, (40, 1), gen)
    monkeypatch.setattr(fk_native, "PIECE", 1000)  # 12 040 pairs: 13 pieces, cut inside rows
    outs = []
    for workers in ("1", "3"):
        monkeypatch.setenv("TORCHCAL_THREADS", workers)
        outs.append(robot.fk(q, params))
    assert len(calls) == 2
    assert torch.equal(outs[0], outs[1])
    torch.testing.assert_close(outs[0], _eager(robot, q, params), rtol=0, atol=1e-9)
    np.testing.assert_allclose(outs[0][39].numpy(), numpy_fk(robot, q.numpy(), params[39, 0].numpy()),
                               rtol=0, atol=1e-9)


def test_non_contiguous_inputs(calls):
    robot = torchcal.robot("kr1000titan")
    gen = torch.Generator().manual_seed(9)
    q = _q(robot, (2 * 29,), gen)[::2]  # every other row
    params = torch.randn(robot.n, 1, 6, 5, generator=gen, dtype=torch.float64).permute(2, 1, 0, 3) * 0.01
    assert params.shape == (6, 1, robot.n, 5) and not q.is_contiguous() and not params.is_contiguous()
    got = robot.fk(q, params)
    assert calls and calls[-1] == fk_native.Grid(6, 29, 0, 1, 1, 0)
    torch.testing.assert_close(got, _eager(robot, q.contiguous(), params.contiguous()), rtol=0, atol=1e-9)


def test_gradients_go_through_torch(calls):
    robot = torchcal.robot("kr1000titan")
    gen = torch.Generator().manual_seed(11)
    q = _q(robot, (8,), gen)
    params = _params(robot, (3, 1), gen).requires_grad_(True)
    out = robot.fk(q, params)
    assert out.requires_grad and calls == []
    out.square().sum().backward()
    leaf = params.detach().clone().requires_grad_(True)
    K.positions(q, robot.chain, leaf).square().sum().backward()
    torch.testing.assert_close(params.grad, leaf.grad)
    with torch.no_grad():  # no gradient asked for: the compiled kernel, the same values
        torch.testing.assert_close(robot.fk(q, params), out.detach(), rtol=0, atol=1e-9)
    assert len(calls) == 1


def test_turned_off_or_without_a_compiler_the_eager_kernel_runs(tmp_path, monkeypatch, calls):
    build = fk_native.kernel.__wrapped__  # without the per-process cache
    monkeypatch.setenv("TORCHCAL_CACHE", str(tmp_path))
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.delenv(fk_native.SWITCH, raising=False)
    assert build() is not None
    built = [p.name for p in tmp_path.iterdir()]
    assert len(built) == 1 and built[0].startswith("fk_kernel-") and built[0].endswith(".so")
    monkeypatch.setenv(fk_native.SWITCH, "torch")
    assert build() is None
    monkeypatch.delenv(fk_native.SWITCH)
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    assert build() is None
    # where it is None, Robot.fk runs the eager kernel: the same answer
    robot = _framed(torchcal.robot("kr1000titan"))
    gen = torch.Generator().manual_seed(13)
    q, params = _q(robot, (50,), gen), _params(robot, (4, 1), gen)
    native = robot.fk(q, params)
    assert len(calls) == 1
    monkeypatch.setattr(fk_native, "kernel", lambda: None)
    eager = robot.fk(q, params)
    assert len(calls) == 1
    torch.testing.assert_close(native, eager, rtol=0, atol=1e-9)
    assert math.isclose(float(native.abs().max()), float(eager.abs().max()), rel_tol=1e-12)
