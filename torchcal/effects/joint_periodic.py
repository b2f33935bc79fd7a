"""`joint_periodic:J@K+K`: periodic joint-angle error at chosen orders (cycles per turn).

Joint J turns by

    q_J + sum_{k in orders_J}  s_k sin(k q_J) + c_k cos(k q_J)

with the orders k (integers, cycles per joint turn) listed in the spec, joint by joint:
``joint_periodic:2@20+29`` (joint 2, orders 20 and 29), ``joint_periodic:1@12+22,2@20+29``
(two joints, each with its own orders). This is the transmission error of a strain-wave
(harmonic-drive) or cycloid reducer at the orders the data show (tooth-mesh and
flexspline-lobe errors seen at the output): `gear_periodic` covers orders 1-4 only.
`torchcal.diagnosis.spectral` finds the orders (a held-out search over the orders the
joint's measured range resolves); `discover` runs it for this effect.

Parameters (2 per order): ``jper_J_sinK``, ``jper_J_cosK`` rad inside; the plausible size
of one sine or cosine amplitude is `MAX_AMPLITUDE_ARCSEC` (docs/effects.md).
"""

import math

import torch

from torchcal.effects.base import Effect, per_context, revolute_only
from torchcal.errors import InputError

#: plausible sine or cosine amplitude of one order (arcsec), the scale of the fit's prior.
#: A strain-wave gear's transmission error is tens of arcsec to a few arc minutes (its
#: data sheets give 30-60 arcsec peak to peak for the whole error); 180 arcsec (3 arcmin)
#: per order is generous.
MAX_AMPLITUDE_ARCSEC = 180.0
ARCSEC = math.pi / 180 / 3600  # rad


class JointPeriodic(Effect):
    """Sine and cosine terms of the listed orders of each listed joint's angle."""

    name = "joint_periodic"
    takes_joints = True
    takes_orders = True

    def __init__(self, robot, joints=(), orders=()):
        """orders: one tuple of orders (integers >= 1) per joint of `joints`, in the same
        order; () gives every joint no order (no parameters: a candidate before the search)."""
        super().__init__(robot, joints)
        orders = tuple(tuple(int(k) for k in ks) for ks in orders) if orders else tuple(() for _ in self.joints)
        if len(orders) != len(self.joints) or any(k < 1 for ks in orders for k in ks):
            raise InputError(f"joint_periodic: one tuple of orders >= 1 per joint expected, got {orders!r} "
                             f"for joints {self.joints}")
        self.orders = orders
        pairs = [(i, k) for i, ks in enumerate(orders) for k in ks]
        self._slot = [i for i, _ in pairs]  # which listed joint each order belongs to
        self._k = [k for _, k in pairs]
        revolute_only(self)  # orders per turn of a joint angle: not a slide's mm

    def spec(self):
        from torchcal.effects.spec import format_spec

        return format_spec(self.name, self.joints, self.orders)

    def param_names(self):
        return [f"jper_{j}_{f}{k}" for j, ks in zip(self.joints, self.orders) for k in ks for f in ("sin", "cos")]

    def param_units(self):
        return ["rad"] * self.n_params

    def plausible_max(self):
        return [MAX_AMPLITUDE_ARCSEC * ARCSEC] * self.n_params

    @per_context
    def _basis(self, ctx):
        """(N, 2m) sin(k q_J), cos(k q_J) of the m orders, in parameter order."""
        q = ctx.q[:, [self.joints[i] - 1 for i in self._slot]]  # (N, m)
        arg = q * torch.tensor(self._k, dtype=q.dtype, device=q.device)
        return torch.stack([torch.sin(arg), torch.cos(arg)], dim=-1).reshape(len(q), -1)

    @per_context
    def _place(self, ctx):
        """(2m, n) one-hot: the joint each parameter moves."""
        place = ctx.q.new_zeros(2 * len(self._k), ctx.q.shape[1])
        cols = [self.joints[i] - 1 for i in self._slot for _ in range(2)]
        place[range(len(cols)), cols] = 1.0
        return place

    def joint_offset(self, p, ctx):
        return (self._basis(ctx).to(p) * p) @ self._place(ctx).to(p)

    def joint_offset_columns(self, p, ctx):
        return [self.joints[i] - 1 for i in self._slot for _ in range(2)], self._basis(ctx).to(p)

    def joint_offset_jacobian(self, p, ctx):
        basis, place = self._basis(ctx).to(p), self._place(ctx).to(p)
        return basis.unsqueeze(1) * place.T.contiguous().unsqueeze(0)  # (N, n, 2m), contiguous
