"""Refits of a fitted model on subsets of its rows (cross-validation folds, split
halves), all from one Jacobian of the whole data at the fit.

A fold refit (`torchcal.diagnosis.crossval.fold_fit`) is `torchcal.calibration.fit.fit`
on the fold's training rows, started at the full-data fit theta*, with its identifiable
set and prior rho kept: the identifiability of the training rows at theta*, one LM solve
to convergence and, with measured orientations, the tool-rotation step (Procrustes at
theta*, a solve, Procrustes again at its solution, a second solve). It takes 6-12 LM
iterations, each a Jacobian of the training rows. `refit` computes the same fit with
fewer Jacobians:

1. One Jacobian of all rows at theta* (`Shared`: positions, and with orientations the
   angular velocities and orientations of the same chain walk), shared by all folds. A
   fold's rows at theta* are rows of it (the orientation rows rebuilt with the fold's
   own tool rotation): its identifiability (every candidate kept when the unit columns'
   smallest singular value is at least SAFE_RANK x RANK_TOL, `identifiability.beyond_doubt`,
   else `identifiability` itself) and the normal matrix ``A = J0^T J0 + Pp`` (Pp the prior rows' information),
   factored once per fold.
2. Chord (simplified Newton) iterations ``x <- x - A^-1 (J^T r(x) + Pp x)`` with a fixed
   Jacobian J: one forward kinematics of the training rows per iteration, no Jacobian.
   They converge linearly (rate ``|A^-1 J^T (J - J(x))|``, 1e-5 - 3e-3 on the UR10
   series C folds) to the point where ``J^T r + Pp x = 0``, which is the fit's
   stationary point only when J is the Jacobian there. A phase stops when a step is at
   most APPROX_TOL of its first (or at most STEP_TOL of the residual norm).
3. Then the true Jacobian of the training rows at the point reached, and chord
   iterations with it, again, until a freshly evaluated Jacobian's first step is at most
   STEP_TOL (1e-9) of the residual norm ``sqrt(|r|^2 + |Pp^1/2 x|^2)``, in the metric of
   A (the change the step makes to the rows, prior rows included): the Gauss-Newton step
   at the result, with its own Jacobian, is negligible, which certifies a stationary
   point of the same objective as the LM's, closer to it than the LM's stopping rule
   leaves the LM (a relative cost change below 1e-12 allows a last step of up to 1e-6
   of the residual norm). Typically two Jacobians per solve.
   With orientations, the first solve (whose solution sets only the second's tool
   rotation) takes one true Jacobian and its chord to that Jacobian's fixed point. The
   posterior (split halves) is computed from the Jacobian that certified the solution,
   evaluated one negligible step before it (the LM fit evaluates one more).

Measured against `fit` (the LM) on UR10 series C's final model of `discover` (73
parameters, positions and orientations, the prior): the held-out positions of the 5
folds agree to 4e-8 mm, those of the stability check's split halves (which extrapolate
up to 3 mm) to 6.3e-7 mm, the LM's own stopping error; the posterior sd (the halves) to
3e-7 relative; tests/test_refit.py asserts 1e-6 mm (and 1e-5 relative sd) on series C's
training split. A fold refit takes 2-3 Jacobians of the training rows and 8-12 forward
kinematics instead of 8-14 of each: the refit CV of that model 2.3x faster, the split
halves (with their posterior) 1.8-2.8x (cProfile of `discover` on that split: the fold
refits 2.2x, docs/performance.md).

`refit_from` fits a model whose start is not its own full-data fit (the per-fold models
of the procedure CV, `torchcal.diagnosis.procedure_cv`: the fold's own orders, started
from the candidate's values matched by name, new ones at zero) the same way, the shared
Jacobian replaced by the training rows' own Jacobian at the start (the one `fit`'s
identifiability step evaluates there, with the tool rotation solved at the start as `fit`
solves it): the same identifiability, tool-rotation step and certificate. On UR10 series
C's `discover` (55 such fold fits) it takes 4.0 Jacobians and 11.5 forward kinematics per
fold fit where the LM took 8-9 and 11 (68 against 152 ms CPU, medians); the printed figures are the
same, the `--json` refit-CV figures within 7e-10 mm (tests/test_refit.py,
tests/test_procedure_cv.py: 1e-6 mm asserted).

`warm_fit` fits a full model (all rows) from a warm start the same way: `fit`'s
identifiability (the pivoting) at the start's own Jacobian, the tool-rotation step and
the rule for the prior's rho (re-estimated from the fit's residual until it settles), each
solve by chord iterations, the metric A rebuilt from every fresh Jacobian (the start can be
far from the fit: new parameters at zero), to the same certificate. It serves the
candidates' full fits of `discover` (`torchcal.diagnosis.step.candidate_fit`) and the
reduced models of its stability check (`torchcal.diagnosis.stability.without`): on UR10
series C's training split 15 fits, all by the chord, 1.7-2.1x faster each than the LM
`fit` (0.06 against 0.11 s CPU), fitted positions within 5e-8 mm of it, rho within 7e-10
and the posterior sd within 2e-7 relative (tests/test_refit.py asserts 1e-6 mm, 1e-8
and 1e-5). None where the chord does not apply (the caller's `fit`).

`refit` returns None where this does not apply, and the caller fits with the LM: a
prior whose rho the refit would estimate itself (a full fit without plausible limits),
a robust or damped full fit, a step that would cross a lower bound (backlash >= 0), a
chord that contracts slowly (a step above MAX_RATE of the one before), Jacobians whose
first steps shrink by less than MAX_GN_RATE per Jacobian (a large residual along a
nearly flat direction, where Gauss-Newton itself converges slowly: on series D's
training split the folds move tool_z by 10 mm, and every fold is the LM's), more than
MAX_CHORD iterations in a phase or MAX_JACOBIANS Jacobians in a solve, or a non-finite
value. A fit whose first fold falls back has its later folds, and later calls' folds,
fitted by the LM at once (`torchcal.diagnosis.crossval.fold_refits`): on series D the
attempts cost 2 % of `discover`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch

from torchcal.calibration.fit import FitResult, Solved, _position_residual, fitted
from torchcal.calibration.identifiability import RANK_TOL, beyond_doubt, check_enough_rows, identifiability
from torchcal.calibration.plausibility import plausible_scales
from torchcal.calibration.prior import RHO_EXACT, prior_factors, prior_strength, rho_settled
from torchcal.defaults import MAX_ANGLE_DEG, MAX_LENGTH_MM
from torchcal.calibration.rows import Rows, orientation_weight, so3_error_jacobian
from torchcal.rotations import procrustes_rotation

#: a chord phase stops at a step whose length (metric of A) is at most this share of the residual norm
STEP_TOL = 1e-9
#: chord iterations per phase at most (then the caller's LM fit)
MAX_CHORD = 20
#: an approximate phase (the shared Jacobian) stops at a step this share of its first
APPROX_TOL = 1e-3
#: true Jacobians per solve at most (then the caller's LM fit: a problem on which the chord crawls)
MAX_JACOBIANS = 5
#: a fresh Jacobian's first step above this share of the previous one's: the LM fit instead
#: (measured: at most 0.017 where the chord certified, the README loop and series C; 0.13-0.27
#: on series D's folds, which never certified)
MAX_GN_RATE = 0.1
#: a phase whose steps shrink by less than this factor does not contract: the LM fit instead
MAX_RATE = 0.2


@dataclass(frozen=True)
class Shared:
    """The rows of all the data at theta (P,): J (N, 3, P) position Jacobian; with
    orientations W (N, 3, P) the angular velocities and R (N, 3, 3) the model's
    orientations (`CalibrationModel.jacobians(frame=True)`), else None."""

    theta: torch.Tensor
    J: torch.Tensor
    W: torch.Tensor | None = None
    R: torch.Tensor | None = None


def shared(full: FitResult, ctx, orientation: bool) -> Shared:
    """The `Shared` Jacobian of the fitted model `full` at its theta, rows of ctx."""
    with torch.no_grad():
        if not orientation:
            return Shared(full.theta, full.model.jacobians(full.theta, ctx)[0])
        J, W, R = full.model.jacobians(full.theta, ctx, rotation=True, frame=True)
    return Shared(full.theta, J, W, R)


def applies(full: FitResult) -> bool:
    """Whether `refit` can refit `full`: a plain fit (not robust, not damped) whose prior,
    if any, has its rho (plausible limits recorded)."""
    return full.robust is None and not full.damping and full.plausible_limits is not None \
        and full.plausible_limits.get("prior_sigma_mm") is not None


def _rows_jacobian(sh: Shared, train: torch.Tensor, rows: Rows) -> torch.Tensor:
    """(n, k, P) the Jacobian of `rows` (the training rows `train` (N,) of sh, with their
    tool rotation) at sh.theta, taken from sh."""
    J = sh.J[train]
    if rows.rotation is None:
        return J
    out = J.new_empty(J.shape[0], 6, J.shape[-1])
    out[:, :3] = J
    out[:, 3:] = so3_error_jacobian(sh.R[train] @ rows.tool_R, rows.rotation, sh.W[train], -rows.w_rot)
    return out


class _NoChord(Exception):
    """A chord phase did not converge (or left the bounds): the LM fit instead."""


@dataclass(frozen=True)
class _Metric:
    """The chord iterations' fixed matrix: A = J0^T J0 + Pp on the free columns (F, F),
    d (F,) the square roots of its diagonal, L the Cholesky factor of D^-1 A D^-1 (D =
    diag(d): unit diagonal, so columns in mm and in rad do not spoil the factorisation),
    the prior's information p2 (F,) = pf^2 on them."""

    A: torch.Tensor
    d: torch.Tensor
    L: torch.Tensor
    p2: torch.Tensor

    def solve(self, g: torch.Tensor) -> torch.Tensor:
        """A^-1 g (F,)."""
        return torch.cholesky_solve((g / self.d)[:, None], self.L)[:, 0] / self.d


