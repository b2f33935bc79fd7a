"""The common shape of a physical effect (it reads the per-measurement `torchcal.effects.context.Context`).

An effect is a small differentiable term with a documented parameter vector. It plays
two roles with the same code: inside a simulated "real" robot (`torchcal.simulation.virtual_robot`) with
chosen values, and inside a fitted model (`torchcal.calibration.model`) with unknown values.
This is also the public API for effects of your own (docs/effects.md walks through one).

Writing an effect: subclass `Effect`, set

- ``name``: lower-case identifier used in specs (``name`` or ``name:J,J``), reports and
  MODEL.json; it must not clash with a registered effect;
- ``takes_joints``: True when the spec lists joints (``self.joints``, 1-based, sorted);
- ``uses_payload`` / ``uses_temperature``: True when the effect reads ``ctx.payload_kg`` /
  ``ctx.temp_c``, so a simulated session varies them; ``uses_approach``: True when it
  reads ``ctx.approach`` (interval calibration then refuses repeats of a pose approached
  from different directions);
- ``param_names()`` / ``param_units()``: one name and one unit string per entry of p
  (names unique within the model, e.g. suffixed with the joint number);
- ``check_context(ctx)``: raise `torchcal.errors.InputError` when the data lack a column
  the effect needs (the effect is then no candidate in `diagnose`);

and implement one or more hooks, all pure, differentiable (torch only: no in-place
writes into p, no numpy, no Python branches on p's values) functions of the parameter
vector ``p (k,)`` (same dtype/device as ctx.q) and the `Context` of N rows, n joints:

- ``joint_offset(p, ctx) -> (N, n) rad``: added to the commanded joint angles ``ctx.q``;
- ``tool_point(p, ctx) -> (3,) mm``: added to the TCP position in the flange frame;
- ``geometric_offset(p, ctx) -> (N, n, 5)``: per-row MD-H deviations [dtheta rad, dd mm,
  da mm, dalpha rad, dbeta rad] added to the geometric ones (e.g. thermal growth);
- ``chain_scale(p, ctx) -> (N,)``: factor on the whole chain and tool (1 = none);
- ``displacement(p, ctx, v) -> (N, 3) mm``: added to the base-frame TCP positions
  ``v (N, 3) mm``;
- ``world(p, ctx, v) -> (N, 3) mm``: maps base-frame positions ``v (N, 3)`` to the
  measurement frame (the last step; use for a frame change).

A hook an effect does not use returns None (the default).

Each hook has a companion giving its derivative w.r.t. p, used by the analytic Jacobian
of `torchcal.calibration.model.CalibrationModel.jacobian` (shapes for p (k,)):
``joint_offset_jacobian -> (N, n, k)``, ``geometric_offset_jacobian -> (N, n, 5, k)``,
``tool_point_jacobian -> (3, k)`` (``(N, 3, k)`` for a per-row tool point),
``chain_scale_jacobian -> (N, k)``, ``world_rotation_jacobian -> (3, 3, k)``,
``displacement_jacobian(p, ctx, v)`` and ``world_jacobian(p, ctx, v) -> (dp (N, 3, k),
dv (N, 3, 3))`` (dv None for a displacement that does not depend on v). The built-in
effects give them analytically; an effect that does not is differentiated by forward-mode
autodiff of that hook alone (the defaults here, which assume, as every hook does, that
row i of the output depends on row i of v only). At p = 0 an effect should do
nothing (diagnosis linearises candidates around p = 0). Minimal example, an encoder
scale error of the listed joints::

    from torchcal.effects import Effect
    from torchcal.effects.base import scatter_joints

    class Scale(Effect):
        name = "my_scale"
        takes_joints = True

        def param_names(self):
            return [f"my_scale_{j}" for j in self.joints]

        def param_units(self):
            return ["1"] * len(self.joints)

        def joint_offset(self, p, ctx):            # (N, n) rad
            cols = ctx.q[:, [j - 1 for j in self.joints]] * p
            return scatter_joints(cols, self.joints, ctx.q.shape[1])

Register it with ``torchcal.effects.register_effect(Scale)``, ``--effects-module FILE.py`` on
the command line, or an entry point of group ``torchcal.effects`` in an installed package.
"""

from __future__ import annotations

import functools
import weakref
from typing import TYPE_CHECKING

import torch

from torchcal.robots.robot import Robot

if TYPE_CHECKING:
    from torchcal.effects.context import Context


