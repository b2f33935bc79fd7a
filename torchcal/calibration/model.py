"""`CalibrationModel`: the geometric MD-H deviations plus a list of physical effects.

One flat parameter vector ``theta (P,)`` holds, in order, the 5n geometric deviations
(joint 1's [dtheta rad, dd mm, da mm, dalpha rad, dbeta rad], joint 2's, ...) and then
each effect's parameters in the order of `effects`. `predict(theta, ctx)` gives the TCP
positions (N, 3) mm in the measurement frame:

1. joint offsets of the effects are added to the commanded angles;
2. MD-H chain with the geometric deviations (+ per-row ones such as thermal growth)
   and the tool point (+ tool offsets);
3. thermal scale of the chain, robot base, load-driven displacements (clearance);
4. base_frame maps to the measurement frame.
"""

from __future__ import annotations

import torch

from torchcal.kinematics import mdh as K
from torchcal.effects import Effect, build
from torchcal.effects.base import Context
from torchcal.robots.robot import Robot


class CalibrationModel:
    """Geometric model + effects for one robot. Holds no fitted values (see FitResult)."""

    def __init__(self, robot: Robot, effects=()):
        self.robot = robot
        self.effects: list[Effect] = [e if isinstance(e, Effect) else build(e, robot) for e in effects]
        sizes = [5 * robot.n] + [e.n_params for e in self.effects]
        bounds = torch.tensor([0] + sizes).cumsum(0).tolist()
        self.slices = [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]

    @property
    def n_params(self) -> int:
        return self.slices[-1].stop

    def specs(self) -> list[str]:
        return [e.spec() for e in self.effects]

    def param_names(self) -> list[str]:
        return self.robot.param_names() + [n for e in self.effects for n in e.param_names()]

    def param_units(self) -> list[str]:
        geo = [u for _ in range(self.robot.n) for u in K.PARAM_UNITS]
        return geo + [u for e in self.effects for u in e.param_units()]

    def default_free(self) -> torch.Tensor:
        """(P,) bool: geometric deviations (dbeta only where the table declares beta) and
        every effect parameter. Identification may hold more of them."""
        free = torch.ones(self.n_params, dtype=torch.bool)
        geo = free[: 5 * self.robot.n].view(self.robot.n, 5)
        geo[:, 4] = self.robot.has_beta
        return free

    def zeros(self) -> torch.Tensor:
        return torch.zeros(self.n_params, dtype=self.robot.dtype, device=self.robot.device)

    def check_context(self, ctx: Context) -> None:
        for e in self.effects:
            e.check_context(ctx)

    def predict(self, theta: torch.Tensor, ctx: Context) -> torch.Tensor:
        """TCP positions (N, 3) mm for parameters theta (P,) and the rows of ctx."""
        robot = self.robot
        geo = theta[self.slices[0]].reshape(robot.n, 5)
        q = ctx.q
        tool = robot.tool[:3, 3].to(theta)
        scale = None
        parts = list(zip(self.effects, self.slices[1:]))
        for e, sl in parts:
            p = theta[sl]
            dq = e.joint_offset(p, ctx)
            if dq is not None:
                q = q + dq
            g = e.geometric_offset(p, ctx)
            if g is not None:
                geo = geo + g  # (N, n, 5): per-row deviations
            t = e.tool_point(p, ctx)
            if t is not None:
                tool = tool + t
            s = e.chain_scale(p, ctx)
            if s is not None:
                scale = s if scale is None else scale * s
        v = K._positions_kernel(q, robot.table.to(theta), geo, None, tool, prismatic=robot.pris)  # (N, 3)
        if scale is not None:
            v = v * scale.unsqueeze(-1)
        base = robot.base.to(theta)
        v = v @ base[:3, :3].T + base[:3, 3]
        for e, sl in parts:
            dv = e.displacement(theta[sl], ctx, v)
            if dv is not None:
                v = v + dv
        for e, sl in parts:
            w = e.world(theta[sl], ctx, v)
            if w is not None:
                v = w
        return v

    def jacobian(self, theta: torch.Tensor, ctx: Context) -> torch.Tensor:
        """d predict / d theta: (N, 3, P), forward mode (P is small, N*3 large)."""
        return torch.func.jacfwd(lambda t: self.predict(t, ctx))(theta)
