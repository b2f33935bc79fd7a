"""Tensor fuzzy c-means (torchcal.partition.fcm), the hierarchical partition (torchcal.partition.zones)
and `torchcal partition`."""

import csv
import json
import math
import sys

import numpy as np
import pytest
import torch

from torchcal import cli
from torchcal.errors import InputError
from torchcal.partition import _native
from torchcal.partition.fcm import fcm, memberships, objective
from torchcal.io.partition_file import (load_partition, partition_from_dict, partition_from_json,
                                        partition_to_json, save_partition)
from torchcal.partition.zones import partition_workspace

skfuzzy = pytest.importorskip("skfuzzy")

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def blobs(n_per, centers, std, seed):
    rng = np.random.default_rng(seed)
    centers = np.asarray(centers, dtype=np.float64)
    x = np.concatenate([c + std * rng.standard_normal((n_per, centers.shape[1])) for c in centers])
    y = np.repeat(np.arange(len(centers)), n_per)
    return x, y


def use_kernel(name, monkeypatch):
    """Make fcm iterate with one kernel: "fused" (fcm_kernel.c, m = 2, float64, CPU; the test
    is skipped where no C compiler builds it) or "torch" (the eager one). Returns the list of
    the fused passes run: True accepted, False failed its check and redone eagerly."""
    mod = sys.modules["torchcal.partition.fcm"]
    runs = []
    if name == "torch":
        monkeypatch.setattr(mod, "_fused_kernel", lambda *args: None)
        return runs
    if _native.kernel() is None:
        pytest.skip("no C compiler here: the fused FCM kernel is not built")
    fused_pass = mod._fused_pass

    def spy(*args):
        out = fused_pass(*args)
        runs.append(out is not None)
        return out

    monkeypatch.setattr(mod, "_fused_pass", spy)
    return runs


@pytest.fixture(params=["fused", "torch"])
def kernel(request, monkeypatch):
    """(name, fused passes run) for each kernel in turn (`use_kernel`)."""
    return request.param, use_kernel(request.param, monkeypatch)


def ran(kernel) -> bool:
    """The test ran on the kernel it names: the eager one, or fused passes (all accepted)."""
    name, runs = kernel
    return name == "torch" or (len(runs) > 0 and all(runs))


def skip_fused_unless_m2(kernel, m):
    if kernel[0] == "fused" and m != 2.0:
        pytest.skip("the fused kernel is m = 2 only (other m run the eager one)")


# ------------------------------------------------------------------ FCM vs scikit-fuzzy

@pytest.mark.parametrize("d", [1, 3])
@pytest.mark.parametrize("m", [2.0, 1.7])
def test_fcm_matches_skfuzzy_from_same_start(d, m):
    rng = np.random.default_rng(d)
    x = rng.standard_normal((600, d))
    x[:200] += 3.0
    u0 = rng.random((3, 600))
    u0 /= u0.sum(axis=0)
    c_ref, u_ref, _, _, _, p_ref, _ = skfuzzy.cluster.cmeans(x.T, 3, m, 1e-7, 300, init=u0)
    res = fcm(torch.tensor(x), 3, m=m, eps=1e-7, init_u=u0, chunk_size=97)  # many chunks, a ragged last one
    torch.testing.assert_close(res.centers, torch.tensor(c_ref), rtol=0, atol=1e-6)
    torch.testing.assert_close(res.memberships, torch.tensor(u_ref), rtol=0, atol=1e-6)
    assert res.n_iter == p_ref
    d2 = ((x[None, :, :] - c_ref[:, None, :]) ** 2).sum(-1)  # (c, N)
    assert res.objective == pytest.approx(float((u_ref ** m * d2).sum()), rel=1e-9)
    assert res.objective == pytest.approx(objective(x, res.centers, res.memberships, m), rel=1e-12)


def numpy_fcm(x, u0, m, eps, max_iter):
    """FCM written from eqs. 26-28 in plain numpy (no torchcal code): x (N, d), u0 (c, N)
    with columns summing to 1. Each iteration: centers from U (eq. 27), memberships from
    those centers (eq. 28, the ratio form literally), stop when ||U_new - U_old||_F < eps.
    Returns (centers the returned U was computed from, U, J of eq. 26 for them, iterations)."""
    u = u0
    for it in range(1, max_iter + 1):
        um = u ** m
        v = um @ x / um.sum(axis=1, keepdims=True)  # (c, d), eq. 27
        dist = np.sqrt(((x[None, :, :] - v[:, None, :]) ** 2).sum(-1))  # (c, N)
        u_new = 1.0 / ((dist[:, None, :] / dist[None, :, :]) ** (2.0 / (m - 1.0))).sum(axis=1)  # eq. 28
        change = np.linalg.norm(u_new - u)
        u = u_new
        if change < eps:
            break
    return v, u, float((u ** m * dist ** 2).sum()), it


@pytest.mark.parametrize("d, m, eps, chunk", [(1, 2.0, 1e-9, None), (1, 2.0, 1e-9, 37), (3, 2.0, 1e-9, 37),
                                               (2, 1.7, 1e-9, 50), (3, 2.0, 0.0, None), (2, 3.0, 0.0, 37)])
