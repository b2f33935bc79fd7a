"""The robot file's own table mistaken (torchcal.calibration.checks.robot_table): data
refused as another robot that fit once the table is read in Craig's modified D-H
convention, or with one length corrected, name that instead of 'another robot'."""

from __future__ import annotations

import pytest
import torch

import torchcal
from torchcal.errors import InputError


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


@pytest.mark.parametrize("joint, key, typed, words", [
    (2, "a_mm", -452.0, r"joints\[2\]\.a_mm -42[45]\.\d instead of -452: a length mistyped"),
    # d of joints 2, 3, 4 moves the points alike (their axes are parallel): all three are named
    (4, "d_mm", 113.3, r"joints\[\d\]\.d_mm \S+ instead of \S+ \(or joints\[\d\]\.d_mm \S+ instead of \S+, "
                       r"joints\[\d\]\.d_mm \S+ instead of \S+: they move the points alike\): a length mistyped"),
])
def test_one_length_mistyped_in_the_robot_file_is_named(joint, key, typed, words):
    """A ur5e robot file with one length mistyped (a2 -452 for -425, d4 113.3 for 133.3)
    against a plain-numpy session of the arm (tests/npsim.py): refused as 'data of another
    robot of that size, or many corrupted rows'; now the length and the value that fits
    are named. The right file fits them."""
    from npsim import physics_session
    from torchcal.io.robot_file import robot_from_dict, robot_to_dict
    from torchcal.measurements import Measurements
    from torchcal.robots.poses import random_poses

    ur = torchcal.robot("ur5e")
    q = random_poses(ur, 40, 3)
    xyz, _ = physics_session(ur, q.numpy(), 4, [], noise_mm=0.02)
    m = Measurements(torch.arange(40), q, torch.from_numpy(xyz))
    obj = robot_to_dict(ur)
    obj["joints"][joint - 1][key] = typed
    wrong = robot_from_dict(obj, "ur5e.json")
    with pytest.raises(InputError, match=r"cannot come from ur5e as given: .* but within 10 mm with the robot file's "
                                         + words):
        torchcal.fit(wrong, m)
    if joint == 4:  # the file's own length is among those named
        with pytest.raises(InputError, match=r"joints\[4\]\.d_mm 13[34]\.\d instead of 113\.3"):
            torchcal.fit(wrong, m)
