"""The sweep's blocks: which workspace points form block b of a sweep, and its seed.

A sweep of N points is cut into blocks of `block` points (default DEFAULT_BLOCK); block b
holds rows [b * block, min(N, (b + 1) * block)) (`block_range`) and its points are
`sample_workspace` of that many points from `block_seed(seed, b)` (`block_points`). A
block is so a function of (seed, b) alone: `torchcal.reliability.sweep.sweep` runs the
blocks in turn, `torchcal.workflows.distributed` runs them anywhere (one task per block),
and both give the same points bit for bit.
"""

from __future__ import annotations

import numpy as np
import torch

from torchcal.errors import InputError
from torchcal.robots.workspace import Workspace, sample_workspace

__all__ = ["DEFAULT_BLOCK", "block_seed", "block_range", "block_points"]

# workspace points per block (the unit of seeding, of distributed tasks and of the streamed
# output): measured (benchmarks/bench_sweep.py --distributed, docs/scale.md) a block costs
# 0.067 ms of one core per point at M = 1e3 states plus 12.6 ms per block on a local Dask
# cluster: under 1% overhead from 18700 points; 20000 points = 1.34 s of one core
DEFAULT_BLOCK = 20_000


def block_seed(seed: int, index: int):
    """The seed of block `index` of a sweep: `seed` itself for block 0, else the numpy
    SeedSequence(seed, spawn_key=(index,)) (independent streams, a function of (seed, index))."""
    return int(seed) if index == 0 else np.random.SeedSequence(int(seed), spawn_key=(int(index),))


def block_range(index: int, *, n_points: int, block: int) -> tuple[int, int]:
    """Rows [start, stop) of block `index` among n_points points in blocks of `block`."""
    return index * block, min(n_points, (index + 1) * block)


def block_points(robot, index: int, *, n_points: int, block: int = DEFAULT_BLOCK, seed: int = 0,
                 workspace: Workspace | None = None) -> torch.Tensor:
    """The workspace points (B, n) rad, float64 CPU, of block `index` of a sweep of n_points:
    `sample_workspace` of the block's size from `block_seed(seed, index)`."""
    a0, a1 = block_range(index, n_points=n_points, block=block)
    if not 0 <= a0 < a1:
        raise InputError(f"block {index} is outside a sweep of {n_points} points in blocks of {block}")
    return sample_workspace(robot.to("cpu", torch.float64), a1 - a0, block_seed(seed, index), workspace)
