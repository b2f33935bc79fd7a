"""Which physical effect is the model missing? The drivers `diagnose` and `discover`
(docs/diagnosis.md).

`diagnose` (one step):

1. Fit the current model (geometric + chosen effects) to all rows exactly as `torchcal
   fit` does (orientation when measured, the plausibility prior); residuals r (N, 3).
2. Where it fails: residual RMS per joint-angle quartile and per workspace region.
3. Pre-screen (`torchcal.diagnosis.screen`): every candidate effect scored by a
   linearised refit with cross-validation by pose; ranked, a verdict proposed
   (`torchcal.diagnosis.selection`).
4. Decide (`torchcal.diagnosis.step`): the proposed candidate and the next best (3 at
   most) are refitted in full and cross-validated by pose on the same folds as the current
   model; a candidate significant in the pre-screen is accepted only when its held-out
   error drops beyond chance (paired one-sided test over poses, Bonferroni over the
   candidates refitted). The rejected ones are listed with their reason.
5. What remains unexplained after the accepted candidate (or the current model).

`discover` repeats the step: the accepted candidate's full fit and its CV become the
next round's current model, so a round prints exactly the figures `diagnose` prints for
that step. With a `TransferCheck` (`torchcal.diagnosis.transfer`) a round's accepted
step is kept only when it lowers the error on another session's held-out poses beyond
chance, and a step on several joints only with the joints whose part does so on its own
(the union of those parts refitted lands; what the round's transfer record names as kept
is what the next round's model holds); the next candidate that met the rule is tried
instead, and a round whose candidates are all refused ends the discovery. Round i is
`diagnose` with budget alpha / 2^i, whose pre-screen spends half of it, so all the
pre-screen tests of all rounds keep the family-wise error below alpha; the refit tests
are a second condition.
Everything is deterministic for a given seed (fold assignment).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
import torch

from torchcal.calibration.fit import SIGMA_DEG, SIGMA_MM, FitResult, fit
from torchcal.calibration.identifiability import unidentified_effects, unidentified_reason
from torchcal.calibration.model import CalibrationModel
from torchcal.diagnosis.candidates import Candidate
from torchcal.diagnosis.crossval import FewPosesWarning, few_poses
from torchcal.diagnosis.stability import absorbing
from torchcal.folds import fold_of_pose
from torchcal.diagnosis.screen import prescreen
from torchcal.diagnosis.selection import ALPHA, MIN_GAIN, REFIT_ALPHA, REFITS, shortlist
from torchcal.diagnosis.step import Scored, Step, fit_options, score_current, score_step
from torchcal.diagnosis.transfer import Within
from torchcal.diagnosis.unexplained import Unexplained, unexplained
from torchcal.effects import context_of
from torchcal.effects.spec import parse_spec, parse_specs
from torchcal.measurements import Measurements
from torchcal.robots.robot import Robot


@dataclass
class Diagnosis:
    """One step: the current model (baseline_effects, baseline_fit, baseline_cv_rms_mm: the
    refit CV), the pre-screen's candidates (ranked), the verdict (the accepted candidate
    or None), step (the full refits, `Step`), where it fails, and what remains."""

    baseline_effects: list
    baseline_fit: FitResult
    baseline_cv_rms_mm: float
    candidates: list
    verdict: Candidate | None
    step: Step | None = None
    where: dict = field(default_factory=dict)
    unexplained: Unexplained | None = None  # what remains after the baseline + the verdict

    def to_dict(self) -> dict:
        res = self.baseline_fit.residuals.norm(dim=-1)
        return {
            "baseline": {"effects": list(self.baseline_effects), "rms_mm": self.baseline_fit.rms_mm,
                         "max_mm": float(res.max()), "cv_rms_mm": self.baseline_cv_rms_mm,
                         "held": list(self.baseline_fit.report.held),
                         "beyond_plausible": list(self.baseline_fit.implausible)},
            "candidates": [c.to_dict() for c in self.candidates],
            "refits": None if self.step is None else self.step.to_dict(),
            "verdict": None if self.verdict is None else
            {"effect": self.verdict.effect, "joints": list(self.verdict.joints)},
            "where": self.where,
            "unexplained": None if self.unexplained is None else self.unexplained.to_dict(),
        }


def where_it_fails(robot: Robot, m: Measurements, residuals: torch.Tensor, bins: int = 4) -> dict:
    """Residual distance RMS per joint-value quantile bin and per workspace region. A
    joint's bins are {"q": [lo, hi], "n", "rms_mm"} in its "unit": 'deg' (revolute) or
    'mm' (prismatic)."""
    d = residuals.norm(dim=-1).numpy(force=True)
    q = robot.q_to_user(m.q).numpy(force=True)
    out = {"per_joint": [], "per_region": []}
    for j, unit in enumerate(robot.joint_units()):
        edges = np.quantile(q[:, j], np.linspace(0, 1, bins + 1))
        idx = np.clip(np.searchsorted(edges, q[:, j], side="right") - 1, 0, bins - 1)
        out["per_joint"].append({"joint": j + 1, "unit": unit, "bins": [
            {"q": [float(edges[b]), float(edges[b + 1])], "n": int((idx == b).sum()),
             "rms_mm": float(np.sqrt((d[idx == b] ** 2).mean())) if (idx == b).any() else None}
            for b in range(bins)]})
    xyz = m.xyz.numpy(force=True)
    reach = np.hypot(xyz[:, 0], xyz[:, 1])
    r_edges = np.quantile(reach, [0, 1 / 3, 2 / 3, 1])
    z_mid = float(np.median(xyz[:, 2]))
    for a in range(3):
        for upper in (False, True):
            sel = (reach >= r_edges[a]) & (reach <= r_edges[a + 1]) & ((xyz[:, 2] > z_mid) == upper)
            if sel.any():
                out["per_region"].append({
                    "reach_mm": [float(r_edges[a]), float(r_edges[a + 1])],
                    "z": "upper" if upper else "lower", "n": int(sel.sum()),
                    "rms_mm": float(np.sqrt((d[sel] ** 2).mean())), "max_mm": float(d[sel].max())})
    return out


def diagnose(robot: Robot, m: Measurements, effects=(), folds: int = 5, seed: int = 0, *,
             alpha: float = ALPHA, min_gain: float = MIN_GAIN, base_fit: FitResult | None = None,
             current: Scored | None = None, refits: int = REFITS, refit_alpha: float = REFIT_ALPHA,
             sigma_mm: float = SIGMA_MM, sigma_deg: float = SIGMA_DEG, report_rest: bool = True) -> Diagnosis:
    """Which effect is missing from `robot` + `effects` on measurements m (module doc).

    alpha: the budget of the step (its pre-screen spends half of it, so that `discover`'s
    round 0 is this call); refit_alpha: the refit tests' level (Bonferroni over
    the candidates refitted; torchcal.diagnosis.selection). base_fit: the current model's
    fit (default: fitted here as `torchcal fit` does; its model then overrides
    `effects`); current: its already scored figures (`discover` passes the accepted
    refit of the previous round). sigma_mm / sigma_deg: the orientation weighting, as in
    `fit`. report_rest: also probe what remains (`unexplained`); `discover` probes only its
    final model.
    """
    ctx = context_of(robot, m)
    if base_fit is None:
        specs = [str(s) for s in parse_specs(list(effects), robot.n)] if effects else []
        model = CalibrationModel.for_measurements(robot, specs, m)  # one tool offset per point id
        base_fit = fit(model, ctx, m.xyz, **fit_options(m, sigma_mm=sigma_mm, sigma_deg=sigma_deg))
    specs = base_fit.model.specs()
    folds_ = fold_of_pose(m.pose, seed, folds)
    if current is None:  # the first step (discover's round 0): once
        few = few_poses(base_fit, m, folds_)
        if few is not None:
            warnings.warn(few, FewPosesWarning, stacklevel=2)
    screen = prescreen(robot, base_fit.model, specs, base_fit, m, ctx, folds_, alpha=alpha / 2, min_gain=min_gain)
    if current is None:
        current = score_current(base_fit, m, ctx, folds_, sigma_mm=sigma_mm, sigma_deg=sigma_deg)
    step = score_step(current, shortlist(screen.candidates, screen.verdict, refits), m, ctx, folds_,
                      alpha=refit_alpha, min_gain=min_gain, sigma_mm=sigma_mm, sigma_deg=sigma_deg)
    acc = step.accepted
    verdict = None if acc is None else next(c for c in screen.candidates if c.spec == acc.spec)
    where = where_it_fails(robot, m, base_fit.residuals)
    rest = base_fit.residuals if acc is None else acc.fit.residuals
    return Diagnosis(specs, base_fit, current.cv_rms_mm, screen.candidates, verdict, step, where,
                     unexplained(robot, m, rest, seed=seed) if report_rest else None)


@dataclass
class Discovery:
    """history[i] = {"effects", "rms_mm" (full fit, training), "cv_rms_mm" (its refit CV),
    "step" (the refits of that round)}; final_effects, fit: the last accepted model;
    stability: added effect -> its `torchcal.diagnosis.stability.Stability` in the final
    model (per joint part for an effect on several joints); absorbing: the effects, or
    joint parts (``joint_periodic:1@12+22``), that fail it (kept in the model, not named as
    physics); named: the final effects named as physics (an effect on several joints
    restricted to the joints whose part holds); carried: the steps a transfer check kept.
    The two labels answer two questions: the split-half label, "does it hold beyond the
    half of this session's workspace it was fitted on", the transfer check, "does it
    hold in another session"; a fit term that carried is printed as both."""

    history: list
    final_effects: list
    fit: FitResult
    diagnoses: list
    unexplained: Unexplained | None = None  # what the final model leaves
    stability: dict = field(default_factory=dict)
    unidentified: dict = field(default_factory=dict)  # final effect none of whose parameters is identified -> why

    def _fit_terms(self) -> list:
        """[(spec, Stability)] of the effects and joint parts kept as fit terms only."""
        return [t for e, st in self.stability.items() for t in st.split_spec(e)[1]]

    @property
    def absorbing(self) -> list:
        return [e for e, _ in self._fit_terms()]

    @property
    def carried(self) -> list:
        """The steps a transfer check kept, in round order (specs): each lowered the other
        session's held-out error beyond chance (`torchcal.diagnosis.transfer`); [] without
        a check."""
        return [h["transfer"]["kept"] for h in self.history if (h.get("transfer") or {}).get("kept")]

    def _carried(self, spec: str) -> bool:
        """Whether every joint of the effect (or joint part) `spec` is in a step the
        transfer check kept (the same effect on the same joints; by name for an effect
        without joints)."""
        if not self.carried:
            return False
        n = self.fit.model.robot.n
        held = {(s.name, j) for c in self.carried for s in [parse_spec(c, n)] for j in (s.joints or [None])}
        s = parse_spec(spec, n)
        return all((s.name, j) in held for j in (s.joints or [None]))

    @property
    def named(self) -> list:
        return [n for e in self.final_effects if e not in self.unidentified
                for n in (self.stability[e].split_spec(e)[0] if e in self.stability else [e])]

    def final_words(self) -> str:
        """The final effects named as physics, and the absorbing ones, in words."""
        out = [f"final effects: {', '.join(self.named) or 'none'}"]
        out += [f"  {e}: in the model as a fit term only, not named: {st.words()}; "
                + ("it carried to the other session (the transfer check kept it): the robot's, not this session's, "
                   "but not the effect it is named after: " if self._carried(e) else "")
                + "it absorbs structure outside the vocabulary (what is left, below)" for e, st in self._fit_terms()]
        out += [f"  {e}: in the model, not named: none of its parameters is identifiable from these data (all held "
                f"at nominal{': ' + why if why else ''}): it changes nothing" for e, why in self.unidentified.items()]
        return "\n".join(out)

    def to_dict(self) -> dict:
        return {"history": self.history, "final_effects": self.final_effects,
                "held": list(self.fit.report.held), "beyond_plausible": list(self.fit.implausible),
                "set_by_prior": list(self.fit.set_by_prior),
                "unexplained": None if self.unexplained is None else self.unexplained.to_dict(),
                "stability": {e: st.to_dict() for e, st in self.stability.items()}, "absorbing": self.absorbing,
                "named": self.named, "carried": self.carried, "unidentified": self.unidentified,
                "residual_stage": self.fit.residual_test}


