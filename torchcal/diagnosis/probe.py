"""A probe of what is left: kernel ridge regression of a model's residual on the recorded
variables, held out by pose.

The residual r (N, 3) mm of a fitted model is regressed on the variables of each row:
each revolute joint angle as (sin q, cos q), each approach direction ``approach_qJ`` as
+-1, and temp_c, payload_kg and a prismatic joint as value over standard deviation. The
model is kernel ridge regression (the posterior mean of a Gaussian process) with the RBF
kernel ``k(x, x') = exp(-|x - x'|^2 / (2 l^2))``, one length scale l for the chosen
inputs, and the three components of r as three outputs that share the kernel:
``r_hat(x) = k(x, X) alpha``, ``alpha = (K + lam I)^-1 R``.

The inputs (an ARD that switches variables on or off) and the hyper-parameters (l in
`LENGTH_SCALES`, lam in `RIDGES`) are chosen by pose-grouped cross-validation (`choose`:
forward selection, on at most about MAX_ROWS rows), so that the held-out figure is
honest: poses are split into `FOLDS` folds and fold f is predicted by the model trained
on the other folds. With fewer than 2 MAX_ROWS rows the choice is nested: fold f's inputs
and hyper-parameters are those that predicted best *within* the other folds (each inner
fold from the other inner folds). With more, they are chosen once, on a subsample of about
MAX_ROWS rows (whole poses), and the test and the figures use only the rows of the other
poses (`Probe.tested`), which the choice never saw. All ridges of one (inputs, l,
training set) come from one eigendecomposition K = V diag(w) V^T: the held-out residual
of a block B of rows is exactly ``[(A^-1)_BB]^-1 (A^-1 R)_B`` with A = K + lam I (the
block leave-out identity of Gaussian-process regression), A^-1 = V diag(1 / (w + lam)) V^T.
The kernel of one variable is low-rank, and `kernel_factors` gives its nonzero eigenpairs
without an N x N eigendecomposition; a block of more rows than their number p is
predicted by ridge regression on them (p x p systems, the same prediction).

Figures:
- learnable_rms_mm: ``sqrt(rms^2 - mean_i g_i)``, g_i = |r_i|^2 - |r_i - r_hat_i|^2 the
  held-out gain of tested row i (every row tested: the distance RMS of r - r_hat): what
  the residual comes down to once the part that is learnable from the recorded variables
  is taken off. ``sqrt(rms^2 - learnable_rms^2)`` is the learnable part.
- p_value: one-sided paired t-test over the tested poses of the held-out gain
  ``g_p = sum_i |r_pi|^2 - |r_pi - r_hat_pi|^2`` (the rows i of pose p), mean(g) > 0. A
  pose's prediction never sees that pose, so with nothing learnable E[g_p] <= 0; repeats
  of a pose are one piece of evidence.
- relevance: for each variable, the share of the learnable part lost when that variable
  is dropped from the inputs (block-CV at the hyper-parameters chosen on all rows):
  ``(mse_without - mse) / (mean|r|^2 - mse)``; carried_by lists those >= `MIN_RELEVANCE`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from torchcal.folds import fold_of_pose
from torchcal.kernel_ridge import (MAX_ROWS, MIN_POSES, block_cv, choose, fit_dual, rbf, stack_inputs, subsample,
                                   variable_features)
from torchcal.statistics import t_sf

#: a variable carries the learnable error when dropping it loses this share of it.
MIN_RELEVANCE = 0.1


@dataclass
class Probe:
    """Result of `probe`: learnable_rms_mm, rms_mm (distance RMS, mm); p_value of the
    held-out gain; inputs, length_scale (rad), ridge: the hyper-parameters chosen on all rows;
    relevance: variable -> share of the learnable part lost without it; prediction (N, 3) mm,
    the held-out prediction; tested (N,) bool: the rows whose poses the choice never saw
    (all rows when the choice is nested)."""

    rms_mm: float
    learnable_rms_mm: float
    p_value: float
    inputs: list
    length_scale: float
    ridge: float
    relevance: dict = field(default_factory=dict)
    prediction: np.ndarray | None = field(default=None, repr=False)
    tested: np.ndarray | None = field(default=None, repr=False)  # (N,) bool: the rows the test and figure use

    @property
    def learnable_mm(self) -> float:
        """Distance RMS of the learnable part, ``sqrt(rms^2 - learnable_rms^2)`` (0 when none)."""
        return float(np.sqrt(max(self.rms_mm ** 2 - self.learnable_rms_mm ** 2, 0.0)))

    def carried_by(self) -> list:
        """[(variable, relevance)] with relevance >= MIN_RELEVANCE, largest first."""
        return sorted(((k, v) for k, v in self.relevance.items() if v >= MIN_RELEVANCE), key=lambda t: -t[1])


def probe(values: dict, residuals: np.ndarray, pose: np.ndarray, *, seed: int = 0,
          prismatic=()) -> Probe:
    """Kernel-ridge probe of residual rows (N, 3) mm on the variables `values` (name -> (N,),
    as `unexplained.variables`; ``order`` is not used: it is not a recorded condition).
    pose (N,) pose ids (folds and the test are by pose). See the module doc."""
    r = np.ascontiguousarray(residuals, dtype=np.float64).reshape(-1, 3)
    rms = float(np.sqrt((r ** 2).sum(-1).mean()))
    pose = np.asarray(pose)
    _, pose_idx = np.unique(pose, return_inverse=True)
    P = int(pose_idx.max()) + 1 if len(r) else 0
    values = {k: v for k, v in values.items() if k != "order"}
    if P < MIN_POSES or not values:
        return Probe(rms, rms, 1.0, [], float("nan"), float("nan"), {}, np.zeros_like(r))
    feats = variable_features(values, prismatic)
    names = list(feats)
    Y = torch.from_numpy(r)
    fold = fold_of_pose(pose, seed)
    pred = np.zeros_like(r)
    rows = subsample(fold, np.ones(len(r), dtype=bool), pose, seed)
    split = len(r) >= 2 * MAX_ROWS  # choose once on `rows`, test the poses outside them
    if split:
        chosen = choose(feats, names, Y, fold, rows)
    for f in np.unique(fold):
        train = fold != f
        inputs, ell, lam, _ = chosen if split else \
            choose(feats, names, Y, fold, subsample(fold, train, pose, seed + 1 + int(f)))
        if inputs:
            X, T = stack_inputs(feats, inputs), torch.from_numpy(train)
            alpha = fit_dual(X[T], Y[T], ell, lam)
            pred[fold == f] = (rbf(X[torch.from_numpy(fold == f)], X[T], ell) @ alpha).numpy(force=True)
    tested = ~rows if split else np.ones(len(r), dtype=bool)
    gain_row = (r ** 2).sum(-1) - ((r - pred) ** 2).sum(-1)
    learn = float(np.sqrt(max(rms ** 2 - gain_row[tested].mean(), 0.0)))
    gain = np.bincount(pose_idx[tested], weights=gain_row[tested], minlength=P)[np.unique(pose_idx[tested])]
    sd = gain.std(ddof=1) if len(gain) > 1 else 0.0
    p = 1.0 if sd == 0 else t_sf(gain.mean() / (sd / np.sqrt(len(gain))), len(gain) - 1)
    # inputs and hyper-parameters on all rows, and what each input carries at them
    inputs, ell, lam, mse = chosen if split else choose(feats, names, Y, fold, rows)
    Yr = Y[torch.from_numpy(rows)]
    total = float(Yr.pow(2).sum(-1).mean())
    blocks = [torch.from_numpy(np.flatnonzero(fold[rows] == g)) for g in np.unique(fold[rows])]
    relevance = {}
    for k in inputs:
        rest = [n for n in inputs if n != k]
        without = total
        if rest:
            X = stack_inputs(feats, rest)[torch.from_numpy(rows)]
            pr, _ = block_cv(rbf(X, X, ell), Yr, blocks, (lam,))
            without = float((pr[0] - Yr).pow(2).sum(-1).mean())
        relevance[k] = (without - mse) / (total - mse) if total - mse > 1e-12 * total else 0.0
    return Probe(rms, learn, p, inputs, float(ell), float(lam), relevance, pred, tested)
