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

