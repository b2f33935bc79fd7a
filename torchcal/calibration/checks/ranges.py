"""Rows beyond what a model was fitted on: the calibrated joint range (`range_warning`,
`warn_outside_range`: rows or converged commands beyond the range of
`torchcal.calibration.joint_range`, counted and named in one `CalibratedRangeWarning`) and
the fitted temperature or payload (`warn_outside_conditions`, one `ConditionRangeWarning`):
the model extrapolates there. No payload given to a model fitted on loads
(`payload_conditions`, one `PayloadAssumedWarning`): read as an unloaded arm.
"""

from __future__ import annotations

import warnings

import torch


def range_warning(q: torch.Tensor, q_range: torch.Tensor | None, robot, what: str | None = "rows",
                  max_joints: int = 3) -> tuple[int, str | None]:
    """(number of rows of q (N, n) rad / mm outside q_range, one-line message or None).

    q_range None (a model file written before torchcal recorded it): (0, None). The
    message names each offending joint (up to `max_joints`) with its farthest value and
    the calibrated range, in deg (mm for a prismatic joint); `what` None: those joints alone."""
    from torchcal.calibration.joint_range import outside_range

    if q_range is None or q.shape[0] == 0:
        return 0, None
    out = outside_range(q, q_range, robot.prismatic)  # (N, n)
    rows = int(out.any(1).sum())
    if rows == 0:
        return 0, None
    r = q_range.to(q)
    dist = torch.where(out, torch.maximum(r[0] - q, q - r[1]), torch.full_like(q, -1.0))
    worst = dist.argmax(0)  # (n,) row farthest outside per joint
    qu = robot.q_to_user(q.detach().to("cpu", torch.float64))
    ru = robot.q_to_user(r.detach().to("cpu", torch.float64))
    units = robot.joint_units()
    joints = out.any(0).nonzero().flatten().tolist()
    parts = [f"joint {j + 1}: {qu[int(worst[j]), j].item():.1f} {units[j]}, calibrated "
             f"{ru[0, j].item():.1f} .. {ru[1, j].item():.1f} {units[j]}" for j in joints[:max_joints]]
    more = f"; and {len(joints) - max_joints} more joint(s)" if len(joints) > max_joints else ""
    if what is None:  # the joints alone
        return rows, f"{'; '.join(parts)}{more}"
    msg = (f"{rows} of {q.shape[0]} {what} lie outside the calibrated joint range "
           f"({'; '.join(parts)}{more}); the model extrapolates there")
    return rows, msg


def warn_outside_range(q: torch.Tensor, q_range, robot, what: str, stage=None, stacklevel: int = 1) -> int:
    """Rows of q (N, n) rad / mm outside the calibrated range q_range (2, n) (None: not
    recorded, 0); one `CalibratedRangeWarning` when any (saying so when a residual stage
    `stage` is applied there). stacklevel: as for `warnings.warn`, counted from the caller."""
    from torchcal.calibration.joint_range import CalibratedRangeWarning

    count, msg = range_warning(q, q_range, robot, what)
    if msg is not None and stage is not None:
        msg += "; its non-physical residual stage extrapolates worst of all"
    if msg is not None:
        warnings.warn(msg, CalibratedRangeWarning, stacklevel=stacklevel + 1)
    return count


def warn_outside_conditions(ranges: dict | None, values: dict, what: str, stacklevel: int = 1) -> int:
    """Rows (`what`: "rows", "targets", ...) whose temperature or payload `values`
    ({"temp_c", "payload_kg"}: (N,) tensors, numbers or None) lie outside the range the
    model was fitted on (`ranges`: FitResult.conditions; None: not recorded, 0); one
    `ConditionRangeWarning` naming each such condition, its fitted range, how many rows
    and the farthest value. Returns the most rows outside for one condition."""
    from torchcal.calibration.joint_range import ConditionRangeWarning, conditions_outside

    found = conditions_outside(ranges, values)
    if not found:
        return 0
    parts = [f"{words} of {n_out} of {n} {what} outside the fitted {lo:.4g} .. {hi:.4g} {unit} (farthest {far:.4g} {unit})"
             for words, unit, lo, hi, n_out, n, far in found]
    warnings.warn(f"{'; '.join(parts)}: the model extrapolates its {' and '.join(f[0] for f in found)} "
                  f"effects there", ConditionRangeWarning, stacklevel=stacklevel + 1)
    return max(f[4] for f in found)


class PayloadAssumedWarning(UserWarning):
    """Targets or rows without a payload for a model whose effects read it and were fitted on loads."""


def payload_conditions(fitted, payload_kg, where: str, done: str = "compensated for", stacklevel: int = 1):
    """The condition ranges (``fitted.conditions``) `warn_outside_conditions` should judge,
    after one `PayloadAssumedWarning` when targets (or rows: `done` "evaluated at") give no
    payload (`payload_kg` None: read as 0 kg, as `torchcal.effects.make_context` does) to a
    model whose effects read the payload and whose calibration data carried loads: its
    recorded payload range (kg) reaches beyond the condition tolerance (max(1 % of its span,
    0.1 kg)). The commands (or model points) are then those of an unloaded arm; the range
    is then returned without its payload (the line has named it: not a second line saying
    that 0 kg lies outside it)."""
    from torchcal.calibration.joint_range import CONDITIONS, RANGE_TOL_FRACTION

    ranges = getattr(fitted, "conditions", None)
    rng = (ranges or {}).get("payload_kg")
    if payload_kg is not None or rng is None:
        return ranges
    lo, hi = rng
    floor = next(c[4] for c in CONDITIONS if c[0] == "payload_kg")
    if hi <= max(RANGE_TOL_FRACTION * (hi - lo), floor):  # fitted unloaded: 0 kg is the data's
        return ranges
    effects = ", ".join(e.spec() for e in fitted.model.effects if e.uses_payload)
    warnings.warn(f"{where}: no payload_kg column: {done} 0 kg, but the model's {effects} was fitted on "
                  f"payloads {lo:.4g} .. {hi:.4g} kg and deflects with the load; give the payload the robot "
                  f"{'will carry' if done.startswith('comp') else 'carried'} (column payload_kg, kg)",
                  PayloadAssumedWarning, stacklevel=stacklevel + 1)
    return {k: v for k, v in ranges.items() if k != "payload_kg"}
