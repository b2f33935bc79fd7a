"""Joint columns mixed up and positions misaligned with the joint values
(torchcal.calibration.checks.columns): fit and evaluate name the mistake instead of
'another robot or units'."""

from __future__ import annotations

import dataclasses
import math
import re

import pytest
import torch

import torchcal
from torchcal.errors import InputError


@pytest.mark.parametrize("mix, phrase", [
    (lambda q: q[:, [0, 2, 1, 3, 4, 5]], "the joint columns q2 and q3 swapped"),
    (lambda q: torch.cat([q[:, :1], -q[:, 1:2], q[:, 2:]], 1),
     r"the joint column q2 negated \(another sign convention\)"),
    (lambda q: torch.cat([q[:, :1], torch.deg2rad(q[:, 1:2]), q[:, 2:]], 1),  # radians under degrees
     r"the joint column q2 in radians \(read as degrees\)"),
    (lambda q: torch.cat([q[:, :1], q[:, 1:2] + math.pi / 2, q[:, 2:]], 1),  # another zero (was "another robot")
     r"the joint column q2 shifted by -90 deg \(another zero position\)"),
])
def test_one_joint_column_mixed_up_is_named(ur10_series_d, mix, phrase):
    """UR10 series D with two joint columns swapped, one negated, or one in radians under
    degrees was refused as 'another robot or units'; fit (the nominal robot in its best
    frame) and evaluate (a fitted model) name the column. Another robot stays another
    robot (test_another_robot_is_refused_by_evaluate_and_diagnose)."""
    rob, m, fitted = ur10_series_d
    bad = dataclasses.replace(m.subset(slice(0, None, 2)), q_prev=None)
    bad = dataclasses.replace(bad, q=mix(bad.q), q_prev=None)
    with pytest.raises(InputError, match=r"cannot come from ur10 as given: .* but within 10 mm with " + phrase +
                                         r": check the joint columns"):
        torchcal.fit(rob, bad, ["base_frame", "tool_offset"])
    with pytest.raises(InputError, match=r"cannot come from the model of ur10 as given: .* with " + phrase):
        torchcal.evaluate(fitted, bad)


@pytest.mark.parametrize("lag, words", [(1, "1 row(s) further up"), (-2, "2 row(s) further down")])
def test_positions_misaligned_with_the_joint_values_are_named(ur10_series_d, lag, words):
    """UR10 series D with x, y, z shifted against the joint columns (two logs joined with a
    row more in one) was refused as 'another robot or units'; fit and evaluate name the
    misalignment. The rows as taken pass (the `ur10_series_d` fixture's fit)."""
    rob, m, fitted = ur10_series_d
    val = dataclasses.replace(m.subset(slice(0, 200)), q_prev=None, rxyz=None)
    rows = torch.arange(max(0, -lag), len(val) - max(0, lag))
    bad = dataclasses.replace(val.subset(rows), xyz=val.xyz[rows + lag])
    with pytest.raises(InputError, match=r"cannot come from ur10 as given: .* but within 10 mm with each row's x, y, z "
                                         rf"taken from {re.escape(words)}: the positions are misaligned"):
        torchcal.fit(rob, bad, ["base_frame", "tool_offset"])
    with pytest.raises(InputError, match=r"cannot come from the model of ur10 as given: .* taken from "
                                         rf"{re.escape(words)}: the positions are misaligned"):
        torchcal.evaluate(fitted, bad)


def test_twin_column_mistakes_are_both_named():
    """On a UR arm q1 negated and q2 shifted by 180 deg give the same points (a plain-numpy
    ur5e session, tests/npsim.py, in a tracker's frame): the refusal named only 'q2
    shifted by +180 deg' for data whose q1 was negated; now it names both. A q5 shifted by
    90 deg has no twin and is named alone."""
    import numpy as np

    from npsim import tracker_session
    from torchcal.measurements import Measurements
    from torchcal.robots.poses import random_poses

    ur = torchcal.robot("ur5e")
    q = random_poses(ur, 60, 5)
    xyz = torch.from_numpy(tracker_session(ur, q.numpy(), seed=5))
    for mix, words in ((lambda q: torch.cat([-q[:, :1], q[:, 1:]], 1),
                        r"with the joint column q2 shifted by \+180 deg \(another zero position\) or column q1 negated "
                        r"\(another sign convention\), which give the same positions on ur5e: check the joint"),
                       (lambda q: torch.cat([q[:, :4], q[:, 4:5] + np.pi / 2, q[:, 5:]], 1),
                        r"with the joint column q5 shifted by -90 deg \(another zero position\): check the joint")):
        with pytest.raises(InputError, match=r"cannot come from ur5e as given: .* but within 10 mm " + words):
            torchcal.fit(ur, Measurements(torch.arange(60), mix(q), xyz), ["base_frame", "tool_offset"])


