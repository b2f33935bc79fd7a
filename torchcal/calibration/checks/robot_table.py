"""The robot file's own table mistaken, named when data refused as another robot fit
once it is corrected: a table in Craig's modified D-H convention (`proximal_table`) or
one length (d or a) mistyped (`length_typo`)."""

from __future__ import annotations

import dataclasses

import torch

from torchcal.calibration.checks.frame_fit import fits_in_a_frame
from torchcal.calibration.checks.verdict import rms_of
from torchcal.errors import InputError

TYPO_MIN_MM = 1.0  # a length off by less is a calibration's business, not a typo
TYPO_TRIES = 2  # best-scored lengths given a full frame fit
TWIN_REL = 1e-6  # lengths whose changes score this alike move the points alike (d of parallel joints)


def _with_table(model, table):
    """`model` (its effects and point ids) on its robot with the MD-H table `table` (n, 5)."""
    from torchcal.calibration.model import CalibrationModel

    return CalibrationModel(dataclasses.replace(model.robot, table=table), model.specs(),
                            points=model.point_ids or None)


def proximal_table(model, m) -> bool:
    """Whether the measurements `m` come within GROSS_MM (`fits_in_a_frame`) of `model`'s
    robot read as a table in Craig's modified D-H convention
    (`torchcal.robots.checks.distal_from_proximal`; the model's effects kept), where they
    do not as read: a data sheet's proximal table typed into a robot file."""
    from torchcal.calibration.model import CalibrationModel
    from torchcal.robots.checks import distal_from_proximal

    if model.robot.n < 2:
        return False
    try:
        other = CalibrationModel(distal_from_proximal(model.robot), model.specs(), points=model.point_ids or None)
    except InputError:
        return False
    return fits_in_a_frame(other, m)


def length_typo(model, m) -> list | None:
    """[(joint (1-based), "d_mm" or "a_mm", the file's value, the value that fits), ...]
    when the measurements `m` come within GROSS_MM of `model`'s robot with one length
    changed by at least TYPO_MIN_MM (a digit mistyped: 452 for 425), else None. Each of the
    2n lengths is scored cheaply: the nominal points move linearly with it, so the best
    change is one least-squares step in the rigid (Kabsch) frame of the nominal points,
    scored by the Kabsch RMS; the TYPO_TRIES best get a full frame and tool fit. The
    lengths whose changes score the same (within TWIN_REL: the d of joints on parallel
    axes, which move the points alike) are listed after it: the data cannot tell which."""
    from torchcal.effects import context_of
    from torchcal.rotations import kabsch

    table = model.robot.table
    ctx = context_of(model.robot, m)

    def points(t):
        with torch.no_grad():
            return _with_table(model, t).predict(model.zeros().to(m.xyz), ctx)

    def rigid_rms(p):
        R, t = kabsch(p, m.xyz)
        return rms_of((p @ R.T + t - m.xyz).norm(dim=-1))

    try:
        p0 = points(table)
        R, t = kabsch(p0, m.xyz)
        r = m.xyz - (p0 @ R.T + t)
        scored = []
        for j in range(table.shape[0]):
            for col, key in ((1, "d_mm"), (2, "a_mm")):
                moved = table.clone()
                moved[j, col] += 1.0
                g = (points(moved) - p0) @ R.T  # mm per mm of the length, in the data's frame
                g, rc = g - g.mean(0), r - r.mean(0)
                gg = float((g * g).sum())
                if gg < 1e-12:
                    continue
                step = float((g * rc).sum()) / gg
                if abs(step) < TYPO_MIN_MM:
                    continue
                moved[j, col] = table[j, col] + step
                scored.append((rigid_rms(points(moved)), j, col, key, moved))
        scored.sort(key=lambda c: c[0])
        for i, (s, j, col, key, moved) in enumerate(scored[:TYPO_TRIES]):
            if fits_in_a_frame(_with_table(model, moved), m):
                return [(j2 + 1, k2, float(table[j2, c2]), float(t2[j2, c2]))
                        for s2, j2, c2, k2, t2 in [scored[i]] + [c for c in scored if c is not scored[i]]
                        if abs(s2 - s) <= s * TWIN_REL + 1e-9]
    except InputError:
        return None
    return None
