"""Worst-case sweep bounds (torchcal.reliability.worst_case, `sweep(..., bounds="worst")`,
``torchcal sweep --bounds worst``) against an independent plain-numpy brute force: a dense
grid over the seat directions of a case with three loose seats, first order (a numpy
finite-difference Jacobian) and full FK (a numpy MD-H chain batched over states)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import torchcal
from torchcal.cli import main
from torchcal.errors import InputError
from torchcal.io.sweep_csv import read_sweep, sweep_csv_text, write_sweep
from torchcal.kinematics import mdh as K
from torchcal.reliability.sweep import sweep, sweep_states, worst_set
from torchcal.reliability.uncertainty import KR1000_BEARING_LENGTH_MM, ClearanceModel, deviation_map
from torchcal.reliability.worst_case import worst_extremes
from torchcal.robots.workspace import sample_workspace

LOOSE = (2, 3, 5)  # seats with clearance: both of joint 2, the second of joint 3
GRID = 72  # directions per seat in the brute force (5 degrees)


def _model(clearance=0.05):
    c = [clearance if k in LOOSE else 0.0 for k in range(12)]
    return ClearanceModel([50.0] * 12, c, KR1000_BEARING_LENGTH_MM)


def _rot(axis, t):
    """(S, 4, 4) rotations about x, y or z by angles t (S,)."""
    c, s = np.cos(t), np.sin(t)
    T = np.zeros(t.shape + (4, 4))
    T[:, 3, 3] = 1.0
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    k = 3 - i - j
    T[:, i, i], T[:, i, j], T[:, j, i], T[:, j, j], T[:, k, k] = c, -s, s, c, 1.0
    return T


def _np_fk(robot, q, dev):
    """TCP positions (S, 3) mm at one pose q (n,) rad for deviation sets dev (S, n, 5):
    A_i = Rz(theta + q) Tz(d) Tx(a) Rx(alpha) Ry(beta), the base and the tool."""
    table = robot.table.numpy()[None] + dev
    S = dev.shape[0]
    T = np.broadcast_to(robot.base.numpy(), (S, 4, 4)).copy()
    for j in range(robot.n):
        th, d, a, al, be = (table[:, j, i] for i in range(5))
        tr = np.broadcast_to(np.eye(4), (S, 4, 4)).copy()
        tr[:, 0, 3], tr[:, 2, 3] = a, d
        T = T @ _rot("z", th + q[j]) @ tr @ _rot("x", al) @ _rot("y", be)
    return (T @ robot.tool.numpy())[:, :3, 3]


def _np_jacobian(robot, q, h=1e-6):
    """(3, 5n) dTCP / d deviation at q (n,) by central differences of `_np_fk`."""
    m = 5 * robot.n
    dev = np.zeros((2 * m, m))
    dev[np.arange(m), np.arange(m)], dev[m + np.arange(m), np.arange(m)] = h, -h
    p = _np_fk(robot, q, dev.reshape(2 * m, robot.n, 5))
    return ((p[:m] - p[m:]) / (2 * h)).T


@pytest.fixture(scope="module")
def case():
    robot = torchcal.robot("kr1000titan")
    model = _model()
    q = sample_workspace(robot, 4, seed=3)
    dev, _ = sweep_states(robot, n_samples=20, seed=5, model=model)
    cs = worst_set(robot, "worst", model, dev, 5, True)
    J = K.param_jacobian(q, robot.chain)
    return robot, model, q, dev, cs, worst_extremes(J, dev, cs)


def test_ascent_reaches_the_grid_maximum_inside_the_outer_bound(case):
    robot, model, q, dev, cs, (axis, ascent, outer) = case
    D = deviation_map(robot, model).numpy()  # (30, 24): the model's seat -> deviation map
    phi = np.linspace(0, 2 * np.pi, GRID, endpoint=False)
    circle = 0.05 * np.stack([np.cos(phi), np.sin(phi)], 1)  # (A, 2) mm
    # every combination of the three loose seats' directions: seat offsets (A^3, 24)
    u = np.zeros((GRID, GRID, GRID, 12, 2))
    u[:, :, :, LOOSE[0]] = circle[:, None, None]
    u[:, :, :, LOOSE[1]] = circle[None, :, None]
    u[:, :, :, LOOSE[2]] = circle[None, None, :]
    u = u.reshape(-1, 24)
    coarse = u.reshape(GRID, GRID, GRID, 24)[::3, ::3, ::3].reshape(-1, 24)  # 24^3 states for the full FK
    for p in range(q.shape[0]):
        qp = q[p].numpy()
        G = _np_jacobian(robot, qp) @ D  # (3, 24)
        first = np.linalg.norm(u @ G.T, axis=1).max()
        a = float(ascent[p])
        assert first * (1 - 1e-9) <= a <= first * (1 + 2e-3)  # the grid max, to its 5-degree spacing
        # the triangle inequality on each seat's largest contribution (sigma_max of its 3 x 2 block)
        bound = sum(0.05 * np.linalg.svd(G[:, 2 * k:2 * k + 2], compute_uv=False)[0] for k in LOOSE)
        assert float(outer[p]) == pytest.approx(bound, rel=1e-6)
        assert a <= float(outer[p]) * (1 + 1e-12)
        # exact axis range: +-sum of each seat's row norm
        rng = 0.05 * sum(np.linalg.norm(G[:, 2 * k:2 * k + 2], axis=1) for k in LOOSE)
        np.testing.assert_allclose(axis[p].numpy(), rng, rtol=1e-6)
        # full FK over the coarse grid: within second-order terms of the first-order max
        dev_full = (coarse @ D.T).reshape(-1, robot.n, 5)
        full = np.linalg.norm(_np_fk(robot, qp, dev_full) - _np_fk(robot, qp, np.zeros((1, robot.n, 5))), axis=1)
        assert full.max() == pytest.approx(np.linalg.norm(coarse @ G.T, axis=1).max(), rel=1e-4)
        assert full.max() <= a * (1 + 1e-4)


def test_worst_sweep_contains_the_sampled_one_and_default_is_unchanged(tmp_path):
    robot = torchcal.robot("kr1000titan")
    kw = dict(n_points=40, n_samples=30, seed=2, block=16, threads=1)
    default = sweep(robot, **kw)
    sampled = sweep(robot, bounds="sampled", **kw)
    worst = sweep(robot, bounds="worst", **kw)
    text = sweep_csv_text(default)
    assert sweep_csv_text(sampled) == text and "dist_hi_outer" not in text
    assert default.bounds == "sampled" and default.dist_upper_outer is None
    assert torch.equal(worst.q, default.q) and torch.equal(worst.dist_lower, default.dist_lower)
    assert bool((worst.dist_upper >= default.dist_upper).all())
    assert bool((worst.dist_upper > 1.05 * default.dist_upper).any())  # 30 states fall short somewhere
    assert bool((worst.dist_upper_outer >= worst.dist_upper).all())
    assert bool((worst.err_lower <= default.err_lower).all() and (worst.err_upper >= default.err_upper).all())
    assert bool((worst.r_set <= default.r_set).all())
    back = read_sweep(write_sweep(worst, tmp_path / "w.csv"), robot=robot)
    assert back.bounds == "worst" and torch.equal(back.dist_upper_outer, worst.dist_upper_outer)
    assert torch.equal(back.r_set, worst.r_set) and torch.equal(back.dist_upper, worst.dist_upper)


def test_worst_refuses_what_it_cannot_bound():
    robot = torchcal.robot("kr1000titan")
    with pytest.raises(InputError, match="bounds must be one of sampled, worst, got 'worse'"):
        sweep(robot, n_points=2, n_samples=2, bounds="worse")
    with pytest.raises(InputError, match="include_nominal=True"):
        sweep(robot, n_points=2, n_samples=2, bounds="worst", include_nominal=False)
    dev, _ = sweep_states(robot, n_samples=4, seed=0)
    with pytest.raises(InputError, match="not the clearance states"):
        worst_set(robot, "worst", None, dev, 1, True)  # drawn with seed 0, not 1


def test_cli_unknown_bounds_one_line(tmp_path, capsys):
    out = tmp_path / "s.csv"
    with pytest.raises(SystemExit) as exc:
        main(["sweep", "--n", "2", "--bounds", "worse", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1 and "--bounds: invalid choice: 'worse'" in err[0]
    assert not out.exists()


def test_worst_blocks_equal_the_in_process_sweep_and_do_not_mix(tmp_path):
    from torchcal.errors import OutputExistsError
    from torchcal.workflows.distributed import plan_sweep, run_sweep

    robot = torchcal.robot("kr1000titan")
    kw = dict(n_points=30, n_samples=20, seed=4, block=8)
    out = tmp_path / "s.csv"
    plan = plan_sweep(robot, bounds="worst", **kw)
    assert plan.manifest()["bounds"] == "worst" and "bounds" not in plan_sweep(robot, **kw).manifest()
    done = []

    def stop(index):
        done.append(index)
        if len(done) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(plan, out, threads=2, on_block=stop)
    with pytest.raises((InputError, OutputExistsError), match="bounds"):  # a sampled run cannot take it up
        run_sweep(plan_sweep(robot, **kw), out)
    run_sweep(plan, out, threads=2)
    assert out.read_text() == sweep_csv_text(sweep(robot, bounds="worst", **kw))
