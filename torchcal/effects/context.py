"""`Context`: what an effect may read about each measurement row, and how it is built.

`make_context(robot, q, ...)` builds it from joint angles (nominal frames, approach
directions), `context_of(robot, m)` from a `Measurements`; `approach_directions` gives the
direction each joint last moved in.
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
            row's pose (the robot starts at all-zero joints and moves row to row; from
            `Measurements.q_prev` when given, so a subset of rows keeps the true
            directions).
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


def approach_directions(q: torch.Tensor, q_prev: torch.Tensor | None = None) -> torch.Tensor:
    """+1 / -1 per joint: the sign of the last non-zero move into each row.

    q (N, n) rad in measurement order; the robot starts at all-zero joints. A joint
    that has not moved yet counts as approached from below (+1).

    q_prev (N, n) rad, optional: the angles each row was reached from
    (`Measurements.q_prev`; per joint the last commanded angle before the row that
    differs from it). Then the direction is sign(q - q_prev) row by row, and only
    where that is 0 (the joint never moved) the previous row's direction is carried
    (+1 at the start): a subset of rows gets the directions of the full session.
    Without q_prev, the previous row of q is the predecessor.
    """
    prev = torch.cat([torch.zeros_like(q[:1]), q[:-1]], dim=0) if q_prev is None else q_prev.to(q)
    step = torch.sign(q - prev)  # (N, n) in {-1, 0, 1}
    # carry the last direction through rows with no move: per joint, the index of the
    # last row at or before each row with a move (a running max; -1 before the first)
    rows = torch.arange(q.shape[0], device=q.device).unsqueeze(1).expand_as(step)
    last = torch.where(step != 0, rows, torch.full_like(rows, -1)).cummax(dim=0).values
    return torch.where(last >= 0, step.gather(0, last.clamp_min(0)), torch.ones_like(step))


def make_context(robot: Robot, q, payload_kg=None, temp_c=None, *, point=None, q_prev=None) -> Context:
    """Context for rows of commanded joint angles q (N, n) rad in measurement order.

    payload_kg, temp_c: (N,) or None. point: (N,) int reflector ids or None. q_prev:
    (N, n) rad, the angles each row was reached from (`Measurements.q_prev`); pass it
    whenever q is a subset of a session's rows, so direction-dependent effects (backlash)
    see the true approach directions.
    """
    q = robot.check_q(q).to(robot.dtype)
    n_rows = q.shape[0]
    payload = torch.zeros(n_rows, dtype=q.dtype, device=q.device) if payload_kg is None \
        else torch.as_tensor(payload_kg, dtype=q.dtype, device=q.device)
    temp = None if temp_c is None else torch.as_tensor(temp_c, dtype=q.dtype, device=q.device)
    point = None if point is None else torch.as_tensor(point, dtype=torch.int64, device=q.device)
    qp = None if q_prev is None else torch.as_tensor(q_prev, dtype=q.dtype, device=q.device)
    if qp is not None and qp.shape != q.shape:
        from torchcal.errors import InputError
        raise InputError(f"make_context: q_prev has shape {tuple(qp.shape)}, q has {tuple(q.shape)}")
    return Context(q, payload, temp, approach_directions(q, qp), robot.frames(q), robot.gravity.to(q), point)


def context_of(robot: Robot, m) -> Context:
    """Context of a `Measurements` (q, payload, temperature, point ids, q_prev)."""
    return make_context(robot, m.q, m.payload_kg, m.temp_c, point=m.point, q_prev=m.q_prev)