def test_fcm_matches_the_formulas_in_numpy(d, m, eps, chunk, kernel):
    # tight: the kernel's last bits differ from numpy's (summation order, 1/S vs the ratio form)
    skip_fused_unless_m2(kernel, m)
    x, _ = blobs(150, [[0.0] * d, [4.0] + [0.0] * (d - 1), [0.0] * (d - 1) + [-5.0]], 0.8, 11)
    u0 = np.random.default_rng(12).random((3, 450))
    u0 /= u0.sum(axis=0)
    v_ref, u_ref, j_ref, it_ref = numpy_fcm(x, u0, m, eps, 40)
    assert it_ref < 40 if eps > 0 else it_ref == 40  # converged runs exercise the stopping rule
    res = fcm(x, 3, m=m, eps=eps, max_iter=40, init_u=u0, chunk_size=chunk)
    assert ran(kernel)
    assert res.n_iter == it_ref
    np.testing.assert_allclose(res.memberships.numpy(), u_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.centers.numpy(), v_ref, rtol=1e-12, atol=1e-12)
    assert res.objective == pytest.approx(j_ref, rel=1e-12)


def test_restarts_that_stop_at_different_iterations_match_numpy(kernel):
    x, _ = blobs(100, [[0.0, 0.0], [3.0, 0.5], [0.5, 3.5], [4.0, 4.0]], 0.9, 13)
    u0 = np.random.default_rng(14).random((5, 4, 400))
    u0 /= u0.sum(axis=1, keepdims=True)
    refs = [numpy_fcm(x, u0[r], 2.0, 1e-8, 300) for r in range(5)]
    assert len({r[3] for r in refs}) > 1  # the batch shrinks as restarts stop
    res = fcm(x, 4, eps=1e-8, init_u=u0, restarts=5, chunk_size=64)
    assert ran(kernel)
    # restarts that reach the same minimum (here all, clusters permuted) have objectives
    # equal to rounding, so which one is kept depends on the last bits: the kept one must
    # reach the lowest objective and be, to 1e-12, numpy's run of one of those restarts
    j_min = min(r[2] for r in refs)
    kept = [r for r in range(5) if refs[r][2] <= j_min * (1 + 1e-12) and refs[r][3] == res.n_iter
            and np.abs(res.memberships.numpy() - refs[r][1]).max() < 1e-12]
    assert len(kept) == 1
    v_ref, u_ref, j_ref, it_ref = refs[kept[0]]
    assert res.n_iter == it_ref and res.objective == pytest.approx(j_ref, rel=1e-12)
    np.testing.assert_allclose(res.memberships.numpy(), u_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.centers.numpy(), v_ref, rtol=1e-12, atol=1e-12)


