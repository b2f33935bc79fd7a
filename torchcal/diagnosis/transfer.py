"""Transfer to another session as a check: does a term belong to the robot or to the
session it was fitted in (docs/diagnosis.md, "Transfer to another session")?

A model fitted on one session (one set-up of the laser tracker, one day) is moved into
another session's measuring frame exactly as `torchcal register` does: only the base
frame is re-estimated (`torchcal.calibration.registration.reregister`), on the other
session's first `poses` poses (in measurement order). Its error on the other session's
remaining poses is the transfer figure.

`discover` with a `TransferCheck` keeps a step only when it *lowers* the other session's
held-out error beyond chance, by the rule a refitted candidate meets within the session
(`torchcal.diagnosis.selection.refit_decision`, the same constants): per held-out pose p
of the other session, ``d_p = e0_p - e1_p``, the squared distance error of the current
model minus the candidate's (both registered on the same poses); a one-sided paired
t-test of mean(d) > 0 over those poses at level ``REFIT_ALPHA / R`` (R: the round's
candidates that met the acceptance rule, all of which may be tried), and a relative gain
of at least `MIN_GAIN`. A term that lowers the error within the session but leaves the
other session's as it was (up to chance) or raises it describes that session (its
tracker set-up, its temperature, its order), not the robot: on the UR10 series, series
B's `joint_periodic:3` terms left D's error as it was (0.854 -> 0.849 mm, p 0.21) and
raised C's (0.608 -> 0.617 mm); "not above", the rule before, kept it.

**Per joint part.** A step on several joints (``joint_periodic:1@12,2@20+29,3@18``, one
effect whose parts are `torchcal.diagnosis.stability.part_specs`) bundles terms that may
belong, joint by joint, to the robot or to the session: the other session can gain from
the bundle while one joint's part raises its error. A deterministic step on J >= 2
joints that the rule above keeps is therefore split, the rule decided before any real
series was run with it:

1. Per joint j, the model "the current model + the step without j's part" is refitted
   on the fitting session as the step itself was (`torchcal.diagnosis.step.candidate_fit`
   from the current model, the whole step's held parameters held). It and the whole
   step's model are registered and scored on the other session exactly as `score`
   does, and j's part is kept when ``refit_decision(without j, whole)`` holds: per held-out
   pose, the squared error without j's part minus with it; paired one-sided t-test,
   relative gain >= `MIN_GAIN`, at level ``REFIT_ALPHA / (R J)``. The family: a round
   tries at most R steps (the whole-step tests' Bonferroni), and a step of J joints makes
   J part tests, so all the part tests of a round spend at most
   R * J * REFIT_ALPHA / (R J) = REFIT_ALPHA, the level of the round's step tests: the
   chance that a part which does not lower the other session's error is kept in a round
   stays below REFIT_ALPHA.
2. All parts are tested at once against the same whole step (not by sequential
   removal): one refit per part, and no part's verdict depends on the order or on
   another's. Its weakness: two parts that explain the same structure on the other
   session each look useless while the other stays, and both are dropped; that errs
   towards "session", the side this check exists for. Sequential removal (drop the
   worst, refit, test again) would keep one of them, at up to J(J+1)/2 refits, with tests
   conditional on the earlier drops and a result that depends on the order.
3. The step that lands is the union of the kept parts: all of them, the step as it was;
   some, the current model + their union refitted as in 1 (with its refit CV on the
   session's folds, the next round's current model), which must itself lower the other
   session's error against the current model by the whole-step rule (level
   REFIT_ALPHA / R), and lower this session's refit CV error against the current model by
   the session's own acceptance rule (the same level; it is a model no round has tested
   here; this last test was added after the transfer matrix of docs/real-data.md was
   first run with the rule, and a re-run gave the same figures), or nothing of the step
   lands; none, nothing of the step lands. When
   nothing lands the next step that met the acceptance rule is tried, as for a refused
   step. The parts only narrow a step the whole-step rule kept: a step it refuses is
   not split (a part is never kept from a step whose bundle the other session does not
   gain from).

A step on one joint, and a step significant by its random part only (a variance term,
which the per-pose transfer figures do not show), is decided as a whole, as before.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from torchcal.calibration.fit import SIGMA_DEG, SIGMA_MM, FitResult
from torchcal.calibration.registration import reregister
from torchcal.diagnosis.crossval import per_pose
from torchcal.diagnosis.procedure_cv import procedure_cv
from torchcal.diagnosis.selection import MIN_GAIN, REFIT_ALPHA, refit_decision
from torchcal.diagnosis.stability import part_specs, restricted
from torchcal.diagnosis.step import Scored, candidate_fit
from torchcal.effects import context_of
from torchcal.effects.context import Context
from torchcal.errors import InputError
from torchcal.measurements import Measurements


def first_poses(pose: torch.Tensor, k: int) -> torch.Tensor:
    """(N,) bool: the rows of the first `k` distinct pose ids in measurement order."""
    seen, first = set(), []
    for p in pose.tolist():
        if p not in seen:
            seen.add(p)
            first.append(p)
    return torch.isin(pose, torch.tensor(first[:k], dtype=pose.dtype, device=pose.device))


@dataclass(frozen=True)
class Transferred:
    """A model's transfer figures: rms_mm, the distance RMS over the other session's
    held-out rows; sq (P,) mm^2, per held-out pose (sorted ids) the sum of its rows'
    squared distance errors (the paired test's unit)."""

    rms_mm: float
    sq: np.ndarray


@dataclass(frozen=True)
class TransferCheck:
    """Measurements `m` of another session of the same robot; the model is registered
    (frame only) on the rows of its first `poses` poses and scored on the others.

    Attributes: m, poses (K), source (what to call the session in messages), alpha (the
    family-wise level of a round's transfer tests), min_gain (the relative gain a kept
    step must bring): those of the in-session refit test."""

    m: Measurements
    poses: int = 30
    source: str = "the other session"
    alpha: float = REFIT_ALPHA
    min_gain: float = MIN_GAIN

    def __post_init__(self):
        n_poses = int(self.m.pose.unique().numel())
        if n_poses < 4:
            raise InputError(f"{self.source}: {n_poses} poses are too few for a transfer check (3 to register "
                             f"the frame on, and more to score)")
        if isinstance(self.poses, bool) or not isinstance(self.poses, int) or not 3 <= self.poses < n_poses:
            raise InputError(f"{self.source}: the transfer check registers on its first 3 to {n_poses - 1} "
                             f"poses (of {n_poses}; the others are scored), got {self.poses!r}",
                             fix=("transfer_poses", str(min(30, n_poses - 1))))

    @property
    def registration_rows(self) -> torch.Tensor:
        """(N,) bool: the rows the frame is registered on."""
        return first_poses(self.m.pose, self.poses)

    def describe(self) -> str:
        reg = self.registration_rows
        held = int(self.m.pose[~reg].unique().numel())
        return (f"transfer check: {self.source}, frame registered on its first {self.poses} poses "
                f"({int(reg.sum())} rows), error on the other {held} poses ({int((~reg).sum())} rows); a step "
                f"is kept when it lowers that error beyond chance")

    def score(self, fit) -> Transferred:
        """The transfer figures of a fitted model (`FitResult`) after re-registering its
        base frame on the registration rows."""
        reg = self.registration_rows
        a, b = self.m.subset(reg), self.m.subset(~reg)
        robot = fit.model.robot
        res = reregister(fit.model, fit.theta, context_of(robot, a), a.xyz.to(fit.theta), pose=a.pose)
        with torch.no_grad():
            err = b.xyz.to(fit.theta) - res.model.predict(res.theta, context_of(robot, b))
        sq = err.pow(2).sum(-1).numpy(force=True)  # (N_b,) mm^2
        return Transferred(float(np.sqrt(sq.mean())), per_pose(b, sq))

    def another_tool(self, fit) -> str | None:
        """One line when the other session's held-out rows, the model `fit` (`FitResult`,
        the search's starting fit) registered as `score` registers it, lie beyond 3x its
        rms and a constant offset of the measured point on the tool brings them within a
        third (`torchcal.calibration.checks.model_data.moved_tool`): the session was measured with
        another reflector or nest, whose error the frame-only registration leaves in every
        figure, so that no step can lower them beyond chance. None otherwise."""
        from torchcal.calibration.checks.model_data import moved_tool

        if self.m.point is not None and len(set(self.m.point.tolist())) > 1:
            return None
        reg = self.registration_rows
        a, b = self.m.subset(reg), self.m.subset(~reg)
        robot = fit.model.robot
        res = reregister(fit.model, fit.theta, context_of(robot, a), a.xyz.to(fit.theta), pose=a.pose)
        with torch.no_grad():
            ctx = context_of(robot, b)
            err = b.xyz.to(fit.theta) - res.model.predict(res.theta, ctx)
            rot = res.model.predict_rotation(res.theta, ctx)
        rms = float(err.norm(dim=-1).pow(2).mean().sqrt())
        msg = moved_tool(rms, err, rot, fit.rms_mm, self.source)
        if msg is None:
            return None
        return (msg.split(": measured at")[0] + ": measured with another reflector or nest than the data searched? "
                "The transfer check registers the measuring frame only, so that error stays in every figure and no "
                "step can lower it beyond chance; give a session of the same reflector")

    def choose(self, current: Transferred, passed: list, within: Within | None = None):
        """The step to keep among `passed` (the round's candidates that met the acceptance
        rule, `Scored`s in rank order): the first that lowers the other session's error
        beyond chance against `current` (the current model's figures), a step on several
        joints narrowed to the joints whose part does so on its own (module doc; `within`:
        the fitting session, for the parts' refits; None: every step decided as a whole).

        Returns (the `Scored` that lands, the step itself or the refitted union of its kept
        parts, and its `Transferred`; or (None, None)), and the record {"current_mm",
        "level" (the step tests' level), "tried": [{"effect", "after_mm", "refused",
        "p_value", "reason"}], "kept": the spec that lands or None}. A step split into
        joint parts adds to its "tried" entry "part_level" (the parts' test level),
        "parts": [{"joint", "effect" (the part's spec), "without_mm" (the figure of the
        step without that part; None when it could not be refitted), "kept", "p_value",
        "reason"}] and "landed": None (no part kept) or {"effect", "after_mm", "refused",
        "p_value", "reason"} (the union of the kept parts against the current model; the
        step itself when every part is kept); its "refused" is then true when nothing of
        it lands."""
        tried, level = [], self.alpha / max(len(passed), 1)
        for s in passed:
            after = self.score(s.fit)
            keep, p, why = self._decide(current, after, len(passed), s.random_only)
            tried.append({"effect": s.spec, "after_mm": after.rms_mm, "refused": not keep, "p_value": p,
                          "reason": why})
            parts = {} if not keep or within is None or s.random_only else part_specs(s.spec, s.fit.model.robot.n)
            if keep and parts:
                s, after = self._split(current, s, after, parts, len(passed), within, tried[-1])
                keep = s is not None
            if keep:
                return (s, after), {"current_mm": current.rms_mm, "level": level, "tried": tried, "kept": s.spec}
        return (None, None), {"current_mm": current.rms_mm, "level": level, "tried": tried, "kept": None}

    def _decide(self, base: Transferred, cand: Transferred, n_tests: int, random_only: bool = False):
        """(keep, p-value, reason without the figures, printed as the transfer's) of `cand`
        against `base` on the other session: `refit_decision` at level alpha / n_tests."""
        keep, p, why = refit_decision(base.rms_mm, base.sq, cand.rms_mm, cand.sq, n_refits=n_tests,
                                      alpha=self.alpha, min_gain=self.min_gain, random_only=random_only)
        return keep, p, why.split(": ", 1)[-1]

    def _split(self, current: Transferred, s, whole: Transferred, parts: dict, n_steps: int, within: Within,
               rec: dict):
        """Step `s` (kept as a whole, figures `whole`) judged per joint part (module doc,
        1-3; parts: `part_specs` of s.spec); writes the figures into its record `rec`.
        Returns (the `Scored` that lands, its `Transferred`) or (None, None)."""
        level_n = n_steps * len(parts)
        rec.update(part_level=self.alpha / level_n, parts=[], landed=None)
        held, fits = list(s.fit.report.held), {}  # fits: spec -> refit (one dropped part: the union is its 'without')
        for j, (part, rest) in parts.items():
            try:
                fits[rest] = within.step_fit(rest, held)
                without = self.score(fits[rest])
            except InputError as e:
                rec["parts"].append({"joint": j, "effect": part, "without_mm": None, "kept": False, "p_value": 1.0,
                                     "reason": f"the step without it cannot be refitted: {e}"})
                continue
            keep, p, why = self._decide(without, whole, level_n)
            rec["parts"].append({"joint": j, "effect": part, "without_mm": without.rms_mm, "kept": keep,
                                 "p_value": p, "reason": why})
        kept = [t["joint"] for t in rec["parts"] if t["kept"]]
        if len(kept) == len(parts):
            rec["landed"] = {"effect": s.spec, "after_mm": whole.rms_mm, "refused": False,
                             "p_value": rec["p_value"], "reason": rec["reason"]}
            return s, whole
        if not kept:
            rec["refused"] = True
            return None, None
        union = restricted(s.spec, kept, s.fit.model.robot.n)
        try:
            f = fits[union] if union in fits else within.step_fit(union, held)
        except InputError as e:
            rec["refused"] = True
            rec["landed"] = {"effect": union, "after_mm": None, "refused": True, "p_value": 1.0,
                             "reason": f"refit impossible: {e}"}
            return None, None
        after = self.score(f)
        keep, p, why = self._decide(current, after, n_steps)
        rec["landed"] = {"effect": union, "after_mm": after.rms_mm, "refused": not keep, "p_value": p, "reason": why}
        scored = within.scored(f, union, s.prior_held) if keep else None
        if keep:  # the union is a new model here too: the session's rule
            ok, _, why_in = within.decide(scored, n_steps)
            if not ok:
                keep = False
                rec["landed"].update(refused=True, reason=f"{why}; within the session: {why_in}")
        rec["refused"] = not keep
        return (scored, after) if keep else (None, None)


@dataclass(frozen=True)
class Within:
    """The session `discover` fits, for the per-part refits of a step on several joints:
    the current model `current` (`Scored`: its fit, the base of every refit, and its refit
    CV, what the union of kept parts must beat), measurements m, context ctx, folds (N,)
    int (the refit CV's folds by pose), sigma_mm / sigma_deg (`fit`'s orientation
    weighting)."""

    current: Scored
    m: Measurements
    ctx: Context
    folds: np.ndarray
    sigma_mm: float = SIGMA_MM
    sigma_deg: float = SIGMA_DEG

    def decide(self, cand: Scored, n_tests: int):
        """(keep, p, reason) of `cand` against the current model by the session's own
        acceptance rule (`refit_decision` on the refit CV, level REFIT_ALPHA / n_tests)."""
        c = self.current
        return refit_decision(c.cv_rms_mm, c.cv.sq, cand.cv_rms_mm, cand.cv.sq, n_refits=n_tests,
                              alpha=REFIT_ALPHA, min_gain=MIN_GAIN)

    def step_fit(self, spec: str, hold) -> FitResult:
        """The current model + the step `spec` fitted on the session as `discover` fits a
        step (`candidate_fit`), the parameters named in `hold` held."""
        return candidate_fit(self.current.fit, spec, self.m, self.ctx, sigma_mm=self.sigma_mm, sigma_deg=self.sigma_deg,
                             hold=hold)

    def scored(self, f: FitResult, spec: str, prior_held) -> Scored:
        """The step `spec` (fitted: f) as the next round's current model: with its refit CV
        on the session's folds; prior_held: the names the prior alone set in the step it
        was cut from (those f still has)."""
        cv, fold_specs = procedure_cv(self.current, f, spec, self.m, self.ctx, self.folds, sigma_mm=self.sigma_mm,
                                      sigma_deg=self.sigma_deg)  # as the step's own refit CV (procedure_cv.py)
        names = f.model.param_names()
        return Scored(f.model.specs(), spec, f.rms_mm, cv.cv_rms_mm, f, cv, accepted=True, passed=True,
                      reason="the joints whose part lowers the other session's error",
                      prior_held=[n for n in prior_held if n in names], fold_specs=fold_specs)


def describe_verdict(v: dict) -> list[str]:
    """The printed lines of a `TransferCheck.choose` record."""
    out = [f"transfer: current model {v['current_mm']:.3f} mm"]
    for t in v["tried"]:
        fig = f"transfer {v['current_mm']:.3f} -> {t['after_mm']:.3f} mm"
        why = f" ({t['reason']})" if t.get("reason") else ""
        if t["refused"] and "parts" not in t:
            out.append(f"  {t['effect']} refused: helps within the session only: {fig}{why}")
        elif "parts" not in t:
            out.append(f"  {t['effect']} kept: {fig}{why}")
        else:
            out += _describe_parts(v["current_mm"], t, fig, why)
    return out


def _describe_parts(current_mm: float, t: dict, fig: str, why: str) -> list[str]:
    """The lines of a step judged per joint part (a "tried" entry with "parts")."""
    out = [f"  {t['effect']} lowers it as a whole: {fig}{why}; per joint, the step without that joint's part "
           f"-> the whole step (level {t['part_level']:.2g}):"]
    for p in t["parts"]:
        fig_p = "" if p["without_mm"] is None else f": transfer {p['without_mm']:.3f} -> {t['after_mm']:.3f} mm"
        out.append(f"    joint {p['joint']} {p['effect']} {'kept' if p['kept'] else 'dropped'}{fig_p} ({p['reason']})")
    landed = t["landed"]
    if landed is None:
        out.append(f"  {t['effect']} refused: no joint's part lowers it on its own")
    elif landed["effect"] == t["effect"]:
        out.append(f"  {t['effect']} kept: every joint's part lowers it")
    else:
        dropped = [str(p["joint"]) for p in t["parts"] if not p["kept"]]
        dropped = f"joint{'s' if len(dropped) > 1 else ''} {', '.join(dropped)}"
        fig_l = "" if landed["after_mm"] is None else f": transfer {current_mm:.3f} -> {landed['after_mm']:.3f} mm"
        out.append(f"  {landed['effect']} {'refused' if landed['refused'] else 'kept'} (the step without "
                   f"{dropped}, refitted){fig_l} ({landed['reason']})")
    return out
