"""The virtual robot (torchcal.simulation.virtual_robot) and `torchcal simulate`.

- determinism by seed; different seeds differ;
- payload_kg present exactly when a payload-driven effect is there, temp_c exactly with
  thermal_expansion; payload within [0, rated];
- CSV round trip of a simulated session;
- the CLI: writes a file, refuses to overwrite without --force (exit 2, one line),
  same seed -> byte-identical file, --truth JSON, unknown effect -> exit 2, no file.
"""

import json
import math

import pytest
import torch
from torch.testing import assert_close

from torchcal.cli import main
from torchcal.effects import make_context
from torchcal.io.measurement_csv import read_measurements, write_measurements
from torchcal.simulation.virtual_robot import VirtualRobot, random_poses


def same(a, b):
    for name in ("pose", "q", "xyz", "payload_kg", "temp_c"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert torch.equal(x, y), name


def test_determinism_by_seed(kr):
    specs = ["joint_compliance:2,3", "thermal_expansion", "joint_clearance:2"]
    q = random_poses(kr, 12, 0)
    a = VirtualRobot(kr, specs, seed=5).measure(q, repeats=3, noise_mm=0.02)
    b = VirtualRobot(kr, specs, seed=5).measure(q, repeats=3, noise_mm=0.02)
    same(a, b)
    assert torch.equal(VirtualRobot(kr, specs, seed=5).theta, VirtualRobot(kr, specs, seed=5).theta)
    c = VirtualRobot(kr, specs, seed=6).measure(q, repeats=3, noise_mm=0.02)
    assert not torch.equal(a.xyz, c.xyz)
    assert not torch.equal(VirtualRobot(kr, specs, seed=5).theta, VirtualRobot(kr, specs, seed=6).theta)
    # an explicit measurement seed changes the draws, not the robot
    d = VirtualRobot(kr, specs, seed=5).measure(q, repeats=3, noise_mm=0.02, seed=99)
    assert not torch.equal(a.xyz, d.xyz)


def test_random_poses_deterministic_and_inside_limits(kr):
    a, b = random_poses(kr, 50, 3), random_poses(kr, 50, 3)
    assert torch.equal(a, b) and not torch.equal(a, random_poses(kr, 50, 4))
    assert kr.within_limits(a).all()
    assert (kr.fk(a)[:, 2] > 0).all()


@pytest.mark.parametrize("specs, payload, temp", [
    ([], False, False),
    (["base_frame", "tool_offset", "gear_periodic:1", "backlash:2", "encoder_scale:3"], False, False),
    (["joint_compliance:2"], True, False),
    (["joint_clearance:3"], True, False),
    (["thermal_expansion"], False, True),
    (["thermal_expansion", "joint_compliance:2,3"], True, True),
])
def test_session_columns(kr, specs, payload, temp):
    vr = VirtualRobot(kr, specs, seed=1)
    m = vr.measure(random_poses(kr, 10, 1), repeats=2, noise_mm=0.01)
    assert (m.payload_kg is not None) == payload
    assert (m.temp_c is not None) == temp
    if payload:
        assert (m.payload_kg >= 0).all() and (m.payload_kg <= kr.payload_kg).all()
        assert m.payload_kg.std() > 0.1 * kr.payload_kg  # varies across the session
        for p in m.pose.unique():  # one payload per pose (repeats carry the same load)
            assert m.payload_kg[m.pose == p].unique().numel() == 1
    if temp:
        assert 18 < m.temp_c.min() and m.temp_c.max() < 37
        assert m.temp_c[-5:].mean() - m.temp_c[:5].mean() > 10  # drifts over the session


def test_measure_rows_repeats_and_noise(kr):
    q = random_poses(kr, 8, 2)
    vr = VirtualRobot(kr, ["gear_periodic:2"], seed=2)
    m = vr.measure(q, repeats=4, noise_mm=0.0)
    assert len(m) == 32
    assert torch.equal(m.pose.bincount(), torch.full((8,), 4))
    assert_close(m.q, q[m.pose])
    exact = vr.model.predict(vr.theta, make_context(kr, m.q))
    assert_close(m.xyz, exact, rtol=0, atol=1e-9)
    noisy = vr.measure(q, repeats=50, noise_mm=0.05)
    err = noisy.xyz - vr.model.predict(vr.theta, make_context(kr, noisy.q))
    assert 0.04 < err.std() < 0.06


def test_csv_round_trip_of_simulated_session(kr, tmp_path):
    vr = VirtualRobot(kr, ["joint_compliance:2", "thermal_expansion"], seed=4)
    m = vr.measure(random_poses(kr, 15, 4), repeats=2, noise_mm=0.02)
    path = write_measurements(tmp_path / "s.csv", m)
    back = read_measurements(path, robot=kr)
    assert torch.equal(back.pose, m.pose)
    assert torch.equal(back.xyz, m.xyz) and torch.equal(back.payload_kg, m.payload_kg)
    assert torch.equal(back.temp_c, m.temp_c)
    assert_close(back.q, m.q, rtol=1e-14, atol=1e-14)
    write_measurements(tmp_path / "t.csv", back)
    assert (tmp_path / "t.csv").read_bytes() == path.read_bytes()


# -- the command line ------------------------------------------------------------------

ARGS = ["simulate", "--robot", "kr1000titan", "--effects", "joint_compliance:2,3", "thermal_expansion",
        "--n", "12", "--repeats", "2", "--noise", "0.02", "--seed", "7"]


def test_cli_simulate_writes_deterministic_file(kr, tmp_path, capsys):
    out, truth = tmp_path / "a.csv", tmp_path / "a.json"
    assert main(ARGS + ["--out", str(out), "--truth", str(truth)]) == 0
    summary = capsys.readouterr().out.strip()
    assert len(summary.splitlines()) == 1 and "24 rows" in summary and str(out) in summary
    m = read_measurements(out, robot=kr)
    assert len(m) == 24 and m.payload_kg is not None and m.temp_c is not None

    # same arguments -> byte-identical; --truth holds the virtual robot's parameters
    vr = VirtualRobot(kr, ["joint_compliance:2,3", "thermal_expansion"], seed=7)
    t = json.loads(truth.read_text())
    assert t["effects"] == ["joint_compliance:2,3", "thermal_expansion"] and t["seed"] == 7
    names, units = vr.model.param_names(), vr.model.param_units()
    assert set(t["parameters"]) == set(names)
    for n, u, v in zip(names, units, vr.theta.tolist()):  # degrees and mm, as MODEL.json
        want = {"rad": ("deg", math.degrees(v)), "rad/mm": ("deg/mm", math.degrees(v)),
                "rad/(kg mm)": ("deg/(N m)", math.degrees(v) / 9.80665e-3)}.get(u, (u, v))
        assert t["parameters"][n]["unit"] == want[0]
        assert t["parameters"][n]["value"] == pytest.approx(want[1], rel=1e-14, abs=1e-300)

    # a second run without --force: exit 2, one line, file untouched
    before = out.read_bytes()
    assert main(ARGS + ["--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--force" in err and "Traceback" not in err
    assert out.read_bytes() == before
    # --force replaces it with the same bytes (same seed)
    assert main(ARGS + ["--out", str(out), "--force"]) == 0
    assert out.read_bytes() == before
    other = tmp_path / "b.csv"
    assert main(ARGS + ["--out", str(other)]) == 0
    assert other.read_bytes() == before
    # a different seed, a different file
    assert main(ARGS[:-1] + ["8", "--out", str(tmp_path / "c.csv")]) == 0
    assert (tmp_path / "c.csv").read_bytes() != before


@pytest.mark.parametrize("bad, needle", [
    (["--effects", "joint_compliancee:2"], "unknown effect"),
    (["--effects", "backlash:9"], "out of range"),
    (["--effects", "thermal_expansion:1"], "takes no joints"),
    (["--robot", "nosuchbot"], "unknown robot"),
    (["--n", "0"], "positive integer"),
    (["--noise", "-1"], ">= 0"),
])
def test_cli_simulate_bad_input(tmp_path, capsys, bad, needle):
    out = tmp_path / "x.csv"
    args = ["simulate", "--n", "5", "--seed", "1", "--out", str(out)] + bad
    try:
        rc = main(args)
    except SystemExit as exc:  # argparse errors exit 2 through the parser
        rc = exc.code
    assert rc == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and needle in err and "Traceback" not in err
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_cli_simulate_missing_folder(tmp_path, capsys):
    out = tmp_path / "nope" / "x.csv"
    assert main(["simulate", "--n", "3", "--out", str(out)]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_effect_sizes_per_effect():
    """effect_mm as a dict sizes each effect separately: doubling one effect's size doubles
    its parameters (same seed) and leaves the other's unchanged."""
    import torch

    from torchcal.io.robot_file import robot
    from torchcal.simulation.virtual_robot import VirtualRobot

    r = robot("kr1000titan")
    specs = ["gear_periodic:2", "joint_compliance:2"]
    a = VirtualRobot(r, specs, seed=3, effect_mm={"gear_periodic": 0.5, "joint_compliance": 1.0})
    b = VirtualRobot(r, specs, seed=3, effect_mm={"gear_periodic:2": 1.0, "joint_compliance": 1.0})
    gear, comp = a.model.slices[1], a.model.slices[2]
    torch.testing.assert_close(b.theta[gear], 2 * a.theta[gear])
    torch.testing.assert_close(b.theta[comp], a.theta[comp])
    c = VirtualRobot(r, specs, seed=3, effect_mm=0.5)  # one size for all, as before
    torch.testing.assert_close(c.theta[gear], a.theta[gear])
