"""A synthetic but realistic example for the README figure and for trying the plots.

The KR 1000 Titan's nominal forward kinematics places 400 random poses in its workspace;
a made-up distance-error interval grows towards the edge of the workspace (as in the
paper, level 1 at the center, level 4 at the edge), R_set = min(1, 2.5 / s_upper) as in
docs/paper.md Table 3; 4 levels by R_set quantiles, then 3/2/3/2 sub-zones in space by k-means
(10 zones). Error intervals of 20 test points and residuals are made up as well. None of
this is a calibration result: `torchcal demo` produces the real ones.

    python -m viz._example OUTDIR      # writes every figure and example.rrd into OUTDIR
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch


def make_example(seed: int = 0, n: int = 400) -> dict[str, np.ndarray]:
    """Synthetic workspace, zones, intervals and residuals (mm, rad); deterministic in `seed`."""
    from sklearn.cluster import KMeans

    from torchcal.io.robot_file import robot

    rng = np.random.default_rng(seed)
    kr = robot("kr1000titan")
    lim = kr.limits.numpy()
    # a front sector of the workspace: q1 +-60 deg, q2/q3 inside their limits, wrist moderate
    lo = np.array([-np.pi / 3, lim[1, 0] * 0.7, lim[2, 0] * 0.5, -np.pi / 2, -np.pi / 2, -np.pi])
    hi = np.array([np.pi / 3, lim[1, 1] * 0.5, lim[2, 1] * 0.7, np.pi / 2, np.pi / 2, np.pi])
    q = lo + (hi - lo) * rng.random((n, 6))  # (n, 6) rad
    pos = kr.fk(torch.as_tensor(q)).numpy()  # (n, 3) mm
    keep = pos[:, 2] > 0.0
    q, pos = q[keep], pos[keep]
    center = np.median(pos, axis=0)
    d = np.linalg.norm((pos - center) / pos.std(axis=0), axis=1)
    s_upper = 1.4 + 2.1 * (d / d.max()) ** 1.2 + 0.08 * rng.standard_normal(len(d))
    r_set = np.minimum(1.0, 2.5 / s_upper)
    # level 0 = most reliable; then sub-zones in space
    level = np.digitize(s_upper, np.quantile(s_upper, [0.25, 0.5, 0.75]))
    zones = np.zeros(len(d), dtype=np.int64)
    next_id = 0
    for lev, k in zip(range(4), (3, 2, 3, 2)):
        m = level == lev
        sub = KMeans(n_clusters=k, n_init=4, random_state=seed).fit_predict(pos[m] / 1000.0)
        zones[m] = next_id + sub
        next_id += k
    names = [f"zone {z + 1} (level {lev + 1})" for lev, k in zip(range(4), (3, 2, 3, 2)) for z in
             range(sum((3, 2, 3, 2)[:lev]), sum((3, 2, 3, 2)[:lev]) + k)]

    t = 20
    width_b = rng.uniform(0.6, 1.4, (t, 3))
    center_b = rng.uniform(-0.9, 0.9, (t, 3))
    width_a = width_b * rng.uniform(0.35, 0.6, (t, 3))
    center_a = center_b * rng.uniform(0.1, 0.3, (t, 3))
    pick = rng.choice(len(d), size=60, replace=False)
    measured = pos[pick]
    drift = np.c_[0.4 * np.sin(q[pick, 1]), 0.3 * np.cos(q[pick, 2]), -0.5 * np.sin(q[pick, 1] + q[pick, 2])]
    model_before = measured - drift - 0.05 * rng.standard_normal((60, 3))
    model_after = measured - 0.05 * rng.standard_normal((60, 3))
    return {
        "q_rad": q, "positions_mm": pos, "r_set": r_set, "zones": zones, "zone_names": names,
        "before_lower_mm": center_b - width_b / 2, "before_upper_mm": center_b + width_b / 2,
        "after_lower_mm": center_a - width_a / 2, "after_upper_mm": center_a + width_a / 2,
        "measured_mm": measured, "model_before_mm": model_before, "model_after_mm": model_after,
        "q_test_rad": q[pick], "residual_before_mm": measured - model_before,
    }


def main(argv: list[str] | None = None) -> int:
    from viz import figures
    from viz.recording import (RecordingWriter, log_discover_history, log_error_intervals, log_residuals,
                               log_summary, log_workspace, summary_markdown)

    argv = sys.argv[1:] if argv is None else argv
    out = Path(argv[0] if argv else ".")
    ex = make_example()
    figures.zone_map(out / "zone_map.png", ex["positions_mm"], ex["zones"], zone_names=ex["zone_names"],
                     title="Workspace zones (synthetic example, KR 1000 Titan)", force=True)
    figures.rset_histogram(out / "rset_histogram.png", ex["r_set"], force=True)
    figures.error_intervals(out / "error_intervals.png", ex["before_lower_mm"], ex["before_upper_mm"],
                            ex["after_lower_mm"], ex["after_upper_mm"], force=True)
    figures.residual_vs_joints(out / "residual_vs_joints.png", ex["q_test_rad"], ex["residual_before_mm"],
                               force=True)
    with RecordingWriter(out / "example.rrd", seed=0, force=True) as rec:
        log_workspace(rec, ex["positions_mm"], ex["r_set"], ex["zones"], zone_names=ex["zone_names"])
        log_residuals(rec, "before", ex["measured_mm"], ex["model_before_mm"])
        log_residuals(rec, "after", ex["measured_mm"], ex["model_after_mm"])
        log_error_intervals(rec, ex["before_lower_mm"], ex["before_upper_mm"], ex["after_lower_mm"],
                            ex["after_upper_mm"])
        log_discover_history(rec, [0.62, 0.31, 0.12, 0.051], [0.66, 0.34, 0.13, 0.055],
                             [None, "joint_compliance:2,3", "gear_periodic:1", "backlash:1"])
        log_summary(rec, summary_markdown("Synthetic example", {"points": len(ex["r_set"]), "zones": 10},
                                          ["made-up data: run `torchcal demo` for real results"]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
