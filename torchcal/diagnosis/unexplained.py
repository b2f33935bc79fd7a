"""What the model leaves unexplained: its size, the noise floor, and what it depends on.

`unexplained(robot, m, residuals)` looks at the residuals (N, 3) mm of any fitted model
(any robot, any effects, built-in or user-written) and answers three questions:

- rms_mm: the distance RMS of the residuals.
- noise_floor_mm: the distance RMS that measurement noise alone would leave.
  * With repeats (some pose ids on two or more rows): the pooled scatter of the residual
    within a pose, ``sqrt(sum_p sum_i |r_pi - mean_p r|^2 / sum_p (m_p - 1))``. It is the
    repeatability of the session: an error shared by a pose's repeats (target nest,
    fixture) is *not* in it, and shows as rms_mm above the floor with no correlate.
  * Without repeats: an estimate from neighbours (floor_from 'neighbours',
    `noise_floor_from_neighbours`: the Gamma test on the joint angles, the differences of
    the residual between poses close in joint space regressed to zero distance), unless
    one of two upper bounds is below it. The upper bounds are held-out errors, which keep
    whatever structure their model does not learn: the probe's ``probe_left_rms_mm``
    (floor_from 'probe') and ``rms_mm * sqrt(1 - strength)`` of the strongest variable
    below (floor_from 'variables'). Figures on simulated sessions:
    benchmarks/study_outside.py, docs/diagnosis.md.
- correlates_with: the variables the residual depends on. The variables are each joint
  angle ``q1..qn``, ``temp_c`` and ``payload_kg`` (when they vary), the measurement
  ``order`` (row index), the approach direction of each joint ``approach_q1..`` (sign
  of q - q_prev) and that of the move before it ``approach_prev_q1..`` (sign of q_prev
  minus the angle the joint came from to reach q_prev, in measurement order; 0 where
  there is none), where a two-move hysteresis shows. For one variable v the residual is fitted by a smooth function of v in
  joint space and in the base frame: columns ``phi_b(v) * [dP/dq (3, n), I3]`` (3 rows
  per measurement), phi_b the piecewise-linear hat functions on 6 quantile knots of v (one
  indicator per value when v takes at most 3 values), i.e. a joint-angle error and a TCP
  offset that both vary smoothly with v (a coupling q_j += k q_i, a gear error, a drift, a
  bent link all have this form).

  The fit is ridge regression, held out by pose: poses are split into 5 folds; the
  prediction for a fold comes from the other four, with the ridge weight chosen on those
  four alone by an inner cross-validation over the same folds (nested, so the choice never
  sees the rows it predicts). With few poses the smooth model has about as many columns as
  rows; plain least squares then over-fits and predicts worse than zero even where the
  dependence is strong, ridge shrinks towards zero instead.
  strength = held-out R^2, ``1 - sum |r - r_hat|^2 / sum |r|^2``.

  Significance by pose: per pose p, ``c_p = sum_i <r_pi, r_hat_pi>``, the held-out
  covariance of residual and prediction, and a one-sided t-test of mean(c_p) > 0 over the
  poses. r_hat of a pose is computed without that pose's rows, so with no dependence
  c_p has mean zero; repeats of a pose are one piece of evidence. (Testing the held-out
  gain ``|r|^2 - |r - r_hat|^2`` instead also charges the prediction's own variance and
  was 10 to 100 times less powerful in a simulated study: docs/diagnosis.md.)
  Forward selection lists the variables: at step s = 1, 2, ... the variables not yet
  listed are tested on what the listed ones leave (the residual minus their held-out
  predictions); among those whose own strength (first-step R^2) is >= MIN_STRENGTH (2 %)
  and whose p-value at this step is below alpha / 2^s / (number of variables), the one
  that explains most of what is left is listed next. So a variable that only mirrors a
  listed one (in random poses the approach direction of a joint goes with its angle) is
  not listed, and a variable that explains nothing on its own is never listed.
  The strength reported is the variable's own (first-step) R^2.
- probe_left_rms_mm: what a flexible smooth model of the residual on the recorded
  variables leaves on held-out poses (`torchcal.diagnosis.probe`: kernel ridge on the
  joint angles, temp_c, payload_kg and the approach directions, hyper-parameters and
  inputs by nested pose-grouped CV); learnable_rms_mm ``sqrt(rms^2 - probe_left_rms^2)``
  is the part of the error that is learnable from the recorded variables; carried_by
  names the variables the probe needs for it (share of it lost without each).
- significant: structured error remains: the probe beats the model on held-out poses
  beyond chance (one-sided paired t-test over poses at PROBE_ALPHA), or a variable is
  listed in correlates_with. Calibrated on simulated null sessions
  (benchmarks/study_unexplained.py, docs/diagnosis.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from torchcal.diagnosis.probe import Probe, probe
from torchcal.folds import fold_of_pose
from torchcal.kernel_ridge import variable_features
from torchcal.measurements import Measurements, previous_rows
from torchcal.robots.robot import Robot
from torchcal.statistics import t_sf

ALPHA = 1e-3
MIN_STRENGTH = 0.02
KNOTS = 6
FOLDS = 5
#: level of the probe's one-sided test over poses (held-out gain > 0).
PROBE_ALPHA = 0.01
#: where the noise floor comes from, in words.
FLOOR_WORDS = {"repeats": "estimate from repeats",
               "neighbours": "no repeats: estimate from neighbours, the differences of the residual between "
                             "poses close in joint space regressed to zero distance",
               "probe": "no repeats: upper bound, the probe's held-out error",
               "variables": "no repeats: upper bound, the strongest variable's held-out error"}
#: nearest neighbours of each pose in the Gamma test (`noise_floor_from_neighbours`).
NEIGHBOURS = 10


@dataclass
class Unexplained:
    """What remains. rms_mm, noise_floor_mm: distance RMS in mm; floor_from: 'repeats',
    'probe' or 'variables' (module doc); correlates_with: [(variable, strength)] strongest first (significant only);
    strengths: every variable tested -> (strength, p-value); learnable_rms_mm: the distance
    RMS of the part the kernel probe learns on held-out poses (mm), probe_left_rms_mm: what
    it leaves (mm), carried_by: [(variable, relevance)] of the
    probe, probe: the full `torchcal.diagnosis.probe.Probe`."""

    significant: bool
    rms_mm: float
    noise_floor_mm: float
    correlates_with: list
    floor_from: str = "repeats"
    strengths: dict = field(default_factory=dict, repr=False)
    residuals: np.ndarray | None = field(default=None, repr=False)  # (N, 3) mm, what was looked at
    learnable_rms_mm: float | None = None
    carried_by: list = field(default_factory=list)
    probe: Probe | None = field(default=None, repr=False)
    probe_left_rms_mm: float | None = None

    def to_dict(self) -> dict:
        out = {"significant": self.significant, "rms_mm": self.rms_mm, "noise_floor_mm": self.noise_floor_mm,
               "noise_floor_from": self.floor_from,
               "correlates_with": [{"variable": v, "strength": s} for v, s in self.correlates_with]}
        if self.probe is not None:
            pr = self.probe
            out["learnable_rms_mm"] = self.learnable_rms_mm
            out["probe_left_rms_mm"] = self.probe_left_rms_mm
            out["carried_by"] = [{"variable": v, "relevance": float(s)} for v, s in self.carried_by]
            chosen = bool(pr.inputs)  # no input chosen: no kernel, so no length scale or ridge (null)
            out["probe"] = {"p_value": pr.p_value, "inputs": list(pr.inputs),
                            "length_scale_rad": pr.length_scale if chosen else None,
                            "ridge": pr.ridge if chosen else None}
        return out

    def learnable_words(self) -> str:
        """How much of the error is learnable from the recorded variables, in words."""
        pr = self.probe
        if pr is None:
            return ""
        if pr.p_value >= PROBE_ALPHA:
            return (f"\n  learnable: nothing beyond chance: a kernel probe on the recorded variables does not beat "
                    f"the model on held-out poses (p {pr.p_value:.2g}; it leaves {self.probe_left_rms_mm:.4f} mm)")
        by = ", ".join(v for v, _ in self.carried_by) or ", ".join(pr.inputs)
        return (f"\n  learnable: of {self.rms_mm:.4f} mm RMS, the model leaves {self.learnable_rms_mm:.4f} mm learnable "
                f"from {by}: a kernel probe on held-out poses brings it to {self.probe_left_rms_mm:.4f} mm "
                f"(p {pr.p_value:.2g}); the rest is not predictable from the recorded variables")

    def describe(self) -> str:
        """The same in words (one or two lines)."""
        floor = f"noise floor {self.noise_floor_mm:.4f} mm ({FLOOR_WORDS[self.floor_from]})"
        head = f"unexplained: rms {self.rms_mm:.4f} mm, {floor}" + self.learnable_words()
        if self.significant:
            if not self.correlates_with:
                return head + "\n  structured error remains: no single variable's smooth model lists it"
            deps = ", ".join(f"{v} (held-out R2 {s:.2f})" for v, s in self.correlates_with)
            return head + f"\n  structured error remains: it depends on {deps}"
        if self.floor_from == "repeats" and self.rms_mm > 1.2 * self.noise_floor_mm:
            return head + "\n  no structure found: the error above the floor is shared by a pose's repeats " \
                          "and none of the variables predicts it (target, fixture or repeatability)"
        return head + "\n  no structure found: none of the variables predicts what remains"


def variables(robot: Robot, m: Measurements) -> dict:
    """name -> (N,) float64 numpy values of every variable that varies over the rows."""
    q = m.q.detach().cpu().numpy()
    out = {f"q{j + 1}": q[:, j] for j in range(robot.n)}
    for name in ("temp_c", "payload_kg"):
        v = getattr(m, name)
        if v is not None:
            out[name] = v.detach().cpu().numpy().astype(np.float64)
    out["order"] = np.arange(len(m), dtype=np.float64)
    q_prev = m.q_prev.detach().cpu()
    step = np.sign(q - q_prev.numpy(force=True))
    rows = previous_rows(m.q.detach().cpu())  # the row each joint was reached from (-1: the start)
    before = torch.sign(q_prev - torch.where(rows >= 0, q_prev.gather(0, rows.clamp_min(0)), q_prev)).numpy(force=True)
    for j in range(robot.n):
        out[f"approach_q{j + 1}"] = step[:, j]
    for j in range(robot.n):
        out[f"approach_prev_q{j + 1}"] = before[:, j]
    return {k: v for k, v in out.items() if np.ptp(v) > 0}


def basis(v: np.ndarray) -> np.ndarray:
    """(N, b) smooth basis of one variable: indicators when it takes <= 3 values, else
    piecewise-linear hat functions on KNOTS quantile knots (they sum to one)."""
    vals = np.unique(v)
    if len(vals) <= 3:
        return (v[:, None] == vals[None]).astype(np.float64)
    knots = np.unique(np.quantile(v, np.linspace(0, 1, KNOTS)))
    H = np.zeros((len(v), len(knots)))
    for b in range(len(knots)):
        e = np.zeros(len(knots))
        e[b] = 1.0
        H[:, b] = np.interp(v, knots, e)
    return H


def tcp_columns(robot: Robot, q: torch.Tensor) -> torch.Tensor:
    """(N, 3, n + 3) float64 on the CPU: dP/dq (a joint-angle error, mm per rad) and I3 (a
    TCP offset) at the commanded q (N, n) rad: what each variable's smooth model scales."""
    N = q.shape[0]
    return torch.cat([robot.joint_jacobian(q.detach().cpu().to(robot.dtype)).to(torch.float64),
                      torch.eye(3, dtype=torch.float64).expand(N, 3, 3)], -1)


