"""The plan file of ``torchcal plan``: ``pose,q1..qN`` (pose 0-based, joint values in
degrees, mm for a prismatic joint), the measurement CSV's pose and joint columns; measure x, y, z (mm) at each row
and add them as columns to get a measurement file."""

from __future__ import annotations

import torch

__all__ = ["plan_csv"]


def plan_csv(q: torch.Tensor, robot) -> str:
    """CSV text ``pose,q1..qN`` for rows q (N, n) rad (mm for a prismatic joint) of `robot`:
    degrees, mm for a prismatic joint (`Robot.q_to_user`)."""
    n = q.shape[1]
    lines = ["pose," + ",".join(f"q{j + 1}" for j in range(n))]
    for i, row in enumerate(robot.q_to_user(q).tolist()):
        lines.append(f"{i}," + ",".join(repr(round(v, 9)) for v in row))
    return "\n".join(lines) + "\n"