def discover(robot: Robot, m: Measurements, effects=(), folds: int = 5, seed: int = 0, *,
             max_rounds: int = 6, alpha: float = ALPHA, sigma_mm: float = SIGMA_MM,
             sigma_deg: float = SIGMA_DEG, transfer=None, report_rest: bool = True) -> Discovery:
    """Add the accepted candidate of each step until none is (module doc); at most
    `max_rounds` effects. transfer: a `TransferCheck` or None; with it, history[i]
    ["transfer"] holds the round's `TransferCheck.choose` record (its "kept": the spec
    that lands, a step or the union of its kept joint parts). report_rest: also probe what
    the final model leaves (`unexplained`, after the search; it changes none of it); False
    leaves `Discovery.unexplained` None (a caller that reads only the search's result)."""
    specs = [str(s) for s in parse_specs(list(effects), robot.n)] if effects else []
    history, diagnoses = [], []
    ctx = context_of(robot, m)
    base = fit(CalibrationModel.for_measurements(robot, specs, m), ctx, m.xyz,
               **fit_options(m, sigma_mm=sigma_mm, sigma_deg=sigma_deg))
    current = None
    t_now = None if transfer is None else transfer.score(base)
    if transfer is not None:  # another reflector in the other session: every step would be refused
        tool = transfer.another_tool(base)
        if tool is not None:
            from torchcal.calibration.checks.model_data import ReflectorWarning
            warnings.warn(tool, ReflectorWarning, stacklevel=2)
    for i in range(max_rounds + 1):
        d = diagnose(robot, m, folds=folds, seed=seed, base_fit=base, current=current, alpha=alpha / 2 ** i,
                     sigma_mm=sigma_mm, sigma_deg=sigma_deg, report_rest=False)  # the final model's, once, below
        diagnoses.append(d)
        if i == max_rounds and d.step.accepted is not None:  # printed as it is: not in the final model
            d.step.decline(f"not taken: the round limit ({max_rounds} effects) is reached")
            d.verdict = None
        cur = d.step.current
        history.append({"effects": list(cur.effects), "rms_mm": cur.rms_mm, "cv_rms_mm": cur.cv_rms_mm,
                        "step": d.step.to_dict()})
        acc = d.step.accepted
        if transfer is not None:  # a step must lower the other session's error (transfer.py)
            passed = sorted([s for s in d.step.refits if s.accepted or s.passed] if i < max_rounds else [],
                            key=lambda s: not s.accepted)  # the step's verdict first, then rank order
            within = Within(cur, m, ctx, fold_of_pose(m.pose, seed, folds), sigma_mm, sigma_deg)
            (acc, after), history[-1]["transfer"] = transfer.choose(t_now, passed, within)
            t_now = t_now if acc is None else after
        if acc is None or i == max_rounds:
            break
        base, current = acc.fit, Scored(acc.effects, "", acc.rms_mm, acc.cv_rms_mm, acc.fit, acc.cv,
                                        prior_held=d.step.current.prior_held + acc.prior_held, fold_specs=acc.fold_specs)
    added = [e for e in base.model.specs() if e not in specs]  # physics or absorption (stability.py)
    rest = unexplained(robot, m, base.residuals, seed=seed) if report_rest else None
    by_spec = {e.spec(): e for e in base.model.effects}
    idle = {e: unidentified_reason(by_spec[e], m) for e in unidentified_effects(base.model, base.report.held)}
    return Discovery(history, base.model.specs(), base, diagnoses, rest,
                     absorbing(base, added, m, ctx, sigma_mm=sigma_mm, sigma_deg=sigma_deg), idle)
