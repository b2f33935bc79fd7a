"""Accuracy figures of position errors, as a calibration report and the standards name them.

`error_summary`: mean, RMS, 95th percentile and maximum of the distance error and of each
axis; `evaluate` prints it and `torchcal report` tabulates it (one function for both).

`iso9283`: pose accuracy AP and pose repeatability RP in the sense of ISO 9283:1998
(sections 7.2.1 and 7.2.2), computed for every pose of the data instead of the standard's
five cube poses: for a pose with rows j = 1..n (its repeats; several reflectors are kept
apart by ``point``), with e_j = measured - commanded (commanded: the model's position),

    AP = |mean_j e_j|                        (AP_x, AP_y, AP_z: the components of the mean)
    l_j = |e_j - mean_j e_j|, RP = l_bar + 3 S_l,  S_l = sqrt(sum (l_j - l_bar)^2 / (n - 1))

RP needs repeats: it is computed for poses with at least 3 rows. docs/report.md says
how this differs from the standard's test procedure.

`tolerance_verdict`: pass or fail per pose (every row of the pose within the tolerance)
and overall (every pose passes).

Inputs are tensors on any device; errors in mm; the results are plain floats (JSON-ready).
"""

from __future__ import annotations

import torch

__all__ = ["error_summary", "iso9283", "pose_groups", "tolerance_verdict"]

AXES = ("x", "y", "z")


def _figures(v: torch.Tensor) -> dict:
    """{"mean_mm", "rms_mm", "p95_mm", "max_mm"} of the values v (N,) >= 0 mm (p95: linear
    interpolation between order statistics)."""
    return {"mean_mm": float(v.mean()), "rms_mm": float(v.pow(2).mean().sqrt()),
            "p95_mm": float(torch.quantile(v, 0.95)), "max_mm": float(v.max())}


def error_summary(residuals_mm: torch.Tensor) -> dict:
    """Figures of errors residuals_mm (N, 3) mm (measured - model):
    {"n", "mean_mm", "rms_mm", "p95_mm", "max_mm"} of the distance |e|, and "axes":
    {"x": {"bias_mm", "mean_mm", "rms_mm", "p95_mm", "max_mm"}, "y", "z"} of |e_x| ... with
    the signed mean of each component as its bias."""
    e = residuals_mm.detach().to("cpu", torch.float64)
    if e.ndim != 2 or e.shape[-1] != 3 or e.shape[0] == 0:
        raise ValueError(f"residuals_mm: expected shape (N, 3) with N >= 1, got {tuple(e.shape)}")
    out = {"n": int(e.shape[0]), **_figures(e.norm(dim=-1)), "axes": {}}
    for k, a in enumerate(AXES):
        out["axes"][a] = {"bias_mm": float(e[:, k].mean()), **_figures(e[:, k].abs())}
    return out


def pose_groups(pose: torch.Tensor, point: torch.Tensor | None = None) -> tuple[torch.Tensor, list]:
    """(group (N,) int64, keys): the group of each row, one per (pose id, point id) in order
    of first appearance; keys[g] = pose id, or (pose id, point id) when point is given."""
    pose = pose.detach().to("cpu", torch.int64)
    cols = pose[:, None] if point is None else torch.stack([pose, point.detach().to("cpu", torch.int64)], 1)
    uniq, inverse = torch.unique(cols, dim=0, return_inverse=True)
    first = torch.full((len(uniq),), len(pose), dtype=torch.int64).scatter_reduce(
        0, inverse, torch.arange(len(pose)), "amin")
    order = torch.argsort(first)
    rank = torch.empty_like(order)
    rank[order] = torch.arange(len(order))
    keys = [int(u[0]) if point is None else (int(u[0]), int(u[1])) for u in uniq[order].tolist()]
    return rank[inverse], keys


def iso9283(residuals_mm: torch.Tensor, group: torch.Tensor, keys=None) -> dict:
    """AP and RP per pose (module doc) of errors residuals_mm (N, 3) mm grouped by group (N,)
    int64 0..G-1 (`pose_groups`); keys: the pose names of the groups (default 0..G-1).

    Returns {"poses", "cycles": {"min", "max"} rows per pose, "ap_mm": {"mean", "max"} over
    the poses, "poses_with_repeats", "rp_mm": {"mean", "max"} over the poses with >= 3 rows
    (None without any), "per_pose": [{"pose", "n", "ap_mm", "ap_xyz_mm", "rp_mm" (None
    below 3 rows)}...]}."""
    e = residuals_mm.detach().to("cpu", torch.float64)
    g = group.detach().to("cpu", torch.int64)
    G = int(g.max()) + 1
    keys = list(range(G)) if keys is None else list(keys)
    n = torch.bincount(g, minlength=G).to(e.dtype)
    mean = torch.zeros(G, 3, dtype=e.dtype).index_add_(0, g, e) / n[:, None]  # (G, 3) barycentre - commanded
    ap = mean.norm(dim=-1)
    lj = (e - mean[g]).norm(dim=-1)  # distance of each row from its pose's barycentre
    lbar = torch.zeros(G, dtype=e.dtype).index_add_(0, g, lj) / n
    var = torch.zeros(G, dtype=e.dtype).index_add_(0, g, (lj - lbar[g]) ** 2) / (n - 1).clamp_min(1)
    rp = lbar + 3 * var.sqrt()
    has = n >= 3
    per_pose = [{"pose": keys[i], "n": int(n[i]), "ap_mm": float(ap[i]), "ap_xyz_mm": mean[i].tolist(),
                 "rp_mm": float(rp[i]) if has[i] else None} for i in range(G)]
    return {"poses": G, "cycles": {"min": int(n.min()), "max": int(n.max())},
            "ap_mm": {"mean": float(ap.mean()), "max": float(ap.max())},
            "poses_with_repeats": int(has.sum()),
            "rp_mm": {"mean": float(rp[has].mean()), "max": float(rp[has].max())} if bool(has.any()) else None,
            "per_pose": per_pose}


def tolerance_verdict(distance_mm: torch.Tensor, group: torch.Tensor, tolerance_mm: float, keys=None) -> dict:
    """Pass or fail against a distance tolerance: a pose (group, `pose_groups`) passes when
    every one of its rows has distance_mm (N,) <= tolerance_mm.

    Returns {"tolerance_mm", "passed" (every pose passes), "poses", "poses_failed",
    "rows", "rows_failed", "worst_mm", "failed": [{"pose", "max_mm"}...] worst first}."""
    d = distance_mm.detach().to("cpu", torch.float64)
    g = group.detach().to("cpu", torch.int64)
    G = int(g.max()) + 1
    keys = list(range(G)) if keys is None else list(keys)
    worst = torch.full((G,), -1.0, dtype=d.dtype).scatter_reduce(0, g, d, "amax")
    bad = torch.nonzero(worst > tolerance_mm).flatten()
    bad = bad[torch.argsort(worst[bad], descending=True)]
    return {"tolerance_mm": float(tolerance_mm), "passed": bool(len(bad) == 0), "poses": G,
            "poses_failed": int(len(bad)), "rows": int(len(d)), "rows_failed": int((d > tolerance_mm).sum()),
            "worst_mm": float(d.max()), "failed": [{"pose": keys[i], "max_mm": float(worst[i])} for i in bad.tolist()]}
