"""viz: rerun recordings read back with rerun.chunk.RrdReader; PNG figures checked on disk."""

from __future__ import annotations

import struct

import numpy as np
import pytest
import rerun as rr
import torch
from rerun.chunk import RrdReader

from torchcal.errors import InputError
from viz import figures
from viz.recording import (RESIDUAL_ARROW_SCALE, RecordingWriter, default_blueprint, log_discover_history,
                           log_discover_round, log_error_intervals, log_residual_vs_variables, log_residuals,
                           log_summary, log_workspace, recording_id, summary_markdown)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


# --------------------------------------------------------------------------- data
def _data(seed: int = 0, n: int = 60, zones: int = 4, t: int = 5):
    rng = np.random.default_rng(seed)
    pos = rng.uniform([500, -2000, 0], [3000, 2000, 3000], (n, 3))  # mm
    zs = np.arange(n) % zones
    r_set = np.clip(1.0 - 0.1 * zs + 0.01 * rng.standard_normal(n), 0, 1)
    b_lo = -rng.uniform(0.2, 1.5, (t, 3))
    b_hi = rng.uniform(0.2, 1.5, (t, 3))
    measured = pos[:10]
    model = measured - rng.normal(0, 0.5, (10, 3))
    return dict(pos=pos, zones=zs, r_set=r_set, b_lo=b_lo, b_hi=b_hi, a_lo=0.4 * b_lo, a_hi=0.4 * b_hi,
                measured=measured, model_before=model, model_after=measured - 0.01)


def _chunks(path) -> dict[str, list]:
    """entity path -> list of record-batch dicts (static and temporal chunks)."""
    out: dict[str, list] = {}
    for ch in RrdReader(path).stream():
        out.setdefault(ch.entity_path, []).append(ch.to_record_batch().to_pydict())
    return out


def _column(chunks, entity, column):
    for rb in chunks[entity]:
        if column in rb:
            return rb
    raise KeyError(f"{entity}:{column}")


@pytest.fixture(scope="module")
def full_recording(tmp_path_factory):
    d = _data()
    path = tmp_path_factory.mktemp("rrd") / "full.rrd"
    with RecordingWriter(path, seed=7) as rec:
        log_workspace(rec, d["pos"], d["r_set"], d["zones"])
        log_residuals(rec, "before", d["measured"], d["model_before"])
        log_residuals(rec, "after", d["measured"], d["model_after"])
        log_error_intervals(rec, d["b_lo"], d["b_hi"], d["a_lo"], d["a_hi"])
        log_discover_history(rec, [0.9, 0.4, 0.12], [1.0, 0.45, 0.13], [None, "joint_compliance:2,3", "backlash"])
        log_summary(rec, summary_markdown("Test run", {"RMS after (mm)": 0.123456, "zones": 4}, ["a note"]))
    return path, d


# --------------------------------------------------------------------------- recordings
def test_recording_is_finalised_and_has_all_entities(full_recording):
    path, _ = full_recording
    reader = RrdReader(path)
    store = reader.store()  # only works when the file has its footer (flushed and disconnected)
    entities = {line.split()[0] for line in store.summary().splitlines()}
    expected = {"/workspace", "/workspace/rset", "/workspace/zones", "/workspace/centres",
                "/residuals/before/measured", "/residuals/before/model", "/residuals/before/residual",
                "/residuals/after/measured", "/residuals/after/model", "/residuals/after/residual",
                "/discover/rms_mm", "/discover/cv_rms_mm", "/discover/added", "/summary"}
    expected |= {f"/error_intervals/{a}/{s}/{b}" for a in "xyz" for s in ("before", "after", "allowed")
                 for b in ("lower", "upper")}
    assert expected <= entities
    [recording] = reader.recordings()
    assert recording.application_id == "torchcal"
    assert recording.recording_id == recording_id(7)
    assert len(reader.blueprints()) == 1
    assert "log_time" not in store.summary()  # no wall-clock timeline


