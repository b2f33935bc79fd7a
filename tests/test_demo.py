"""`torchcal demo` (torchcal.workflows.paper) and the `calibrate` / `compensate` commands.

The pipeline runs once per module (fixture). Its JSON must carry the fields of issue 6 and
meet the targets: every reduction at least the paper's, every test point within +-1 mm
per axis with R_set = 1 after partitioned compensation.
"""

import json
import math

import pytest
import torch

from torchcal import cli
from torchcal.workflows.paper import PAPER_REDUCTION_PERCENT, DemoConfig, reduction_percent, run_pipeline

AXES = ("x", "y", "z")


@pytest.fixture(scope="module")
def result():
    return run_pipeline(DemoConfig(seed=0))


@pytest.fixture(scope="module")
def doc(result):
    d = result.to_json()
    json.dumps(d, allow_nan=False)  # what --json writes
    return d


def _interval(v):
    return isinstance(v, list) and len(v) == 2 and all(isinstance(x, float) for x in v) and v[0] <= v[1]


def test_json_has_the_issue_fields(doc):
    assert doc["zones"] == 10 and isinstance(doc["seconds"], float)
    for ax in AXES:
        assert set(doc["reduction_percent"][ax]) == {"lower", "upper"}
        assert set(doc["global"]["reduction_percent"][ax]) == {"lower", "upper"}
    assert isinstance(doc["partitioned"]["test_rms_mm"], float)
    assert isinstance(doc["global"]["test_rms_mm"], float)
    pts = doc["test_points"]
    assert len(pts) == 20
    for p in pts:
        assert 1 <= p["zone"] <= 10
        for key in ("error_before_mm", "error_after_mm"):
            assert set(p[key]) == set(AXES) and all(_interval(p[key][ax]) for ax in AXES)
        assert set(p["r_set_after"]) == {"x", "y", "z", "distance"}
        assert all(0.0 <= p["r_set_after"][k] <= 1.0 for k in p["r_set_after"])
    # 2 test points per zone, assigned before measuring
    assert sorted(p["zone"] for p in pts) == [z for z in range(1, 11) for _ in range(2)]


def test_targets_met(doc):
    red = doc["reduction_percent"]
    for ax in AXES:
        for b in ("lower", "upper"):
            assert red[ax][b] >= PAPER_REDUCTION_PERCENT[ax][b], (ax, b, red[ax][b])
    for p in doc["test_points"]:
        for ax in AXES:
            lo, hi = p["error_after_mm"][ax]
            assert -1.0 <= lo and hi <= 1.0, (p["zone"], ax, lo, hi)
        assert all(v == 1.0 for v in p["r_set_after"].values())
    assert doc["targets_met"]["all"]
    # compensation helped a lot, and the uncompensated errors are a few mm
    assert doc["before"]["test_rms_mm"] > 2.0
    assert doc["partitioned"]["test_rms_mm"] < 0.2 * doc["before"]["test_rms_mm"]


def test_paper_pipeline_shape(result, doc):
    cfg = result.config
    assert doc["levels"] == 4
    assert [int((result.partition.zone_level == lev).sum()) for lev in (1, 2, 3, 4)] == list(cfg.zones_per_level)
    assert len(result.sweep) == 100 and 0.5 < float(result.sweep.r_set.min()) and float(result.sweep.r_set.max()) == 1.0
    # one interval parameter set per zone, intervals around their centres
    for fits in (result.fits["partitioned"], result.fits["partitioned_geometric"]):
        assert len(fits) == 10
        for f in fits:
            assert (f.radius >= 0).all() and f.converged
    assert doc["seconds"] < 60


def test_partitioned_vs_global_is_reported(doc):
    p, g = doc["partitioned"]["test_rms_mm"], doc["global"]["test_rms_mm"]
    assert doc["partitioned_beats_global"] == (p < g)
    assert set(doc["variants"]) == {"partitioned", "global", "partitioned_geometric", "global_geometric"}


def test_reduction_formula():
    before_lo = torch.tensor([[-2.0, 1.0, -4.0], [-4.0, 3.0, -2.0]], dtype=torch.float64)
    before_hi = before_lo + 1
    after_lo = torch.tensor([[-0.5, -0.1, -0.3], [-0.5, 0.1, -0.3]], dtype=torch.float64)
    after_hi = after_lo + 0.4
    red = reduction_percent(before_lo, before_hi, after_lo, after_hi)
    assert math.isclose(red["x"]["lower"], 100 * (1 - 0.5 / 3.0))
    assert math.isclose(red["y"]["lower"], 100.0)  # after mean 0
    assert math.isclose(red["z"]["upper"], 100 * (1 - 0.1 / 2.0))


