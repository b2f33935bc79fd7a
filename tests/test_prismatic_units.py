"""A prismatic joint's value is a length (mm, or m with --length-unit m), never an angle:
in compensate's seeds, in the measurement reader and in the unit plausibility check.

Reference: the same targets / measurements written in deg + mm and in rad + m give the
same joint values inside (hand conversion), and compensate writes the same commands.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch

from torchcal.cli import main
from torchcal.io.targets_csv import read_targets
from torchcal.errors import InputError
from torchcal.calibration.plausibility import check_units
from torchcal.io.measurement_csv import read_measurements
from torchcal.robots.robot_file import robot_from_dict

# a SCARA: revolute, revolute, prismatic (mm), revolute
SCARA = json.loads((Path(__file__).resolve().parents[1] / "examples" / "scara.json").read_text())
Q_USER = [[30.0, -45.0, 120.0, 10.0], [-60.0, 80.0, 35.5, -90.0], [10.0, 20.0, 180.0, 45.0]]  # deg, deg, mm, deg


def _rad_m(row):
    return [math.radians(row[0]), math.radians(row[1]), row[2] / 1000.0, math.radians(row[3])]


def _write(path, header, rows):
    path.write_text(",".join(header) + "\n" + "".join(",".join(repr(float(v)) for v in r) + "\n" for r in rows))
    return path


def test_compensate_seeds_of_a_slide_are_lengths(tmp_path):
    robot = robot_from_dict(SCARA)
    q = robot.q_from_user(torch.tensor(Q_USER, dtype=torch.float64))
    xyz = robot.fk(q)
    head = ["x", "y", "z", "q1", "q2", "q3", "q4"]
    a = _write(tmp_path / "deg_mm.csv", head, [[*xyz[i].tolist(), *Q_USER[i]] for i in range(3)])
    b = _write(tmp_path / "rad_m.csv", head, [[*(xyz[i] / 1000).tolist(), *_rad_m(Q_USER[i])] for i in range(3)])
    t1, s1, _ = read_targets(a, 4, prismatic=robot.prismatic)
    t2, s2, _ = read_targets(b, 4, length_unit="m", angle_unit="rad", prismatic=robot.prismatic)
    torch.testing.assert_close(t2, t1, rtol=1e-12, atol=1e-9)
    torch.testing.assert_close(s1, torch.tensor(Q_USER, dtype=torch.float64))
    torch.testing.assert_close(s2, s1, rtol=1e-12, atol=1e-9)  # 0.12 m -> 120 mm, not 6.9 "degrees"
    # through the command line: a model of the nominal robot, the same commands either way
    rf = tmp_path / "scara.json"
    rf.write_text(json.dumps(SCARA))
    data = _write(tmp_path / "m.csv", ["pose", "q1", "q2", "q3", "q4", "x", "y", "z"],
                  [[i, *robot.q_to_user(qq).tolist(), *robot.fk(qq).tolist()]
                   for i, qq in enumerate(robot.q_from_user(torch.tensor(
                       [[a0, b0, c0, d0] for a0 in (-100, -20, 50, 120) for b0 in (-120, 30, 110)
                        for c0, d0 in ((20, 0), (150, 90))], dtype=torch.float64)))])
    model = tmp_path / "model.json"
    assert main(["fit", str(data), "--robot", str(rf), "--out", str(model)]) == 0
    for f, extra in ((a, []), (b, ["--length-unit", "m", "--angle-unit", "rad"])):
        assert main(["compensate", str(f), "--model", str(model), "--out", str(f.with_suffix(".out")), *extra]) == 0
    out_a, out_b = (a.with_suffix(".out").read_text().splitlines(), b.with_suffix(".out").read_text().splitlines())
    qa = torch.tensor([[float(c) for c in r.split(",")[2:6]] for r in out_a[1:]], dtype=torch.float64)
    qb = torch.tensor([[float(c) for c in r.split(",")[2:6]] for r in out_b[1:]], dtype=torch.float64)
    torch.testing.assert_close(qb, qa, rtol=0, atol=1e-6)
    torch.testing.assert_close(qa, torch.tensor(Q_USER, dtype=torch.float64), rtol=0, atol=1e-3)


def test_reader_keeps_a_slide_a_length(tmp_path):
    robot = robot_from_dict(SCARA)
    q = robot.q_from_user(torch.tensor(Q_USER, dtype=torch.float64))
    xyz = robot.fk(q)
    head = ["pose", "q1", "q2", "q3", "q4", "x", "y", "z"]
    a = _write(tmp_path / "a.csv", head, [[i, *Q_USER[i], *xyz[i].tolist()] for i in range(3)])
    b = _write(tmp_path / "b.csv", head, [[i, *_rad_m(Q_USER[i]), *(xyz[i] / 1000).tolist()] for i in range(3)])
    ma = read_measurements(a, robot=robot)
    mb = read_measurements(b, robot=robot, length_unit="m", angle_unit="rad")
    torch.testing.assert_close(ma.q, q)
    torch.testing.assert_close(mb.q, q)
    assert mb.q[1, 2].item() == pytest.approx(35.5)  # mm


def test_plausibility_ignores_slide_lengths(tmp_path):
    """Radians read as degrees are caught although the slide's mm values are large; a slide
    of 180 mm does not make --angle-unit rad look like degrees."""
    robot = robot_from_dict(SCARA)
    q = robot.q_from_user(torch.tensor(Q_USER, dtype=torch.float64))
    xyz = robot.fk(q)
    # angles written in radians but read as degrees (the slide in mm, right)
    wrong = _write(tmp_path / "w.csv", ["pose", "q1", "q2", "q3", "q4", "x", "y", "z"],
                   [[i, math.radians(Q_USER[i][0]), math.radians(Q_USER[i][1]), Q_USER[i][2],
                     math.radians(Q_USER[i][3]), *xyz[i].tolist()] for i in range(3)])
    m = read_measurements(wrong, robot=robot)
    with pytest.raises(InputError, match="look like radians read as degrees"):
        check_units(m, robot)
    # the same file read with --angle-unit rad passes (the slide's 180 mm is no angle)
    check_units(read_measurements(wrong, robot=robot, angle_unit="rad"), robot, angle_unit="rad")