def _metric(G: torch.Tensor, pf: torch.Tensor) -> _Metric:
    """The `_Metric` of the Gram matrix G (F, F) of the rows' Jacobian on the free
    columns, prior factors pf (F,) on them."""
    p2 = pf ** 2
    A = G + torch.diag(p2)
    d = A.diagonal().clamp_min(1e-300).sqrt()
    L, info = torch.linalg.cholesky_ex(A / d[:, None] / d[None])
    if int(info):
        raise _NoChord("normal matrix not positive definite")
    return _Metric(A, d, L, p2)


def _chord(rows: Rows, J: torch.Tensor, metric: _Metric, free: torch.Tensor, x: torch.Tensor,
           lower: torch.Tensor | None, approx: bool = True, r0: torch.Tensor | None = None
           ) -> tuple[torch.Tensor, int, bool, float]:
    """(x (P,), iterations, certified, the first step's length): chord iterations ``x <- x - A^-1 (J^T r(x) + Pp x)``
    from x with the fixed Jacobian J (n, k, P) of the rows (A of `metric`: it sets the rate
    only), moving `free` (P,) only, until a step is at most APPROX_TOL of the first (J's
    fixed point reached as far as it is worth: a later Jacobian corrects it) or at most
    STEP_TOL of the residual norm; certified: that happened on the first step, i.e. J's
    Gauss-Newton step at x was already negligible (module doc, 3.). approx False: on to
    STEP_TOL of the residual norm (J's own fixed point). r0: the rows' residual (n, k)
    at x when already evaluated (with J, `Rows.jacobian(residual=True)`)."""
    Jt = J.reshape(-1, J.shape[-1]).T  # a view: J^T r on all columns, then the free ones
    A, p2 = metric.A, metric.p2
    first = last = math.inf
    for it in range(1, MAX_CHORD + 1):
        r = (rows.residual(x, walk_once=True) if it > 1 or r0 is None else r0).reshape(-1)
        xf = x[free]
        step = -metric.solve((Jt @ r)[free] + p2 * xf)
        size = float(step @ (A @ step)) ** 0.5
        norm = float(r @ r + p2 @ (xf * xf)) ** 0.5
        if not (math.isfinite(size) and math.isfinite(norm)):
            raise _NoChord("a non-finite step")
        x = x.clone()
        x[free] = xf + step
        if lower is not None and bool((x < lower).any()):
            raise _NoChord("a step crosses a lower bound")
        first = size if it == 1 else first
        if size <= STEP_TOL * norm:
            return x, it, it == 1, first
        if size > MAX_RATE * last:
            raise _NoChord("chord iterations do not contract")
        if approx and size <= APPROX_TOL * first:
            return x, it, False, first
        last = size
    raise _NoChord("chord iterations did not converge")


