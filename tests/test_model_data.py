"""Measurements against a fitted model (torchcal.calibration.checks.model_data): a UR10
model on data of another robot or in a moved measuring frame gets one line naming the
cause, and so do rows beyond its calibrated range; data of the right robot in the right
frame pass silently."""

from __future__ import annotations

import dataclasses
import re
import warnings
from pathlib import Path

import pytest
import torch

import torchcal
from torchcal.calibration.checks.model_data import check_points
from torchcal.calibration.checks.verdict import GROSS_MM, MismatchWarning
from torchcal.errors import InputError
from torchcal.io.measurement_csv import write_measurements
from torchcal.measurements import fixed_xyz_to_matrix

UR10 = Path(__file__).resolve().parents[1] / "examples" / "ur10" / "ur10.json"


def moved(m, deg=10.0, shift=(500.0, 0.0, 0.0)):
    """Measurements m seen from a tracker turned `deg` about z and shifted `shift` mm."""
    R = fixed_xyz_to_matrix(torch.deg2rad(torch.tensor([0.0, 0.0, deg], dtype=torch.float64)))
    return dataclasses.replace(m, xyz=m.xyz @ R.T + torch.tensor(shift, dtype=torch.float64))


def test_right_data_pass_silently(ur10_fitted):
    _, _, fitted, val = ur10_fitted
    with warnings.catch_warnings():
        warnings.simplefilter("error", MismatchWarning)
        warnings.simplefilter("ignore", UserWarning)  # calibrated-range lines are not the subject
        ev = torchcal.evaluate(fitted, val)
    assert ev.rms_mm < 3 * fitted.rms_mm


def test_another_robot_is_refused_by_evaluate_and_diagnose(titan_data, ur10_fitted):
    rob, _, fitted, _ = ur10_fitted
    data = titan_data
    with pytest.raises(InputError, match="cannot come from the model of ur10.*another robot or units"):
        torchcal.evaluate(fitted, data)
    with pytest.raises(InputError, match="cannot come from"):
        torchcal.diagnose(rob, data, ["base_frame"])


def test_moved_frame_points_at_register(ur10_fitted):
    _, _, fitted, val = ur10_fitted
    with pytest.raises(InputError, match=r"measuring frame moved.*torchcal register") as exc:
        torchcal.evaluate(fitted, moved(val))
    # the line names the motion: 10 deg, about 500 mm
    assert "10 deg" in str(exc.value)
    # diagnose refits the frame: a warning, not a refusal
    with pytest.warns(MismatchWarning, match="measuring frame moved"):
        torchcal.api.check_diagnosis_data(fitted, fitted.model, moved(val))


def test_bound_is_ratio_and_absolute():
    g = torch.Generator().manual_seed(0)
    p = torch.randn(50, 3, generator=g, dtype=torch.float64) * 500
    off = torch.zeros_like(p)
    off[:, 0] = 0.9 * GROSS_MM  # a 9 mm error: large, yet not gross whatever the training rms
    assert check_points(p, p + off, training_rms_mm=0.01).verdict is None
    off[:, 0] = 2.0 * GROSS_MM
    assert check_points(p, p + off, training_rms_mm=0.01).verdict == "frame"  # a pure shift
    assert check_points(p, p + off, training_rms_mm=5.0).verdict is None  # within 10x a poor fit
    # a scaled copy: no rigid motion explains it
    r = check_points(p, p * 1.5, training_rms_mm=0.01)
    assert r.verdict == "mismatch" and r.spread_ratio == pytest.approx(1.5)


def test_cli_evaluate_refuses_and_writes_nothing(ur10_fitted, tmp_path):
    from torchcal.cli import main
    from torchcal.io.modelfile import to_dict
    from torchcal.io.files import write_json

    rob, _, fitted, val = ur10_fitted
    write_json(tmp_path / "m.json", to_dict(fitted))
    write_measurements(tmp_path / "moved.csv", moved(val), robot=rob)
    rc = main(["evaluate", str(tmp_path / "moved.csv"), "--model", str(tmp_path / "m.json"),
               "--json", str(tmp_path / "out.json")])
    assert rc == 2 and not (tmp_path / "out.json").exists()


def test_rows_outside_the_calibrated_range_are_named_as_the_cause(titan_data):
    """UR10 series D: its first 200 rows keep joint 6 within -90.2 .. -89.7 deg, so a model
    fitted on them leaves the tool offset undetermined; on the next 200 rows (joint 6 over
    +-90 deg) it is off by hundreds of mm, yet by its training error on the rows inside its
    calibrated range. The refusal names the calibrated range, not 'another robot or units'."""
    from torchcal.io.measurement_csv import read_measurements

    rob = torchcal.robot(UR10)
    m = read_measurements(UR10.parent / "series_d.csv", robot=rob)
    fitted = torchcal.fit(rob, m.subset(slice(0, 200)), ["base_frame", "tool_offset"])
    val = m.subset(slice(200, 400))
    with pytest.raises(InputError) as exc:
        torchcal.evaluate(fitted, val)
    msg = str(exc.value)
    assert "rows inside its calibrated joint range" in msg and "joint 6: " in msg, msg
    assert "another robot or units (length" not in msg and "`torchcal register`" not in msg
    rms_in = float(re.search(r"but by ([0-9.]+) mm", msg).group(1))
    assert rms_in < 3 * fitted.training_rms_mm  # the rows inside agree with the model
    with pytest.raises(InputError, match="another robot or units"):  # another robot stays another robot
        torchcal.evaluate(fitted, dataclasses.replace(val, xyz=titan_data.xyz[:1].expand(200, 3) +
                                                      torch.randn(200, 3, dtype=torch.float64,
                                                                  generator=torch.Generator().manual_seed(1)) * 300))
