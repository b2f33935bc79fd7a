"""The nominal robot in its best measuring frame and with its best tool offset, fitted to
measurements (`in_frame`, `registered`): what the checks of data against the nominal robot
judge by (`torchcal.calibration.checks.robot_data`, `...sessions`). For a model of a frame
and one tool offset the fit runs without the kinematic chain in its loop (`frame_fit`), and
a lower bound of its RMS (`frame_bound_mm`) refuses a candidate without a solve
(`fits_in_a_frame`).
"""

from __future__ import annotations

import math

import torch

from torchcal.calibration.checks.verdict import GROSS_MM, rms_of
from torchcal.errors import InputError


def in_frame(model, m, tool: bool = True):
    """Predicted points (N, 3) mm of the nominal `model` (its parameters at zero but its
    measuring frame: base_frame, and tool_offset when `tool`, those of them it has) fitted
    to the measurements `m`, from the closed-form registration."""
    from torchcal.calibration.fit import fit
    from torchcal.calibration.registration import frame_slices, register_frame
    from torchcal.effects import context_of

    ctx = context_of(model.robot, m)
    free = torch.zeros(model.n_params, dtype=torch.bool)
    for sl in frame_slices(model, tool):
        free[sl] = True
    if not bool(free.any()):
        with torch.no_grad():
            return model.predict(model.zeros().to(m.xyz), ctx).detach()
    start, _ = register_frame(model, ctx, m.xyz)
    quick = frame_fit(model, ctx, m.xyz, start, free)
    if quick is not None:
        return quick
    res = fit(model, ctx, m.xyz, theta0=start, free=free, register=False, max_length_mm=None, max_angle_deg=None)
    return (m.xyz - res.residuals).detach()


def _frame_and_tool(model):
    """(the base_frame effect, its slice, the tool_offset's slice) of a model of exactly
    base_frame and a single tool_offset (one offset for every point), else None: the models
    whose nominal points the tool offset moves linearly (`frame_fit`, `frame_bound_mm`)."""
    names = [e.name for e in model.effects]
    if sorted(names) != ["base_frame", "tool_offset"] or model.effects[names.index("tool_offset")].points:
        return None
    i, j = names.index("base_frame"), names.index("tool_offset")
    return model.effects[i], model.slices[1 + i], model.slices[1 + j]


def frame_fit(model, ctx, xyz: torch.Tensor, start: torch.Tensor, free: torch.Tensor):
    """`in_frame`'s fit without the kinematic chain in its loop: the predicted points (N, 3)
    mm, or None where it does not apply (then `fit` does it). For a model of exactly
    base_frame and a single tool_offset (every other parameter held at zero, no prior:
    what `fit` solves for `in_frame`) the points are ``R(r) (c + A u) + t``, c (N, 3) the
    nominal points (base frame) and A (N, 3, 3) their derivative w.r.t. the tool offset u
    (the chain's flange rotations: u enters linearly), both taken once from the model; the
    same Levenberg-Marquardt (`torchcal.calibration.lm`, `fit`'s max_iter) on the same
    residuals and Jacobian from the same start, so the same fit to rounding (a frame fit of
    a refused file runs 20-60 iterations, each of which walked the chain twice or more).
    None too when the identifiability analysis `fit` runs would hold a parameter; the
    same InputError as `fit` for too few rows."""
    from torchcal.calibration.identifiability import check_enough_rows, identifiability
    from torchcal.calibration.lm import levenberg_marquardt

    parts = _frame_and_tool(model)
    if parts is None:
        return None
    frame, frame_sl, tool_sl = parts
    J0 = model.jacobian(start, ctx)  # (N, 3, P) at the start, as `fit`'s identifiability takes it
    report = identifiability(J0, model.param_names(), free, first=torch.ones_like(free))
    if not torch.equal(report.free.cpu(), free.cpu()):
        return None
    check_enough_rows(report, 3 * xyz.shape[0], model, ctx, free)  # `fit`'s refusal of too few rows
    zero = start.clone()
    zero[frame_sl] = 0.0
    zero[tool_sl] = 0.0
    with torch.no_grad():
        c = model.predict(zero, ctx)  # (N, 3) base frame, no tool offset
    A = torch.einsum("ji,njk->nik", frame._rotation(start[frame_sl][3:6]), J0[:, :, tool_sl])  # R0^T dv/du
    n, P = xyz.shape[0], start.shape[0]

    def points(z):
        u = z[tool_sl]
        return c + (A @ u.unsqueeze(-1)).squeeze(-1)

    def res_fn(x):
        z = x[0]
        return (frame.world(z[frame_sl], ctx, points(z)) - xyz).reshape(1, -1)

    def jac_fn(x):
        z = x[0]
        dp, dv = frame.world_jacobian(z[frame_sl], ctx, points(z))
        J = xyz.new_zeros(n, 3, P)
        J[:, :, frame_sl] = dp
        J[:, :, tool_sl] = dv @ A
        return J.reshape(1, n * 3, P)

    res = levenberg_marquardt(res_fn, start.unsqueeze(0), free=free.to(start.device), jacobian_fn=jac_fn,
                              max_iter=60)
    z = res.x[0]
    with torch.no_grad():
        return frame.world(z[frame_sl], ctx, points(z)).detach()


