"""What the model leaves unexplained: its size, the noise floor, and what it depends on.

`unexplained(robot, m, residuals)` looks at the residuals (N, 3) mm of any fitted model
(any robot, any effects, built-in or user-written) and answers three questions:

- rms_mm: the distance RMS of the residuals.
- noise_floor_mm: the distance RMS that measurement noise alone would leave.
  * With repeats (some pose ids on two or more rows): the pooled scatter of the residual
    within a pose, ``sqrt(sum_p sum_i |r_pi - mean_p r|^2 / sum_p (m_p - 1))``. It is the
    repeatability of the session: an error shared by a pose's repeats (target nest,
    fixture) is *not* in it, and shows as rms_mm above the floor with no correlate.
  * Without repeats: ``rms_mm * sqrt(1 - strength)`` of the strongest variable below,
    i.e. the held-out error that no single variable predicts. It is an upper bound of
    the noise (it keeps whatever the variables do not explain), documented as such.
- correlates_with: the variables the residual depends on, strongest first. The
  variables are each joint angle ``q1..qn``, ``temp_c`` and ``payload_kg`` (when they
  vary), the measurement ``order`` (row index) and the approach direction of each joint
  ``approach_q1..`` (sign of q - q_prev). For one variable v the residual is fitted by a
  smooth function of v in joint space and in the base frame: columns
  ``phi_b(v) * [dP/dq (3, n), I3]`` (3 rows per measurement), phi_b the piecewise-linear
  hat functions on 6 quantile knots of v (one indicator per value when v takes at most 3
  values), i.e. a joint-angle error and a TCP offset that both vary smoothly with v
  (a coupling q_j += k q_i, a gear error, a drift, a bent link all have this form).
  strength = held-out R^2 of that fit, ``1 - sum |r - r_hat|^2 / sum |r|^2``, with
  r_hat predicted for each fold by pose (5 folds) from the other folds.
  A variable correlates when strength >= MIN_STRENGTH (2 %) and its held-out gain is
  significant by pose: per pose p, ``d_p = sum_i |r_pi|^2 - |r_pi - r_hat_pi|^2``, one-sided
  t-test of mean(d_p) > 0 over the poses at level alpha / (number of variables)
  (Bonferroni). Pose-level: repeats of a pose are one piece of evidence. Under pure noise
  a held-out prediction only adds error (E d_p < 0), so the test is conservative.
- significant: structured error remains, i.e. at least one variable correlates.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.stats
import torch

from torchcal.measurements import Measurements
from torchcal.robots.robot import Robot

ALPHA = 1e-3
MIN_STRENGTH = 0.02
KNOTS = 6
FOLDS = 5


@dataclass
class Unexplained:
    """What remains. rms_mm, noise_floor_mm: distance RMS in mm; floor_from: 'repeats' or
    'estimate'; correlates_with: [(variable, strength)] strongest first (significant only);
    strengths: every variable tested -> (strength, p-value)."""

    significant: bool
    rms_mm: float
    noise_floor_mm: float
    correlates_with: list
    floor_from: str = "repeats"
    strengths: dict = field(default_factory=dict, repr=False)
    residuals: np.ndarray | None = field(default=None, repr=False)  # (N, 3) mm, what was looked at

    def to_dict(self) -> dict:
        return {"significant": self.significant, "rms_mm": self.rms_mm, "noise_floor_mm": self.noise_floor_mm,
                "correlates_with": [{"variable": v, "strength": s} for v, s in self.correlates_with]}

    def describe(self) -> str:
        """The same in words (one or two lines)."""
        floor = f"noise floor {self.noise_floor_mm:.4f} mm ({'from repeats' if self.floor_from == 'repeats' else 'estimated, no repeats: an upper bound'})"
        head = f"unexplained: rms {self.rms_mm:.4f} mm, {floor}"
        if self.significant:
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
    step = np.sign(q - m.q_prev.detach().cpu().numpy())
    for j in range(robot.n):
        out[f"approach_q{j + 1}"] = step[:, j]
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


def _fold_of_pose(pose: np.ndarray, seed: int) -> np.ndarray:
    ids, inverse = np.unique(pose, return_inverse=True)
    return (np.random.default_rng(seed).permutation(len(ids)) % FOLDS)[inverse]


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


def unexplained(robot: Robot, m: Measurements, residuals: torch.Tensor, seed: int = 0,
                alpha: float = ALPHA) -> Unexplained:
    """What the model leaves unexplained in `residuals` (N, 3) mm (measured - model or
    model - measured: the sign does not matter) on the rows of m (see the module doc)."""
    r = residuals.detach().cpu().to(torch.float64).numpy().reshape(-1, 3)
    N = len(r)
    pose = m.pose.cpu().numpy()
    rms = float(np.sqrt((r ** 2).sum(-1).mean()))
    folds = _fold_of_pose(pose, seed)
    _, pose_idx = np.unique(pose, return_inverse=True)
    P = int(pose_idx.max()) + 1 if N else 0
    D = torch.cat([robot.joint_jacobian(m.q.detach().cpu().to(robot.dtype)).to(torch.float64),
                   torch.eye(3, dtype=torch.float64).expand(N, 3, 3)], -1)  # (N, 3, n + 3)
    rt = torch.from_numpy(r)
    total = float((r ** 2).sum())
    strengths = {}
    for name, v in variables(robot, m).items():
        H = torch.from_numpy(basis(v))  # (N, b)
        X = (H[:, None, :, None] * D[:, :, None, :]).reshape(N * 3, -1)  # (3N, b (n + 3))
        X = X / X.norm(dim=0).clamp_min(1e-300)
        y = rt.reshape(-1)
        pred = torch.zeros_like(y)
        rows = np.repeat(folds, 3)
        for f in range(FOLDS):
            test = torch.from_numpy(rows == f)
            if not test.any() or test.all():
                continue
            coef = torch.linalg.lstsq(X[~test], y[~test], rcond=1e-10, driver="gelsd").solution
            pred[test] = X[test] @ coef
        e = (y - pred).reshape(-1, 3).numpy()
        strength = 1.0 - float((e ** 2).sum()) / max(total, 1e-300)
        d = np.bincount(pose_idx, weights=(r ** 2).sum(-1) - (e ** 2).sum(-1), minlength=P)
        sd = d.std(ddof=1) if P > 1 else 0.0
        p = 1.0 if sd == 0 else float(scipy.stats.t.sf(d.mean() / (sd / np.sqrt(P)), P - 1))
        strengths[name] = (strength, p)
    level = alpha / max(len(strengths), 1)
    corr = sorted(((k, s) for k, (s, p) in strengths.items() if s >= MIN_STRENGTH and p < level),
                  key=lambda t: -t[1])
    floor = noise_floor_from_repeats(pose, r)
    source = "repeats"
    if floor is None:
        best = max((s for s, _ in strengths.values()), default=0.0)
        floor, source = rms * float(np.sqrt(1 - min(max(best, 0.0), 1.0))), "estimate"
    return Unexplained(bool(corr), rms, floor, [(k, float(s)) for k, s in corr], source, strengths, r)
