"""Measured orientations in another convention or unit (torchcal.calibration.checks.orientation)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

import torchcal
from torchcal.calibration.checks.verdict import MismatchWarning
from torchcal.errors import InputError
from torchcal.measurements import fixed_xyz_to_matrix

UR10 = Path(__file__).resolve().parents[1] / "examples" / "ur10" / "ur10.json"


@pytest.mark.parametrize("reading, phrase", [
    ("rad", r"fixed-axis XYZ angles in radians \(read as degrees\)"),
    ("intrinsic", r"intrinsic \(moving-axis\) XYZ angles"),
    ("rotvec", r"a rotation vector \(axis-angle, as UR controllers report\)")])
def test_orientations_in_another_convention_are_named(tmp_path, reading, phrase):
    """UR10 series C's rx, ry, rz written in radians, as intrinsic XYZ angles or as a
    rotation vector (UR's TCP pose): before, fit went on and gave a model off by mm
    (rx, ry, rz in radians: training rms 2.45 mm against 0.44, the tool offset -10 mm off,
    orientation rms 18 deg); now one line names the reading. The data as written pass."""
    from torchcal.rotations import matrix_to_fixed_xyz, matrix_to_rotvec

    lines = (UR10.parent / "series_c.csv").read_text().splitlines()[:121]
    head = lines[0].split(",")
    cols = [head.index(c) for c in ("rx", "ry", "rz")]
    rows = [line.split(",") for line in lines[1:]]
    r = torch.deg2rad(torch.tensor([[float(row[c]) for c in cols] for row in rows], dtype=torch.float64))
    R = fixed_xyz_to_matrix(r)
    new = {"rad": r, "intrinsic": -torch.rad2deg(matrix_to_fixed_xyz(R.transpose(-1, -2))),
           "rotvec": torch.rad2deg(torch.stack([matrix_to_rotvec(x) for x in R]))}[reading]
    for row, v in zip(rows, new.tolist()):
        for c, x in zip(cols, v):
            row[c] = repr(x)
    (tmp_path / "o.csv").write_text("\n".join([lines[0]] + [",".join(row) for row in rows]) + "\n")
    with pytest.raises(InputError, match=r"o.csv: rx, ry, rz disagree with the tool orientation of ur10 by rms "
                                         rf"[0-9.]+ deg .*: they look like {phrase}; rx, ry, rz are fixed-axis XYZ"):
        torchcal.fit(UR10, tmp_path / "o.csv", ["base_frame", "tool_offset"])
    (tmp_path / "ok.csv").write_text("\n".join(lines) + "\n")
    res = torchcal.fit(UR10, tmp_path / "ok.csv", ["base_frame", "tool_offset"])
    with pytest.warns(MismatchWarning, match=rf"o.csv: rx, ry, rz disagree .*: they look like {phrase};"):
        torchcal.evaluate(res, tmp_path / "o.csv")  # positions still agree: the figures, with the warning


def test_sigma_deg_on_data_without_orientations_warns_in_the_library(tmp_path, capsys):
    """sigma_deg weighs measured rx, ry, rz against positions: on data without them it
    changes nothing. The command line said so in one line; torchcal.fit, diagnose and
    discover took it silently. Now one UnusedSigmaWarning at the caller's line (none when
    sigma_deg is not given, or the data have rx, ry, rz), and the command line still says
    it once, naming its option (tracker positions of a plain-numpy ur5e, npsim)."""
    import warnings

    import npsim
    from torchcal.calibration.checks.orientation import UnusedSigmaWarning
    from torchcal.cli import main
    from torchcal.io.measurement_csv import read_measurements, write_measurements
    from torchcal.measurements import Measurements
    from torchcal.robots.poses import random_poses

    rob = torchcal.robot("ur5e")
    q = random_poses(rob, 40, 21).numpy()
    m = Measurements(torch.arange(40), torch.as_tensor(q), torch.as_tensor(npsim.tracker_session(rob, q, seed=3)),
                     source="s.csv")
    effects = ["base_frame", "tool_offset"]
    line = r"^s.csv: sigma_deg 0.5 is ignored: the data have no rx, ry, rz"
    with pytest.warns(UnusedSigmaWarning, match=line) as caught:
        torchcal.fit(rob, m, effects, sigma_deg=0.5)
    assert [w.filename for w in caught if w.category is UnusedSigmaWarning] == [__file__]
    for run in (torchcal.diagnose, torchcal.discover):  # raised: the warning comes before the search
        with warnings.catch_warnings():
            warnings.simplefilter("error", UnusedSigmaWarning)
            with pytest.raises(UnusedSigmaWarning, match=line):
                run(rob, m, effects, sigma_deg=0.5)
    with_rxyz = read_measurements(UR10.parent / "series_c.csv", robot=torchcal.robot(UR10)).subset(slice(0, 60))
    assert with_rxyz.rxyz is not None
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnusedSigmaWarning)
        plain = torchcal.fit(rob, m, effects)
        torchcal.fit(UR10, with_rxyz, effects, sigma_deg=0.5)
    assert plain.sigma_deg == torchcal.fit(rob, m, effects, sigma_deg=None).sigma_deg > 0  # None: the default
    write_measurements(tmp_path / "s.csv", m)
    capsys.readouterr()
    assert main(["fit", str(tmp_path / "s.csv"), "--robot", "ur5e", "--effects", *effects, "--sigma-deg", "0.5",
                 "--out", str(tmp_path / "m.json")]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if "sigma" in line]
    assert len(err) == 1 and err[0].startswith("torchcal: warning: --sigma-deg 0.5 is ignored"), err