def test_a_restart_cut_at_max_iter_beside_one_that_stopped_earlier_matches_numpy(kernel):
    # at the last allowed iteration one restart is left: its memberships are written during
    # that pass; the kept one stopped earlier (lower objective), so U is recomputed from it
    x, y = blobs(60, [[0.0], [3.0], [6.0], [20.0]], 1.0, 21)
    good = np.full((3, 240), 0.05)
    good[np.minimum(y, 2), np.arange(240)] = 0.9  # near the planted labels: stops first
    rnd = np.random.default_rng(0).random((3, 240))
    v_g, u_g, j_g, it_g = numpy_fcm(x, good / good.sum(0), 2.0, 1e-3, 300)
    v_r, u_r, j_r, it_r = numpy_fcm(x, rnd / rnd.sum(0), 2.0, 1e-3, it_g + 1)
    assert it_r == it_g + 1 and j_r > j_g * (1 + 1e-9)  # cut, not converged: the stopped one wins
    for init, (v, u, j, it) in ((np.stack([rnd, good]), (v_g, u_g, j_g, it_g)), (rnd, (v_r, u_r, j_r, it_r))):
        res = fcm(x, 3, eps=1e-3, max_iter=it_g + 1, init_u=init, restarts=len(init) if init.ndim == 3 else 1,
                  chunk_size=50)
        assert ran(kernel)
        assert res.n_iter == it and res.objective == pytest.approx(j, rel=1e-12)
        np.testing.assert_allclose(res.memberships.numpy(), u, rtol=0, atol=1e-12)
        np.testing.assert_allclose(res.centers.numpy(), v, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("d, c, n, eps", [
    (3, 4, 8205, 0.0),   # two full blocks of 4096 points and a ragged end of 13 (not a multiple of 8)
    (2, 5, 4103, 1e-9),  # converged: the norm against the start, then against the previous centers
    (1, 2, 5, 0.0),      # fewer points than one group of eight
    (4, 7, 1003, 1e-9),  # beyond the specialised d <= 3, c <= 6: the general loop
])
def test_fused_kernel_matches_the_formulas_in_numpy(d, c, n, eps, monkeypatch):
    # the fused kernel's sums per lane, per block of 4096 points and over the blocks, its
    # ragged ends and product form of eq. 28, against numpy_fcm (independent code)
    runs = use_kernel("fused", monkeypatch)
    rng = np.random.default_rng(n)
    centers = rng.uniform(-6.0, 6.0, (c, d))
    x = centers[rng.integers(0, c, n)] + rng.standard_normal((n, d))
    u0 = rng.random((c, n))
    v_ref, u_ref, j_ref, it_ref = numpy_fcm(x, u0 / u0.sum(axis=0), 2.0, eps, 15 if eps == 0 else 300)
    assert it_ref < 300
    res = fcm(x, c, eps=eps, max_iter=15 if eps == 0 else 300, init_u=u0)
    assert len(runs) == res.n_iter + (eps > 0) and all(runs)  # every iteration (+ U at the end when eps > 0)
    assert res.n_iter == it_ref
    np.testing.assert_allclose(res.memberships.numpy(), u_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.centers.numpy(), v_ref, rtol=1e-12, atol=1e-12)
    assert res.objective == pytest.approx(j_ref, rel=1e-12)


def test_fused_kernel_hands_over_where_its_products_overflow(monkeypatch):
    # at 1e40 the squared distances are ~1e80 and the product form's products of c - 1 = 5 of
    # them overflow: the fused pass fails its check and the eager kernel redoes the iteration
    runs = use_kernel("fused", monkeypatch)
    x, _ = blobs(40, [[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 3.0], [3.0, 3.0, 3.0],
                      [-3.0, 0.0, 3.0]], 0.5, 9)
    x = x * 1e40
    u0 = np.random.default_rng(9).random((6, 240))
    v_ref, u_ref, j_ref, it_ref = numpy_fcm(x, u0 / u0.sum(axis=0), 2.0, 0.0, 8)
    res = fcm(x, 6, eps=0.0, max_iter=8, init_u=u0)
    assert runs == [False]  # tried once; later iterations stay on the checked eager path
    assert res.n_iter == it_ref
    np.testing.assert_allclose(res.memberships.numpy(), u_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.centers.numpy() / 1e40, v_ref / 1e40, rtol=1e-12, atol=1e-12)
    assert res.objective == pytest.approx(j_ref, rel=1e-12)


def test_fused_kernel_is_built_once_into_the_cache_and_can_be_turned_off(tmp_path, monkeypatch):
    import shutil

    if not (shutil.which("cc") or shutil.which("gcc")):
        pytest.skip("no C compiler here")
    build = _native.kernel.__wrapped__  # without the per-process cache
    monkeypatch.setenv("TORCHCAL_CACHE", str(tmp_path))
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.delenv("TORCHCAL_FCM_KERNEL", raising=False)
    assert build() is not None
    built = list(tmp_path.iterdir())
    assert len(built) == 1 and built[0].name.startswith("fcm_kernel-") and built[0].suffix == ".so"  # no temporary left
    stamp = built[0].stat().st_mtime_ns
    assert build() is not None and list(tmp_path.iterdir()) == built and built[0].stat().st_mtime_ns == stamp
    monkeypatch.setenv("TORCHCAL_FCM_KERNEL", "torch")
    assert build() is None
    monkeypatch.delenv("TORCHCAL_FCM_KERNEL")
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    assert build() is None  # the eager kernel runs


def test_chunking_and_default_start_do_not_change_results():
    x, _ = blobs(100, [[0, 0], [4, 0], [0, 4]], 0.5, 0)
    a = fcm(x, 3, seed=3, chunk_size=17)
    b = fcm(x, 3, seed=3)
    torch.testing.assert_close(a.centers, b.centers)
    torch.testing.assert_close(a.memberships, b.memberships)
    assert a.n_iter == b.n_iter
    c = fcm(x, 3, seed=3)  # explicit generator: reproducible, no global RNG
    torch.testing.assert_close(b.memberships, c.memberships, rtol=0, atol=0)


@pytest.mark.parametrize("d", [1, 2, 3])
def test_squared_distances_are_the_differences_squared_bit_for_bit(d):
    # the first feature's (x - v)^2 in one pass (mse_loss) gives the bits of x - v times
    # itself, the further features added by a fused multiply-add: memberships unchanged
    from torchcal.partition.fcm import _sq_dist

    g = torch.Generator().manual_seed(d)
    x = torch.randn(d, 1000, generator=g, dtype=torch.float64) * 7.0  # (d, N)
    V = torch.randn(2, 3, d, generator=g, dtype=torch.float64) * 5.0  # (R, c, d)
    t = x[0] - V[..., 0, None]
    ref = t * t
    for k in range(1, d):
        t = x[k] - V[..., k, None]
        ref = torch.addcmul(ref, t, t)
    assert torch.equal(_sq_dist(x.unbind(0), V), ref)
    np.testing.assert_allclose(ref.numpy(), ((x.T.numpy()[None, None] - V.numpy()[:, :, None]) ** 2).sum(-1),
                               rtol=1e-14)


def test_batched_restarts_keep_the_best_single_run():
    rng = np.random.default_rng(5)
    x = rng.standard_normal((300, 2))
    u0 = rng.random((4, 5, 300))
    res = fcm(x, 5, eps=1e-8, init_u=u0, restarts=4)
    singles = [fcm(x, 5, eps=1e-8, init_u=u0[r]) for r in range(4)]
    best = min(range(4), key=lambda r: singles[r].objective)
    assert len({s.n_iter for s in singles}) > 1  # restarts converge at different iterations
    assert res.objective == pytest.approx(singles[best].objective, rel=1e-12)
    assert res.n_iter == singles[best].n_iter
    torch.testing.assert_close(res.centers, singles[best].centers)
    torch.testing.assert_close(res.memberships, singles[best].memberships)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_fcm_keeps_dtype_and_device(device, dtype):
    x, _ = blobs(50, [[0.0], [5.0]], 0.3, 1)
    xt = torch.tensor(x, dtype=dtype, device=device)
    res = fcm(xt, 2, restarts=3)
    assert res.centers.dtype == dtype and res.centers.device.type == device
    assert res.memberships.shape == (2, 100)
    torch.testing.assert_close(res.memberships.sum(0), torch.ones(100, dtype=dtype, device=device))


def test_point_exactly_on_a_center():
    x = torch.tensor([0.0, 1.0, 2.0, 10.0, 11.0], dtype=torch.float64)
    u = memberships(x, [[2.0], [10.0], [10.0]])
    torch.testing.assert_close(u[:, 2], torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64), rtol=0, atol=0)
    torch.testing.assert_close(u[:, 3], torch.tensor([0.0, 0.5, 0.5], dtype=torch.float64), rtol=0, atol=0)
    assert torch.isfinite(u).all()
    # a start whose first center is exactly the point x=2: eq. 28 hits d = 0 inside fcm
    u0 = torch.tensor([[0, 0, 1, 0, 0], [1, 1, 0, 1, 1]], dtype=torch.float64)
    res = fcm(x, 2, init_u=u0, max_iter=1, m=1.5)
    torch.testing.assert_close(res.centers[0], torch.tensor([2.0], dtype=torch.float64))
    torch.testing.assert_close(res.memberships[:, 2], torch.tensor([1.0, 0.0], dtype=torch.float64), rtol=0, atol=0)
    assert torch.isfinite(res.memberships).all() and math.isfinite(res.objective)
    # many exact duplicates (R_set = 1 saturates): still finite, columns sum to 1
    r = torch.cat([torch.ones(50), torch.linspace(0.6, 0.99, 50)]).double()
    res = fcm(r, 4, restarts=3)
    assert torch.isfinite(res.memberships).all()
    torch.testing.assert_close(res.memberships.sum(0), torch.ones(100, dtype=torch.float64))


