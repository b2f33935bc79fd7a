"""Gross outliers: 2% of 240 training rows off by 5 mm in a random direction.
`torchcal fit --robust huber|cauchy` flags those pose ids and the fit is not corrupted:
the held-out RMS on 120 clean poses stays within 10% of the fit on clean data."""

from __future__ import annotations

import json

import pytest
import torch

import torchcal
from torchcal.simulation import virtual_robot as sim
from torchcal.robots.poses import random_poses
from torchcal.cli import main
from torchcal.measurements import Measurements
from torchcal.io.measurement_csv import write_measurements

ROBOT = "kr1000titan"
N_TRAIN, N_TEST, FRACTION, OFFSET_MM = 240, 120, 0.02, 5.0


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = tmp_path_factory.mktemp("outliers")
    robot = torchcal.robot(ROBOT)
    vr = sim.VirtualRobot(robot, [], seed=11)
    q = random_poses(robot, N_TRAIN + N_TEST, torch.Generator().manual_seed(12))
    train = vr.measure(q[:N_TRAIN], noise_mm=0.02)
    test = vr.measure(q[N_TRAIN:], noise_mm=0.02)
    write_measurements(d / "clean.csv", train)
    write_measurements(d / "test.csv", test)

    g = torch.Generator().manual_seed(13)
    n_bad = round(FRACTION * N_TRAIN)
    rows = torch.randperm(N_TRAIN, generator=g)[:n_bad]
    direction = torch.randn(n_bad, 3, generator=g, dtype=torch.float64)
    direction = direction / direction.norm(dim=-1, keepdim=True)
    xyz = train.xyz.clone()
    xyz[rows] += OFFSET_MM * direction
    dirty = Measurements(train.pose, train.q, xyz)
    write_measurements(d / "dirty.csv", dirty)
    planted = sorted(int(train.pose[r]) for r in rows)
    return d, planted


def _fit(d, data_name, out_name, *extra):
    out = d / out_name
    assert main(["fit", str(d / data_name), "--robot", ROBOT, "--out", str(out), *extra]) == 0
    return json.loads(out.read_text())


def _held_out_rms(d, model_name):
    out = d / f"eval-{model_name}"
    assert main(["evaluate", str(d / "test.csv"), "--model", str(d / model_name), "--json", str(out)]) == 0
    return json.loads(out.read_text())["rms_mm"]


@pytest.fixture(scope="module")
def clean_rms(data):
    d, _ = data
    obj = _fit(d, "clean.csv", "clean.json")
    assert obj["fit"]["outlier_poses"] == []
    return _held_out_rms(d, "clean.json")


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_robust_fit_flags_outliers_and_is_not_corrupted(data, clean_rms, capsys, loss):
    d, planted = data
    obj = _fit(d, "dirty.csv", f"dirty-{loss}.json", "--robust", loss)
    flagged = obj["fit"]["outlier_poses"]
    assert obj["fit"]["robust"] == loss
    assert set(planted) <= set(flagged), (planted, flagged)
    assert len(set(flagged) - set(planted)) <= 2, (planted, flagged)
    printed = capsys.readouterr().out
    line = next(ln for ln in printed.splitlines() if ln.startswith("outliers (pose ids)"))
    assert [int(p) for p in line.split(": ", 1)[1].split(", ")] == flagged

    rms = _held_out_rms(d, f"dirty-{loss}.json")
    assert rms <= 1.10 * clean_rms, (rms, clean_rms)


def test_plain_fit_is_corrupted_by_the_same_outliers(data, clean_rms):
    """The check above is not vacuous: without --robust the outliers do hurt."""
    d, _ = data
    obj = _fit(d, "dirty.csv", "dirty-plain.json")
    assert obj["fit"]["outlier_poses"] == [] and obj["fit"]["robust"] is None
    assert _held_out_rms(d, "dirty-plain.json") > 1.10 * clean_rms


def test_robust_fit_on_clean_data_flags_nothing(data, clean_rms):
    d, _ = data
    obj = _fit(d, "clean.csv", "clean-huber.json", "--robust", "huber")
    assert obj["fit"]["outlier_poses"] == []
    assert _held_out_rms(d, "clean-huber.json") <= 1.10 * clean_rms


@pytest.fixture(scope="module")
def tracker_gross():
    """A UR10 from the plain-numpy simulator (tests/npsim.py: tracker frame, 290 mm
    reflector, hidden joint-2 sag): 200 training rows of which 10 (5 %) carry a wrong q2
    (+20 deg, hundreds of mm off), 200 clean held-out rows."""
    from pathlib import Path

    import numpy as np
    from npsim import tracker_session

    rob = torchcal.robot(Path(__file__).resolve().parents[1] / "examples" / "ur10" / "ur10.json")
    q = random_poses(rob, 400, torch.Generator().manual_seed(1))
    xyz = torch.as_tensor(tracker_session(rob, q.numpy(), seed=2))
    m = lambda qq, x: Measurements(torch.arange(qq.shape[0]), qq, x)  # noqa: E731
    bad = torch.randperm(200, generator=torch.Generator().manual_seed(5))[:10]
    q_bad = q[:200].clone()
    q_bad[bad, 1] += np.radians(20.0)
    return rob, m(q[:200], xyz[:200]), m(q_bad, xyz[:200]), m(q[200:], xyz[200:]), sorted(bad.tolist())


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_robust_fit_with_the_prior_is_as_good_as_clean(tracker_gross, loss):
    """5 % gross rows: the robust fit names them and its held-out error stays within 10 % of
    the clean fit's, with the plausibility prior on (its rho from the inlier rows: the
    gross rows' RMS would make the prior hundreds of times too strong)."""
    import warnings

    rob, clean, dirty, test, bad = tracker_gross
    eff = ["base_frame", "tool_offset"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # calibrated-range lines are not the subject
        ref = torchcal.evaluate(torchcal.fit(rob, clean, eff), test).rms_mm
        res = torchcal.fit(rob, dirty, eff, robust=loss)
        rms = torchcal.evaluate(res, test).rms_mm
    assert sorted(res.outliers) == bad
    assert res.plausible_limits["prior_sigma_mm"] < 2 * clean_prior_rho(rob, clean, eff)
    assert rms <= 1.10 * ref, (rms, ref)


def clean_prior_rho(rob, clean, eff) -> float:
    return torchcal.fit(rob, clean, eff).plausible_limits["prior_sigma_mm"]