def registered(model, m):
    """`in_frame` of `model` with base_frame and tool_offset (appended where missing)."""
    from torchcal.calibration.registration import with_frame

    return in_frame(with_frame(model, model.zeros(), tool=True)[0], m)


def quick_rms(model, ctx, xyz: torch.Tensor) -> float:
    """RMS (mm) of the nominal `model` as it is or, when it has base_frame, after the
    closed-form rigid motion (no solve): within GROSS_MM is the common case, decided
    cheaply; a frame and tool offset fitted could only come closer."""
    from torchcal.rotations import kabsch

    with torch.no_grad():
        p = model.predict(model.zeros().to(xyz), ctx)
    if "base_frame" in [e.name for e in model.effects] and p.shape[0] >= 3:
        R, t = kabsch(p, xyz)
        p = p @ R.T + t
    return rms_of((p - xyz).norm(dim=-1))


def fits_in_a_frame(model, m) -> bool:
    """Whether the nominal `model` in a measuring frame and with a tool offset of its own
    (`registered`) comes within GROSS_MM of the measurements `m`; a bound beyond it
    (`frame_bound_mm`) says no without a solve, and so do too few rows (False)."""
    try:
        if frame_bound_mm(model, m) > GROSS_MM * (1 + 1e-6):  # no frame and tool can fit: no solve
            return False
        return rms_of((registered(model, m) - m.xyz).norm(dim=-1)) <= GROSS_MM
    except InputError:
        return False


def frame_bound_mm(model, m) -> float:
    """A lower bound (mm) of the RMS that `registered` can reach: of min over R in SO(3),
    t, u of the RMS of ``R (c_i + A_i u) + t - x_i`` (c (N, 3) the nominal points, A (N, 3, 3)
    their derivative w.r.t. the tool offset u, x the measured points), for a model of
    base_frame and a single tool_offset once the frame is added (else 0: no bound).
    Rotating each residual by R^T leaves its length: for fixed R the best u and R^T t are
    linear least squares, so the sum of squares is ``f(r) = |Q (X r - c)|^2``, a quadratic
    in r = vec(R) (9,) (Q projects out the columns of [A_i, I]). Relaxing R to
    ``|r|^2 = 3`` (every rotation has it) bounds it from below, and for any lam below the
    smallest eigenvalue of G = X^T Q X, ``f(r) >= 3 lam - b^T (G - lam I)^-1 b + c^T Q c``
    (b = X^T Q c; Lagrangian duality), the tightest such lam found by bisection. Any local
    minimum the fit's solver reaches lies at or above it: a bound beyond GROSS_MM refuses
    a candidate with the verdict the solve would give (on the refusals of
    the check tests (then tests/test_mismatch.py) it rules out 108 of the 109 candidates beyond it)."""
    from torchcal.calibration.registration import frame_slices, with_frame
    from torchcal.effects import context_of

    model = with_frame(model, model.zeros(), tool=True)[0]
    parts = _frame_and_tool(model)
    if parts is None or len(m) < 3:
        return 0.0
    ctx = context_of(model.robot, m)
    model.check_context(ctx)
    tool_sl = parts[2]
    zero = model.zeros().to(m.xyz)
    with torch.no_grad():
        c = model.predict(zero, ctx).to(torch.float64).cpu()  # (N, 3)
        A = model.jacobian(zero, ctx)[:, :, tool_sl].to(torch.float64).cpu()  # (N, 3, 3)
    x = m.xyz.detach().to("cpu", torch.float64)
    n = x.shape[0]
    basis, _ = torch.linalg.qr(torch.cat([A, torch.eye(3, dtype=x.dtype).expand(n, 3, 3)], -1).reshape(3 * n, 6))

    def proj(v):  # v (3N, k) with the columns of [A_i, I] projected out
        return v - basis @ (basis.T @ v)

    X = torch.zeros(n, 3, 3, 3, dtype=x.dtype)  # (R^T x_i)_a = sum_b R[b, a] x_ib: r[3 b + a] = R[b, a]
    for a in range(3):
        X[:, a, :, a] = x
    QX, Qc = proj(X.reshape(3 * n, 9)), proj(c.reshape(-1, 1))
    w, V = torch.linalg.eigh(QX.T @ QX)
    bb = (V.T @ (QX.T @ Qc)).flatten()
    k = float((Qc * Qc).sum())
    w0 = float(w[0])

    def norm2(lam):  # |(G - lam I)^-1 b|^2
        return float(((bb / (w - lam)) ** 2).sum())

    def bound(lam):
        return 3 * lam - float((bb ** 2 / (w - lam)).sum()) + k

    step = 1.0 + abs(w0)
    lo, hi = w0 - step, w0 - 1e-12 * step
    if norm2(hi) <= 3:  # the maximum of the dual at lam -> w0: the bound there
        lam = hi
    else:
        while norm2(lo) > 3:
            step *= 2
            lo = w0 - step
        for _ in range(100):
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if norm2(mid) > 3 else (mid, hi)
        lam = lo
    return math.sqrt(max(bound(lam), 0.0) / n)
