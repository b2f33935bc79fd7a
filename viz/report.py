"""The calibration report as one self-contained HTML file (``torchcal report``).

`report_html(rep)` renders a `torchcal.workflows.report.CalibrationReport`: CSS inline,
figures embedded as base64 PNG (`viz.figures`), no script, no font or any other request
leaving the file, so it opens from a USB stick. The first page is the summary and the
verdict; the evidence follows, one section per printed A4 page or more (``@page``, a
page break before each section): provenance, the model (for an interval model of
``calibrate``: its zones and parameter intervals), accuracy on the held-out poses (mean,
RMS, p95, max; per axis; ISO 9283 AP and RP), the verdict per pose, the paper's Table 5
(interval models), discover's rounds, what stays learnable, the transfer check. Figures scale to the window
(``max-width: 100%``); wide tables scroll inside their box on a narrow screen.
"""

from __future__ import annotations

import base64
import html
import json

from torchcal.io.files import atomic_write

__all__ = ["report_html", "write_report"]

CSS = """
@page { size: A4; margin: 14mm 12mm; }
* { box-sizing: border-box; }
body { font-family: "DejaVu Sans", Arial, Helvetica, sans-serif; font-size: 11pt; color: #1a1a1a;
       max-width: 1100px; margin: 0 auto; padding: 12px 16px; line-height: 1.35; }
h1 { font-size: 20pt; margin: 0 0 4px 0; }
h2 { font-size: 15pt; border-bottom: 2px solid #444; padding-bottom: 2px; margin-top: 28px; }
h3 { font-size: 12pt; margin: 16px 0 6px 0; }
.sub { color: #555; margin: 0 0 12px 0; }
.verdict { font-size: 16pt; font-weight: bold; padding: 10px 14px; border-radius: 6px; margin: 12px 0; }
.pass { background: #dff3df; border: 2px solid #2c9f2c; color: #1d6b1d; }
.fail { background: #fbe0e0; border: 2px solid #d62728; color: #8e1a1b; }
.none { background: #eeeeee; border: 2px solid #888888; color: #333333; }
.box { overflow-x: auto; max-width: 100%; }
table { border-collapse: collapse; margin: 6px 0 10px 0; font-size: 9.5pt; }
th, td { border: 1px solid #bbb; padding: 3px 7px; text-align: left; vertical-align: top; }
th { background: #f0f0f0; }
td.n { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
.h { word-break: break-all; font-family: "DejaVu Sans Mono", monospace; font-size: 8.5pt; }
tr.rej td { color: #555; }
figure { margin: 10px 0; }
figure img { max-width: 100%; height: auto; display: block; border: 1px solid #ddd; }
figcaption { font-size: 9pt; color: #444; }
.note { font-size: 9.5pt; color: #333; }
section.page { break-before: page; page-break-before: always; }
section, figure, table { break-inside: auto; }
figure, tr { break-inside: avoid; page-break-inside: avoid; }
@media (max-width: 640px) {
  body { font-size: 10pt; padding: 6px; }
  h1 { font-size: 16pt; }
  .verdict { font-size: 13pt; }
}
@media print {
  body { max-width: none; padding: 0; font-size: 10pt; }
  .box { overflow: visible; }
  table { font-size: 8.5pt; }
}
"""

FAILED_SHOWN = 200  # failing poses listed in the per-pose verdict (the count says the rest)


def _e(x) -> str:
    return html.escape(str(x), quote=True)


def _mm(v, digits: int = 4) -> str:
    return "-" if v is None else f"{v:.{digits}f} mm"


def _num(v, digits: int = 6) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, float)):
        return f"{v:.{digits}g}"
    return _e(v)


def _table(header, rows, numeric=(), cls_rows=None) -> str:
    """An HTML table in a scrolling box; rows: lists of already escaped cells; numeric:
    the indices of right-aligned columns; header None: no header row."""
    head = "<thead><tr>" + "".join(f"<th>{h}</th>" for h in header) + "</tr></thead>" if header else ""
    body = []
    for k, r in enumerate(rows):
        cls = f' class="{cls_rows[k]}"' if cls_rows and cls_rows[k] else ""
        body.append(f"<tr{cls}>" + "".join(f'<td class="n">{c}</td>' if i in numeric else f"<td>{c}</td>"
                                            for i, c in enumerate(r)) + "</tr>")
    return f'<div class="box"><table>{head}<tbody>{"".join(body)}</tbody></table></div>'