def smooth_columns(H: torch.Tensor, D: torch.Tensor) -> torch.Tensor:
    """(3N, b (n + 3)) columns ``phi_b(v) * D`` of one variable's smooth model: H (N, b) its
    `basis`, D (N, 3, n + 3) the `tcp_columns`; 3 rows per measurement."""
    return (H[:, None, :, None] * D[:, :, None, :]).reshape(H.shape[0] * 3, -1)


def noise_floor_from_repeats(pose: np.ndarray, r: np.ndarray) -> float | None:
    """Pooled within-pose distance RMS of residual rows r (N, 3), or None without repeats."""
    _, inv, counts = np.unique(pose, return_inverse=True, return_counts=True)
    dof = int((counts - 1).sum())
    if dof == 0:
        return None
    mean = np.zeros((len(counts), 3))
    np.add.at(mean, inv, r)
    mean /= counts[:, None]
    return float(np.sqrt(((r - mean[inv]) ** 2).sum() / dof))


def noise_floor_from_neighbours(x: np.ndarray, r: np.ndarray, k: int = NEIGHBOURS) -> float | None:
    """Gamma-test estimate (distance RMS, mm) of the noise in residual rows r (N, 3), one row
    per pose, at inputs x (N, d), or None (fewer than 2 k + 2 rows, or a non-positive
    intercept).

    For the p-th nearest neighbour nn_p(i) of each row (p = 1..k, Euclidean in x),
    ``delta_p = mean_i |x_i - x_nn_p(i)|^2`` and ``gamma_p = mean_i |r_i - r_nn_p(i)|^2 / 2``.
    A smooth structure s(x) adds ``E|s(x_i) - s(x_j)|^2 / 2``, which goes to zero with the
    distance, to gamma = E|e|^2 (independent noise e of both rows): the least-squares line
    gamma_p = G + A delta_p, extrapolated to zero distance, gives G, the noise's mean
    squared distance; the floor is sqrt(G). (Stefansson, Koncar and Jones, 1997.) It needs no
    model to learn the structure; it is biased up where the structure changes faster than
    the neighbours are close, and down where gamma bends over the distances sampled."""
    import scipy.spatial

    n = len(r)
    if n < 2 * k + 2:
        return None
    _, nn = scipy.spatial.cKDTree(x).query(x, k + 1)
    nn = nn[:, 1:]  # (N, k): each row's neighbours, itself left out
    delta = ((x[:, None, :] - x[nn]) ** 2).sum(-1).mean(0)
    gamma = 0.5 * ((r[:, None, :] - r[nn]) ** 2).sum(-1).mean(0)
    slope, intercept = np.polyfit(delta, gamma, 1)
    return float(np.sqrt(intercept)) if intercept > 0 else None


