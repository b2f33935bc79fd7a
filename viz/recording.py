"""What a calibration logs into a rerun recording (``.rrd``), and the layout it opens on.

Open one with ``rerun FILE.rrd``. Two layers:

- ``log_*`` functions (here) log plain arrays (numpy or torch, any device) into a
  ``rerun.RecordingStream`` or a writer: no files, no viewer, no global recording;
- the file writer (`viz.recording_writer`) opens the file, hands out its stream, and on
  close finalises the file and moves it into place atomically; `RecordingWriter` here is
  that writer laid out on `default_blueprint` for what was logged.

Example::

    from viz.recording import RecordingWriter, log_workspace, log_summary
    with RecordingWriter("demo.rrd", seed=0) as rec:
        log_workspace(rec, positions_mm, r_set, zones)
        log_summary(rec, "# torchcal demo\\n...")

Entity paths (positions in mm in the robot base frame, z up; rerun scene units are mm):

- ``workspace``: AnnotationContext, zone id -> name (``"zone k+1"``) and colour.
- ``workspace/rset``: Points3D coloured by R_set on ``RdYlGn`` (red = low) over the data range.
- ``workspace/zones``: Points3D with ``class_ids`` = zone id (colour and name from ``workspace``).
- ``workspace/centres``: Points3D, one per zone, labelled with the zone's mean R_set and size.
- ``residuals/{before,after}/measured``: Points3D, measured TCP positions.
- ``residuals/{before,after}/model``: Points3D, the model's (predicted) positions.
- ``residuals/{before,after}/residual``: Arrows3D from model to measured, drawn
  ``arrow_scale`` times the residual (default `RESIDUAL_ARROW_SCALE` = 100: a 1 mm residual
  is a 100 mm arrow); each label gives the true length in mm.
- ``error_map/points``: Points3D, positions coloured by their distance error (light = small,
  dark = large; `log_error_map`); ``error_map/error_mm``: the values.
- ``error_intervals/{x,y,z}/{before,after}/{lower,upper}``: Scalars in mm on the sequence
  timeline ``test_point`` (1, 2, ...): the paper's Fig. 11, one time-series plot per axis.
- ``error_intervals/{x,y,z}/allowed/{lower,upper}``: Scalars, the allowed band (+-1 mm).
- ``discover/rms_mm``, ``discover/cv_rms_mm``: Scalars in mm on the sequence timeline
  ``round`` (0 = the starting model, k = after the k-th added effect).
- ``discover/added``: TextLog per round, the effect added.
- ``summary``: TextDocument, markdown.
- ``variables/kk_NAME[_significant]/{points,frame,axes}``: the residual against variable
  NAME of rank kk (01 = strongest dependence), a 2D scatter (`log_residual_vs_variables`,
  the recording's twin of `viz.figures.residual_vs_variables`); ``variables``: the table.

Error intervals are time series (x axis = test point number) rather than 3D line strips:
bounds per test point are read most easily as a plot, as in the paper. A time-series view
shows the timeline selected in the time panel; the default blueprint selects
``test_point`` when error intervals were logged, else ``round``.

Recordings are deterministic in content (`viz.recording_writer`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from torchcal.errors import InputError
from viz import _common as C
from viz.recording_writer import APPLICATION_ID, recording_id  # noqa: F401 (re-exported)
from viz.recording_writer import RecordingWriter as _Writer
from viz.recording_writer import stream_of as _stream

RESIDUAL_ARROW_SCALE = 100.0
"""Default factor from residual length (mm) to drawn arrow length (mm): a 0.5 mm residual
is drawn 50 mm long, visible next to a 3 m robot."""
MAX_POINTS = 200_000
"""Default cap on logged workspace points (evenly spaced subsample beyond it)."""
MAX_LABELS = 5_000
"""Per-point labels are written only up to this many points (they cost file size)."""
STAGES = ("before", "after")
TEST_POINT_TIMELINE = "test_point"
ROUND_TIMELINE = "round"


def _columns(stream: rr.RecordingStream, entity: str, timeline: str, steps, values) -> None:
    """Send one scalar series `values` at sequence indices `steps` on `timeline`."""
    stream.send_columns(entity, indexes=[rr.TimeColumn(timeline, sequence=np.asarray(steps, dtype=np.int64))],
                        columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=np.float64)))


# --------------------------------------------------------------------------- workspace
def log_workspace(rec, positions_mm, r_set, zones, *, centers_mm=None, zone_names=None,
                  rset_range=None, max_points: int | None = MAX_POINTS, point_radius_ui: float = 3.0) -> None:
    """Log workspace points coloured by R_set and by zone, and the zone centers.

    Args:
        rec: a `rerun.RecordingStream` or a `RecordingWriter`.
        positions_mm: (N, 3) workspace points, mm, robot base frame.
        r_set: (N,) set reliability per point, in [0, 1] (1 = fully reliable).
        zones: (N,) integer zone id per point (0-based).
        centers_mm: (Z, 3) zone centers in space, mm; default: mean of each zone's points.
        zone_names: display name per zone id; default ``"zone k+1"`` (ids are 0-based in
            arrays and shown 1-based, as the paper's zones 1..10).
        rset_range: (low, high) R_set mapped to red..green; default: the data range.
        max_points: log at most this many points (evenly spaced subsample); None: all.
        point_radius_ui: point radius in UI points (independent of the robot's size).

    Logs ``workspace`` (AnnotationContext: zone id -> name, colour), ``workspace/rset``,
    ``workspace/zones`` and ``workspace/centres`` (all static).
    """
    stream = _stream(rec, "workspace")
    pos = C.points(positions_mm, "positions_mm")
    n = pos.shape[0]
    rs = C.vector(r_set, "r_set", n)
    zs = C.labels(zones, "zones", n)
    names, centers = C.zone_centers(pos, zs, centers_mm, zone_names)
    count = len(names)
    lo, hi = C.rset_range(rs, rset_range)
    rgb = C.zone_rgb(count)
    stream.log("workspace", rr.AnnotationContext(
        [rr.AnnotationInfo(id=z, label=names[z], color=tuple(int(c) for c in rgb[z])) for z in range(count)]),
        static=True)

    idx = C.subsample(n, max_points)
    p, r, z = pos[idx], rs[idx], zs[idx]
    radius = rr.Radius.ui_points(point_radius_ui)
    with_labels = len(idx) <= MAX_LABELS
    rset_labels = [f"{names[zi]}, R_set {ri:.3f}" for zi, ri in zip(z, r)] if with_labels else None
    stream.log("workspace/rset", rr.Points3D(p, colors=C.rset_rgb(r, lo, hi), radii=radius,
                                             labels=rset_labels, show_labels=False), static=True)
    stream.log("workspace/zones", rr.Points3D(p, class_ids=z.astype(np.uint16), radii=radius,
                                              labels=rset_labels, show_labels=False), static=True)

    keep = np.isfinite(centers).all(axis=1)
    center_labels = []
    for k in range(count):
        members = zs == k
        if members.any():
            center_labels.append(f"{names[k]}: R_set {rs[members].mean():.3f}, {int(members.sum())} pts")
        else:
            center_labels.append(f"{names[k]}: no points")
    stream.log("workspace/centres", rr.Points3D(
        centers[keep], class_ids=np.arange(count, dtype=np.uint16)[keep],
        radii=rr.Radius.ui_points(3.0 * point_radius_ui), labels=[s for s, k in zip(center_labels, keep) if k],
        show_labels=True), static=True)


# --------------------------------------------------------------------------- residuals
def log_residuals(rec, stage: str, measured_mm, model_mm, *, arrow_scale: float = RESIDUAL_ARROW_SCALE,
                  point_names: Sequence[str] | None = None, point_radius_ui: float = 3.0) -> None:
    """Log measured and model positions and the residual arrows of one stage.

    Args:
        rec: a `rerun.RecordingStream` or a `RecordingWriter`.
        stage: ``"before"`` or ``"after"`` (calibration / compensation).
        measured_mm: (N, 3) measured TCP positions, mm.
        model_mm: (N, 3) positions the model predicts for the same poses, mm.
        arrow_scale: drawn arrow length per mm of residual (default 100: 1 mm -> 100 mm).
        point_names: (N,) names for the labels (e.g. ``"pose 12"``); default ``"point i"``.
        point_radius_ui: point radius in UI points.

    Logs ``residuals/{stage}/measured``, ``/model`` (Points3D) and ``/residual`` (Arrows3D
    from model to measured, vectors = (measured - model) * arrow_scale; each label gives
    the true residual length in mm), all static.
    """
    if stage not in STAGES:
        raise InputError(f"stage: expected one of {STAGES}, got {stage!r}")
    if not (isinstance(arrow_scale, (int, float)) and np.isfinite(arrow_scale) and arrow_scale > 0):
        raise InputError(f"arrow_scale: expected a positive number, got {arrow_scale!r}")
    stream = _stream(rec, f"residuals/{stage}")
    if isinstance(rec, RecordingWriter):
        rec.arrow_scale = float(arrow_scale)
    meas = C.points(measured_mm, "measured_mm")
    model = C.points(model_mm, "model_mm", meas.shape[0])
    n = meas.shape[0]
    if point_names is None:
        point_names = [f"point {i}" for i in range(n)]
    elif len(point_names) != n:
        raise InputError(f"point_names: expected {n} names (one per point), got {len(point_names)}")
    res = meas - model  # (N, 3) mm
    norm = np.linalg.norm(res, axis=1)
    radius = rr.Radius.ui_points(point_radius_ui)
    base = f"residuals/{stage}"
    stream.log(f"{base}/measured", rr.Points3D(meas, colors=C.MEASURED_RGB, radii=radius,
                                               labels=[f"{s} measured" for s in point_names],
                                               show_labels=False), static=True)
    model_rgb = C.MODEL_BEFORE_RGB if stage == "before" else C.MODEL_AFTER_RGB
    stream.log(f"{base}/model", rr.Points3D(model, colors=model_rgb, radii=radius,
                                            labels=[f"{s} model ({stage})" for s in point_names],
                                            show_labels=False), static=True)
    arrow_rgb = C.BEFORE_RGB if stage == "before" else C.AFTER_RGB
    stream.log(f"{base}/residual", rr.Arrows3D(
        origins=model, vectors=res * float(arrow_scale), colors=arrow_rgb,
        radii=rr.Radius.ui_points(1.5),
        labels=[f"{s}: {v:.3f} mm (drawn x{arrow_scale:g})" for s, v in zip(point_names, norm)],
        show_labels=False), static=True)


def log_error_map(rec, positions_mm, error_mm, *, point_names: Sequence[str] | None = None,
                  point_radius_ui: float = 4.0) -> None:
    """Log the positions coloured by their distance error (the twin of `viz.figures.error_map`).

    Args:
        rec: a `rerun.RecordingStream` or a `RecordingWriter`.
        positions_mm: (N, 3) measured TCP positions, mm.
        error_mm: (N,) distance error per row, mm.
        point_names: (N,) names for the labels (default ``"point i"``).

    Logs ``error_map/points`` (Points3D on `viz._common.ERROR_CMAP`, 0 .. the 99th
    percentile; each label gives the error in mm) and ``error_map/error_mm`` (the values), static.
    """
    stream = _stream(rec, "error_map")
    pos = C.points(positions_mm, "positions_mm")
    e = C.vector(error_mm, "error_mm", len(pos))
    if point_names is None:
        point_names = [f"point {i}" for i in range(len(pos))]
    elif len(point_names) != len(pos):
        raise InputError(f"point_names: expected {len(pos)} names (one per point), got {len(point_names)}")
    stream.log("error_map/points", rr.Points3D(pos, colors=C.error_rgb(e, C.error_scale(e)),
                                               radii=rr.Radius.ui_points(point_radius_ui),
                                               labels=[f"{s}: {v:.4f} mm" for s, v in zip(point_names, e)],
                                               show_labels=False), static=True)
    stream.log("error_map/error_mm", rr.AnyValues(error_mm=e), static=True)


# --------------------------------------------------------------------------- error intervals (Fig. 11)
def log_error_intervals(rec, before_lower_mm, before_upper_mm, after_lower_mm=None, after_upper_mm=None, *,
                        allowed_mm: float | None = 1.0, also=()) -> None:
    """Log error intervals per test point before and after compensation (the paper's Fig. 11).

    Args:
        rec: a `rerun.RecordingStream` or a `RecordingWriter`.
        before_lower_mm, before_upper_mm: (T, 3) lower / upper bound of the x, y, z error of
            each test point before compensation, mm.
        after_lower_mm, after_upper_mm: (T, 3) the same after compensation, or both None.
        allowed_mm: the allowed component error, drawn as the band +-allowed_mm; None: none.
        also: further (name, lower (T, 3), upper (T, 3)) after compensation by other
            methods, logged as stages of their own (name: an entity path part).

    Logs Scalars on the sequence timeline ``test_point`` (1..T) at
    ``error_intervals/{axis}/{stage}/{lower,upper}`` and ``error_intervals/{axis}/allowed/...``,
    with SeriesLines/SeriesPoints styles (before red, after green, allowed grey).
    """
    stream = _stream(rec, "error_intervals")
    b_lo, b_hi = C.intervals(before_lower_mm, before_upper_mm, "before", None)
    stages = [("before", b_lo, b_hi, C.BEFORE_RGB)]
    if (after_lower_mm is None) != (after_upper_mm is None):
        raise InputError("after_lower_mm, after_upper_mm: give both or neither")
    if after_lower_mm is not None:
        a_lo, a_hi = C.intervals(after_lower_mm, after_upper_mm, "after", b_lo.shape[0])
        stages.append(("after", a_lo, a_hi, C.AFTER_RGB))
    for (name, lo, hi), rgb in zip(also, C.ALSO_RGB):
        stages.append((name, *C.intervals(lo, hi, name, b_lo.shape[0]), rgb))
    if allowed_mm is not None and not (np.isfinite(allowed_mm) and allowed_mm > 0):
        raise InputError(f"allowed_mm: expected a positive number of mm or None, got {allowed_mm!r}")
    steps = np.arange(1, b_lo.shape[0] + 1)
    for a, axis in enumerate(C.AXES):
        for stage, lo, hi, rgb in stages:
            for bound, vals in (("lower", lo[:, a]), ("upper", hi[:, a])):
                path = f"error_intervals/{axis}/{stage}/{bound}"
                label = f"{stage} {bound}"
                stream.log(path, rr.SeriesLines(colors=rgb, names=label, widths=2.0),
                           rr.SeriesPoints(colors=rgb, names=label, markers="circle", marker_sizes=3.0),
                           static=True)
                _columns(stream, path, TEST_POINT_TIMELINE, steps, vals)
        if allowed_mm is not None:
            for bound, sign in (("lower", -1.0), ("upper", 1.0)):
                path = f"error_intervals/{axis}/allowed/{bound}"
                stream.log(path, rr.SeriesLines(colors=C.ALLOWED_RGB, names=f"allowed {sign * allowed_mm:+g} mm",
                                                widths=1.0), static=True)
                _columns(stream, path, TEST_POINT_TIMELINE, steps, np.full(len(steps), sign * allowed_mm))


# --------------------------------------------------------------------------- discover
def _discover_styles(stream: rr.RecordingStream) -> None:
    stream.log("discover/rms_mm", rr.SeriesLines(colors=C.BEFORE_RGB, names="RMS error, training (mm)", widths=2.0),
               rr.SeriesPoints(colors=C.BEFORE_RGB, names="RMS error, training (mm)", markers="circle",
                               marker_sizes=4.0), static=True)
    stream.log("discover/cv_rms_mm", rr.SeriesLines(colors=C.MEASURED_RGB, names="RMS error, held out (mm)",
                                                    widths=2.0),
               rr.SeriesPoints(colors=C.MEASURED_RGB, names="RMS error, held out (mm)", markers="diamond",
                               marker_sizes=4.0), static=True)


def log_discover_round(rec, round_index: int, rms_mm: float, cv_rms_mm: float | None = None,
                       added: str | None = None) -> None:
    """Log the error after one round of ``discover`` (call once per round, as it runs).

    Args:
        rec: a `rerun.RecordingStream` or a `RecordingWriter`.
        round_index: 0 for the starting model, k after the k-th added effect.
        rms_mm: RMS position error on the training poses after this round, mm.
        cv_rms_mm: cross-validated (held-out) RMS error, mm, or None.
        added: the effect added in this round (e.g. ``"joint_compliance:2,3"``), or None.

    Logs ``discover/rms_mm``, ``discover/cv_rms_mm`` (Scalars) and ``discover/added``
    (TextLog) at ``round = round_index``; round 0 also logs the series styles (names,
    colours), so a history should start at round 0.
    """
    stream = _stream(rec, "discover")
    if isinstance(round_index, bool) or not isinstance(round_index, (int, np.integer)) or round_index < 0:
        raise InputError(f"round_index: expected a non-negative integer, got {round_index!r}")
    values = {"rms_mm": rms_mm, "cv_rms_mm": cv_rms_mm}
    for key, v in values.items():
        if v is not None and not np.isfinite(float(v)):
            raise InputError(f"{key}: expected a finite number of mm, got {v!r}")
    if round_index == 0:
        _discover_styles(stream)
    for key, v in values.items():
        if v is not None:
            _columns(stream, f"discover/{key}", ROUND_TIMELINE, [int(round_index)], [float(v)])
    text = f"round {int(round_index)}: " + (f"added {added}, " if added else "") + f"RMS {float(rms_mm):.4f} mm"
    if cv_rms_mm is not None:
        text += f", held-out RMS {float(cv_rms_mm):.4f} mm"
    stream.send_columns("discover/added", indexes=[rr.TimeColumn(ROUND_TIMELINE, sequence=[int(round_index)])],
                        columns=rr.TextLog.columns(text=[text], level=["INFO"]))


def log_discover_history(rec, rms_mm, cv_rms_mm=None, added: Sequence[str | None] | None = None) -> None:
    """Log a whole ``discover`` history: `log_discover_round` for rounds 0..R-1.

    Args:
        rms_mm: (R,) training RMS error after each round, mm (round 0 = starting model).
        cv_rms_mm: (R,) held-out RMS error, mm, or None.
        added: (R,) effect added in each round (None or "" for round 0), or None.
    """
    rms = C.vector(rms_mm, "rms_mm")
    cv = None if cv_rms_mm is None else C.vector(cv_rms_mm, "cv_rms_mm", rms.shape[0])
    if added is not None and len(added) != rms.shape[0]:
        raise InputError(f"added: expected {rms.shape[0]} entries (one per round), got {len(added)}")
    for k in range(rms.shape[0]):
        log_discover_round(rec, k, float(rms[k]), None if cv is None else float(cv[k]),
                           None if added is None else added[k])


# --------------------------------------------------------------------------- residual against variables
VARIABLE_BOX = (100.0, 60.0)
"""Width and height of the drawn box of one residual-against-variable scatter (2D scene
units): x spans the variable's range, y +-(max |y|) around the zero line."""
SIGNIFICANT_RGB = C.BEFORE_RGB
OTHER_RGB = (90, 90, 90)


def variable_entity(rank: int, name: str) -> str:
    """Entity path of the `rank`-th (1 = strongest) variable's scatter."""
    return f"variables/{rank:02d}_{name}"


def log_residual_vs_variables(rec, values, residual_mm, strengths, *, correlates=(), components=None,
                              prismatic=(), point_radius_ui: float = 2.5) -> list[tuple[str, str]]:
    """Log the residual against every variable (as `viz.figures.residual_vs_variables`):
    one 2D scatter per variable, strongest dependence first, the significant ones red.

    Args:
        rec: a `rerun.RecordingStream` or a `RecordingWriter`.
        values: {name: (N,) values} of `torchcal.diagnosis.unexplained.variables` (joint
            angles ``q1..`` in rad, drawn in degrees).
        residual_mm: (N, 3) residual vectors (or (N,) lengths), mm.
        strengths: {name: strength} (held-out R^2); the order, strongest first.
        correlates: the names found significant: drawn red, entity and view names carry
            ``significant``/``*``.
        components: {name: (N,) mm} signed residual component per variable, drawn instead
            of the length where given.
        prismatic: names of the prismatic joints (``q3``: values in mm, drawn as given).

    A rerun 2D view has equal axes and y down, so each scatter is drawn in a box of
    `VARIABLE_BOX` scene units: x = the variable scaled from its minimum (left) to its
    maximum (right), y up = the plotted residual value scaled to +-box/2 by its largest
    magnitude. Each point's label gives the true values. Logs, all static, for rank k
    (1 = strongest): ``variables/kk_NAME/points`` (Points2D, N points, red when
    significant, else grey), ``variables/kk_NAME/frame`` (LineStrips2D: box and zero line)
    and ``variables/kk_NAME/axes`` (Points2D, labelled axis ends in true units); and
    ``variables`` (TextDocument: the table rank, variable, strength, significant).

    Returns [(entity, view title)] in rank order (the writer keeps it for the blueprint).
    """
    stream = _stream(rec, "variables")
    panels = C.variable_panels(values, residual_mm, strengths, correlates, components, prismatic)
    W, H = VARIABLE_BOX
    views, table = [], ["| rank | variable | strength (held-out R2) | significant | entity |", "|---|---|---|---|---|"]
    radius = rr.Radius.ui_points(point_radius_ui)
    for k, p in enumerate(panels, start=1):
        base = variable_entity(k, p["name"]) + ("_significant" if p["significant"] else "")
        x, y = p["x"], p["y"]
        x0, x1 = float(x.min()), float(x.max())
        span = x1 - x0 if x1 > x0 else 1.0
        ymax = float(np.abs(y).max()) or 1.0
        pos = np.stack([(x - x0) / span * W, -y / ymax * (H / 2)], axis=1)  # y up on screen
        unit = " deg" if p["x_label"].endswith("(deg)") else " mm" if p["x_label"].endswith("(mm)") else ""
        labels = [f"{p['name']} {xi:.4g}{unit}: {yi:+.4f} mm" for xi, yi in zip(x, y)] \
            if len(x) <= MAX_LABELS else None
        rgb = SIGNIFICANT_RGB if p["significant"] else OTHER_RGB
        stream.log(f"{base}/points", rr.Points2D(pos, colors=rgb, radii=radius, labels=labels, show_labels=False),
                   static=True)
        box = [[0, -H / 2], [W, -H / 2], [W, H / 2], [0, H / 2], [0, -H / 2]]
        stream.log(f"{base}/frame", rr.LineStrips2D([box, [[0, 0], [W, 0]]], colors=OTHER_RGB,
                                                    radii=rr.Radius.ui_points(0.5), draw_order=-1.0), static=True)
        ends = [[0, H / 2 + 4], [W, H / 2 + 4], [-2, -H / 2], [-2, H / 2]]  # below left/right, then y ends
        what = "|residual|" if p["y_label"].startswith("|") else "residual component"
        stream.log(f"{base}/axes", rr.Points2D(ends, radii=rr.Radius.ui_points(0.1), colors=OTHER_RGB, labels=[
            f"{p['x_label']} {x0:.4g}", f"{x1:.4g}", f"{what} {ymax:+.3f} mm", f"{-ymax:+.3f} mm"],
            show_labels=True), static=True)
        title = f"{'* ' if p['significant'] else ''}{p['name']}  R2 {C.r2_text(p['strength'])}: {p['y_label']}"
        views.append((base, title))
        table.append(f"| {k} | {p['name']} | {p['strength']:.3f} | {'yes' if p['significant'] else 'no'} | {base} |")
    stream.log("variables", rr.TextDocument("# Residual against each variable, strongest first\n\n"
                                            + "\n".join(table) + "\n", media_type=rr.MediaType.MARKDOWN),
               static=True)
    if isinstance(rec, RecordingWriter):
        rec.variable_views = views
    return views


# --------------------------------------------------------------------------- summary
def summary_markdown(title: str, facts: Mapping[str, object] | None = None, notes: Sequence[str] = ()) -> str:
    """A markdown summary: a title, a two-column table of `facts`, then `notes` as bullets.

    Floats are written with 4 significant digits; put the unit in the key (``"RMS (mm)"``).
    """
    lines = [f"# {title}", ""]
    if facts:
        lines += ["| quantity | value |", "|---|---|"]
        for key, value in facts.items():
            text = f"{value:.4g}" if isinstance(value, (float, np.floating)) else str(value)
            lines.append(f"| {key} | {text} |")
        lines.append("")
    lines += [f"- {note}" for note in notes]
    return "\n".join(lines).rstrip() + "\n"


def log_summary(rec, markdown: str) -> None:
    """Log a markdown text summary at ``summary`` (static TextDocument)."""
    stream = _stream(rec, "summary")
    if not isinstance(markdown, str):
        raise InputError(f"markdown: expected a str, got {type(markdown).__name__}")
    stream.log("summary", rr.TextDocument(markdown, media_type=rr.MediaType.MARKDOWN), static=True)


# --------------------------------------------------------------------------- blueprint
ALL_SECTIONS = frozenset({"workspace", "residuals/before", "residuals/after", "error_map", "error_intervals",
                          "discover", "summary", "variables"})


def default_blueprint(sections=ALL_SECTIONS, *, arrow_scale: float = RESIDUAL_ARROW_SCALE,
                      variable_views: Sequence[tuple[str, str]] = ()) -> rrb.Blueprint:
    """The layout a recording opens on, with views only for the logged `sections`.

    Left: 3D views (workspace by R_set, workspace by zone, residuals before, after).
    Right: error intervals per axis (tabs x, y, z), the ``discover`` error per round, the
    summary. The time panel selects ``test_point`` when error intervals are present,
    else ``round``. With ``variables`` logged: a second tab, one 2D view per
    `variable_views` entry ``(entity, title)`` (as returned by `log_residual_vs_variables`),
    in that order (strongest dependence first), beside the table.
    """
    sections = set(sections)
    unknown = sections - ALL_SECTIONS
    if unknown:
        raise InputError(f"sections: unknown {sorted(unknown)}; expected a subset of {sorted(ALL_SECTIONS)}")
    spatial = []
    if "workspace" in sections:
        spatial.append(rrb.Spatial3DView(origin="/", name="Workspace: R_set (red = low)",
                                         contents=["+ /workspace/rset", "+ /workspace/centres"]))
        spatial.append(rrb.Spatial3DView(origin="/", name="Workspace: zones",
                                         contents=["+ /workspace/zones", "+ /workspace/centres"]))
    if "error_map" in sections:
        spatial.append(rrb.Spatial3DView(origin="/", name="Distance error (dark = large)",
                                         contents=["+ /error_map/points"]))
    for stage in STAGES:
        if f"residuals/{stage}" in sections:
            spatial.append(rrb.Spatial3DView(origin="/", name=f"Residuals {stage} (arrows x{arrow_scale:g})",
                                             contents=[f"+ /residuals/{stage}/**"]))
    panels = []
    if "error_intervals" in sections:
        panels.append(rrb.Tabs(*[rrb.TimeSeriesView(origin=f"/error_intervals/{axis}",
                                                    name=f"Error interval {axis} (mm) per test point")
                                 for axis in C.AXES], name="Error intervals"))
    if "discover" in sections:
        panels.append(rrb.TimeSeriesView(origin="/discover", name="discover: RMS error (mm) per round"))
    if "summary" in sections:
        panels.append(rrb.TextDocumentView(origin="/summary", name="Summary"))
    columns = []
    if spatial:
        columns.append(rrb.Grid(*spatial, grid_columns=2 if len(spatial) > 1 else 1, name="3D"))
    if panels:
        columns.append(rrb.Vertical(*panels, name="Plots"))
    timeline = TEST_POINT_TIMELINE if "error_intervals" in sections else ROUND_TIMELINE
    tabs = []
    if columns:
        shares = [3, 2] if len(columns) == 2 else None
        tabs.append(rrb.Horizontal(*columns, column_shares=shares, name="Overview"))
    if "variables" in sections:
        W, H = VARIABLE_BOX
        bounds = rrb.VisualBounds2D(x_range=[-0.25 * W, 1.1 * W], y_range=[-0.6 * H, 0.75 * H])
        views = [rrb.Spatial2DView(origin=f"/{e}", name=t, visual_bounds=bounds) for e, t in variable_views]
        views.append(rrb.TextDocumentView(origin="/variables", contents="$origin", name="Variables by strength"))
        tabs.append(rrb.Grid(*views, grid_columns=4, name="Residual against each variable"))
    if not tabs:
        return rrb.Blueprint(rrb.TimePanel(timeline=timeline))
    root = tabs[0] if len(tabs) == 1 else rrb.Tabs(*tabs)
    return rrb.Blueprint(root, rrb.TimePanel(timeline=timeline))


# --------------------------------------------------------------------------- writer
class RecordingWriter(_Writer):
    """A `viz.recording_writer.RecordingWriter` (same arguments) that opens on
    `default_blueprint` for the sections its ``log_*`` calls logged, with their arrow scale
    and variable views."""

    def __init__(self, path, **options):
        super().__init__(path, **options)
        self.arrow_scale = RESIDUAL_ARROW_SCALE
        self.variable_views: list[tuple[str, str]] = []

    def layout(self) -> rrb.Blueprint:
        return default_blueprint(self.sections, arrow_scale=self.arrow_scale, variable_views=self.variable_views)
