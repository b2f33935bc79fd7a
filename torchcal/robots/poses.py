"""Random joint configurations inside a robot's limits."""

from __future__ import annotations

import torch

from torchcal.robots.robot import Robot


def random_poses(robot: Robot, n: int, generator: torch.Generator | int, margin: float = 0.1,
                 min_z_mm: float | None = 0.0) -> torch.Tensor:
    """n joint vectors (n, dof) rad uniform inside the limits shrunk by `margin` of each
    range (wrist joints limited to +-180 deg), keeping TCP z > min_z_mm (the floor).
    `generator`: a torch.Generator, or an int seed for a new one."""
    if isinstance(generator, int):
        generator = torch.Generator().manual_seed(generator)
    lo, hi = robot.limits[:, 0].clone(), robot.limits[:, 1].clone()
    lo, hi = lo.clamp_min(-torch.pi), hi.clamp_max(torch.pi)
    span = hi - lo
    lo, hi = lo + margin * span, hi - margin * span
    out = []
    while sum(len(o) for o in out) < n:
        q = lo + (hi - lo) * torch.rand(2 * n + 16, robot.n, generator=generator, dtype=robot.dtype)
        if min_z_mm is not None:
            q = q[robot.fk(q)[:, 2] > min_z_mm]
        out.append(q)
    return torch.cat(out)[:n]
