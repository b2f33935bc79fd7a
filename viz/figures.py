"""Static PNG figures (matplotlib, Agg, no screen, no pyplot global state).

Each function takes plain arrays (numpy or torch, any device), draws one figure, writes it
atomically (temporary file beside the target, then ``os.replace``) and returns the path.
An existing file is replaced only with ``force=True``. Each has a ``*_figure`` twin that
returns the `matplotlib.figure.Figure` instead of writing it (for tests and for callers
that add to it; write it with `save_figure`). Output is deterministic: fixed size
and dpi, no timestamps or version in the PNG metadata, subsampling (when a cap is hit) by
evenly spaced indices.

====================  ======================================================  ======
function              what                                                    axes
====================  ======================================================  ======
`zone_map`            workspace points by zone in x-y, x-z, y-z; centers      3
`rset_histogram`      histogram of R_set over the workspace points            1
`error_intervals`     error interval per test point and axis, before/after    3
                      compensation (and further methods beside), with the
                      allowed band (paper's Fig. 11)
`error_map`           positions coloured by their distance error: 3-D, x-y,   3
                      x-z (for ``evaluate``)
`residual_vs_joints`  residual against each joint angle (for ``diagnose``)    n
`residual_vs_         residual (length, or signed component along the fitted  one per
variables`            dependence) against each variable, strongest first      variable
====================  ======================================================  ======

Units: positions and errors in mm, joint angles given in rad and drawn in degrees.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from torchcal.errors import InputError
from torchcal.io.files import atomic_write, check_output
from viz import _common as C

DPI = 110
MAX_SCATTER = 20_000
MIN_BIN_POINTS = 5  # a joint-angle bin with fewer rows draws no RMS point (its dots show them)
"""Default cap on points drawn in a scatter (evenly spaced subsample beyond it)."""


def _rgb(c) -> tuple[float, float, float]:
    return tuple(float(v) / 255.0 for v in c)


def _new_figure(width_in: float, height_in: float, layout: str | None = "constrained") -> Figure:
    fig = Figure(figsize=(width_in, height_in), dpi=DPI, layout=layout)
    FigureCanvasAgg(fig)
    return fig


def _fixed_grid(fig: Figure, nrows: int, ncols: int, *, left: float, right: float, bottom: float, top: float,
                wspace: float, hspace: float, **kw) -> np.ndarray:
    """(nrows, ncols) axes of `fig` (made with ``layout=None``) placed by fixed margins and
    gaps, all in inches: no layout engine measures every tick label and title before the
    draw (the constrained layout of a 20-panel figure cost about as much as drawing it,
    docs/performance.md). `kw` goes to `Figure.subplots` (sharex, sharey)."""
    w, h = fig.get_size_inches()
    cell_w = (w - left - right - wspace * (ncols - 1)) / ncols
    cell_h = (h - top - bottom - hspace * (nrows - 1)) / nrows
    spec = {"left": left / w, "right": 1 - right / w, "bottom": bottom / h, "top": 1 - top / h,
            "wspace": wspace / cell_w, "hspace": hspace / cell_h}
    return fig.subplots(nrows, ncols, squeeze=False, gridspec_kw=spec, **kw)


OVERHANG = 0.15
"""Inches an x tick label at the right end of an axis (e.g. "150") can reach beyond it."""


def _widen_for_y_labels(fig: Figure, axes, beside: float, *, between: bool) -> None:
    """Widen the left margin (and, `between`, the gaps between the columns) of `fig`'s
    fixed grid (`_fixed_grid`, all `axes` on one grid) to the widest y tick label of `axes`
    plus `beside` inches (the y label and the pads; a gap also OVERHANG for the last x tick
    label of the panel to its left), where the fixed margins are narrower. The labels are those the locator and formatter will draw (default tick label size),
    the longest of each axes measured once; no tick artists are made."""
    from matplotlib import rcParams
    from matplotlib.text import Text

    renderer = fig.canvas.get_renderer()
    widest = 0.0
    for ax in axes:
        y = ax.yaxis
        lo, hi = sorted(y.get_view_interval())
        locs = [v for v in y.get_majorticklocs() if lo <= v <= hi]
        if locs:
            label = Text(text=max(y.get_major_formatter().format_ticks(locs), key=len),
                         fontsize=rcParams["ytick.labelsize"])
            label.set_figure(fig)
            widest = max(widest, label.get_window_extent(renderer).width / fig.dpi)
    need = widest + beside
    grid = axes[0].get_subplotspec().get_gridspec()
    w = fig.get_size_inches()[0]
    ncols = grid.ncols
    cell = (grid.right - grid.left) * w / (ncols + grid.wspace * (ncols - 1))
    gap = grid.wspace * cell
    if need <= grid.left * w and (not between or need + OVERHANG <= gap or ncols == 1):
        return
    left = max(grid.left * w, need)
    gap = max(gap, need + OVERHANG) if between else gap
    cell = (grid.right * w - left - gap * (ncols - 1)) / ncols
    grid.update(left=left / w, wspace=gap / cell)  # moves the axes of pyplot's figures only: place them here
    for ax in axes:
        ax.set_position(ax.get_subplotspec().get_position(fig))


def png_bytes(fig: Figure, dpi: int = DPI) -> bytes:
    """`fig` (made by `_new_figure`: an Agg canvas) rendered as PNG bytes (no metadata: the
    same figure gives the same bytes). Drawn once by the canvas (`print_png`: the
    constrained layout, then the pixels); `fig.savefig` draws a figure with a layout
    engine twice (a draw without rendering for the layout first), the same bytes for
    about 15 % more CPU (measured on the 31 figures the tests render, docs/performance.md)."""
    buf = io.BytesIO()
    before = fig.dpi
    fig.dpi = dpi
    try:
        fig.canvas.print_png(buf, metadata={"Software": None})
    finally:
        fig.dpi = before
    return buf.getvalue()


def save_figure(fig: Figure, path, force: bool = False) -> Path:
    """Render `fig` to PNG bytes and write them atomically to `path`; returns the path."""
    path = check_output(path, force)
    return atomic_write(path, png_bytes(fig), force=force)


# --------------------------------------------------------------------------- zone map
def _tagged(k: int, name: str) -> str:
    """Legend text of zone id `k`: its name, prefixed by its marker ``k + 1`` unless it says it."""
    tag = f"zone {k + 1}"
    return name if name == tag or name.startswith(tag + " ") else f"{k + 1}: {name}"


def zone_map(path, positions_mm, zones, *, centers_mm=None, zone_names=None, title: str = "Workspace zones",
             max_points: int | None = MAX_SCATTER, force: bool = False) -> Path:
    """Write `zone_map_figure` to the PNG `path` (atomically); returns the path.

    ``force`` replaces an existing file; the other arguments are `zone_map_figure`'s.
    """
    check_output(path, force)  # fail before drawing
    fig = zone_map_figure(positions_mm, zones, centers_mm=centers_mm, zone_names=zone_names, title=title,
                          max_points=max_points)
    return save_figure(fig, path, force)


def zone_map_figure(positions_mm, zones, *, centers_mm=None, zone_names=None, title: str = "Workspace zones",
                    max_points: int | None = MAX_SCATTER) -> Figure:
    """Zone map in three views: x-y (top), x-z (side), y-z (front), coloured by zone.

    Args:
        positions_mm: (N, 3) workspace points, mm, robot base frame.
        zones: (N,) integer zone id per point (0-based).
        centers_mm: (Z, 3) zone centers, mm; default: mean of each zone's points.
        zone_names: display name per zone id; default ``"zone k"`` (1-based, as in the paper).
        title: figure title.
        max_points: draw at most this many points (evenly spaced); None: all.

    Zone id k (0-based in the arrays) is marked ``k + 1`` at its center and in the legend.
        force: replace an existing file.

    Returns the figure (3 axes).
    """
    pos = C.points(positions_mm, "positions_mm")
    zs = C.labels(zones, "zones", pos.shape[0])
    names, centers = C.zone_centers(pos, zs, centers_mm, zone_names)
    count = len(names)
    rgb = C.zone_rgb(count) / 255.0
    idx = C.subsample(pos.shape[0], max_points)
    p, z = pos[idx], zs[idx]

    fig = _new_figure(15.0, 5.4)
    axes = fig.subplots(1, 3)
    views = (("x-y (top)", 0, 1), ("x-z (side)", 0, 2), ("y-z (front)", 1, 2))
    size = 14 if len(idx) <= 2000 else 4
    for ax, (label, i, j) in zip(axes, views):
        for k in range(count):
            m = z == k
            if m.any():
                ax.scatter(p[m, i], p[m, j], s=size, color=rgb[k], alpha=0.75, linewidths=0, rasterized=False)
        ok = np.isfinite(centers).all(axis=1)
        ax.scatter(centers[ok, i], centers[ok, j], s=150, marker="X", c=rgb[ok], edgecolors="black",
                   linewidths=1.2, zorder=3)
        for k in np.flatnonzero(ok):
            ax.annotate(str(k + 1), (centers[k, i], centers[k, j]), xytext=(6, 6), textcoords="offset points",
                        fontsize=9, fontweight="bold", zorder=4)
        ax.set_title(label)
        ax.set_xlabel(f"{C.AXES[i]} (mm)")
        ax.set_ylabel(f"{C.AXES[j]} (mm)")
        ax.set_aspect("equal", adjustable="box")
        ax.grid(True, alpha=0.3)
    handles = [Line2D([], [], marker="o", linestyle="", color=rgb[k], markersize=7, label=_tagged(k, names[k]))
               for k in range(count)]
    handles.append(Line2D([], [], marker="X", linestyle="", markerfacecolor="white", markeredgecolor="black",
                          markersize=10, label="zone centre"))
    fig.legend(handles=handles, loc="outside right center", frameon=False)
    fig.suptitle(f"{title} ({pos.shape[0]} points, {count} zones)")
    return fig


# --------------------------------------------------------------------------- R_set histogram
def rset_histogram(path, r_set, *, bins: int = 20, title: str = "Set reliability R_set over the workspace",
                   force: bool = False) -> Path:
    """Write `rset_histogram_figure` to the PNG `path` (atomically); returns the path."""
    check_output(path, force)  # fail before drawing
    return save_figure(rset_histogram_figure(r_set, bins=bins, title=title), path, force)


def rset_histogram_figure(r_set, *, bins: int = 20,
                          title: str = "Set reliability R_set over the workspace") -> Figure:
    """Histogram of R_set (1 = fully reliable), bars coloured red (low) to green (high).

    Args:
        r_set: (N,) set reliability per workspace point, in [0, 1].
        bins: number of bins over the data range.
        title: figure title.

    Returns the figure (1 axes).
    """
    rs = C.vector(r_set, "r_set")
    if rs.size == 0:
        raise InputError("r_set: expected at least one value, got none")
    if isinstance(bins, bool) or not isinstance(bins, (int, np.integer)) or bins < 1:
        raise InputError(f"bins: expected a positive integer, got {bins!r}")
    lo, hi = C.rset_range(rs, None)
    fig = _new_figure(7.5, 4.5)
    ax = fig.subplots()
    edges = np.linspace(lo, hi, bins + 1) if rs.max() > rs.min() else np.linspace(rs.min() - 0.01,
                                                                                     rs.max() + 0.01, bins + 1)
    counts, edges = np.histogram(rs, bins=edges)
    center = (edges[:-1] + edges[1:]) / 2
    ax.bar(center, counts, width=np.diff(edges), color=C.rset_rgb(center, lo, hi) / 255.0,
           edgecolor="black", linewidth=0.5)
    ax.axvline(rs.mean(), color="black", linestyle="--", linewidth=1.2, label=f"mean {rs.mean():.3f}")
    share = float((rs >= 1.0 - 1e-12).mean())
    ax.plot([], [], linestyle="", label=f"min {rs.min():.3f}, max {rs.max():.3f}")
    ax.plot([], [], linestyle="", label=f"R_set = 1: {100 * share:.1f}% of points")
    ax.set_xlabel("R_set (set reliability, 1 = fully reliable)")
    ax.set_ylabel("number of workspace points")
    ax.set_title(f"{title} ({rs.size} points)")
    ax.legend(loc="upper left", frameon=False)
    ax.grid(True, axis="y", alpha=0.3)
    return fig


# --------------------------------------------------------------------------- error intervals (Fig. 11)
def error_intervals(path, before_lower_mm, before_upper_mm, after_lower_mm=None, after_upper_mm=None, *,
                    allowed_mm: float | None = 1.0,
                    title: str = "Error interval per test point, before and after compensation",
                    after_name: str = "after", also=(), force: bool = False) -> Path:
    """Write `error_intervals_figure` to the PNG `path` (atomically); returns the path."""
    check_output(path, force)  # fail before drawing
    fig = error_intervals_figure(before_lower_mm, before_upper_mm, after_lower_mm, after_upper_mm,
                                 allowed_mm=allowed_mm, title=title, after_name=after_name, also=also)
    return save_figure(fig, path, force)


def error_intervals_figure(before_lower_mm, before_upper_mm, after_lower_mm=None, after_upper_mm=None, *,
                           allowed_mm: float | None = 1.0,
                           title: str = "Error interval per test point, before and after compensation",
                           after_name: str = "after", also=()) -> Figure:
    """Error-interval bars per test point and axis, before and after compensation (Fig. 11).

    Args:
        before_lower_mm, before_upper_mm: (T, 3) lower / upper x, y, z error per test
            point before compensation, mm.
        after_lower_mm, after_upper_mm: (T, 3) the same after compensation, or both None.
        allowed_mm: allowed component error, shaded as the band +-allowed_mm; None: none.
        title: figure title.
        after_name: legend name of the "after" bars.
        also: further (name, lower (T, 3), upper (T, 3)) after compensation by other
            methods, drawn beside "after" (at most 3).

    Returns the figure: 3 axes (x, y, z), test points numbered 1..T.
    """
    b_lo, b_hi = C.intervals(before_lower_mm, before_upper_mm, "before", None)
    if (after_lower_mm is None) != (after_upper_mm is None):
        raise InputError("after_lower_mm, after_upper_mm: give both or neither")
    stages = [("before", b_lo, b_hi, _rgb(C.BEFORE_RGB))]
    if after_lower_mm is not None:
        a_lo, a_hi = C.intervals(after_lower_mm, after_upper_mm, "after", b_lo.shape[0])
        stages.append((after_name, a_lo, a_hi, _rgb(C.AFTER_RGB)))
    if len(also) > len(C.ALSO_RGB):
        raise InputError(f"also: at most {len(C.ALSO_RGB)} further methods, got {len(also)}")
    for (name, lo, hi), rgb in zip(also, C.ALSO_RGB):
        stages.append((name, *C.intervals(lo, hi, name, b_lo.shape[0]), _rgb(rgb)))
    if allowed_mm is not None and not (np.isfinite(allowed_mm) and allowed_mm > 0):
        raise InputError(f"allowed_mm: expected a positive number of mm or None, got {allowed_mm!r}")
    t = np.arange(1, b_lo.shape[0] + 1)
    n_t = len(t)
    fig = _new_figure(max(8.0, min(16.0, 0.45 * n_t + 3.0)), 8.0)
    axes = fig.subplots(3, 1, sharex=True)
    offset = 0.34 / len(stages) if len(stages) > 1 else 0.0
    for a, ax in enumerate(axes):
        if allowed_mm is not None:
            ax.axhspan(-allowed_mm, allowed_mm, color=_rgb(C.ALLOWED_RGB), alpha=0.15, linewidth=0,
                       label=f"allowed ±{allowed_mm:g} mm")
            for s in (-1, 1):
                ax.axhline(s * allowed_mm, color=_rgb(C.ALLOWED_RGB), linestyle="--", linewidth=0.9)
        ax.axhline(0.0, color="black", linewidth=0.6)
        for s, (stage, lo, hi, col) in enumerate(stages):
            x = t + (s - (len(stages) - 1) / 2) * 2 * offset
            ax.vlines(x, lo[:, a], hi[:, a], color=col, linewidth=3.0 if len(stages) <= 2 else 2.2, label=stage)
            ax.scatter(np.r_[x, x], np.r_[lo[:, a], hi[:, a]], marker="_", s=60, color=col, linewidths=1.5)
        ax.set_ylabel(f"{C.AXES[a]} error (mm)")
        ax.grid(True, axis="y", alpha=0.3)
    axes[-1].set_xlabel("test point")
    if n_t <= 40:
        axes[-1].set_xticks(t)
    axes[-1].set_xlim(0.4, n_t + 0.6)
    handles, labels_ = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels_, loc="outside lower center", ncols=len(handles), frameon=False)
    fig.suptitle(title)
    return fig


# --------------------------------------------------------------------------- error map
def error_map(path, positions_mm, error_mm, *, title: str = "Distance error over the workspace",
              force: bool = False) -> Path:
    """Write `error_map_figure` to the PNG `path` (atomically); returns the path."""
    check_output(path, force)  # fail before drawing
    return save_figure(error_map_figure(positions_mm, error_mm, title=title), path, force)


def error_map_figure(positions_mm, error_mm, *, title: str = "Distance error over the workspace") -> Figure:
    """Where the error is: the measured positions coloured by their distance error.

    Args:
        positions_mm: (N, 3) TCP positions, mm (the measurement frame).
        error_mm: (N,) distance error |measured - model| per row, mm.
        title: figure title.

    Returns the figure: a 3-D view and the x-y (top) and x-z (side) views, one colour
    scale (0 .. the 99th percentile, `viz._common.error_scale`; the largest errors drawn
    on top and ringed).
    """
    pos = C.points(positions_mm, "positions_mm")
    e = C.vector(error_mm, "error_mm", len(pos))
    top = C.error_scale(e)
    order = np.argsort(e)  # the largest errors drawn last, on top
    worst = order[-min(5, len(order)):] if len(order) else order
    fig = _new_figure(16.0, 5.6, layout=None)
    # fixed places (fractions of the 16 x 5.6 in figure: those the constrained layout gave
    # before, without its pass over every label): the 3-D view, the x-y and x-z views, the
    # colour scale; the suptitle above
    ax3 = fig.add_axes((0.0, 0.03, 0.33, 0.88), projection="3d")
    ax3.set_box_aspect(None, zoom=0.82)  # room for the z label beside the next panel
    sc = ax3.scatter(pos[order, 0], pos[order, 1], pos[order, 2], c=e[order], cmap=C.ERROR_CMAP, vmin=0.0,
                     vmax=top, s=8, depthshade=False)
    ax3.set_xlabel("x (mm)", labelpad=8)
    ax3.set_ylabel("y (mm)", labelpad=10)
    ax3.set_zlabel("z (mm)", labelpad=8)
    ax3.scatter(pos[worst, 0], pos[worst, 1], pos[worst, 2], s=60, facecolors="none", edgecolors="tab:blue",
                linewidths=1.0, depthshade=False)
    ax3.set_title("3-D")
    for k, (i, j, lab) in enumerate([(0, 1, "x-y (top)"), (0, 2, "x-z (side)")]):
        ax = fig.add_axes((0.376 + 0.296 * k, 0.086, 0.248, 0.827))
        ax.scatter(pos[order, i], pos[order, j], c=e[order], cmap=C.ERROR_CMAP, vmin=0.0, vmax=top, s=8)
        ax.scatter(pos[worst, i], pos[worst, j], s=60, facecolors="none", edgecolors="tab:blue", linewidths=1.0,
                   label=f"{len(worst)} largest")
        ax.set_xlabel("xyz"[i] + " (mm)")
        ax.set_ylabel("xyz"[j] + " (mm)")
        ax.set_title(lab)
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
    fig.axes[-1].legend(loc="upper right", fontsize=8)
    fig.colorbar(sc, cax=fig.add_axes((0.945, 0.127, 0.012, 0.744)),
                 label=f"distance error (mm; scale to the 99th percentile, {top:.3g})")
    fig.suptitle(f"{title}: {len(e)} rows, RMS {float(np.sqrt(np.mean(e ** 2))) if len(e) else 0.0:.4g} mm, "
                 f"max {float(e.max()) if len(e) else 0.0:.4g} mm", y=0.99, va="top")
    return fig


# --------------------------------------------------------------------------- error histogram
def error_histogram_figure(before_mm, after_mm, *, tolerance_mm: float | None = None, bins: int = 40,
                           title: str = "Distance error before and after calibration") -> Figure:
    """Histograms of the distance error before_mm (N,) and after_mm (M,) mm on one axis
    (shared bins from 0 to the largest error), their RMS and 95th percentiles marked, and
    the tolerance as a vertical line when given."""
    b = C.vector(before_mm, "before_mm")
    a = C.vector(after_mm, "after_mm")
    top = max(float(b.max(initial=0.0)), float(a.max(initial=0.0)), tolerance_mm or 0.0) * 1.02 or 1.0
    edges = np.linspace(0.0, top, bins + 1)
    fig = _new_figure(8.0, 3.6)
    ax = fig.add_subplot(1, 1, 1)
    for v, name, rgb in ((b, "before", C.BEFORE_RGB), (a, "after", C.AFTER_RGB)):
        rms, p95 = float(np.sqrt(np.mean(v ** 2))), float(np.percentile(v, 95))
        ax.hist(v, bins=edges, color=_rgb(rgb), alpha=0.55, label=f"{name}: RMS {rms:.3f} mm, p95 {p95:.3f} mm")
        ax.axvline(p95, color=_rgb(rgb), linestyle=":", linewidth=1.2)
    if tolerance_mm is not None:
        ax.axvline(tolerance_mm, color="black", linewidth=1.5, label=f"tolerance {tolerance_mm:g} mm")
    ax.set_xlabel("distance error |measured - model| (mm); dotted: 95th percentile")
    ax.set_ylabel("rows")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    fig.suptitle(title)
    return fig


# --------------------------------------------------------------------------- residual vs joints
def residual_vs_joints(path, q_rad, residual_mm, *, joint_names: Sequence[str] | None = None, bins: int = 12,
                       title: str = "Residual against each joint angle", max_points: int | None = MAX_SCATTER,
                       prismatic=None, force: bool = False) -> Path:
    """Write `residual_vs_joints_figure` to the PNG `path` (atomically); returns the path."""
    check_output(path, force)  # fail before drawing
    fig = residual_vs_joints_figure(q_rad, residual_mm, joint_names=joint_names, bins=bins, title=title,
                                    max_points=max_points, prismatic=prismatic)
    return save_figure(fig, path, force)


def residual_vs_joints_figure(q_rad, residual_mm, *, joint_names: Sequence[str] | None = None, bins: int = 12,
                              title: str = "Residual against each joint angle",
                              max_points: int | None = MAX_SCATTER, prismatic=None) -> Figure:
    """Residual against each joint angle, one subplot per joint (for ``diagnose``).

    A trend here points at a missing joint effect: a slope or bow against q2/q3 at
    compliance, a sinusoid at a periodic gear error, two bands at backlash.

    Args:
        q_rad: (N, n) joint angles, rad (drawn in degrees); mm for a prismatic joint.
        residual_mm: (N,) residual length, or (N, 3) residual vector (measured - model), mm.
            Components are drawn as x/y/z dots; the black line is the RMS residual length
            per bin of the joint angle.
        joint_names: n names; default ``"q1".."qn"``.
        bins: number of joint-angle bins for the RMS line; a bin of fewer than MIN_BIN_POINTS
            rows has no RMS point (the line breaks there; its rows are drawn as dots).
        title: figure title.
        max_points: draw at most this many dots per subplot (evenly spaced); None: all.
        prismatic: (n,) bool, the prismatic joints (drawn in mm as given); default none.

    Returns the figure (n axes).
    """
    q = C.to_numpy(q_rad, "q_rad")
    if q.ndim != 2 or q.shape[1] < 1:
        raise InputError(f"q_rad: expected shape (N, n) in rad, got {tuple(q.shape)}")
    if not np.isfinite(q).all():
        raise InputError("q_rad: contains NaN or infinite values")
    n_pts, n_j = q.shape
    r = C.to_numpy(residual_mm, "residual_mm")
    if r.ndim == 1 and r.shape[0] == n_pts:
        comps, norm = None, np.abs(r)
    elif r.ndim == 2 and r.shape == (n_pts, 3):
        comps, norm = r, np.linalg.norm(r, axis=1)
    else:
        raise InputError(f"residual_mm: expected shape ({n_pts},) or ({n_pts}, 3) in mm (one row per row of q_rad), "
                         f"got {tuple(r.shape)}")
    if not np.isfinite(r).all():
        raise InputError("residual_mm: contains NaN or infinite values")
    if joint_names is None:
        joint_names = [f"q{j + 1}" for j in range(n_j)]
    elif len(joint_names) != n_j:
        raise InputError(f"joint_names: expected {n_j} names (one per joint), got {len(joint_names)}")
    if isinstance(bins, bool) or not isinstance(bins, (int, np.integer)) or bins < 1:
        raise InputError(f"bins: expected a positive integer, got {bins!r}")
    slide = np.zeros(n_j, dtype=bool) if prismatic is None else np.asarray(prismatic, dtype=bool).reshape(-1)
    if slide.shape != (n_j,):
        raise InputError(f"prismatic: expected {n_j} flags (one per joint), got {slide.shape[0]}")
    q_deg = np.where(slide, q, np.degrees(q))  # deg; mm for a prismatic joint
    idx = C.subsample(n_pts, max_points)
    ncols = min(3, n_j)
    nrows = -(-n_j // ncols)
    fig = _new_figure(4.6 * ncols, 3.4 * nrows + 0.6, layout=None)
    # fixed margins (in): y tick labels + label left, x tick labels + label + the legend below,
    # the title and suptitle above; shared y: no tick labels between the columns
    axes = _fixed_grid(fig, nrows, ncols, left=0.8, right=0.15, bottom=0.95, top=0.6, wspace=0.3, hspace=0.8,
                       sharey=True).ravel()
    for extra in axes[n_j:]:
        fig.delaxes(extra)
    comp_rgb = [_rgb(C.MEASURED_RGB), _rgb(C.MODEL_BEFORE_RGB), _rgb(C.AFTER_RGB)]
    size = 10 if len(idx) <= 2000 else 3
    for j in range(n_j):
        ax = axes[j]
        x = q_deg[idx, j]
        if comps is None:
            ax.scatter(x, norm[idx], s=size, color="0.55", alpha=0.7, linewidths=0, label="|residual|")
        else:
            for a in range(3):
                ax.scatter(x, comps[idx, a], s=size, color=comp_rgb[a], alpha=0.6, linewidths=0,
                           label=f"{C.AXES[a]} component")
        lo, hi = q_deg[:, j].min(), q_deg[:, j].max()
        if hi > lo:
            edges = np.linspace(lo, hi, bins + 1)
            which = np.clip(np.digitize(q_deg[:, j], edges) - 1, 0, bins - 1)
            ms = np.bincount(which, weights=norm ** 2, minlength=bins)
            cnt = np.bincount(which, minlength=bins)
            ok = cnt >= MIN_BIN_POINTS  # one row is no RMS: the line breaks at thin bins
            centre = (edges[:-1] + edges[1:]) / 2
            line = np.where(ok, np.sqrt(ms / np.maximum(cnt, 1)), np.nan)
            ax.plot(centre, line, color="black", linewidth=1.8, marker="o", markersize=3,
                    label=f"RMS |residual| per bin (of {MIN_BIN_POINTS}+ poses)")
        ax.axhline(0.0, color="black", linewidth=0.5)
        ax.set_xlabel(f"{joint_names[j]} ({'mm' if slide[j] else 'deg'})")
        if j % ncols == 0:
            ax.set_ylabel("residual (mm)")
        ax.set_title(f"joint {j + 1}" if joint_names[j] == f"q{j + 1}" else joint_names[j])
        ax.grid(True, alpha=0.3)
    _widen_for_y_labels(fig, axes[:n_j], 0.35, between=False)  # shared y: labels in the first column only
    handles, labels_ = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels_, loc="lower center", ncols=len(handles), frameon=False, markerscale=2.0,
               bbox_to_anchor=(0.5, 0.0))
    fig.suptitle(f"{title} ({n_pts} poses, RMS {np.sqrt(np.mean(norm ** 2)):.3f} mm)")
    return fig


def residual_vs_variables(path, values, residual_mm, strengths, *, correlates=(), components=None, title: str =
                          "Residual against each variable, strongest dependence first",
                          max_points: int | None = MAX_SCATTER, prismatic=(), force: bool = False) -> Path:
    """Write `residual_vs_variables_figure` to the PNG `path` (atomically); returns the path."""
    check_output(path, force)
    fig = residual_vs_variables_figure(values, residual_mm, strengths, correlates=correlates, components=components,
                                       title=title, max_points=max_points, prismatic=prismatic)
    return save_figure(fig, path, force)


def residual_vs_variables_figure(values, residual_mm, strengths, *, correlates=(), components=None, title: str =
                                 "Residual against each variable, strongest dependence first",
                                 max_points: int | None = MAX_SCATTER, prismatic=()) -> Figure:
    """Residual against every variable of `torchcal.diagnosis.unexplained` (joint
    angles, temperature, payload, measurement order, approach direction per joint), one
    panel per variable, ordered by strength (held-out R^2), strongest first.

    Args:
        values: {name: (N,) values} (joint angles in rad, drawn in degrees; the joints named
            in `prismatic`, e.g. {"q3"}, and the others as given, with their unit).
        residual_mm: (N, 3) residual vectors (or (N,) lengths), mm.
        strengths: {name: strength}; panels for the names in `values`, by strength descending.
        correlates: names found significant: their panel titles carry "*" and a red frame.
        components: {name: (N,) mm}: the signed residual component drawn for that variable
            instead of the length (see `torchcal.diagnosis.dependence`); the y label says which.

    Returns the figure; its axes are in panel order, each titled "NAME  R2 s" (`r2_text`).
    """
    panels = C.variable_panels(values, residual_mm, strengths, correlates, components, prismatic)
    n = len(panels[0]["y"]) if panels else 0
    idx = C.subsample(n, max_points)
    ncols = min(4, max(len(panels), 1))
    nrows = -(-max(len(panels), 1) // ncols)
    fig = _new_figure(3.8 * ncols, 2.9 * nrows + 0.6, layout=None)
    # fixed margins and gaps (in): y tick labels + label beside each panel, x tick labels +
    # label and the next panel's title between the rows, the suptitle above
    axes = _fixed_grid(fig, nrows, ncols, left=0.8, right=0.1, bottom=0.5, top=0.7, wspace=0.87,
                       hspace=0.75).ravel()
    for ax, p in zip(axes, panels):
        ax.plot(p["x"][idx], p["y"][idx], ".", ms=2, color="0.35")
        if not p["y_label"].startswith("|"):
            ax.axhline(0.0, color="black", linewidth=0.5)
        mark = p["significant"]
        ax.set_title(f"{'* ' if mark else ''}{p['name']}  R2 {C.r2_text(p['strength'])}",
                     color="red" if mark else "black", fontsize=9)
        if mark:
            for sp in ax.spines.values():
                sp.set_color("red")
                sp.set_linewidth(2)
        ax.set_xlabel(p["x_label"], fontsize=8)
        ax.set_ylabel(p["y_label"], fontsize=7 if len(p["y_label"]) > 20 else 8)
    for ax in axes[len(panels):]:
        ax.set_visible(False)
    _widen_for_y_labels(fig, axes[:max(len(panels), 1)], 0.3, between=True)
    fig.suptitle(title, y=1 - 0.1 / fig.get_size_inches()[1], va="top")
    return fig
