"""`torchcal demo` (torchcal.workflows.paper_experiment) and the `calibrate` / `compensate` commands.

The demo's tests assert properties every honest run must have, on a small configuration
over two seeds (no figures of the paper, no wall-clock): the multi-seed JSON keys, fresh
test moves and disjoint poses, the reduction formula against a hand computation, the
confidence intervals and the paired test against numpy/scipy, and checked compensation.
"""

import json
import math

import numpy as np
import pytest
import scipy.stats
import torch

from torchcal import cli
from torchcal.statistics import mean_ci, paired_comparison
from torchcal.workflows.paper_config import MAIN_METHODS, METHODS, DemoConfig
from torchcal.workflows.paper_experiment import run_demo
from torchcal.workflows.paper_report import reduction_percent

AXES = ("x", "y", "z")
SMALL = DemoConfig(n_sweep=40, sweep_samples=40, zones_per_level=(2, 2), points_per_zone=10,
                   points_per_zone_more=12, test_per_zone=2, repeats=3, discover_rounds=0)


PROGRESS = []  # (message, share of the work done) as the `run` fixture reported them


@pytest.fixture(scope="module")
def run():
    return run_demo(SMALL, seeds=2, progress=lambda msg, done: PROGRESS.append((msg, done)))


def test_progress_reports_the_work_done_not_the_steps_started(run):
    """Each step start reports the shares of the steps before it (discovery's big share
    counted only once it is done); 100 % only when the last seed has finished."""
    from torchcal.workflows.paper_experiment import step_shares

    share = step_shares(SMALL)
    steps = ["sweep", "partition", "calibrate", "discover", "test", "done"]
    expected, done = [], 0.0
    for k in range(2):
        for st in steps:
            expected.append((f"seed {k + 1}/2: {st}", (k + (1.0 if st == "done" else done)) / 2))
            done += share.get(st, 0.0)
        done = 0.0
    assert [m for m, _ in PROGRESS] == [m for m, _ in expected]
    np.testing.assert_allclose([d for _, d in PROGRESS], [d for _, d in expected], atol=1e-12)
    assert math.isclose(sum(share.values()), 1.0) and [d for _, d in PROGRESS].index(1.0) == len(PROGRESS) - 1
    full = step_shares(DemoConfig())  # with discovery, the bar is at 16 % when it starts, not 60 %
    assert full["sweep"] + full["partition"] + full["calibrate"] < 0.2 and full["discover"] > 0.7


@pytest.fixture(scope="module")
def doc(run):
    d = run.to_json()
    json.dumps(d, allow_nan=False)  # what --json writes
    return d


def _ci(v):
    return isinstance(v, list) and len(v) == 2 and all(isinstance(x, float) for x in v) and v[0] <= v[1]


def test_json_has_the_issue_fields(doc):
    assert doc["seeds"] == 2 and doc["seed_values"] == [0, 1]
    assert set(MAIN_METHODS) <= set(doc["methods"])
    for name, m in doc["methods"].items():
        assert isinstance(m["fitted_effects"], list) and "base_frame" in m["fitted_effects"]
        assert isinstance(m["test_rms_mm"]["mean"], float) and _ci(m["test_rms_mm"]["ci95"])
        for ax in AXES:
            assert set(m["reduction_percent"][ax]) == {"lower", "upper"}
            assert all(_ci(m["reduction_percent"][ax][b]["ci95"]) for b in ("lower", "upper"))
    pvg = doc["partitioned_vs_global"]
    assert set(pvg) >= {"diff_mm", "ci95", "p", "significant"} and 0.0 <= pvg["p"] <= 1.0 and _ci(pvg["ci95"])
    # existing keys stay
    for key in ("zones", "seconds", "reduction_percent", "test_points", "partitioned", "global", "variants",
                "partitioned_beats_global", "targets_met", "config"):
        assert key in doc
    # (2, 2) on 40 sweep points: level 2 holds 3, too few for 2 zones (2 points each on average): clipped to 1
    assert doc["zones"] == 3 and len(doc["test_points"]) == 6
    assert doc["partitioned_beats_global"] == (pvg["significant"] and pvg["diff_mm"] < 0)


