"""Transfer to another session as a check (torchcal.diagnosis.transfer): a term that only
session A carries is found by `discover` on A, refused when session B is the check
("helps within the session only") while the robot's own term is kept, and `register`
warns when a model's error on a new session is far above its training error."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import torchcal
from torchcal.calibration.registration import TransferWarning, far_from_training
from torchcal.cli import main
from torchcal.diagnosis.transfer import TransferCheck, first_poses
from torchcal.errors import InputError
from torchcal.io.measurement_csv import write_measurements
from torchcal.io.modelfile import to_dict
from torchcal.io.files import write_json
from torchcal.measurements import Measurements, fixed_xyz_to_matrix
from torchcal.robots.poses import random_poses
from torchcal.simulation.virtual_robot import VirtualRobot

TURN = fixed_xyz_to_matrix(torch.deg2rad(torch.tensor([1.0, -2.0, 25.0], dtype=torch.float64)))
SHIFT = torch.tensor([900.0, -400.0, 120.0], dtype=torch.float64)
AMPLITUDE_RAD = 4e-4  # session A's periodic joint-2 error, 0.023 deg


@pytest.fixture(scope="module")
def sessions():
    """Sessions A and B of one "real" UR5e (geometric errors + joint compliance on joints 2
    and 3, which the starting model lacks). Session A alone also carries a joint-2 angle
    error 4e-4 sin(2 q2) rad (its set-up, not the robot), made here in numpy: the robot
    is measured at q + error while q is what the file records. B is measured in a tracker
    frame turned 25 deg and shifted 1 m."""
    robot = torchcal.robot("ur5e")
    vr = VirtualRobot(robot, ["joint_compliance:2,3"], seed=1)
    qa = random_poses(robot, 120, torch.Generator().manual_seed(2))
    err = np.zeros(tuple(qa.shape))
    err[:, 1] = AMPLITUDE_RAD * np.sin(2 * qa[:, 1].numpy())
    got = vr.measure(qa + torch.from_numpy(err), seed=3)  # rows in pose order (one repeat)
    a = Measurements(got.pose, qa, got.xyz, got.payload_kg, got.temp_c)
    b = vr.measure(random_poses(robot, 120, torch.Generator().manual_seed(4)), seed=5)
    b = Measurements(b.pose, b.q, b.xyz @ TURN.T + SHIFT, b.payload_kg, b.temp_c)
    return robot, a, b


def test_first_poses_and_bad_counts(sessions):
    _, _, b = sessions
    pose = torch.tensor([5, 5, 2, 9, 2, 1])
    assert first_poses(pose, 2).tolist() == [True, True, True, False, True, False]
    for k in (2, 120, 500):
        with pytest.raises(InputError, match="first 3 to 119 poses .* pass transfer_poses='30'"):
            TransferCheck(b, k)
    check = TransferCheck(b, 30)
    assert int(check.registration_rows.sum()) == 30 and "first 30 poses" in check.describe()


def test_session_term_is_refused_with_the_other_session_as_check(sessions, tmp_path, capsys):
    robot, a, b = sessions
    alone = torchcal.discover(robot, a, ["base_frame", "tool_offset"], max_rounds=3)
    assert "gear_periodic:2" in alone.final_effects  # found within session A
    write_measurements(tmp_path / "a.csv", a)
    write_measurements(tmp_path / "b.csv", b)
    assert main(["discover", str(tmp_path / "a.csv"), "--robot", "ur5e", "--effects", "base_frame", "tool_offset",
                 "--transfer", str(tmp_path / "b.csv"), "--json", str(tmp_path / "h.json")]) == 0
    out = capsys.readouterr().out
    history = json.loads((tmp_path / "h.json").read_text())["history"]
    assert "frame registered on its first 30 poses" in out
    assert out.count("transfer: current model") == len(history)  # every round prints its figure
    tried = [t for h in history for t in h["transfer"]["tried"]]
    gear = [t for t in tried if t["effect"] == "gear_periodic:2"]
    assert gear and all(t["refused"] for t in gear)  # the session's term, every time it passed in A
    rec = next(h["transfer"] for h in history if gear[0] in h["transfer"]["tried"])
    assert gear[0]["after_mm"] > rec["current_mm"]
    assert f"gear_periodic:2 refused: helps within the session only: transfer {rec['current_mm']:.3f} -> " in out
    final = json.loads((tmp_path / "h.json").read_text())["final_effects"]
    assert "gear_periodic:2" not in final
    assert "joint_compliance:2" in final  # the robot's term carries over and is kept
    for h in history:  # a kept step never raises the other session's error
        if h["transfer"]["kept"]:
            assert h["transfer"]["tried"][-1]["after_mm"] <= h["transfer"]["current_mm"]


def test_register_warns_when_far_above_training(sessions, tmp_path, capsys):
    robot, a, b = sessions
    assert far_from_training(0.5, 0.2) is None and far_from_training(0.7, 0.2).startswith("registered rms 0.7 mm")
    assert far_from_training(5.0, None) is None
    model = torchcal.fit(robot, a, ["base_frame", "tool_offset", "joint_compliance:2,3", "gear_periodic:2"])
    write_json(tmp_path / "a.json", to_dict(model))
    write_measurements(tmp_path / "b30.csv", b.subset(first_poses(b.pose, 30)))
    write_measurements(tmp_path / "a30.csv", a.subset(slice(0, 30)))
    assert main(["register", str(tmp_path / "b30.csv"), "--model", str(tmp_path / "a.json"),
                 "--out", str(tmp_path / "b.json")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "x the model's training rms" in err[0] and "warning above 3x" in err[0]
    assert main(["register", str(tmp_path / "a30.csv"), "--model", str(tmp_path / "a.json"),
                 "--out", str(tmp_path / "a2.json")]) == 0
    assert capsys.readouterr().err == ""  # its own session: no warning
    with pytest.warns(TransferWarning):
        torchcal.register(model, b.subset(first_poses(b.pose, 30)))


def test_cli_discover_refuses_bad_transfer_input(sessions, tmp_path, capsys):
    robot, a, b = sessions
    write_measurements(tmp_path / "a.csv", a)
    write_measurements(tmp_path / "b.csv", b)
    base = ["discover", str(tmp_path / "a.csv"), "--robot", "ur5e", "--out", str(tmp_path / "m.json")]
    assert main(base + ["--transfer", str(tmp_path / "b.csv"), "--transfer-poses", "120"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "first 3 to 119 poses (of 120" in err[0] and err[0].endswith("pass --transfer-poses 30")
    assert main(base + ["--transfer", str(tmp_path / "a.csv")]) == 2
    assert "--transfer names DATA itself" in capsys.readouterr().err
    assert main(base + ["--transfer", str(tmp_path / "none.csv")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "b.csv"]
