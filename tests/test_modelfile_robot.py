"""A model given with `--robot` (or `robot=`) of its geometry but other joint limits: the
given robot's limits are used, with one warning line naming them (`with_limits_of`).
Before, the model's own limits were used in silence: `compensate --robot` marked commands
outside the given robot's limits `within_limits` true, and `evaluate --robot` did not name
the rows outside them. Hidden physics: tests/npsim.py (plain numpy MD-H deviations)."""

import csv
import json
import math

import numpy as np
import pytest
import torch

import torchcal
from torchcal.api import compensate_targets
from torchcal.cli import main
from torchcal.io.measurement_csv import write_measurements
from torchcal.io.modelfile import RobotLimitsWarning
from torchcal.io.robot_file import robot_to_dict
from torchcal.measurements import Measurements
from torchcal.robots.poses import random_poses

from npsim import physics_session

NARROW_DEG = [(-180, 180), (-180, 0), (-160, 160), (-180, 180), (-180, 180), (-180, 180)]


def robot_file(path, rob, limits_deg):
    d = robot_to_dict(rob)
    for j, (lo, hi) in zip(d["joints"], limits_deg):
        j["lower"], j["upper"] = lo, hi
    path.write_text(json.dumps(d))
    return path


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """A ur5e (limits +-360 deg) with seeded MD-H deviations, fitted on 80 poses; 20 targets
    anywhere in its workspace; a robot file of the same geometry with narrower limits."""
    d = tmp_path_factory.mktemp("limits")
    rob = torchcal.robot("ur5e")
    q = random_poses(rob, 80, 3)
    xyz, _ = physics_session(rob, q.numpy(), seed=5, hidden=[])
    write_measurements(d / "data.csv", Measurements(torch.arange(80), q, torch.from_numpy(xyz)), robot=rob)
    assert main(["fit", str(d / "data.csv"), "--robot", "ur5e", "--out", str(d / "m.json")]) == 0
    p = rob.fk(random_poses(rob, 20, 9)).tolist()
    with open(d / "targets.csv", "w") as fh:
        fh.write("x,y,z\n" + "".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in p))
    robot_file(d / "narrow.json", rob, NARROW_DEG)
    robot_file(d / "same.json", rob, [(-360, 360)] * 6)
    return d


def outside_narrow(path) -> list:
    """1-based rows of a compensate output whose command lies outside NARROW_DEG, and
    whether each is marked within_limits."""
    out = []
    for i, r in enumerate(csv.DictReader(open(path))):
        if any(not lo <= float(r[f"q{j + 1}"]) <= hi for j, (lo, hi) in enumerate(NARROW_DEG)):
            out.append((i + 1, r["within_limits"]))
    return out


def test_compensate_uses_the_given_robots_limits(setup, capsys):
    d = setup
    assert main(["compensate", str(d / "targets.csv"), "--model", str(d / "m.json"), "--out", str(d / "q.csv")]) == 0
    assert outside_narrow(d / "q.csv"), "the model's own limits give commands outside the narrow ones"
    capsys.readouterr()
    rc = main(["compensate", str(d / "targets.csv"), "--model", str(d / "m.json"), "--robot", str(d / "narrow.json"),
               "--out", str(d / "qn.csv")])
    err = capsys.readouterr().err
    # no command outside the given limits is called within them (each is solved inside them or named)
    assert [r for r in outside_narrow(d / "qn.csv") if r[1] == "true"] == []
    assert rc == (1 if outside_narrow(d / "qn.csv") else 0)
    lines = [x for x in err.splitlines() if "other joint limits" in x]
    assert len(lines) == 1 and "joint 1 limits -360..360 deg in the model, -180..180 deg given" in lines[0], err


def test_evaluate_names_the_rows_outside_the_given_robots_limits(setup, capsys):
    d = setup
    capsys.readouterr()
    assert main(["evaluate", str(d / "data.csv"), "--model", str(d / "m.json"), "--robot", str(d / "narrow.json")]) == 0
    err = capsys.readouterr().err
    q2 = np.array([float(r["q2"]) for r in csv.DictReader(open(d / "data.csv"))])
    assert f"{int((q2 > 0).sum())} row(s) outside the joint limits" in err and "other joint limits" in err


def test_the_same_limits_say_nothing_and_the_model_in_memory_is_not_changed(setup, capsys):
    d = setup
    for robot in ("ur5e", str(d / "same.json")):  # the preset, and a robot file written from it
        capsys.readouterr()
        assert main(["evaluate", str(d / "data.csv"), "--model", str(d / "m.json"), "--robot", robot]) == 0
        assert "limits" not in capsys.readouterr().err
    fitted = torchcal.load(d / "m.json")
    before = fitted.model.robot.limits.clone()
    with pytest.warns(RobotLimitsWarning):
        res = compensate_targets(fitted, d / "targets.csv", robot=d / "narrow.json")
    assert torch.equal(fitted.model.robot.limits, before)
    q = torch.rad2deg(res.compensation.q)
    inside = torch.stack([(q[:, j] >= lo) & (q[:, j] <= hi) for j, (lo, hi) in enumerate(NARROW_DEG)]).all(0)
    assert bool((inside | ~res.compensation.within_limits).all()) and math.isfinite(float(q.abs().max()))