def test_demo_command_writes_json(tmp_path, monkeypatch, result, capsys):
    import torchcal.workflows.paper as P

    monkeypatch.setattr(P, "run_pipeline", lambda cfg, progress=None: result)
    out = tmp_path / "demo.json"
    assert cli.main(["demo", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "Table 3" in printed and "Table 4" in printed and "Table 5" in printed and "global" in printed
    d = json.loads(out.read_text())
    assert d["zones"] == 10 and len(d["test_points"]) == 20
    assert cli.main(["demo", "--json", str(out)]) == 2  # exists, no --force: refused before any work
    assert "output exists" in capsys.readouterr().err


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A small simulated session with repeats, a partition and targets."""
    from torchcal.io.measurement_csv import write_measurements
    from torchcal.partition.zones import partition_workspace
    from torchcal.robots.robot import robot
    from torchcal.simulation.virtual_robot import VirtualRobot
    from torchcal.reliability.sweep import sample_workspace, sweep

    d = tmp_path_factory.mktemp("session")
    r = robot("kr1000titan")
    vr = VirtualRobot(r, ["base_frame"], seed=4)
    q = sample_workspace(r, 40, seed=5)
    write_measurements(d / "data.csv", vr.measure(q, repeats=3, noise_mm=0.01))
    sw = sweep(r, sample_workspace(r, 60, seed=6), n_samples=100)
    partition_workspace(sw.positions, sw.r_set, levels=2, zones=[1, 1], seed=0).save(d / "part.json")
    qt = sample_workspace(r, 6, seed=7)
    t = r.fk(qt)
    rows = [",".join(map(repr, list(a) + list(b))) for a, b in zip(t.tolist(), torch.rad2deg(qt).tolist())]
    (d / "targets.csv").write_text("x,y,z," + ",".join(f"q{k}" for k in range(1, 7)) + "\n" + "\n".join(rows) + "\n")
    return d, vr, qt, t


def test_calibrate_and_compensate_commands(session, capsys):
    from torchcal.effects import make_context

    d, vr, qt, t = session
    for extra, name in (([], "global.json"), (["--partition", str(d / "part.json")], "zones.json")):
        assert cli.main(["calibrate", str(d / "data.csv"), "--robot", "kr1000titan", "--effects", "base_frame",
                         *extra, "--out", str(d / name)]) == 0
        m = json.loads((d / name).read_text())
        assert m["format"] == "torchcal-interval-model/1"
        assert len(m["zones"]) == (1 if not extra else 2)
        assert all(lo <= hi for z in m["zones"] for lo, hi in zip(z["lower"], z["upper"]))
        out = d / f"q_{name}.csv"
        assert cli.main(["compensate", str(d / "targets.csv"), "--model", str(d / name), "--out", str(out)]) == 0
        lines = out.read_text().splitlines()
        assert lines[0] == "point,zone,q1,q2,q3,q4,q5,q6,residual_mm,converged"
        q = torch.deg2rad(torch.tensor([[float(v) for v in ln.split(",")[2:8]] for ln in lines[1:]],
                                       dtype=torch.float64))
        assert all(ln.endswith("true") for ln in lines[1:])
        # the true (noise-free) robot at the corrected commands: close to the targets
        true = vr.model.predict(vr.theta, make_context(vr.robot, q))
        before = vr.model.predict(vr.theta, make_context(vr.robot, qt))
        assert (true - t).norm(dim=-1).max() < 0.1 < (before - t).norm(dim=-1).min()
    capsys.readouterr()


def test_command_errors(session, capsys):
    d, *_ = session
    bad = d / "bad_targets.csv"
    bad.write_text("x,y\n1,2\n")
    assert cli.main(["compensate", str(bad), "--model", str(d / "global.json"), "--out", str(d / "o.csv")]) == 2
    assert "header has no column 'z'" in capsys.readouterr().err
    bad.write_text("x,y,z\n1,2,abc\n")
    assert cli.main(["compensate", str(bad), "--model", str(d / "global.json"), "--out", str(d / "o.csv")]) == 2
    assert "line 2, column z: expected a number (mm)" in capsys.readouterr().err
    assert cli.main(["calibrate", str(d / "data.csv"), "--robot", "kr1000titan", "--out",
                     str(d / "data.csv"), "--force"]) == 2
    assert "refusing to write over it" in capsys.readouterr().err
