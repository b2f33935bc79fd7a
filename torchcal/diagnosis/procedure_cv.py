"""The refit CV of a searched candidate scores the whole procedure, not its outcome.

A `joint_periodic` candidate's orders come from a held-out spectral search
(`torchcal.diagnosis.spectral`) on the same folds that the refit CV
(`torchcal.diagnosis.crossval.refit_cv`) then tests it on. Refitting the model with the
orders chosen on all rows scores a structure selected with the held-out poses (the "wrong
way to do cross-validation", Hastie, Tibshirani and Friedman, The Elements of Statistical
Learning, 7.10.2): on a few dozen poses a chosen order's held-out gain is in good part the
luck of the folds that chose it.

The rule (`procedure_cv`): fold f's refit uses the orders that the same search finds on
the other folds' rows alone (`torchcal.diagnosis.spectral.fold_orders`: the same alpha,
determination rule and limits rule, the limits from those rows' measured range, the inner
folds their own fold labels), and predicts fold f with the model refitted with THOSE
orders:

- a fold whose search finds the full-data orders of every joint is refitted exactly as
  `refit_cv` refits it (`fold_fit` of the candidate's full fit), so on large data, where
  the folds find the same orders, the figures do not move;
- a fold whose search finds other orders refits the model with them, from the
  candidate's full fit (parameters matched by name, then the current fit's, new ones at
  zero), the parameters the candidate's full fit held still held; fitted, as the fold
  refits of `refit_cv` are, by chord iterations to a certified stationary point of the
  same objective (`torchcal.calibration.refit.refit_from`, from the start's own Jacobian
  of the fold's rows), by the LM where that does not apply (and for the candidate's later
  folds, and for everything on top of a fit whose refits fell back:
  `torchcal.diagnosis.crossval.lm_only`);
- a fold whose search finds no order on any joint is predicted by the current model's
  refit of that fold (no periodic term): its held-out errors are the current model's.

The full-data orders stay what is fitted, accepted and printed. A model so scored carries
its per-fold models (``fold_specs``, fold -> effects); a later round scores every
candidate on top of the current model's fold models, so a step after a searched one is
compared with the current model's honest figure on like terms. Candidates without an
internal search (the other effects: their structure is fixed by the vocabulary, and the
pre-screen's choice among them is Bonferroni-corrected) are refitted as `refit_cv`
refits them unless the current model has fold models.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from torchcal.calibration import refit as rf
from torchcal.calibration.model import CalibrationModel
from torchcal.diagnosis.crossval import RefitCV, fold_fit, lm_only, mark_lm_only, refit_cv
from torchcal.diagnosis.spectral import fold_orders
from torchcal.effects.spec import format_spec, parse_spec, parse_specs
from torchcal.errors import InputError


class FoldSearches:
    """The spectral search re-run per fold for one step (`fold_orders`), on the current full
    fit's residual r (3N,) and free columns A (3N, p) (what the pre-screen searched), each
    joint's searches run once for all the step's candidates that hold that joint."""

    def __init__(self, current_fit, ctx, folds: np.ndarray):
        self.fit, self.ctx, self.folds = current_fit, ctx, np.asarray(folds)
        self._ra, self._orders, self._bases = None, {}, {}  # _bases: fold -> `search_base`, for every joint

    def orders(self, joint: int) -> dict:
        """{fold: the orders of `joint` found without that fold's rows}."""
        if joint not in self._orders:
            model, theta = self.fit.model, self.fit.theta
            if self._ra is None:
                r = self.fit.residuals.reshape(-1).numpy(force=True)
                A = model.jacobian(theta, self.ctx).reshape(-1, model.n_params)[:, self.fit.report.free]
                self._ra = r, A.numpy(force=True)
            self._orders[joint] = fold_orders(model.robot, model, theta, self.ctx, *self._ra, self.folds, joint,
                                              bases=self._bases)
        return self._orders[joint]

    def specs(self, spec: str) -> dict | None:
        """{fold: the candidate's spec in that fold, or None where no joint has an order} for a
        searched candidate `spec` (``joint_periodic:...``); None for a candidate without a
        search (its spec is the same in every fold)."""
        s = parse_spec(spec, self.fit.model.robot.n)
        if s.name != "joint_periodic":
            return None
        per_joint = {j: self.orders(j) for j in s.joints}
        out = {}
        for f in (int(x) for x in np.unique(self.folds)):
            kept = [(j, per_joint[j][f]) for j in s.joints if per_joint[j][f]]
            out[f] = format_spec(s.name, tuple(j for j, _ in kept), tuple(ks for _, ks in kept)) if kept else None
        return out


def fold_start(f, current_fit, specs: list, m):
    """A start for `fold_fit`: the model of `specs` with the parameters of the full fit f
    matched by name (else the current fit's, else zero), f's held parameters held; the
    other fields f's (its prior scales and rho), no covariance or residuals."""
    model = CalibrationModel.for_measurements(f.model.robot, specs, m)
    names = model.param_names()
    theta, free = model.zeros(), model.default_free()
    sources = [(f.model.param_names(), f.theta), (current_fit.model.param_names(), current_fit.theta)]
    held = set(f.report.held) | set(current_fit.report.held)
    for i, n in enumerate(names):
        for src, th in sources:
            if n in src:
                theta[i] = th[src.index(n)]
                break
        free[i] &= n not in held
    report = dataclasses.replace(f.report, free=free, held=[n for n, ok in zip(names, free.tolist()) if not ok],
                                 rank=int(free.sum()))
    return dataclasses.replace(f, model=model, theta=theta, std=torch.zeros_like(theta), residuals=None, weights=None,
                               report=report, covariance=None, implausible=[], set_by_prior=[])


def procedure_cv(current, f, spec: str, m, ctx, folds: np.ndarray, *, sigma_mm: float, sigma_deg: float,
                 searches: FoldSearches | None = None):
    """(RefitCV, fold_specs) of the candidate `spec` (fitted on all rows: f) on top of the
    current model `current` (`Scored`; its ``fold_specs`` and per-pose held-out errors
    ``cv.sq``), folds (N,) by pose (module doc). fold_specs: {fold: effects of the fold's
    model} when a fold's model differs from f's, else None. Without a search and without
    the current model's fold models: `refit_cv` itself. searches: the step's `FoldSearches`
    on current.fit (made here when None)."""
    cand = (searches or FoldSearches(current.fit, ctx, folds)).specs(spec)
    n = f.model.robot.n
    full = [str(s) for s in parse_specs(f.model.specs(), n)]
    labels = [int(x) for x in np.unique(folds)]
    base = {fo: list(current.fit.model.specs() if current.fold_specs is None else current.fold_specs[fo])
            for fo in labels}  # the current model's fold models
    fold_specs = {}  # fold -> the fold model's effects, None: the current model's fold refit
    for fo in labels:
        add = spec if cand is None else cand[fo]
        fold_specs[fo] = None if add is None else [str(s) for s in parse_specs(base[fo] + [add], n)]
    if all(s == full for s in fold_specs.values()):  # every fold's model is f's: today's refit CV
        return refit_cv(f, m, ctx, folds, sigma_mm=sigma_mm, sigma_deg=sigma_deg), None
    _, pose_of_row = np.unique(m.pose.cpu().numpy(), return_inverse=True)
    sq = np.zeros(len(current.cv.sq))
    # the chord where the current model's and the candidate's fold refits took it (`crossval.fold_refits`)
    chord = not (lm_only(current.fit) or lm_only(f))
    for fo in labels:
        test = folds == fo
        poses = np.unique(pose_of_row[test])
        if fold_specs[fo] is None:  # no order in this fold: the current model's prediction
            sq[poses] = current.cv.sq[poses]
            fold_specs[fo] = base[fo]
            continue
        start = f if fold_specs[fo] == full else fold_start(f, current.fit, fold_specs[fo], m)
        t = torch.from_numpy(test)
        try:
            res = None
            if chord:  # the chord fit from the start's own Jacobian; the LM where it does not apply
                res = rf.refit_from(start, m, ctx, ~t, sigma_mm=sigma_mm, sigma_deg=sigma_deg, posterior=False)
                if res is None:  # the later folds, and the next round's on top of f, share its conditioning
                    chord = False
                    mark_lm_only(f)
            if res is None:
                res = fold_fit(start, m, ctx, ~t, sigma_mm=sigma_mm, sigma_deg=sigma_deg, posterior=False)
        except InputError as e:
            return RefitCV(float("inf"), np.full(len(sq), np.inf), str(e)), None
        with torch.no_grad():
            d = (start.model.predict(res.theta, ctx.subset(t)) - m.xyz[t]).pow(2).sum(-1).cpu().numpy()
        sq[poses] = np.bincount(pose_of_row[test], weights=d, minlength=len(sq))[poses]
    return RefitCV(float(np.sqrt(sq.sum() / len(m))), sq), fold_specs
