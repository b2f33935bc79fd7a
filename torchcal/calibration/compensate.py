"""Compensation: corrected joint commands so that the calibrated model reaches each target.

For targets ``t (M, 3)`` mm and calibrated parameters per target (its zone's center
parameters, docs/paper.md section 6), find joint commands q with

    model.predict(theta_zone, q) = t

starting from a seed ``q0`` (the nominal inverse: the command that nominally reaches the
target; in a simulation it is known, otherwise `nominal_start` computes it in the
model's measuring frame, from the nearest of the model's calibration poses).

Frames: the model predicts in its measuring frame (the tracker's, when it has a
base_frame effect); targets in the robot base frame are mapped there first with the
fitted base frame (`measuring_from_base`). Joint 1's dtheta and dd trade against the base
frame's rotation about z and its z translation: the base frame is the fit's choice
among them (the identification holds the redundant ones). Position
needs 3 of the n joint values, so the step is the minimum-norm damped Newton step in
joint space (Levenberg-Marquardt on the joints)

    dq = J^T (J J^T + lambda I)^-1 (t - p(q)),    J = dp/dq (3, n) mm/rad,

which keeps the redundant joints (the orientation) at the seed's values to first order.
lambda is 1e-9 of trace(J J^T) / 3 (just enough to stay regular near a singularity); a
step that increases the residual is halved (up to 30 times), a step longer than
`max_step_rad` is shortened. A row whose residual fell by less than STALL_FRACTION of
itself over its last STALL_ITERS iterations stops there, not converged: a target beyond
the reach (or one the arm cannot get nearer from its configuration) creeps toward the
stretched arm by about 1e-6 of its residual per iteration, and would otherwise hold the
whole batch for every one of `max_iter` iterations; a target that converges falls far
faster (the rule never stops one: `tests/test_compensate_targets.py`). J is the analytic
joint Jacobian for geometric-only models
(`torchcal.kinematics.mdh.joint_jacobian` with the zone's deviations) and reverse-mode
autograd of `CalibrationModel.predict` otherwise. Every target is solved in one batch.

A fitted model (`compensate_fitted`: a `FitResult`; of a `ZonedFit` each target
with its zone's parameters) with a non-physical residual stage is inverted with it: the
physical model is solved for the target minus the stage's correction at the current
solution, repeated until the correction settles (`with_stage`). `compensate_targets`
is ``torchcal compensate``: the targets' frame, conditions and reach checked, the
commands in the user's units (`TargetCompensation`).

Units: targets mm, joint angles rad inside (the CLI reads and writes degrees).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import torch

from torchcal.kinematics import mdh as K
from torchcal.effects.context import Context, approach_directions
from torchcal.errors import InputError, number_argument
from torchcal.calibration.model import CalibrationModel

__all__ = ["Compensation", "compensate", "predict_rows", "nominal_inverse", "nominal_start", "measuring_from_base",
           "frame_model", "FRAMES", "with_stage", "compensate_fitted", "TargetCompensation", "compensate_targets"]

FRAMES = ("measuring", "base")  # the frames compensate reads targets in
TRIES = 8  # nearest calibration poses a nominal start tries per target
STALL_ITERS = 10  # a row stops when over its last STALL_ITERS iterations its residual fell
STALL_FRACTION = 1e-5  # ... by less than this fraction of itself (`compensate`)


@dataclass(frozen=True, eq=False)
class Compensation:
    """Corrected joint commands.

    Attributes:
        q: (M, n) rad corrected commands.
        q0: (M, n) rad seeds (nominal inverse).
        predicted_mm: (M, 3) calibrated-model positions at q.
        residual_mm: (M, 3) target - predicted (the predicted residual).
        iterations: (M,) Newton iterations.
        converged: (M,) bool, |residual| <= tol_mm.
        within_limits: (M,) bool, q inside the robot's joint limits.
        outside_range: number of converged targets whose q lie outside the joint range the model
            was calibrated on (`torchcal.calibration.joint_range`; set by
            `torchcal.compensate`), None when not checked or unknown.
        zone: (M,) int64 1-based zone whose parameters each target was solved with (set by
            `compensate_fitted`; 1 for a model without zones), None when not set.
    """

    q: torch.Tensor
    q0: torch.Tensor
    predicted_mm: torch.Tensor
    residual_mm: torch.Tensor
    iterations: torch.Tensor
    converged: torch.Tensor
    within_limits: torch.Tensor
    outside_range: int | None = None
    zone: torch.Tensor | None = None

    @property
    def correction_rad(self) -> torch.Tensor:
        """(M, n) q - q0."""
        return self.q - self.q0


def _per_row_theta(model: CalibrationModel, theta, zone, M: int) -> torch.Tensor:
    theta = torch.as_tensor(theta)
    if not theta.is_floating_point():
        theta = theta.to(model.robot.dtype)
    P = model.n_params
    if theta.ndim == 1:
        if theta.shape[0] != P:
            raise InputError(f"theta: expected ({P},) parameters for this model, got {tuple(theta.shape)}")
        return theta.expand(M, P)
    if theta.ndim != 2 or theta.shape[1] != P:
        raise InputError(f"theta: expected (P,) or (Z, P) with P = {P}, got {tuple(theta.shape)}")
    if zone is None:
        if theta.shape[0] != M:
            raise InputError(f"zone: needed to pick one of {theta.shape[0]} parameter sets per target")
        return theta
    zone = torch.as_tensor(zone, dtype=torch.long)
    if zone.shape != (M,):
        raise InputError(f"zone: expected ({M},) zone indices, got shape {tuple(zone.shape)}")
    if M and (zone.min() < 0 or zone.max() >= theta.shape[0]):
        raise InputError(f"zone: indices must lie in 0..{theta.shape[0] - 1}, got "
                         f"{int(zone.min())}..{int(zone.max())}")
    return theta[zone.to(theta.device)]


def _context(model: CalibrationModel, q, approach, payload, temp) -> Context:
    robot = model.robot
    frames = K.fk_frames(q, robot.chain.to(q))
    return Context(q, payload, temp, approach, frames, robot.gravity.to(q))


def predict_rows(model: CalibrationModel, thetas: torch.Tensor, q: torch.Tensor, approach=None,
                 payload_kg=None, temp_c=None) -> torch.Tensor:
    """Model positions (M, 3) mm with one parameter set per row: thetas (M, P), q (M, n) rad.

    Differentiable in q. Geometric-only models broadcast the deviations through the MD-H
    kernel; with effects, rows are grouped by identical parameter sets.
    """
    robot = model.robot
    M = q.shape[0]
    if not model.effects:
        geo = thetas[:, : 5 * robot.n].reshape(M, robot.n, 5)
        return K.positions(q, robot.chain.to(q), geo)
    approach = approach_directions(q.detach()) if approach is None else approach
    payload = torch.zeros(M, dtype=q.dtype, device=q.device) if payload_kg is None else payload_kg
    ctx = _context(model, q, approach, payload, temp_c)
    if M and bool((thetas == thetas[0]).all()):  # one set for every row (a global model): no grouping
        return model.predict(thetas[0], ctx)
    uniq, inv = torch.unique(thetas, dim=0, return_inverse=True)
    out = []
    rows_of = []
    for k in range(uniq.shape[0]):
        rows = (inv == k).nonzero().flatten()
        out.append(model.predict(uniq[k], ctx.subset(rows)))
        rows_of.append(rows)
    res = torch.cat(out)
    order = torch.cat(rows_of)
    return res[torch.argsort(order)]


def _joint_jacobian(model, thetas, q, approach, payload, temp):
    """(M, 3, n) dp/dq mm/rad and p (M, 3)."""
    robot = model.robot
    if not model.effects:
        M = q.shape[0]
        geo = thetas[:, : 5 * robot.n].reshape(M, robot.n, 5)
        J = K.joint_jacobian(q, robot.chain.to(q), geo)
        return J, predict_rows(model, thetas, q)
    qv = q.detach().clone().requires_grad_(True)
    with torch.enable_grad():
        p = predict_rows(model, thetas, qv, approach, payload, temp)  # (M, 3)
        rows = [torch.autograd.grad(p[:, k].sum(), qv, retain_graph=k < 2)[0] for k in range(3)]
    return torch.stack(rows, dim=1), p.detach()


def compensate(model: CalibrationModel, theta, targets, q0, zone=None, tol_mm: float = 1e-6,
               max_iter: int = 30, max_step_rad: float = 0.2, payload_kg=None, temp_c=None) -> Compensation:
    """Corrected joint commands for targets with the calibrated model.

    Args:
        model: the calibrated model's structure.
        theta: (P,) one parameter set for every target, or (Z, P) one per zone.
        targets: (M, 3) mm target positions.
        q0: (M, n) rad seeds, the nominal inverse of the targets.
        zone: (M,) int row of theta (0-based: zone id - 1) for each target when theta is (Z, P).
        tol_mm: stop when every |target - predicted| <= tol_mm.
        max_iter: Newton iterations at most. A row stops earlier, not converged, when its
            residual fell by less than STALL_FRACTION of itself over its last STALL_ITERS
            iterations (a target beyond the reach: it would creep on for all of them).
        max_step_rad: longest joint step per iteration (norm over joints).
        payload_kg, temp_c: (M,) conditions of the moves (for load/thermal effects).
    Returns:
        `Compensation` (q corrected, predicted residual, convergence; ``iterations``
        counts each row's iterations up to its stop).
    """
    robot = model.robot
    q0 = robot.check_q(q0, "q0").to(robot.dtype)
    if q0.ndim != 2:
        raise InputError(f"q0: expected (M, {robot.n}) seeds, got shape {tuple(q0.shape)}")
    t = torch.as_tensor(targets, dtype=q0.dtype, device=q0.device)
    if t.shape != (q0.shape[0], 3):
        raise InputError(f"targets: expected ({q0.shape[0]}, 3) mm to match q0, got {tuple(t.shape)}")
    if not torch.isfinite(t).all():
        raise InputError("targets: positions must be finite")
    M = q0.shape[0]
    thetas = _per_row_theta(model, theta, zone, M).to(q0)
    approach = approach_directions(q0)
    q = q0.clone()
    J, p = _joint_jacobian(model, thetas, q, approach, payload_kg, temp_c)
    r = t - p
    err = r.norm(dim=-1)
    iters = torch.zeros(M, dtype=torch.long, device=q.device)
    eye = torch.eye(3, dtype=q.dtype, device=q.device)
    history = [err]  # each iteration's residuals, for the stall rule
    stalled = torch.zeros(M, dtype=torch.bool, device=q.device)
    for _ in range(max_iter):
        active = (err > tol_mm) & ~stalled
        if not active.any():
            break
        JJt = J @ J.transpose(1, 2)  # (M, 3, 3)
        lam = 1e-9 * torch.diagonal(JJt, dim1=1, dim2=2).sum(-1) / 3
        step = (J.transpose(1, 2) @ torch.linalg.solve(JJt + lam[:, None, None] * eye, r.unsqueeze(-1))).squeeze(-1)
        norm = step.norm(dim=-1, keepdim=True)
        step = step * (max_step_rad / norm.clamp_min(max_step_rad))
        step = step * active[:, None]
        scale = torch.ones(M, 1, dtype=q.dtype, device=q.device)
        for _ in range(30):  # backtracking per row
            q_new = q + scale * step
            p_new = predict_rows(model, thetas, q_new, approach, payload_kg, temp_c)
            err_new = (t - p_new).norm(dim=-1)
            worse = (err_new > err) & active
            if not worse.any():
                break
            scale = torch.where(worse[:, None], scale * 0.5, scale)
        ok = (err_new <= err) & active
        q = torch.where(ok[:, None], q_new, q)
        iters = iters + active.long()
        if not ok.any():
            break
        J, p = _joint_jacobian(model, thetas, q, approach, payload_kg, temp_c)
        r = t - p
        err = r.norm(dim=-1)
        history.append(err)
        if len(history) > STALL_ITERS:
            stalled |= active & (history[-1 - STALL_ITERS] - err < STALL_FRACTION * history[-1 - STALL_ITERS])
    return Compensation(q, q0, p, r, iters, err <= tol_mm, robot.within_limits(q))


def nominal_inverse(robot, targets, q0=None, tol_mm: float = 1e-6, max_iter: int = 100) -> Compensation:
    """Nominal inverse kinematics (position only) from starting commands: the commands that the
    *nominal* robot needs to reach the targets (M, 3) mm in its base frame. q0 (M, n) or (n,)
    rad starting commands (default: the middle of the joint limits). Returns a
    `Compensation` whose q is the nominal inverse."""
    t = torch.as_tensor(targets, dtype=robot.dtype, device=robot.device)
    if t.ndim != 2 or t.shape[1] != 3:
        raise InputError(f"targets: expected (M, 3) mm, got shape {tuple(t.shape)}")
    if q0 is None:
        q0 = robot.limits.mean(-1)
    seed = robot.check_q(q0, "q0").to(robot.dtype)
    seed = seed.expand(t.shape[0], robot.n).clone() if seed.ndim == 1 else seed
    return compensate(CalibrationModel(robot), torch.zeros(5 * robot.n, dtype=robot.dtype, device=robot.device), t, seed,
                      tol_mm=tol_mm, max_iter=max_iter)


def measuring_from_base(model: CalibrationModel, theta: torch.Tensor):
    """(R (3, 3), t (3,)): the model's measuring frame <- robot base frame, its base_frame
    effect at theta (P,) (a point v in the base frame is ``R v + t`` mm in the measuring
    frame); the identity without a base_frame effect."""
    R = torch.eye(3, dtype=theta.dtype, device=theta.device)
    t = theta.new_zeros(3)
    for e, sl in zip(model.effects, model.slices[1:]):
        if e.name == "base_frame":
            R, t = e.world_rotation(theta[sl], None), theta[sl][:3]
    return R, t


def frame_model(model: CalibrationModel, theta: torch.Tensor):
    """(CalibrationModel, theta' (P',)): the nominal geometry in the model's measuring frame,
    its base_frame and (a single) tool_offset at their values in theta (P,), MD-H
    deviations zero. With one tool offset per measured point, the nominal tool."""
    names, parts = [], []
    for e, sl in zip(model.effects, model.slices[1:]):
        if e.name == "base_frame" or (e.name == "tool_offset" and not model.points):
            names.append(e.name)
            parts.append(theta[sl])
    return CalibrationModel(model.robot, names), torch.cat([theta.new_zeros(5 * model.robot.n), *parts])


def nominal_start(model: CalibrationModel, theta: torch.Tensor, targets, poses=None, q_range=None, seed: int = 0,
                  tol_mm: float = 1e-6, once=()) -> Compensation:
    """Starting commands for compensating targets (M, 3) mm given in the model's measuring
    frame, the one default of `torchcal.compensate` and ``torchcal compensate``: the
    nominal inverse (nominal MD-H geometry with the model's base frame and tool offset at
    theta (P,), `frame_model`), each target started from the pose of `poses` (K, n) rad /
    mm whose position in that frame is nearest (the model's calibration poses,
    ``seed_poses``: the arm configuration it was calibrated in). A target is tried from
    its TRIES nearest poses in turn until a solution lies inside the joint limits and the
    calibrated joint range q_range (2, n) (`torchcal.calibration.joint_range`; where the
    model does not extrapolate); failing that, the first inside the limits. Without poses:
    256 seeded random poses inside the joint limits (`torchcal.robots.poses.random_poses`,
    seed). once: 0-based rows tried from their nearest pose only (targets beyond the
    robot's reach, `torchcal.calibration.checks.targets.check_targets`: no start reaches them).

    Returns the `Compensation` of the nominal inverse: q (M, n) rad / mm; ``converged``
    (M,) says which targets it reached (the others keep the nearest q it found, and the
    calibrated solve still tries them)."""
    from torchcal.calibration.joint_range import outside_range
    from torchcal.robots.poses import random_poses

    robot = model.robot
    t = torch.as_tensor(targets, dtype=robot.dtype, device=robot.device)
    if t.ndim != 2 or t.shape[1] != 3:
        raise InputError(f"targets: expected (M, 3) mm, got shape {tuple(t.shape)}")
    cm, th = frame_model(model, theta.to(t))
    cand = random_poses(robot, 256, seed) if poses is None else robot.check_q(poses, "poses")
    cand = cand.to(t)
    with torch.no_grad():
        pos = predict_rows(cm, th.expand(cand.shape[0], -1), cand)  # (K, 3)
    order = torch.cdist(t, pos).argsort(dim=1)[:, :TRIES]  # (M, <= TRIES) nearest first

    def level(c):  # 2: inside the limits and the calibrated range, 1: inside the limits, 0: neither
        ok = c.converged & c.within_limits
        inside = ok if q_range is None else ok & ~outside_range(c.q, q_range.to(c.q), robot.prismatic).any(-1)
        return ok.long() + inside.long()

    best = compensate(cm, th, t, cand[order[:, 0]], tol_mm=tol_mm, max_iter=100)
    score = level(best)
    score[torch.as_tensor(list(once), dtype=torch.long, device=score.device)] = 2  # not tried again
    for k in range(1, order.shape[1]):
        left = (score < 2).nonzero().flatten()
        if not left.numel():
            break
        alt = compensate(cm, th, t[left], cand[order[left, k]], tol_mm=tol_mm, max_iter=100)
        better = level(alt) > score[left]
        take = left[better]
        if take.numel():
            best = Compensation(*(torch.index_put(getattr(best, f), (take,), getattr(alt, f)[better])
                                  for f in ("q", "q0", "predicted_mm", "residual_mm", "iterations", "converged",
                                            "within_limits")))
            score[take] = level(alt)[better]
    return best


def with_stage(stage, model: CalibrationModel, theta, t, comp: Compensation, zone, options: dict,
               max_rounds: int = 10) -> Compensation:
    """Compensation through the physical model plus a residual stage (`stage.predict(q)`
    (M, 3) mm): solve the physical model for the target minus the stage's correction at the
    current solution `comp`, until the correction changes by at most options' tol_mm (it
    varies slowly with q: a few rounds). options: the keywords of `compensate`."""
    tol = float(options.get("tol_mm", 1e-6))
    corr = stage.predict(comp.q).to(t)
    for _ in range(max_rounds):
        comp = compensate(model, theta, t - corr, comp.q, zone=zone, **options)
        new = stage.predict(comp.q).to(t)
        moved = float((new - corr).norm(dim=-1).max()) if len(t) else 0.0
        corr = new
        if moved <= tol:
            break
    pred = comp.predicted_mm + corr
    res = t - pred
    return replace(comp, predicted_mm=pred, residual_mm=res, converged=comp.converged & (res.norm(dim=-1) <= tol))


def compensate_fitted(fitted, targets, q0=None, *, tol_mm: float = 1e-6, max_iter: int = 30,
                      max_step_rad: float = 0.2, payload_kg=None, temp_c=None, check: bool = True,
                      stacklevel: int = 1, where: str = "targets") -> Compensation:
    """Corrected joint commands (M, n) rad for targets (M, 3) mm in the measuring frame of a
    fitted model: a `FitResult`, or a `ZonedFit`, whose zones are those of the commands: each
    target is solved with the parameters of the zone of its seed's nominal TCP position
    (robot base frame, as `calibrate` assigns calibration poses; the targets' own
    coordinates are in the measuring frame, which a base_frame effect can put metres
    away), and a target whose solution's nominal TCP position lies in another zone is
    solved once more, from there, with that zone's parameters (`Compensation.zone`: the
    zone of the final solve; a target on a boundary keeps that of its second solve), so
    that `ZonedFit.predict` at the commands meets the targets. Commands whose nominal TCP
    lies far from every sweep point of the partition are named (their zone is
    extrapolated: `torchcal.calibration.checks.partition.warn_far_from_sweep`).

    q0: (M, n) rad starting commands, default `nominal_start` (a target beyond the reach
    from its nearest calibration pose only, as ``torchcal compensate``). check: refuse
    targets inside the robot's base (metres read as mm), warn about those beyond its reach
    (`torchcal.calibration.checks.targets.check_targets`); refuse seeds q0 of another shape or
    beyond what a joint can turn (degrees), warn about seeds whose model point lies more
    than 100 mm from their target (`check_seeds`). A residual stage is inverted with the
    model (`with_stage`). Converged commands outside the calibrated range are counted
    (``outside_range``) and named in one `CalibratedRangeWarning` (at `stacklevel`, counted
    from the caller); targets at a temperature / payload outside the range the model was
    fitted on (``fitted.conditions``) in one `ConditionRangeWarning`; no payload_kg for a
    model fitted on loads in one `PayloadAssumedWarning`
    (`torchcal.calibration.checks.ranges.payload_conditions`; `where` names the targets)."""
    from torchcal.calibration.checks.partition import warn_far_from_sweep
    from torchcal.calibration.checks.ranges import payload_conditions, warn_outside_conditions, warn_outside_range
    from torchcal.calibration.checks.targets import check_seeds, check_targets

    cm, theta, q_range, stage = fitted.model, fitted.theta, fitted.q_range, fitted.residual_model
    robot = cm.robot
    t = torch.as_tensor(targets, dtype=robot.dtype, device=robot.device)
    if t.ndim != 2 or t.shape[-1] != 3 or t.shape[0] == 0:
        raise InputError(f"targets: expected (M, 3) mm, M >= 1, got shape {tuple(t.shape)}")
    number_argument("tol_mm", tol_mm, above=0)
    number_argument("max_iter", max_iter, integer=True, at_least=1)
    number_argument("max_step_rad", max_step_rad, above=0)
    far = check_targets(cm, theta, t) if check else []
    if q0 is None:
        q0 = nominal_start(cm, theta, t, poses=fitted.seed_poses, q_range=q_range, once=far).q
    elif check:  # the caller's seeds: shape, finite, radians (not degrees), near their targets
        q0 = robot.check_q(q0, "q0").to(t)
        if q0.shape != (t.shape[0], robot.n):
            raise InputError(f"q0: expected ({t.shape[0]}, {robot.n}) rad, one seed per target, "
                             f"got shape {tuple(q0.shape)}")
        at = predict_rows(cm, theta.to(t).expand(len(t), -1), q0,
                          payload_kg=None if payload_kg is None else torch.as_tensor(payload_kg).to(t),
                          temp_c=None if temp_c is None else torch.as_tensor(temp_c).to(t))
        check_seeds(at, t, q0, robot, "q0", skip=far, angle_unit="rad")
    theta = fitted.zone_theta.to(t)
    cond = {k: None if v is None else torch.as_tensor(v).to(t) for k, v in (("payload_kg", payload_kg),
                                                                            ("temp_c", temp_c))}

    def solve(rows, start, zone):  # the targets `rows` from `start`, each with its zone's parameters
        opts = dict(tol_mm=tol_mm, max_iter=max_iter, max_step_rad=max_step_rad,
                    **{k: None if v is None else v[rows] for k, v in cond.items()})
        c = compensate(cm, theta, t[rows], start, zone=zone, **opts)
        return c if stage is None else with_stage(stage, cm, theta, t[rows], c, zone, opts)

    every = torch.arange(t.shape[0], device=t.device)
    zoned = theta.shape[0] > 1
    zone = _command_zone(fitted, q0) if zoned else torch.zeros(t.shape[0], dtype=torch.long, device=t.device)
    comp = solve(every, q0, zone)
    if zoned:  # a solution in another zone than its seed's: solved again with that zone's set
        landed = _command_zone(fitted, comp.q)
        moved = (landed != zone).nonzero().flatten()
        if len(moved):
            zone[moved] = landed[moved]
            again = solve(moved, comp.q[moved], zone[moved])
            comp = replace(comp, **{f: _put(getattr(comp, f), moved, getattr(again, f))
                                    for f in ("q", "predicted_mm", "residual_mm", "converged", "within_limits")},
                           iterations=_put(comp.iterations, moved, comp.iterations[moved] + again.iterations))
    comp = replace(comp, zone=zone + 1)
    ranges = payload_conditions(fitted, payload_kg, where, stacklevel=stacklevel + 1)  # none given: named once
    warn_outside_conditions(ranges, cond, "targets", stacklevel=stacklevel + 1)
    if getattr(fitted, "partition", None) is not None:
        with torch.no_grad():
            warn_far_from_sweep(fitted.partition, robot.fk(comp.q), stacklevel=stacklevel + 1)
    if q_range is None:
        return comp
    outside = warn_outside_range(comp.q[comp.converged], q_range, robot, "converged targets", stage,
                                 stacklevel=stacklevel + 1)
    return replace(comp, outside_range=outside)


def _command_zone(fitted, q: torch.Tensor) -> torch.Tensor:
    """(M,) int64 0-based row of `fitted.zone_theta` for commands q (M, n) rad / mm: the zone
    of their nominal TCP position, as `calibrate` assigns calibration poses and
    `ZonedFit.predict` rows (robot base frame)."""
    with torch.no_grad():
        return (fitted.assign(fitted.model.robot.fk(q)) - 1).to(q.device)


def _put(whole: torch.Tensor, rows: torch.Tensor, part: torch.Tensor) -> torch.Tensor:
    """A copy of `whole` with `part` in `rows` (its first dimension)."""
    out = whole.clone()
    out[rows] = part
    return out


@dataclass
class TargetCompensation:
    """What ``torchcal compensate`` computes and writes: the corrected commands of a
    targets file, each with the zone it was compensated in (Q.csv:
    `torchcal.io.targets_csv.compensation_csv`).

    Attributes:
        targets: (M, 3) mm target positions in `frame`.
        compensation: the `Compensation` (q rad / mm, residuals, convergence, limits).
        zone: (M,) 1-based zone of each target (1 for a single-set model).
        q_user: (M, n) corrected commands in deg (mm for a prismatic joint).
        n_zones, method: the model's parameter sets and how it was calibrated ("fit" for
            a fitted model).
        robot: the robot's name.
        beyond_reach: 0-based rows of targets beyond the robot's reach (named, not refused).
        frame: the frame the targets were given in, "measuring" or "base".
        seeded: the commands started from the caller's seeds (else from the nearest
            calibration pose, whose configuration and tool orientation they keep).
        base_frame_fitted: the model has a base_frame effect (base-frame targets are mapped
            with it, and it holds joint 1's zero offset and d1).
        tool_offset_mm: [x, y, z] mm, the model's fitted tool offset from the robot file's
            tool (one measured point), None without one: the point that reaches the targets
            is the measured point (the reflector of the calibration), not the robot file's TCP.
    """

    targets: torch.Tensor
    compensation: Compensation
    zone: torch.Tensor
    q_user: torch.Tensor
    n_zones: int
    method: str
    robot: str
    beyond_reach: list = field(default_factory=list)
    frame: str = "measuring"
    seeded: bool = False
    base_frame_fitted: bool = False
    tool_offset_mm: list | None = None

    @property
    def residual_mm(self) -> torch.Tensor:
        """(M,) mm distance from the calibrated model's position to each target."""
        return self.compensation.residual_mm.norm(dim=-1)

    @property
    def not_converged(self) -> list:
        """0-based rows that did not meet the tolerance."""
        return (~self.compensation.converged).nonzero().flatten().tolist()

    @property
    def outside_limits(self) -> list:
        """0-based rows whose command lies outside the joint limits."""
        return (~self.compensation.within_limits).nonzero().flatten().tolist()

    @property
    def failed(self) -> list:
        """0-based rows that did not converge or lie outside the joint limits."""
        return sorted(set(self.not_converged) | set(self.outside_limits))

    def to_dict(self) -> dict:
        """Q.csv's rows and the failures (1-based rows), JSON types."""
        c, res = self.compensation, self.residual_mm.tolist()
        rows = [{"point": i + 1, "zone": int(self.zone[i]), "q": self.q_user[i].tolist(), "residual_mm": res[i],
                 "converged": bool(c.converged[i]), "within_limits": bool(c.within_limits[i])}
                for i in range(self.targets.shape[0])]
        return {"robot": self.robot, "frame": self.frame, "n_zones": self.n_zones, "method": self.method,
                "targets": rows,
                "max_residual_mm": max(res), "outside_range": c.outside_range,
                "not_converged": [i + 1 for i in self.not_converged],
                "outside_limits": [i + 1 for i in self.outside_limits],
                "beyond_reach": [i + 1 for i in self.beyond_reach]}


def compensate_targets(im, targets, *, frame: str = "measuring", seeds=None, payload_kg=None, temp_c=None,
                       where: str = "targets", stacklevel: int = 1, length_unit: str = "mm") -> TargetCompensation:
    """``torchcal compensate`` on a fitted model `im` (a `ZonedFit`: each target in its zone):
    targets (M, 3) mm in `frame` ("measuring": the model's measuring frame; "base": the
    robot base frame, mapped to the measuring frame with the fitted base frame of the first
    parameter set, `measuring_from_base`). seeds: (M, n) starting commands in deg (mm for a
    slide), default `nominal_start`; payload_kg, temp_c: (M,) conditions. A model effect
    that needs a condition the targets lack is refused naming it; targets inside the
    robot's base (metres read as mm) are refused, those beyond its reach listed in
    ``beyond_reach``; `where` names the targets in messages; length_unit: the unit they
    were given in before conversion to mm (mm given as metres are refused)."""
    import warnings

    from torchcal.calibration.checks.targets import check_seeds, check_target_conditions, check_targets
    from torchcal.calibration.checks.verdict import MismatchWarning

    if frame not in FRAMES:
        raise InputError(f"frame: expected one of {', '.join(FRAMES)}, got {frame!r}")
    rob = im.model.robot
    t = torch.as_tensor(targets, dtype=torch.float64)
    if t.ndim != 2 or t.shape[-1] != 3 or t.shape[0] == 0:
        raise InputError(f"targets: expected (M, 3) mm, M >= 1, got shape {tuple(t.shape)}")
    if not bool(torch.isfinite(t).all()):
        raise InputError("targets: positions must be finite")
    check_target_conditions(im.model, t, payload_kg, temp_c, where)
    given, o = t, None
    R, o_base = measuring_from_base(im.model, im.theta.to(t))
    if frame == "base":  # the solve is in the measuring frame, where the model predicts
        t, o = t @ R.T + o_base, o_base
    other = None  # the targets read in the other frame: a frame mix-up is named
    if any(e.name == "base_frame" for e in im.model.effects):
        other = (given @ R.T + o_base, "robot base frame", ("frame", "base")) if frame == "measuring" else \
            (given, "measuring frame", ("frame", "measuring"))
    with warnings.catch_warnings():  # metres or inches read as mm, the other frame: refused; beyond the reach: listed
        warnings.simplefilter("ignore", MismatchWarning)
        far = check_targets(im.model, im.theta, t, where=where, about=o, other_frame=other, length_unit=length_unit)
    if seeds is None:
        q0 = nominal_start(im.model, im.theta, t, poses=im.seed_poses, q_range=im.q_range, once=far).q
    else:  # seeds are the targets' nominal commands: radians in degrees refused, far ones named
        q0 = rob.q_from_user(torch.as_tensor(seeds))
        at = predict_rows(im.model, im.theta.to(t).expand(len(t), -1), q0.to(t),
                          payload_kg=None if payload_kg is None else torch.as_tensor(payload_kg).to(t),
                          temp_c=None if temp_c is None else torch.as_tensor(temp_c).to(t))
        check_seeds(at, t, q0, rob, where, skip=far)
    comp = compensate_fitted(im, t, q0, check=False, payload_kg=payload_kg, temp_c=temp_c, stacklevel=stacklevel + 1,
                             where=where)
    from torchcal.calibration.zone_calibration import ZonedFit

    method = im.method if isinstance(im, ZonedFit) else ("global" if im.radius is not None else "fit")
    tool = [im.theta[sl].tolist() for e, sl in zip(im.model.effects, im.model.slices[1:]) if e.name == "tool_offset"]
    return TargetCompensation(given, comp, comp.zone, rob.q_to_user(comp.q), im.zone_theta.shape[0], method,
                              rob.name, far, frame, seeds is not None,
                              any(e.name == "base_frame" for e in im.model.effects),
                              tool[0] if len(tool) == 1 and len(tool[0]) == 3 else None)
