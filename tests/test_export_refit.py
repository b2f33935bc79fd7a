"""Export that holds: a model with joint compliance exported with --data refits the geometry
alone, and that robot is better on held-out poses than the full model's geometry exported
without its compliance; without --data export says it cannot tell by how much."""

from __future__ import annotations

import pytest

import torchcal
from torchcal.calibration.geometry_only import refit_geometry
from torchcal.cli import main
from torchcal.io.files import write_json
from torchcal.io.measurement_csv import write_measurements
from torchcal.io.modelfile import to_dict
from torchcal.robots.poses import random_poses
from torchcal.io.robot_file import load_robot_file
from torchcal.simulation.virtual_robot import VirtualRobot

EFFECTS = ["base_frame", "tool_offset", "joint_compliance:2,3"]


@pytest.fixture(scope="module")
def session():
    rob = torchcal.robot("ur5e")
    # a heavily loaded arm: 1 mm of compliance sag (RMS over a session), hidden in the data
    vr = VirtualRobot(rob, EFFECTS, seed=5, effect_mm={"joint_compliance": 1.0})
    train = vr.measure(random_poses(rob, 80, 11), seed=12)
    held = vr.measure(random_poses(rob, 80, 13), seed=14)
    full = torchcal.fit(rob, train, EFFECTS)
    return rob, train, held, full


def geometry_rms(robot, m) -> float:
    """RMS mm of a robot's geometry alone (its base and tool included) on measurements m."""
    return float((robot.fk(m.q) - m.xyz).norm(dim=-1).pow(2).mean().sqrt())


def test_refit_geometry_beats_the_naive_export_on_held_out_poses(session, tmp_path, capsys):
    rob, train, held, full = session
    write_json(tmp_path / "m.json", to_dict(full))
    write_measurements(tmp_path / "train.csv", train, robot=rob)
    assert main(["export", str(tmp_path / "m.json"), "--robot-file", str(tmp_path / "naive.json")]) == 0
    err = capsys.readouterr().err
    assert "by how much cannot be told without data" in err and "--data" in err
    assert main(["export", str(tmp_path / "m.json"), "--robot-file", str(tmp_path / "refit.json"),
                 "--data", str(tmp_path / "train.csv")]) == 0
    out = capsys.readouterr().out
    assert "exported robot alone rms" in out and "full model" in out
    naive = geometry_rms(load_robot_file(tmp_path / "naive.json"), held)
    refit = geometry_rms(load_robot_file(tmp_path / "refit.json"), held)
    assert refit < naive
    # the printed figure is the exported robot's own rms on the data
    printed = float(out.split("exported robot alone rms ")[1].split()[0])
    assert printed == pytest.approx(geometry_rms(load_robot_file(tmp_path / "refit.json"), train), abs=1e-4)


def test_refit_is_the_geometry_only_optimum_from_the_model(session):
    rob, train, _, full = session
    r = refit_geometry(full.model, full.theta, train, identified=full.report.free)
    assert r.dropped == ["joint_compliance:2,3"]
    assert r.full_rms_mm <= r.refit_rms_mm <= r.naive_rms_mm
    # an independent geometry-only fit from zero reaches the same optimum
    direct = torchcal.fit(rob, train, ["base_frame", "tool_offset"])
    assert r.refit_rms_mm == pytest.approx(direct.rms_mm, rel=1e-3)
