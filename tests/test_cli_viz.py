"""--rrd/--plots of `torchcal diagnose` and `torchcal discover`: recordings read back with
rerun.chunk.RrdReader, PNGs checked on disk, existing outputs refused without --force."""

from __future__ import annotations

import argparse
import os

import numpy as np
import pytest
import torch
from rerun.chunk import RrdReader

import torchcal
import torchcal.io.measurement_csv  # the fixture below uses it; nothing else imports it when this file runs alone
import torchcal.io.files
import torchcal.simulation.virtual_robot
from torchcal.cli import main
from torchcal.cli._viz import PLOTS, check_outputs
from torchcal.errors import InputError

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    robot = torchcal.robot("kr1000titan")
    vr = torchcal.simulation.virtual_robot.VirtualRobot(robot, ["backlash:3"], seed=1)
    m = vr.measure(torchcal.simulation.virtual_robot.random_poses(robot, 80, torch.Generator().manual_seed(2)), noise_mm=0.02)
    path = tmp_path_factory.mktemp("cli_viz") / "data.csv"
    torchcal.io.measurement_csv.write_measurements(path, m)
    return path, torchcal.io.measurement_csv.read_measurements(path, robot=robot)


def _entities(path) -> set[str]:
    return {line.split()[0] for line in RrdReader(path).store().summary().splitlines()}


def _column(path, entity: str, column: str) -> list:
    """All values of `column` at `entity`, over the chunks (temporal rows in order)."""
    out = []
    for ch in RrdReader(path).stream():
        if ch.entity_path == entity:
            rb = ch.to_record_batch().to_pydict()
            if column in rb:
                out += rb[column]
    assert out, f"{entity}:{column} not found"
    return out


def _png_ok(path) -> None:
    assert path.is_file() and path.stat().st_size > 10_000
    assert path.read_bytes()[:8] == PNG_MAGIC


def _variable_scatters(path, m) -> list[tuple[str, float, bool]]:
    """The recording's residual-against-variable scatters: one per variable of
    `unexplained.variables` (the same set as the PNG), ranks 01.. by strength descending
    (read from the ``variables`` table), each with one point per row of m."""
    from torchcal.diagnosis.unexplained import variables

    names = set(variables(torchcal.robot("kr1000titan"), m))
    [text] = _column(path, "/variables", "TextDocument:text")[0]
    rows = [r.strip("|").split("|") for r in text.splitlines() if r.startswith("| ") and r[2].isdigit()]
    table = [(int(k), v.strip(), float(s), sig.strip() == "yes", e.strip()) for k, v, s, sig, e in rows]
    assert [k for k, *_ in table] == list(range(1, len(names) + 1))
    assert {v for _, v, *_ in table} == names
    strengths = [s for _, _, s, *_ in table]
    assert strengths == sorted(strengths, reverse=True)
    ents = _entities(path)
    for k, v, _, sig, e in table:
        assert e == f"variables/{k:02d}_{v}" + ("_significant" if sig else "")
        assert {f"/{e}/points", f"/{e}/frame", f"/{e}/axes"} <= ents
        assert len(_column(path, f"/{e}/points", "Points2D:positions")[0]) == len(m)
    return [(v, s, sig) for _, v, s, sig, _ in table]


def test_diagnose_rrd_and_plots(data, tmp_path, capsys):
    csv, m = data
    rrd, plots = tmp_path / "diag.rrd", tmp_path / "plots" / "diag"  # nested folder: created
    assert main(["diagnose", str(csv), "--robot", "kr1000titan", "--rrd", str(rrd), "--plots", str(plots)]) == 0
    assert f"wrote {rrd}" in capsys.readouterr().out
    ents = _entities(rrd)
    assert {"/residuals/before/measured", "/residuals/before/model", "/residuals/before/residual",
            "/summary"} <= ents
    assert not any(e.startswith("/residuals/after") for e in ents)
    measured = np.array(_column(rrd, "/residuals/before/measured", "Points3D:positions")[0])
    np.testing.assert_allclose(measured, m.xyz.numpy(), atol=1e-3)  # float32 in the file
    model = np.array(_column(rrd, "/residuals/before/model", "Points3D:positions")[0])
    rms = float(np.sqrt(np.mean(np.sum((measured - model) ** 2, axis=1))))
    assert 0.1 < rms < 1.0  # backlash left unmodelled: ~0.25 mm
    [text] = _column(rrd, "/summary", "TextDocument:text")[0]
    assert "torchcal diagnose" in text and "missing backlash:3" in text
    assert os.stat(rrd).st_mode & 0o777 == 0o666 & ~_umask()
    _variable_scatters(rrd, m)
    _png_ok(plots / "residual_vs_joints.png")
    _png_ok(plots / "residual_vs_variables.png")


