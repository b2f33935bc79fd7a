"""Re-registration: a fitted model moved to a measuring frame turned 10 deg and shifted
500 mm recovers that frame (to noise) from 30 poses and evaluates there as the original
does in its own frame; geometry, effects, covariance and calibrated range are kept."""

from __future__ import annotations

import contextlib
import dataclasses
import math
from pathlib import Path

import pytest
import torch

import torchcal
from torchcal.calibration.registration import frame_slices
from torchcal.effects.base_frame import rotvec_to_matrix
from torchcal.cli import main
from torchcal.errors import InputError
from torchcal.io.files import read_json, write_json
from torchcal.io.measurement_csv import write_measurements
from torchcal.io.modelfile import to_dict
from torchcal.measurements import fixed_xyz_to_matrix
from torchcal.robots.poses import random_poses
from torchcal.simulation.virtual_robot import VirtualRobot

UR10 = Path(__file__).resolve().parents[1] / "examples" / "ur10" / "ur10.json"
TURN = fixed_xyz_to_matrix(torch.deg2rad(torch.tensor([2.0, -1.0, 10.0], dtype=torch.float64)))
SHIFT = torch.tensor([500.0, -200.0, 50.0], dtype=torch.float64)


def moved(m):
    return dataclasses.replace(m, xyz=m.xyz @ TURN.T + SHIFT)


def frame(model, theta):
    """(R, t) measurement <- robot base of a model's base_frame."""
    p = theta[frame_slices(model)[0]]
    return rotvec_to_matrix(p[3:6]), p[:3]


@pytest.fixture(scope="module")
def ur10():
    rob = torchcal.robot(UR10)
    vr = VirtualRobot(rob, ["base_frame", "joint_compliance:2,3"], seed=1)  # compliance: not in the model
    fitted = torchcal.fit(rob, vr.measure(random_poses(rob, 60, 3), seed=4), ["base_frame", "tool_offset"])
    new = moved(vr.measure(random_poses(rob, 30, 9), seed=10))
    val = vr.measure(random_poses(rob, 40, 5), seed=6)
    return rob, fitted, new, val


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_register_recovers_the_moved_frame(ur10):
    _, fitted, new, val = ur10
    res = torchcal.register(fitted, new)
    R0, t0 = frame(fitted.model, fitted.theta)
    R1, t1 = frame(res.model, res.theta)
    # expected: the old frame followed by the tracker's motion
    Re, te = TURN @ R0, TURN @ t0 + SHIFT
    angle = math.degrees(math.acos(min(1.0, (float(torch.trace(Re.T @ R1)) - 1) / 2)))
    assert angle < 0.01 and float((t1 - te).norm()) < 0.2  # noise 0.02 mm, unmodelled compliance 0.3 mm
    # and it evaluates in the new frame as the original does in its own
    e0 = torchcal.evaluate(fitted, val).rms_mm
    e1 = torchcal.evaluate(res, moved(val)).rms_mm
    assert abs(e1 - e0) < 0.2 * e0


def test_register_keeps_geometry_effects_covariance_and_range(ur10):
    _, fitted, new, _ = ur10
    res = torchcal.register(fitted, new)
    keep = torch.ones(fitted.theta.shape[0], dtype=torch.bool)
    keep[frame_slices(fitted.model)[0]] = False
    assert res.model.specs() == fitted.model.specs()
    assert torch.equal(res.theta[keep], fitted.theta[keep])
    c0, c1 = fitted.covariance.cov, res.covariance.cov
    assert torch.equal(c1[keep][:, keep], c0[keep][:, keep])
    assert float(c1[~keep][:, ~keep].diagonal().min()) > 0  # the frame's own uncertainty
    assert float(c1[~keep][:, keep].abs().max()) == 0.0
    assert torch.equal(res.q_range, fitted.q_range)
    assert res.registration["rms_before_mm"] > 100 and res.registration["rms_after_mm"] < 1


