"""Data without a column an effect reads (thermal_expansion: temp_c) are refused in one line
naming the file by every command that fits or scores the model, before any other check
computes with the missing column (`check_conditions`); data with the column pass. Data:
tests/npsim.py (plain-numpy thermal growth) and the UR10 series."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import torchcal
from torchcal.calibration.checks.conditions import check_conditions
from torchcal.calibration.model import CalibrationModel
from torchcal.cli import main
from torchcal.io.measurement_csv import read_measurements
from torchcal.robots.poses import random_poses

from npsim import thermal_session

UR10 = Path(__file__).resolve().parents[1] / "examples" / "ur10"


def thermal_file(path, rob, n, seed, with_temp=True, repeats=1):
    """A CSV of a thermal npsim session at n poses (temp_c 15..35 degC), each pose `repeats`
    times, with or without its temp_c column."""
    q = random_poses(rob, n, seed).numpy()
    temp = np.random.default_rng(seed).uniform(15, 35, n)
    rows = []
    for r in range(repeats):
        xyz = thermal_session(rob, q, temp, seed + 100 * r)
        rows += [(i, q[i], xyz[i], temp[i]) for i in range(n)]
    head = "pose," + ",".join(f"q{j + 1}" for j in range(rob.n)) + ",x,y,z" + (",temp_c" if with_temp else "")
    path.write_text(head + "\n" + "".join(
        f"{i}," + ",".join(f"{v:.6f}" for v in np.rad2deg(qi)) + "," + ",".join(f"{v:.5f}" for v in p)
        + (f",{t:.3f}" if with_temp else "") + "\n" for i, qi, p, t in rows))
    return path


def test_every_command_names_the_file_without_temp_c(tmp_path, capsys):
    rob = torchcal.robot("ur5e")
    with_t = thermal_file(tmp_path / "warm.csv", rob, 40, 1)
    model = tmp_path / "m.json"
    assert main(["fit", str(with_t), "--robot", "ur5e", "--effects", "thermal_expansion", "--out", str(model)]) == 0
    bare = thermal_file(tmp_path / "bare.csv", rob, 40, 2, with_temp=False, repeats=2)
    out = tmp_path / "out.json"
    for argv in (["fit", str(bare), "--robot", "ur5e", "--effects", "thermal_expansion", "--out", str(out)],
                 ["discover", str(bare), "--robot", "ur5e", "--effects", "thermal_expansion", "--out", str(out)],
                 ["calibrate", str(bare), "--robot", "ur5e", "--effects", "thermal_expansion", "--out", str(out)],
                 ["diagnose", str(bare), "--robot", "ur5e", "--effects", "thermal_expansion"],
                 ["evaluate", str(bare), "--model", str(model)]):
        capsys.readouterr()
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "Traceback" not in err, err
        assert f"{bare}: thermal_expansion needs the temp_c column" in err, err
        assert not out.exists()


@pytest.mark.parametrize("robot", ["ur5e", "kr1000titan", "puma560"])
def test_data_with_temp_c_pass(tmp_path, robot):
    rob = torchcal.robot(robot)
    cm = CalibrationModel(rob, ["thermal_expansion"])
    for seed in range(3):
        m = read_measurements(thermal_file(tmp_path / f"t{seed}.csv", rob, 30, seed), robot=rob)
        check_conditions(cm, m)


def test_the_ur10_series_pass():
    rob = torchcal.robot(UR10 / "ur10.json")
    cm = CalibrationModel(rob, ["base_frame", "tool_offset", "thermal_expansion"])
    for s in "bcd":
        check_conditions(cm, read_measurements(UR10 / f"series_{s}.csv", robot=rob))
