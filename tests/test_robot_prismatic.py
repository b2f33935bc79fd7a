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
from torchcal.calibration.checks.units import check_units
from torchcal.io.measurement_csv import read_measurements
from torchcal.io.robot_file import robot_from_dict

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


# --- joint effects on a slide, where_it_fails, the priors -----------------

ANGLE_EFFECTS = ["backlash", "gear_periodic", "joint_compliance", "joint_periodic"]


@pytest.mark.parametrize("name", ANGLE_EFFECTS)
def test_angle_effects_refuse_a_slide(name):
    """backlash, gear_periodic and joint_compliance are angles of a revolute joint: on the
    SCARA's slide (joint 3, q in mm) they are refused with the joint named, on its revolute
    joints they build."""
    from torchcal.calibration.model import CalibrationModel

    robot = robot_from_dict(SCARA)
    at = "@5" if name == "joint_periodic" else ""  # its orders per turn
    with pytest.raises(InputError, match=f"{name}:3{at}: joint\\(s\\) 3 .* prismatic"):
        CalibrationModel(robot, [f"{name}:3{at}"])
    assert CalibrationModel(robot, [f"{name}:2{at}"]).n_params > 5 * robot.n
    CalibrationModel(robot, ["encoder_scale:3"])  # a scale error is one on a slide too


def test_discover_does_not_offer_angle_effects_on_a_slide():
    from torchcal.diagnosis.candidates import candidate_specs
    from torchcal.effects import make_context

    robot = robot_from_dict(SCARA)
    q = robot.q_from_user(torch.tensor(Q_USER, dtype=torch.float64))
    offered = candidate_specs(robot, {}, make_context(robot, q))
    on_slide = {name for name, js in offered if js == (3,)}
    assert not on_slide & set(ANGLE_EFFECTS), on_slide
    assert "encoder_scale" in on_slide
    assert {name for name, js in offered if js == (2,)} >= set(ANGLE_EFFECTS)
    # a coupling of the slide's mm into a revolute joint's angle is not offered either
    from torchcal.calibration.model import CalibrationModel
    assert "coupling_3_4" not in CalibrationModel(robot, ["cross_coupling:4"]).param_names()


def test_where_it_fails_bins_a_slide_in_mm():
    """Data of the SCARA from the plain-numpy chain (tests/npsim.py); the slide's bins lie
    inside its 0..200 mm stroke, the revolute joints' inside their limits in degrees."""
    import numpy as np
    from npsim import numpy_fk

    from torchcal.diagnosis.diagnose import where_it_fails
    from torchcal.measurements import Measurements
    from torchcal.robots.poses import random_poses

    robot = robot_from_dict(SCARA)
    q = random_poses(robot, 80, torch.Generator().manual_seed(0))
    xyz = torch.as_tensor(numpy_fk(robot, q.numpy(), np.zeros((robot.n, 5))))
    m = Measurements(torch.arange(80), q, xyz)
    out = where_it_fails(robot, m, torch.full((80, 3), 0.01, dtype=torch.float64))["per_joint"]
    assert [j["unit"] for j in out] == ["deg", "deg", "mm", "deg"]
    slide = [v for b in out[2]["bins"] for v in b["q"]]
    assert 0.0 <= min(slide) and max(slide) <= 200.0 and max(slide) - min(slide) > 100.0
    elbow = [v for b in out[1]["bins"] for v in b["q"]]
    assert -150.0 <= min(elbow) and max(elbow) <= 150.0 and max(elbow) - min(elbow) > 100.0


def test_each_none_scale_drops_only_its_own_prior():
    import math

    from torchcal.calibration.model import CalibrationModel
    from torchcal.calibration.plausibility import plausible_scales

    model = CalibrationModel(robot_from_dict(SCARA), [])
    n = model.robot.n
    no_angle = plausible_scales(model, 5.0, None).reshape(n, 5)  # [dtheta, dd, da, dalpha, dbeta]
    assert torch.isinf(no_angle[:, [0, 3, 4]]).all() and (no_angle[:, [1, 2]] == 5.0).all()
    no_length = plausible_scales(model, None, 1.0).reshape(n, 5)
    assert torch.isinf(no_length[:, [1, 2]]).all()
    assert torch.allclose(no_length[:, [0, 3, 4]], torch.full((n, 3), math.radians(1.0), dtype=torch.float64))
