"""The printed report of `torchcal demo` (the library returns data: `torchcal.workflows.paper_report.DemoRun`).

Sections: the virtual robot (its settings), Table 3 (first and last sweep points),
Table 4 (compact, the paper's method, first seed), Table 5 (test points before and after,
first seed), then the side-by-side of the methods over the seeds (test RMS and the
paper's six reductions, mean and 95 % CI), compensation checks, the paired comparison of
partitioned vs global, and the zones' spatial extent.
"""

from __future__ import annotations

import math

from torchcal.workflows.paper_config import AXES, BOUNDS, METHODS, PAPER_REDUCTION_PERCENT

LABEL = {"paper_partitioned": "paper part.", "global_geometric": "global geom.",
         "discovered_global": "disc. global", "discovered_partitioned": "disc. part.",
         "paper_partitioned_gcv": "paper GCV", "paper_partitioned_more": "paper more"}


def _iv(lo: float, hi: float, w: int = 6, p: int = 3) -> str:
    return f"[{lo:{w}.{p}f},{hi:{w}.{p}f}]"


def _mc(stat: dict, p: int = 2) -> str:
    """mean [lo, hi] or mean alone when there is no CI (one seed)."""
    if stat["ci95"] is None:
        return f"{stat['mean']:.{p}f}"
    lo, hi = stat["ci95"]
    return f"{stat['mean']:.{p}f} [{lo:.{p}f}, {hi:.{p}f}]"


