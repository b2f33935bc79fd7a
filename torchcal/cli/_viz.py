"""``--rrd FILE`` and ``--plots DIR`` of the commands: what each one records and draws.

One function per command, called after its computation with its parsed ``args``
(``args.rrd``, ``args.plots``, ``args.force``; ``args.data`` where there is an input file):

- `diagnosis_outputs` (``diagnose``): residual against each joint angle (PNG); a
  recording with measured vs model positions, residual arrows and the text summary.
- `discovery_outputs` (``discover``): the error after each round as a time series, the
  residual arrows before (round 0) and after (final model), the summary; PNGs of the
  residual against each joint angle before and after.
- `evaluation_outputs` (``evaluate``): the (held-out) error over the workspace, 3-D and
  coloured; the residual against each joint angle and every variable (PNGs, as
  ``diagnose``); a recording with the error map, residual arrows and the summary.
- `demo_outputs` (``demo``): workspace by R_set and by zone, error intervals per test
  point before and after compensation (the paper's Fig. 11), the summary; PNGs of the
  zone map, the R_set histogram and the error intervals (the paper's per-zone method and,
  beside it, the method with the lowest test RMS).

Every output is checked before anything is written (`check_outputs`; commands may also
call it before their computation to fail early): an existing file is refused with one
InputError line unless ``--force``; the ``--plots`` folder is created when missing. The
``viz`` package (and so rerun and matplotlib) is imported only here, on demand.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch


# PNG file names in the --plots folder, per command.
PLOTS = {
    "diagnose": ("residual_vs_joints.png", "residual_vs_variables.png"),
    "discover": ("residual_vs_joints_before.png", "residual_vs_joints_after.png", "residual_vs_variables.png"),
    "demo": ("zone_map.png", "rset_histogram.png", "error_intervals.png"),
    "evaluate": ("error_map.png", "residual_vs_joints.png", "residual_vs_variables.png"),
}


def _inputs(args) -> list[Path]:
    return [Path(p).resolve() for p in (getattr(args, "data", None), getattr(args, "model", None))
            if p and Path(p).exists()]


def check_outputs(args, command: str) -> tuple[Path | None, list[Path]]:
    """Check every visual output of `command` before any is written; create the --plots
    folder. Returns (rrd path or None, PNG paths, empty without --plots); calling it twice is harmless. Raises
    InputError (one line) as `torchcal.cli._args.check_outputs` does, and when
    --plots names a file."""
    from torchcal.cli._args import check_folder, make_folder
    from torchcal.cli._args import check_outputs as check_files

    rrd = Path(args.rrd) if getattr(args, "rrd", None) else None
    plots = getattr(args, "plots", None)
    check_folder("--plots", plots)
    pngs = [Path(plots) / name for name in PLOTS[command]] if plots else []
    if plots:
        make_folder("--plots", plots)
    check_files([("--rrd", rrd)] + [("--plots", p) for p in pngs], bool(getattr(args, "force", False)),
                inputs=list(_inputs(args)))
    return rrd, pngs


def _np(x) -> np.ndarray:
    return x.detach().to("cpu", torch.float64).numpy() if isinstance(x, torch.Tensor) else np.asarray(x, float)


def _pose_names(m) -> list[str]:
    return [f"row {i + 1} (pose {int(p)})" for i, p in enumerate(_np(m.pose).astype(np.int64))]


def _effects_text(effects) -> str:
    return ", ".join(effects) or "geometric only"


def _fit_facts(fit) -> dict:
    d = np.linalg.norm(_np(fit.residuals), axis=1)
    return {"RMS (mm)": float(np.sqrt(np.mean(d ** 2))), "max (mm)": float(d.max())}


# --------------------------------------------------------------------------- diagnose
def diagnosis_markdown(robot, m, d) -> str:
    """The ``diagnose`` summary as markdown: baseline, candidates, verdict, worst region."""
    from viz.recording import summary_markdown

    rep = d.to_dict()
    b = rep["baseline"]
    v = d.verdict
    facts = {"robot": robot.name, "data": str(m.source) if m.source else "(in memory)", "rows": int(m.q.shape[0]),
             "baseline effects": _effects_text(b["effects"]), "baseline RMS (mm)": b["rms_mm"],
             "baseline held-out RMS (mm)": b["cv_rms_mm"], "baseline max (mm)": b["max_mm"],
             "verdict": "nothing significant (residual at the noise level)" if v is None else f"missing {v.spec}"}
    text = summary_markdown("torchcal diagnose", facts)
    lines = ["", "## Candidates (best first)", "",
             "| candidate | new params | RMS (mm) | held-out RMS (mm) | gain % | p-value | significant |",
             "|---|---|---|---|---|---|---|"]
    for c in d.candidates[:10]:
        lines.append(f"| {c.spec} | {c.k} | {c.rms_mm:.4f} | {c.cv_rms_mm:.4f} | {100 * c.score:.1f} | "
                     f"{c.p_value:.2g} | {'yes' if c.significant else 'no'} |")
    regions = rep.get("where", {}).get("per_region", [])
    if regions:
        lines += ["", "## Where it fails (reach band x height half)", "",
                  "| reach (mm) | half | rows | RMS (mm) | max (mm) |", "|---|---|---|---|---|"]
        for r in sorted(regions, key=lambda r: -r["rms_mm"]):
            lines.append(f"| {r['reach_mm'][0]:.0f}-{r['reach_mm'][1]:.0f} | {r['z']} | {r['n']} | "
                         f"{r['rms_mm']:.4f} | {r['max_mm']:.4f} |")
    return text + "\n".join(lines) + "\n"


def diagnosis_outputs(args, robot, m, d) -> None:
    """``diagnose --rrd/--plots``: residual vs joints PNG; recording of the baseline fit.

    Recording: ``residuals/before/{measured,model,residual}`` (the baseline model's
    positions = measured - residual, arrows model -> measured), ``variables/...`` (what
    the baseline + verdict leave against each variable, as the PNG) and ``summary``.
    PNG: ``residual_vs_joints.png`` (x/y/z residual and RMS per bin against each joint).
    """
    rrd, pngs = check_outputs(args, "diagnose")
    fit = d.baseline_fit
    xyz = _np(m.xyz)
    res = _np(fit.residuals)
    force = bool(args.force)
    if pngs:
        from viz import figures

        figures.residual_vs_joints(pngs[0], _np(m.q), res, force=force, prismatic=_np(robot.prismatic),
                                   title=f"diagnose: residual of [{_effects_text(d.baseline_effects)}] "
                                         f"against each joint angle")
        _variables_png(pngs[1], robot, m, d.unexplained, force, "diagnose: what the baseline + verdict leave")
    if rrd is not None:
        from viz.recording import RecordingWriter, log_residuals, log_summary

        with RecordingWriter(rrd, seed=int(getattr(args, "seed", 0) or 0), force=force) as rec:
            log_residuals(rec, "before", xyz, xyz - res, point_names=_pose_names(m))
            _variables_rrd(rec, robot, m, d.unexplained)
            log_summary(rec, diagnosis_markdown(robot, m, d))
    for p in ([rrd] if rrd is not None else []) + pngs:
        print(f"wrote {p}")


def _variables(robot, m, un) -> dict | None:
    """The residual-against-variables data of `unexplained` (None without residuals): the
    arguments shared by the PNG and the recording. What is drawn against each variable is
    the signed residual component along its fitted dependence
    (`torchcal.diagnosis.dependence`): the length would hide a sign that flips (backlash)."""
    from torchcal.diagnosis.dependence import signed_components
    from torchcal.diagnosis.unexplained import variables

    if un is None or un.residuals is None:
        return None
    return {"values": variables(robot, m), "residual_mm": un.residuals,
            "strengths": {k: s for k, (s, _) in un.strengths.items()},
            "correlates": [v for v, _ in un.correlates_with],
            "components": signed_components(robot, m, un.residuals),
            "prismatic": [f"q{j + 1}" for j in robot.prismatic.nonzero().flatten().tolist()]}


def _variables_png(path, robot, m, un, force: bool, what: str) -> None:
    """Residual against every variable of `unexplained`, strongest dependence first, the
    significant ones marked (``residual_vs_variables.png``)."""
    from viz import figures

    data = _variables(robot, m, un)
    if data is None:
        return
    figures.residual_vs_variables(path, **data, force=force,
                                  title=f"{what}: residual against each variable, strongest dependence "
                                        f"first (* significant)")


def _variables_rrd(rec, robot, m, un) -> None:
    """The same in the recording (``variables/...``, `viz.recording.log_residual_vs_variables`)."""
    from viz.recording import log_residual_vs_variables

    data = _variables(robot, m, un)
    if data is not None:
        log_residual_vs_variables(rec, **data)


# --------------------------------------------------------------------------- evaluate
def evaluation_markdown(model, m, ev, un) -> str:
    """The ``evaluate`` summary as markdown: the model, the rows, the errors, what they depend on."""
    from viz.recording import summary_markdown

    rep = ev.to_dict()
    facts = {"robot": model.robot.name, "model effects": _effects_text(model.specs()),
             "data": str(m.source) if m.source else "(in memory)", "rows": rep["n"], "RMS (mm)": rep["rms_mm"],
             "mean (mm)": rep["mean_mm"], "max (mm)": rep["max_mm"]}
    if "outside_range" in rep:
        facts["rows outside the calibrated range"] = rep["outside_range"]
    if "orientation_rms_deg" in rep:
        facts["orientation RMS (deg)"] = rep["orientation_rms_deg"]
    return summary_markdown("torchcal evaluate", facts, notes=[un.describe()] if un is not None else [])


def evaluation_outputs(args, model, m, ev) -> None:
    """``evaluate --rrd/--plots``: where the model fails on these (held-out) rows, drawn
    with the figures of ``diagnose``.

    PNGs: ``error_map.png`` (the rows' measured positions coloured by the distance error:
    3-D, top and side), ``residual_vs_joints.png`` and ``residual_vs_variables.png`` (the
    residual against every variable, `torchcal.diagnosis.unexplained` on these rows).
    Recording: ``error_map/...``, ``residuals/after/...`` (measured, model, arrows),
    ``variables/...`` and ``summary``.
    """
    from torchcal.diagnosis.unexplained import unexplained

    rrd, pngs = check_outputs(args, "evaluate")
    robot = model.robot
    xyz, res = _np(m.xyz), _np(ev.residuals_mm)
    e = np.linalg.norm(res, axis=1)
    force = bool(args.force)
    un = unexplained(robot, m, ev.residuals_mm, seed=0) if len(m) >= 10 else None
    what = f"evaluate [{_effects_text(model.specs())}] on {Path(str(m.source)).name if m.source else 'data'}"
    if pngs:
        from viz import figures

        figures.error_map(pngs[0], xyz, e, force=force, title=f"{what}: distance error over the workspace")
        figures.residual_vs_joints(pngs[1], _np(m.q), res, force=force, prismatic=_np(robot.prismatic),
                                   title=f"{what}: residual against each joint angle")
        if un is not None:
            _variables_png(pngs[2], robot, m, un, force, what)
    if rrd is not None:
        from viz.recording import RecordingWriter, log_error_map, log_residuals, log_summary

        names = _pose_names(m)
        with RecordingWriter(rrd, seed=0, force=force) as rec:
            log_error_map(rec, xyz, e, point_names=names)
            log_residuals(rec, "after", xyz, xyz - res, point_names=names)
            if un is not None:
                _variables_rrd(rec, robot, m, un)
            log_summary(rec, evaluation_markdown(model, m, ev, un))
    for p in ([rrd] if rrd is not None else []) + [p for p in pngs if p.exists()]:
        print(f"wrote {p}")


# --------------------------------------------------------------------------- discover
def _added(history) -> list[str | None]:
    """Effect added in each round (None for round 0)."""
    out: list[str | None] = [None]
    for prev, cur in zip(history, history[1:]):
        new = [e for e in cur["effects"] if e not in prev["effects"]]
        out.append(", ".join(new) or None)
    return out


def discovery_markdown(robot, m, res) -> str:
    """The ``discover`` summary as markdown: rounds, final effects, before/after."""
    from viz.recording import summary_markdown

    before = res.diagnoses[0].baseline_fit if res.diagnoses else res.fit
    fb, fa = _fit_facts(before), _fit_facts(res.fit)
    facts = {"robot": robot.name, "data": str(m.source) if m.source else "(in memory)", "rows": int(m.q.shape[0]),
             "rounds": len(res.history), "final effects": _effects_text(res.final_effects),
             "RMS before (mm)": fb["RMS (mm)"], "RMS after (mm)": fa["RMS (mm)"],
             "max before (mm)": fb["max (mm)"], "max after (mm)": fa["max (mm)"]}
    text = summary_markdown("torchcal discover", facts)
    lines = ["", "## Rounds", "", "| round | added | RMS (mm) | held-out RMS (mm) |", "|---|---|---|---|"]
    for k, (h, a) in enumerate(zip(res.history, _added(res.history))):
        lines.append(f"| {k} | {a or '(start: ' + _effects_text(h['effects']) + ')'} | {h['rms_mm']:.4f} | "
                     f"{h['cv_rms_mm']:.4f} |")
    return text + "\n".join(lines) + "\n"


def discovery_outputs(args, robot, m, res) -> None:
    """``discover --rrd/--plots``: error per round, residuals before/after, summary, PNGs.

    Recording: ``discover/{rms_mm,cv_rms_mm,added}`` on the ``round`` timeline (0 = the
    starting model), ``residuals/before/...`` (round 0's fit), ``residuals/after/...``
    (the final model's fit), ``variables/...`` (what the final model leaves against each
    variable, as the PNG) and ``summary``.
    PNGs: ``residual_vs_joints_before.png`` and ``residual_vs_joints_after.png``.
    """
    rrd, pngs = check_outputs(args, "discover")
    before = res.diagnoses[0].baseline_fit if res.diagnoses else res.fit
    start = res.history[0]["effects"] if res.history else []
    xyz = _np(m.xyz)
    force = bool(args.force)
    if pngs:
        from viz import figures

        q = _np(m.q)
        figures.residual_vs_joints(pngs[0], q, _np(before.residuals), force=force, prismatic=_np(robot.prismatic),
                                   title=f"discover, before (round 0: {_effects_text(start)}): residual "
                                         f"against each joint angle")
        figures.residual_vs_joints(pngs[1], q, _np(res.fit.residuals), force=force, prismatic=_np(robot.prismatic),
                                   title=f"discover, after ({_effects_text(res.final_effects)}): residual "
                                         f"against each joint angle")
        _variables_png(pngs[2], robot, m, res.unexplained, force, "discover: what the final model leaves")
    if rrd is not None:
        from viz.recording import RecordingWriter, log_discover_history, log_residuals, log_summary

        names = _pose_names(m)
        with RecordingWriter(rrd, seed=int(getattr(args, "seed", 0) or 0), force=force) as rec:
            log_discover_history(rec, [h["rms_mm"] for h in res.history], [h["cv_rms_mm"] for h in res.history],
                                 _added(res.history))
            log_residuals(rec, "before", xyz, xyz - _np(before.residuals), point_names=names)
            log_residuals(rec, "after", xyz, xyz - _np(res.fit.residuals), point_names=names)
            _variables_rrd(rec, robot, m, res.unexplained)
            log_summary(rec, discovery_markdown(robot, m, res))
    for p in ([rrd] if rrd is not None else []) + pngs:
        print(f"wrote {p}")


# --------------------------------------------------------------------------- demo
def _demo_after(result):
    """The partitioned (per-zone, the paper's method) evaluation after compensation."""
    after = result.after
    if not isinstance(after, dict):
        return after
    return after["paper_partitioned"] if "paper_partitioned" in after else after["partitioned"]


def _demo_best(run) -> str | None:
    """The method with the lowest mean test RMS over the seeds, when it is not the paper's
    per-zone one (None then, or for a result without methods)."""
    runs = getattr(run, "runs", [run])
    after = runs[0].after
    if not isinstance(after, dict) or "paper_partitioned" not in after:
        return None
    mean = {k: float(np.mean([float(r.after[k].rms_mm) for r in runs])) for k in after}
    best = min(mean, key=mean.get)
    return None if best == "paper_partitioned" else best


def demo_markdown(run) -> str:
    """The ``demo`` summary as markdown: key numbers (first seed), then the printed report verbatim."""
    from viz.recording import summary_markdown

    result = getattr(run, "first", run)
    before, after = result.before, _demo_after(result)
    cfg = result.config
    facts = {"robot": getattr(cfg, "robot", "kr1000titan"), "seed": getattr(cfg, "seed", 0),
             "sweep points": int(result.sweep.positions.shape[0]), "zones": int(result.partition.labels.max()),
             "test points": int(before.lower.shape[0]),
             "test RMS before (mm)": float(before.rms_mm), "test RMS after (mm)": float(after.rms_mm),
             "max |error| before (mm)": float(before.max_abs_mm), "max |error| after (mm)": float(after.max_abs_mm),
             "allowed per axis (mm)": float(cfg.allowed_axis_mm)}
    text = summary_markdown("torchcal demo", facts)
    if hasattr(run, "runs"):
        from torchcal.cli._report import format_report

        report = format_report(run)
    else:
        report = run.format_report() if hasattr(run, "format_report") else ""
    if report:
        text += "\n## Report\n\n```\n" + report.rstrip() + "\n```\n"
    return text


def demo_outputs(args, result) -> None:
    """``demo --rrd/--plots`` for a finished demo (`result`: `torchcal.workflows.paper_report.DemoRun`, its
    first seed is drawn; or one `PipelineResult`).

    Recording: ``workspace/{rset,zones,centres}`` (the sweep points coloured by R_set and by
    zone, zone centres labelled), ``error_intervals/{x,y,z}/{before,after,allowed}/...`` per
    test point (the paper's Fig. 11; after = per-zone compensation; ``best_METHOD`` = the
    method with the lowest mean test RMS, when it is another) and ``summary``.
    PNGs: ``zone_map.png`` (three views), ``rset_histogram.png``, ``error_intervals.png``.
    """
    rrd, pngs = check_outputs(args, "demo")
    run, result = result, getattr(result, "first", result)
    force = bool(args.force)
    pos = _np(result.sweep.positions)
    r_set = _np(result.sweep.r_set)
    zones = _np(result.partition.labels).astype(np.int64) - 1  # 1..Z -> 0-based
    before, after = result.before, _demo_after(result)
    b_lo, b_hi, a_lo, a_hi = (_np(t) for t in (before.lower, before.upper, after.lower, after.upper))
    allowed = float(result.config.allowed_axis_mm)
    best = _demo_best(run)  # drawn beside the paper's method
    also = []
    if best is not None:
        from torchcal.cli._report import LABEL

        ev = result.after[best]
        also = [(f"after, {LABEL.get(best, best)} (best test RMS)", _np(ev.lower), _np(ev.upper))]
    if pngs:
        from viz import figures

        figures.zone_map(pngs[0], pos, zones, force=force,
                         title="Workspace zones of the sweep (partition by R_set and position)")
        figures.rset_histogram(pngs[1], r_set, force=force)
        figures.error_intervals(pngs[2], b_lo, b_hi, a_lo, a_hi, allowed_mm=allowed, force=force,
                                after_name="after, paper part. (per zone)", also=also,
                                title="Error interval per test point, before and after compensation: the paper's "
                                      "per-zone method" + (" and the best method" if also else " (also the best)"))
    if rrd is not None:
        from viz.recording import RecordingWriter, log_error_intervals, log_summary, log_workspace

        with RecordingWriter(rrd, seed=int(getattr(args, "seed", 0) or 0), force=force) as rec:
            log_workspace(rec, pos, r_set, zones)
            log_error_intervals(rec, b_lo, b_hi, a_lo, a_hi, allowed_mm=allowed,
                                also=[(f"best_{best}", lo, hi) for _, lo, hi in also])
            log_summary(rec, demo_markdown(run))
    for p in ([rrd] if rrd is not None else []) + pngs:
        print(f"wrote {p}")