def _solve(rows: Rows, J: torch.Tensor, metric: _Metric, free: torch.Tensor, x: torch.Tensor,
           lower: torch.Tensor | None, certify: bool = True, r0: torch.Tensor | None = None,
           refresh=None) -> tuple[torch.Tensor, torch.Tensor, int]:
    """(x (P,), the rows' Jacobian at the last point it was evaluated, iterations): the
    stationary point of the rows plus the prior from x, by chord iterations with J (a
    Jacobian evaluated elsewhere), then with the true Jacobian at the point reached, again
    and again, until that Jacobian's first step is at most STEP_TOL of the residual norm
    (module doc, 2. and 3.); at most MAX_JACOBIANS of them, each one's first step at most
    MAX_GN_RATE of the one before (else Gauss-Newton converges slowly: the LM instead).
    certify False: one true Jacobian, its chord to its fixed point (the first solve of a fit with orientations,
    whose solution sets only the tool rotation of the second, module doc). r0: the rows'
    residual at x when already evaluated (with J). refresh: J (n, k, P) -> the `_Metric` of
    a fresh Jacobian (a start far from the fit, where the first Jacobian's A would not
    contract: `warm_fit`), None: the one metric throughout."""
    x, its, _, _ = _chord(rows, J, metric, free, x, lower, r0=r0)
    before = math.inf
    for _ in range(MAX_JACOBIANS):
        J, r = rows.jacobian(x, residual=True)  # the residual at x from the same chain walk
        if refresh is not None:
            metric = refresh(J)
        x, k, certified, first = _chord(rows, J, metric, free, x, lower, approx=certify, r0=r)
        its += k
        if certified or not certify:
            return x, J, its
        if first > MAX_GN_RATE * before:  # Gauss-Newton itself converges slowly here
            raise _NoChord("successive Jacobians' first steps shrink slowly")
        before = first
    raise _NoChord("no Jacobian certified a stationary point")


