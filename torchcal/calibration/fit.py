"""Identification: identifiability analysis and the fit of a `CalibrationModel`.

Identifiability (at the starting point, on the column-scaled Jacobian):

- QR with column pivoting orders the free parameters from most to least independent;
  those whose pivot |R_kk| falls below ``rank_tol * |R_00|`` cannot be identified from
  these poses. They are reported by name and *held at nominal* (zero deviation) instead
  of being silently damped as eq. 29 would.
- Singular values of the identifiable columns give the condition number and the
  observability indices of Borm & Menq / Nahvi & Hollerbach (O1..O5, m = number of poses).

The fit is Levenberg-Marquardt (`torchcal.calibration.lm`) on the identifiable parameters, with
optional robust row weights by IRLS (Huber or Cauchy on the per-pose distance residual,
scale = the median distance residual, thresholds at 2.5 times it). Standard errors from ``s^2 (J^T W J)^-1``, s^2 = weighted RSS / dof,
pose-level when poses repeat (`torchcal.calibration.covariance`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import math

import numpy as np
import scipy.linalg
import torch

from torchcal.effects.base import Context
from torchcal.errors import InputError
from torchcal.calibration.lm import levenberg_marquardt
from torchcal.calibration.joint_range import joint_range
from torchcal.calibration.model import CalibrationModel
from torchcal.calibration.plausibility import MAX_ANGLE_DEG, MAX_LENGTH_MM
from torchcal.calibration.covariance import ParameterCovariance, parameter_covariance
from torchcal.rotations import procrustes_rotation, so3_error

RANK_TOL = 1e-6
SIGMA_MM = 0.01   # default position uncertainty of one measurement (laser tracker), mm
SIGMA_DEG = 0.01  # default orientation uncertainty (36 arcsec, tracker 6-D probe), deg


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


def identifiability(J: torch.Tensor, names, candidate_free, rank_tol: float = RANK_TOL) -> Identifiability:
    """J (N, 3, P) or (R, P) position Jacobian; candidate_free (P,) bool."""
    n_rows = J.shape[0]
    J = J.reshape(-1, J.shape[-1]).detach().cpu().double().numpy()
    cand = np.flatnonzero(candidate_free.cpu().numpy())
    norms = np.linalg.norm(J[:, cand], axis=0)
    live = cand[norms > 1e-12 * max(norms.max(initial=0.0), 1e-300)]
    # unit columns, rounded to 1e-10: columns equal in exact arithmetic (dd of parallel
    # axes, base_rz and dtheta1) become equal in floating point too, and a norm larger by
    # at most 1e-8 for earlier columns makes the pivoting keep the first of them (the
    # robot's before the base frame's), whatever the rounding of the Jacobian
    Js = np.round(J[:, live] / np.linalg.norm(J[:, live], axis=0), 10)
    Js = Js * (1 + 1e-8 * np.arange(len(live), 0, -1) / max(len(live), 1))
    free = torch.zeros(J.shape[1], dtype=torch.bool)
    if live.size:
        _, R, piv = scipy.linalg.qr(Js, mode="economic", pivoting=True)
        d = np.abs(np.diag(R))
        rank = int((d > rank_tol * d[0]).sum())
        keep = live[piv[:rank]]
        free[torch.as_tensor(np.sort(keep))] = True
        s = np.linalg.svd(Js[:, np.sort(piv[:rank])], compute_uv=False)
    else:
        rank, s = 0, np.ones(1)
    held = [names[i] for i in cand if not free[i]]
    m = max(n_rows, 1)
    obs = {
        "O1": float(np.exp(np.log(s).mean()) / np.sqrt(m)),
        "O2": float(s[-1] / s[0]),
        "O3": float(s[-1]),
        "O4": float(s[-1] ** 2 / s[0]),
        "O5": float(1.0 / np.sum(1.0 / s)),
    }
    return Identifiability(free, held, rank, float(s[0] / s[-1]), obs, n_rows)


@dataclass
class FitResult:
    """A fitted model.

    theta: (P,) parameters; std: (P,) standard errors (0 where held); residuals: (N, 3)
    mm measured - model; weights: (N,) final robust weights (ones when not robust);
    report: identifiability; outliers: row indices with weight below 0.1 (robust fits);
    status: how the (last) LM solve stopped, 'converged', 'stalled' or 'max_iterations'
    (`torchcal.calibration.lm.LMStatus`).
    registration: the closed-form start (rms before/after, frame) or None; implausible:
    names of MD-H deviations held because they grew beyond `plausible_limits`;
    orientation: {"sigma_mm", "sigma_deg", "weight_mm_per_rad", "tool_rotation" (3, 3),
    "rms_deg"} when orientations were fitted. q_range: (2, n) min and max of the data's
    commanded q, rad / mm (`torchcal.calibration.joint_range`). robust, sigma_mm,
    sigma_deg: the settings of the fit that made it.
    """

    model: CalibrationModel
    theta: torch.Tensor
    std: torch.Tensor
    residuals: torch.Tensor
    weights: torch.Tensor
    report: Identifiability
    n_iter: int
    outliers: list = field(default_factory=list)
    covariance: ParameterCovariance | None = None  # (P, P) and how it was estimated
    status: str = "converged"

    @property
    def converged(self) -> bool:
        """True only when the solver met its convergence rule (never for a stalled solve)."""
        return self.status == "converged"

    def to_dict(self, source=None, seed: int = 0, pose_ids=None) -> dict:
        """The MODEL.json object of ``torchcal fit`` (`torchcal.io.modelfile.to_dict`):
        format, robot, effects, parameters (value, unit, std, ci95), covariance,
        identifiability, fit (n, rms_mm, max_mm, robust, outlier_poses, iterations,
        status), provenance."""
        from torchcal.io.modelfile import to_dict

        return to_dict(self, source=source, seed=seed, pose_ids=pose_ids)
    registration: dict | None = None
    implausible: list = field(default_factory=list)
    orientation: dict | None = None
    plausible_limits: dict | None = None
    q_range: torch.Tensor | None = None  # (2, n) [min; max] commanded q of the data, rad / mm
    robust: str | None = None
    sigma_mm: float = SIGMA_MM
    sigma_deg: float = SIGMA_DEG

    @property
    def rms_mm(self) -> float:
        """RMS of the distance residual per pose, mm."""
        return float(self.residuals.norm(dim=-1).pow(2).mean().sqrt())


def _robust_weights(dist: torch.Tensor, kind: str) -> torch.Tensor:
    u = dist / dist.median().clamp_min(1e-9)  # typical distance residual = 1
    if kind == "huber":
        return torch.where(u <= 2.5, torch.ones_like(u), 2.5 / u)
    if kind == "cauchy":
        return 1.0 / (1.0 + (u / 2.5) ** 2)
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
        max_angle_deg: float | None = MAX_ANGLE_DEG) -> FitResult:
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

    Plausibility: free MD-H deviations that end beyond `max_length_mm` (dd, da) or
    `max_angle_deg` (dtheta, dalpha, dbeta) are held at their start value and the fit
    is repeated (torchcal.calibration.plausibility); so are effect parameters beyond
    their effect's `plausible_max()` (e.g. gear harmonics above 1 deg). They are listed in
    `FitResult.implausible`. None disables the check.
    """
    from torchcal.calibration import registration as reg
    from torchcal.calibration.plausibility import implausible_deviations

    model.check_context(ctx)
    reg_info = None
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
    report = identifiability(J0, model.param_names(), cand, rank_tol)
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

    def solve(x, free_now):
        weights = torch.ones(n_rows, dtype=xyz.dtype, device=xyz.device)
        rounds = 1 if robust is None else 8
        for _ in range(rounds):
            w = weights.repeat_interleave(k).unsqueeze(0)
            res = levenberg_marquardt(lambda z: resid(z[0]).reshape(1, -1), x, free=free_now, weights=w,
                                      jacobian_fn=lambda z: jac(z[0]).reshape(1, -1, z.shape[-1]),
                                      max_iter=max_iter)
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
    x, weights, n_iter, status = solve(theta0.unsqueeze(0), free_now)
    if rotation is not None:
        fit_tool_rotation(x[0])
        x, weights, n_iter, status = solve(x, free_now)
    implausible: list[str] = []
    if max_length_mm is not None and max_angle_deg is not None:
        names = model.param_names()
        for _ in range(5):
            bad = implausible_deviations(model, x[0], free_now, max_length_mm, max_angle_deg)
            if not bad:
                break
            implausible += [names[i] for i in bad]
            x = x.clone()
            x[0, bad] = theta0[bad]
            # judge identifiability again without them: a parameter held as redundant
            # with one of them (e.g. tool_z with dd6) is free again
            cand = cand.clone()
            cand[[names.index(n) for n in implausible]] = False
            report = identifiability(jac(x[0]), names, cand, rank_tol)
            free_now = report.free.clone()
            x, weights, n_iter, status = solve(x, free_now)
        report.held = report.held + [n for n in implausible if n not in report.held]
    theta = x[0]
    r = resid(theta).detach()
    resid_pos = -r[:, :3]
    rot_res = None if rotation is None else r[:, 3:] / w_rot  # (N, 3) rad, model vs measured
    if rotation is None:
        covariance = parameter_covariance(model.jacobian(theta, ctx), resid_pos, free_now, pose=pose,
                                          weights=weights if robust else None)
    else:  # rows of 6 residuals: row-wise estimate s^2 (J^T W J)^-1
        J = jac(theta).reshape(-1, theta.shape[0])[:, free_now]
        wk = weights.repeat_interleave(k)
        dof = max(k * n_rows - int(free_now.sum()), 1)
        s2 = float((wk * r.reshape(-1) ** 2).sum()) / dof
        cov = torch.zeros(theta.shape[0], theta.shape[0], dtype=theta.dtype, device=theta.device)
        if int(free_now.sum()):
            idx = free_now.nonzero().flatten()
            cov[idx[:, None], idx[None, :]] = s2 * torch.linalg.pinv((J.T * wk) @ J)
        covariance = ParameterCovariance(cov, dof, math.sqrt(s2), "rows")
    std = covariance.std
    outliers = torch.nonzero(weights < 0.1).flatten().tolist() if robust else []
    orient = None
    if rotation is not None:
        orient = {"sigma_mm": sigma_mm, "sigma_deg": sigma_deg, "weight_mm_per_rad": w_rot,
                  "tool_rotation": state["tool_R"],
                  "rms_deg": math.degrees(float(rot_res.norm(dim=-1).pow(2).mean().sqrt()))}
    return FitResult(model, theta.detach(), std, resid_pos, weights, report, n_iter, outliers, covariance,
                     status=status,
                     registration=reg_info, implausible=implausible, orientation=orient,
                     plausible_limits=None if max_length_mm is None else
                     {"max_length_mm": max_length_mm, "max_angle_deg": max_angle_deg},
                     q_range=joint_range(ctx.q), robust=robust, sigma_mm=sigma_mm, sigma_deg=sigma_deg)