def test_register_appends_a_base_frame_and_tool(ur10):
    rob, fitted, new, _ = ur10
    geo = torchcal.fit(rob, ur10[3], [])  # fitted in the robot base frame, no frame effect
    res = torchcal.register(geo, moved(ur10[3]), tool=True)
    assert res.model.specs() == ["base_frame", "tool_offset"]
    assert torch.equal(res.theta[: geo.theta.shape[0]], geo.theta)
    R, t = frame(res.model, res.theta)
    # the simulated robot's own frame is within a mm / a tenth of a degree of identity
    assert float((t - SHIFT).norm()) < 5.0 and float((R - TURN).abs().max()) < 2e-3


def test_registration_only_is_the_closed_form_optimum(ur10):
    rob, _, new, _ = ur10
    from torchcal.calibration.registration import kabsch

    res = torchcal.register(rob, new)
    assert res.model.specs() == ["base_frame"]
    assert float(res.theta[: 5 * rob.n].abs().max()) == 0.0
    nominal = rob.fk(new.q)
    R, t = kabsch(nominal, new.xyz)
    ref = float((nominal @ R.T + t - new.xyz).norm(dim=-1).pow(2).mean().sqrt())
    assert res.rms_mm <= ref + 1e-9


def test_register_refuses_another_robot(ur10):
    _, fitted, _, _ = ur10
    ti = torchcal.robot("kr1000titan")
    data = VirtualRobot(ti, [], seed=2).measure(random_poses(ti, 30, 7), seed=8)
    with pytest.raises(InputError, match="cannot come from"):
        torchcal.register(fitted, data)


def test_cli_register(ur10, tmp_path, capsys):
    from torchcal.cli import main

    rob, fitted, new, val = ur10
    write_json(tmp_path / "m.json", to_dict(fitted))
    write_measurements(tmp_path / "new.csv", new, robot=rob)
    write_measurements(tmp_path / "val.csv", moved(val), robot=rob)
    assert main(["register", str(tmp_path / "new.csv"), "--model", str(tmp_path / "m.json"),
                 "--out", str(tmp_path / "r.json")]) == 0
    old, obj = read_json(tmp_path / "m.json"), read_json(tmp_path / "r.json")
    for key in ("fit", "calibrated_range", "effects", "identifiability", "provenance"):
        assert obj[key] == old[key], key
    assert obj["registration"]["n"] == 30 and obj["registration"]["model"] == str(tmp_path / "m.json")
    capsys.readouterr()
    assert main(["evaluate", str(tmp_path / "val.csv"), "--model", str(tmp_path / "r.json")]) == 0
    rms = float(capsys.readouterr().out.split("rms ")[1].split()[0])
    assert rms < 2 * fitted.rms_mm
    # the original model on the moved data is refused, pointing at register
    assert main(["evaluate", str(tmp_path / "val.csv"), "--model", str(tmp_path / "m.json")]) == 2
    assert "torchcal register" in capsys.readouterr().err
    # registration only: nominal robot, best frame, no "implausible" lines
    assert main(["register", str(tmp_path / "new.csv"), "--robot", str(UR10), "--out",
                 str(tmp_path / "nom.json")]) == 0
    out = capsys.readouterr()
    assert "implausible" not in out.out + out.err
    nom = read_json(tmp_path / "nom.json")
    assert nom["effects"] == ["base_frame"] and nom["fit"]["n"] == 30


def test_a_registration_that_leaves_the_frame_undetermined_warns():
    """UR10 series D: a model of its odd rows registered with the tool on 100 even rows where
    joint 6 stands still put the frame 69 mm off (rms 0.36 mm on those rows, 45 mm on the
    session, exit 0, no word); the frame's own uncertainty over the model's calibration poses is far above 3x
    its training rms: one TransferWarning. On the 316 even rows, or without --tool on the
    100, it stays quiet."""
    import warnings

    from torchcal.calibration.registration import TransferWarning, frame_uncertainty
    from torchcal.io.measurement_csv import read_measurements

    rob = torchcal.robot(UR10)
    m = read_measurements(UR10.parent / "series_d.csv", robot=rob)
    fitted = torchcal.fit(rob, m.subset(slice(1, None, 2)), ["base_frame", "tool_offset"])
    even = m.subset(slice(0, None, 2))
    still = even.subset(slice(0, 100))
    assert float(still.q[:, 5].max() - still.q[:, 5].min()) < math.radians(1.0)  # joint 6 still
    with pytest.warns(TransferWarning, match=r"the registration on 100 rows leaves the measuring frame and tool "
                                             r"offset undetermined: .* uncertain by up to [0-9.]+ mm"):
        loose = torchcal.register(fitted, still, tool=True)
    assert float(frame_uncertainty(loose, fitted.seed_poses, tool=True).max()) > 3 * fitted.training_rms_mm
    with warnings.catch_warnings():
        warnings.simplefilter("error", TransferWarning)
        torchcal.register(fitted, even, tool=True)
        torchcal.register(fitted, still)


