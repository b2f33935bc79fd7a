"""The batched Levenberg-Marquardt solver (torchcal.calibration.lm).

- a nonlinear least-squares problem (exponential fit) solves to the parameters scipy's
  own solver finds, in float32 and float64, on every available device;
- batch elements keep their own status: a wrong Jacobian (every step goes uphill) and a
  non-finite residual stall, are never reported converged and leave x at the start;
- `max_iter` stops with MAX_ITERATIONS; held parameters never move;
- the default forward-mode Jacobian equals finite differences.
"""

import numpy as np
import pytest
import torch
from torch.testing import assert_close

from torchcal.calibration.lm import LMStatus, batched_jacobian, levenberg_marquardt

DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(),
                                                                reason="no CUDA device"))]

T = np.linspace(0.0, 2.0, 12)
TRUTH = np.array([[2.0, -1.3, 0.5], [0.7, 0.4, -0.2]])  # (B, 3): a exp(b t) + c
X0 = TRUTH + np.array([0.5, 0.3, -0.4])  # a start in the basin of the solution


def data(B=2, noise=0.01):
    rng = np.random.default_rng(0)
    y = TRUTH[:B, :1] * np.exp(TRUTH[:B, 1:2] * T) + TRUTH[:B, 2:3]
    return y + noise * rng.standard_normal(y.shape)  # (B, 12)


def residual_factory(y):
    t = torch.as_tensor(T, dtype=y.dtype, device=y.device)

    def residual(x):  # (B, 3) -> (B, 12)
        return x[:, :1] * torch.exp(x[:, 1:2] * t) + x[:, 2:3] - y
    return residual


def scipy_reference(y):
    import scipy.optimize
    def r(p, yy):
        return p[0] * np.exp(p[1] * T) + p[2] - yy
    return np.stack([scipy.optimize.least_squares(r, x0, args=(yy,), xtol=1e-15, ftol=1e-15,
                                                  gtol=1e-15).x for x0, yy in zip(X0, y)])


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_solves_like_scipy(dtype, device):
    y_np = data()
    y = torch.as_tensor(y_np, dtype=dtype, device=device)
    res = levenberg_marquardt(residual_factory(y), torch.as_tensor(X0, dtype=dtype, device=device))
    assert res.x.dtype == dtype and res.x.device.type == device and res.status.device.type == device
    assert res.status.tolist() == [LMStatus.CONVERGED] * 2 and bool(res.converged.all())
    assert res.status_labels() == ["converged", "converged"]
    tol = 1e-3 if dtype == torch.float32 else 1e-6  # the ftol rule stops on the cost, flat at the minimum
    assert_close(res.x.cpu().double(), torch.as_tensor(scipy_reference(y_np)), atol=tol, rtol=tol)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_failed_solve_is_not_converged(dtype, device):
    """Element 0 has the true Jacobian, element 1 its negative (every step goes uphill)."""
    y = torch.as_tensor(data(), dtype=dtype, device=device)
    residual = residual_factory(y)
    sign = torch.tensor([1.0, -1.0], dtype=dtype, device=device)[:, None, None]

    def wrong_jacobian(x):
        return batched_jacobian(residual, x) * sign

    x0 = torch.as_tensor(X0, dtype=dtype, device=device)
    res = levenberg_marquardt(residual, x0, jacobian_fn=wrong_jacobian)
    assert res.status.tolist() == [LMStatus.CONVERGED, LMStatus.STALLED]
    assert res.converged.tolist() == [True, False]
    assert_close(res.x[1], x0[1])  # no step was ever accepted
    assert_close(res.cost[1], 0.5 * (residual(x0)[1] ** 2).sum())


def test_non_finite_residual_stalls():
    y = torch.as_tensor(data(1), dtype=torch.float64)
    residual = residual_factory(y)
    res = levenberg_marquardt(lambda x: residual(x) * torch.nan, torch.ones(1, 3, dtype=torch.float64))
    assert res.status.tolist() == [LMStatus.STALLED] and not res.converged.any()


