"""diagnose / discover / calibrate on data with several measured points per pose.

The baseline of diagnose and discover is the per-point model (one tool offset per point
id, as torchcal.fit builds it); with a single shared offset the three reflectors 100 mm
apart leave tens of mm of residual and the hidden effect drowns. Simulated truth: ur5e,
MD-H deviations, three reflectors, and a periodic gear error on joint 2 that the baseline
lacks; diagnose must name it. Interval calibration (rows of a pose grouped into one
interval) refuses such data with one line.
"""

from __future__ import annotations

import math

import pytest
import torch

import torchcal
from torchcal.calibration.model import CalibrationModel
from torchcal.cli import main
from torchcal.effects import make_context
from torchcal.errors import InputError
from torchcal.io.measurement_csv import write_measurements
from torchcal.measurements import Measurements
from torchcal.robots.poses import random_poses

OFFSETS = torch.tensor([[60.0, 0.0, 40.0], [-30.0, 52.0, 45.0], [-30.0, -52.0, 50.0]], dtype=torch.float64)


@pytest.fixture(scope="module")
def data(mdh_deviations):
    rob = torchcal.robot("ur5e")
    truth = CalibrationModel(rob, ["gear_periodic:2", "tool_offset"], points=[1, 2, 3])
    g = torch.Generator().manual_seed(7)
    th = truth.zeros()
    th[: 5 * rob.n] = mdh_deviations(rob, g).flatten()
    s = truth.slices[1].start  # first harmonic of joint 2's gear error, 0.01 deg amplitude
    th[s:s + 2] = torch.tensor([1.0, -0.7], dtype=torch.float64) * math.radians(0.01)
    th[truth.slices[2]] = OFFSETS.flatten()
    n = 30
    q = random_poses(rob, n, 1).repeat_interleave(3, 0)
    pt = torch.tensor([1, 2, 3] * n)
    xyz = truth.predict(th, make_context(rob, q, point=pt)) + 0.02 * torch.randn(3 * n, 3, generator=g,
                                                                               dtype=torch.float64)
    return rob, Measurements(pose=torch.arange(n).repeat_interleave(3), q=q, xyz=xyz, point=pt)


def test_diagnose_uses_the_per_point_model_and_names_the_hidden_effect(data):
    rob, m = data
    d = torchcal.diagnose(rob, m, ["tool_offset"], folds=3, seed=0)
    # the baseline is the per-point model: residual at the level of noise + gear error
    # (one shared offset would leave ~60 mm: the reflectors are ~100 mm apart)
    assert d.baseline_fit.model.points == (1, 2, 3)
    assert d.baseline_cv_rms_mm < 0.2
    assert d.verdict is not None and d.verdict.spec == "gear_periodic:2"


def test_several_points_without_tool_offset_refused(data, tmp_path, capsys):
    rob, m = data
    for run in (torchcal.diagnose, torchcal.discover):
        with pytest.raises(InputError, match="3 measured points per pose .* add tool_offset"):
            run(rob, m, [], folds=3)
    csv = tmp_path / "m.csv"
    write_measurements(csv, m)
    for argv in (["diagnose", str(csv), "--robot", "ur5e"], ["discover", str(csv), "--robot", "ur5e"],
                 ["calibrate", str(csv), "--robot", "ur5e", "--effects", "tool_offset",
                  "--out", str(tmp_path / "im.json")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and ("add tool_offset" in err or "several measured points" in err), err
    assert not (tmp_path / "im.json").exists()