@pytest.mark.parametrize("scale", [1e-30, 1e30])
def test_extreme_scales_take_the_careful_path(scale):
    # m = 1.1 gives w = d^-20: it under/overflows at these scales, eq. 28 itself does not
    x, _ = blobs(30, [[0.0, 0.0], [3.0, 1.0]], 0.5, 6)
    u0 = np.random.default_rng(6).random((2, 60))
    ref = fcm(x, 2, m=1.1, init_u=u0, max_iter=20)
    res = fcm(x * scale, 2, m=1.1, init_u=u0, max_iter=20)
    torch.testing.assert_close(res.memberships, ref.memberships, rtol=0, atol=1e-9)
    torch.testing.assert_close(res.centers / scale, ref.centers, rtol=1e-9, atol=1e-12)
    assert res.objective / scale ** 2 == pytest.approx(ref.objective, rel=1e-9)


def test_memberships_of_the_result_follow_eq_28():
    x, _ = blobs(50, [[0.0, 0.0, 0.0], [2.0, 2.0, 0.0]], 0.7, 7)
    for m in (2.0, 1.5, 3.0):
        res = fcm(x, 2, m=m, restarts=2)
        torch.testing.assert_close(memberships(x, res.centers, m), res.memberships, rtol=0, atol=1e-12)
        v, u = res.centers.numpy(), res.memberships.numpy()
        d = np.sqrt(((x[None] - v[:, None]) ** 2).sum(-1))  # (c, N)
        u28 = 1.0 / ((d[:, None, :] / d[None, :, :]) ** (2 / (m - 1))).sum(axis=1)  # eq. 28 literally
        np.testing.assert_allclose(u, u28, rtol=0, atol=1e-12)


# ------------------------------------------------------------------ planted clusters

@pytest.mark.parametrize("centers", [[[0.0], [5.0], [12.0]], [[0, 0, 0], [6, 0, 0], [0, 6, 3]]])
def test_planted_blobs_are_recovered(centers):
    from sklearn.metrics import adjusted_rand_score  # here: scikit-learn is slow to import for one check

    x, y = blobs(80, centers, 0.5, 2)
    res = fcm(x, 3, restarts=3)
    labels = res.memberships.argmax(dim=0)
    assert adjusted_rand_score(y, labels.numpy()) == 1.0
    assert res.centers.shape == (3, len(centers[0]))
    assert res.memberships.shape == (3, 240)
    assert torch.equal(memberships(x, res.centers).argmax(dim=0), labels)
    found = res.centers[memberships(np.asarray(centers, dtype=np.float64), res.centers).argmax(dim=0)]
    torch.testing.assert_close(found, torch.tensor(centers, dtype=torch.float64), rtol=0, atol=0.2)
    assert 0 < res.n_iter < 300 and res.objective > 0


@pytest.mark.parametrize("kwargs, match", [
    (dict(x=np.arange(5.0), c=5), r"c: 5 clusters need more points than clusters .* 5 points"),
    (dict(x=np.arange(5.0), c=1), r"c: expected at least 2 clusters, got 1"),
    (dict(x=np.arange(5.0), c=2, m=1.0), r"m: expected a fuzzifier m > 1, got 1.0"),
    (dict(x=np.full((6, 2), 3.0), c=2), r"x: all 6 points are identical"),
    (dict(x=[0.0, 1.0, float("nan"), 3.0], c=2), r"x: contains NaN or inf \(first at row 2"),
    (dict(x=[0.0, 1.0, float("inf"), 3.0], c=2), r"NaN or inf"),
    (dict(x=np.zeros((2, 2, 2)), c=2), r"x: expected shape \(N,\) or \(N, d\)"),
    (dict(x=np.arange(5.0), c=2, init_u=np.ones((3, 5))), r"init_u: expected shape \(2, 5\)"),
    (dict(x=np.arange(5.0), c=2, init_u=[[1, 1, 1, 1, 1], [0, 0, -1, 0, 0]]), r"init_u: expected finite, non-negative"),
    (dict(x=np.arange(5.0), c=2, init_u=[[1, 1, 1, 1, 1], [0, 0, float("nan"), 0, 0]]), r"init_u: expected finite, non-negative"),
    (dict(x=np.arange(5.0), c=2, init_u=[[1, 0, 1, 1, 1], [1, 0, 0, 0, 0]]), r"init_u: some point has all memberships 0"),
])
def test_fcm_errors(kwargs, match, kernel):
    with pytest.raises(ValueError, match=match) as info:
        fcm(**kwargs)
    assert isinstance(info.value, InputError)