class Effect:
    """Base class. Subclasses set `name`, `takes_joints` and describe their parameters."""

    name: str = ""
    takes_joints: bool = False
    uses_payload: bool = False  # reads ctx.payload_kg: a simulated session varies the payload
    uses_temperature: bool = False  # reads ctx.temp_c: a simulated session drifts the temperature
    uses_approach: bool = False  # reads ctx.approach: the direction of each move matters (rows' order)

    def __init__(self, robot: Robot, joints=()):
        self.robot = robot
        self.joints = tuple(int(j) for j in joints)  # 1-based, as in specs and reports

    def __getstate__(self):
        """Pickled and copied without the `per_context` and `per_value` caches."""
        return {k: v for k, v in self.__dict__.items() if not k.startswith(("_per_context_", "_per_value_"))}

    # parameter description ----------------------------------------------------------
    def param_names(self) -> list[str]:
        """Names of the parameters, one per entry of p."""
        raise NotImplementedError

    def param_units(self) -> list[str]:
        """Units of the parameters ('rad', 'mm', '1', '1/K', ...), one per entry of p."""
        raise NotImplementedError

    def plausible_max(self) -> list[float] | None:
        """Plausible size |p| per parameter, in the units of `param_units` (None: no
        prior, the default; an inf entry: none for that parameter). The fit puts a weak
        Gaussian prior of this scale on each parameter (torchcal.calibration.plausibility),
        as it does on the MD-H deviations, and names the parameters that end beyond it: a
        value no real robot has means the parameter absorbed something else, typically a
        combination of nearly dependent columns that cancels on the calibration poses and
        explodes outside them. docs/effects.md lists the built-in effects' scales."""
        return None

    def lower_bounds(self) -> list[float] | None:
        """Lowest physical value per parameter, in its unit (None: no bound, the default;
        -inf entries: none for that parameter). A magnitude that cannot be negative
        (lost motion, a clearance pushed by the load) has 0: the fit keeps it at or above
        it (a projected step, `torchcal.calibration.lm`)."""
        return None

    @property
    def n_params(self) -> int:
        return len(self.param_names())

    def spec(self) -> str:
        """'name' or 'name:J,J' (1-based joints)."""
        return self.name if not self.takes_joints else f"{self.name}:{','.join(map(str, self.joints))}"

    def check_context(self, ctx: Context) -> None:
        """Raise InputError when the data lack what the effect needs (e.g. temp_c)."""

    # hooks ------------------------------------------------------------------------------
    def joint_offset(self, p, ctx):
        return None

    def tool_point(self, p, ctx):
        return None

    def geometric_offset(self, p, ctx):
        return None

    def chain_scale(self, p, ctx):
        return None

    def displacement(self, p, ctx, v):
        return None

    def world(self, p, ctx, v):
        return None

    def world_rotation(self, p, ctx):
        """(3, 3) rotation part of `world` (for measured orientations), or None."""
        return None

    # derivatives of the hooks w.r.t. p (module docstring); defaults: autodiff of the hook
    def joint_offset_columns(self, p, ctx):
        """`joint_offset_jacobian` of an effect whose every parameter moves one joint:
        (joint index (k,) 0-based, values (N, k)), D[:, joint[c], c] = values[:, c] and 0
        elsewhere; None (the default): use `joint_offset_jacobian`. Lets the model's
        Jacobian take the columns as products instead of a batched matrix product with
        the mostly zero D (the same numbers)."""
        return None

    def joint_offset_jacobian(self, p, ctx):
        """(N, n, k) d joint_offset / d p."""
        return torch.func.jacfwd(lambda t: self.joint_offset(t, ctx))(p)

    def tool_point_jacobian(self, p, ctx):
        """(3, k) (or (N, 3, k)) d tool_point / d p."""
        return torch.func.jacfwd(lambda t: self.tool_point(t, ctx))(p)

    def geometric_offset_jacobian(self, p, ctx):
        """(N, n, 5, k) d geometric_offset / d p."""
        return torch.func.jacfwd(lambda t: self.geometric_offset(t, ctx))(p)

    def chain_scale_jacobian(self, p, ctx):
        """(N, k) d chain_scale / d p."""
        return torch.func.jacfwd(lambda t: self.chain_scale(t, ctx))(p)

    def world_rotation_jacobian(self, p, ctx):
        """(3, 3, k) d world_rotation / d p."""
        return torch.func.jacfwd(lambda t: self.world_rotation(t, ctx))(p)

    def displacement_jacobian(self, p, ctx, v):
        """(d / d p (N, 3, k), d / d v (N, 3, 3) or None) of displacement."""
        return row_jacobians(lambda t, u: self.displacement(t, ctx, u), p, v)

    def world_jacobian(self, p, ctx, v):
        """(d / d p (N, 3, k), d / d v (N, 3, 3)) of world."""
        return row_jacobians(lambda t, u: self.world(t, ctx, u), p, v)


