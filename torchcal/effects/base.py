"""The common shape of a physical effect, and the per-measurement context it reads.

An effect is a small differentiable term with a documented parameter vector. It plays
two roles with the same code: inside a simulated "real" robot (`torchcal.simulation.virtual_robot`) with
chosen values, and inside a fitted model (`torchcal.calibration.model`) with unknown values.

Each effect contributes through one or more hooks, all pure functions of its parameter
vector ``p (k,)`` and the `Context`:

- ``joint_offset(p, ctx) -> (N, n) rad``: added to the commanded joint angles;
- ``tool_point(p, ctx) -> (3,) mm``: added to the TCP position on the flange;
- ``geometric_offset(p, ctx) -> (N, n, 5)``: per-row MD-H deviations added to the
  geometric ones (e.g. thermal growth of the link lengths);
- ``chain_scale(p, ctx) -> (N,) or None``: factor on the whole chain and tool;
- ``displacement(p, ctx, v) -> (N, 3) mm``: added to the base-frame TCP position ``v``;
- ``world(p, ctx, v) -> (N, 3) mm``: maps base-frame positions to the measurement frame.

A hook an effect does not use returns None.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchcal.robots.robot import Robot


@dataclass(frozen=True)
class Context:
    """What effects may read about each measurement (all on one device/dtype).

    Attributes:
        q: (N, n) rad commanded joint angles.
        payload_kg: (N,) payload mass at the flange (zeros when not measured).
        temp_c: (N,) temperature in deg C (None when not measured).
        approach: (N, n) +1 / -1, the direction each joint last moved in to reach the
            row's pose (the robot starts at all-zero joints and moves row to row).
        frames: (N, n + 2, 4, 4) nominal world frames at q (base, links, TCP).
        gravity: (3,) unit vector of gravity in the robot base frame.
        point: (N,) int64 measured-point (reflector) ids, or None (one point per pose).
    """

    q: torch.Tensor
    payload_kg: torch.Tensor
    temp_c: torch.Tensor | None
    approach: torch.Tensor
    frames: torch.Tensor
    gravity: torch.Tensor
    point: torch.Tensor | None = None

    @property
    def n_rows(self) -> int:
        return self.q.shape[0]

    def subset(self, index) -> "Context":
        """The context of rows `index` (approach directions stay as computed in order)."""
        pick = lambda t: None if t is None else t[index]  # noqa: E731
        return Context(pick(self.q), pick(self.payload_kg), pick(self.temp_c),
                       pick(self.approach), pick(self.frames), self.gravity, pick(self.point))


def approach_directions(q: torch.Tensor) -> torch.Tensor:
    """+1 / -1 per joint: the sign of the last non-zero move into each row.

    q (N, n) rad in measurement order; the robot starts at all-zero joints. A joint
    that has not moved yet counts as approached from below (+1).
    """
    prev = torch.cat([torch.zeros_like(q[:1]), q[:-1]], dim=0)
    step = torch.sign(q - prev)  # (N, n) in {-1, 0, 1}
    out = torch.empty_like(q)
    last = torch.ones_like(q[0])
    for i in range(q.shape[0]):  # carry the last direction through rows with no move
        last = torch.where(step[i] != 0, step[i], last)
        out[i] = last
    return out


def make_context(robot: Robot, q, payload_kg=None, temp_c=None, point=None) -> Context:
    """Context for rows of commanded joint angles q (N, n) rad in measurement order
    (point: (N,) int reflector ids or None)."""
    q = robot.check_q(q).to(robot.dtype)
    n_rows = q.shape[0]
    payload = torch.zeros(n_rows, dtype=q.dtype, device=q.device) if payload_kg is None \
        else torch.as_tensor(payload_kg, dtype=q.dtype, device=q.device)
    temp = None if temp_c is None else torch.as_tensor(temp_c, dtype=q.dtype, device=q.device)
    point = None if point is None else torch.as_tensor(point, dtype=torch.int64, device=q.device)
    return Context(q, payload, temp, approach_directions(q), robot.frames(q), robot.gravity.to(q), point)


def context_of(robot: Robot, m) -> Context:
    """Context of a `Measurements` (q, payload, temperature, point ids)."""
    return make_context(robot, m.q, m.payload_kg, m.temp_c, m.point)


class Effect:
    """Base class. Subclasses set `name`, `takes_joints` and describe their parameters."""

    name: str = ""
    takes_joints: bool = False

    def __init__(self, robot: Robot, joints=()):
        self.robot = robot
        self.joints = tuple(int(j) for j in joints)  # 1-based, as in specs and reports

    # parameter description ----------------------------------------------------------
    def param_names(self) -> list[str]:
        """Names of the parameters, one per entry of p."""
        raise NotImplementedError

    def param_units(self) -> list[str]:
        raise NotImplementedError

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


def scatter_joints(values: torch.Tensor, joints, n: int) -> torch.Tensor:
    """Place per-joint columns values (N, len(joints)) into an (N, n) tensor of zeros."""
    place = values.new_zeros(len(joints), n)  # one-hot rows: vmap/autograd friendly
    place[range(len(joints)), [j - 1 for j in joints]] = 1.0
    return values @ place