def test_discover_rrd_and_plots(data, tmp_path):
    csv, m = data
    rrd, plots = tmp_path / "disc.rrd", tmp_path / "plots"
    assert main(["discover", str(csv), "--robot", "kr1000titan", "--rrd", str(rrd), "--plots", str(plots)]) == 0
    ents = _entities(rrd)
    assert {"/discover/rms_mm", "/discover/cv_rms_mm", "/discover/added", "/summary"} <= ents
    assert {f"/residuals/{s}/{k}" for s in ("before", "after") for k in ("measured", "model", "residual")} <= ents
    rounds = _column(rrd, "/discover/rms_mm", "round")
    rms = [v[0] for v in _column(rrd, "/discover/rms_mm", "Scalars:scalars")]
    assert rounds == [0, 1] and rms[0] > 0.2 and rms[1] < 0.06  # backlash found in round 1
    added = [t[0] for t in _column(rrd, "/discover/added", "TextLog:text")]
    assert "added backlash:3" in added[1]
    [text] = _column(rrd, "/summary", "TextDocument:text")[0]
    assert "final effects | backlash:3" in text
    scatters = _variable_scatters(rrd, m)
    assert not any(sig for *_, sig in scatters)  # backlash found: nothing significant is left
    for name in PLOTS["discover"]:
        _png_ok(plots / name)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def test_existing_outputs_refused_without_force(tmp_path):
    rrd, plots = tmp_path / "x.rrd", tmp_path / "plots"
    args = argparse.Namespace(rrd=str(rrd), plots=str(plots), force=False, data=None)
    assert check_outputs(args, "discover") == (rrd, [plots / n for n in PLOTS["discover"]])
    assert plots.is_dir()  # created
    (plots / PLOTS["discover"][1]).write_bytes(b"old")
    with pytest.raises(InputError, match="output exists; pass --force"):
        check_outputs(args, "discover")
    args.force = True
    check_outputs(args, "discover")
    rrd.write_bytes(b"old")
    args.force = False
    args.plots = None
    with pytest.raises(InputError, match="x.rrd: output exists"):
        check_outputs(args, "diagnose")
    # --plots naming a file, an output over the input, a missing .rrd folder
    with pytest.raises(InputError, match="expects a folder"):
        check_outputs(argparse.Namespace(rrd=None, plots=str(rrd), force=True), "diagnose")
    with pytest.raises(InputError, match="names the input file .*refusing to write over it"):
        check_outputs(argparse.Namespace(rrd=str(rrd), plots=None, force=True, data=str(rrd)), "diagnose")
    with pytest.raises(InputError, match="does not exist"):
        check_outputs(argparse.Namespace(rrd=str(tmp_path / "no" / "x.rrd"), plots=None, force=False), "diagnose")