def test_residual_vs_variables_recording_strongest_first_significant_marked(tmp_path):
    """One 2D scatter per variable, in strength order, N points each; the drawn points map
    back to (variable, residual length) by the documented box scaling; the significant
    variable's entity is marked and red; the blueprint has one view per variable."""
    from viz.recording import OTHER_RGB, SIGNIFICANT_RGB, VARIABLE_BOX

    rng = np.random.default_rng(1)
    n = 50
    values = {"q2": rng.uniform(-1, 1, n), "order": np.arange(n, dtype=float), "approach_q3": np.sign(rng.normal(size=n))}
    res = rng.normal(0, 0.1, (n, 3))
    strengths = {"q2": 0.05, "order": -0.01, "approach_q3": 0.6}
    path = tmp_path / "v.rrd"
    with RecordingWriter(path) as rec:
        views = log_residual_vs_variables(rec, values, res, strengths, correlates=["approach_q3"])
    assert [e for e, _ in views] == ["variables/01_approach_q3_significant", "variables/02_q2", "variables/03_order"]
    assert views[0][1].startswith("* approach_q3") and not views[1][1].startswith("*")
    ch = _chunks(path)
    W, H = VARIABLE_BOX
    length = np.linalg.norm(res, axis=1)
    for (entity, _), name in zip(views, ["approach_q3", "q2", "order"]):
        rb = _column(ch, f"/{entity}/points", "Points2D:positions")
        xy = np.array(rb["Points2D:positions"][0])
        assert xy.shape == (n, 2)
        x = np.degrees(values[name]) if name == "q2" else values[name]
        np.testing.assert_allclose(xy[:, 0], (x - x.min()) / np.ptp(x) * W, rtol=1e-5, atol=1e-4)
        np.testing.assert_allclose(xy[:, 1], -length / length.max() * H / 2, rtol=1e-5, atol=1e-4)
        rgb = SIGNIFICANT_RGB if name == "approach_q3" else OTHER_RGB
        assert rb["Points2D:colors"][0][0] == int.from_bytes(bytes(rgb) + b"\xff", "big")
        assert f"/{entity}/frame" in ch and f"/{entity}/axes" in ch
    [text] = _column(ch, "/variables", "TextDocument:text")["TextDocument:text"][0]
    assert "| 1 | approach_q3 | 0.600 | yes |" in text
    assert len(RrdReader(path).blueprints()) == 1


def test_recording_workspace_values(full_recording):
    path, d = full_recording
    ch = _chunks(path)
    rset = _column(ch, "/workspace/rset", "Points3D:positions")
    np.testing.assert_allclose(np.array(rset["Points3D:positions"][0]), d["pos"], rtol=1e-6)
    assert len(rset["Points3D:colors"][0]) == len(d["pos"])
    zones = _column(ch, "/workspace/zones", "Points3D:class_ids")
    assert zones["Points3D:class_ids"][0] == d["zones"].tolist()
    centres = _column(ch, "/workspace/centres", "Points3D:positions")
    want = np.array([d["pos"][d["zones"] == z].mean(axis=0) for z in range(4)])
    np.testing.assert_allclose(np.array(centres["Points3D:positions"][0]), want, rtol=1e-6)
    assert centres["Points3D:labels"][0][0].startswith("zone 1: R_set ")
    [ctx] = _column(ch, "/workspace", "AnnotationContext:context")["AnnotationContext:context"][0]
    assert [c["class_description"]["info"]["label"] for c in ctx] == ["zone 1", "zone 2", "zone 3", "zone 4"]


def test_recording_residual_arrows_are_scaled(full_recording):
    path, d = full_recording
    ch = _chunks(path)
    arrows = _column(ch, "/residuals/before/residual", "Arrows3D:vectors")
    vec = np.array(arrows["Arrows3D:vectors"][0])
    np.testing.assert_allclose(vec, (d["measured"] - d["model_before"]) * RESIDUAL_ARROW_SCALE, rtol=1e-5)
    np.testing.assert_allclose(np.array(arrows["Arrows3D:origins"][0]), d["model_before"], rtol=1e-6)
    norm0 = np.linalg.norm(d["measured"][0] - d["model_before"][0])
    assert arrows["Arrows3D:labels"][0][0].startswith(f"point 0: {norm0:.3f} mm")
    meas = _column(ch, "/residuals/after/measured", "Points3D:positions")
    assert len(meas["Points3D:positions"][0]) == 10


