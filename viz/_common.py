"""Shared helpers of `viz`: array conversion and checks, colours, atomic output paths.

Everything here is plain numpy; torch tensors (any device, any float dtype) are accepted
and copied to host float64 once, at the entry of each public function.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from torchcal.errors import InputError

AXES = ("x", "y", "z")

# Fixed colours (RGB 0-255) shared by the recordings and the figures.
BEFORE_RGB = (214, 39, 40)  # red: before calibration / compensation
AFTER_RGB = (44, 160, 44)  # green: after
MEASURED_RGB = (31, 119, 180)  # blue: measured positions
MODEL_BEFORE_RGB = (255, 127, 14)  # orange: model positions before
MODEL_AFTER_RGB = (148, 103, 189)  # purple: model positions after
ALLOWED_RGB = (127, 127, 127)  # grey: allowed error band
ALSO_RGB = ((23, 190, 207), (188, 189, 34), (227, 119, 194))  # cyan, olive, pink: further 'after' methods
RSET_CMAP = "RdYlGn"  # R_set colormap: red = unreliable, green = reliable


def to_numpy(x, name: str) -> np.ndarray:
    """`x` (torch tensor, numpy array, nested list) as a float64 numpy array on the host."""
    try:
        import torch

        if isinstance(x, torch.Tensor):
            x = x.detach().to("cpu", torch.float64).numpy()
    except ImportError:  # pragma: no cover - torch is a dependency
        pass
    try:
        arr = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: expected an array of numbers, got {type(x).__name__} ({exc})") from None
    return arr


def points(x, name: str, n: int | None = None) -> np.ndarray:
    """`x` as finite (N, 3) float64; `n` checks N."""
    arr = to_numpy(x, name)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"{name}: expected shape (N, 3) in mm, got {tuple(arr.shape)}")
    if n is not None and arr.shape[0] != n:
        raise InputError(f"{name}: expected {n} rows (one per point), got {arr.shape[0]}")
    if not np.isfinite(arr).all():
        raise InputError(f"{name}: contains NaN or infinite values")
    return arr


def vector(x, name: str, n: int | None = None) -> np.ndarray:
    """`x` as finite (N,) float64; `n` checks N."""
    arr = to_numpy(x, name)
    if arr.ndim != 1:
        raise InputError(f"{name}: expected shape (N,), got {tuple(arr.shape)}")
    if n is not None and arr.shape[0] != n:
        raise InputError(f"{name}: expected {n} values (one per point), got {arr.shape[0]}")
    if not np.isfinite(arr).all():
        raise InputError(f"{name}: contains NaN or infinite values")
    return arr


def labels(x, name: str, n: int | None = None) -> np.ndarray:
    """`x` as (N,) int64 zone labels (non-negative integers)."""
    arr = to_numpy(x, name)
    if arr.ndim != 1:
        raise InputError(f"{name}: expected shape (N,), got {tuple(arr.shape)}")
    if n is not None and arr.shape[0] != n:
        raise InputError(f"{name}: expected {n} labels (one per point), got {arr.shape[0]}")
    if arr.size and (not np.isfinite(arr).all() or (arr != np.round(arr)).any() or arr.min() < 0):
        raise InputError(f"{name}: expected non-negative integer zone labels")
    return arr.astype(np.int64)


def names_for(ids: np.ndarray, names, name: str) -> list[str]:
    """Display names for zone ids 0..max(ids): `names[i]`, or ``"zone {i + 1}"``.

    Zone ids are 0-based in arrays and shown 1-based to people (the paper's zones 1..10).
    """
    count = int(ids.max()) + 1 if ids.size else 0
    if names is None:
        return [f"zone {i + 1}" for i in range(count)]
    names = [str(s) for s in names]
    if len(names) < count:
        raise InputError(f"{name}: expected at least {count} names (zone ids go up to {count - 1}), got {len(names)}")
    return names


def subsample(n: int, max_points: int | None) -> np.ndarray:
    """Indices of at most `max_points` of `n` points, evenly spaced (deterministic)."""
    if max_points is None or n <= max_points:
        return np.arange(n)
    if max_points < 1:
        raise InputError(f"max_points: expected a positive integer or None, got {max_points}")
    return np.unique(np.linspace(0, n - 1, max_points).round().astype(np.int64))


def zone_centers(pos: np.ndarray, zones: np.ndarray, centers_mm=None, zone_names=None):
    """(names, centers (count, 3) mm) of the zones: the given centers, or the mean of
    each zone's points (NaN for an empty zone)."""
    names = names_for(zones, zone_names, "zone_names")
    count = len(names)
    if centers_mm is None:
        centers = np.array([pos[zones == z].mean(axis=0) if (zones == z).any() else np.full(3, np.nan)
                            for z in range(count)]).reshape(count, 3)
        return names, centers
    centers = points(centers_mm, "centers_mm")
    if centers.shape[0] < count:
        raise InputError(f"centers_mm: expected one row per zone ({count} zones), got {centers.shape[0]}")
    return names_for(np.arange(centers.shape[0]), zone_names, "zone_names"), centers


def zone_rgb(count: int) -> np.ndarray:
    """(count, 3) uint8 distinct colours for zones 0..count-1 (tab10, then tab20)."""
    from matplotlib import colormaps

    cmap = colormaps["tab10"] if count <= 10 else colormaps["tab20"]
    k = cmap.N
    rgba = np.array([cmap(i % k) for i in range(count)]).reshape(count, 4)
    return (rgba[:, :3] * 255).round().astype(np.uint8)


def rset_rgb(r_set: np.ndarray, vmin: float, vmax: float) -> np.ndarray:
    """(N, 3) uint8 colours of R_set values on `RSET_CMAP` over [vmin, vmax]."""
    from matplotlib import colormaps

    span = vmax - vmin
    t = np.clip((r_set - vmin) / span, 0.0, 1.0) if span > 0 else np.ones_like(r_set)
    return (colormaps[RSET_CMAP](t)[:, :3] * 255).round().astype(np.uint8)


ERROR_CMAP = "magma_r"  # error maps: light = small, dark red/black = large


def error_scale(error_mm: np.ndarray) -> float:
    """Top of the colour scale of an error map, mm: the 99th percentile (one wild row
    does not wash out the rest; rows above it get the top colour)."""
    top = float(np.percentile(error_mm, 99)) if error_mm.size else 1.0
    return top if top > 0 else 1.0


def error_rgb(error_mm: np.ndarray, vmax: float) -> np.ndarray:
    """(N, 3) uint8 colours of errors (mm) on `ERROR_CMAP` over [0, vmax]."""
    from matplotlib import colormaps

    t = np.clip(error_mm / vmax, 0.0, 1.0)
    return (colormaps[ERROR_CMAP](t)[:, :3] * 255).round().astype(np.uint8)


def rset_range(r_set: np.ndarray, given) -> tuple[float, float]:
    """Colour range of R_set: `given` (lo, hi), or the data range ([0, 1] when all equal)."""
    if given is not None:
        lo, hi = (float(v) for v in given)
        if not hi > lo:
            raise InputError(f"rset_range: expected (low, high) with high > low, got {given}")
        return lo, hi
    if r_set.size == 0:
        return 0.0, 1.0
    lo, hi = float(r_set.min()), float(r_set.max())
    if hi > lo:
        return lo, hi
    return (0.0, 1.0) if 0.0 <= lo <= 1.0 else (lo - 0.5, lo + 0.5)


def intervals(lower, upper, name: str, n: int | None) -> tuple[np.ndarray, np.ndarray]:
    """`lower`, `upper` as (T, 3) float64 with lower <= upper; `n` checks T; `name` prefixes errors."""
    lo = to_numpy(lower, f"{name}_lower_mm")
    hi = to_numpy(upper, f"{name}_upper_mm")
    for arr, what in ((lo, "lower"), (hi, "upper")):
        if arr.ndim != 2 or arr.shape[1] != 3 or (n is not None and arr.shape[0] != n):
            want = "(T, 3)" if n is None else f"({n}, 3)"
            raise InputError(f"{name}_{what}_mm: expected shape {want} (test points x axes, mm), got {tuple(arr.shape)}")
        if not np.isfinite(arr).all():
            raise InputError(f"{name}_{what}_mm: contains NaN or infinite values")
    if lo.shape != hi.shape:
        raise InputError(f"{name}_upper_mm: expected the shape of {name}_lower_mm {lo.shape}, got {hi.shape}")
    if (lo > hi).any():
        t, a = np.argwhere(lo > hi)[0]
        raise InputError(f"{name}_lower_mm: lower bound above upper bound at test point {t + 1}, axis {AXES[a]} "
                         f"({lo[t, a]:.6g} > {hi[t, a]:.6g} mm)")
    return lo, hi


def temp_beside(path: Path) -> Path:
    """A new empty temporary file in `path`'s folder (same file system, for os.replace)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes it 0600; the output gets the usual mode
    return Path(tmp)


#: the x labels of the recorded variables that are not joints (`torchcal.diagnosis.unexplained.variables`)
VARIABLE_LABELS = {"temp_c": "temp_c (deg C)", "payload_kg": "payload_kg (kg)", "order": "order (row of the file)"}


def r2_text(value: float) -> str:
    """A held-out R^2 with 2 decimals, without the sign of a value that rounds to zero
    ("0.00", not "-0.00": no dependence, not a negative one)."""
    if not np.isfinite(value):
        return "-"
    return f"{value:.2f}" if abs(value) >= 0.005 else "0.00"


def variable_label(name: str, prismatic=()) -> str:
    """The axis label of variable `name`: joints ``qJ`` in deg (mm where `name` is in
    `prismatic`), ``approach_qJ`` / ``approach_prev_qJ`` as the sign of a move, the
    others with their unit."""
    if name[:1] == "q" and name[1:].isdigit():
        return f"{name} ({'mm' if name in prismatic else 'deg'})"
    if name.startswith("approach_"):
        return f"{name} (sign of the move: -1, 0, +1)"
    return VARIABLE_LABELS.get(name, name)


def variable_panels(values, residual_mm, strengths, correlates=(), components=None, prismatic=()):
    """The panels of a residual-against-variables plot, shared by the figure and the recording.

    values: {name: (N,) values} (joint angles ``q1..`` in rad, mm for the joints named in
    `prismatic`); residual_mm: (N, 3) residual vectors or (N,) lengths, mm; strengths:
    {name: strength}; correlates: the significant names; components: {name: (N,) mm} a
    signed residual component per variable, drawn instead of the length where given (see
    `torchcal.diagnosis.dependence`).

    Returns a list, strongest first, of dicts with name, x (N,) (revolute joint angles in
    degrees, prismatic joints in mm), x_label, y (N,) mm, y_label, strength (nan where
    none), significant (bool).
    """
    r = to_numpy(residual_mm, "residual_mm")
    if r.ndim == 2 and r.shape[1] == 3:
        norm = np.linalg.norm(r, axis=1)
    elif r.ndim == 1:
        norm = np.abs(r)
    else:
        raise InputError(f"residual_mm: expected shape (N, 3) or (N,) in mm, got {tuple(r.shape)}")
    components = components or {}
    names = sorted(values, key=lambda k: -float(strengths.get(k, -np.inf)))
    out = []
    for name in names:
        v = vector(values[name], f"values[{name!r}]", len(norm))
        angle = name[:1] == "q" and name[1:].isdigit() and name not in prismatic
        signed = name in components
        out.append({"name": name, "x": np.degrees(v) if angle else v, "x_label": variable_label(name, prismatic),
                    "y": vector(components[name], f"components[{name!r}]", len(norm)) if signed else norm,
                    "y_label": "residual along its fitted dependence (mm)" if signed else "|residual| (mm)",
                    "strength": float(strengths.get(name, np.nan)), "significant": name in correlates})
    return out
