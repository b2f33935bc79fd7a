"""The workspace of a robot as sampled configurations: which configurations count as
workspace points (`Workspace`: floor, keep-out column, reach) and a Latin-hypercube
sampler inside the joint limits that keeps only those (`sample_workspace`). The sweep,
the accuracy map and measurement planning all sample here. q in rad (mm for a prismatic
joint), positions in mm in the robot's base frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from torchcal.errors import InputError, number_argument
from torchcal.kinematics import mdh as K


@dataclass(frozen=True)
class Workspace:
    """Which sampled configurations count as workspace points (mm).

    Attributes:
        floor_z_mm: the TCP must lie above the floor, z > floor_z_mm in the robot's world
            frame (the frame of its ``base``: world <- joint-1 frame).
        column_radius_mm, column_height_mm: keep-out cylinder about the joint-1 axis (the
            base column and turntable): rejected if sqrt(x^2 + y^2) < column_radius_mm
            and z < column_height_mm, x, y, z in the joint-1 frame (the robot's ``base``
            undone: a robot standing anywhere in the cell keeps its own column). Default 350 mm up to 1100 mm (the shoulder height
            d1 of the KR 1000 Titan); the paper's Table 3 point 6 at radius 387 mm, z 631
            mm is just outside.
        reach_fraction: the TCP must lie within this fraction of the arm's full stretch
            from the shoulder (origin of frame 1), the stretch taken as the sum over links
            2..n of sqrt(a^2 + d^2) plus the tool offset (an upper bound): it drops the
            near-singular stretched arm. 1 disables it; a value outside (0, 1] (a length
            in mm, a percentage) is an InputError, and so is a non-finite floor, column
            radius or height.
    """

    floor_z_mm: float = 0.0
    column_radius_mm: float = 350.0
    column_height_mm: float = 1100.0
    reach_fraction: float = 0.95

    def __post_init__(self):
        for name in ("floor_z_mm", "column_radius_mm", "column_height_mm", "reach_fraction"):
            number_argument(f"Workspace: {name}", getattr(self, name))
        if self.column_radius_mm < 0:
            raise InputError(f"Workspace: column_radius_mm: expected a radius >= 0 mm, got {self.column_radius_mm!r}")
        if not 0 < self.reach_fraction <= 1:
            raise InputError(f"Workspace: reach_fraction: expected a share of the arm's full stretch in (0, 1] "
                             f"(1: no limit), got {self.reach_fraction!r}")

    def accept(self, robot, q: torch.Tensor) -> torch.Tensor:
        """(N,) bool for q (N, n) rad."""
        q = robot.check_q(q)
        p = robot.fk(q)  # (N, 3) TCP
        shoulder = K.fk_positions(q[:, :1], robot.chain.to(q).first(1))
        ok = p[:, 2] > self.floor_z_mm
        B = robot.base.to(p)
        local = (p - B[:3, 3]) @ B[:3, :3]  # joint-1 frame
        radial = local[:, :2].norm(dim=-1)
        ok &= ~((radial < self.column_radius_mm) & (local[:, 2] < self.column_height_mm))
        if self.reach_fraction < 1:
            t = robot.table
            # a prismatic joint's d reaches d + its farthest limit
            d = torch.where(robot.prismatic[1:], (t[1:, 1, None] + robot.limits[1:]).abs().amax(-1), t[1:, 1])
            stretch = (d ** 2 + t[1:, 2] ** 2).sqrt().sum() + robot.tool[:3, 3].norm()
            ok &= (p - shoulder).norm(dim=-1) <= self.reach_fraction * stretch.to(p)
        return ok


class LatinHypercube:
    """Latin hypercubes in [0, 1)^d, the points of scipy.stats.qmc.LatinHypercube(d, rng=seed)
    (scrambled, strength 1, no optimisation) written out in numpy: importing scipy.stats for
    it cost about 0.65 s of CPU in every process that samples a workspace (a command, each
    worker of a sweep). seed: an int, a numpy SeedSequence or Generator, read as scipy reads
    ``rng``: the points come from a child spawned from ``numpy.random.default_rng(seed)``
    (a SeedSequence's spawn counter advances). tests/test_workspace.py holds them to scipy's."""

    def __init__(self, d: int, seed=None):
        self.d = int(d)
        self.rng = np.random.default_rng(seed).spawn(1)[0]

    def random(self, n: int) -> np.ndarray:
        """(n, d) points, one in each of the n strata [k/n, (k+1)/n) of every axis; successive
        calls draw on from the same stream."""
        samples = self.rng.uniform(size=(n, self.d))
        perms = np.tile(np.arange(1, n + 1), (self.d, 1))
        for i in range(self.d):
            self.rng.shuffle(perms[i, :])
        return (perms.T - samples) / n


def sample_workspace(robot, n: int, seed=0, workspace: Workspace | None = None,
                     max_rounds: int = 50) -> torch.Tensor:
    """n joint configurations (n, dof) rad, float64 on the CPU, inside limits and workspace.

    Rounds of Latin hypercubes (`LatinHypercube`: scipy's with rng=seed; seed an int or a
    numpy SeedSequence) are scaled to the joint limits and filtered by `workspace` until
    n pass; the first n are returned. A floor well above the robot's own base is named in
    one `torchcal.robots.checks.FloorWarning` (`warn_base_below_floor`).
    """
    from torchcal.robots.checks import warn_base_below_floor

    if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 1:
        raise InputError(f"number of workspace points must be a positive integer, got {n!r}")
    workspace = Workspace() if workspace is None else workspace
    warn_base_below_floor(robot, workspace.floor_z_mm, stacklevel=2)
    engine = LatinHypercube(robot.n, seed)
    lo = robot.limits[:, 0].cpu().numpy()
    hi = robot.limits[:, 1].cpu().numpy()
    cpu = robot.to("cpu", torch.float64)
    kept, have, drawn, size = [], 0, 0, int(n)
    for _ in range(max_rounds):
        u = engine.random(size)  # (size, dof) in [0, 1)
        u *= hi - lo
        u += lo
        q = torch.from_numpy(u)
        q = q[workspace.accept(cpu, q)]
        kept.append(q)
        have, drawn = have + q.shape[0], drawn + size
        if have >= n:
            return torch.cat(kept)[:n]
        rate = max(have / drawn, 0.05)  # acceptance so far
        size = max(64, int(1.5 * (n - have) / rate))
    raise InputError(f"workspace filter too strict: only {have} of {n} points found in {max_rounds} rounds")