def test_recording_scalars(full_recording):
    path, d = full_recording
    ch = _chunks(path)
    rms = _column(ch, "/discover/rms_mm", "Scalars:scalars")
    rounds = {r: v[0] for rb in ch["/discover/rms_mm"] if "round" in rb
              for r, v in zip(rb["round"], rb["Scalars:scalars"])}
    assert rounds == {0: 0.9, 1: 0.4, 2: 0.12}
    assert "round" in rms
    texts = [t for rb in ch["/discover/added"] for row in rb["TextLog:text"] for t in row]
    assert any("added joint_compliance:2,3" in t for t in texts)
    lo = _column(ch, "/error_intervals/y/before/lower", "Scalars:scalars")
    assert lo["test_point"] == [1, 2, 3, 4, 5]
    np.testing.assert_allclose([v[0] for v in lo["Scalars:scalars"]], d["b_lo"][:, 1])
    band = _column(ch, "/error_intervals/z/allowed/upper", "Scalars:scalars")
    assert [v[0] for v in band["Scalars:scalars"]] == [1.0] * 5
    [doc] = _column(ch, "/summary", "TextDocument:text")["TextDocument:text"][0]
    assert doc.startswith("# Test run") and "| RMS after (mm) | 0.1235 |" in doc and "- a note" in doc


def test_log_into_plain_stream_and_torch_input(tmp_path):
    d = _data()
    path = tmp_path / "plain.rrd"
    stream = rr.RecordingStream("torchcal-test", recording_id="fixed")
    stream.save(path)
    log_workspace(stream, torch.as_tensor(d["pos"], dtype=torch.float32), torch.as_tensor(d["r_set"]),
                  torch.as_tensor(d["zones"]), max_points=25)
    log_discover_round(stream, 0, 1.5)
    stream.flush()
    stream.disconnect()
    ch = _chunks(path)
    assert len(_column(ch, "/workspace/rset", "Points3D:positions")["Points3D:positions"][0]) == 25
    assert _column(ch, "/discover/rms_mm", "Scalars:scalars")["Scalars:scalars"] == [[1.5]]
    assert "/discover/cv_rms_mm" not in {k for k, v in ch.items() if any("Scalars:scalars" in rb for rb in v)}


def test_writer_is_atomic_and_refuses_to_overwrite(tmp_path):
    path = tmp_path / "out.rrd"
    with pytest.raises(RuntimeError, match="boom"):
        with RecordingWriter(path) as rec:
            log_summary(rec, "# partial")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []  # neither the target nor a temporary file
    with RecordingWriter(path) as rec:
        log_summary(rec, "# first")
    with pytest.raises(InputError, match="output exists"):
        RecordingWriter(path).open()
    with RecordingWriter(path, force=True) as rec:
        log_summary(rec, "# second")
    assert _column(_chunks(path), "/summary", "TextDocument:text")["TextDocument:text"] == [["# second"]]
    assert [p.name for p in tmp_path.iterdir()] == ["out.rrd"]
    with pytest.raises(InputError, match="does not exist"):
        RecordingWriter(tmp_path / "missing" / "x.rrd").open()


def test_recording_id_is_deterministic():
    assert recording_id(3) == recording_id(3) != recording_id(4)
    assert recording_id(3, "other") != recording_id(3)


def test_recording_input_errors(tmp_path):
    d = _data()
    stream = rr.RecordingStream("torchcal-test")  # no sink: nothing is written
    with pytest.raises(InputError, match=r"positions_mm: expected shape \(N, 3\) in mm, got \(60, 2\)"):
        log_workspace(stream, d["pos"][:, :2], d["r_set"], d["zones"])
    with pytest.raises(InputError, match="r_set: expected 60 values"):
        log_workspace(stream, d["pos"], d["r_set"][:5], d["zones"])
    with pytest.raises(InputError, match="zones: expected non-negative integer"):
        log_workspace(stream, d["pos"], d["r_set"], d["zones"] - 0.5)
    with pytest.raises(InputError, match="stage: expected one of"):
        log_residuals(stream, "during", d["measured"], d["model_before"])
    with pytest.raises(InputError, match="model_mm: expected 10 rows"):
        log_residuals(stream, "before", d["measured"], d["model_before"][:3])
    with pytest.raises(InputError, match="before_lower_mm: lower bound above upper bound at test point 1, axis x"):
        log_error_intervals(stream, d["b_hi"], d["b_lo"])
    with pytest.raises(InputError, match="give both or neither"):
        log_error_intervals(stream, d["b_lo"], d["b_hi"], d["a_lo"])
    with pytest.raises(InputError, match="round_index: expected a non-negative integer"):
        log_discover_round(stream, -1, 0.3)
    with pytest.raises(InputError, match="rec: expected a rerun.RecordingStream"):
        log_summary("not a stream", "# x")
    with pytest.raises(InputError, match="sections: unknown"):
        default_blueprint({"workspace", "plots"})