# ------------------------------------------------------------------ hierarchical partition

def synthetic_sweep(n=240, seed=0):
    """Positions (mm) in a box; R_set falls from the middle to the edge, saturates at 1."""
    g = torch.Generator().manual_seed(seed)
    pos = torch.rand(n, 3, generator=g, dtype=torch.float64) * torch.tensor([2400.0, 2400.0, 1600.0])
    pos -= torch.tensor([1200.0, 1200.0, -200.0])
    radial = (pos[:, :2].norm(dim=1) / 1700.0).clamp(max=1.0)
    r = (1.03 - 0.35 * radial ** 2).clamp(max=1.0)
    return pos, r


@pytest.fixture(scope="module")
def paper_partition():
    pos, r = synthetic_sweep()
    return partition_workspace(pos, r, 4, [3, 2, 3, 2], seed=0, restarts=3)


def test_levels_are_ordered_by_reliability(paper_partition):
    p = paper_partition
    assert p.n_levels == 4 and p.n_zones == 10
    assert p.zone_level.tolist() == [1, 1, 1, 2, 2, 3, 3, 3, 4, 4]
    assert torch.all(p.level_centers[:-1] > p.level_centers[1:])  # level 1 most reliable
    lev = p.point_levels
    for k in range(1, 4):  # 1-D FCM levels are intervals of R_set, in order
        assert p.r_set[lev == k].min() >= p.r_set[lev == k + 1].max()
    assert sorted(p.labels.unique().tolist()) == list(range(1, 11))
    u = p.memberships
    assert u.shape == (10, 240)
    torch.testing.assert_close(u.sum(0), torch.ones(240, dtype=torch.float64))
    summ = p.summary()
    assert [s["points"] for s in summ] == torch.bincount(p.labels)[1:].tolist()
    for s in summ:
        assert s["r_set_min"] <= s["r_set_mean"] <= s["r_set_max"]


def test_sub_zones_are_nearest_centers_in_level_features(paper_partition):
    p = paper_partition
    for lev in range(1, 5):
        zones = torch.nonzero(p.zone_level == lev)[:, 0]  # 0-based zone indices of the level
        sel = p.point_levels == lev
        d = torch.cdist(p.features(lev)[sel], p.zone_centers[zones])  # (n_level, k)
        assert torch.equal(zones[d.argmin(dim=1)] + 1, p.labels[sel])


def test_r_weight_trades_reliability_against_space():
    pos, r = synthetic_sweep(200, seed=4)

    def spreads(w):
        p = partition_workspace(pos, r, 2, [3, 3], r_weight=w, restarts=2)
        r_sd = torch.stack([p.r_set[p.labels == z].std() for z in range(1, 7)]).mean()
        xy_sd = torch.stack([p.positions[p.labels == z, :2].std(dim=0).norm() for z in range(1, 7)]).mean()
        return float(r_sd), float(xy_sd)

    r0, s0 = spreads(0.0)
    r5, s5 = spreads(5.0)
    assert r5 < 0.7 * r0 and s5 > s0


def test_assign_training_and_new_points(paper_partition):
    p = paper_partition
    assert (p.assign(p.positions) == p.labels).float().mean() >= 0.95
    near = p.positions[:5] + 1e-3
    assert torch.equal(p.assign(near), p.labels[:5])
    assert p.assign(p.positions[0].tolist()).shape == (1,)
    with pytest.raises(ValueError, match=r"points: expected shape \(M, 3\)"):
        p.assign(np.zeros((4, 2)))


def test_json_round_trip(paper_partition, tmp_path):
    p = paper_partition
    text = partition_to_json(p)
    q = partition_from_json(text)
    assert partition_to_json(q) == text
    for name in ("positions", "r_set", "labels", "point_ids", "level_centers", "zone_level", "zone_centers",
                 "feature_mean", "feature_std"):
        assert torch.equal(getattr(q, name), getattr(p, name)), name
    torch.testing.assert_close(q.memberships, p.memberships, rtol=0, atol=0)
    assert q.summary() == p.summary()
    probe = torch.tensor([[0.0, 0.0, 800.0], [900.0, -900.0, 300.0]])
    assert torch.equal(q.assign(probe), p.assign(probe))
    save_partition(p, tmp_path / "p.json")
    assert torch.equal(load_partition(tmp_path / "p.json").labels, p.labels)
    obj = json.loads(text)
    obj["colour"] = "red"
    with pytest.raises(ValueError, match=r"unknown keys \['colour'\]"):
        partition_from_dict(obj)


def test_saturated_reliability_like_a_real_sweep():
    # a real KR 1000 sweep has R_set = 1 exactly at most points: level 1 holds them all
    pos, r = synthetic_sweep(200, seed=5)
    r = torch.where(torch.arange(200) < 170, torch.ones(200, dtype=torch.float64), 0.7 + 0.25 * r)
    p = partition_workspace(pos, r, 4, "auto", restarts=2)
    lev = p.point_levels
    assert torch.all(lev[:170] == 1) and float(p.level_centers[0]) == pytest.approx(1.0, abs=1e-3)
    assert torch.isfinite(p.memberships).all() and torch.isfinite(p.level_memberships).all()
    assert sorted(p.labels.unique().tolist()) == list(range(1, p.n_zones + 1))
    with pytest.raises(ValueError, match=r"r_set: only 2 distinct values among 200 points; levels='auto'"):
        partition_workspace(pos, (r > 0.99).double(), "auto", "auto", level_range=(3, 5))


