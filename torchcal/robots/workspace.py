"""The workspace of a robot as sampled configurations: which configurations count as
workspace points (`Workspace`: floor, keep-out column, reach) and a Latin-hypercube
sampler inside the joint limits that keeps only those (`sample_workspace`). The sweep,
the accuracy map and measurement planning all sample here. q in rad (mm for a prismatic
joint), positions in mm in the robot's base frame.
"""

from __future__ import annotations

import warnings
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
            undone: a robot standing anywhere in the cell keeps its own column). None
            (default): scaled to the robot (`column`), COLUMN_MM = (350, 1100) mm times the
            arm's full stretch (`arm_stretch`) over the KR 1000 Titan's 3037 mm: exactly
            350 mm up to 1100 mm on the KR 1000 (its shoulder height d1; the paper's Table 3
            point 6 at radius 387 mm, z 631 mm is just outside), 132 up to 416 mm on a
            UR5e, 190 up to 597 mm on a UR10. The KR 1000's column kept on those arms
            removed 53 % (UR5e), 29 % (UR10) and 62 % (puma560) of the joint vectors the
            floor and reach keep (none of the KR 1000's; scaled: 7.5, 8.4 and 0 %). A radius below MIN_COLUMN_SHARE
            of the stretch, thinner than any link, warns (`warn_thin_column`).
        reach_fraction: the TCP must lie within this fraction of the arm's full stretch
            from the shoulder (origin of frame 1), the stretch taken as the sum over links
            2..n of sqrt(a^2 + d^2) plus the tool offset (an upper bound): it drops the
            near-singular stretched arm. 1 disables it; a value outside (0, 1] (a length
            in mm, a percentage) is an InputError, and so is a non-finite floor, column
            radius or height.
    """

    floor_z_mm: float = 0.0
    column_radius_mm: float | None = None
    column_height_mm: float | None = None
    reach_fraction: float = 0.95

    def __post_init__(self):
        for name in ("floor_z_mm", "column_radius_mm", "column_height_mm", "reach_fraction"):
            if getattr(self, name) is not None or name in ("floor_z_mm", "reach_fraction"):
                number_argument(f"Workspace: {name}", getattr(self, name))
        if self.column_radius_mm is not None and self.column_radius_mm < 0:
            raise InputError(f"Workspace: column_radius_mm: expected a radius >= 0 mm, got {self.column_radius_mm!r}")
        if not 0 < self.reach_fraction <= 1:
            raise InputError(f"Workspace: reach_fraction: expected a share of the arm's full stretch in (0, 1] "
                             f"(1: no limit), got {self.reach_fraction!r}")

    def column(self, robot) -> tuple[float, float]:
        """(radius, height) mm of the keep-out column for `robot`: the values given, or
        COLUMN_MM scaled by arm_stretch(robot) / KR1000_STRETCH_MM where None."""
        scale = arm_stretch(robot) / KR1000_STRETCH_MM
        r, h = self.column_radius_mm, self.column_height_mm
        return (COLUMN_MM[0] * scale if r is None else r, COLUMN_MM[1] * scale if h is None else h)

    def for_robot(self, robot) -> "Workspace":
        """This filter with the column's defaults resolved for `robot` (numbers only)."""
        r, h = self.column(robot)
        return Workspace(self.floor_z_mm, r, h, self.reach_fraction)

    def accept(self, robot, q: torch.Tensor) -> torch.Tensor:
        """(N,) bool for q (N, n) rad."""
        q = robot.check_q(q)
        p = robot.fk(q)  # (N, 3) TCP
        shoulder = K.fk_positions(q[:, :1], robot.chain.to(q).first(1))
        ok = p[:, 2] > self.floor_z_mm
        B = robot.base.to(p)
        local = (p - B[:3, 3]) @ B[:3, :3]  # joint-1 frame
        radial = local[:, :2].norm(dim=-1)
        radius, height = self.column(robot)
        ok &= ~((radial < radius) & (local[:, 2] < height))
        if self.reach_fraction < 1:
            ok &= (p - shoulder).norm(dim=-1) <= self.reach_fraction * arm_stretch(robot)
        return ok


COLUMN_MM = (350.0, 1100.0)  # the default keep-out column's radius and height on the KR 1000 Titan
KR1000_STRETCH_MM = 3037.0  # arm_stretch of the kr1000titan preset: 1400 + 65 + 1200 + 372 mm
MIN_COLUMN_SHARE = 0.02  # a column radius under this share of the arm's stretch is thinner than its links


def arm_stretch(robot) -> float:
    """The arm's full stretch from the shoulder (origin of frame 1), mm: the sum over links
    2..n of sqrt(a^2 + d^2) (a prismatic joint's d at d + its farthest limit) plus the tool
    offset, an upper bound of the shoulder-to-TCP distance."""
    t = robot.table
    d = torch.where(robot.prismatic[1:], (t[1:, 1, None] + robot.limits[1:]).abs().amax(-1), t[1:, 1])
    return float((d ** 2 + t[1:, 2] ** 2).sqrt().sum() + robot.tool[:3, 3].norm())


def warn_thin_column(robot, radius_mm: float, stacklevel: int = 1) -> bool:
    """One `torchcal.robots.checks.RobotUnitWarning` (True) when a keep-out column radius
    radius_mm > 0 lies below MIN_COLUMN_SHARE (2 %) of the arm's stretch: thinner than any
    link of the arm (a UR5e's 1150 mm stretch: 23 mm, its base is 149 mm across), so no
    keep-out column; metres (0.35 for 350 mm) likely. 0 turns the column off in silence."""
    from torchcal.robots.checks import RobotUnitWarning

    stretch = arm_stretch(robot)
    if not 0 < radius_mm < MIN_COLUMN_SHARE * stretch:
        return False
    warnings.warn(f"workspace: column radius {radius_mm:g} mm is thinner than any link of {robot.name} (under "
                  f"{100 * MIN_COLUMN_SHARE:g} % of its {stretch:.0f} mm stretch, {MIN_COLUMN_SHARE * stretch:.0f} mm): "
                  f"in metres? ({1000 * radius_mm:g} mm); 0 turns the column off", RobotUnitWarning,
                  stacklevel=stacklevel + 1)
    return True


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
    if workspace.column_radius_mm is not None:
        warn_thin_column(robot, workspace.column_radius_mm, stacklevel=2)
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
