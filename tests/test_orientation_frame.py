"""Orientations in another frame than the positions are refused before a fit, in one line
naming the turn between the two frames (`check_orientation_frame`); orientations of an
honest 6-D session (plain-numpy arm, tests/npsim.py: MD-H deviations, a tracker 3 m away,
a reflector 290 mm off the flange, a tilted probe) and of the UR10 series pass."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

import torchcal
from torchcal.calibration.model import CalibrationModel
from torchcal.calibration.checks.orientation_frame import ORIENT_DEG, check_orientation_frame, position_frame
from torchcal.cli import main
from torchcal.errors import InputError
from torchcal.io.measurement_csv import read_measurements, write_measurements
from torchcal.measurements import Measurements
from torchcal.robots.poses import random_poses
from torchcal.rotations import matrix_to_fixed_xyz

from npsim import _rotvec, numpy_frames

UR10 = Path(__file__).resolve().parents[1] / "examples" / "ur10"


def six_d_session(rob, n, seed, turn_deg=0.0):
    """A plain-numpy 6-D tracker session of `rob`: positions and orientations of a probe
    (290 mm off the flange, tilted 30 deg) in a tracker frame; the orientations then turned
    `turn_deg` about the tracker's z axis alone (0: honest)."""
    rng = np.random.default_rng(seed)
    dev = np.zeros((rob.n, 5))
    dev[:, [1, 2]] = rng.uniform(-0.3, 0.3, (rob.n, 2))
    dev[:, [0, 3]] = np.radians(rng.uniform(-0.03, 0.03, (rob.n, 2)))
    probe = np.eye(4)
    probe[:3, :3], probe[:3, 3] = _rotvec(np.radians([30.0, 0.0, 0.0])), [20.0, -10.0, 290.0]
    R = _rotvec(np.radians(rng.uniform(-180, 180)) * np.array([0.0, 0.0, 1.0])) @ _rotvec(np.radians([2.0, -1.0, 0.0]))
    t = np.array([2500.0, -1500.0, -400.0])
    q = random_poses(rob, n, seed)
    T = np.array([numpy_frames(rob, qq, dev)[-1] @ rob.tool.numpy() @ probe for qq in q.numpy()])
    xyz = T[:, :3, 3] @ R.T + t + rng.normal(0, 0.02, (n, 3))
    rot = _rotvec(np.radians([0.0, 0.0, turn_deg])) @ R @ T[:, :3, :3]
    rot = np.array([r @ _rotvec(np.radians(rng.normal(0, 0.01, 3))) for r in rot])
    return Measurements(torch.arange(n), q, torch.from_numpy(xyz), rxyz=matrix_to_fixed_xyz(torch.from_numpy(rot)))


@pytest.mark.parametrize("robot", ["ur5e", "kr1000titan", "puma560"])
def test_honest_orientations_pass_and_turned_ones_are_refused(robot):
    rob = torchcal.robot(robot)
    model = CalibrationModel(rob, ["base_frame", "tool_offset"])
    for seed in range(3):
        check_orientation_frame(model, six_d_session(rob, 60, seed))  # no refusal
        pose = rob.fk_pose(six_d_session(rob, 60, seed).q)  # the probe offset is found: the frame is not tilted
        _, _, u = position_frame(pose, six_d_session(rob, 60, seed).xyz)
        assert float((u - torch.tensor([20.0, -10.0, 290.0], dtype=torch.float64)).norm()) < 5.0
        with pytest.raises(InputError, match=r"fit in a frame of their own turned (19\.9\d*|20(\.0\d*)?) deg"):
            check_orientation_frame(model, six_d_session(rob, 60, seed, turn_deg=20.0))


def test_fit_refuses_the_file_in_one_line_and_writes_nothing(tmp_path, capsys):
    rob = torchcal.robot("ur5e")
    write_measurements(tmp_path / "ok.csv", six_d_session(rob, 60, 5))
    write_measurements(tmp_path / "turned.csv", six_d_session(rob, 60, 5, turn_deg=20.0))
    args = ["--robot", "ur5e", "--effects", "base_frame", "tool_offset"]
    assert main(["fit", str(tmp_path / "ok.csv"), *args, "--out", str(tmp_path / "ok.json")]) == 0
    capsys.readouterr()
    assert main(["fit", str(tmp_path / "turned.csv"), *args, "--out", str(tmp_path / "t.json")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "in another frame than the positions" in err and not (tmp_path / "t.json").exists()


def test_the_ur10_series_pass_with_a_wide_margin():
    rob = torchcal.robot(UR10 / "ur10.json")
    for s in "bcd":
        m = read_measurements(UR10 / f"series_{s}.csv", robot=rob)
        pose = rob.fk_pose(m.q)
        F, _, _ = position_frame(pose, m.xyz)
        from torchcal.calibration.checks.orientation import tool_rotation_rms_deg
        assert tool_rotation_rms_deg(pose[:, :3, :3], m.rotation, F) < ORIENT_DEG / 20
