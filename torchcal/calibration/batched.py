"""The calibration model evaluated for B zones at once (one parameter vector per zone).

`batched_predict` / `batched_jacobian` stack per-zone contexts with equal row counts and
evaluate ``x (B, P)``: geometric-only models through the MD-H kernel with a broadcast
parameter batch, models with effects by vmap of `CalibrationModel.predict` and the
analytic `CalibrationModel.jacobian` per zone: the batched LM of benchmarks/bench_identify.py
(the calibration itself fits zone after zone with `torchcal.calibration.fit.fit`).
Units: parameters as in `CalibrationModel.param_units` (rad, mm); positions mm.
"""

from __future__ import annotations

import torch

from torchcal.kinematics import mdh as K
from torchcal.effects.context import Context
from torchcal.calibration.model import CalibrationModel

__all__ = ["batched_predict", "batched_jacobian"]


def _stack_contexts(ctxs: list[Context]) -> dict:
    """Stack per-zone contexts with equal row counts into (B, m, ...) tensors."""
    out = {"q": torch.stack([c.q for c in ctxs]), "payload": torch.stack([c.payload_kg for c in ctxs]),
           "approach": torch.stack([c.approach for c in ctxs]), "frames": torch.stack([c.frames for c in ctxs]),
           "gravity": ctxs[0].gravity}
    temps = [c.temp_c for c in ctxs]
    out["temp"] = None if any(t is None for t in temps) else torch.stack(temps)
    return out


def batched_predict(model: CalibrationModel, x: torch.Tensor, ctxs: list[Context]) -> torch.Tensor:
    """Model positions for B zones at once: x (B, P), ctxs B contexts of m rows -> (B, m, 3) mm.

    Geometric-only models use the MD-H kernel with a broadcast parameter batch; models
    with effects vmap `CalibrationModel.predict` over the zones.
    """
    st = _stack_contexts(ctxs)
    robot = model.robot
    if not model.effects:
        geo = x[:, : 5 * robot.n].reshape(-1, 1, robot.n, 5)  # (B, 1, n, 5)
        return K.positions(st["q"].to(x), robot.chain.to(x), geo)
    g = st["gravity"]
    if st["temp"] is None:
        def one(th, q, pl, ap, fr):
            return model.predict(th, Context(q, pl, None, ap, fr, g))
        return torch.func.vmap(one)(x, st["q"], st["payload"], st["approach"], st["frames"])

    def one_t(th, q, pl, tc, ap, fr):
        return model.predict(th, Context(q, pl, tc, ap, fr, g))
    return torch.func.vmap(one_t)(x, st["q"], st["payload"], st["temp"], st["approach"], st["frames"])


def batched_jacobian(model: CalibrationModel, x: torch.Tensor, ctxs: list[Context]) -> torch.Tensor:
    """d positions / d x for B zones: (B, m, 3, P).

    Geometric-only models: the analytic MD-H parameter Jacobian (docs/paper.md eq. 17)
    with a broadcast parameter batch; otherwise the analytic `CalibrationModel.jacobian`
    zone by zone.
    """
    robot = model.robot
    if not model.effects:
        st = _stack_contexts(ctxs)
        geo = x[:, : 5 * robot.n].reshape(-1, 1, robot.n, 5)
        return K.param_jacobian(st["q"].to(x), robot.chain.to(x), geo)
    return torch.stack([model.jacobian(xb, c) for xb, c in zip(x, ctxs)])