#: ridge weights tried, relative to the (unit) squared column norms.
RIDGE_GRID = (0.0, 1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0, 1e3, 1e4)


def _ridge(G: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(..., len(RIDGE_GRID), k) ridge coefficients for normal equations G (..., k, k),
    b (..., k), one eigendecomposition per system (eigenvalues below 1e-12 of the largest
    count as zero: minimum-norm solution)."""
    w, V = torch.linalg.eigh(G)  # batched: one call (small LAPACK calls thrash threads)
    mu = torch.tensor(RIDGE_GRID, dtype=G.dtype)[:, None]
    keep = (w > 1e-12 * w.amax(-1, keepdim=True).clamp_min(1e-300))[..., None, :]
    f = torch.where(keep, 1.0 / (w[..., None, :] + mu).clamp_min(1e-300), torch.zeros((), dtype=G.dtype))
    return (f * (V.mT @ b[..., None]).mT) @ V.mT


def held_out_prediction(X: torch.Tensor, y: torch.Tensor, fold: np.ndarray) -> torch.Tensor:
    """Nested-CV ridge prediction of y (R,) from X (R, k) for every row, each fold
    predicted from the others with the ridge weight chosen by an inner cross-validation
    over those others (fold (R,) ints in 0..F-1)."""
    F = int(fold.max()) + 1
    masks = [torch.from_numpy(fold == f) for f in range(F)]
    Xs = [X[mk] for mk in masks]
    Gs = torch.stack([x.T @ x for x in Xs])  # (F, k, k) per-fold normal equations
    bs = torch.stack([x.T @ y[mk] for x, mk in zip(Xs, masks)])  # (F, k)
    pairs = [(f, g) for f in range(F) for g in range(F) if g != f]
    # training sets: all folds but (f, g) for the inner choice, all but f for the prediction
    drop_G = torch.stack([Gs[f] + Gs[g] for f, g in pairs] + list(Gs))
    drop_b = torch.stack([bs[f] + bs[g] for f, g in pairs] + list(bs))
    C = _ridge(Gs.sum(0) - drop_G, bs.sum(0) - drop_b)  # (len(pairs) + F, grid, k)
    err = torch.zeros(F, len(RIDGE_GRID), dtype=y.dtype)
    for i, (f, g) in enumerate(pairs):
        err[f] += ((Xs[g] @ C[i].T - y[masks[g], None]) ** 2).sum(0)
    pred = torch.zeros_like(y)
    for f in range(F):
        if masks[f].any():
            pred[masks[f]] = Xs[f] @ C[len(pairs) + f, int(err[f].argmin())]
    return pred


def _test(name_values: dict, D: torch.Tensor, r: np.ndarray, folds: np.ndarray, pose_idx: np.ndarray):
    """{name: (strength, p, r_hat (N, 3))} for residual rows r (N, 3), see the module doc."""
    P = int(pose_idx.max()) + 1
    y = torch.from_numpy(np.ascontiguousarray(r)).reshape(-1)
    total = max(float((r ** 2).sum()), 1e-300)
    rows = np.repeat(folds, 3)
    out = {}
    for name, v in name_values.items():
        X = smooth_columns(torch.from_numpy(basis(v)), D)  # (3N, b (n + 3))
        X = X / X.norm(dim=0).clamp_min(1e-300)
        pred = held_out_prediction(X, y, rows).reshape(-1, 3).numpy(force=True)
        strength = 1.0 - float(((r - pred) ** 2).sum()) / total
        c = np.bincount(pose_idx, weights=(r * pred).sum(-1), minlength=P)
        sd = c.std(ddof=1) if P > 1 else 0.0
        p = 1.0 if sd == 0 else t_sf(c.mean() / (sd / np.sqrt(P)), P - 1)
        out[name] = (strength, p, pred)
    return out


def unexplained(robot: Robot, m: Measurements, residuals: torch.Tensor, seed: int = 0,
                alpha: float = ALPHA) -> Unexplained:
    """What the model leaves unexplained in `residuals` (N, 3) mm (measured - model or
    model - measured: the sign does not matter) on the rows of m (see the module doc)."""
    r = residuals.detach().cpu().to(torch.float64).numpy(force=True).reshape(-1, 3)
    N = len(r)
    pose = m.pose.cpu().numpy()
    rms = float(np.sqrt((r ** 2).sum(-1).mean()))
    folds = fold_of_pose(pose, seed, FOLDS)
    _, pose_idx = np.unique(pose, return_inverse=True)
    D = tcp_columns(robot, m.q)  # (N, 3, n + 3)
    values = variables(robot, m) if N > 1 else {}
    first = _test(values, D, r, folds, pose_idx)
    strengths = {k: (s, p) for k, (s, p, _) in first.items()}
    corr, rest, step, tested = [], r, 1, first
    while tested:
        level = alpha / 2 ** step / max(len(values), 1)
        ok = [(k, s) for k, (s, p, _) in tested.items() if strengths[k][0] >= MIN_STRENGTH and p < level]
        if not ok:
            break
        name = max(ok, key=lambda t: t[1])[0]
        corr.append((name, strengths[name][0]))
        rest = rest - tested[name][2]
        left = {k: v for k, v in values.items() if k not in {c for c, _ in corr}}
        tested, step = _test(left, D, rest, folds, pose_idx), step + 1
    pr = probe({k: v for k, v in values.items()}, r, pose, seed=seed,
               prismatic=robot.prismatic.nonzero().flatten().tolist())
    floor = noise_floor_from_repeats(pose, r)
    source = "repeats"
    if floor is None:
        best = max((s for s, _ in strengths.values()), default=0.0)
        by_variable = rms * float(np.sqrt(1 - min(max(best, 0.0), 1.0)))
        floor, source = (pr.learnable_rms_mm, "probe") if pr.learnable_rms_mm <= by_variable else (by_variable, "variables")
        q = {f"q{j + 1}": v for j, v in enumerate(m.q.detach().cpu().numpy().T)}
        x = np.hstack(list(variable_features(q, robot.prismatic.nonzero().flatten().tolist()).values()))
        near = noise_floor_from_neighbours(x, r) if len(np.unique(pose)) == N else None
        if near is not None and near <= floor:  # an estimate, unless an upper bound is below it
            floor, source = near, "neighbours"
    found = pr.p_value < PROBE_ALPHA
    return Unexplained(bool(corr) or found, rms, floor, [(k, float(s)) for k, s in corr], source, strengths, r,
                       pr.learnable_mm, pr.carried_by() if found else [], pr, pr.learnable_rms_mm)
