"""`fit` gives no silent wrong answer: data that no calibration of this robot can explain
are refused with one line naming the likely cause, exit status 2 and nothing written.
The data come from the plain-numpy simulator of tests/npsim.py (a UR10 seen by a tracker
3 m away, a 290 mm reflector, a hidden joint-2 sag), not from torchcal's own model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

import torchcal
from npsim import tracker_session
from torchcal.calibration.checks.robot_data import check_fitted
from torchcal.calibration.checks.verdict import GROSS_MM
from torchcal.cli import main
from torchcal.errors import InputError
from torchcal.io.measurement_csv import write_measurements
from torchcal.measurements import Measurements
from torchcal.robots.poses import random_poses

UR10 = Path(__file__).resolve().parents[1] / "examples" / "ur10" / "ur10.json"
FRAME = ["base_frame", "tool_offset"]


def _m(q, xyz):
    return Measurements(torch.arange(q.shape[0]), q, torch.as_tensor(xyz, dtype=torch.float64))


@pytest.fixture(scope="module")
def ur10():
    rob = torchcal.robot(UR10)
    q = random_poses(rob, 120, torch.Generator().manual_seed(1))
    return rob, q, tracker_session(rob, q.numpy(), seed=2)


def _fit_cli(tmp_path, capsys, rob, m, effects, *extra):
    data, out = tmp_path / "data.csv", tmp_path / "model.json"
    if not data.exists():
        write_measurements(data, m, robot=rob)
    rc = main(["fit", str(data), "--robot", str(UR10), "--effects", *effects, "--out", str(out), *extra])
    cap = capsys.readouterr()
    return rc, cap.err, out.exists()


def test_tracker_data_fit_with_their_frame(ur10, tmp_path, capsys):
    """The control: the same data with base_frame tool_offset fit (the refusals below are
    about the data, not about the simulator)."""
    rob, q, xyz = ur10
    rc, err, written = _fit_cli(tmp_path, capsys, rob, _m(q, xyz), FRAME)
    assert rc == 0 and written, err


def test_tracker_frame_not_modelled(ur10, tmp_path, capsys):
    rob, q, xyz = ur10
    rc, err, written = _fit_cli(tmp_path, capsys, rob, _m(q, xyz), ["joint_compliance:2"])
    assert rc == 2 and not written and err.count("\n") == 1
    assert "in another frame" in err and "--effects joint_compliance:2 base_frame tool_offset" in err
    with pytest.raises(InputError, match="in another frame"):  # the library says it too
        torchcal.fit(rob, _m(q, xyz), ["base_frame"])


def test_another_robots_data(ur10, tmp_path, capsys):
    rob = ur10[0]
    ti = torchcal.robot("kr1000titan")
    qt = random_poses(ti, 120, torch.Generator().manual_seed(3))
    rc, err, written = _fit_cli(tmp_path, capsys, rob, _m(qt, tracker_session(ti, qt.numpy(), seed=4)), FRAME)
    assert rc == 2 and not written and "cannot come from ur10" in err and "another robot" in err


def test_joint_columns_reversed(ur10, tmp_path, capsys):
    rob, q, xyz = ur10
    rc, err, written = _fit_cli(tmp_path, capsys, rob, _m(q.flip(-1), xyz), FRAME)
    assert rc == 2 and not written and "joint columns are in reverse order" in err


def test_x_and_z_swapped_is_a_mirrored_frame(ur10, tmp_path, capsys):
    rob, q, xyz = ur10
    rc, err, written = _fit_cli(tmp_path, capsys, rob, _m(q, xyz[:, [2, 1, 0]]), FRAME)
    assert rc == 2 and not written and "mirror image" in err and "two of them swapped" in err


@pytest.fixture(scope="module")
def gross(ur10):
    """6 of 120 rows (5 %) with a wrong q2 (+20 deg): their pose ids and the data."""
    _, q, xyz = ur10
    bad = torch.randperm(q.shape[0], generator=torch.Generator().manual_seed(5))[:6]
    q2 = q.clone()
    q2[bad, 1] += np.radians(20.0)
    return sorted(bad.tolist()), _m(q2, xyz)


def test_gross_outliers_point_at_robust(ur10, gross, tmp_path, capsys):
    rob = ur10[0]
    bad, m = gross
    rc, err, written = _fit_cli(tmp_path, capsys, rob, m, FRAME)
    assert rc == 2 and not written and "gross outliers" in err and err.rstrip().endswith("pass --robust huber")
    named = err.split("pose ids ", 1)[1].split(")", 1)[0]
    assert sorted(int(p) for p in named.split(", ")) == bad
    rc, err, written = _fit_cli(tmp_path, capsys, rob, m, FRAME, "--robust", "huber")
    assert rc == 0 and written, err


def test_a_fitted_rms_beyond_any_calibration_is_refused():
    r = torch.zeros(50, 3, dtype=torch.float64)
    r[:, 0] = 0.5
    assert check_fitted(r) is None
    r[:3, 0] = 400.0  # three gross rows: beyond the bound unless the robust fit set them aside
    assert "nothing sensible was fitted" in check_fitted(r, (), "d.csv", "ur10")
    assert check_fitted(r, [0, 1, 2]) is None
    assert check_fitted(r + 2 * GROSS_MM) is not None


@pytest.mark.parametrize("command", ["diagnose", "discover"])
def test_diagnose_and_discover_name_the_tracker_frame(ur10, tmp_path, capsys, command):
    """Tracker data without base_frame tool_offset: the cause named before any work (not
    "another robot or units", and no reflector absorbed into link 6), nothing written."""
    rob, q, xyz = ur10
    write_measurements(tmp_path / "t.csv", _m(q, xyz), robot=rob)
    rc = main([command, str(tmp_path / "t.csv"), "--robot", str(UR10), "--json", str(tmp_path / "o.json")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and not (tmp_path / "o.json").exists()
    assert "in another frame" in err and err.rstrip().endswith("--effects base_frame tool_offset")


def test_a_reflector_in_the_base_frame_is_named_too(ur10):
    """Data in the robot's base frame but with a 290 mm reflector instead of the nominal tool."""
    rob, q, _ = ur10
    xyz = tracker_session(rob, q.numpy(), seed=2, distance_mm=0.0)
    with pytest.raises(InputError, match="in another frame"):
        torchcal.api.check_robot_data_of(torchcal.calibration.CalibrationModel(rob, []), _m(q, xyz))


@pytest.mark.parametrize("command", ["fit", "diagnose", "discover"])
def test_help_says_what_tracker_data_need(command, capsys):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "tracker data" in out.lower() and "base_frame tool_offset" in out