def test_default_blueprint_only_logged_sections():
    assert default_blueprint({"summary"}) is not None
    assert default_blueprint(set()) is not None
    assert default_blueprint() is not None


# --------------------------------------------------------------------------- figures
def _png_size(path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def _visible_axes(fig) -> int:
    return len(fig.axes)  # unused grid cells are removed, so this counts the drawn subplots


@pytest.fixture(scope="module")
def figure_data():
    d = _data(n=120, zones=5, t=8)
    rng = np.random.default_rng(1)
    q = rng.uniform(-2.0, 2.0, (80, 6))
    res = np.c_[0.3 * np.sin(q[:, 1]), 0.1 * q[:, 2], 0.05 * rng.standard_normal(80)]
    return d, q, res


def test_zone_map(tmp_path, figure_data):
    d, _, _ = figure_data
    out = figures.zone_map(tmp_path / "zones.png", d["pos"], d["zones"])
    assert out == tmp_path / "zones.png"
    w, h = _png_size(out)
    assert (w, h) == (round(15.0 * figures.DPI), round(5.4 * figures.DPI))
    assert out.stat().st_size > 20_000
    assert _visible_axes(figures.zone_map_figure(d["pos"], d["zones"])) == 3


def test_zone_map_draws_given_centers(figure_data):
    d, _, _ = figure_data
    count = int(d["zones"].max()) + 1
    given = np.arange(3 * count, dtype=float).reshape(count, 3) * 100.0

    def drawn(fig):  # offsets of the x-y view's center markers (the last scatter)
        return np.asarray(fig.axes[0].collections[-1].get_offsets())

    new = drawn(figures.zone_map_figure(d["pos"], d["zones"], centers_mm=given))
    np.testing.assert_array_equal(new, given[:, :2])
    with pytest.raises(TypeError):  # one name, no former one
        figures.zone_map_figure(d["pos"], d["zones"], centres_mm=given)


def test_rset_histogram(tmp_path, figure_data):
    d, _, _ = figure_data
    out = figures.rset_histogram(tmp_path / "rset.png", d["r_set"])
    _png_size(out)
    assert out.stat().st_size > 10_000
    assert _visible_axes(figures.rset_histogram_figure(d["r_set"])) == 1
    assert _visible_axes(figures.rset_histogram_figure(np.ones(5))) == 1  # constant R_set


def test_error_intervals_figure(tmp_path, figure_data):
    d, _, _ = figure_data
    out = figures.error_intervals(tmp_path / "iv.png", torch.as_tensor(d["b_lo"]), d["b_hi"], d["a_lo"], d["a_hi"])
    _png_size(out)
    assert out.stat().st_size > 10_000
    fig = figures.error_intervals_figure(d["b_lo"], d["b_hi"])  # before only
    assert _visible_axes(fig) == 3
    assert [ax.get_ylabel() for ax in fig.axes] == ["x error (mm)", "y error (mm)", "z error (mm)"]


@pytest.mark.parametrize("n_joints", [6, 4])
def test_residual_vs_joints(tmp_path, figure_data, n_joints):
    _, q, res = figure_data
    if n_joints == 6:
        out = figures.residual_vs_joints(tmp_path / "rj.png", q, res)
        _png_size(out)
        assert out.stat().st_size > 10_000
    fig = figures.residual_vs_joints_figure(q[:, :n_joints], np.linalg.norm(res, axis=1))
    assert _visible_axes(fig) == n_joints
    assert fig.axes[1].get_xlabel() == "q2 (deg)"


def test_a_prismatic_joint_is_drawn_in_mm_and_variables_carry_their_units(figure_data):
    """A prismatic joint's values (mm) are drawn as given and labelled mm (before: times
    57.3 and labelled deg); temp_c, payload_kg, order and the approach signs carry their
    units; a held-out R2 that rounds to zero is written 0.00 (before: -0.00)."""
    _, q, res = figure_data
    q = q[:, :3].copy()
    q[:, 2] = np.linspace(100.0, 400.0, len(q))  # a slide, mm
    fig = figures.residual_vs_joints_figure(q, res, prismatic=[False, False, True])
    assert [ax.get_xlabel() for ax in fig.axes] == ["q1 (deg)", "q2 (deg)", "q3 (mm)"]
    x = fig.axes[2].collections[0].get_offsets()[:, 0]
    assert x.min() >= 100.0 and x.max() <= 400.0
    np.testing.assert_allclose(fig.axes[0].collections[0].get_offsets()[:, 0].max(), np.degrees(q[:, 0]).max())
    n = len(q)
    values = {"q1": q[:, 0], "q3": q[:, 2], "temp_c": np.linspace(20, 25, n), "payload_kg": np.linspace(0, 5, n),
              "order": np.arange(n, dtype=float), "approach_q1": np.sign(np.sin(np.arange(n)))}
    strengths = {"q1": 0.2, "q3": 0.1, "temp_c": -0.004, "payload_kg": -0.2, "order": 0.0, "approach_q1": 0.001}
    fig = figures.residual_vs_variables_figure(values, res, strengths, prismatic=["q3"])
    got = {ax.get_title(): ax.get_xlabel() for ax in fig.axes if ax.get_visible()}
    assert got == {"q1  R2 0.20": "q1 (deg)", "q3  R2 0.10": "q3 (mm)", "temp_c  R2 0.00": "temp_c (deg C)",
                   "order  R2 0.00": "order (row of the file)", "approach_q1  R2 0.00":
                   "approach_q1 (sign of the move: -1, 0, +1)", "payload_kg  R2 -0.20": "payload_kg (kg)"}
    q3 = [ax for ax in fig.axes if ax.get_title().startswith("q3")][0]
    assert q3.lines[0].get_xdata().max() <= 400.0


def test_figures_are_deterministic_and_not_overwritten(tmp_path, figure_data):
    d, _, _ = figure_data
    a = figures.rset_histogram(tmp_path / "a.png", d["r_set"])
    b = figures.rset_histogram(tmp_path / "b.png", d["r_set"])
    assert a.read_bytes() == b.read_bytes()
    with pytest.raises(InputError, match="output exists"):
        figures.rset_histogram(a, d["r_set"])
    figures.rset_histogram(a, d["r_set"][:50], force=True)
    assert a.read_bytes() != b.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "b.png"]  # no temporary files left


