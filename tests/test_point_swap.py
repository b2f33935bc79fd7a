"""Point ids exchanged between two reflectors at a few poses of a training file
(torchcal.calibration.checks.point_swap), on sessions of the plain-numpy simulator."""

from __future__ import annotations

import csv
import warnings

import pytest
import torch

import torchcal
from npsim import reflectors_session
from torchcal.calibration.checks.point_swap import swapped_poses
from torchcal.io.measurement_csv import read_measurements

NEAR = {1: (60.0, 0.0, 40.0), 2: (60.0, 0.0, 42.0)}  # two nests 2 mm apart
FAR = {1: (60.0, 0.0, 40.0), 2: (-30.0, 52.0, 45.0)}  # 104 mm apart


def _session(path, points, swap=()):
    """A ur5e session of 30 poses at each reflector (npsim), the ids of reflectors 1 and 2
    exchanged at the pose ids `swap`."""
    reflectors_session(path, torchcal.robot("ur5e"), 30, points)
    rows = list(csv.reader(path.open()))
    for r in rows[1:]:
        if int(r[0]) in swap:
            r[-1] = {"1": "2", "2": "1"}[r[-1]]
    path.write_text("".join(",".join(r) + "\n" for r in rows))
    return path


def _exchanged(path):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        torchcal.fit(torchcal.robot("ur5e"), read_measurements(path), effects=["base_frame", "tool_offset"])
    return [str(x.message) for x in w if "exchanged" in str(x.message)]


@pytest.mark.parametrize("swap", [(), (4, 17)])
def test_near_reflectors_exchanged_at_two_poses_are_named(tmp_path, swap):
    """Two nests 2 mm apart, ids exchanged at poses 4 and 17: before, fitted in silence
    (rms 0.25 mm against 0.017 mm honest, the offsets and geometry pulled). Now one warning
    naming exactly those poses; the honest session none."""
    found = _exchanged(_session(tmp_path / "s.csv", NEAR, swap))
    if swap:
        assert len(found) == 1 and "at 2 pose(s) (pose ids 4, 17) two rows fit each other's reflector" in found[0]
    else:
        assert found == []


def test_far_reflectors_exchanged_are_refused_naming_the_exchange(tmp_path, capsys):
    """Reflectors 104 mm apart exchanged at pose 9: refused before the fit as "gross
    outliers (mis-typed or corrupted rows)". Now the refusal names the exchanged ids."""
    from torchcal.cli import main

    data = _session(tmp_path / "s.csv", FAR, (9,))
    out = tmp_path / "m.json"
    assert main(["fit", str(data), "--robot", "ur5e", "--effects", "base_frame", "tool_offset", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "at 1 pose(s) (pose ids 9) two rows fit each other's reflector" in err[0], err
    assert "point ids exchanged there" in err[0] and not out.exists()


def test_swapped_poses_needs_both_a_far_pair_and_a_gain():
    """The rule on errors alone: a pair named only when its rms as given is beyond 3 median
    row errors and the exchange brings it down 3 times."""
    pose = torch.tensor([1, 1, 2, 2, 3, 3])
    point = torch.tensor([1, 2, 1, 2, 1, 2])
    own = torch.full((6, 3), 0.01, dtype=torch.float64)
    other = torch.full((6, 3), 2.0, dtype=torch.float64)
    err = {1: own.clone(), 2: own.clone()}
    err[2][point == 1], err[1][point == 2] = other[point == 1], other[point == 2]  # honest: the other misses
    assert swapped_poses(err, point, pose) == []
    err[1][2], err[2][2] = other[2], own[2]  # pose 2's rows fit each other's reflector
    err[2][3], err[1][3] = other[3], own[3]
    assert swapped_poses(err, point, pose) == [2]
    err[1][2], err[2][2] = own[2] * 2.5, own[2]  # as given within 3 median errors: not named
    err[2][3], err[1][3] = own[3] * 2.5, own[3]
    assert swapped_poses(err, point, pose) == []


def test_discover_names_the_exchanged_poses_too(tmp_path):
    """`discover` fits the same training file: the same warning after its last model."""
    data = read_measurements(_session(tmp_path / "s.csv", NEAR, (4, 17)))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        torchcal.discover(torchcal.robot("ur5e"), data, ["base_frame", "tool_offset"], max_rounds=0, report_rest=False)
    found = [str(x.message) for x in w if "exchanged" in str(x.message)]
    assert len(found) == 1 and "(pose ids 4, 17)" in found[0], found
