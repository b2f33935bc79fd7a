"""Identification: identifiability analysis and the fit of a `CalibrationModel`.

Identifiability (at the starting point, on the column-scaled Jacobian):

- QR with column pivoting orders the free parameters from most to least independent;
  those whose pivot |R_kk| falls below ``rank_tol * |R_00|`` cannot be identified from
  these poses. They are reported by name and *held at nominal* (zero deviation) instead
  of being silently damped as eq. 29 would. This is what removes the gauge (a base frame
  against joint 1's dtheta and dd, a tool offset against the last link): it is decided
  at the registered start, the parameters without a plausibility prior (the frames)
  pivoted first, so the robot's deviation is the one held; from a cold start it is
  judged once more at the first solution (a held parameter is freed only where its
  pivot reaches `RECHECK_TOL`). Nothing is held for its size.
- Plausibility is part of the estimation: a weak Gaussian prior on each parameter's
  physical scale (`torchcal.calibration.plausibility.plausible_scales`), one residual row
  ``rho * theta_i / s_i`` each, with rho the fit's own per-axis residual RMS (a first
  solve with rho = sigma_mm gives it, a second, warm-started, solve uses it, and up to
  three more while rho moves by more than 10 %; a robust fit takes it over the rows
  within the IRLS threshold only, so gross rows do not inflate the prior). From a
  cold start (nominal or registration) the identifiability is judged once more at the
  first solution, before the second solve.
  Parameters that end beyond their scale anyway are named (`FitResult.implausible`).
- Singular values of the identifiable columns give the condition number and the
  observability indices of Borm & Menq / Nahvi & Hollerbach (O1..O5, m = number of poses).

The fit is Levenberg-Marquardt (`torchcal.calibration.lm`) on the identifiable parameters, with
optional robust row weights by IRLS (Huber or Cauchy on the per-pose distance residual,
scale = the median distance residual, thresholds at ROBUST_K = 2.5 times it). Standard errors are
posterior ones, the prior included: ``s^2 (J^T W J + Pp)^-1`` with ``Pp = diag(rho^2 / s_i^2)``,
s^2 = weighted RSS / dof, pose-level when poses repeat (`torchcal.calibration.covariance`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import math

import torch

from torchcal.effects.context import Context
from torchcal.errors import InputError
from torchcal.calibration.lm import levenberg_marquardt
from torchcal.calibration.joint_range import joint_range, seed_poses
from torchcal.calibration.model import CalibrationModel
from torchcal.defaults import MAX_ANGLE_DEG, MAX_LENGTH_MM, SIGMA_DEG, SIGMA_MM
from torchcal.calibration.covariance import ParameterCovariance, parameter_covariance
from torchcal.rotations import procrustes_rotation, so3_error

RANK_TOL = 1e-6
RHO_EXACT = 1e-9  # mm: a residual RMS below it is a fit to rounding (the prior is left out)
RECHECK_TOL = 1e-2  # pivot a parameter held at a cold start needs at the first solution


@dataclass
class Identifiability:
    """Rank analysis of the scaled Jacobian.

    free: (P,) bool identifiable parameters; held: names held at nominal; rank: number
    identifiable; condition: condition number of the scaled identifiable columns;
    observability: dict O1..O5.
    """

    free: torch.Tensor
    held: list[str]
    rank: int
    condition: float
    observability: dict
    n_rows: int

    def to_dict(self) -> dict:
        return {"rank": self.rank, "condition_number": self.condition, "held_at_nominal": self.held,
                "observability": self.observability, "poses": self.n_rows}


def _pivoted(U: torch.Tensor, Q: torch.Tensor, rank_tol: float) -> list[int]:
    """Indices of the rows of U (p, R) (unit vectors: the columns of the scaled Jacobian)
    kept, in pivot order, by Gram-Schmidt with pivoting of U projected off the orthonormal
    rows of Q (k, R): at each step the row with the largest remaining norm (the lowest
    index among those equal to rounding, so that exactly dependent columns of a symmetric
    geometry are chosen the same way whatever the last digits of the data), while that
    norm exceeds rank_tol."""
    P = U - (U @ Q.T) @ Q if Q.shape[0] else U.clone()
    kept: list[int] = []
    taken = torch.zeros(P.shape[0], dtype=torch.bool, device=P.device)
    for _ in range(P.shape[0]):
        norms = torch.linalg.vector_norm(P, dim=1).masked_fill_(taken, -1.0)
        best = float(norms.max())
        if best <= rank_tol:
            break
        i = int(torch.nonzero(norms >= best * (1 - 1e-9))[0])
        q = P[i] / norms[i]
        P.addr_(P @ q, q, alpha=-1.0)
        P.addr_(P @ q, q, alpha=-1.0)  # twice is enough (Kahan): orthogonal to rounding
        kept.append(i)
        taken[i] = True
    return kept


def identifiability(J: torch.Tensor, names, candidate_free, rank_tol: float = RANK_TOL,
                    first=None, rest_tol: float | None = None) -> Identifiability:
    """J (N, 3, P) or (R, P) position Jacobian; candidate_free (P,) bool.

    first: (P,) bool, columns chosen before the others (the gauge: of a base frame and
    joint 1's dtheta / dd, or a tool offset and the last link's length, the ones in
    `first` are kept and the others held). The fit passes the parameters without a
    plausibility prior (frames), so the prior falls on a robot deviation only where
    the data determine it. rest_tol: the pivot threshold of the columns not in `first`
    (default rank_tol). Computed in float64 on J's device."""
    n_rows = J.shape[0]
    J = J.detach().reshape(-1, J.shape[-1]).to(torch.float64)
    dev = J.device
    cand = torch.nonzero(candidate_free.to(dev)).flatten()
    norms = torch.linalg.vector_norm(J[:, cand], dim=0)
    live = cand[norms > 1e-12 * max(float(norms.max()) if norms.numel() else 0.0, 1e-300)]
    # unit columns, rounded to 1e-10: columns equal in exact arithmetic (dd of parallel
    # axes, base_rz and dtheta1) become equal in floating point too, and a norm larger by
    # at most 1e-8 for earlier columns makes the pivoting keep the first of them (the
    # robot's before the base frame's), whatever the rounding of the Jacobian
    U = torch.round(J[:, live].T / torch.linalg.vector_norm(J[:, live], dim=0)[:, None], decimals=10)
    n_live = live.numel()
    U = U * (1 + 1e-8 * torch.arange(n_live, 0, -1, dtype=J.dtype, device=dev) / max(n_live, 1))[:, None]
    free = torch.zeros(J.shape[1], dtype=torch.bool)
    if n_live:  # U (n_live, R): the unit columns as rows, each one contiguous
        pri = torch.zeros(n_live, dtype=torch.bool, device=dev) if first is None else first.to(dev)[live]
        a = torch.nonzero(pri).flatten()[_pivoted(U[pri], U.new_zeros(0, U.shape[1]), rank_tol)]
        Qa = torch.linalg.qr(U[a].T).Q.T if a.numel() else U.new_zeros(0, U.shape[1])
        b = torch.nonzero(~pri).flatten()[_pivoted(U[~pri], Qa, rank_tol if rest_tol is None else rest_tol)]
        kept = torch.cat([a, b]).sort().values
        rank = kept.numel()
        free[live[kept].cpu()] = True
        s = torch.linalg.svdvals(U[kept]).cpu()
    else:
        rank, s = 0, torch.ones(1, dtype=torch.float64)
    held = [names[i] for i in cand.tolist() if not free[i]]
    m = max(n_rows, 1)
    obs = {
        "O1": float(s.log().mean().exp() / math.sqrt(m)),
        "O2": float(s[-1] / s[0]),
        "O3": float(s[-1]),
        "O4": float(s[-1] ** 2 / s[0]),
        "O5": float(1.0 / (1.0 / s).sum()),
    }
    return Identifiability(free, held, rank, float(s[0] / s[-1]), obs, n_rows)


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
    robust: str | None = None
    sigma_mm: float = SIGMA_MM
    sigma_deg: float = SIGMA_DEG
    residual_model: object = None
    training: dict | None = None
    provenance: dict | None = None
    set_by_prior: list = field(default_factory=list)
    residual_test: dict | None = None  # the residual stage's held-out test (torchcal.diagnosis.residual_stage)

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
        gross-mismatch check (`torchcal.calibration.mismatch`)."""
        return None if self.training is None else self.training.get("rms_mm")

    @property
    def tool_rotation(self) -> torch.Tensor | None:
        """(3, 3) measured tool frame <- nominal tool frame of a model fitted to
        orientations, else None."""
        return None if self.orientation is None else self.orientation["tool_rotation"]


def training_summary(residuals: torch.Tensor) -> dict:
    """{"n", "rms_mm", "max_mm"} of residuals (N, 3) mm."""
    d = residuals.detach().norm(dim=-1)
    return {"n": int(d.shape[0]), "rms_mm": float(d.pow(2).mean().sqrt()), "max_mm": float(d.max())}


ROBUST_K = 2.5  # IRLS threshold, in units of the median distance residual


def _inliers(dist: torch.Tensor) -> torch.Tensor:
    """(N,) bool: rows within ROBUST_K times the median distance residual dist (N,) mm,
    the rows a robust loss treats as ordinary (their RMS is the prior's rho)."""
    return dist <= ROBUST_K * dist.median().clamp_min(1e-9)


def _robust_weights(dist: torch.Tensor, kind: str) -> torch.Tensor:
    u = dist / dist.median().clamp_min(1e-9)  # typical distance residual = 1
    if kind == "huber":
        return torch.where(u <= ROBUST_K, torch.ones_like(u), ROBUST_K / u)
    if kind == "cauchy":
        return 1.0 / (1.0 + (u / ROBUST_K) ** 2)
    raise InputError(f"robust: unknown loss {kind!r}; expected 'huber' or 'cauchy'")


def _generic_rank(model: CalibrationModel, ctx: Context, cand, rank_tol: float) -> int:
    """Number of parameters identifiable at random poses inside the joint limits (the
    data's payload / temperature values reused in turn): what enough poses would give."""
    from torchcal.effects import make_context
    from torchcal.robots.poses import random_poses

    robot = model.robot
    n = int(cand.sum()) + 16
    q = random_poses(robot, n, torch.Generator().manual_seed(0)).to(ctx.q)
    idx = torch.arange(n, device=ctx.q.device) % ctx.q.shape[0]
    temp = None if ctx.temp_c is None else ctx.temp_c[idx]
    payload = None if ctx.payload_kg is None else ctx.payload_kg[idx]
    g = make_context(robot, q, payload, temp)
    J = model.jacobian(model.zeros(), g)
    return identifiability(J, model.param_names(), cand, rank_tol).rank


def _so3_error_jacobian(Rp: torch.Tensor, Rm: torch.Tensor, W: torch.Tensor) -> torch.Tensor:
    """d `so3_error`(Rp, Rm) / d theta (N, 3, P) for d Rp / d theta_k = [W_k]x Rp,
    W (N, 3, P) rad per unit (`CalibrationModel.rotation_jacobian`). With E = Rp^T Rm,
    dE_k = -[w_k]x E for w_k = Rp^T W_k, and the axial vector of the skew part of
    [w]x E is (tr(E) I - E) w / 2."""
    E = Rp.transpose(-1, -2) @ Rm
    tr = E.diagonal(dim1=-2, dim2=-1).sum(-1)
    M = torch.diag_embed(tr.unsqueeze(-1).expand(-1, 3)) - E
    return -0.5 * (M @ Rp.transpose(-1, -2)) @ W


def fit(model: CalibrationModel, ctx: Context, xyz: torch.Tensor, theta0=None, free=None,
        robust: str | None = None, max_iter: int = 60, rank_tol: float = RANK_TOL,
        pose=None, rotation: torch.Tensor | None = None, sigma_mm: float = SIGMA_MM,
        sigma_deg: float = SIGMA_DEG, register: bool = True,
        max_length_mm: float | None = MAX_LENGTH_MM,
        max_angle_deg: float | None = MAX_ANGLE_DEG, prior_sigma_mm: float | None = None) -> FitResult:
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
    `FitResult.implausible`.
    """
    from torchcal.calibration import registration as reg
    from torchcal.calibration.plausibility import beyond_plausible, plausible_scales, set_by_prior

    model.check_context(ctx)
    reg_info = None
    cold = theta0 is None  # a start at nominal / registration, possibly far from the fit
    if theta0 is None:
        theta0 = model.zeros()
        if register and any(e.name == "base_frame" for e in model.effects) and xyz.shape[0] >= 3:
            theta0, reg_info = reg.register_frame(model, ctx, xyz)
    cand = model.default_free() if free is None else free
    n_cand = int(cand.sum())
    n_rows = xyz.shape[0]
    k = 3 if rotation is None else 6
    w_rot = sigma_mm / math.radians(sigma_deg)  # mm per rad
    state = {"tool_R": None}

    def fit_tool_rotation(theta):
        with torch.no_grad():
            state["tool_R"] = procrustes_rotation(model.predict_rotation(theta, ctx), rotation)

    def resid(theta):  # (N, k): model - measured (position mm, orientation mm-equivalent)
        r = model.predict(theta, ctx) - xyz
        if rotation is None:
            return r
        e = so3_error(model.predict_rotation(theta, ctx) @ state["tool_R"], rotation)
        return torch.cat([r, -w_rot * e], dim=-1)

    def jac(theta):  # (N, k, P), analytic (CalibrationModel.jacobians)
        J, W = model.jacobians(theta, ctx, rotation=rotation is not None)
        if rotation is None:
            return J
        Rp = model.predict_rotation(theta, ctx) @ state["tool_R"]
        return torch.cat([J, -w_rot * _so3_error_jacobian(Rp, rotation, W)], dim=1)

    if rotation is not None:
        fit_tool_rotation(theta0)
    J0 = jac(theta0)
    scales = plausible_scales(model, max_length_mm, max_angle_deg).to(theta0)
    report = identifiability(J0, model.param_names(), cand, rank_tol, first=~torch.isfinite(scales))
    if k * n_rows <= report.rank:
        # the equations, not the model, bound the rank here: count the identifiable
        # parameters at generic poses (seeded, so the message is reproducible)
        kk = _generic_rank(model, ctx, cand, rank_tol)
        need = kk // 3 + 1
        raise InputError(f"too few poses: {n_rows} poses give {3 * n_rows} equations (3 per pose) "
                         f"but the model [{', '.join(model.specs()) or 'geometric only'}] has {kk} "
                         f"identifiable parameters (of {n_cand}); need at least {need} poses, "
                         f"in practice {max(2 * need, need + 10)} or more spread over the workspace")
    if n_cand and report.rank == 0:
        raise InputError("no parameter is identifiable from these poses")

    lower = model.lower_bounds().to(theta0)  # a physical sign (backlash >= 0): projected steps
    lower = None if bool(torch.isinf(lower).all()) else lower
    has_prior = bool(torch.isfinite(scales).any())
    inv_scale = torch.where(torch.isfinite(scales), 1.0 / scales, torch.zeros_like(scales))  # (P,)

    def solve(x, free_now, rho):
        """LM on the measurement rows plus the prior rows rho * theta / s (module doc)."""
        weights = torch.ones(n_rows, dtype=xyz.dtype, device=xyz.device)
        rounds = 1 if robust is None else 8
        prior = rho * inv_scale

        def res_fn(z):
            return torch.cat([resid(z[0]).reshape(-1), prior * z[0]]).unsqueeze(0)

        def jac_fn(z):
            return torch.cat([jac(z[0]).reshape(-1, z.shape[-1]), torch.diag(prior)]).unsqueeze(0)

        for _ in range(rounds):
            w = torch.cat([weights.repeat_interleave(k), torch.ones_like(prior)]).unsqueeze(0)
            res = levenberg_marquardt(res_fn, x, free=free_now, weights=w, jacobian_fn=jac_fn,
                                      max_iter=max_iter, lower=lower)
            x = res.x
            if robust is None:
                break
            dist = (model.predict(x[0], ctx) - xyz).norm(dim=-1)
            new = _robust_weights(dist, robust)
            if (new - weights).abs().max() < 1e-4:
                weights = new
                break
            weights = new
        return x, weights, int(res.n_iter[0]), res.status_labels()[0]

    free_now = report.free.clone()
    rho = sigma_mm if prior_sigma_mm is None else prior_sigma_mm
    x, weights, n_iter, status = solve(theta0.unsqueeze(0), free_now, rho if has_prior else 0.0)
    if rotation is not None:
        fit_tool_rotation(x[0])
    again = rotation is not None
    if cold:  # identifiability once more at the first solution (a far start, e.g. a tool
        # 60 mm off its nominal point, can make parameters look dependent that are not):
        # the free ones stay, a held one is freed where it is clearly identifiable there
        # (RECHECK_TOL; small deviations only break an exact symmetry of the nominal
        # geometry to their own order, which would free near-gauge parameters)
        report = identifiability(jac(x[0]), model.param_names(), cand, rank_tol, first=free_now,
                                 rest_tol=RECHECK_TOL)
        if not torch.equal(report.free, free_now):
            newly = free_now & ~report.free
            x = x.clone()
            x[0, newly] = theta0[newly]
            free_now, again = report.free.clone(), True
    def residual_rms():  # per-axis RMS mm; robust: of the inlier rows only (gross rows would inflate the prior)
        with torch.no_grad():
            r = model.predict(x[0], ctx) - xyz
            if robust is not None:
                r = r[_inliers(r.norm(dim=-1))]
            return max(float(r.pow(2).mean().sqrt()), 1e-12)

    if has_prior and prior_sigma_mm is None:  # the prior's rho from this fit's own residual
        rho = residual_rms()
        again = again or rho >= RHO_EXACT  # below it the data are fitted exactly: no prior needed
    if again:
        x, weights, n_iter, status = solve(x, free_now, rho if has_prior else 0.0)
    for _ in range(3):  # rho and the fit agree (a first solve far from the optimum gives a rho too large)
        if not has_prior or prior_sigma_mm is not None:
            break
        new = residual_rms()
        if abs(new - rho) <= 0.1 * rho or new < RHO_EXACT:
            break
        rho = new
        x, weights, n_iter, status = solve(x, free_now, rho)
    implausible = beyond_plausible(model, x[0], free_now, scales.cpu()) if has_prior else []
    theta = x[0]
    r = resid(theta).detach()
    resid_pos = -r[:, :3]
    rot_res = None if rotation is None else r[:, 3:] / w_rot  # (N, 3) rad, model vs measured
    prior_rows = rho * inv_scale if has_prior and math.isfinite(rho) else None  # posterior (covariance.py)
    if rotation is None:
        covariance = parameter_covariance(model.jacobian(theta, ctx), resid_pos, free_now, pose=pose,
                                          weights=weights if robust else None, prior=prior_rows)
    else:  # rows of 6 residuals: row-wise estimate s^2 (J^T W J)^-1
        J = jac(theta).reshape(-1, theta.shape[0])[:, free_now]
        wk = weights.repeat_interleave(k)
        dof = max(k * n_rows - int(free_now.sum()), 1)
        s2 = float((wk * r.reshape(-1) ** 2).sum()) / dof
        cov = torch.zeros(theta.shape[0], theta.shape[0], dtype=theta.dtype, device=theta.device)
        if int(free_now.sum()):
            idx = free_now.nonzero().flatten()
            Pp = 0.0 if prior_rows is None else torch.diag(prior_rows[free_now] ** 2)
            cov[idx[:, None], idx[None, :]] = s2 * torch.linalg.pinv((J.T * wk) @ J + Pp)
        covariance = ParameterCovariance(cov, dof, math.sqrt(s2), "rows")
    std = covariance.std
    prior_set = set_by_prior(model, std, free_now, scales.cpu()) if has_prior else []
    outliers = torch.nonzero(weights < 0.1).flatten().tolist() if robust else []
    orient = None
    if rotation is not None:
        orient = {"sigma_mm": sigma_mm, "sigma_deg": sigma_deg, "weight_mm_per_rad": w_rot,
                  "tool_rotation": state["tool_R"],
                  "rms_deg": math.degrees(float(rot_res.norm(dim=-1).pow(2).mean().sqrt()))}
    return FitResult(model, theta.detach(), std, resid_pos, weights, report, n_iter, outliers, covariance,
                     status=status,
                     registration=reg_info, implausible=implausible, orientation=orient,
                     plausible_limits=None if not has_prior else
                     {"max_length_mm": max_length_mm, "max_angle_deg": max_angle_deg, "prior_sigma_mm": rho},
                     q_range=joint_range(ctx.q), seed_poses=seed_poses(ctx.q), robust=robust, sigma_mm=sigma_mm,
                     sigma_deg=sigma_deg,
                     training=training_summary(resid_pos), set_by_prior=prior_set)