def test_figure_input_errors(figure_data):
    d, q, res = figure_data
    with pytest.raises(InputError, match=r"residual_mm: expected shape \(80,\) or \(80, 3\)"):
        figures.residual_vs_joints_figure(q, res[:10])
    with pytest.raises(InputError, match="joint_names: expected 6 names"):
        figures.residual_vs_joints_figure(q, res, joint_names=["a"])
    with pytest.raises(InputError, match="zones: expected 120 labels"):
        figures.zone_map_figure(d["pos"], d["zones"][:3])
    with pytest.raises(InputError, match="zone_names: expected at least 5 names"):
        figures.zone_map_figure(d["pos"], d["zones"], zone_names=["a", "b"])
    with pytest.raises(InputError, match="bins: expected a positive integer"):
        figures.rset_histogram_figure(d["r_set"], bins=0)
    with pytest.raises(InputError, match="allowed_mm: expected a positive number"):
        figures.error_intervals_figure(d["b_lo"], d["b_hi"], allowed_mm=-1.0)


def test_a_bin_of_too_few_rows_draws_no_rms_point():
    """One row alone in a joint-angle bin (UR10 series C: q2 near -95 deg) is no RMS: the
    line has no point there (before: a point at that row's residual, 1 mm above the rest)."""
    rng = np.random.default_rng(4)
    q = rng.uniform(-1.0, 0.0, (120, 2))
    q[0, 1] = np.radians(-95.0)  # alone below the others' range (-57..0 deg) of q2
    res = rng.normal(0.0, 0.05, 120)
    res[0] = 1.0
    fig = figures.residual_vs_joints_figure(q, res, bins=12)
    line = fig.axes[1].get_lines()[0]
    y = np.asarray(line.get_ydata(), dtype=float)
    assert np.nanmax(y) < 0.3, y
    assert np.isfinite(y).sum() >= 6  # the filled bins keep their points
    x = np.asarray(line.get_xdata(), dtype=float)
    assert not np.isfinite(y[x < -80]).any()


