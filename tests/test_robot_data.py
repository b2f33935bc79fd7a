"""Measurements against the nominal robot (torchcal.calibration.checks.robot_data): data of
another robot are refused in one line, and many corrupted rows are not called a unit."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import torch

import torchcal
from torchcal.errors import InputError
from torchcal.io.measurement_csv import write_measurements

UR10 = Path(__file__).resolve().parents[1] / "examples" / "ur10" / "ur10.json"


def test_cli_diagnose_refuses_another_robot(titan_data, tmp_path, capsys):
    from torchcal.cli import main

    write_measurements(tmp_path / "titan.csv", titan_data, robot=torchcal.robot("kr1000titan"))
    rc = main(["diagnose", str(tmp_path / "titan.csv"), "--robot", str(UR10), "--effects", "base_frame",
               "--json", str(tmp_path / "d.json")])
    err = capsys.readouterr().err
    assert rc == 2 and "cannot come from" in err and err.count("\n") == 1 and not (tmp_path / "d.json").exists()


def test_many_corrupted_rows_are_not_called_a_unit():
    """40 % of UR10 series C's rows moved 30-80 mm along x were refused as 'data of another
    robot or units' although the spreads agree: the line now says that no unit explains
    it, and names corrupted rows beside another robot of that size."""
    from torchcal.io.measurement_csv import read_measurements

    rob = torchcal.robot(UR10)
    m = read_measurements(UR10.parent / "series_c.csv", robot=rob).subset(slice(0, 120))
    g = torch.Generator().manual_seed(0)
    hit = torch.rand(len(m), generator=g) < 0.4
    shift = torch.zeros_like(m.xyz)
    shift[hit, 0] = 30 + 50 * torch.rand(int(hit.sum()), generator=g, dtype=torch.float64)
    bad = dataclasses.replace(m, xyz=m.xyz + shift, rxyz=None)
    with pytest.raises(InputError, match=r"cannot come from ur10: .*; likely causes: the spreads agree within 10 %, so "
                                         r"no unit: data of another robot of that size, or many corrupted rows"):
        torchcal.fit(rob, bad, ["base_frame", "tool_offset"], robust="huber")


def test_a_robot_file_in_craigs_convention_is_named():
    """Tracker data of a Panda (plain-numpy session, tests/npsim.py) against its robot file
    typed from Craig's modified D-H table (a and alpha one row down): refused as 'data of
    another robot ... or many corrupted rows'; now the line names the table's convention
    and the fix. The hand-rewritten table fits them."""
    from npsim import tracker_session
    from test_robots_checks import PANDA_CRAIG, panda_distal, panda_file
    from torchcal.io.robot_file import robot_from_dict
    from torchcal.measurements import Measurements
    from torchcal.robots.poses import random_poses

    right = robot_from_dict(panda_file(panda_distal()))
    typed = robot_from_dict(panda_file(PANDA_CRAIG))
    q = random_poses(right, 40, 3)
    xyz = torch.from_numpy(tracker_session(right, q.numpy(), 3, reflector_mm=(0, 0, 150)))
    m = Measurements(torch.arange(40), q, xyz)
    assert torchcal.fit(right, m, ["base_frame", "tool_offset"]).rms_mm < 0.5
    with pytest.raises(InputError, match=r"cannot come from panda as given: rms .* but within 10 mm with the robot "
                                         r"file's a_mm and alpha_deg moved up one row: its table is in Craig's "
                                         r"modified D-H convention"):
        torchcal.fit(typed, m, ["base_frame", "tool_offset"])
