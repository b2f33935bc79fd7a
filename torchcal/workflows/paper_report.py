"""The report of the paper's experiment: figures from its results (reductions per axis and
bound, the per-method statistics over seeds, the paired comparison) and the JSON document
of ``torchcal demo --json`` (`DemoRun.to_json`). The printed tables:
`torchcal.cli._report`."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from torchcal.calibration.fit import FitResult
from torchcal.calibration.intervals import parameter_intervals
from torchcal.statistics import mean_ci, paired_comparison
from torchcal.workflows.paper_config import AXES, BOUNDS, METHODS, PAPER_REDUCTION_PERCENT, DemoConfig


def reduction_percent(before_lo, before_hi, after_lo, after_hi, absolute: bool = False) -> dict:
    """Per axis {lower, upper}: 100 * (1 - |mean after| / |mean before|) over the points.

    Bounds (M, 3) mm. absolute=True: the mean of |bound| instead (robust variant).
    """
    f = (lambda t: t.abs().mean(0)) if absolute else (lambda t: t.mean(0).abs())  # noqa: E731
    out: dict = {ax: {} for ax in AXES}
    for name, b, a in (("lower", before_lo, after_lo), ("upper", before_hi, after_hi)):
        red = 100.0 * (1.0 - f(a) / f(b).clamp_min(1e-300))
        for k, ax in enumerate(AXES):
            out[ax][name] = float(red[k])
    return out


def fit_json(f: FitResult) -> dict:
    """One interval fit (a zone's or the global one) in the demo's JSON."""
    return {"fit_rms_mm": f.rms_mm, "damping": f.damping, "rank": f.report.rank,
            "condition_number": f.report.condition, "held": f.report.held,
            "converged": f.converged, "parameters": parameter_intervals(f, degrees=True)}


@dataclass(eq=False)
class DemoRun:
    """The experiment over seeds ``config.seed .. config.seed + K - 1``: `runs` (one
    `PipelineResult` each), figures per method as mean and 95 % CI, the paired comparison."""

    config: DemoConfig
    runs: list
    seconds: float

    @property
    def first(self) -> "PipelineResult":
        return self.runs[0]

    def method_stats(self, which: str) -> dict:
        """The issue's M: fitted effects, test RMS and the six reductions, mean and CI over seeds."""
        red = [r.reductions(which) for r in self.runs]
        comp = [r.compensation(which) for r in self.runs]
        return {"fitted_effects": sorted({s for r in self.runs for s in r.models[which].specs()}),
                "fitted_effects_per_seed": [r.models[which].specs() for r in self.runs],
                "test_rms_mm": mean_ci(r.after[which].rms_mm for r in self.runs),
                "reduction_percent": {ax: {b: mean_ci(x[ax][b] for x in red) for b in BOUNDS} for ax in AXES},
                "compensation": {k: sum(c[k] for c in comp) for k in comp[0]},
                "targets_met_seeds": sum(r.targets_met(which)["all"] for r in self.runs)}

    def paired(self, a: str = "paper_partitioned", b: str = "global_geometric") -> dict:
        """a - b test RMS, paired over seeds (K >= 2) or over test points (K = 1)."""
        if len(self.runs) >= 2:
            out = paired_comparison([r.after[a].rms_mm for r in self.runs], [r.after[b].rms_mm for r in self.runs])
            out["paired_over"] = "seeds"
        else:
            out = paired_comparison(self.first.point_rms(a).tolist(), self.first.point_rms(b).tolist())
            out["paired_over"] = "test points"
        out["beats"] = bool(out["significant"] and out["diff_mm"] < 0)
        return out

    def to_json(self) -> dict:
        """The `torchcal demo --json` document: the first seed's details (the single-seed keys) plus
        the multi-seed keys (seeds, truth_effects, methods, partitioned_vs_global)."""
        res, cfg = self.first, self.config
        ev = res.after["paper_partitioned"]
        points = []
        for i in range(res.test_q.shape[0]):
            points.append({
                "zone": int(res.test_zone[i]) + 1,
                "level": res.zone_level[int(res.test_zone[i])],
                "target_mm": res.test_targets[i].tolist(),
                "q_nominal_deg": torch.rad2deg(res.test_q[i]).tolist(),
                "q_compensated_deg": torch.rad2deg(ev.q[i]).tolist(),
                "error_before_mm": res.before.interval(i),
                "error_after_mm": ev.interval(i),
                "r_set_before": res.before.r_set_dict(i),
                "r_set_after": ev.r_set_dict(i),
                "predicted_residual_mm": float(ev.predicted_residual_mm[i].norm()),
                "compensation_ok": {k: bool(c.converged[i] and c.within_limits[i]) for k, c in res.comps.items()},
                "other_variants": {k: {"error_after_mm": e.interval(i), "r_set_after": e.r_set_dict(i)}
                                   for k, e in res.after.items() if k != "paper_partitioned"},
            })
        zones = [{"zone": z + 1, "level": res.zone_level[z], **res.zone_extent()[z],
                  **{k: fit_json(f[z]) for k, f in res.fits.items() if METHODS[k][0]}} for z in range(res.n_zones)]
        s = res.sweep
        table3 = [{"point": i + 1, "position_mm": s.positions[i].tolist(),
                   "distance_error_mm": [float(s.dist_lower[i]), float(s.dist_upper[i])],
                   "r_set": float(s.r_set[i]), "zone": int(res.partition.labels[i]),
                   "level": int(res.partition.point_levels[i])} for i in range(len(s))]
        glob = res.summary("global_geometric")
        glob["fit"] = fit_json(res.fits["global_geometric"][0])
        pvg = self.paired()
        ext = [[z["rms_radius_mm"] for z in r.zone_extent()] for r in self.runs]
        return {
            "zones": res.n_zones,
            "levels": int(res.partition.n_levels),
            "seconds": self.seconds,
            "seeds": len(self.runs),
            "seed_values": [r.seed for r in self.runs],
            "truth_effects": res.truth_effects,
            "methods": {k: self.method_stats(k) for k in METHODS},
            "partitioned_vs_global": pvg,
            "discovered_partitioned_vs_global": self.paired("discovered_partitioned", "discovered_global"),
            "zone_compactness": {
                "workspace_rms_radius_mm": mean_ci(r.workspace_rms_radius_mm() for r in self.runs),
                "zone_rms_radius_mm_median": mean_ci(sorted(e)[len(e) // 2] for e in ext),
                "zone_rms_radius_mm_max": mean_ci(max(e) for e in ext)},
            "reduction_percent": res.reductions("paper_partitioned"),
            "test_points": points,
            "partitioned": res.summary("paper_partitioned"),
            "global": glob,
            "partitioned_beats_global": pvg["beats"],
            "variants": {k: res.summary(k) for k in METHODS},
            "before": {"test_rms_mm": res.before.rms_mm, "max_abs_error_mm": res.before.max_abs_mm,
                       "over_seeds": mean_ci(r.before.rms_mm for r in self.runs)},
            "robust_reduction_percent": res.reductions("paper_partitioned", absolute=True),
            "paper_reduction_percent": PAPER_REDUCTION_PERCENT,
            "targets_met": res.targets_met("paper_partitioned"),
            "zone_parameters": zones,
            "sweep": {"summary": s.summary(), "table3": table3},
            "partition": res.partition.summary(),
            "timings_s": res.timings,
            "config": cfg.to_json(),
            "units": {"lengths": "mm", "angles": "deg", "errors": "measured - target, mm"},
        }
