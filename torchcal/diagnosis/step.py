"""One step of the loop, scored by full nonlinear refits: the figures `diagnose` and
`discover` both print.

`score_step` takes the current model's full fit and the candidates to try (the
pre-screen's shortlist, torchcal.diagnosis.selection) and, for the current model and each
candidate, reports

- rms_mm: the full fit's training distance RMS (the candidate's model refitted from the
  current fit, its new parameters starting at zero);
- cv_rms_mm: the pose-grouped K-fold CV of that model refitted on the other folds
  (`torchcal.diagnosis.crossval.refit_cv`), on the same folds for all; for a searched
  candidate (`joint_periodic`), and for any candidate on top of a model so scored, the CV
  of the whole procedure: each fold refits the orders its training poses' own search
  finds (`torchcal.diagnosis.procedure_cv`);
- p-value, accepted and a reason (`torchcal.diagnosis.selection.refit_decision`);
- held: parameters the identifiability analysis held (unidentifiable), beyond: those that
  ended beyond their plausible size (`torchcal.calibration.plausibility`).

A candidate passes only when the data determine it: each of its new parameters (with a
plausible scale) is identifiable, has a posterior sd (the prior included) below half its
plausible size and a value within it (`torchcal.calibration.plausibility.determination`);
otherwise it is rejected with the figures and the parameter it is collinear with. Of the
candidates that pass, the one with the largest refit gain (lowest refit CV RMS) is
accepted, unless a simpler one that passed (fewer new parameters) is not significantly
worse per pose (`choose`); a candidate significant by its random part only is taken only
when no deterministic one passes.

`Step.lines()` is the text both commands print; `Step.to_dict()` their JSON.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from torchcal.calibration.fit import SIGMA_DEG, SIGMA_MM, FitResult, fit
from torchcal.calibration.model import CalibrationModel
from torchcal.calibration.plausibility import determination, determination_words
from torchcal.calibration.refit import warm_fit
from torchcal.diagnosis.crossval import RefitCV, lm_only, refit_cv
from torchcal.diagnosis.procedure_cv import FoldSearches, procedure_cv
from torchcal.diagnosis.selection import ALPHA, MIN_GAIN, not_better, refit_decision
from torchcal.effects.spec import parse_specs
from torchcal.errors import InputError


@dataclass
class Scored:
    """A model scored by its full refit: effects (specs), spec (the candidate added, '' for
    the current model), rms_mm, cv_rms_mm, fit (`FitResult`), cv (`RefitCV`); for a
    candidate, p_value, accepted and reason."""

    effects: list
    spec: str
    rms_mm: float
    cv_rms_mm: float
    fit: FitResult | None = field(default=None, repr=False)
    cv: RefitCV | None = field(default=None, repr=False)
    p_value: float = 1.0
    accepted: bool = False
    reason: str = ""
    passed: bool = False  # met the acceptance rule (accepted unless another had a larger refit gain)
    random_only: bool = False  # significant in the pre-screen by its random part only
    k: int = 0  # new identified parameters (beyond the current model's)
    prior_held: list = field(default_factory=list)  # held at nominal: the prior alone set them
    fold_specs: dict | None = None  # fold -> the effects of that fold's model in cv, when not all `effects`

    @property
    def held(self) -> list:
        return [] if self.fit is None else [n for n in self.fit.report.held if n not in self.prior_held]

    @property
    def beyond(self) -> list:
        return [] if self.fit is None else list(self.fit.implausible)

    def to_dict(self) -> dict:
        out = {"effects": list(self.effects), "rms_mm": self.rms_mm, "cv_rms_mm": self.cv_rms_mm,
               "held": self.held, "held_set_by_prior": list(self.prior_held), "beyond_plausible": self.beyond}
        if self.fold_specs is not None:
            out["fold_effects"] = {str(k): list(v) for k, v in self.fold_specs.items()}
        if self.spec:
            out.update(candidate=self.spec, p_value=self.p_value, passed=self.passed, accepted=self.accepted,
                       reason=self.reason)
        return out


@dataclass
class Step:
    """The current model and its refitted candidates; `accepted` is the verdict (or None)."""

    current: Scored
    refits: list
    level: float

    @property
    def accepted(self) -> Scored | None:
        return next((s for s in self.refits if s.accepted), None)

    def decline(self, why: str) -> None:
        """Take back the accepted candidate (it stays 'passed, not taken', with `why`)."""
        for s in self.refits:
            if s.accepted:
                s.accepted, s.reason = False, f"{s.reason}; {why}"

    def lines(self) -> list[str]:
        """The printed figures of the step (`diagnose` and `discover` print these)."""
        c = self.current
        out = [f"model [{', '.join(c.effects) or 'geometric only'}]: rms {c.rms_mm:.4f} mm, "
               f"refit cv rms {c.cv_rms_mm:.4f} mm"]
        out += _plausibility_lines(c, [])
        for s in self.refits:
            verdict = "accepted" if s.accepted else "passed, not taken" if s.passed else "rejected"
            out.append(f"  + {s.spec:<24} rms {s.rms_mm:.4f} mm, refit cv rms {s.cv_rms_mm:.4f} mm: "
                       f"{verdict} ({s.reason})")
            out += ["  " + ln for ln in _plausibility_lines(s, [] if c.fit is None else list(c.fit.report.held))]
        return out

    def to_dict(self) -> dict:
        return {"current": self.current.to_dict(), "refits": [s.to_dict() for s in self.refits],
                "level": self.level, "accepted": None if self.accepted is None else self.accepted.spec}


def _plausibility_lines(s: Scored, current_held: list) -> list[str]:
    """The held line (only the names beyond `current_held`) and the beyond-plausible line."""
    out = []
    held = [n for n in s.held if n not in current_held]
    if held:
        also = ", besides the current model's" if current_held else ""
        out.append(f"  held at nominal (not identifiable{also}): {', '.join(held)}")
    if s.prior_held:
        out.append(f"  held at nominal (not determined by the data, the prior alone set them): {', '.join(s.prior_held)}")
    if s.beyond:
        out.append(f"  beyond plausible size (shrunk by the prior): {', '.join(s.beyond)}")
    return out


def fit_options(m, *, sigma_mm: float = SIGMA_MM, sigma_deg: float = SIGMA_DEG) -> dict:
    """The options `torchcal fit` fits measurements m with (orientation when measured)."""
    return {"pose": m.pose, "rotation": m.rotation, "sigma_mm": sigma_mm, "sigma_deg": sigma_deg}


def candidate_fit(base: FitResult, spec: str, m, ctx, *, sigma_mm: float, sigma_deg: float,
                  hold=()) -> FitResult:
    """The full fit of the current model plus `spec` on all of m, from the current fit
    (parameters matched by name; the new ones start at zero), with the parameters the
    current fit held still held, and those named in `hold` (the identifiability analysis
    may hold more)."""
    robot = base.model.robot
    specs = [str(s) for s in parse_specs(base.model.specs() + [spec], robot.n)]
    model = CalibrationModel.for_measurements(robot, specs, m)
    names, held = base.model.param_names(), set(base.report.held) | set(hold)
    theta0, free = model.zeros(), model.default_free()
    for i, n in enumerate(model.param_names()):
        if n in names:
            theta0[i] = base.theta[names.index(n)]
        free[i] &= n not in held  # the current model's gauge stays: the same parameters held
    # by chord iterations (`refit.warm_fit`) unless the current fit's own refits needed the LM
    res = None if lm_only(base) else warm_fit(model, ctx, m.xyz, theta0, free,
                                              **fit_options(m, sigma_mm=sigma_mm, sigma_deg=sigma_deg))
    if res is None:  # the chord does not apply: the LM's fit
        res = fit(model, ctx, m.xyz, theta0=theta0, free=free, **fit_options(m, sigma_mm=sigma_mm, sigma_deg=sigma_deg))
    res.report.held = [n for n in model.param_names() if n in held] + res.report.held
    return res


def score_current(base: FitResult, m, ctx, folds: np.ndarray, *, sigma_mm: float = SIGMA_MM,
                  sigma_deg: float = SIGMA_DEG) -> Scored:
    """The current model's figures: its fit and its refit CV."""
    cv = refit_cv(base, m, ctx, folds, sigma_mm=sigma_mm, sigma_deg=sigma_deg)
    return Scored(base.model.specs(), "", base.rms_mm, cv.cv_rms_mm, base, cv)


