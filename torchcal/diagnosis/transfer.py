"""Transfer to another session as a check: does a term belong to the robot or to the
session it was fitted in (docs/diagnosis.md, "Transfer to another session")?

A model fitted on one session (one set-up of the laser tracker, one day) is moved into
another session's measuring frame exactly as `torchcal register` does: only the base
frame is re-estimated (`torchcal.calibration.registration.reregister`), on the other
session's first `poses` poses (in measurement order). Its error on the other session's
remaining poses is the transfer figure. `discover` with a `TransferCheck` accepts a step
only when the transfer figure of the new model is not above that of the current one: a
term that lowers the error within the session but raises it on the other session
describes that session (its tracker set-up, its temperature, its order), not the robot.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchcal.calibration.registration import reregister
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
class TransferCheck:
    """Measurements `m` of another session of the same robot; the model is registered
    (frame only) on the rows of its first `poses` poses and scored on the others.

    Attributes: m, poses (K), source (what to call the session in messages)."""

    m: Measurements
    poses: int = 30
    source: str = "the other session"

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
                f"({int(reg.sum())} rows), error on the other {held} poses ({int((~reg).sum())} rows)")

    def rms_mm(self, fit) -> float:
        """Distance RMS (mm) on the held-out rows of the other session of a fitted model
        (`FitResult`) after re-registering its base frame on the registration rows."""
        reg = self.registration_rows
        a, b = self.m.subset(reg), self.m.subset(~reg)
        robot = fit.model.robot
        xyz = a.xyz.to(fit.theta)
        res = reregister(fit.model, fit.theta, context_of(robot, a), xyz, pose=a.pose)
        with torch.no_grad():
            err = b.xyz.to(fit.theta) - res.model.predict(res.theta, context_of(robot, b))
        return float(err.norm(dim=-1).pow(2).mean().sqrt())

    def choose(self, current_mm: float, passed: list):
        """The step to keep among `passed` (the round's candidates that met the acceptance
        rule, `Scored`s in rank order): the first whose transfer figure is not above
        `current_mm` (the current model's). Returns (that `Scored` or None, the record
        {"current_mm", "tried": [{"effect", "after_mm", "refused"}], "kept": spec or None}).
        """
        tried = []
        for s in passed:
            after = self.rms_mm(s.fit)
            tried.append({"effect": s.spec, "after_mm": after, "refused": after > current_mm})
            if after <= current_mm:
                return s, {"current_mm": float(current_mm), "tried": tried, "kept": s.spec}
        return None, {"current_mm": float(current_mm), "tried": tried, "kept": None}


def describe_verdict(v: dict) -> list[str]:
    """The printed lines of a `TransferCheck.choose` record."""
    out = [f"transfer: current model {v['current_mm']:.3f} mm"]
    for t in v["tried"]:
        fig = f"transfer {v['current_mm']:.3f} -> {t['after_mm']:.3f} mm"
        out.append(f"  {t['effect']} refused: helps within the session only: {fig}" if t["refused"]
                   else f"  {t['effect']} kept: {fig}")
    return out
