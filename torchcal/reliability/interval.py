"""Interval tensors: lower/upper and center/radius form.

An `Interval` is a pair of tensors ``lower <= upper`` of one broadcast shape; every
element is the closed interval ``[lower, upper]``. The center/radius form (docs/paper.md
eq. 23) is ``center = (upper + lower) / 2``, ``radius = (upper - lower) / 2``.

Interval arithmetic here is the plain (exact) arithmetic of independent intervals:

- ``a + b``: ``[a.l + b.l, a.u + b.u]`` (a number or tensor is a point interval);
- ``k * a`` for a number or tensor ``k``: center ``k c``, radius ``|k| r`` (a negative
  ``k`` flips the bounds);
- ``linear_hull(K, iv)``: the exact interval hull of ``{K x : x in iv}`` for a box ``iv``,
  center ``K c`` and radius ``|K| r``. Each bound is attained at a vertex of the box
  (``x = c +- sign(K_i) r`` for row i), so the hull is tight, row by row;
- ``sample_hull(samples, dim)``: the smallest interval that contains the samples along
  ``dim`` (an inner estimate of the true range of whatever was sampled).

Units are those of the tensors (mm, rad, ...). Tensors keep their device and dtype.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchcal.errors import InputError


def _tensor(x, like: torch.Tensor | None = None) -> torch.Tensor:
    """x as a floating tensor (float64 unless it already is floating / `like` says)."""
    if isinstance(x, torch.Tensor):
        t = x
    else:  # numbers and lists: float64 (or like's dtype), never torch's float32 default
        t = torch.as_tensor(x, dtype=torch.float64 if like is None else like.dtype,
                            device=None if like is None else like.device)
    if not t.is_floating_point():
        t = t.to(torch.float64 if like is None else like.dtype)
    return t


@dataclass(frozen=True, eq=False)
class Interval:
    """Closed intervals ``[lower, upper]``, elementwise; shapes broadcast.

    Attributes:
        lower: (...) tensor, lower bounds.
        upper: (...) tensor, upper bounds, ``upper >= lower`` everywhere.

    Example::

        >>> iv = Interval(torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 2.0]))
        >>> (iv * -2.0).lower
        tensor([-2., -4.])
    """

    lower: torch.Tensor
    upper: torch.Tensor

    def __post_init__(self):
        lo = _tensor(self.lower)
        hi = _tensor(self.upper, like=lo if not isinstance(self.upper, torch.Tensor) else None)
        dtype = torch.promote_types(lo.dtype, hi.dtype)
        if lo.device != hi.device:
            raise InputError(f"Interval: lower is on {lo.device} but upper on {hi.device}")
        lo, hi = torch.broadcast_tensors(lo.to(dtype), hi.to(dtype))
        if bool((hi < lo).any()):
            idx = (hi < lo).nonzero()[0].tolist()
            raise InputError(f"Interval: lower must be <= upper, got lower {lo[tuple(idx)].item()} > "
                             f"upper {hi[tuple(idx)].item()} at index {idx}")
        object.__setattr__(self, "lower", lo)
        object.__setattr__(self, "upper", hi)

    # -- forms ------------------------------------------------------------------------
    @classmethod
    def from_center_radius(cls, center, radius) -> "Interval":
        """``[center - radius, center + radius]``; radius must be >= 0."""
        c = _tensor(center)
        r = _tensor(radius, like=c if not isinstance(radius, torch.Tensor) else None)
        if bool((r < 0).any()):
            raise InputError(f"Interval.from_center_radius: radius must be >= 0, got min {r.min().item()}")
        return cls(c - r, c + r)

    @classmethod
    def point(cls, x) -> "Interval":
        """The degenerate interval ``[x, x]``."""
        x = _tensor(x)
        return cls(x, x)

    @property
    def center(self) -> torch.Tensor:
        """(upper + lower) / 2."""
        return 0.5 * (self.upper + self.lower)

    @property
    def radius(self) -> torch.Tensor:
        """(upper - lower) / 2, >= 0."""
        return 0.5 * (self.upper - self.lower)

    @property
    def width(self) -> torch.Tensor:
        """upper - lower."""
        return self.upper - self.lower

    @property
    def shape(self) -> torch.Size:
        return self.lower.shape

    @property
    def dtype(self):
        return self.lower.dtype

    @property
    def device(self):
        return self.lower.device

    def to(self, device=None, dtype=None) -> "Interval":
        return Interval(self.lower.to(device=device, dtype=dtype), self.upper.to(device=device, dtype=dtype))

    def __getitem__(self, idx) -> "Interval":
        return Interval(self.lower[idx], self.upper[idx])

    def reshape(self, *shape) -> "Interval":
        return Interval(self.lower.reshape(*shape), self.upper.reshape(*shape))

    def contains(self, x, atol: float = 0.0) -> torch.Tensor:
        """Elementwise bool: ``lower - atol <= x <= upper + atol``."""
        x = _tensor(x, like=self.lower)
        return (x >= self.lower - atol) & (x <= self.upper + atol)

    def hull(self, other: "Interval") -> "Interval":
        """The smallest interval containing both (elementwise)."""
        return Interval(torch.minimum(self.lower, other.lower), torch.maximum(self.upper, other.upper))

    # -- arithmetic -------------------------------------------------------------------
    def __add__(self, other) -> "Interval":
        if isinstance(other, Interval):
            return Interval(self.lower + other.lower, self.upper + other.upper)
        k = _tensor(other, like=self.lower)
        return Interval(self.lower + k, self.upper + k)

    __radd__ = __add__

    def __neg__(self) -> "Interval":
        return Interval(-self.upper, -self.lower)

    def __sub__(self, other) -> "Interval":
        if isinstance(other, Interval):
            return self + (-other)
        return self + (-_tensor(other, like=self.lower))

    def __rsub__(self, other) -> "Interval":
        return (-self) + other

    def __mul__(self, k) -> "Interval":
        """Scaling by a number or tensor (not by another interval); negative k flips."""
        if isinstance(k, Interval):
            raise InputError("Interval * Interval is not supported; scale by a number or tensor")
        k = _tensor(k, like=self.lower)
        a, b = self.lower * k, self.upper * k
        return Interval(torch.minimum(a, b), torch.maximum(a, b))

    __rmul__ = __mul__

    def __repr__(self) -> str:
        return f"Interval(lower={self.lower!r}, upper={self.upper!r})"


def linear_hull(K: torch.Tensor, iv: Interval) -> Interval:
    """Exact interval hull of the linear image ``{K x : x in iv}`` of a box.

    K (..., m, p), iv of shape (..., p) (batch dims broadcast) -> Interval (..., m) with
    center ``K c`` and radius ``|K| r``. Row i attains its upper bound at the box vertex
    ``x = c + sign(K_i) r`` and its lower bound at ``c - sign(K_i) r``, so no smaller
    interval contains the image.
    """
    K = _tensor(K, like=iv.lower if not isinstance(K, torch.Tensor) else None)
    if K.ndim < 2 or iv.lower.ndim == 0 or K.shape[-1] != iv.shape[-1]:
        raise InputError(f"linear_hull: expected K (..., m, p) and an interval of shape (..., p), "
                         f"got K {tuple(K.shape)} and interval {tuple(iv.shape)}")
    c = iv.center.to(K.dtype).unsqueeze(-1)  # (..., p, 1)
    r = iv.radius.to(K.dtype).unsqueeze(-1)
    center = (K @ c).squeeze(-1)  # (..., m)
    radius = (K.abs() @ r).squeeze(-1)
    return Interval(center - radius, center + radius)


def sample_hull(samples: torch.Tensor, dim: int = 0) -> Interval:
    """Interval ``[min, max]`` of `samples` along `dim` (that dim is removed)."""
    samples = _tensor(samples)
    if samples.ndim == 0 or samples.shape[dim] == 0:
        raise InputError(f"sample_hull: need at least one sample along dim {dim}, got shape {tuple(samples.shape)}")
    lo, hi = torch.aminmax(samples, dim=dim)
    return Interval(lo, hi)
