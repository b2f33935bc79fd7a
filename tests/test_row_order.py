"""Rows re-ordered after the session (torchcal.calibration.checks.row_order)."""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import pytest
import torch

import torchcal
from torchcal.robots.poses import random_poses
from torchcal.simulation.virtual_robot import VirtualRobot

UR10 = Path(__file__).resolve().parents[1] / "examples" / "ur10" / "ur10.json"


def test_backlash_on_rows_sorted_after_the_session_warns(tmp_path, capsys):
    """Backlash reads each row's approach direction from the row order: 200 UR10 series D
    rows sorted by q1 (a spreadsheet) were fitted silently with every row's predecessor
    wrong. One RowOrderWarning line; the file in the order taken, a model without backlash,
    and a sorted split file (prev_q columns: the true predecessors) stay quiet."""
    from torchcal.calibration.checks.row_order import RowOrderWarning
    from torchcal.calibration.model import CalibrationModel
    from torchcal.cli import main
    from torchcal.io.measurement_csv import read_measurements

    rob = torchcal.robot(UR10)
    lines = (UR10.parent / "series_d.csv").read_text().splitlines()[:201]
    ordered = sorted(lines[1:], key=lambda r: float(r.split(",")[1]))
    (tmp_path / "sorted.csv").write_text("\n".join([lines[0]] + ordered) + "\n")
    m = read_measurements(tmp_path / "sorted.csv", robot=rob)
    with pytest.warns(RowOrderWarning, match=r"sorted\.csv: backlash reads each row's approach direction from the "
                                             r"row order, but the pose ids step down at \d+ of 200 rows"):
        CalibrationModel.for_measurements(rob, ["base_frame", "tool_offset", "backlash:2"], m)
    session = read_measurements(UR10.parent / "series_d.csv", robot=rob).subset(slice(0, 200))
    shuffled = session.subset(torch.argsort(session.q[:, 0]))  # a subset keeps its true predecessors
    with warnings.catch_warnings():
        warnings.simplefilter("error", RowOrderWarning)
        CalibrationModel.for_measurements(rob, ["base_frame", "tool_offset", "backlash:2"], session)
        CalibrationModel.for_measurements(rob, ["base_frame", "tool_offset"], m)
        CalibrationModel.for_measurements(rob, ["base_frame", "tool_offset", "backlash:2"], shuffled)
        cycles = VirtualRobot(rob, ["backlash:2"], seed=1).measure(random_poses(rob, 30, 2), repeats=3, seed=3)
        assert bool((cycles.pose[1:] < cycles.pose[:-1]).any())  # repeats: each cycle in random order
        CalibrationModel.for_measurements(rob, ["backlash:2"], dataclasses.replace(cycles, q_prev=None))
    capsys.readouterr()
    assert main(["fit", str(tmp_path / "sorted.csv"), "--robot", str(UR10), "--effects", "base_frame", "tool_offset",
                 "backlash:2", "--out", str(tmp_path / "m.json")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("torchcal: warning: ") and "step down" in err[0], err
