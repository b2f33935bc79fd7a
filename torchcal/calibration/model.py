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

`predict_rotation` gives the TCP orientation (N, 3, 3) in the measurement frame (chain
with the deviations, nominal tool rotation, base_frame rotation) for measured
orientations. With several measured points per pose (`points`), `tool_offset` holds one
offset per point id.
"""

from __future__ import annotations

import math

import torch

from torchcal.kinematics import mdh as K
from torchcal.effects import Effect, build
from torchcal.effects.context import Context
from torchcal.robots.robot import Robot


class CalibrationModel:
    """Geometric model + effects for one robot. Holds no fitted values (see FitResult)."""

    def __init__(self, robot: Robot, effects=(), points=None):
        self.robot = robot
        self.effects: list[Effect] = [e if isinstance(e, Effect) else build(e, robot) for e in effects]
        self.points: tuple = ()
        # the point ids of the data it was made for (one or several; () unknown), recorded in MODEL.json
        self.point_ids: tuple = () if points is None else tuple(sorted({int(p) for p in points}))
        if points is not None:
            for e in self.effects:
                if hasattr(e, "set_points"):
                    e.set_points(points)
                    self.points = e.points
        sizes = [5 * robot.n] + [e.n_params for e in self.effects]
        bounds = torch.tensor([0] + sizes).cumsum(0).tolist()
        self.slices = [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]

    @classmethod
    def for_measurements(cls, robot: Robot, effects, m) -> "CalibrationModel":
        """The model of `effects` for the data `m` (`Measurements`): with several `point`
        ids, one tool offset per point (InputError when `effects` lacks tool_offset), so
        that fit, diagnose and discover start from the same model."""
        from torchcal.calibration.checks.row_order import check_row_order
        from torchcal.errors import InputError

        specs = [str(s) for s in effects]
        points = None if m.point is None else sorted(set(m.point.tolist()))
        if points is not None and len(points) > 1 and not any(s.split(":")[0] == "tool_offset" for s in specs):
            raise InputError(f"{m.source or 'measurements'}: {len(points)} measured points per pose (point column) "
                             "need one tool offset each: add tool_offset to the effects")
        check_row_order(m, specs)  # backlash on rows sorted after the session: one warning
        return cls(robot, specs, points=points)

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

    def lower_bounds(self) -> torch.Tensor:
        """(P,) lowest physical value of each parameter (-inf: none; an effect's
        `Effect.lower_bounds`, e.g. 0 for backlash), the dtype and device of `zeros`."""
        lo = torch.full((self.n_params,), -math.inf, dtype=self.robot.dtype, device=self.robot.device)
        for e, sl in zip(self.effects, self.slices[1:]):
            b = getattr(e, "lower_bounds", lambda: None)()
            if b is not None:
                lo[sl] = torch.as_tensor(b, dtype=lo.dtype, device=lo.device)
        return lo

    def zeros(self) -> torch.Tensor:
        return torch.zeros(self.n_params, dtype=self.robot.dtype, device=self.robot.device)

    def check_context(self, ctx: Context) -> None:
        for e in self.effects:
            e.check_context(ctx)

    def predict_rotation(self, theta: torch.Tensor, ctx: Context) -> torch.Tensor:
        """TCP orientations (N, 3, 3), measurement frame <- tool frame (the robot's nominal
        tool rotation), for parameters theta (P,): MD-H chain with the deviations and
        joint offsets of the effects, then the base_frame rotation."""
        robot = self.robot
        geo = theta[self.slices[0]].reshape(robot.n, 5)
        q = ctx.q
        parts = list(zip(self.effects, self.slices[1:]))
        for e, sl in parts:
            dq = e.joint_offset(theta[sl], ctx)
            if dq is not None:
                q = q + dq
            g = e.geometric_offset(theta[sl], ctx)
            if g is not None:
                geo = geo + g
        R = K.fk_rotation(q, robot.chain.to(theta).flange, geo) @ robot.tool[:3, :3].to(theta)
        for e, sl in parts:
            w = e.world_rotation(theta[sl], ctx)
            if w is not None:
                R = w @ R
        return R

    def _chain_inputs(self, theta: torch.Tensor, ctx: Context):
        """What the effects' hooks give the chain walk at theta (P,): joint angles q (N, n)
        rad, deviations geo (n, 5) or (N, n, 5), tool point (3,) or (N, 3) mm, the chain's
        scale (N,) or None, and the (effect, slice) pairs."""
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
        return q, geo, tool, scale, parts

    def _placed(self, v: torch.Tensor, scale, theta: torch.Tensor, ctx: Context, parts) -> torch.Tensor:
        """Positions v (N, 3) mm in the joint-1 frame -> the measurement frame: the chain's
        scale, the robot's base, then the effects' displacements and world maps."""
        if scale is not None:
            v = v * scale.unsqueeze(-1)
        base = self.robot.base.to(theta)
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

    def predict(self, theta: torch.Tensor, ctx: Context) -> torch.Tensor:
        """TCP positions (N, 3) mm for parameters theta (P,) and the rows of ctx."""
        q, geo, tool, scale, parts = self._chain_inputs(theta, ctx)
        v = K.positions(q, self.robot.chain.to(theta).local, geo, tool_point=tool)  # (N, 3), joint-1 frame
        return self._placed(v, scale, theta, ctx, parts)

    def predict_pose(self, theta: torch.Tensor, ctx: Context) -> tuple[torch.Tensor, torch.Tensor]:
        """(`predict` (N, 3) mm, `predict_rotation` (N, 3, 3)) at theta (P,), from one pass
        over the effects' hooks and one walk of the chain (`torchcal.kinematics.mdh.tcp_frame`):
        the same numbers to rounding (the base applied after the walk, the positions
        from the walked frames), about 0.85x the time of the two."""
        robot = self.robot
        q, geo, tool, scale, parts = self._chain_inputs(theta, ctx)
        v, R = K.tcp_frame(q, robot.chain.to(theta).local, geo, tool_point=tool)  # joint-1 frame
        v = self._placed(v, scale, theta, ctx, parts)
        R = R @ robot.tool[:3, :3].to(theta)
        if not robot.chain.plain_base:
            R = robot.base[:3, :3].to(theta) @ R
        for e, sl in parts:
            w = e.world_rotation(theta[sl], ctx)
            if w is not None:
                R = w @ R
        return v, R

    def jacobian(self, theta: torch.Tensor, ctx: Context) -> torch.Tensor:
        """d predict / d theta (N, 3, P), mm per unit of each parameter, analytic.

        The chain rule through the steps of `predict`: the MD-H kernel's derivatives
        w.r.t. q, the deviations and the tool point (`torchcal.kinematics.mdh.chain_jacobians`),
        times each effect's hook companions (`torchcal.effects.base`; forward-mode
        autodiff of the hook alone for an effect that gives none).
        """
        return self.jacobians(theta, ctx)[0]

    def rotation_jacobian(self, theta: torch.Tensor, ctx: Context) -> torch.Tensor:
        """Angular velocity (N, 3, P) rad per unit of each parameter of the frame of
        `predict_rotation`, measurement frame: d R / d theta_k = [W[..., k]]x R."""
        return self.jacobians(theta, ctx, rotation=True)[1]

    def jacobians(self, theta: torch.Tensor, ctx: Context, *, rotation: bool = False, frame: bool = False,
                  position: bool = False, out: torch.Tensor | None = None):
        """(J (N, 3, P) of `jacobian`, W (N, 3, P) of `rotation_jacobian` or None); with
        `frame` also R (N, 3, 3), the orientations of `predict_rotation` (from the same
        chain walk, so the fit's orientation rows need no second one); with `position`
        last the TCP positions (N, 3) mm of `predict` from the same walk (equal to
        `predict`'s to rounding: another order of the same products). out: an (N, 3, P)
        tensor (a view of the caller's buffer) that receives J and is returned as J."""
        robot = self.robot
        n, P = robot.n, self.n_params
        geo = theta[self.slices[0]].reshape(n, 5)
        q = ctx.q
        tool = robot.tool[:3, 3].to(theta)
        parts = list(zip(self.effects, self.slices[1:]))
        # per hook: the inputs of the chain it adds to, and (slice, value, companion) per effect
        terms = {"joint_offset": [], "geometric_offset": [], "tool_point": [], "chain_scale": []}
        cols_q = []  # (slice, joint index (k,), values (N, k)): joint offsets one joint per parameter
        for e, sl in parts:
            p = theta[sl]
            for hook, found in terms.items():
                value = getattr(e, hook)(p, ctx)
                if value is None:
                    continue
                cols = e.joint_offset_columns(p, ctx) if hook == "joint_offset" else None
                if cols is not None:
                    cols_q.append((sl, *cols))
                    found.append((sl, value, None))
                else:
                    found.append((sl, value, getattr(e, hook + "_jacobian")(p, ctx)))
        q = q + sum(v for _, v, _ in terms["joint_offset"])
        geo = geo + sum(v for _, v, _ in terms["geometric_offset"])  # (N, n, 5) with per-row terms
        tool = tool + sum(v for _, v, _ in terms["tool_point"])
        d_q, d_geo, d_tool = ([(sl, D) for sl, _, D in terms[h] if D is not None]
                              for h in ("joint_offset", "geometric_offset", "tool_point"))
        scales = terms["chain_scale"]
        cj = K.chain_jacobians(q, robot.chain.to(theta).local, geo, tool_point=tool)
        N = q.shape[0]
        # the effects' columns start at zero and are added to: only they are zeroed
        J = theta.new_empty(N, 3, P) if out is None else out
        J[..., : 5 * n] = cj.dparams
        J[..., 5 * n:].zero_()
        W = None
        if rotation:
            W = theta.new_empty(N, 3, P)
            W[..., : 5 * n] = cj.wparams
            W[..., 5 * n:].zero_()
        for sl, D in d_q:  # (N, n, k)
            J[..., sl] += cj.dq @ D
            if rotation:
                W[..., sl] += cj.wq @ D
        for sl, idx, vals in cols_q:  # cj.dq @ D for the D of `joint_offset_columns`
            for j, a, b in _runs(idx):  # a joint's parameters a..b-1: its dq column times their values
                cols = slice(sl.start + a, sl.start + b)
                J[..., cols].addcmul_(cj.dq[:, :, j, None], vals[:, None, a:b])  # in place, no temporary
                if rotation:
                    W[..., cols].addcmul_(cj.wq[:, :, j, None], vals[:, None, a:b])
        for sl, G in d_geo:  # (N, n, 5, k)
            G = G.reshape(N, 5 * n, -1)
            J[..., sl] += cj.dparams @ G
            if rotation:
                W[..., sl] += cj.wparams @ G
        for sl, T in d_tool:  # (3, k) or (N, 3, k)
            J[..., sl] += _rows_times(cj.rotation, T) if T.dim() == 3 else _times_shared(cj.rotation, T)
        v = cj.position
        if scales:
            total = torch.stack([s.expand(N) for _, s, _ in scales]).prod(0)  # (N,)
            J = J * total[:, None, None]
            for i, (sl, _, S) in enumerate(scales):
                others = torch.ones_like(total)
                for j, (_, s, _) in enumerate(scales):
                    if j != i:
                        others = others * s
                J[..., sl] += v.unsqueeze(-1) * (others[:, None] * S).unsqueeze(1)
            v = v * total.unsqueeze(-1)
        base = robot.base.to(theta)
        if not robot.chain.plain_base:  # an identity base leaves the columns as they are
            J = _rows_times(base[:3, :3], J)
            if rotation:
                W = _rows_times(base[:3, :3], W)
        v = v @ base[:3, :3].T + base[:3, 3]
        for e, sl in parts:
            p = theta[sl]
            dv = e.displacement(p, ctx, v)
            if dv is not None:
                Dp, Dv = e.displacement_jacobian(p, ctx, v)
                if Dv is not None:
                    J = J + _rows_times(Dv, J)
                J[..., sl] += Dp
                v = v + dv
        for e, sl in parts:
            p = theta[sl]
            w = e.world(p, ctx, v)
            if w is not None:
                Dp, Dv = e.world_jacobian(p, ctx, v)
                J = _rows_times(Dv, J)
                J[..., sl] += Dp
                v = w
        world_R = {}  # effect index -> its world_rotation, for the frame below as well
        if rotation:
            for i, (e, sl) in enumerate(parts):
                p = theta[sl]
                Rw = world_R[i] = e.world_rotation(p, ctx)
                if Rw is not None:
                    W = _rows_times(Rw, W)
                    dR = e.world_rotation_jacobian(p, ctx)  # (3, 3, k)
                    Om = torch.einsum("ijk,lj->kil", dR, Rw)  # dR_k Rw^T, skew (k, 3, 3)
                    W[..., sl] += torch.stack([Om[:, 2, 1], Om[:, 0, 2], Om[:, 1, 0]], dim=0)
        if out is not None and J is not out:  # a step above made a new tensor
            J = out.copy_(J)
        if not frame:
            return (J, W, v) if position else (J, W)
        R = cj.rotation @ robot.tool[:3, :3].to(theta)  # predict_rotation's steps
        if not robot.chain.plain_base:
            R = base[:3, :3] @ R
        for i, (e, sl) in enumerate(parts):
            w = world_R[i] if i in world_R else e.world_rotation(theta[sl], ctx)
            if w is not None:
                R = w @ R
        return (J, W, R, v) if position else (J, W, R)


def _runs(idx) -> list:
    """[(value, start, stop)]: the runs of equal consecutive values of idx (a list of ints)."""
    out, a = [], 0
    for i in range(1, len(idx) + 1):
        if i == len(idx) or idx[i] != idx[a]:
            out.append((idx[a], a, i))
            a = i
    return out


def _times_shared(M: torch.Tensor, T: torch.Tensor) -> torch.Tensor:
    """M_i @ T for every row: M (N, 3, 3), one T (3, k) -> (N, 3, k), as one GEMM of the
    stacked rows instead of N small ones."""
    return (M.reshape(-1, 3) @ T).reshape(M.shape[0], 3, T.shape[-1])


def _rows_times(M: torch.Tensor, J: torch.Tensor) -> torch.Tensor:
    """M_i @ J_i for every row: M (N, 3, 3) or one (3, 3) (also an expanded one), J (N, 3, P)
    -> (N, 3, P) contiguous. On a CPU a batched product of small matrices is fast only on
    contiguous operands (else it runs as a loop of N small GEMMs), so J is made contiguous
    and one matrix for all rows is broadcast rather than expanded."""
    J = J.contiguous()
    if M.dim() == 2 or M.stride(0) == 0:
        return torch.matmul(M if M.dim() == 2 else M[0], J)
    return M.contiguous() @ J