def test_max_iterations_and_held_parameters():
    y = torch.as_tensor(data(), dtype=torch.float64)
    x0 = torch.as_tensor(X0)
    res = levenberg_marquardt(residual_factory(y), x0, max_iter=2)
    assert res.status.tolist() == [LMStatus.MAX_ITERATIONS] * 2 and res.n_iter.tolist() == [2, 2]
    free = torch.tensor([[True, True, False], [False, True, True]])
    held = levenberg_marquardt(residual_factory(y), x0, free=free)
    assert_close(held.x[~free], x0[~free], atol=0, rtol=0)
    assert (held.x[free] != x0[free]).all()


def test_forward_jacobian_matches_finite_differences():
    y = torch.as_tensor(data(), dtype=torch.float64)
    residual = residual_factory(y)
    x = torch.tensor([[1.5, -0.7, 0.2], [0.3, 0.9, 1.1]], dtype=torch.float64)
    J = batched_jacobian(residual, x)  # (B, R, P)
    h = 1e-6
    fd = torch.stack([(residual(x + h * e) - residual(x - h * e)) / (2 * h)
                      for e in torch.eye(3, dtype=torch.float64)], dim=-1)
    assert_close(J, fd, atol=1e-7, rtol=1e-7)


def test_fit_result_keeps_the_status(kr):
    """`fit` reports the solver's status; MODEL.json carries it under "fit"."""
    from torchcal.calibration.fit import fit
    from torchcal.calibration.model import CalibrationModel
    from torchcal.effects import make_context
    from torchcal.io.modelfile import to_dict
    from torchcal.robots.poses import random_poses

    model = CalibrationModel(kr)
    q = random_poses(kr, 30, 3)
    ctx = make_context(kr, q)
    xyz = model.predict(model.zeros(), ctx) + 0.5
    good = fit(model, ctx, xyz)
    assert good.status == "converged" and good.converged
    assert to_dict(good)["fit"]["status"] == "converged"
    short = fit(model, ctx, xyz, max_iter=1)
    assert short.status == "max_iterations" and not short.converged
    bad = fit(model, ctx, xyz * torch.nan)
    assert bad.status == "stalled" and not bad.converged and bad.n_iter == 1
    assert to_dict(bad)["fit"]["status"] == "stalled"


def test_a_step_lost_to_rounding_is_not_convergence():
    """float32, r(x) = (1e4 + x) - 1e4 - 4e-4: the residual moves in steps of float32's
    spacing at 1e4 (1e-3), so no step of x changes the cost, while the gradient (the
    analytic derivative, 1) says x is not stationary (cosine 1). Equal costs are not
    progress there: the solve stalls at the start and says so. Taking an equal cost as a
    converged step would report x = 4e-4 as 'converged'."""
    big = torch.tensor(1e4, dtype=torch.float32)

    def residual(x):
        return (big + x) - big - 4e-4

    res = levenberg_marquardt(residual, torch.zeros(1, 1, dtype=torch.float32))
    assert res.status.tolist() == [LMStatus.STALLED] and not bool(res.converged.any())
    assert float(res.x) == 0.0


def test_an_exact_fit_converges_at_rounding_level():
    """Noise-free data: the residual ends at rounding level, where the cosine of the
    stationarity test is noise; the Gauss-Newton step below sqrt(eps) relative to x
    counts as stationary, so the solve converges (instead of running to max_iter)."""
    y = torch.as_tensor(data(noise=0.0))
    res = levenberg_marquardt(residual_factory(y), torch.as_tensor(X0), max_iter=100)
    assert res.status.tolist() == [LMStatus.CONVERGED] * 2 and int(res.n_iter.max()) < 30
    assert_close(res.x, torch.as_tensor(TRUTH), atol=1e-10, rtol=1e-10)
