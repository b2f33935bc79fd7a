"""`Chain`: the kinematic structure of a serial robot, what the MD-H kernels take.

A chain is the nominal MD-H table, the joint types, and the base and tool frames. It is
frozen: its tensors are treated as immutable, so the facts the kernels branch on (which
joints are prismatic, whether the base or the tool is the identity) are read once, when it
is built, instead of on every call.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import torch


@dataclass(frozen=True, eq=False)
class Chain:
    """A serial MD-H chain.

    Attributes:
        table: (n, 5) nominal [theta_offset rad, d mm, a mm, alpha rad, beta rad].
        prismatic: (n,) bool, the joints whose q (mm) adds to d instead of theta.
        base: (4, 4) world <- joint-1 frame (mm).
        tool: (4, 4) flange <- TCP (mm).
        linear: the indices of the prismatic joints (read from `prismatic` when built).
    """

    table: torch.Tensor
    prismatic: torch.Tensor
    base: torch.Tensor
    tool: torch.Tensor
    linear: tuple = field(init=False, repr=False)
    plain_base: bool = field(init=False, repr=False)
    plain_tool: bool = field(init=False, repr=False)

    def __post_init__(self):
        n = self.table.shape[0] if self.table.ndim == 2 else -1
        if self.table.ndim != 2 or self.table.shape[1] != 5:
            raise ValueError(f"Chain: table must be (n, 5), got {tuple(self.table.shape)}")
        if self.prismatic.shape != (n,) or self.prismatic.dtype != torch.bool:
            raise ValueError(f"Chain: prismatic must be ({n},) bool, got {tuple(self.prismatic.shape)} "
                             f"{self.prismatic.dtype}")
        for name in ("base", "tool"):
            if getattr(self, name).shape != (4, 4):
                raise ValueError(f"Chain: {name} must be (4, 4), got {tuple(getattr(self, name).shape)}")
        eye = torch.eye(4, dtype=self.base.dtype, device=self.base.device)
        object.__setattr__(self, "linear", tuple(self.prismatic.nonzero().flatten().tolist()))
        object.__setattr__(self, "plain_base", bool(torch.equal(self.base, eye)))
        object.__setattr__(self, "plain_tool", bool(torch.equal(self.tool, eye.to(self.tool))))

    @classmethod
    def revolute(cls, table: torch.Tensor) -> "Chain":
        """All joints revolute, identity base and tool: table (n, 5)."""
        eye = torch.eye(4, dtype=table.dtype, device=table.device)
        return cls(table, torch.zeros(table.shape[0], dtype=torch.bool, device=table.device), eye, eye)

    @property
    def n(self) -> int:
        """Number of joints."""
        return self.table.shape[0]

    def to(self, x) -> "Chain":
        """The chain with its tensors cast like ``Tensor.to(x)`` (a dtype, a device or a
        tensor whose dtype and device to take); itself when nothing changes."""
        table = self.table.to(x)
        if table is self.table:
            return self
        return self._with(table, self.prismatic.to(table.device), self.base.to(table), self.tool.to(table),
                          self.plain_base, self.plain_tool)

    @cached_property
    def local(self) -> "Chain":
        """The chain from the joint-1 frame to the flange: identity base and tool."""
        eye = torch.eye(4, dtype=self.table.dtype, device=self.table.device)
        return self._with(self.table, self.prismatic, eye, eye, True, True)

    @cached_property
    def flange(self) -> "Chain":
        """The chain from the world to the flange: the base, identity tool."""
        eye = torch.eye(4, dtype=self.table.dtype, device=self.table.device)
        return self._with(self.table, self.prismatic, self.base, eye, self.plain_base, True)

    def first(self, k: int) -> "Chain":
        """The first k links, with the base and an identity tool."""
        eye = torch.eye(4, dtype=self.table.dtype, device=self.table.device)
        return Chain(self.table[:k], self.prismatic[:k], self.base, eye)

    def _with(self, table, prismatic, base, tool, plain_base: bool, plain_tool: bool) -> "Chain":
        """A chain of the same joint types whose frames are known to be (or not be) the
        identity: nothing is read from the tensors."""
        new = object.__new__(Chain)
        for name, value in (("table", table), ("prismatic", prismatic), ("base", base), ("tool", tool),
                            ("linear", self.linear), ("plain_base", plain_base), ("plain_tool", plain_tool)):
            object.__setattr__(new, name, value)
        return new