def test_cli_refusal_is_one_line(data, tmp_path, capsys):
    csv, _ = data
    rrd = tmp_path / "taken.rrd"
    rrd.write_bytes(b"old")
    code = main(["diagnose", str(csv), "--robot", "kr1000titan", "--rrd", str(rrd), "--folds", "2"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "output exists; pass --force" in err
    assert rrd.read_bytes() == b"old"


def _fake_demo_result(seed: int = 0, n: int = 60, zones: int = 4, t: int = 6):
    """The fields of a torchcal.workflows.paper_experiment.PipelineResult that demo_outputs reads (small, fast)."""
    from types import SimpleNamespace as NS

    g = torch.Generator().manual_seed(seed)
    pos = torch.rand(n, 3, generator=g, dtype=torch.float64) * 3000.0
    labels = torch.arange(n) % zones + 1  # 1..Z as Partition.labels
    r_set = (1.0 - 0.05 * (labels - 1)).to(torch.float64)
    lo = -torch.rand(t, 3, generator=g, dtype=torch.float64) - 0.5

    def ev(scale):
        return NS(lower=scale * lo, upper=scale * (lo + 0.3), rms_mm=float(scale),
                  max_abs_mm=float(scale * lo.abs().max()))

    return NS(config=NS(robot="kr1000titan", seed=seed, allowed_axis_mm=1.0),
              sweep=NS(positions=pos, r_set=r_set), partition=NS(labels=labels),
              before=ev(2.0), after={"partitioned": ev(0.2)}, format_report=lambda: "TABLE 5\n...")


def test_demo_outputs(tmp_path):
    from torchcal.cli._viz import demo_outputs

    res = _fake_demo_result()
    rrd, plots = tmp_path / "demo.rrd", tmp_path / "plots"
    args = argparse.Namespace(rrd=str(rrd), plots=str(plots), force=False, seed=0)
    demo_outputs(args, res)
    ents = _entities(rrd)
    assert {"/workspace", "/workspace/rset", "/workspace/zones", "/workspace/centres", "/summary"} <= ents
    assert {f"/error_intervals/{a}/{s}/{b}" for a in "xyz" for s in ("before", "after", "allowed")
            for b in ("lower", "upper")} <= ents
    class_ids = _column(rrd, "/workspace/zones", "Points3D:class_ids")[0]
    np.testing.assert_array_equal(class_ids, (res.partition.labels - 1).numpy())  # 0-based in the file
    before_lo = [v[0] for v in _column(rrd, "/error_intervals/x/before/lower", "Scalars:scalars")]
    np.testing.assert_allclose(before_lo, res.before.lower[:, 0].numpy())
    [text] = _column(rrd, "/summary", "TextDocument:text")[0]
    assert "torchcal demo" in text and "TABLE 5" in text
    for name in PLOTS["demo"]:
        _png_ok(plots / name)
    with pytest.raises(InputError, match="output exists"):
        demo_outputs(args, res)


def test_demo_error_intervals_show_the_best_method_beside_the_papers(tmp_path, monkeypatch):
    """The best method (lowest mean test RMS) is drawn and recorded next to the paper's
    per-zone one; when the paper's is the best, it alone."""
    from types import SimpleNamespace as NS

    import torchcal.cli._report
    from torchcal.cli._viz import demo_outputs
    from viz.figures import error_intervals_figure

    monkeypatch.setattr(torchcal.cli._report, "format_report", lambda run: "REPORT")
    res = _fake_demo_result()
    paper, glob, worse = (res.after["partitioned"], NS(**{**vars(res.after["partitioned"])}), res.before)
    glob.lower, glob.upper, glob.rms_mm = 0.5 * paper.lower, 0.5 * paper.upper, 0.1
    runs = [NS(**{**vars(res), "after": {"paper_partitioned": paper, "global_geometric": glob,
                                          "discovered_global": worse}})]
    run = NS(runs=runs, first=runs[0], config=res.config, format_report=res.format_report)
    rrd = tmp_path / "demo.rrd"
    demo_outputs(argparse.Namespace(rrd=str(rrd), plots=None, force=False, seed=0), run)
    lo = [v[0] for v in _column(rrd, "/error_intervals/y/best_global_geometric/lower", "Scalars:scalars")]
    np.testing.assert_allclose(lo, glob.lower[:, 1].numpy())
    fig = error_intervals_figure(res.before.lower, res.before.upper, paper.lower, paper.upper,
                                 after_name="after, paper", also=[("after, global (best)", glob.lower, glob.upper)])
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert labels[-3:] == ["before", "after, paper", "after, global (best)"]
    glob.rms_mm = 0.3  # the paper's method is now the best: nothing beside it
    rrd2 = tmp_path / "demo2.rrd"
    demo_outputs(argparse.Namespace(rrd=str(rrd2), plots=None, force=False, seed=0), run)
    assert not any("best_" in e for e in _entities(rrd2))