def _kv(pairs) -> str:
    return _table(None, [[f"<b>{_e(k)}</b>", v] for k, v in pairs])


def _json_cell(v) -> str:
    if isinstance(v, float):
        return _num(v)
    if isinstance(v, (dict, list)):
        return f'<span class="h">{_e(json.dumps(v, default=str)[:600])}</span>'
    return _e(v)


def _figure(fig, caption: str, alt: str) -> str:
    from viz.figures import png_bytes

    data = base64.b64encode(png_bytes(fig)).decode("ascii")
    return (f'<figure><img alt="{_e(alt)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{caption}</figcaption></figure>")


# --------------------------------------------------------------------------- sections
def _verdict_box(rep) -> str:
    v = rep.verdict_after
    if v is None:
        why = ("no tolerance given (--tolerance-mm)" if rep.after is not None
               else "no held-out measurements given (--data)")
        return f'<div class="verdict none">No verdict: {_e(why)}</div>'
    word = "PASS" if v["passed"] else "FAIL"
    cls = "pass" if v["passed"] else "fail"
    return (f'<div class="verdict {cls}">{word}: {v["poses"] - v["poses_failed"]} of {v["poses"]} held-out poses '
            f'within {v["tolerance_mm"]:g} mm (worst {v["worst_mm"]:.3f} mm)</div>')


def _stats_rows(after: dict, before: dict | None) -> list:
    rows = []
    for label, key in (("mean", "mean_mm"), ("RMS", "rms_mm"), ("p95", "p95_mm"), ("max", "max_mm")):
        b = before[key] if before else None
        change = f"{100 * (after[key] - b) / b:+.1f} %" if b else "-"
        rows.append([f"distance {label}", _mm(b), _mm(after[key]), change])
    return rows


def _summary(rep) -> str:
    m = rep.model
    out = [f"<h1>Calibration report: {_e(m.get('robot', '?'))}</h1>",
           f'<p class="sub">torchcal {_e(m.get("provenance", {}).get("torchcal_version", ""))}; written '
           f"{_e(rep.created_utc)}; lengths in mm, angles in degrees</p>", _verdict_box(rep)]
    effects = ", ".join(s for s, _ in rep.effects) or "geometric only"
    fit = m.get("fit", {})
    pairs = [("model", f"{_e(rep.files['model']['name'])}: MD-H geometry + {_e(effects)}"
                       + (f"; interval calibration, {len(m['zones'])} zone(s)" if "zones" in m else "")),
             ("fitted on", f"{_e(m.get('provenance', {}).get('input', '?'))}"
                           + (f": {fit['n']} rows, training RMS {_mm(fit.get('rms_mm'))}" if fit else ""))]
    if rep.after is not None:
        d = rep.files.get("data")
        pairs.append(("held-out data", f"{_e(d['name'] if d else 'measurements')}: {rep.after['n']} rows, "
                                       f"{rep.iso_after['poses']} poses (the fit never saw them)"))
    if rep.history is not None:
        terms = rep.history.get("absorbing", [])
        named = rep.history.get("named")  # absent in a history written before the split-half check
        pairs.append(("discovery", f"{len(rep.history.get('history', []))} round(s); final effects "
                                   f"{_e(', '.join(rep.history.get('final_effects', [])) or 'none')}"
                                   + ("" if named is None else f"; named as physics: {_e(', '.join(named) or 'none')}")
                                   + (f"; fit terms only, not named: {_e(', '.join(terms))}" if terms else "")))
    out.append(_kv(pairs))
    if rep.after is not None:
        out.append("<h3>Accuracy on the held-out poses</h3>")
        out.append(_table(["figure", "before (nominal robot)", "after (calibrated model)", "change"],
                          _stats_rows(rep.after, rep.before), numeric=(1, 2, 3)))
        ia, ib = rep.iso_after, rep.iso_before
        iso = [["AP (ISO 9283 pose accuracy), max over poses", _mm(ib["ap_mm"]["max"]), _mm(ia["ap_mm"]["max"])]]
        if ia["rp_mm"] is not None:
            iso.append([f"RP (repeatability, {ia['poses_with_repeats']} poses with repeats), max",
                        _mm(ib["rp_mm"]["max"]), _mm(ia["rp_mm"]["max"])])
        else:
            iso.append(["RP (repeatability)", "-", "not computed: no pose is measured 3 times or more"])
        out.append(_table(["ISO 9283", "before", "after"], iso, numeric=(1, 2)))
        out.append(f'<p class="note">Before: {_e(rep.before_model)}. After: the calibrated model as fitted. '
                   f"Errors are |measured - model| in the measurement frame. "
                   + (f"{rep.outside_range} held-out rows lie outside the joint range the model was "
                      f"calibrated on (the model extrapolates there). " if rep.outside_range else "")
                   + "".join(f"<b>Warning:</b> {_e(w)}. " for w in getattr(rep, "data_warnings", []))
                   + "The evidence follows on the next pages.</p>")
    else:
        out.append('<p class="note">No held-out measurements were given (<code>--data</code>): the figures '
                   "below are the fit's own; accuracy on unseen poses is not shown.</p>")
    return "<section>" + "".join(out) + "</section>"


def _provenance(rep) -> str:
    rows = []
    for role, f in (("model", rep.files["model"]), ("held-out data", rep.files.get("data")),
                    ("discover history", rep.files.get("history"))):
        if f:
            rows.append([_e(role), _e(f["path"]), f'{f["bytes"]:,}', f'<span class="h">{_e(f["sha256"])}</span>',
                         _e(f["modified_utc"])])
    prov = rep.model.get("provenance", {})
    if prov.get("input"):
        rows.append(["training data (from the model)", _e(prov["input"]), "-",
                     f'<span class="h">{_e(prov.get("input_sha256", "-"))}</span>', "-"])
    out = ["<h2>1. Provenance</h2>", _table(["file", "path", "bytes", "SHA-256", "modified"], rows, numeric=(2,))]
    pairs = [("units", "positions and errors in mm; joint angles in degrees (mm for a prismatic joint); "
                       "parameters in the unit beside them"),
             ("measurement frame", "the instrument's (laser tracker's) frame: every measured and modelled "
                                   "position is expressed in it")]
    bf = rep.model.get("base_frame")
    if bf:
        pairs.append(("robot base in the measurement frame",
                      f"translation {_e(', '.join(f'{v:.3f}' for v in bf['translation_mm']))} mm; rotation "
                      f"fixed-XYZ {_e(', '.join(f'{v:.4f}' for v in bf['rotation_fixed_xyz_deg']))} deg"))
    rng = rep.model.get("calibrated_range")
    if rng:
        pairs.append(("calibrated joint range", "; ".join(
            f"q{i + 1} {lo:.1f}..{hi:.1f} {u}" for i, (lo, hi, u) in enumerate(zip(rng["q_min"], rng["q_max"],
                                                                                    rng["unit"])))))
    if prov.get("seed") is not None:
        pairs.append(("seed", _e(prov["seed"])))
    out.append(_kv(pairs))
    return '<section class="page">' + "".join(out) + "</section>"


STANDARD_KEYS = ("name", "value", "unit", "std", "ci95", "identified")


def _effects(rep) -> str:
    rows = [["geometric", "MD-H deviations of every joint [dtheta, dd, da, dalpha, dbeta] (always part of the "
                          "model)"]] + [[_e(s), _e(p) or "-"] for s, p in rep.effects]
    return "<h3>Effects</h3>" + _table(["effect", "physics"], rows)


def _zone_model(rep) -> str:
    """The model section of an interval model (``torchcal calibrate``): zones, and each
    identified parameter's interval per zone, in mm and degrees."""
    m = rep.model
    zones = m.get("zones", [])
    out = ["<h2>2. The model</h2>", _effects(rep),
           f'<p class="note">Interval calibration ({_e(m.get("zone_method", "?"))}), {len(zones)} zone(s)'
           + (" of a workspace partition by R_set and position (the paper's pipeline, docs/paper.md)"
              if m.get("partition") else "") + ".</p>"]
    rows = [[_e(z["zone"]), _e(z.get("level") if z.get("level") is not None else "-"),
             _e(z.get("poses") if z.get("poses") is not None else "-"), _mm(z.get("rms_mm")),
             _e(len(z.get("held", []))),
             _num(z.get("damping"), 3), _e(z.get("note", ""))] for z in zones]
    out.append("<h3>Zones</h3>" + _table(["zone", "level", "poses", "fit RMS", "held", "damping mu", "note"], rows,
                                         numeric=(2, 3, 4, 5)))
    head = ["parameter", "unit"] + [f"zone {z['zone']}" for z in zones]
    rows = []
    for k, p in enumerate(m.get("parameters", [])):  # the zones' values are in the file's units, as these
        if not any(z["identified"][k] for z in zones):
            continue
        cells = []
        for z in zones:
            c, lo, hi = (z[key][k] for key in ("value", "lower", "upper"))
            cells.append(f"{c:.4g} [{lo:.4g}, {hi:.4g}]" if z["identified"][k] else "held")
        rows.append([_e(p["name"]), _e(p.get("unit", ""))] + cells)
    out.append("<h3>Interval parameters per zone</h3>"
               '<p class="note">center [lower, upper] of each identified parameter (deviation from nominal; '
               "frames: the pose itself); held: not identifiable in that zone.</p>"
               + _table(head, rows, numeric=tuple(range(2, 2 + len(zones)))))
    return '<section class="page">' + "".join(out) + "</section>"


def _model(rep) -> str:
    m = rep.model
    if "zones" in m:
        return _zone_model(rep)
    out = ["<h2>2. The model</h2>", _effects(rep)]
    fit = m.get("fit", {})
    ident = m.get("identifiability", {})
    cov = m.get("covariance") or {}
    pairs = [("fit", f"{fit.get('n', '?')} rows, RMS {_mm(fit.get('rms_mm'))}, max {_mm(fit.get('max_mm'))}, "
                     f"solver {_e(fit.get('status', '?'))} after {fit.get('iterations', '?')} iterations"
                     + (f", robust {_e(fit['robust'])}" if fit.get("robust") else "")),
             ("identifiability", f"rank {ident.get('rank', '?')}, condition number "
                                 f"{_num(ident.get('condition_number'), 4)}"),
             ("held at nominal (not identifiable from these poses)",
              _e(", ".join(ident.get("held_at_nominal", [])) or "none"))]
    plaus = m.get("plausibility") or {}
    if plaus:
        pairs.append(("beyond the plausible size (shrunk by the prior)", _e(", ".join(plaus.get("beyond", []))
                                                                             or "none")))
    if cov:
        pairs.append(("uncertainty", f"{_e(cov.get('method', ''))} covariance, residual sigma "
                                     f"{_mm(cov.get('sigma_mm'))} per axis, {cov.get('dof', '?')} degrees of freedom"))
    out.append(_kv(pairs))
    params = m.get("parameters", [])
    extra = sorted({k for p in params for k in p if k not in STANDARD_KEYS})
    rows, cls = [], []
    for p in params:
        ci = p.get("ci95")
        row = [_e(p["name"]), _num(p.get("value")), _e(p.get("unit", "")), _num(p.get("std"), 3),
               f"[{_num(ci[0], 5)}, {_num(ci[1], 5)}]" if ci else "-",
               "identified" if p.get("identified") else "held at nominal"]
        row += [_json_cell(p.get(k, "")) for k in extra]
        rows.append(row)
        cls.append("" if p.get("identified") else "rej")
    out.append("<h3>Parameters</h3>")
    out.append(f'<p class="note">value: the deviation from nominal (frames: the pose itself), std: its standard '
               f"error, ci95: the 95 % interval, as the model file holds them"
               + ("; base_rx..base_rz: the rotation vector (axis times angle) of the base frame, not the "
                  "fixed-XYZ angles given with it above" if any(p["name"] == "base_rx" for p in params) else "")
               + (f"; further labels of the file: {_e(', '.join(extra))}" if extra else "") + ".</p>")
    out.append(_table(["parameter", "value", "unit", "std", "ci95", "status"] + [_e(k) for k in extra], rows,
                      numeric=(1, 3, 4), cls_rows=cls))
    return '<section class="page">' + "".join(out) + "</section>"


def _accuracy(rep) -> str:
    from viz import figures

    out = ["<h2>3. Accuracy on the held-out poses</h2>"]
    if rep.after is None:
        return '<section class="page">' + out[0] + "<p>No held-out measurements were given.</p></section>"
    a, b = rep.after, rep.before
    rows = _stats_rows(a, b)
    for ax in "xyz":
        for label, key in (("bias (signed mean)", "bias_mm"), ("RMS", "rms_mm"), ("p95 |e|", "p95_mm"),
                           ("max |e|", "max_mm")):
            bb, aa = b["axes"][ax][key], a["axes"][ax][key]
            rows.append([f"{ax} {label}", _mm(bb), _mm(aa), "-"])
    out.append(_table(["figure", "before (nominal robot)", "after (calibrated model)", "change"], rows,
                      numeric=(1, 2, 3)))
    out.append(f'<p class="note">{a["n"]} rows. Before: {_e(rep.before_model)}. p95: the 95th percentile '
               "(linear interpolation). Per axis: the component of measured - model.</p>")
    ia, ib = rep.iso_after, rep.iso_before
    iso_rows = [["AP, mean over poses", _mm(ib["ap_mm"]["mean"]), _mm(ia["ap_mm"]["mean"])],
                ["AP, max over poses", _mm(ib["ap_mm"]["max"]), _mm(ia["ap_mm"]["max"])]]
    if ia["rp_mm"] is not None:
        iso_rows += [["RP, mean over poses with repeats", _mm(ib["rp_mm"]["mean"]), _mm(ia["rp_mm"]["mean"])],
                     ["RP, max over poses with repeats", _mm(ib["rp_mm"]["max"]), _mm(ia["rp_mm"]["max"])]]
    out.append("<h3>ISO 9283 pose accuracy and repeatability</h3>")
    out.append(_table(["figure", "before", "after"], iso_rows, numeric=(1, 2)))
    out.append(f'<p class="note">{ia["poses"]} poses, {ia["cycles"]["min"]} to {ia["cycles"]["max"]} rows each. '
               "AP = |mean over the pose's rows of (measured - model)|, the distance from the commanded "
               "position (the model's) to the barycentre of the attained ones. RP = l&#772; + 3 S<sub>l</sub> "
               "over a pose's rows, l<sub>j</sub> the distance of row j from the barycentre, for poses measured "
               f"3 times or more ({ia['poses_with_repeats']} here). Computed on the poses of the data, not on the "
               "standard's five cube poses with 30 cycles each (docs/report.md).</p>")
    da, db = (rep.residuals_after.norm(dim=-1).numpy(), rep.residuals_before.norm(dim=-1).numpy())
    out.append(_figure(figures.error_histogram_figure(db, da, tolerance_mm=rep.tolerance_mm),
                       "Distance error on the held-out rows before (nominal robot) and after calibration.",
                       "histogram of the distance error before and after"))
    m = rep.data
    xyz = m.xyz.detach().cpu().numpy()
    out.append(_figure(figures.error_map_figure(xyz, da, title="Calibrated model on the held-out rows"),
                       "Error map: the held-out measured positions coloured by the calibrated model's distance "
                       "error (the five largest ringed).", "error map over the workspace"))
    out.append(_figure(figures.residual_vs_joints_figure(m.q.detach().cpu().numpy(),
                                                         rep.residuals_after.detach().cpu().numpy(),
                                                         prismatic=rep.robot.prismatic.cpu().numpy(),
                                                         title="Calibrated model: residual against each joint "
                                                               "angle (held-out rows)"),
                       "Residual of the calibrated model against each joint angle.", "residual against joints"))
    return '<section class="page">' + "".join(out) + "</section>"


def _per_pose(rep) -> str:
    out = ["<h2>4. Verdict per pose</h2>"]
    v, vb = rep.verdict_after, rep.verdict_before
    if v is None:
        out.append("<p>No verdict: " + ("no tolerance was given (<code>--tolerance-mm</code>)."
                                          if rep.after is not None else "no held-out measurements were given.")
                   + "</p>")
        return '<section class="page">' + "".join(out) + "</section>"
    out.append(_verdict_box(rep))
    out.append(_table(["", "before (nominal robot)", "after (calibrated model)"], [
        ["poses passing", f"{vb['poses'] - vb['poses_failed']} of {vb['poses']}",
         f"{v['poses'] - v['poses_failed']} of {v['poses']}"],
        ["rows within tolerance", f"{vb['rows'] - vb['rows_failed']} of {vb['rows']}",
         f"{v['rows'] - v['rows_failed']} of {v['rows']}"],
        ["worst row", _mm(vb["worst_mm"]), _mm(v["worst_mm"])]], numeric=(1, 2)))
    out.append(f'<p class="note">A pose passes when every row measured at it (repeats, reflectors) lies within '
               f"{v['tolerance_mm']:g} mm of the calibrated model; the robot passes when every held-out pose "
               "passes. Every pose not listed below passes.</p>")
    if v["failed"]:
        shown = v["failed"][:FAILED_SHOWN]
        out.append(f"<h3>Failing poses after calibration ({v['poses_failed']}, worst first"
                   + (f"; the first {FAILED_SHOWN} listed" if len(v["failed"]) > FAILED_SHOWN else "") + ")</h3>")
        out.append(_table(["pose", "largest distance error", "over the tolerance by"],
                          [[_e(f["pose"]), _mm(f["max_mm"]), _mm(f["max_mm"] - v["tolerance_mm"])] for f in shown],
                          numeric=(1, 2)))
    return '<section class="page">' + "".join(out) + "</section>"


def _iv(lo, hi) -> str:
    return "[" + ", ".join(f"{a:+.3f}..{b:+.3f}" for a, b in zip(lo, hi)) + "]"


def _table5(rep) -> str:
    """The paper's Table 5 on the held-out poses (an interval model with zones)."""
    if not rep.zones:
        return ""
    tol = rep.tolerance_mm
    out = ["<h2>4b. Per pose and zone: error intervals and R_set (the paper's Table 5)</h2>",
           f'<p class="note">Per held-out pose: the interval [min..max] over its rows of measured - model, per '
           "axis x, y, z (mm), before (" + _e(rep.before_model) + ") and after (the center parameters of the "
           "pose's zone)"
           + (f"; R_set of each axis interval against [-{tol:g}, {tol:g}] mm and of the distance against "
              f"[0, {tol:g}] mm (1: surely within; docs/paper.md)" if tol else "; R_set needs --tolerance-mm")
           + ".</p>"]
    head = ["pose", "zone", "rows", "before x, y, z (mm)", "after x, y, z (mm)"]
    if tol:
        head += ["R_set before x y z dist", "R_set after x y z dist"]
    rows = []
    for r in rep.zones:
        row = [_e(r["pose"]), _e(r["zone"]), _e(r["rows"]), _iv(r["before"]["lower"], r["before"]["upper"]),
               _iv(r["after"]["lower"], r["after"]["upper"])]
        if tol:
            row += [" ".join(f"{v:.2f}" for v in r[k]["r_set"]) for k in ("before", "after")]
        rows.append(row)
    out.append(_table(head, rows, numeric=(2,)))
    if tol:
        import statistics

        for k in ("before", "after"):
            d = [r[k]["r_set"][3] for r in rep.zones]
            out.append(f'<p class="note">R_set of the distance {k}: median {statistics.median(d):.3f}, '
                       f"{sum(v >= 1.0 for v in d)} of {len(d)} poses at 1.</p>")
    return '<section class="page">' + "".join(out) + "</section>"


def _fit_terms(h: dict) -> list:
    """[(spec, stability record)] of what discover kept as fit terms only (its history's
    ``absorbing``: effects, or joint parts of an effect on several joints, that failed
    the split-half check, `torchcal.diagnosis.stability`)."""
    records = {}
    for spec, st in (h.get("stability") or {}).items():
        records[spec] = st
        records.update({p["spec"]: p for p in (st.get("parts") or {}).values()})
    return [(spec, records.get(spec, {})) for spec in h.get("absorbing", [])]


def _labels(h: dict) -> str:
    """The named effects and the fit terms of a discover history, as a paragraph ('' for
    a history without the split-half check)."""
    if "named" not in h and not h.get("absorbing"):
        return ""
    terms = [f"{_e(spec)} (fitted on one side of the median of {_e(st.get('split', '?'))} it does not predict "
             f"the other side better: gain {1000 * st.get('gain_mm', 0.0):+.1f} um, p {st.get('p_value', 1.0):.2g})"
             for spec, st in _fit_terms(h)]
    return (f"<p>Named as physics: {_e(', '.join(h.get('named', [])) or 'none')}. "
            + (f"In the model as fit terms only, not named: {'; '.join(terms)}." if terms else
               "Every added effect held on the half of the poses it was not fitted on.") + "</p>")


def _rounds(rep) -> str:
    h = rep.history
    out = ["<h2>5. Discovery rounds</h2>"]
    if h is None:
        out.append("<p>No discover history was given (<code>--history</code>, the <code>--json</code> of "
                   "<code>torchcal discover</code>).</p>")
        return '<section class="page">' + "".join(out) + "</section>"
    out.append(f'<p class="note">Each round refits the most promising missing effects in full and accepts one '
               f"only when the refit lowers the held-out (cross-validated) error beyond chance and by enough "
               f"(docs/diagnosis.md). Final effects: {_e(', '.join(h.get('final_effects', [])) or 'none')}.</p>")
    out.append(_labels(h))
    for k, r in enumerate(h.get("history", [])):
        out.append(f"<h3>Round {k}: model [{_e(', '.join(r.get('effects', [])) or 'geometric only')}]</h3>")
        out.append(f"<p>fit RMS {_mm(r.get('rms_mm'))}, refit cross-validated RMS {_mm(r.get('cv_rms_mm'))}</p>")
        step = r.get("step") or {}
        refits = step.get("refits", [])
        if refits:
            rows, cls = [], []
            for c in refits:
                verdict = "accepted" if c.get("accepted") else ("passed, not taken" if c.get("passed")
                                                                 else "rejected")
                rows.append([_e(c.get("candidate")), _mm(c.get("rms_mm")), _mm(c.get("cv_rms_mm")),
                             _num(c.get("p_value"), 3), verdict, _e(c.get("reason", ""))])
                cls.append("" if c.get("accepted") else "rej")
            out.append(_table(["candidate", "refit RMS", "refit cv RMS", "p", "verdict", "reason"], rows,
                              numeric=(1, 2, 3), cls_rows=cls))
        else:
            out.append('<p class="note">No candidate was refitted in this round.</p>')
    return '<section class="page">' + "".join(out) + "</section>"


def _unexplained_text(u: dict) -> str:
    pairs = [("RMS left", _mm(u.get("rms_mm"))), ("noise floor (estimated)", _mm(u.get("noise_floor_mm"))),
             ("learnable part (a kernel probe on held-out poses)", _mm(u.get("learnable_rms_mm"))),
             ("what the probe leaves", _mm(u.get("probe_left_rms_mm"))),
             ("learnable beyond chance", "yes" if u.get("significant") else "no")]
    probe = u.get("probe") or {}
    if probe:
        pairs.append(("probe", f"inputs {_e(', '.join(probe.get('inputs', [])) or 'none')}, p "
                               f"{_num(probe.get('p_value'), 3)}"))
    cw = u.get("correlates_with") or []
    if cw:
        pairs.append(("depends on", _e(", ".join(f"{c['variable']} (held-out R2 {c['strength']:.2f})" for c in cw))))
    return _kv(pairs)


def _learnable(rep) -> str:
    from viz import figures
    from torchcal.diagnosis.dependence import signed_components
    from torchcal.diagnosis.unexplained import variables

    out = ["<h2>6. What stays learnable</h2>"]
    if rep.unexplained is not None:
        u = rep.unexplained
        out.append("<h3>On the held-out poses (calibrated model)</h3>")
        out.append(f"<p>{_e(u.describe())}</p>")
        out.append(_unexplained_text(u.to_dict()))
        if u.residuals is not None:
            m, robot = rep.data, rep.robot
            fig = figures.residual_vs_variables_figure(
                variables(robot, m), u.residuals, {k: s for k, (s, _) in u.strengths.items()},
                correlates=[v for v, _ in u.correlates_with],
                components=signed_components(robot, m, u.residuals),
                prismatic=[f"q{j + 1}" for j in robot.prismatic.nonzero().flatten().tolist()],
                title="Held-out residual against each variable, strongest dependence first (* significant)")
            out.append(_figure(fig, "What the calibrated model leaves, against every recorded variable.",
                               "residual against each variable"))
    if rep.history is not None and rep.history.get("unexplained"):
        out.append("<h3>On the training poses (discover's final model)</h3>")
        out.append(_unexplained_text(rep.history["unexplained"]))
    if len(out) == 1:
        out.append("<p>Not available: give held-out data (<code>--data</code>) or discover's history "
                   "(<code>--history</code>).</p>")
    return '<section class="page">' + "".join(out) + "</section>"


def _transfer(rep) -> str:
    """The transfer check as discover recorded it: each round's `transfer` record
    (`torchcal.diagnosis.transfer.TransferCheck.choose`: current_mm, tried, kept)."""
    rounds = [(k, r["transfer"]) for k, r in enumerate((rep.history or {}).get("history", [])) if r.get("transfer")]
    if not rounds:
        return ""
    out = ["<h2>7. Transfer check (second session)</h2>",
           '<p class="note">Each round\'s model registered (frame only) on the other session\'s first poses, '
           "its distance RMS on that session's other poses; a step that did not lower it beyond chance (paired "
           "test over that session's poses) was refused as helping within the training session only "
           "(docs/diagnosis.md).</p>"]
    rows, cls = [], []
    for k, t in rounds:
        if not t.get("tried"):
            rows.append([str(k), "none", _mm(t.get("current_mm")), "", "no step to check"])
            cls.append("")
        for c in t.get("tried", []):
            why = f" ({_e(c['reason'])})" if c.get("reason") else ""
            if "parts" not in c:
                rows.append([str(k), _e(c.get("effect")), _mm(t.get("current_mm")), _mm(c.get("after_mm")),
                             ("refused: helps within the session only" if c.get("refused") else "kept") + why])
                cls.append("rej" if c.get("refused") else "")
                continue
            # a step on several joints, judged per joint part (torchcal.diagnosis.transfer)
            rows.append([str(k), _e(c.get("effect")), _mm(t.get("current_mm")), _mm(c.get("after_mm")),
                         "lowers it as a whole" + why + "; per joint:"])
            cls.append("")
            for p in c["parts"]:
                rows.append([str(k), f"&nbsp;&nbsp;joint {p['joint']}: {_e(p.get('effect'))}", _mm(p.get("without_mm")),
                             _mm(c.get("after_mm")), ("kept" if p.get("kept") else "dropped") +
                             f" ({_e(p.get('reason'))}; before: the step without this part)"])
                cls.append("" if p.get("kept") else "rej")
            landed = c.get("landed")
            rows.append([str(k), _e(c.get("effect") if landed is None else landed.get("effect")),
                         _mm(t.get("current_mm")), _mm(None if landed is None else landed.get("after_mm")),
                         "refused: no joint's part lowers it on its own" if landed is None else
                         ("refused" if landed.get("refused") else "kept") + f" ({_e(landed.get('reason'))})"])
            cls.append("rej" if c.get("refused") else "")
    out.append(_table(["round", "step", "other session before", "other session after", "verdict"], rows,
                      numeric=(2, 3), cls_rows=cls))
    return '<section class="page">' + "".join(out) + "</section>"


def report_html(rep) -> str:
    """The report's HTML text (module doc) of a `CalibrationReport`."""
    title = f"Calibration report: {rep.model.get('robot', '')}"
    body = "".join([_summary(rep), _provenance(rep), _model(rep), _accuracy(rep), _per_pose(rep), _table5(rep),
                    _rounds(rep), _learnable(rep), _transfer(rep)])
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{_e(title)}</title><style>{CSS}</style></head><body>{body}</body></html>\n")


def write_report(path, rep, *, force: bool = False, inputs=()):
    """Write `report_html(rep)` to `path` atomically (an existing file only with force,
    an input never); returns the path."""
    return atomic_write(path, report_html(rep), force=force, inputs=inputs)