def test_truth_has_errors_outside_every_geometric_model(run, doc):
    truth = doc["truth_effects"]
    assert {s.split(":")[0] for s in truth} >= {"base_frame", "joint_compliance", "gear_periodic", "joint_clearance"}
    assert doc["config"]["clearance_random"] == 0.5  # the simulator's default share
    fitted = set(run.first.models["paper_partitioned"].specs())
    assert fitted == {"base_frame"} and not {s for s in truth if not s.startswith("base_frame")} & fitted


def test_fresh_test_moves_and_disjoint_poses(run):
    for res in run.runs:
        cal = torch.cat([res.cal_q["paper"], res.cal_q["more"]])
        # no calibration pose is used twice, no test pose is a calibration pose
        assert torch.cdist(res.cal_q["paper"], res.cal_q["paper"]).fill_diagonal_(1.0).min() > 1e-9
        assert torch.cdist(res.test_q, cal).min() > 1e-9
        # each test point sits in the zone it is compensated with
        r = res.models["global_geometric"].robot
        assert torch.equal(res.partition.assign(r.fk(res.test_q)) - 1, res.test_zone)
        # the poses per zone are the configured numbers
        assert [int(n) for n in torch.bincount(res.test_zone)] == [SMALL.test_per_zone] * res.n_zones
        for f in res.fits["paper_partitioned"]:
            assert f.residuals.shape[0] == SMALL.points_per_zone
        assert res.fits["global_geometric"][0].residuals.shape[0] == SMALL.points_per_zone * res.n_zones
    # different seeds, different robots and moves
    a, b = run.runs
    assert not torch.equal(a.test_q, b.test_q) and a.before.rms_mm != b.before.rms_mm


def test_reduction_formula():
    before_lo = torch.tensor([[-2.0, 1.0, -4.0], [-4.0, 3.0, -2.0]], dtype=torch.float64)
    before_hi = before_lo + 1
    after_lo = torch.tensor([[-0.5, -0.1, -0.3], [-0.5, 0.1, -0.3]], dtype=torch.float64)
    after_hi = after_lo + 0.4
    red = reduction_percent(before_lo, before_hi, after_lo, after_hi)
    assert math.isclose(red["x"]["lower"], 100 * (1 - 0.5 / 3.0))
    assert math.isclose(red["y"]["lower"], 100.0)  # after mean 0
    assert math.isclose(red["z"]["upper"], 100 * (1 - 0.1 / 2.0))


def test_reductions_of_the_run_by_hand(run):
    res = run.first
    ev = res.after["paper_partitioned"]
    b = res.before.lower[:, 2].numpy().mean()
    a = ev.lower[:, 2].numpy().mean()
    assert math.isclose(res.reductions()["z"]["lower"], 100 * (1 - abs(a) / abs(b)), rel_tol=1e-12)


def test_confidence_intervals_against_scipy(run, doc):
    for name in METHODS:
        per_seed = np.array([r.after[name].rms_mm for r in run.runs])
        st = doc["methods"][name]["test_rms_mm"]
        lo, hi = st["ci95"]
        assert math.isclose(st["mean"], per_seed.mean()) and lo <= st["mean"] <= hi
        ref = scipy.stats.t.interval(0.95, len(per_seed) - 1, loc=per_seed.mean(), scale=scipy.stats.sem(per_seed))
        np.testing.assert_allclose([lo, hi], ref, rtol=1e-10)
        red = np.array([r.reductions(name)["x"]["upper"] for r in run.runs])
        st = doc["methods"][name]["reduction_percent"]["x"]["upper"]
        assert math.isclose(st["mean"], red.mean()) and st["ci95"][0] <= st["mean"] <= st["ci95"][1]
    assert mean_ci([2.5])["ci95"] is None  # one seed: no interval invented


