"""Random joint configurations inside a robot's limits."""

from __future__ import annotations

import torch

from torchcal.robots.robot import Robot


def random_poses(robot: Robot, n: int, seed: torch.Generator | int, margin: float = 0.1,
                 min_z_mm: float | None = 0.0) -> torch.Tensor:
    """n joint vectors (n, dof), rad (revolute) / mm (prismatic), on the robot's device,
    uniform inside the limits shrunk by `margin` of each range (revolute joints limited
    to +-180 deg; a prismatic joint spans its own limits), keeping TCP z > min_z_mm (the
    floor). `seed`: an int (a new generator on the robot's device) or a torch.Generator
    (its draws are moved to the robot's device)."""
    if isinstance(seed, int):
        seed = torch.Generator(device=robot.device).manual_seed(seed)
    rev = ~robot.prismatic
    lo, hi = robot.limits[:, 0].clone(), robot.limits[:, 1].clone()
    lo = torch.where(rev, lo.clamp_min(-torch.pi), lo)
    hi = torch.where(rev, hi.clamp_max(torch.pi), hi)
    span = hi - lo
    lo, hi = lo + margin * span, hi - margin * span
    out = []
    while sum(len(o) for o in out) < n:
        u = torch.rand(2 * n + 16, robot.n, generator=seed, dtype=robot.dtype, device=seed.device)
        q = lo + (hi - lo) * u.to(robot.device)
        if min_z_mm is not None:
            q = q[robot.fk(q)[:, 2] > min_z_mm]
        out.append(q)
    return torch.cat(out)[:n]