def test_partition_auto_and_errors():
    pos, r = synthetic_sweep(120, seed=1)
    p = partition_workspace(pos, r, 3, "auto", restarts=1)
    assert p.n_levels == 3 and all(2 <= (p.zone_level == k).sum() <= 3 for k in (1, 2, 3))
    p = partition_workspace(pos, r, "auto", "auto", zone_range=(3, 4), restarts=1)
    assert 2 <= p.n_levels <= 6 and all(3 <= (p.zone_level == k).sum() <= 4 for k in range(1, p.n_levels + 1))
    assert p.options["levels"] == "auto" and p.options["zone_range"] == [3, 4]
    with pytest.raises(ValueError, match="zones: 3 sub-zone counts"):
        partition_workspace(pos, r, 4, [3, 2, 3])
    with pytest.raises(ValueError, match=r"r_set: only 2 distinct values among 120 points; cannot form 4 levels"):
        partition_workspace(pos, (r > 0.9).double(), 4, "auto")
    with pytest.raises(ValueError, match=r"r_set: all 120 values are equal"):
        partition_workspace(pos, torch.ones(120), 2, "auto")
    with pytest.raises(ValueError, match=r"zones: level \d has \d+ points, too few for 200 sub-zones"):
        partition_workspace(pos, r, 2, [200, 2])
    with pytest.raises(ValueError, match=r"zone_range: expected 2 <= low <= high"):
        partition_workspace(pos, r, 2, "auto", zone_range=(1, 3))
    with pytest.raises(ValueError, match=r"r_set: contains NaN or inf"):
        partition_workspace(pos, torch.where(r > 0.9, torch.nan, r), 2, "auto")


def test_zones_too_small_for_the_sweep_are_refused_or_named():
    """A requested count above half a level's points is refused; zones left with fewer
    sweep points than the k-NN vote that assigns poses to zones (5) get one warning, and
    'auto' never chooses such a split (before: --zones 60,2 on 200 points gave 62 zones, 36
    of one point, silently; auto on (2, 60) 119 zones, 62 of one point)."""
    import warnings

    from torchcal.partition.zones import ZoneSizeWarning

    pos, r = synthetic_sweep(200, seed=6)
    with pytest.raises(ValueError, match=r"zones: level 1 has (\d+) points, too few for 70 sub-zones: a zone "
                                         r"needs at least 2 sweep points on average, so at most \d+ sub-zone\(s\)"):
        partition_workspace(pos, r, 2, [70, 2], restarts=1)
    with pytest.warns(ZoneSizeWarning, match=r"zones: \d+ of 32 zones hold fewer than 5 sweep points \(zone "
                                             r"\(points\): \d+ \([1-4]\)"):
        p = partition_workspace(pos, r, 2, [30, 2], restarts=1)
    assert int((torch.bincount(p.labels)[1:] < 5).sum()) > 0
    with warnings.catch_warnings():
        warnings.simplefilter("error", ZoneSizeWarning)
        p = partition_workspace(pos, r, 2, "auto", zone_range=(2, 60), restarts=1)
        assert p.n_zones > 2 and int(torch.bincount(p.labels)[1:].min()) >= 5
        partition_workspace(pos, r, 2, [3, 2], restarts=1)  # zones of tens of points: no word


# ------------------------------------------------------------------ command line

def write_sweep_csv(path, pos, r, q_count=6):
    eta = 2 * r - 1
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["point"] + [f"q{i}" for i in range(1, q_count + 1)] +
                   ["x", "y", "z", "ex_lo", "ex_hi", "ey_lo", "ey_hi", "ez_lo", "ez_hi",
                    "dist_lo", "dist_hi", "eta", "r_set"])
        for j in range(len(r)):
            w.writerow([j + 1] + [f"{10.0 * i:.3f}" for i in range(q_count)] +
                       [f"{float(v):.6f}" for v in pos[j]] + ["-0.1", "0.1"] * 3 +
                       ["0", f"{2.5 / float(r[j]):.6f}", f"{float(eta[j]):.6f}", repr(float(r[j]))])


def test_cli_partition(tmp_path, capsys):
    pos, r = synthetic_sweep(160, seed=2)
    sweep = tmp_path / "sweep.csv"
    out = tmp_path / "partition.json"
    write_sweep_csv(sweep, pos, r)
    argv = ["partition", str(sweep), "--levels", "4", "--zones", "3,2,3,2", "--seed", "1", "--out", str(out)]
    assert cli.main(argv) == 0
    text = capsys.readouterr().out
    assert "160 points -> 4 levels, 10 zones" in text
    assert len([ln for ln in text.splitlines() if ln.split() and ln.split()[0].isdigit()]) == 10
    p = load_partition(out)
    assert p.n_zones == 10 and p.point_ids.tolist() == list(range(1, 161))
    torch.testing.assert_close(p.positions, pos, rtol=0, atol=1e-6)
    assert cli.main(argv) == 2
    assert "output exists; pass --force" in capsys.readouterr().err
    assert cli.main(argv + ["--force"]) == 0


