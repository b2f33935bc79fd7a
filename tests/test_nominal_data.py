"""Positions that are the nominal robot itself (the controller's TCP exported in place of the
tracker's readings) get one warning from fit, discover and calibrate; measured positions of
real and simulated arms, noise-free ones included, do not (`warn_nominal_data`). Real arms:
tests/npsim.py (plain-numpy MD-H deviations, a tracker frame) and the UR10 series."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest
import torch

import torchcal
from torchcal.calibration.model import CalibrationModel
from torchcal.calibration.checks.nominal_data import NOMINAL_FLOOR_MM, NominalDataWarning, nominal_rms_mm
from torchcal.cli import main
from torchcal.io.measurement_csv import read_measurements
from torchcal.measurements import Measurements
from torchcal.robots.poses import random_poses

from npsim import physics_session, tracker_session

UR10 = Path(__file__).resolve().parents[1] / "examples" / "ur10"


def controller_file(path, rob, n, seed, digits=2, repeats=1):
    """The controller's own TCP positions (nominal FK, rounded to `digits` mm) at n poses,
    each pose `repeats` times."""
    q = random_poses(rob, n, seed)
    p = rob.fk(q)
    path.write_text("pose," + ",".join(f"q{j + 1}" for j in range(rob.n)) + ",x,y,z\n" + "".join(
        f"{i}," + ",".join(f"{v:.4f}" for v in torch.rad2deg(q[i]).tolist()) + ","
        + ",".join(f"{v:.{digits}f}" for v in p[i].tolist()) + "\n" for i in range(n) for _ in range(repeats)))
    return path


@pytest.mark.parametrize("robot,effects", [("ur5e", []), ("kr1000titan", ["base_frame", "tool_offset"])])
def test_fit_warns_on_the_controllers_positions(tmp_path, capsys, robot, effects):
    rob = torchcal.robot(robot)
    data = controller_file(tmp_path / "ctrl.csv", rob, 60, 4)
    args = ["--robot", robot] + (["--effects", *effects] if effects else [])
    assert main(["fit", str(data), *args, "--out", str(tmp_path / "m.json")]) == 0  # a warning, not a refusal
    err = capsys.readouterr().err
    assert err.count("x, y, z agree with the nominal") == 1 and "rather than measured" in err, err
    with pytest.warns(NominalDataWarning):
        torchcal.discover(rob, data, effects=effects, report_rest=False)
    with pytest.warns(NominalDataWarning):  # interval calibration: 2 readings per pose
        torchcal.calibrate(rob, controller_file(tmp_path / "ctrl2.csv", rob, 60, 4, repeats=2), effects)


@pytest.mark.parametrize("robot", ["ur5e", "kr1000titan", "puma560"])
def test_measured_positions_are_not_named(robot):
    """Noise-free simulated arms (plain numpy), in the base frame and seen by a tracker: the
    nominal robot is 0.5 mm or more off; fit and the check say nothing."""
    rob = torchcal.robot(robot)
    for seed in range(3):
        q = random_poses(rob, 40, seed)
        xyz, _ = physics_session(rob, q.numpy(), seed, [], noise_mm=0.0)
        m = Measurements(torch.arange(40), q, torch.from_numpy(xyz))
        assert nominal_rms_mm(CalibrationModel(rob, []), m) > 30 * NOMINAL_FLOOR_MM
        trk = Measurements(torch.arange(40), q, torch.from_numpy(tracker_session(rob, q.numpy(), seed, noise_mm=0.0)))
        with warnings.catch_warnings():
            warnings.simplefilter("error", NominalDataWarning)
            torchcal.fit(rob, m)
            torchcal.fit(rob, trk, ["base_frame", "tool_offset"])


def test_the_ur10_series_are_not_named():
    rob = torchcal.robot(UR10 / "ur10.json")
    model = CalibrationModel(rob, ["base_frame", "tool_offset"])
    for s in "bcd":
        assert nominal_rms_mm(model, read_measurements(UR10 / f"series_{s}.csv", robot=rob)) > 50 * NOMINAL_FLOOR_MM