def refit(full: FitResult, sh: Shared, m, ctx, train: torch.Tensor, *, sigma_mm: float, sigma_deg: float,
          posterior: bool = True) -> FitResult | None:
    """`fit` of `full`'s model on the rows `train` (N,) bool of the measurements m
    (context ctx), as `torchcal.diagnosis.crossval.fold_fit` asks it (from full.theta,
    full's identifiable set as candidates, its plausible scales and rho, the measured
    orientations when m has them, weighed by sigma_mm / sigma_deg), by the shared
    Jacobian sh (`shared`) and chord iterations (module doc); None where they do not apply
    (the caller fits with the LM). InputError as `fit` (too few rows)."""
    if not applies(full):
        return None
    rows = _fold_rows(full, m, ctx, train, sigma_mm, sigma_deg)
    if rows.rotation is not None:  # the tool rotation at theta*, from the shared orientations
        rows = replace(rows, tool_R=procrustes_rotation(sh.R[train], rows.rotation))
    return _chord_fit(full, rows, _rows_jacobian(sh, train, rows), m.pose[train], sigma_mm=sigma_mm,
                      sigma_deg=sigma_deg, posterior=posterior)


def refit_from(start: FitResult, m, ctx, train: torch.Tensor, *, sigma_mm: float, sigma_deg: float,
               posterior: bool = True) -> FitResult | None:
    """The same fit as `refit` (`fold_fit` of `start` on the rows `train` (N,) bool of m,
    from start.theta) where start is not a fit of its model on all of m, so that no shared
    Jacobian serves it (the per-fold models of `torchcal.diagnosis.procedure_cv`, whose
    start is the candidate's values matched by name): the first Jacobian is the training
    rows' own at start.theta, the one `fit`'s identifiability step evaluates, with the tool
    rotation solved there as `fit` solves it; then the same chord iterations and
    certificate (module doc). None where they do not apply (the caller's LM fit)."""
    if not applies(start):
        return None
    rows = _fold_rows(start, m, ctx, train, sigma_mm, sigma_deg)
    if rows.rotation is not None:
        rows = rows.with_tool_rotation(start.theta)
    with torch.no_grad():
        J0, r0 = rows.jacobian(start.theta, residual=True)
    return _chord_fit(start, rows, J0, m.pose[train], sigma_mm=sigma_mm, sigma_deg=sigma_deg, posterior=posterior,
                      r0=r0)