@pytest.mark.parametrize("edit, match", [
    (lambda rows: [[c for c in row if c != "r_set"] for row in rows[:1]] + [row[:-1] for row in rows[1:]],
     r"header must be point,q1,.*got point,q1,.*,eta$"),
    (lambda rows: rows[:2] + [rows[2][:7] + ["abc"] + rows[2][8:]] + rows[3:], r"row 3, column x: not a number: 'abc'"),
    (lambda rows: rows[:3] + [rows[3][:-1] + ["1.5"]] + rows[4:], r"row 4, column r_set: 1.5 is outside \[0, 1\]"),
    (lambda rows: rows[:2] + [rows[2][:5]] + rows[3:], r"row 3: expected 20 columns, got 5"),
    (lambda rows: rows[:1], r"no data rows"),
])
def test_cli_bad_sweep_csv(tmp_path, capsys, edit, match):
    pos, r = synthetic_sweep(20, seed=3)
    sweep = tmp_path / "sweep.csv"
    write_sweep_csv(sweep, pos, r)
    rows = list(csv.reader(open(sweep)))
    with open(sweep, "w", newline="") as fh:
        csv.writer(fh).writerows(edit(rows))
    assert cli.main(["partition", str(sweep), "--levels", "2", "--out", str(tmp_path / "p.json")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert str(sweep) in err
    import re
    assert re.search(match, err), err


def test_cli_bad_options(tmp_path, capsys):
    pos, r = synthetic_sweep(20, seed=3)
    sweep = tmp_path / "sweep.csv"
    write_sweep_csv(sweep, pos, r)
    assert cli.main(["partition", str(sweep), "--levels", "4", "--zones", "3,2", "--out", str(tmp_path / "p.json")]) == 2
    assert "--zones: 2 counts for --levels 4" in capsys.readouterr().err
    assert cli.main(["partition", str(sweep), "--levels", "2", "--zones", "6,2", "--out", str(tmp_path / "p.json")]) == 2
    err = capsys.readouterr().err
    assert err.strip().splitlines()[-1].startswith("torchcal partition: error: zones: level 1 has ")
    assert "too few for 6 sub-zones" in err and "records no robot" in err  # the sweep of an old torchcal
    assert not (tmp_path / "p.json").exists()
    assert cli.main(["partition", str(tmp_path / "nope.csv"), "--out", str(tmp_path / "p.json")]) == 2
    assert "sweep CSV does not exist" in capsys.readouterr().err


def test_zones_numbered_alike_by_partition_and_interval_model(paper_partition, kr):
    """A zone has one number everywhere (1..Z): the per-zone model assigns the ids the
    partition assigns, and its zone - 1 row is that zone's parameters."""
    import dataclasses

    from torchcal.calibration.fit import FitResult, Identifiability
    from torchcal.calibration.model import CalibrationModel
    from torchcal.calibration.zone_calibration import ZonedFit

    p = paper_partition
    model = CalibrationModel(kr)
    Z = p.n_zones
    free = torch.ones(model.n_params, dtype=torch.bool)
    glob = FitResult(model, model.zeros(), model.zeros(), None, None, Identifiability(free, [], 0, 1.0, {}, 0), 0)
    zones = [dataclasses.replace(glob, theta=torch.full((model.n_params,), float(z), dtype=torch.float64))
             for z in range(1, Z + 1)]
    im = ZonedFit.of(glob, zones, p, "damped", [0] * Z)
    probe = p.positions[::7]
    ids = im.assign(probe)
    assert torch.equal(ids, p.assign(probe)) and int(ids.min()) >= 1 and int(ids.max()) <= Z
    assert im.zone_theta[ids - 1, 0].tolist() == ids.double().tolist()


# ------------------------------------------------------------------ the robot it was made for
def test_partition_file_records_and_checks_its_robot(paper_partition, tmp_path):
    """PARTITION.json version 2 records the robot (`made_for`); `load_partition(robot=)`
    refuses another robot or other joint limits with one line naming the file and what
    differs, reads a file of version 1 (no record) with one warning, and reads its
    partition unchanged."""
    import dataclasses
    import warnings

    import torchcal
    from torchcal.io.robot_file import UnrecordedRobotWarning, robot_fingerprint

    kr, ur = torchcal.robot("kr1000titan"), torchcal.robot("ur5e")
    path = tmp_path / "zones.json"
    save_partition(paper_partition, path, made_for=kr)
    obj = json.loads(path.read_text())
    assert obj["version"] == 2 and obj["made_for"]["name"] == "kr1000titan"
    assert obj["made_for"]["fingerprint"] == robot_fingerprint(kr)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = load_partition(path, kr)
    assert partition_to_json(back) == partition_to_json(paper_partition)
    with pytest.raises(InputError) as e:
        load_partition(path, ur)
    assert str(e.value).startswith(f"{path}: made for robot 'kr1000titan' (fingerprint {robot_fingerprint(kr)[:12]}), "
                                   f"not 'ur5e' (fingerprint {robot_fingerprint(ur)[:12]}): the MD-H table differs")
    assert str(e.value).endswith("; make the sweep and partition again for this robot")
    assert "\n" not in str(e.value)
    lim = kr.limits.clone()
    lim[4, 0] += 0.1
    with pytest.raises(InputError, match=r"not 'kr1000titan' .*: joint 5 limits .* deg in the file, .* deg given;"):
        load_partition(path, dataclasses.replace(kr, limits=lim))
    # a file of version 1 (no record): reads, with one warning when checked against a robot
    old = dict(obj, version=1)
    del old["made_for"]
    (tmp_path / "old.json").write_text(json.dumps(old))
    with pytest.warns(UnrecordedRobotWarning, match=r"old\.json: records no robot .* robot 'ur5e'$"):
        back = load_partition(tmp_path / "old.json", ur)
    assert partition_to_json(back) == partition_to_json(paper_partition)
    assert json.loads(partition_to_json(back))["made_for"] is None
    # version 2 without its record, or version 3: errors, not a silent read
    del obj["made_for"]
    with pytest.raises(InputError, match=r"zones: missing key 'made_for'"):
        partition_from_dict(obj, "zones")
    with pytest.raises(InputError, match=r"expected format 'torchcal.partition' version 2 \(or 1\), got .* version 3"):
        partition_from_dict(dict(obj, version=3, made_for=None), "zones")


def test_cli_partition_copies_the_sweeps_record(tmp_path, capsys):
    """`torchcal partition` of a sweep of `torchcal sweep` records that sweep's robot (the
    same record); of an older sweep CSV (no record line), one warning and no record."""
    import torchcal
    from torchcal.io.sweep_csv import sweep_record, write_sweep
    from torchcal.reliability.sweep import sweep
    from torchcal.robots.workspace import sample_workspace

    kr = torchcal.robot("kr1000titan")
    s = tmp_path / "sweep.csv"
    write_sweep(sweep(kr, sample_workspace(kr, 40, seed=6), n_samples=30), s)
    argv = ["partition", str(s), "--levels", "2", "--zones", "2,1", "--out", str(tmp_path / "p.json")]
    assert cli.main(argv) == 0
    assert "records no robot" not in capsys.readouterr().err  # (a level of 2 sweep points is named)
    assert json.loads((tmp_path / "p.json").read_text())["made_for"] == sweep_record(s)
    old = tmp_path / "old.csv"
    old.write_text("".join(s.read_text().splitlines(keepends=True)[1:]))
    assert cli.main(argv[:1] + [str(old)] + argv[2:-1] + [str(tmp_path / "p_old.json")]) == 0
    err = capsys.readouterr().err
    assert err.count("records no robot") == 1 and err.startswith(f"torchcal: warning: {old}: records no robot")
    assert json.loads((tmp_path / "p_old.json").read_text())["made_for"] is None


@pytest.mark.parametrize("opt, value", [("--m", "1"), ("--m", "0.5"), ("--restarts", "0"), ("--r-weight", "-1")])
def test_cli_number_errors_name_the_option(tmp_path, capsys, opt, value):
    """A bad --m / --restarts / --r-weight is named as the command-line option, not as the
    library argument (m:, restarts:, r_weight:), in one line, writing nothing."""
    pos, r = synthetic_sweep(20, seed=3)
    sweep = tmp_path / "sweep.csv"
    write_sweep_csv(sweep, pos, r)
    assert cli.main(["partition", str(sweep), opt, value, "--out", str(tmp_path / "p.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"torchcal partition: error: {opt}: "), err
    assert not (tmp_path / "p.json").exists()


def _robot_sweep(name, n, seed):
    """A sweep (`torchcal.reliability.sweep`) of preset `name` at n workspace points: the
    KR 1000's own clearance model, others 0.01 mm seats over 100 mm and 0.03 mm allowed."""
    import torchcal
    from torchcal.reliability.sweep import sweep
    from torchcal.reliability.uncertainty import ClearanceModel
    from torchcal.robots.workspace import sample_workspace

    rob = torchcal.robot(name)
    cl = None if name == "kr1000titan" else ClearanceModel([20.0] * (2 * rob.n), [0.01] * (2 * rob.n), [100.0] * rob.n)
    return sweep(rob, sample_workspace(rob, n, seed=seed), n_samples=50, model=cl,
                 allowed_mm=2.5 if cl is None else 0.03)


@pytest.mark.parametrize("m,zones", [("50", "2,1"), ("3", "3,3"), ("50", "auto")])
def test_cli_a_fuzzifier_that_merges_the_sub_zone_centers_is_refused(tmp_path, capsys, m, zones):
    """FCM with a large m falls to its trivial fixed point (every center the level's mean):
    the sub-zones it returns are split by rounding. Before: written, exit 0, two zones with
    the same printed centre (e.g. 299.25, -411.33, 2164.10 and 299.24, -411.38, 2164.06 mm)."""
    from torchcal.io.sweep_csv import write_sweep

    write_sweep(_robot_sweep("kr1000titan", 60, 6), tmp_path / "sweep.csv")
    out = tmp_path / "part.json"
    assert cli.main(["partition", str(tmp_path / "sweep.csv"), "--levels", "2", "--zones", zones, "--m", m,
                     "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert "the FCM sub-zones of level 1 share one center" in err and f"fuzzifier m = {m}" in err, err
    assert not out.exists()


@pytest.mark.parametrize("name,n,seed", [("kr1000titan", 60, 6), ("kr1000titan", 200, 1), ("ur5e", 200, 2),
                                         ("puma560", 150, 3)])
def test_honest_sweeps_keep_their_sub_zones_apart(name, n, seed):
    """Sweeps of three robots with m = 1.5 and 2 (default): every partition passes, centers
    1.3 standard deviations or more apart (far above MIN_CENTER_SEPARATION)."""
    sw = _robot_sweep(name, n, seed)
    for m in (1.5, 2.0):
        for zones in ([2, 1], [3, 3], "auto"):
            p = partition_workspace(sw.positions, sw.r_set, 2, zones, m=m, restarts=2)
            assert p.n_zones >= 2