def test_a_slide_column_in_metres_is_named():
    """The SCARA of examples/ with its lift's column (q3, prismatic, mm) written in metres:
    refused as 'data of another robot of that size, or many corrupted rows'; fit and
    evaluate now name the column. Plain-numpy session (tests/npsim.py), base frame."""
    from pathlib import Path

    import numpy as np

    from npsim import numpy_fk
    from torchcal.measurements import Measurements
    from torchcal.robots.poses import random_poses

    scara = torchcal.robot(Path(__file__).resolve().parents[1] / "examples" / "scara.json")
    q = random_poses(scara, 40, 3)
    rng = np.random.default_rng(5)
    dev = np.zeros((4, 5))
    dev[:, [1, 2]] = rng.uniform(-0.5, 0.5, (4, 2))
    dev[:, [0, 3]] = np.radians(rng.uniform(-0.02, 0.02, (4, 2)))
    tool = np.eye(4)
    tool[:3, 3] = [30.0, 20.0, 120.0]
    xyz = torch.from_numpy(numpy_fk(scara, q.numpy(), dev, tool=tool) + rng.normal(0, 0.01, (40, 3)))
    fitted = torchcal.fit(scara, Measurements(torch.arange(40), q, xyz), ["tool_offset"])
    assert fitted.rms_mm < 0.03
    bad = Measurements(torch.arange(40), torch.cat([q[:, :2], q[:, 2:3] / 1000, q[:, 3:]], 1), xyz)
    words = r"with the joint column q3 \(prismatic\) in metres \(read as mm\)"
    with pytest.raises(InputError, match=r"cannot come from scara as given: .* but within 10 mm " + words):
        torchcal.fit(scara, bad, ["tool_offset"])
    with pytest.raises(InputError, match=r"cannot come from the model of scara as given: .* " + words):
        torchcal.evaluate(fitted, bad)


@pytest.mark.parametrize("sign, words", [(1, r"q3 \+ q2"), (-1, r"q3 - q2")])
def test_a_coupled_j2_j3_column_is_named(sign, words):
    """A KR 1000 session (plain numpy, tests/npsim.py, in a tracker's frame) whose q3 column
    holds joint 3's angle against the base, q3 +- q2, as a controller with coupled J2/J3
    (Fanuc's) reports it: refused as 'data of another robot or units'; now the column and
    the convention are named."""
    from npsim import tracker_session
    from torchcal.measurements import Measurements
    from torchcal.robots.poses import random_poses

    kr = torchcal.robot("kr1000titan")
    q = random_poses(kr, 40, 3)
    xyz = torch.from_numpy(tracker_session(kr, q.numpy(), seed=3))
    coupled = torch.cat([q[:, :2], q[:, 2:3] + sign * q[:, 1:2], q[:, 3:]], 1)
    with pytest.raises(InputError, match=r"cannot come from kr1000titan as given: .* but within 10 mm with the joint "
                                         rf"column q3 holding {words} \(joint 3's angle against the base, not link 2: "
                                         r"a controller's coupled J2/J3 convention, e.g. Fanuc's\): check the joint"):
        torchcal.fit(kr, Measurements(torch.arange(40), coupled, xyz), ["base_frame", "tool_offset"])


TRACK7 = {"name": "track7", "base": [[0, 0, 1, 0], [0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1]], "payload_kg": 5,
          "joints": [{"type": "prismatic", "theta_offset_deg": 0, "d_mm": 0, "a_mm": 0, "alpha_deg": 90,
                      "lower": 0, "upper": 3000}]
          + [{"type": "revolute", "theta_offset_deg": 0, "d_mm": d, "a_mm": a, "alpha_deg": al, "lower": -360,
              "upper": 360, **({"beta_deg": 0} if al == 0 and k < 5 else {})}
             for k, (d, a, al) in enumerate([(162.5, 0, 90), (0, -425, 0), (0, -392.2, 0), (133.3, 0, 90),
                                             (99.7, 0, -90), (99.6, 0, 0)])]}


def test_an_external_axis_logged_after_the_arm_and_mixed_type_swaps_are_named():
    """A ur5e on a horizontal track (prismatic joint 1, a plain-numpy session in a tracker's
    frame, tests/npsim.py) whose file logs the track after the arm's six joints (KUKA's E1
    after A6): refused as 'data of another robot or units'; now named. The SCARA of
    examples/ with its columns q2 (deg) and q3 (the lift, mm) swapped is named too (the
    swap moved the values without their units: 'another robot')."""
    from pathlib import Path

    import numpy as np

    from npsim import numpy_fk, tracker_session
    from torchcal.calibration.checks.columns import reordered
    from torchcal.io.robot_file import robot_from_dict
    from torchcal.measurements import Measurements
    from torchcal.robots.poses import random_poses

    track = robot_from_dict(TRACK7)
    q = random_poses(track, 40, 3)
    xyz = torch.from_numpy(tracker_session(track, q.numpy(), 3))
    logged = reordered(q, track.prismatic, [*range(1, 7), 0])  # the file: A1..A6, then the track
    assert torch.allclose(logged[:, 6], torch.deg2rad(q[:, 0])) and torch.equal(logged[:, 0], torch.rad2deg(q[:, 1]))
    with pytest.raises(InputError, match=r"cannot come from track7 as given: .* but within 10 mm with the joint "
                                         r"columns rotated: q7 holding joint 1 and q1..q6 joints 2..7 \(an external "
                                         r"axis, e.g. a track, logged after the arm's joints"):
        torchcal.fit(track, Measurements(torch.arange(40), logged, xyz), ["base_frame", "tool_offset"])
    scara = torchcal.robot(Path(__file__).resolve().parents[1] / "examples" / "scara.json")
    q = random_poses(scara, 40, 3)
    xyz = torch.from_numpy(numpy_fk(scara, q.numpy(), np.zeros((4, 5))))
    swapped = reordered(q, scara.prismatic, [0, 2, 1, 3])
    with pytest.raises(InputError, match=r"cannot come from scara as given: .* with the joint columns q2 and q3 swapped"):
        torchcal.fit(scara, Measurements(torch.arange(40), swapped, xyz), ["tool_offset"])
    backwards = reordered(q, scara.prismatic, [3, 2, 1, 0])
    with pytest.raises(InputError, match=r"data: the joint columns are in reverse order: .* with q4 .. q1 read as q1 .. q4"):
        torchcal.fit(scara, Measurements(torch.arange(40), backwards, xyz), ["tool_offset"])