def _fold_rows(full: FitResult, m, ctx, train: torch.Tensor, sigma_mm: float, sigma_deg: float) -> Rows:
    """The `Rows` of full's model on the rows `train` (N,) bool of m (no tool rotation yet)."""
    return Rows(full.model, ctx.subset(train), m.xyz[train], None if m.rxyz is None else m.rotation[train],
                orientation_weight(sigma_mm, sigma_deg))


def _chord_fit(full: FitResult, rows: Rows, J0: torch.Tensor, pose: torch.Tensor, *, sigma_mm: float,
               sigma_deg: float, posterior: bool, r0: torch.Tensor | None = None) -> FitResult | None:
    """The fold fit of `refit` / `refit_from` on `rows` (their tool rotation at full.theta)
    from full.theta, J0 (n, k, P) the rows' Jacobian there: the identifiability of the
    training rows, the chord solves, the `FitResult` (pose (n,) the rows' pose ids); None
    where the chord does not apply (`_NoChord`); r0 the rows' residual (n, k) at
    full.theta when already evaluated with J0."""
    model, theta = full.model, full.theta
    lim = full.plausible_limits
    scales = plausible_scales(model, lim.get("max_length_mm"), lim.get("max_angle_deg")).to(theta)
    rho = lim["prior_sigma_mm"]
    pf = prior_factors(rho, scales)
    cand = full.report.free.to(theta.device)
    Jc = J0.reshape(-1, J0.shape[-1])[:, cand]
    G = Jc.T @ Jc
    n = rows.xyz.shape[0]
    report = beyond_doubt(G, cand, n)
    if report is None:
        report = identifiability(J0, model.param_names(), cand, RANK_TOL, first=~torch.isfinite(scales))
    check_enough_rows(report, rows.k * n, model, rows.ctx, cand, RANK_TOL)
    free = report.free.to(theta.device)
    keep = free[cand]
    lower = model.lower_bounds().to(theta)
    lower = None if bool(torch.isinf(lower[free]).all()) else torch.where(free, lower, -math.inf)
    try:
        # one factorisation serves every phase: A sets the rate, not the result
        metric = _metric(G[keep][:, keep], pf[free])
        x, J, its = _solve(rows, J0, metric, free, theta, lower, certify=rows.rotation is None, r0=r0)
        if rows.rotation is not None:  # the tool-rotation step, then the second solve
            rows = rows.with_tool_rotation(x)
            x, J, k = _solve(rows, J, metric, free, x, lower)
            its += k
    except _NoChord:
        return None
    s = Solved(x[None], torch.ones(n, dtype=x.dtype, device=x.device), its, "converged")
    return fitted(rows, x, report, s, scales=scales, rho=rho, pose=pose, posterior=posterior,
                  max_length_mm=lim.get("max_length_mm"), max_angle_deg=lim.get("max_angle_deg"),
                  sigma_mm=sigma_mm, sigma_deg=sigma_deg, jacobian=J if posterior else None)