def per_context(method):
    """Decorator for an effect's method ``method(self, ctx) -> tensor`` that depends on the
    rows of ctx only (a basis of the joint angles): the value for the last `Context` it
    was called with is kept (a Context is immutable), so that the residual and Jacobian
    evaluations of a solve on the same rows compute it once. Held by a weak reference to
    that ctx; not kept when ctx.q requires grad (a graph must not outlive its backward)."""
    attr = f"_per_context_{method.__name__}"

    @functools.wraps(method)
    def cached(self, ctx):
        memo = self.__dict__.get(attr)
        if memo is not None and memo[0]() is ctx:
            return memo[1]
        value = method(self, ctx)
        if not ctx.q.requires_grad:
            self.__dict__[attr] = (weakref.ref(ctx), value)
        return value

    return cached


def per_value(method):
    """Decorator for an effect's method ``method(self, r) -> tensor`` that depends on the
    values of a small parameter tensor r only (a rotation from a rotation vector): the
    value for the last r it was called with is kept, keyed by a copy of r compared value
    by value (so a theta changed in place is seen), so that the residual and Jacobian
    evaluations at one theta compute it once. Not kept for an r that requires grad or is
    wrapped by torch.func (vmap, jvp, jacfwd), which get a fresh value."""
    attr = f"_per_value_{method.__name__}"

    @functools.wraps(method)
    def cached(self, r):
        if r.requires_grad or torch._C._functorch.is_functorch_wrapped_tensor(r):
            return method(self, r)
        memo = self.__dict__.get(attr)
        if memo is not None:
            key, value = memo
            if key.shape == r.shape and key.dtype == r.dtype and key.device == r.device and torch.equal(key, r):
                return value
        value = method(self, r)
        self.__dict__[attr] = (r.detach().clone(), value)
        return value

    return cached


def row_jacobians(fn, p: torch.Tensor, v: torch.Tensor):
    """Forward-mode derivatives of a row-wise map fn(p (k,), v (N, 3)) -> (N, 3):
    (d / d p (N, 3, k), d / d v (N, 3, 3)), from k + 3 Jacobian-vector products (the
    v tangents move every row at once, valid because row i depends on v_i only)."""
    k = p.shape[0]
    eye = torch.eye(k + 3, dtype=p.dtype, device=p.device)
    tp = eye[:, :k]  # (k + 3, k)
    tv = eye[:, k:].unsqueeze(1).expand(k + 3, *v.shape)  # (k + 3, N, 3)
    out = torch.func.vmap(lambda a, b: torch.func.jvp(fn, (p, v), (a, b))[1])(tp, tv)  # (k + 3, N, 3)
    out = out.permute(1, 2, 0)
    return out[..., :k], out[..., k:]


def joint_columns(values: torch.Tensor, joints, n: int) -> torch.Tensor:
    """Jacobian of a joint offset whose parameters act joint by joint: values (N, J, m),
    the derivative of joint ``joints[i]``'s offset w.r.t. its m parameters (parameter
    index ``i m + r``) -> (N, n, J m)."""
    N, J, m = values.shape
    out = values.new_zeros(N, n, J, m)
    idx = torch.arange(J, device=values.device)
    out[:, [j - 1 for j in joints], idx] = values
    return out.reshape(N, n, J * m)


def scatter_joints(values: torch.Tensor, joints, n: int) -> torch.Tensor:
    """Place per-joint columns values (N, len(joints)) into an (N, n) tensor of zeros."""
    place = values.new_zeros(len(joints), n)  # one-hot rows: vmap/autograd friendly
    place[range(len(joints)), [j - 1 for j in joints]] = 1.0
    return values @ place


def revolute_only(effect: Effect) -> None:
    """Refuse (InputError) an effect on a prismatic joint (a slide, q in mm) when its
    parameters are angles of the joint (rad: lost motion, transmission error, gravity
    deflection): on a slide they would be lengths and forces with other ranges, which
    these effects do not model. `discover` then does not offer it there
    (`torchcal.diagnosis.candidates.candidate_specs` skips what refuses)."""
    from torchcal.errors import InputError

    slides = [j for j in effect.joints if bool(effect.robot.prismatic[j - 1])]
    if slides:
        raise InputError(f"{effect.spec()}: joint(s) {', '.join(map(str, slides))} of {effect.robot.name!r} "
                         f"are prismatic (slides, q in mm); {effect.name} models an angle error of a revolute "
                         "joint and is not defined on a slide")