def score_step(current: Scored, candidates: list, m, ctx, folds: np.ndarray, *, alpha: float = ALPHA,
               min_gain: float = MIN_GAIN, sigma_mm: float = SIGMA_MM, sigma_deg: float = SIGMA_DEG) -> Step:
    """Refit each candidate (`Candidate`s of the pre-screen, in shortlist order) in full,
    cross-validate it on the folds (N,) and decide (module doc; level alpha over the
    candidates refitted)."""
    refits = []
    searches = FoldSearches(current.fit, ctx, folds)  # each joint's fold searches once for the step

    def decide(c, random_only, hold=()):
        f = candidate_fit(current.fit, c.spec, m, ctx, sigma_mm=sigma_mm, sigma_deg=sigma_deg, hold=hold)
        cv, fold_specs = procedure_cv(current, f, c.spec, m, ctx, folds, sigma_mm=sigma_mm, sigma_deg=sigma_deg,
                                      searches=searches)
        ok, p, why = refit_decision(current.cv_rms_mm, current.cv.sq, cv.cv_rms_mm, cv.sq,
                                    n_refits=len(candidates), alpha=alpha, min_gain=min_gain,
                                    random_only=random_only)
        if cv.error:
            ok, why = False, f"fold refit impossible: {cv.error}"
        new = [n for n in f.model.param_names() if n not in current.fit.model.param_names()]
        bad = determination(f, new, ctx) if ok else []
        return f, cv, ok, p, why, new, bad, fold_specs

    for c in candidates:
        random_only = c.significant and not c.deterministic
        try:
            f, cv, ok, p, why, new, bad, fold_specs = decide(c, random_only)
            prior_set, held_now = [d["name"] for d in bad if d["why"] == "prior"], []
            if bad and len(prior_set) == len(bad) and len(prior_set) < len([n for n in new if n not in f.report.held]):
                # some of its parameters only the prior sets (e.g. low harmonics collinear with
                # a joint offset): held at nominal, the rest refitted and judged once more
                f, cv, ok, p, why, new, bad, fold_specs = decide(c, random_only, prior_set)
                why, held_now = why + f"; held at nominal, the prior alone set them: {', '.join(prior_set)}", prior_set
        except InputError as e:
            refits.append(Scored(current.effects + [c.spec], c.spec, float("inf"), float("inf"),
                                 reason=f"refit impossible: {e}"))
            continue
        if ok and bad:  # the data must determine what it adds (module doc)
            ok, why = False, f"{determination_words(bad)} ({why})"
        if ok and new and all(n in f.report.held for n in new):
            ok, why = False, f"not determined: none of its parameters is identifiable from these poses ({why})"
        k = sum(1 for n in new if n not in f.report.held)
        refits.append(Scored(f.model.specs(), c.spec, f.rms_mm, cv.cv_rms_mm, f, cv, p, False, why, ok, random_only, k,
                             held_now, fold_specs))
    best = choose(refits)
    if best is not None:
        best.accepted = True
        for s in refits:
            if s.passed and s is not best:
                s.reason += (f"; {best.spec} gains more (refit cv {best.cv_rms_mm:.4f} mm)" if s.cv_rms_mm > best.cv_rms_mm
                             else f"; {best.spec} is simpler and not worse per pose" if not s.random_only
                             else f"; {best.spec} ranked before it")
    return Step(current, refits, alpha / max(len(candidates), 1))


def choose(refits: list) -> Scored | None:
    """The step's verdict among the refits that passed: of the deterministic ones the
    largest refit gain (lowest refit CV RMS), or a simpler one (fewer new identified
    parameters) that it does not beat significantly per pose (paired held-out squared
    errors, `not_better`), the simplest such; a random-only term (whose variance no refit
    CV shows) only when no deterministic one passed, the first in shortlist order."""
    passed = [s for s in refits if s.passed]
    det = [s for s in passed if not s.random_only]
    if not det:
        return passed[0] if passed else None
    best = min(det, key=lambda s: s.cv_rms_mm)
    simpler = [s for s in det if s.k < best.k and not_better(best.cv, s.cv, "sq", -1.0)]
    return min(simpler, key=lambda s: (s.k, s.cv_rms_mm), default=best)