def warm_fit(model, ctx, xyz: torch.Tensor, theta0: torch.Tensor, free: torch.Tensor, *, pose=None,
             rotation: torch.Tensor | None = None, sigma_mm: float, sigma_deg: float) -> FitResult | None:
    """`fit(model, ctx, xyz, theta0=theta0, free=free, pose=pose, rotation=rotation,
    sigma_mm=sigma_mm, sigma_deg=sigma_deg)` (a warm start: the plausibility prior with its
    default scales, its rho estimated from the fit's own residual) with each LM solve
    replaced by chord iterations and the certificate of the fold refits (module doc): the
    same identifiability at theta0 (the pivoting), tool-rotation step (Procrustes at theta0
    and at the first solution) and rho rule (`fit`'s: once more after the first solution,
    up to three more while it moves by more than 10 %); the first solve, whose solution
    sets only the tool rotation and the first rho, to one true Jacobian's fixed point, the
    later ones certified (a stationary point to STEP_TOL of the residual norm, where the
    LM stops at a relative cost change of 1e-12). The candidates' and the reduced models'
    full fits of `torchcal.diagnosis` (`candidate_fit`, `stability.without`). None where
    the chord does not apply (no prior, a slow chord, a bound crossed: the caller's `fit`);
    InputError as `fit` (too few rows)."""
    model.check_context(ctx)
    rows = Rows(model, ctx, xyz, rotation, orientation_weight(sigma_mm, sigma_deg))
    if rotation is not None:
        rows = rows.with_tool_rotation(theta0)
    with torch.no_grad():
        J0, r0 = rows.jacobian(theta0, residual=True)
    scales = plausible_scales(model, MAX_LENGTH_MM, MAX_ANGLE_DEG).to(theta0)
    if not bool(torch.isfinite(scales).any()):
        return None
    report = identifiability(J0, model.param_names(), free, RANK_TOL, first=~torch.isfinite(scales))
    check_enough_rows(report, rows.k * xyz.shape[0], model, ctx, free, RANK_TOL)
    free_now = report.free.to(theta0.device)
    lower = model.lower_bounds().to(theta0)
    lower = None if bool(torch.isinf(lower[free_now]).all()) else torch.where(free_now, lower, -math.inf)

    def metric(J: torch.Tensor, rho: float) -> _Metric:  # A of the Jacobian J (n, k, P), the prior of rho
        Jf = J.reshape(-1, J.shape[-1])[:, free_now]
        return _metric(Jf.T @ Jf, prior_factors(rho, scales)[free_now])

    try:
        rho = sigma_mm
        x, J, its = _solve(rows, J0, metric(J0, rho), free_now, theta0, lower, certify=rows.rotation is None, r0=r0,
                           refresh=lambda Jn: metric(Jn, rho))
        if rows.rotation is not None:
            rows = rows.with_tool_rotation(x)
        rho = prior_strength(_position_residual(rows, x[None]))
        if rows.rotation is not None or rho >= RHO_EXACT:
            x, J, its = _solve(rows, J, metric(J, rho), free_now, x, lower, refresh=lambda Jn: metric(Jn, rho))
        for _ in range(3):  # rho and the fit agree (`fit`'s rule)
            new = prior_strength(_position_residual(rows, x[None]))
            if rho_settled(new, rho):
                break
            rho = new
            x, J, its = _solve(rows, J, metric(J, rho), free_now, x, lower, refresh=lambda Jn: metric(Jn, rho))
    except _NoChord:
        return None
    n = xyz.shape[0]
    s = Solved(x[None], torch.ones(n, dtype=x.dtype, device=x.device), its, "converged")
    return fitted(rows, x, report, s, scales=scales, rho=rho, pose=pose, posterior=True,
                  max_length_mm=MAX_LENGTH_MM, max_angle_deg=MAX_ANGLE_DEG, sigma_mm=sigma_mm,
                  sigma_deg=sigma_deg, jacobian=J)