# ----------------------------------------------------------------------------- point ids
@pytest.fixture(scope="module")
def two_points(tmp_path_factory):
    """A UR5e fitted with tool_offset on point 1 (a reflector 60 mm off the flange), and
    data of point 2 (62 mm) and of point 1 again, as measurement CSVs with a point column."""
    from torchcal.measurements import Measurements

    d = tmp_path_factory.mktemp("points")
    rob = torchcal.robot("ur5e")
    for name, n, seed, z, pid in (("a", 40, 1, 60.0, 1), ("b", 30, 2, 62.0, 2), ("a2", 30, 3, 60.0, 1)):
        q = random_poses(rob, n, seed)
        tool = torch.eye(4, dtype=torch.float64)
        tool[:3, 3] = torch.tensor([0.0, 3.0, z], dtype=torch.float64)
        xyz = dataclasses.replace(rob, tool=rob.tool @ tool).fk(q)  # the reflector on the flange
        write_measurements(d / f"{name}.csv", Measurements(torch.arange(n), q, xyz,
                                                           point=torch.full((n,), pid, dtype=torch.int64)))
    assert main(["fit", str(d / "a.csv"), "--robot", "ur5e", "--effects", "tool_offset",
                              "--out", str(d / "a.json")]) == 0
    return d


def test_a_model_records_the_point_ids_it_was_fitted_on(two_points):
    d = two_points
    assert read_json(d / "a.json")["point_ids"] == [1]
    assert torchcal.load(d / "a.json").model.point_ids == (1,)
    old = read_json(d / "a.json")
    del old["point_ids"]  # a file of an older torchcal: read as before, nothing to check
    write_json(d / "old.json", old)
    with _no_point_warning():
        torchcal.evaluate(d / "old.json", d / "b.csv")


@contextlib.contextmanager
def _no_point_warning():
    """A PointIdWarning in the block is an error."""
    import warnings

    from torchcal.calibration.checks.model_data import PointIdWarning

    with warnings.catch_warnings():
        warnings.simplefilter("error", PointIdWarning)
        yield


def test_evaluate_on_another_point_warns_in_one_line(two_points, capsys):
    """Before: 2 mm rms on point 2's data in silence (the offset between the reflectors)."""
    d = two_points
    capsys.readouterr()
    assert main(["evaluate", str(d / "b.csv"), "--model", str(d / "a.json")]) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if "point id" in line]
    assert err == [f"torchcal: warning: {d / 'b.csv'}: point id(s) 2, but the model was fitted on the data of point "
                   "id(s) 1: its tool is that point's, so every row of another point is off by the distance between "
                   "the two (another reflector or nest?)"]
    with _no_point_warning():
        assert torchcal.evaluate(d / "a.json", d / "a2.csv").rms_mm < 1e-6