# --------------------------------------------------------------------------- fixed layout
def _texts_clear(fig):
    """Draw `fig`; assert each visible axes with its tick labels, axis labels and title
    lies inside the figure and clear of every other one, and the suptitle and legends
    clear of them all (the multi-panel figures place their axes by fixed margins, no
    layout engine that would make room for a wide label)."""
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    page = fig.bbox
    boxes = [ax.get_tightbbox(r) for ax in fig.axes if ax.get_visible()]
    for b in boxes:
        assert b.x0 >= page.x0 - 1 and b.y0 >= page.y0 - 1 and b.x1 <= page.x1 + 1 and b.y1 <= page.y1 + 1, b
    others = [fig._suptitle.get_window_extent(r)] + [lg.get_window_extent(r) for lg in fig.legends]
    for i, a in enumerate(boxes):
        for b in boxes[i + 1:] + others:
            cut = a.intersection(a, b)
            assert cut is None or cut.width < 1 or cut.height < 1, (a, b)


@pytest.mark.parametrize("scale_mm", [1.0, 1e-3, 30.0])
def test_twenty_variable_panels_keep_their_labels_clear(scale_mm):
    """The report's 20-panel figure: every panel drawn with its title, x and y label, no
    tick label or axis label running into the next panel or out of the page, for small,
    wide-labelled and large residuals."""
    rng = np.random.default_rng(5)
    n = 90
    names = ([f"q{j}" for j in range(1, 7)] + [f"approach_q{j}" for j in range(1, 7)]
             + [f"approach_prev_q{j}" for j in range(1, 6)] + ["temp_c", "payload_kg", "order"])
    values = {k: rng.choice([-1.0, 0.0, 1.0], n) if k.startswith("approach") else rng.uniform(-2.5, 2.5, n)
              for k in names}
    values.update(temp_c=rng.uniform(19.0, 31.0, n), payload_kg=rng.uniform(0.0, 5.0, n),
                  order=np.arange(n, dtype=float))
    res = scale_mm * rng.normal(0.0, 1.0, (n, 3)) - 2.5 * scale_mm
    strengths = {k: float(v) for k, v in zip(names, rng.uniform(-0.05, 0.4, len(names)))}
    comps = {k: scale_mm * rng.normal(0.0, 1.0, n) for k in names[::2]}
    fig = figures.residual_vs_variables_figure(values, res, strengths, correlates=("q2", "order"), components=comps)
    shown = [ax for ax in fig.axes if ax.get_visible()]
    assert len(shown) == 20
    assert all(ax.get_title() and ax.get_xlabel() and ax.get_ylabel() for ax in shown)
    _texts_clear(fig)


@pytest.mark.parametrize("n_joints", [1, 4, 6, 7])
def test_joint_panels_and_legend_keep_their_labels_clear(figure_data, n_joints):
    _, q, res = figure_data
    q = np.tile(q, (1, 2))[:, :n_joints]
    fig = figures.residual_vs_joints_figure(q, res * 40.0)  # tick labels like -10.0
    assert _visible_axes(fig) == n_joints and len(fig.legends) == 1
    _texts_clear(fig)


@pytest.mark.parametrize("box_mm", [(200.0, 1400.0), (-1300.0, 1800.0), (0.0, 5.0)])
def test_error_map_views_keep_their_labels_clear(box_mm):
    """The error map's fixed places: 3-D view, x-y and x-z views, colour scale and title
    apart, for a UR-sized workspace (tick labels like -1250), a small one, one near 0."""
    lo, hi = box_mm
    rng = np.random.default_rng(2)
    pos = rng.uniform(lo, hi, (300, 3))
    fig = figures.error_map_figure(pos, rng.uniform(0.0, 0.3, 300))
    assert [ax.get_title() for ax in fig.axes[:3]] == ["3-D", "x-y (top)", "x-z (side)"]
    assert fig.axes[3].get_ylabel().startswith("distance error (mm")
    _texts_clear(fig)
