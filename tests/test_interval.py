"""Tests of torchcal.reliability.interval: forms, arithmetic, the linear hull, the sample hull.

Checked against brute force: the hull of a linear map equals the min / max over every
vertex of the box (so it is tight, each bound attained at a vertex), and random points
of the box map inside it; the sample hull equals numpy's min / max.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from torchcal.errors import InputError
from torchcal.reliability.interval import Interval, linear_hull, sample_hull

BATCHES = ((), (10,), (4, 5))
DTYPES = (torch.float64, torch.float32)
DEVICES = ("cpu",) + (("cuda",) if torch.cuda.is_available() else ())


def _gen(seed=0):
    return torch.Generator().manual_seed(seed)


def _random_interval(shape, gen, dtype=torch.float64):
    c = torch.randn(tuple(shape), generator=gen, dtype=torch.float64)
    r = torch.rand(tuple(shape), generator=gen, dtype=torch.float64)
    return Interval.from_center_radius(c.to(dtype), r.to(dtype))


# -- forms ----------------------------------------------------------------------------
def test_center_radius_round_trip():
    iv = Interval(torch.tensor([-1.0, 2.0, 3.0]), torch.tensor([3.0, 2.0, 7.0]))
    torch.testing.assert_close(iv.center, torch.tensor([1.0, 2.0, 5.0]))
    torch.testing.assert_close(iv.radius, torch.tensor([2.0, 0.0, 2.0]))
    torch.testing.assert_close(iv.width, 2 * iv.radius)
    back = Interval.from_center_radius(iv.center, iv.radius)
    torch.testing.assert_close(back.lower, iv.lower)
    torch.testing.assert_close(back.upper, iv.upper)
    assert not hasattr(iv, "centre") and not hasattr(Interval, "from_centre_radius")  # one name: center


def test_numbers_become_float64_and_broadcast():
    iv = Interval(0.0, torch.tensor([1.0, 2.0], dtype=torch.float64))
    assert iv.dtype == torch.float64 and iv.shape == (2,)
    assert Interval(0, 1).dtype == torch.float64
    p = Interval.point(3.0)
    assert p.radius.item() == 0.0 and p.center.item() == 3.0


def test_bad_bounds_are_errors():
    with pytest.raises(InputError, match=r"lower must be <= upper.*index \[1\]"):
        Interval(torch.tensor([0.0, 2.0]), torch.tensor([1.0, 1.0]))
    with pytest.raises(ValueError, match="radius must be >= 0"):
        Interval.from_center_radius(0.0, -1.0)
    with pytest.raises(InputError, match=r"Interval \* Interval"):
        Interval(0.0, 1.0) * Interval(0.0, 1.0)


# -- arithmetic -------------------------------------------------------------------------
@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("batch", BATCHES)
def test_addition_is_exact(batch, dtype):
    g = _gen(1)
    a, b = _random_interval(batch, g, dtype), _random_interval(batch, g, dtype)
    s = a + b
    torch.testing.assert_close(s.center, a.center + b.center)
    torch.testing.assert_close(s.radius, a.radius + b.radius)
    assert s.dtype == dtype
    # bounds attained by the endpoints
    torch.testing.assert_close(s.upper, a.upper + b.upper)
    shifted = a + 2.0
    torch.testing.assert_close(shifted.lower, a.lower + 2.0)
    torch.testing.assert_close((2.0 + a).upper, a.upper + 2.0)
    d = a - b
    torch.testing.assert_close(d.lower, a.lower - b.upper)
    torch.testing.assert_close(d.upper, a.upper - b.lower)
    torch.testing.assert_close((1.0 - a).lower, 1.0 - a.upper)


@pytest.mark.parametrize("batch", BATCHES)
def test_scaling_flips_for_negative_factors(batch):
    g = _gen(2)
    a = _random_interval(batch, g)
    k = torch.randn(tuple(batch), generator=g, dtype=torch.float64)
    s = a * k
    torch.testing.assert_close(s.center, k * a.center)
    torch.testing.assert_close(s.radius, k.abs() * a.radius)
    assert bool((s.lower <= s.upper).all())
    neg = a * -3.0
    torch.testing.assert_close(neg.lower, -3.0 * a.upper)
    torch.testing.assert_close(neg.upper, -3.0 * a.lower)
    torch.testing.assert_close((-3.0 * a).lower, neg.lower)
    torch.testing.assert_close((-a).lower, -a.upper)


def test_contains_and_hull():
    a, b = Interval(0.0, 1.0), Interval(2.0, 3.0)
    h = a.hull(b)
    assert h.lower.item() == 0.0 and h.upper.item() == 3.0
    assert bool(a.contains(0.5)) and not bool(a.contains(1.5)) and bool(a.contains(1.05, atol=0.1))


# -- linear hull ------------------------------------------------------------------------
@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("batch", BATCHES)
def test_linear_hull_equals_vertex_extremes(batch, dtype):
    """Every bound of the hull is attained at a vertex of the box: tight."""
    g = _gen(3)
    m, p = 3, 5
    Kmat = torch.randn(*batch, m, p, generator=g, dtype=torch.float64)
    box = _random_interval((*batch, p), g)
    hull = linear_hull(Kmat.to(dtype), box.to(dtype=dtype))
    assert hull.shape == (*batch, m) and hull.dtype == dtype
    signs = torch.tensor(list(itertools.product((-1.0, 1.0), repeat=p)), dtype=torch.float64)  # (2^p, p)
    verts = box.center.unsqueeze(-2) + signs * box.radius.unsqueeze(-2)  # (*batch, 2^p, p)
    images = verts @ Kmat.transpose(-1, -2)  # (*batch, 2^p, m)
    tol = dict(rtol=1e-5, atol=1e-5) if dtype == torch.float32 else {}
    torch.testing.assert_close(hull.lower, images.amin(-2).to(dtype), **tol)
    torch.testing.assert_close(hull.upper, images.amax(-2).to(dtype), **tol)


def test_linear_hull_contains_random_points_of_the_box():
    g = _gen(4)
    Kmat = torch.randn(3, 7, generator=g, dtype=torch.float64)
    box = _random_interval((7,), g)
    hull = linear_hull(Kmat, box)
    x = box.lower + box.width * torch.rand(10000, 7, generator=g, dtype=torch.float64)
    y = x @ Kmat.T
    assert bool(hull.contains(y).all())
    # and the sampled image is strictly inside unless the box is hit at a vertex
    assert bool((y.amax(0) <= hull.upper).all())


def test_linear_hull_broadcasts_one_box_over_many_maps():
    g = _gen(5)
    Kmat = torch.randn(11, 3, 4, generator=g, dtype=torch.float64)
    box = _random_interval((4,), g)
    hull = linear_hull(Kmat, box)
    for i in range(11):
        one = linear_hull(Kmat[i], box)
        torch.testing.assert_close(hull.lower[i], one.lower)
        torch.testing.assert_close(hull.upper[i], one.upper)


def test_linear_hull_shape_error():
    with pytest.raises(InputError, match=r"expected K \(\.\.\., m, p\).*got K \(3, 4\) and interval \(5,\)"):
        linear_hull(torch.zeros(3, 4), Interval(torch.zeros(5), torch.ones(5)))


# -- sample hull ------------------------------------------------------------------------
@pytest.mark.parametrize("dim", (0, 1, -1))
def test_sample_hull_is_min_max(dim):
    g = _gen(6)
    x = torch.randn(6, 7, 3, generator=g, dtype=torch.float64)
    h = sample_hull(x, dim)
    np.testing.assert_allclose(h.lower.numpy(), x.numpy().min(axis=dim))
    np.testing.assert_allclose(h.upper.numpy(), x.numpy().max(axis=dim))
    assert bool(h.contains(x.movedim(dim, 0)).all())


def test_sample_hull_needs_samples():
    with pytest.raises(InputError, match="at least one sample"):
        sample_hull(torch.zeros(0, 3), 0)


@pytest.mark.parametrize("device", DEVICES)
def test_device_is_kept(device):
    box = Interval(torch.zeros(4, device=device), torch.ones(4, device=device))
    h = linear_hull(torch.ones(2, 4, device=device), box)
    assert h.device.type == device and (box * -1.0).device.type == device
    assert sample_hull(torch.ones(3, 2, device=device)).device.type == device
