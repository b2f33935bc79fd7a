"""Does the non-physical residual stage earn its place? The held-out test that `fit
--residual-model` and `discover --residual-model` apply before adding it.

The stage (`torchcal.calibration.residual_model`) is judged as `discover` judges an
effect: on pose-grouped folds (`torchcal.folds.fold_of_pose`), the physical
model is refitted on the other folds (`fold_fit`), the stage is fitted to that refit's
training residuals, and both are predicted on the held-out poses. Per pose p,
``d_p = e0_p - e1_p`` (held-out squared distance error without the stage minus with it);
the stage is applied only when the one-sided paired t-test of mean(d) > 0 has p below
`REFIT_ALPHA` (0.05, one test) and the held-out RMS drops by at least `MIN_GAIN` (2 %):
`torchcal.diagnosis.selection.refit_decision`, the rule of a refitted candidate. Otherwise
it is refused, with the figures. When applied, the stage is fitted on all rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from torchcal.folds import fold_of_pose
from torchcal.diagnosis.crossval import fold_refits, per_pose
from torchcal.diagnosis.selection import MIN_GAIN, REFIT_ALPHA, refit_decision
from torchcal.errors import InputError


@dataclass
class StageTest:
    """applied: the stage passed the test; cv_without_mm / cv_with_mm: held-out distance
    RMS of the physical model alone / with the stage (mm); p_value, level; reason (words,
    with the figures); stage: the stage fitted on all rows when applied, else None."""

    applied: bool
    cv_without_mm: float
    cv_with_mm: float
    p_value: float
    level: float
    reason: str
    stage: object = None

    def to_dict(self) -> dict:
        return {"applied": self.applied, "cv_without_mm": self.cv_without_mm, "cv_with_mm": self.cv_with_mm,
                "p_value": self.p_value, "level": self.level, "reason": self.reason}

    def describe(self) -> str:
        """One line: applied or refused, and why."""
        if self.applied:
            return f"residual stage applied: held-out {self.reason}"
        return f"residual stage refused: held-out {self.reason}"


def stage_test(full, m, ctx, *, kind: str = "kernel", folds: int = 5, seed: int = 0, sigma_mm: float,
               sigma_deg: float, alpha: float = REFIT_ALPHA, min_gain: float = MIN_GAIN) -> StageTest:
    """The held-out test of the residual stage on top of the fitted model `full`
    (`FitResult`) on measurements m (context ctx), module doc."""
    from torchcal.calibration.residual_model import fit_residual_model

    robot = full.model.robot
    fold = fold_of_pose(m.pose, seed, folds)
    e0, e1 = np.zeros(len(m)), np.zeros(len(m))
    try:
        # the refits' theta and residuals only: no posterior (`fit`'s posterior=False)
        for test, res in fold_refits(full, m, ctx, fold, sigma_mm=sigma_mm, sigma_deg=sigma_deg,
                                     posterior=False):
            with torch.no_grad():
                r = (m.xyz[test] - full.model.predict(res.theta, ctx.subset(test))).cpu().to(torch.float64)
            stage = fit_residual_model(robot, m.subset(~test), res.residuals, kind=kind, seed=seed)
            corr = torch.zeros_like(r) if stage is None else stage.predict(m.q[test]).cpu().to(torch.float64)
            e0[test.numpy(force=True)] = r.pow(2).sum(-1).numpy(force=True)
            e1[test.numpy(force=True)] = (r - corr).pow(2).sum(-1).numpy(force=True)
    except InputError as e:
        if "residual model" in str(e):  # a wrong kind: the caller's mistake, not a fold's
            raise
        return StageTest(False, float("inf"), float("inf"), 1.0, alpha, f"fold refit impossible: {e}")
    sq0, sq1 = per_pose(m, e0), per_pose(m, e1)
    cv0, cv1 = float(np.sqrt(e0.mean())), float(np.sqrt(e1.mean()))
    ok, p, why = refit_decision(cv0, sq0, cv1, sq1, n_refits=1, alpha=alpha, min_gain=min_gain)
    why = f"rms {cv1:.4f} mm with the stage vs {cv0:.4f} mm without ({folds} pose-grouped folds): " + \
        why.split(": ", 1)[-1]
    stage = fit_residual_model(robot, m, full.residuals, kind=kind, seed=seed) if ok else None
    if ok and stage is None:
        ok, why = False, why + "; on all rows no joint angle predicts the residual"
    return StageTest(ok, cv0, cv1, p, alpha, why, stage)