def format_report(run, table3_rows=(6, 2)) -> str:
    """The text report of a `DemoRun` (module doc)."""
    res, cfg = run.first, run.config
    s, part = res.sweep, res.partition
    doc = run.to_json()
    out = []
    w = out.append
    w(f"Virtual robot ({cfg.robot}), seeds {doc['seed_values'][0]}..{doc['seed_values'][-1]} ({doc['seeds']}):")
    w(f"  MD-H deviations +-{0.5 * cfg.geometric_scale:g} mm, +-{0.02 * cfg.geometric_scale:g} deg; "
      f"effects {', '.join(res.truth_effects)}")
    w(f"  frame offset {list(cfg.base_offset_mm)} mm, tilt {list(cfg.base_tilt_deg)} deg; compliance "
      f"{cfg.compliance_mm:g} mm RMS (payload 0..{res.models['global_geometric'].robot.payload_kg:g} kg); "
      f"gear {cfg.gear_mm:g} mm RMS; clearance random share {cfg.clearance_random:g}; noise {cfg.noise_mm:g} mm")
    w("")
    # Table 3
    how = (f"{cfg.sweep_samples} clearance states of the Table 2 model each" if cfg.sweep_source == "model"
           else f"{cfg.repeats} moves of the robot each")
    w(f"Table 3 analogue (seed {res.seed}): sweep of {len(s)} Latin-hypercube points, {how}, "
      f"allowed distance error [0, {cfg.allowed_distance_mm:g}] mm")
    w(f"{'pt':>4} {'p_x mm':>10} {'p_y mm':>10} {'p_z mm':>10}  {'distance error mm':>19} {'R_set':>6} "
      f"{'level':>5} {'zone':>4}")
    head, tail = table3_rows
    idx = list(range(min(head, len(s))))
    idx += [i for i in range(max(len(s) - tail, len(idx)), len(s))]
    for k, i in enumerate(idx):
        if k and i != idx[k - 1] + 1:
            w(f"{'...':>4}")
        p = s.positions[i]
        w(f"{i + 1:>4} {p[0]:>10.3f} {p[1]:>10.3f} {p[2]:>10.3f}  [0, {float(s.dist_upper[i]):>9.6f}]     "
          f"{float(s.r_set[i]):>6.3f} {int(part.point_levels[i]):>5} {int(part.labels[i]):>4}")
    sm = s.summary()
    w(f"R_set from {sm['r_set_min']:.3f} to {sm['r_set_max']:.3f} (median {sm['r_set_median']:.3f}); "
      f"{100 * sm['share_r_set_1']:.0f}% of the points at 1")
    w("")
    # Table 4 (compact) with zone extent
    fits = res.fits["paper_partitioned"]
    model = res.models["paper_partitioned"]
    units = model.param_units()
    ext = res.zone_extent()
    w(f"Table 4 analogue (compact, seed {res.seed}): the paper's method per zone (eq. 29, mu = {cfg.paper_mu:g}); "
      f"model: geometric + {', '.join(model.specs())}; zone extent = sweep points' distance from their centroid")
    w(f"{'zone':>4} {'level':>5} {'pts':>4} {'extent rms mm':>13} {'max mm':>7} {'held':>4} {'fit rms mm':>10} "
      f"{'median width mm':>15} {'deg':>8}")

    def med(v):
        return sorted(v)[len(v) // 2] if v else float("nan")
    n = model.robot.n
    for z, f in enumerate(fits):
        lens = [2 * float(f.radius[k]) for k in range(5 * n) if f.report.free[k] and units[k] == "mm"]
        angs = [2 * math.degrees(float(f.radius[k])) for k in range(5 * n) if f.report.free[k] and units[k] == "rad"]
        e = ext[z]
        w(f"{z + 1:>4} {res.zone_level[z]:>5} {e['sweep_points']:>4} {e['rms_radius_mm']:>13.0f} "
          f"{e['max_radius_mm']:>7.0f} {len(f.report.held):>4} {f.rms_mm:>10.4f} {med(lens):>15.4f} {med(angs):>8.5f}")
    w(f"workspace (all sweep points): RMS distance from the centroid {res.workspace_rms_radius_mm():.0f} mm")
    w("")
    # Table 5
    ev = res.after["paper_partitioned"]
    w(f"Table 5 analogue (seed {res.seed}): {res.test_q.shape[0]} fresh test points ({cfg.test_per_zone} per zone), "
      f"{cfg.repeats} moves each; errors = measured - target (mm); after = the paper's method")
    w(f"{'pt':>3} {'zone':>4} | {'before dX':>15} {'dY':>15} {'dZ':>15} | {'after dX':>15} {'dY':>15} "
      f"{'dZ':>15} | R_set x y z dist")
    for i in range(res.test_q.shape[0]):
        b = [_iv(float(res.before.lower[i, k]), float(res.before.upper[i, k])) for k in range(3)]
        a = [_iv(float(ev.lower[i, k]), float(ev.upper[i, k])) for k in range(3)]
        rs = " ".join(f"{float(v):.3g}" for v in ev.r_set[i])
        w(f"{i + 1:>3} {int(res.test_zone[i]) + 1:>4} | {' '.join(f'{c:>15}' for c in b)} | "
          f"{' '.join(f'{c:>15}' for c in a)} | {rs}")
    w("")
    # side by side over seeds
    K = doc["seeds"]
    ci = "mean [95% CI]" if K > 1 else "one seed, no CI"
    w(f"Methods side by side over {K} seed(s), {ci}; same fresh test moves for every method:")
    for k in METHODS:
        m = doc["methods"][k]
        w(f"  {LABEL[k]:<13} {METHODS[k][1]}; fitted: geometric + {', '.join(m['fitted_effects'])}")
    names = list(METHODS)
    col = 24 if K > 1 else 13
    w(f"{'':<22}" + " ".join(f"{LABEL[m]:>{col}}" for m in names))
    w(f"{'test RMS mm':<22}" + " ".join(f"{_mc(doc['methods'][m]['test_rms_mm'], 3):>{col}}" for m in names)
      + f"   (before: {_mc(doc['before']['over_seeds'], 3)})")
    w("reduction % (paper's figure in brackets), 100 * (1 - |mean bound after| / |mean bound before|):")
    for ax in AXES:
        for bd in BOUNDS:
            title = f"{ax} {bd} ({PAPER_REDUCTION_PERCENT[ax][bd]:.2f})"
            w(f"{title:<22}" + " ".join(f"{_mc(doc['methods'][m]['reduction_percent'][ax][bd], 1):>{col}}"
                                        for m in names))
    w(f"{'compensation failed':<22}" + " ".join(
        f"{doc['methods'][m]['compensation']['failed']:>{col - 6}} / {doc['methods'][m]['compensation']['targets']:<4}"
        for m in names))
    w(f"{'seeds all within +-' + format(cfg.allowed_axis_mm, 'g') + ' mm':<22}" + " ".join(
        f"{doc['methods'][m]['targets_met_seeds']:>{col - 6}} / {K:<4}" for m in names))
    for title, key in (("Partitioned (the paper) vs global geometric", "partitioned_vs_global"),
                       ("Discovered partitioned vs discovered global", "discovered_partitioned_vs_global")):
        c = doc[key]
        ci_txt = "" if c["ci95"] is None else f", 95% CI [{c['ci95'][0]:+.3f}, {c['ci95'][1]:+.3f}]"
        verdict = ("beats" if c["beats"] else "is significantly worse than" if c["significant"]
                   else "does not differ significantly from")
        w(f"{title}: test RMS difference {c['diff_mm']:+.3f} mm{ci_txt}, p = {c['p']:.3g} "
          f"(paired over {c['paired_over']}): partitioned {verdict} global")
    zc = doc["zone_compactness"]
    w(f"Zone extent: median zone RMS radius {_mc(zc['zone_rms_radius_mm_median'], 0)} mm, largest "
      f"{_mc(zc['zone_rms_radius_mm_max'], 0)} mm, workspace {_mc(zc['workspace_rms_radius_mm'], 0)} mm")
    w(f"{res.n_zones} zones in {int(part.n_levels)} levels; {run.seconds:.1f} s")
    return "\n".join(out)
