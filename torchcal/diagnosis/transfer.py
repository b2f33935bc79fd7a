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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from torchcal.calibration.registration import reregister
from torchcal.diagnosis.crossval import per_pose
from torchcal.diagnosis.selection import MIN_GAIN, REFIT_ALPHA, refit_decision
from torchcal.effects import context_of
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

    def choose(self, current: Transferred, passed: list):
        """The step to keep among `passed` (the round's candidates that met the acceptance
        rule, `Scored`s in rank order): the first that lowers the other session's error
        beyond chance against `current` (the current model's figures; module doc).
        Returns (that `Scored` and its `Transferred`, or (None, None); the record
        {"current_mm", "tried": [{"effect", "after_mm", "refused", "p_value", "reason"}],
        "kept": spec or None})."""
        tried = []
        for s in passed:
            after = self.score(s.fit)
            keep, p, why = refit_decision(current.rms_mm, current.sq, after.rms_mm, after.sq,
                                          n_refits=len(passed), alpha=self.alpha, min_gain=self.min_gain,
                                          random_only=s.random_only)
            tried.append({"effect": s.spec, "after_mm": after.rms_mm, "refused": not keep, "p_value": p,
                          "reason": why.split(": ", 1)[-1]})  # the figures are printed as the transfer's
            if keep:
                return (s, after), {"current_mm": current.rms_mm, "tried": tried, "kept": s.spec}
        return (None, None), {"current_mm": current.rms_mm, "tried": tried, "kept": None}


def describe_verdict(v: dict) -> list[str]:
    """The printed lines of a `TransferCheck.choose` record."""
    out = [f"transfer: current model {v['current_mm']:.3f} mm"]
    for t in v["tried"]:
        fig = f"transfer {v['current_mm']:.3f} -> {t['after_mm']:.3f} mm"
        why = f" ({t['reason']})" if t.get("reason") else ""
        out.append(f"  {t['effect']} refused: helps within the session only: {fig}{why}" if t["refused"]
                   else f"  {t['effect']} kept: {fig}{why}")
    return out
