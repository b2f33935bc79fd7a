"""`torchcal evaluate --residuals/--plots/--rrd`: per-row held-out errors in a CSV, and the
figures and recording of where the model fails on held-out rows (diagnose's figure code)."""

import csv
import json

import numpy as np
import pytest

from torchcal.cli import main
from torchcal.cli._viz import PLOTS

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """Training rows with q1 < 0 of a virtual UR5e with backlash on joint 3 (left out of
    the fitted model), a geometric fit on them, and fresh poses of the same robot."""
    d = tmp_path_factory.mktemp("evaluate")
    common = ["--robot", "ur5e", "--effects", "backlash:3", "--noise", "0.01", "--seed", "5"]
    assert main(["simulate", *common, "--n", "160", "--out", str(d / "all.csv")]) == 0
    assert main(["simulate", *common, "--n", "120", "--pose-seed", "6", "--out", str(d / "test.csv")]) == 0
    lines = (d / "all.csv").read_text().splitlines()
    train = [lines[0]] + [ln for ln in lines[1:] if float(ln.split(",")[1]) < 0]
    (d / "train.csv").write_text("\n".join(train) + "\n")
    assert main(["fit", str(d / "train.csv"), "--robot", "ur5e", "--out", str(d / "m.json")]) == 0
    return d


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_residuals_csv_one_row_per_measurement(session, tmp_path, capsys):
    import torchcal
    from torchcal.effects import context_of
    from torchcal.io.measurement_csv import read_measurements
    from torchcal.io.modelfile import load

    data, out, rep = session / "test.csv", tmp_path / "res.csv", tmp_path / "rep.json"
    assert main(["evaluate", str(data), "--model", str(session / "m.json"), "--residuals", str(out),
                 "--json", str(rep)]) == 0
    rows, doc = _rows(out), json.loads(rep.read_text())
    assert list(rows[0]) == ["row", "pose", "ex_mm", "ey_mm", "ez_mm", "e_mm", "outside_range"]  # no rx: no orientation
    m = read_measurements(data, robot=torchcal.robot("ur5e"))
    fitted = load(session / "m.json")
    model, theta = fitted.model, fitted.theta
    expected = (m.xyz - model.predict(theta, context_of(model.robot, m))).numpy()
    e = np.array([[float(r[k]) for k in ("ex_mm", "ey_mm", "ez_mm")] for r in rows])
    np.testing.assert_allclose(e, expected, atol=1e-9)
    np.testing.assert_allclose([float(r["e_mm"]) for r in rows], np.linalg.norm(expected, axis=1), atol=1e-9)
    assert [int(r["pose"]) for r in rows] == m.pose.tolist() and [int(r["row"]) for r in rows] == list(
        range(1, len(m) + 1))
    # the pooled RMS from the rows is the report's
    assert np.sqrt(np.mean(np.sum(e ** 2, axis=1))) == pytest.approx(doc["rms_mm"], rel=1e-12)
    # trained on q1 < 0: rows beyond the training rows' joint range by 10 deg are flagged,
    # rows inside it never
    tr = np.array([[float(r[f"q{j}"]) for j in range(1, 7)] for r in _rows(session / "train.csv")])
    q = m.q_deg.numpy()
    beyond = np.maximum(tr.min(0) - q, q - tr.max(0)).max(1)  # deg, < 0 inside on every joint
    flag = np.array([r["outside_range"] == "true" for r in rows])
    assert (beyond > 10).sum() > 20 and (beyond < 0).sum() > 20
    assert flag[beyond > 10].all() and not flag[beyond < 0].any() and flag.sum() == doc["outside_range"]
    assert f"wrote {out}" in capsys.readouterr().out


def _entities(path) -> set[str]:
    from rerun.chunk import RrdReader
    return {line.split()[0] for line in RrdReader(path).store().summary().splitlines()}


def test_plots_and_recording_show_where_held_out_rows_fail(session, tmp_path, capsys):
    from rerun.chunk import RrdReader
    data, rrd, plots = session / "test.csv", tmp_path / "e.rrd", tmp_path / "plots"
    assert main(["evaluate", str(data), "--model", str(session / "m.json"), "--rrd", str(rrd),
                 "--plots", str(plots)]) == 0
    for name in PLOTS["evaluate"]:
        p = plots / name
        assert p.read_bytes()[:8] == PNG_MAGIC and p.stat().st_size > 10_000
    ents = _entities(rrd)
    assert {"/error_map/points", "/residuals/after/residual", "/summary", "/variables"} <= ents
    e = []
    for ch in RrdReader(rrd).stream():
        if ch.entity_path == "/error_map/error_mm":
            e += ch.to_record_batch().to_pydict()["error_mm"]
    assert len(e[0]) == 120
    # the unmodelled backlash of joint 3 shows on the held-out rows: its approach direction
    # is the strongest, significant dependence
    text = [ch.to_record_batch().to_pydict() for ch in RrdReader(rrd).stream() if ch.entity_path == "/variables"]
    table = text[0]["TextDocument:text"][0][0]
    first = next(r for r in table.splitlines() if r.startswith("| 1 "))
    assert "approach_q3" in first and "yes" in first
    capsys.readouterr()
    # an existing PNG: refused before any work, nothing written
    rrd2 = tmp_path / "e2.rrd"
    assert main(["evaluate", str(data), "--model", str(session / "m.json"), "--rrd", str(rrd2),
                 "--plots", str(plots)]) == 2
    assert "output exists" in capsys.readouterr().err and not rrd2.exists()