def test_paired_comparison():
    a, b = [1.0, 1.2, 0.9, 1.1], [1.1, 1.25, 1.0, 1.3]
    c = paired_comparison(a, b)
    ref = scipy.stats.ttest_rel(a, b)
    assert math.isclose(c["p"], ref.pvalue) and math.isclose(c["diff_mm"], np.mean(np.subtract(a, b)))
    assert c["significant"] == (ref.pvalue < 0.05)
    # a noise-level difference is no win (no strict "<")
    same = paired_comparison([0.2345, 0.2350], [0.2346, 0.2349])
    assert not same["significant"]
    assert not paired_comparison([1.0, 2.0], [1.0, 2.0])["significant"]


def test_compensation_is_checked(run, doc):
    for res in run.runs:
        for name, c in res.comps.items():
            model = res.models[name]
            z = res.test_zone if METHODS[name][0] else torch.zeros_like(res.test_zone)
            thetas = torch.stack([f.theta for f in res.fits[name]])[z]
            from torchcal.calibration.compensate import predict_rows
            reach = (predict_rows(model, thetas, c.q) - res.test_targets).norm(dim=-1)
            assert torch.equal(c.converged, reach <= 1e-6)
            assert torch.equal(c.within_limits, model.robot.within_limits(c.q))
            counts = res.compensation(name)
            ok = c.converged & c.within_limits
            assert counts["failed"] == int((~ok).sum()) and counts["targets"] == len(ok)
    for name in METHODS:
        tot = doc["methods"][name]["compensation"]
        assert tot["failed"] == sum(r.compensation(name)["failed"] for r in run.runs)


