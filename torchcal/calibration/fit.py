"""The fit of a `CalibrationModel`: `fit`, a composition of separately tested parts.

1. Start (`start`): the given theta0, or nominal, or (a model with base_frame) the
   closed-form registration of the nominal model onto the measurements
   (`torchcal.calibration.registration`).
2. Rows (`torchcal.calibration.rows`): position rows and, with measured orientations,
   orientation rows with the tool-rotation step (Procrustes at the start and after the
   first solve).
3. Identifiability (`torchcal.calibration.identifiability`) at the start, the parameters
   without a plausibility prior (the frames) pivoted first; those the poses cannot
   identify are held at nominal; too few equations is refused in words. From a cold start
   (nominal or registration) it is judged once more at the first solution (`recheck`).
4. Prior rows (`torchcal.calibration.prior`): one row ``rho * theta_i / s_i`` per
   parameter with a plausible scale s_i (`torchcal.calibration.plausibility`); rho is the
   fit's own per-axis residual RMS (a first solve with rho = sigma_mm gives it, a second,
   warm-started, solve uses it, and up to three more while rho moves by more than 10 %; a
   robust fit takes it over the rows within the IRLS threshold only).
   Parameters that end beyond their scale anyway are named (`FitResult.implausible`).
5. Solve (`solve`): Levenberg-Marquardt (`torchcal.calibration.lm`) on the identifiable
   parameters, with robust row weights by IRLS when asked (`torchcal.calibration.robust`:
   Huber or Cauchy on the per-pose distance residual).
6. Covariance (`torchcal.calibration.covariance`): posterior standard errors, the prior
   included, ``s^2 (J^T W J + Pp)^-1`` with ``Pp = diag(rho^2 / s_i^2)``, s^2 = weighted
   RSS / dof, pose-level when poses repeat.

Each part is a function of its inputs; `fit` passes state between them explicitly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from torchcal.calibration.covariance import ParameterCovariance, parameter_covariance, row_covariance
from torchcal.calibration.identifiability import (RANK_TOL, Identifiability, beyond_doubt, check_enough_rows,
                                                  identifiability, recheck)
from torchcal.calibration.joint_range import condition_range, joint_range, seed_poses
from torchcal.calibration.lm import levenberg_marquardt
from torchcal.calibration.model import CalibrationModel
from torchcal.calibration.prior import RHO_EXACT, prior_factors, prior_strength, rho_settled
from torchcal.calibration.robust import robust_weights
from torchcal.calibration.rows import Rows, orientation_weight
from torchcal.defaults import MAX_ANGLE_DEG, MAX_LENGTH_MM, SIGMA_DEG, SIGMA_MM
from torchcal.effects.context import Context

ROBUST_ROUNDS = 8  # IRLS rounds at most
WEIGHT_TOL = 1e-4  # IRLS stops once no robust weight moves by more


@dataclass
class FitResult:
    """THE fitted model: what `torchcal.fit`, `torchcal.register` and
    `torchcal.io.modelfile.load` (``torchcal.load``) return and what `evaluate`,
    `compensate`, `export` and `accuracy` take. Every fact about a fitted model lives
    here, as a declared field; the `CalibrationModel` (``model``) is the structure only
    (robot, effects, parameter layout) and holds no fitted value. One type rather than a
    fit result beside a loaded (model, theta) pair: the two carried different facts
    (settings, tool rotation, calibrated range), and whichever way a model comes in, in
    memory or from MODEL.json, evaluate and compensate now see the same fields. The name
    stays `FitResult` (every fitted model comes from a fit; registration only moves its
    frame).

    model: the `CalibrationModel`; theta: (P,) parameters in the model's units (mm, rad);
    std: (P,) standard errors (0 where held); residuals: (N, 3) mm measured - model on the
    data of the fit (None after `load`: MODEL.json stores no rows); weights: (N,) final
    robust weights (ones when not robust; None after `load`); report: identifiability
    (``report.free`` the identified parameters, ``report.held`` those held at nominal);
    n_iter: solver iterations; outliers: row indices with weight below 0.1 (robust fits;
    after `load` the file's ``outlier_poses``, pose ids when it was written with them);
    covariance: the (P, P) `ParameterCovariance` (None when unknown); status: how the
    (last) LM solve stopped, 'converged', 'stalled' or 'max_iterations'
    (`torchcal.calibration.lm.LMStatus`).
    registration: the closed-form start (rms before/after, frame), or after `register` the
    re-registration, or None; implausible: names of free parameters that end beyond their
    plausible scale although the prior shrinks them (none is held for it);
    plausible_limits: {"max_length_mm", "max_angle_deg", "prior_sigma_mm"} (rho of the
    prior rows) or None (no prior); orientation: {"sigma_mm", "sigma_deg",
    "weight_mm_per_rad", "tool_rotation" (3, 3), "rms_deg"} when orientations were fitted,
    else None. q_range: (2, n) calibrated joint range, the min and max of the data's
    commanded q, rad / mm (`torchcal.calibration.joint_range`; None when unknown);
    seed_poses: (K, n) a few calibration poses that seed compensate (`joint_range.seed_poses`).
    conditions: {"temp_c": [lo, hi] degC, "payload_kg": [lo, hi] kg} the data spanned of each
    condition one of the effects reads (`joint_range.condition_range`), None when none (or unknown).
    robust, sigma_mm, sigma_deg: the settings of the fit that made it. residual_model: the
    optional non-physical residual stage (`torchcal.calibration.residual_model`), applied
    by evaluate and compensate. training: {"n", "rms_mm", "max_mm"} of the data the model
    was fitted on (kept by `register`, whose residuals are those of the new data).
    provenance: MODEL.json's {"input", "input_sha256", "torchcal_version", "seed"} after
    `load`; None for a fit in memory (`torchcal.save` writes it from its arguments).
    set_by_prior: names of free parameters the data do not determine (posterior sd at least
    half their plausible scale, `torchcal.calibration.plausibility.set_by_prior`): their
    value is the prior's, not a measurement.
    """

    model: CalibrationModel
    theta: torch.Tensor
    std: torch.Tensor
    residuals: torch.Tensor | None
    weights: torch.Tensor | None
    report: Identifiability
    n_iter: int
    outliers: list = field(default_factory=list)
    covariance: ParameterCovariance | None = None  # (P, P) and how it was estimated
    status: str = "converged"
    registration: dict | None = None
    implausible: list = field(default_factory=list)
    orientation: dict | None = None
    plausible_limits: dict | None = None
    q_range: torch.Tensor | None = None  # (2, n) [min; max] commanded q of the data, rad / mm
    seed_poses: torch.Tensor | None = None  # (K, n) calibration poses that seed compensate, rad / mm
    conditions: dict | None = None  # {"temp_c": [lo, hi], "payload_kg": [lo, hi]} its effects read (joint_range)
    robust: str | None = None
    sigma_mm: float = SIGMA_MM
    sigma_deg: float = SIGMA_DEG
    residual_model: object = None
    training: dict | None = None
    provenance: dict | None = None
    set_by_prior: list = field(default_factory=list)
    residual_test: dict | None = None  # the residual stage's held-out test (torchcal.diagnosis.residual_stage)
    radius: torch.Tensor | None = None  # (P,) interval half-widths of an interval calibration (intervals.py)
    damping: float = 0.0  # mu of eq. 29 the fit was damped with (0: none)

    @property
    def converged(self) -> bool:
        """True only when the solver met its convergence rule (never for a stalled solve)."""
        return self.status == "converged"

    @property
    def rms_mm(self) -> float:
        """RMS of the distance residual per pose, mm (of ``residuals``; after `load`, the
        training rms)."""
        if self.residuals is None:
            return self.training_rms_mm
        return float(self.residuals.norm(dim=-1).pow(2).mean().sqrt())

    @property
    def training_rms_mm(self) -> float | None:
        """RMS mm of the fit the model came from (None when unknown), the scale of the
        gross-mismatch check (`torchcal.calibration.checks`)."""
        return None if self.training is None else self.training.get("rms_mm")

    @property
    def tool_rotation(self) -> torch.Tensor | None:
        """(3, 3) measured tool frame <- nominal tool frame of a model fitted to
        orientations, else None."""
        return None if self.orientation is None else self.orientation["tool_rotation"]

    # one parameter set for every position; `torchcal.calibration.zone_calibration.ZonedFit`
    # overrides these three with one set per zone of its partition
    @property
    def zone_theta(self) -> torch.Tensor:
        """(Z, P) parameters of each zone: theta as the one row of a model without zones."""
        return self.theta[None]

    def assign(self, positions: torch.Tensor) -> torch.Tensor:
        """(M,) int64 1-based zone of each position (M, 3) mm: 1 without zones."""
        return torch.ones(positions.shape[0], dtype=torch.long)

    def predict(self, ctx: Context) -> torch.Tensor:
        """(N, 3) mm model positions of the rows of ctx (the residual stage not included)."""
        return self.model.predict(self.theta.to(ctx.q), ctx)


def training_summary(residuals: torch.Tensor) -> dict:
    """{"n", "rms_mm", "max_mm"} of residuals (N, 3) mm."""
    d = residuals.detach().norm(dim=-1)
    return {"n": int(d.shape[0]), "rms_mm": float(d.pow(2).mean().sqrt()), "max_mm": float(d.max())}


def start(model: CalibrationModel, ctx: Context, xyz: torch.Tensor, theta0=None,
          register: bool = True) -> tuple[torch.Tensor, dict | None]:
    """(theta (P,), registration info or None): theta0 when given; else nominal, or, for a
    model with base_frame and at least 3 rows when `register`, the closed-form rigid
    registration of the nominal model onto xyz (N, 3) mm."""
    from torchcal.calibration import registration as reg

    if theta0 is not None:
        return theta0, None
    if register and any(e.name == "base_frame" for e in model.effects) and xyz.shape[0] >= 3:
        return reg.register_frame(model, ctx, xyz)
    return model.zeros(), None


@dataclass(frozen=True)
class Solved:
    """One `solve`: x (1, P), weights (N,) the robust weights x was solved with (ones
    when not robust; once IRLS settled, the robust weights of x's own residuals to within
    WEIGHT_TOL), n_iter and status of the last LM solve."""

    x: torch.Tensor
    weights: torch.Tensor
    n_iter: int
    status: str


def solve(rows: Rows, x: torch.Tensor, free: torch.Tensor, prior: torch.Tensor, *, robust: str | None = None,
          max_iter: int = 60, lower: torch.Tensor | None = None, anchor=None, known=None) -> Solved:
    """LM on the measurement rows plus the prior rows ``prior_i * theta_i`` (prior (P,),
    `torchcal.calibration.prior.prior_factors`), from x (1, P), moving the parameters
    `free` (P,) bool only, above `lower` (P,) (None: unbounded). robust ('huber',
    'cauchy'): IRLS, the row weights recomputed from the distance residual after each
    solve (`torchcal.calibration.robust.robust_weights`), at most ROBUST_ROUNDS times,
    until no weight moves by more than WEIGHT_TOL. anchor (damp (P,), theta0 (P,)): the
    damping rows ``damp_i * (theta_i - theta0_i)`` as well (`fit`'s `damping`). known
    (theta (P,), J (N, k, P)): the rows' Jacobian already evaluated at theta (`fit`'s
    identifiability step), taken for an LM iteration at that theta instead of a second
    evaluation (the same numbers)."""
    n, k = rows.xyz.shape[0], rows.k
    weights = torch.ones(n, dtype=rows.xyz.dtype, device=rows.xyz.device)
    damp, theta0 = anchor if anchor is not None else (None, None)

    def res_fn(z):
        extra = [] if damp is None else [damp * (z[0] - theta0)]
        return torch.cat([rows.residual(z[0]).reshape(-1), prior * z[0]] + extra).unsqueeze(0)

    store = []  # the buffer, allocated once per solve: the LM uses a Jacobian within its iteration only

    def jac_fn(z):  # one (1, n k + P [+ P], P) buffer: the rows' Jacobian is written into it
        P = z.shape[-1]
        if not store:
            store.append(z.new_empty(n * k + (1 if damp is None else 2) * P, P))
        out = store[0]
        if known is not None and torch.equal(z[0], known[0]):
            out[: n * k] = known[1].reshape(n * k, P)
        else:
            rows.jacobian(z[0], out=out[: n * k].view(n, k, P))
        out[n * k: n * k + P] = torch.diag(prior)
        if damp is not None:
            out[n * k + P:] = torch.diag(damp)
        return out.unsqueeze(0)

    for i in range(1 if robust is None else ROBUST_ROUNDS):
        w = torch.cat([weights.repeat_interleave(k), torch.ones_like(prior)]
                      + ([] if damp is None else [torch.ones_like(damp)])).unsqueeze(0)
        res = levenberg_marquardt(res_fn, x, free=free, weights=w, jacobian_fn=jac_fn, max_iter=max_iter, lower=lower)
        x = res.x
        if robust is None:
            break
        new = robust_weights((rows.model.predict(x[0], rows.ctx) - rows.xyz).norm(dim=-1), robust)
        if bool((new - weights).abs().max() < WEIGHT_TOL) or i == ROBUST_ROUNDS - 1:
            break  # x is returned with the weights it was solved with
        weights = new
    return Solved(x, weights, int(res.n_iter[0]), res.status_labels()[0])


def _position_residual(rows: Rows, x: torch.Tensor) -> torch.Tensor:
    """(N, 3) model - measured positions mm at x (1, P), off the graph."""
    with torch.no_grad():
        return rows.model.predict(x[0], rows.ctx) - rows.xyz


def fit(model: CalibrationModel, ctx: Context, xyz: torch.Tensor, *, theta0=None, free=None,
        robust: str | None = None, max_iter: int = 60, rank_tol: float = RANK_TOL,
        pose=None, rotation: torch.Tensor | None = None, sigma_mm: float = SIGMA_MM,
        sigma_deg: float = SIGMA_DEG, register: bool = True,
        max_length_mm: float | None = MAX_LENGTH_MM,
        max_angle_deg: float | None = MAX_ANGLE_DEG, prior_sigma_mm: float | None = None,
        prior: bool = True, damping: float = 0.0, posterior: bool = True,
        rank_shortcut: bool = False) -> FitResult:
    """Fit model parameters to measured TCP positions xyz (N, 3) mm [and orientations].

    pose: (N,) int pose ids; with repeats the standard errors are pose-level
    (`torchcal.calibration.covariance`).

    free: (P,) bool candidate parameters (default `model.default_free()`); the
    identifiability analysis at the (registered) start may hold more. robust: None,
    'huber' or 'cauchy'.

    Registration (`register`, theta0 not given, the model has base_frame): the start is
    the closed-form rigid registration of the nominal model onto the measurements
    (torchcal.calibration.registration), so the base frame carries the instrument's frame
    and the robot's deviations start (and stay) small.

    Orientation (`rotation` (N, 3, 3) measured, measurement frame <- measured tool frame):
    each row adds three residuals, the orientation error in rad times
    ``sigma_mm / radians(sigma_deg)`` (mm per rad), i.e. both kinds of residual are
    weighed by their stated measurement uncertainty (default 0.01 mm and 0.01 deg). The
    constant rotation between the nominal tool frame and the measured frame is solved in
    closed form (Procrustes) at the start and again after the first fit.

    Plausibility (the prior, module doc): MD-H deviations have the scales `max_length_mm`
    (dd, da) and `max_angle_deg` (dtheta, dalpha, dbeta), effect parameters their
    effect's `plausible_max()`; each None scale drops its own prior only. rho: the
    per-axis RMS of the position residual of a first solve with rho = sigma_mm, or
    `prior_sigma_mm` when given (one solve; the fold refits of a cross-validation pass
    the full fit's). Free parameters ending beyond their scale are listed in
    `FitResult.implausible`. prior=False leaves the plausibility prior out altogether.

    Damping (docs/paper.md eq. 29, `torchcal.calibration.intervals`): with ``damping = mu
    > 0`` the fit is the damped least-squares solution around the start theta0: rows
    ``sqrt(mu) D (theta - theta0)`` on the free parameters, D the column norms of the
    Jacobian at theta0 (scale-invariant), which shrink what the data barely determine
    towards theta0 (e.g. a zone towards the global calibration). They count as prior
    information in the covariance, and with them fewer equations than parameters are
    allowed.

    posterior=False skips the covariance (std NaN, covariance None, set_by_prior empty):
    for the fold refits of a cross-validation, which use theta only.

    rank_shortcut=True (a warm start theta0): where every candidate is identifiable beyond
    doubt (`torchcal.calibration.identifiability.beyond_doubt`: the smallest singular value
    of the unit columns far above rank_tol), the identifiability report comes from the
    candidate columns' Gram matrix instead of the pivoting: the same free set, the
    condition number and observability to rounding. For fold refits, whose report serves
    its free set.
    """
    from torchcal.calibration.plausibility import plausible_scales

    model.check_context(ctx)
    cold = theta0 is None  # a start at nominal / registration, possibly far from the fit
    theta0, reg_info = start(model, ctx, xyz, theta0, register)
    cand = model.default_free() if free is None else free
    names = model.param_names()
    rows = Rows(model, ctx, xyz, rotation, orientation_weight(sigma_mm, sigma_deg))
    if rotation is not None:
        rows = rows.with_tool_rotation(theta0)
    J0 = rows.jacobian(theta0)
    scales = plausible_scales(model, max_length_mm, max_angle_deg).to(theta0) if prior else \
        torch.full_like(theta0, math.inf)
    report = None
    if rank_shortcut and not cold:
        Jc = J0.reshape(-1, J0.shape[-1])[:, cand.to(J0.device)]
        report = beyond_doubt(Jc.T @ Jc, cand, xyz.shape[0], rank_tol)
    if report is None:
        report = identifiability(J0, names, cand, rank_tol, first=~torch.isfinite(scales))
    # damping rows make up for missing equations (docstring): only "nothing identifiable" is refused then
    check_enough_rows(report, math.inf if damping else rows.k * xyz.shape[0], model, ctx, cand, rank_tol)

    lower = model.lower_bounds().to(theta0)  # a physical sign (backlash >= 0): projected steps
    lower = None if bool(torch.isinf(lower).all()) else lower
    has_prior = bool(torch.isfinite(scales).any())
    # eq. 29's damping rows sqrt(mu) D (theta - theta0) on the free parameters (docstring)
    damp = (math.sqrt(damping) * J0.reshape(-1, J0.shape[-1]).norm(dim=0)) * report.free.to(theta0.device) \
        if damping else None
    options = dict(robust=robust, max_iter=max_iter, lower=lower,
                   anchor=None if damp is None else (damp, theta0))

    free_now = report.free.clone()
    rho = sigma_mm if prior_sigma_mm is None else prior_sigma_mm
    s = solve(rows, theta0.unsqueeze(0), free_now, prior_factors(rho if has_prior else 0.0, scales), **options,
              known=(theta0, J0))
    x = s.x
    if rotation is not None:
        rows = rows.with_tool_rotation(x[0])
    again, known = rotation is not None, None
    if cold:  # identifiability once more at the first solution (identifiability.recheck)
        known = (x[0], rows.jacobian(x[0]))
        report = recheck(known[1], names, cand, free_now, rank_tol)
        if not torch.equal(report.free, free_now):
            newly = free_now & ~report.free
            x = x.clone()
            x[0, newly] = theta0[newly]
            free_now, again = report.free.clone(), True
    if has_prior and prior_sigma_mm is None:  # the prior's rho from this fit's own residual
        rho = prior_strength(_position_residual(rows, x), robust is not None)
        again = again or rho >= RHO_EXACT  # below it the data are fitted exactly: no prior needed
    if again:
        s = solve(rows, x, free_now, prior_factors(rho if has_prior else 0.0, scales), **options, known=known)
        x = s.x
    for _ in range(3):  # rho and the fit agree (a first solve far from the optimum gives a rho too large)
        if not has_prior or prior_sigma_mm is not None:
            break
        new = prior_strength(_position_residual(rows, x), robust is not None)
        if rho_settled(new, rho):
            break
        rho = new
        s = solve(rows, x, free_now, prior_factors(rho, scales), **options)
        x = s.x
    return fitted(rows, x[0], report, s, scales=scales, rho=rho if has_prior else None, damp=damp, pose=pose,
                  robust=robust, posterior=posterior, registration=reg_info, max_length_mm=max_length_mm,
                  max_angle_deg=max_angle_deg, sigma_mm=sigma_mm, sigma_deg=sigma_deg, damping=damping)


def fitted(rows: Rows, theta: torch.Tensor, report: Identifiability, s: Solved, *, scales: torch.Tensor,
           rho: float | None, damp: torch.Tensor | None = None, pose=None, robust: str | None = None,
           posterior: bool = True, registration: dict | None = None, max_length_mm: float | None = MAX_LENGTH_MM,
           max_angle_deg: float | None = MAX_ANGLE_DEG, sigma_mm: float = SIGMA_MM, sigma_deg: float = SIGMA_DEG,
           damping: float = 0.0, jacobian: torch.Tensor | None = None) -> FitResult:
    """The `FitResult` of a solution theta (P,) of the rows `rows` (its tool rotation the
    one solved with): the residuals, the posterior (unless `posterior` is False) from the
    rows' Jacobian at theta (`jacobian` (N, k, P) when the caller has it, at theta or a
    negligible step from it, else evaluated here), the prior's rho (None: no prior) and the damping rows `damp` counted as prior
    information; report: the identifiability of the fit (``report.free`` moved); s: its
    last `Solved`; scales (P,) the plausible scales; the rest `fit`'s options, kept."""
    from torchcal.calibration.plausibility import beyond_plausible, set_by_prior

    model, ctx, free_now = rows.model, rows.ctx, report.free
    has_prior = rho is not None
    r = rows.residual(theta).detach()
    resid_pos = -r[:, :3]
    prior_rows = prior_factors(rho, scales) if has_prior and math.isfinite(rho) else None  # posterior
    if damp is not None:  # the damping rows are prior information too
        prior_rows = damp if prior_rows is None else (prior_rows ** 2 + damp ** 2).sqrt()
    if not posterior:
        covariance = None
    elif rows.rotation is None:
        covariance = parameter_covariance(model.jacobian(theta, ctx) if jacobian is None else jacobian, resid_pos,
                                          free_now, pose=pose, weights=s.weights if robust else None,
                                          prior=prior_rows)
    else:  # rows of 6 residuals: row-wise estimate s^2 (J^T W J)^-1
        J = rows.jacobian(theta) if jacobian is None else jacobian
        covariance = row_covariance(J.reshape(-1, theta.shape[0]), r.reshape(-1), free_now,
                                    weights=s.weights.repeat_interleave(rows.k), prior=prior_rows)
    std = torch.full_like(theta, math.nan).detach() if covariance is None else covariance.std
    orient = None
    if rows.rotation is not None:
        rot_res = r[:, 3:] / rows.w_rot  # (N, 3) rad, model vs measured
        orient = {"sigma_mm": sigma_mm, "sigma_deg": sigma_deg, "weight_mm_per_rad": rows.w_rot,
                  "tool_rotation": rows.tool_R,
                  "rms_deg": math.degrees(float(rot_res.norm(dim=-1).pow(2).mean().sqrt()))}
    return FitResult(model, theta.detach(), std, resid_pos, s.weights, report, s.n_iter,
                     torch.nonzero(s.weights < 0.1).flatten().tolist() if robust else [], covariance,
                     status=s.status, registration=registration,
                     implausible=beyond_plausible(model, theta, free_now, scales.cpu()) if has_prior else [],
                     orientation=orient,
                     plausible_limits=None if not has_prior else
                     {"max_length_mm": max_length_mm, "max_angle_deg": max_angle_deg, "prior_sigma_mm": rho},
                     q_range=joint_range(ctx.q), seed_poses=seed_poses(ctx.q),
                     conditions=condition_range(model.effects, ctx), robust=robust, sigma_mm=sigma_mm,
                     sigma_deg=sigma_deg, training=training_summary(resid_pos),
                     set_by_prior=set_by_prior(model, std, free_now, scales.cpu()) if has_prior and posterior else [],
                     damping=float(damping))
