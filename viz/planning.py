"""Figures of `torchcal plan` and `torchcal accuracy` (matplotlib Agg, written atomically).

====================  ===================================================  ======
`plan_poses`          candidates (grey) and the chosen poses in their        2
                      measuring order (numbered path), x-y and x-z
`criterion_vs_n`      design criterion of the greedy plan vs N, and of       1
                      random plans of the same size
`accuracy_map`        predicted TCP sigma over the workspace, x-y and x-z     2
`accuracy_histogram`  histogram of the predicted TCP sigma                  1
`log_accuracy`        rerun recording: workspace points coloured by sigma    -
====================  ===================================================  ======

Positions in mm (base frame), sigma in mm.
"""

from __future__ import annotations

import numpy as np

from viz import _common as C
from viz.figures import _new_figure, save_figure


def plan_poses(path, candidates_mm, chosen_mm, *, force: bool = False):
    cand = C.points(candidates_mm, "candidates_mm")
    ch = C.points(chosen_mm, "chosen_mm")
    fig = _new_figure(11, 5)
    axes = fig.subplots(1, 2)
    keep = C.subsample(len(cand), 5000)
    for ax, (i, j, lab) in zip(axes, [(0, 1, "x-y (top)"), (0, 2, "x-z (side)")]):
        ax.scatter(cand[keep, i], cand[keep, j], s=2, c="0.8", label=f"candidates ({len(cand)})")
        ax.plot(ch[:, i], ch[:, j], "-", color="tab:blue", lw=0.6, alpha=0.6)
        sc = ax.scatter(ch[:, i], ch[:, j], s=18, c=np.arange(len(ch)), cmap="viridis", zorder=3,
                        label=f"chosen ({len(ch)}), colour = order")
        ax.set_xlabel("xyz"[i] + " (mm)")
        ax.set_ylabel("xyz"[j] + " (mm)")
        ax.set_title(lab)
        ax.set_aspect("equal", adjustable="datalim")
    axes[0].legend(loc="upper right", fontsize=7)
    fig.colorbar(sc, ax=axes[1], label="measuring order")
    fig.suptitle("Planned measurement poses (TCP positions)")
    return save_figure(fig, path, force=force)


def criterion_vs_n(path, ns, plan_values, random_values, criterion: str, *, force: bool = False):
    fig = _new_figure(6, 4)
    ax = fig.subplots()
    def _xy(vals):
        pts = [(n, v) for n, v in zip(ns, vals) if v is not None]
        return [p[0] for p in pts], [p[1] for p in pts]
    ax.plot(*_xy(plan_values), "-", color="tab:blue", label="planned (greedy, before exchange)")
    ax.plot(*_xy(random_values), "--", color="tab:orange", label="random (mean of 5)")
    ax.set_xlabel("number of poses N")
    ax.set_ylabel({"D": "log det M (scaled)", "O1": "O1", "E": "smallest eigenvalue of M"}[criterion])
    ax.set_title(f"Criterion {criterion} vs N")
    ax.legend()
    ax.grid(alpha=0.3)
    return save_figure(fig, path, force=force)


def accuracy_map(path, positions_mm, sigma_mm, *, title="Predicted TCP sigma (1-sigma, mm)", force=False):
    pos = C.points(positions_mm, "positions_mm")
    s = C.vector(sigma_mm, "sigma_mm", len(pos))
    fig = _new_figure(11, 5)
    axes = fig.subplots(1, 2)
    order = np.argsort(s)  # worst drawn last, on top
    for ax, (i, j, lab) in zip(axes, [(0, 1, "x-y (top)"), (0, 2, "x-z (side)")]):
        sc = ax.scatter(pos[order, i], pos[order, j], c=s[order], s=6, cmap="magma_r")
        ax.set_xlabel("xyz"[i] + " (mm)")
        ax.set_ylabel("xyz"[j] + " (mm)")
        ax.set_title(lab)
        ax.set_aspect("equal", adjustable="datalim")
    fig.colorbar(sc, ax=axes[1], label="sigma (mm)")
    fig.suptitle(title)
    return save_figure(fig, path, force=force)


def accuracy_histogram(path, sigma_mm, *, bins: int = 30, force: bool = False):
    s = C.vector(sigma_mm, "sigma_mm")
    fig = _new_figure(6, 4)
    ax = fig.subplots()
    ax.hist(s, bins=bins, color="tab:purple", alpha=0.8)
    for q, ls in ((50, "-"), (95, "--")):
        v = np.percentile(s, q)
        ax.axvline(v, color="k", ls=ls, lw=1, label=f"{q}th percentile {v:.4f} mm")
    ax.set_xlabel("predicted TCP sigma (mm)")
    ax.set_ylabel("workspace points")
    ax.set_title(f"Predicted TCP sigma over {len(s)} workspace points")
    ax.legend()
    return save_figure(fig, path, force=force)


def log_accuracy(path, positions_mm, sigma_mm, *, seed: int = 0, force: bool = False):
    """A rerun recording: the workspace points coloured by sigma (blue low .. red high)."""
    import rerun as rr
    import rerun.blueprint as rrb

    from viz.recording import RecordingWriter

    pos = C.points(positions_mm, "positions_mm")
    s = C.vector(sigma_mm, "sigma_mm", len(pos))
    u = (s - s.min()) / max(float(np.ptp(s)), 1e-300)
    rgb = (np.stack([u, 0.2 * np.ones_like(u), 1 - u], -1) * 255).astype(np.uint8)
    bp = rrb.Blueprint(rrb.Spatial3DView(origin="/accuracy", name="predicted TCP sigma"))
    with RecordingWriter(path, seed=seed, blueprint=bp, force=force) as rec:
        rec.stream.log("accuracy/points", rr.Points3D(pos, colors=rgb, radii=np.full(len(pos), 8.0)),
                       static=True)
        rec.stream.log("accuracy/sigma_mm", rr.AnyValues(sigma_mm=s), static=True)
    return path
