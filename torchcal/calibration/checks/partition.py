"""A partition against the robot given (`check_partition`), and positions beyond its sweep
(`warn_far_from_sweep`).

Partitions that record no robot (one built in memory, an older file) are judged by
geometry: their sweep points are the nominal TCP positions of the robot they were made
for, in its base frame. More than OUTLIER_SHARE = 10 % of them beyond 1.05 R (R: the reach,
as for targets, `torchcal.calibration.checks.targets`), or calibration poses whose nominal
TCP positions lie a median farther from the nearest sweep point than PARTITION_SPACING = 3
times the sweep's own median spacing and than R / 20: a partition of another robot (or of
another region), refused. A calibration row or a compensated command whose nominal TCP
lies farther than PARTITION_SPACING sweep spacings from every sweep point takes an
extrapolated zone: named in one warning.
"""

from __future__ import annotations

import warnings

import torch

from torchcal.calibration.checks.targets import REACH_MARGIN, TARGET_RATIO, WORKSPACE_POSES
from torchcal.calibration.checks.verdict import OUTLIER_SHARE, MismatchWarning, listed
from torchcal.errors import InputError

PARTITION_SPACING = 3.0


def check_partition(partition, robot, q: torch.Tensor, where: str = "partition") -> None:
    """Refuse (one InputError line naming `where`) a `torchcal.partition.zones.Partition`
    that cannot be of `robot` by its geometry (module docstring): sweep points beyond the
    reach, or calibration poses q (N, n) rad / mm far from every sweep point."""
    from torchcal.robots.poses import random_poses

    with torch.no_grad():
        ws = robot.fk(random_poses(robot, WORKSPACE_POSES, torch.Generator().manual_seed(0)).to(
            robot.device, robot.dtype)).detach().to("cpu", torch.float64)
        p = robot.fk(q.to(robot.device, robot.dtype)).detach().to("cpu", torch.float64)  # (N, 3) mm
    origin = robot.base[:3, 3].detach().to("cpu", torch.float64)
    reach = float((ws - origin).norm(dim=-1).max())
    pts = partition.positions.detach().to("cpu", torch.float64)
    dist = (pts - origin).norm(dim=-1)
    far = int((dist > REACH_MARGIN * reach).sum())
    if far > OUTLIER_SHARE * pts.shape[0]:
        raise InputError(f"{where}: {far} of its {pts.shape[0]} sweep points lie beyond the reach of robot "
                         f"{robot.name!r} ({reach:.4g} mm from its base; up to {float(dist.max()):.4g} mm): a "
                         "partition of another robot? make the sweep and partition for this robot")
    if pts.shape[0] < 2 or p.shape[0] == 0:
        return
    spacing, near = partition.nearest_sweep(p)
    near = float(near.median())
    if near > max(PARTITION_SPACING * spacing, reach / TARGET_RATIO):
        raise InputError(f"{where}: the calibration poses of robot {robot.name!r} lie a median {near:.4g} mm from "
                         f"the nearest of its sweep points (spaced a median {spacing:.4g} mm apart): a partition "
                         "of another robot, or of another part of the workspace? make the sweep and partition for "
                         "this robot")


def warn_far_from_sweep(partition, positions: torch.Tensor, where: str = "targets", stacklevel: int = 2) -> list[int]:
    """Name (one `MismatchWarning`) the positions (M, 3) mm, robot base frame, that lie
    farther from the nearest sweep point of `partition` than PARTITION_SPACING times the
    sweep's median spacing: their zone is the nearest sweep points' zone, an extrapolation
    (a sweep of another region of the workspace). Returns their 0-based rows."""
    pts = partition.positions.detach().to("cpu", torch.float64)
    if pts.shape[0] < 2 or positions.shape[0] == 0:
        return []
    spacing, near = partition.nearest_sweep(positions)
    far = (near > PARTITION_SPACING * spacing).nonzero().flatten().tolist()
    if far:
        warnings.warn(f"{where}: {len(far)} command(s) reach nominal TCP positions up to {float(near.max()):.4g} mm "
                      f"from the nearest sweep point of the partition (spaced a median {spacing:.4g} mm apart): "
                      f"row(s) {listed(i + 1 for i in far)}; their zone is extrapolated from the nearest sweep "
                      "points (sweep the region they lie in)", MismatchWarning, stacklevel=stacklevel + 1)
    return far