def test_demo_command(tmp_path, monkeypatch, run, capsys):
    import torchcal.workflows.paper_experiment as P

    seen = {}

    def fake(cfg, seeds=1, progress=None, **_):
        seen["seeds"] = seeds
        return run
    monkeypatch.setattr(P, "run_demo", fake)
    out = tmp_path / "demo.json"
    assert cli.main(["demo", "--json", str(out)]) == 0 and seen["seeds"] == 1
    printed = capsys.readouterr().out
    for text in ("Table 3", "Table 4", "Table 5", "Methods side by side", "compensation failed", "Zone extent"):
        assert text in printed
    d = json.loads(out.read_text())
    assert d["seeds"] == 2 and set(MAIN_METHODS) <= set(d["methods"])
    assert cli.main(["demo", "--json", str(out)]) == 2  # exists, no --force: refused before any work
    assert "output exists" in capsys.readouterr().err
    assert cli.main(["demo", "--seeds"]) == 0 and seen["seeds"] == 10
    assert cli.main(["demo", "--seeds", "3"]) == 0 and seen["seeds"] == 3
    capsys.readouterr()
    assert cli.main(["demo", "--seeds", "0"]) == 2
    assert "--seeds" in capsys.readouterr().err


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A small simulated session with repeats, a partition and targets."""
    from torchcal.io.measurement_csv import write_measurements
    from torchcal.io.partition_file import save_partition
    from torchcal.partition.zones import partition_workspace
    from torchcal.io.robot_file import robot
    from torchcal.simulation.virtual_robot import VirtualRobot
    from torchcal.reliability.sweep import sweep
    from torchcal.robots.workspace import sample_workspace

    d = tmp_path_factory.mktemp("session")
    r = robot("kr1000titan")
    vr = VirtualRobot(r, ["base_frame"], seed=4)
    q = sample_workspace(r, 40, seed=5)
    write_measurements(d / "data.csv", vr.measure(q, repeats=3, noise_mm=0.01))
    sw = sweep(r, sample_workspace(r, 60, seed=6), n_samples=100)
    save_partition(partition_workspace(sw.positions, sw.r_set, levels=2, zones=[1, 1], seed=0), d / "part.json")
    qt = sample_workspace(r, 6, seed=7)
    t = r.fk(qt)
    rows = [",".join(map(repr, list(a) + list(b))) for a, b in zip(t.tolist(), torch.rad2deg(qt).tolist())]
    (d / "targets.csv").write_text("x,y,z," + ",".join(f"q{k}" for k in range(1, 7)) + "\n" + "\n".join(rows) + "\n")
    return d, vr, qt, t


@pytest.fixture(scope="module")
def global_model(session):
    """`calibrate` of the session without a partition (base_frame): global.json, read by the
    two tests below."""
    d, *_ = session
    assert cli.main(["calibrate", str(d / "data.csv"), "--robot", "kr1000titan", "--effects", "base_frame",
                     "--out", str(d / "global.json")]) == 0
    return d / "global.json"


def test_calibrate_and_compensate_commands(session, global_model, capsys):
    from torchcal.effects import make_context

    d, vr, qt, t = session
    for extra, name in (([], "global.json"), (["--partition", str(d / "part.json")], "zones.json")):
        if extra:  # the global model: the fixture's
            assert cli.main(["calibrate", str(d / "data.csv"), "--robot", "kr1000titan", "--effects", "base_frame",
                             *extra, "--out", str(d / name)]) == 0
        m = json.loads((d / name).read_text())
        assert m["format"] == "torchcal-model/2"
        assert all(p["interval"][0] <= p["value"] <= p["interval"][1] for p in m["parameters"])
        assert len(m.get("zones", [])) == (0 if not extra else 2)
        assert all(lo <= hi for z in m.get("zones", []) for lo, hi in zip(z["lower"], z["upper"]))
        out = d / f"q_{name}.csv"
        assert cli.main(["compensate", str(d / "targets.csv"), "--model", str(d / name), "--out", str(out)]) == 0
        lines = out.read_text().splitlines()
        assert lines[0] == "point,zone,q1,q2,q3,q4,q5,q6,residual_mm,converged,within_limits"
        q = torch.deg2rad(torch.tensor([[float(v) for v in ln.split(",")[2:8]] for ln in lines[1:]],
                                       dtype=torch.float64))
        assert all(ln.endswith("true") for ln in lines[1:])
        # the true (noise-free) robot at the corrected commands: close to the targets
        true = vr.model.predict(vr.theta, make_context(vr.robot, q))
        before = vr.model.predict(vr.theta, make_context(vr.robot, qt))
        assert (true - t).norm(dim=-1).max() < 0.1 < (before - t).norm(dim=-1).min()
    capsys.readouterr()


def test_command_errors(session, global_model, capsys):
    d, *_ = session
    model = global_model  # the fixture's: the test does not lean on another test's output
    capsys.readouterr()
    bad = d / "bad_targets.csv"
    bad.write_text("x,y\n1,2\n")
    assert cli.main(["compensate", str(bad), "--model", str(model), "--out", str(d / "o.csv")]) == 2
    assert "header has no column 'z'" in capsys.readouterr().err
    bad.write_text("x,y,z\n1,2,abc\n")
    assert cli.main(["compensate", str(bad), "--model", str(model), "--out", str(d / "o.csv")]) == 2
    assert "line 2, column z: expected a number (mm)" in capsys.readouterr().err
    assert cli.main(["calibrate", str(d / "data.csv"), "--robot", "kr1000titan", "--out",
                     str(d / "data.csv"), "--force"]) == 2
    assert "refusing to write over it" in capsys.readouterr().err


def test_seeds_in_processes_equal_seeds_in_turn():
    """Seeds side by side in 2 processes (`processes=2`, what `torchcal demo` does on 2
    cores) give the report of the seeds one after another, figure for figure, with
    discovery on (its fitted effects carry autograd history across the process boundary).
    One reliability level of one zone each (2 zones, 20 calibration poses, not SMALL's 4
    and 40): discovery is most of a seed's work, it scales with the poses, and the equality
    asked for is as strict on the smaller run, as long as discovery does add an effect."""
    import dataclasses

    cfg = dataclasses.replace(SMALL, discover_rounds=1, zones_per_level=(1, 1))

    def figures(r):
        d = r.to_json()
        for k in ("seconds", "timings_s"):
            d.pop(k, None)
        return json.dumps(d, sort_keys=True)
    in_turn = run_demo(cfg, seeds=2)
    assert all(len(r.models["discovered_global"].effects) == 2 for r in in_turn.runs)  # base_frame + one found
    assert figures(run_demo(cfg, seeds=2, processes=2)) == figures(in_turn)