def test_register_on_another_point_needs_the_tool(two_points, capsys):
    d = two_points
    capsys.readouterr()
    out = d / "r.json"
    assert main(["register", str(d / "b.csv"), "--model", str(d / "a.json"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"torchcal register: error: {d / 'b.csv'}: point id(s) 2, but ")
    assert err.endswith("(another reflector or nest?); pass --tool\n") and not out.exists()
    with pytest.raises(InputError, match=r"point id\(s\) 2, .*; pass tool=True$"):
        torchcal.register(d / "a.json", d / "b.csv")
    assert main(["register", str(d / "b.csv"), "--model", str(d / "a.json"), "--tool",
                              "--out", str(out)]) == 0
    assert read_json(out)["point_ids"] == [2]
    with _no_point_warning():
        assert torchcal.evaluate(out, d / "b.csv").rms_mm < 1e-3


@pytest.fixture(scope="module")
def zoned(tmp_path_factory):
    """A per-zone model (`calibrate --partition`, base_frame) of a KR 1000 Titan with a joint
    compliance it does not hold, and 30 poses of a new set-up: the tracker turned and
    shifted by TURN, SHIFT (`moved`)."""
    from torchcal.io.sweep_csv import write_sweep
    from torchcal.reliability.sweep import sweep
    from torchcal.robots.workspace import sample_workspace

    d = tmp_path_factory.mktemp("zoned")
    kr = torchcal.robot("kr1000titan")
    write_sweep(sweep(kr, sample_workspace(kr, 60, seed=6), n_samples=50), d / "sweep.csv")
    assert main(["partition", str(d / "sweep.csv"), "--levels", "2", "--zones", "2,1",
                 "--out", str(d / "part.json")]) == 0
    real = VirtualRobot(kr, ["base_frame", "joint_compliance:2"], seed=4)
    write_measurements(d / "old.csv", real.measure(sample_workspace(kr, 40, seed=5), repeats=3, noise_mm=0.01))
    write_measurements(d / "new.csv", moved(real.measure(sample_workspace(kr, 30, seed=8), noise_mm=0.01)))
    assert main(["calibrate", str(d / "old.csv"), "--robot", "kr1000titan", "--effects", "base_frame",
                 "--partition", str(d / "part.json"), "--out", str(d / "zoned.json")]) == 0
    return d


def test_register_moves_every_zone_of_a_per_zone_model(zoned, capsys):
    """Every zone takes the global frame's rigid change (new <- old), checked against that
    change computed here from the two global frames: each zone predicts in the new frame
    what it predicted in the old, moved. Before, the API returned the global fit alone
    (the zones dropped) and the command kept the zones in the old frame (844 mm on the
    new set-up)."""
    from torchcal.calibration.zone_calibration import ZonedFit

    d = zoned
    old = torchcal.load(d / "zoned.json")
    assert main(["register", str(d / "new.csv"), "--model", str(d / "zoned.json"), "--out", str(d / "moved.json")]) == 0
    capsys.readouterr()
    new = torchcal.load(d / "moved.json")
    api = torchcal.register(old, d / "new.csv")
    assert isinstance(new, ZonedFit) and isinstance(api, ZonedFit) and len(new.zones) == len(old.zones) == 3
    (R0, t0), (R1, t1) = frame(old.model, old.theta), frame(new.model, new.theta)
    q = random_poses(old.model.robot, 50, 3)
    for a, b, c in zip(old.zones, new.zones, api.zones):
        ctx = torchcal.effects.context_of(old.model.robot, torchcal.measurements.Measurements(
            pose=torch.arange(50), q=q, xyz=torch.zeros(50, 3, dtype=torch.float64)))
        p_old, p_new = old.model.predict(a.theta, ctx), new.model.predict(b.theta, ctx)
        expect = (p_old - t0) @ (R1 @ R0.T).T + t1
        assert (p_new - expect).norm(dim=-1).max() < 1e-6
        assert torch.allclose(b.theta, c.theta, atol=1e-6)
    assert torchcal.evaluate(new, d / "new.csv").rms_mm < 1.0  # the joint compliance no zone holds: ~0.15 mm


def test_a_per_zone_model_without_a_base_frame_is_refused(zoned):
    """Its zones have no frame to move: one InputError naming what to calibrate with."""
    d = zoned
    bare = torchcal.calibrate("kr1000titan", d / "old.csv", partition=d / "part.json")
    with pytest.raises(InputError, match=r"^register: a per-zone model needs base_frame among its effects to be "
                                         r"moved to a new set-up \(its effects: none\); calibrate it with them$"):
        torchcal.register(bare, d / "new.csv")
