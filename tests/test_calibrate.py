"""`torchcal calibrate --partition`: the partition must be made for the given robot.

A partition (and the sweep it was made from) records the robot it was made for; calibrate
refuses another robot's, or one of other joint limits, with one line (exit 2, nothing
written), takes the same robot from another file, and reads a partition file of an older
torchcal (no record) with one warning and the same result as a recorded one."""

import json
import re
import warnings

import pytest
import torch

import torchcal
from torchcal import cli
from torchcal.io.robot_file import robot_fingerprint, robot_to_dict


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A sweep and partition of the KR 1000 Titan (`torchcal partition`), and repeated
    measurements of it and of a UR5e (virtual robots with a base frame)."""
    from torchcal.io.measurement_csv import write_measurements
    from torchcal.io.sweep_csv import write_sweep
    from torchcal.reliability.sweep import sweep
    from torchcal.robots.workspace import sample_workspace
    from torchcal.simulation.virtual_robot import VirtualRobot

    d = tmp_path_factory.mktemp("calibrate")
    kr = torchcal.robot("kr1000titan")
    write_sweep(sweep(kr, sample_workspace(kr, 60, seed=6), n_samples=50), d / "sweep.csv")
    assert cli.main(["partition", str(d / "sweep.csv"), "--levels", "2", "--zones", "2,1",
                     "--out", str(d / "part.json")]) == 0
    for name, seed in (("kr1000titan", 4), ("ur5e", 5)):
        r = torchcal.robot(name)
        vr = VirtualRobot(r, ["base_frame"], seed=seed)
        write_measurements(d / f"{name}.csv", vr.measure(sample_workspace(r, 30, seed=seed + 1), repeats=3,
                                                         noise_mm=0.01))
    return d


def _calibrate(d, data, robot, partition, out):
    return cli.main(["calibrate", str(d / data), "--robot", str(robot), "--effects", "base_frame",
                     "--partition", str(partition), "--out", str(out)])


def test_a_partition_of_another_robot_is_refused(session, capsys):
    d = session
    out = d / "ur5e_zones.json"
    assert _calibrate(d, "ur5e.csv", "ur5e", d / "part.json", out) == 2
    err = capsys.readouterr().err
    kr, ur = (robot_fingerprint(torchcal.robot(n)) for n in ("kr1000titan", "ur5e"))
    assert err.count("\n") == 1 and err.startswith(
        f"torchcal calibrate: error: {d / 'part.json'}: made for robot 'kr1000titan' (fingerprint {kr[:12]}), "
        f"not 'ur5e' (fingerprint {ur[:12]}): the MD-H table differs at joint(s) ")
    assert err.endswith("; make the sweep and partition again for this robot\n")
    assert not out.exists()


def test_the_same_robot_with_other_joint_limits_is_refused(session, capsys):
    d = session
    robot = robot_to_dict(torchcal.robot("kr1000titan"))
    robot["joints"][0]["lower"], robot["joints"][0]["upper"] = -170.0, 170.0
    (d / "kr_wide.json").write_text(json.dumps(robot))
    out = d / "wide_zones.json"
    assert _calibrate(d, "kr1000titan.csv", d / "kr_wide.json", d / "part.json", out) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith(f"torchcal calibrate: error: {d / 'part.json'}: made for robot 'kr1000titan' ")
    assert "not 'kr1000titan' (fingerprint " in err
    assert ": joint 1 limits -150..150 deg in the file, -170..170 deg given; make the sweep and partition" in err
    assert not out.exists()


def test_a_matching_partition_and_an_old_one_give_the_same_model(session, capsys):
    """The recorded partition with the robot it was made for (as a preset, and as a robot
    file of another name), and the same partition as a file of an older torchcal (version
    1, no record: one warning), give the same model and the same printed table."""
    d = session
    runs = {}
    robot_file = dict(robot_to_dict(torchcal.robot("kr1000titan")), name="titan_cell_3")
    (d / "titan.json").write_text(json.dumps(robot_file))
    old = json.loads((d / "part.json").read_text())
    assert old.pop("made_for")["name"] == "kr1000titan"
    (d / "part_v1.json").write_text(json.dumps(dict(old, version=1)))
    for key, robot, part in (("preset", "kr1000titan", "part.json"), ("file", d / "titan.json", "part.json"),
                             ("old", "kr1000titan", "part_v1.json")):
        out = d / f"zones_{key}.json"
        assert _calibrate(d, "kr1000titan.csv", robot, d / part, out) == 0
        cap = capsys.readouterr()
        model = json.loads(out.read_text())
        model["provenance"].pop("partition")
        model["partition"].pop("made_for")  # the partition's record, embedded as the file has it (none in v1)
        del model["nominal_robot"]["name"], model["robot"]
        runs[key] = (model, cap.out.replace(str(out), "OUT").replace("titan_cell_3", "kr1000titan"), cap.err)
    damped = "torchcal: warning: zone 1, zone 2, zone 3: the damping shared by the zones chosen by GCV is 10, the top "
    assert runs["preset"][2] == runs["file"][2] and runs["preset"][2].startswith(damped)  # zones as global: a word
    assert runs["preset"][2].count("\n") == 1
    assert runs["old"][2] == (f"torchcal: warning: {d / 'part_v1.json'}: records no robot (a file of an older "
                              f"torchcal, or made from one): could not check that it was made for robot "
                              f"'kr1000titan'\n") + runs["preset"][2]
    assert runs["preset"][:2] == runs["file"][:2] == runs["old"][:2]
    assert len(runs["old"][0]["zones"]) == 3 and "zone level poses" in runs["old"][1]


def _in_memory_partition(robot_name, seed=1):
    """A partition built in memory (no record) of 40 workspace points of `robot_name`."""
    import torch

    from torchcal.partition.zones import partition_workspace
    from torchcal.robots.workspace import sample_workspace

    rob = torchcal.robot(robot_name)
    r = torch.rand(40, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    return partition_workspace(rob.fk(sample_workspace(rob, 40, seed=seed)), r, levels=2, zones=[2, 1], seed=0)


@pytest.mark.parametrize("part_of, data_of, words", [
    ("kr1000titan", "ur5e", "partition: 39 of its 40 sweep points lie beyond the reach of robot 'ur5e'"),
    ("ur5e", "kr1000titan", "partition: the calibration poses of robot 'kr1000titan' lie a median ")])
def test_a_partition_in_memory_of_another_robot_is_refused(session, part_of, data_of, words):
    """torchcal.calibrate(partition=Partition) without a record: judged by its geometry
    (before: zones of another robot's workspace assigned in silence)."""
    from torchcal.errors import InputError

    with pytest.raises(InputError, match=re.escape(words)) as info:
        torchcal.calibrate(data_of, session / f"{data_of}.csv", ["base_frame"], partition=_in_memory_partition(part_of))
    assert "another robot" in str(info.value) and "\n" not in str(info.value)


def test_a_partition_object_keeps_its_record_and_a_matching_one_passes(session):
    """A Partition read from a file carries the file's record (made_for), checked by
    torchcal.calibrate as the path is; the robot's own partition in memory passes."""
    from torchcal.errors import InputError
    from torchcal.io.partition_file import load_partition

    part = load_partition(session / "part.json")
    assert part.made_for["name"] == "kr1000titan"
    from torchcal.io.partition_file import save_partition
    save_partition(part, session / "part_again.json")  # saved back: the record stays
    assert load_partition(session / "part_again.json").made_for == part.made_for
    with pytest.raises(InputError, match=r"^partition: made for robot 'kr1000titan' .*, not 'ur5e' "):
        torchcal.calibrate("ur5e", session / "ur5e.csv", ["base_frame"], partition=part)
    with pytest.raises(InputError, match="partition: expected a Partition, a PARTITION.json path or None, got dict"):
        torchcal.calibrate("ur5e", session / "ur5e.csv", ["base_frame"], partition={"zones": 3})
    from torchcal.calibration.gcv import DampingWarning

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.simplefilter("ignore", DampingWarning)  # zones of data without zone-dependent errors
        res = torchcal.calibrate("kr1000titan", session / "kr1000titan.csv", ["base_frame"],
                                 partition=_in_memory_partition("kr1000titan", seed=9))
    assert res.partition.n_zones == 3 and sum(res.zone_poses) == 30


def test_a_partition_in_memory_builds_its_sweep_tree_once(session, monkeypatch):
    """The geometry check of a partition without a record and the swept-region warning
    query one KD-tree of its sweep points (before: each built its own), with the same
    result as a tree of their own."""
    import math

    import scipy.spatial
    import torch

    built = []

    class Counting(scipy.spatial.cKDTree):
        def __init__(self, data, *a, **k):
            built.append(len(data))
            super().__init__(data, *a, **k)

    monkeypatch.setattr(scipy.spatial, "cKDTree", Counting)
    part = _in_memory_partition("kr1000titan", seed=9)
    torchcal.calibrate("kr1000titan", session / "kr1000titan.csv", ["base_frame"], partition=part)
    assert built == [40]
    q = torch.tensor([[0.1, -0.2, 0.3, 0.0, 0.5, 0.0], [1.0, 0.4, -0.3, 0.2, 0.1, 0.0]], dtype=torch.float64)
    p = torchcal.robot("kr1000titan").fk(q)
    spacing, near = part.nearest_sweep(p)
    d = torch.cdist(part.positions, part.positions) + torch.diag(torch.full((40,), math.inf, dtype=torch.float64))
    assert spacing == pytest.approx(float(d.min(dim=1).values.median()), rel=1e-12)
    torch.testing.assert_close(near, torch.cdist(p, part.positions).min(dim=1).values, rtol=1e-12, atol=1e-9)
    assert built == [40]


def test_an_interval_calibration_records_its_point_id(tmp_path):
    """calibrate of data of one point id records it in MODEL.json, as fit does (before: not
    recorded, so a model of reflector 4 was used on reflector 5's data in silence)."""
    import dataclasses

    import torch

    from torchcal.robots.poses import random_poses
    from torchcal.simulation.virtual_robot import VirtualRobot

    rob = torchcal.robot("ur5e")
    m = VirtualRobot(rob, ["base_frame"], seed=6).measure(random_poses(rob, 20, 6), repeats=3, seed=7)
    m = dataclasses.replace(m, point=torch.full((len(m),), 4, dtype=torch.int64))
    torchcal.save(torchcal.calibrate(rob, m, ["base_frame"]), tmp_path / "m.json")
    assert json.loads((tmp_path / "m.json").read_text())["point_ids"] == [4]


@pytest.mark.parametrize("how", ["fit", "calibrate"])
def test_a_model_refitted_on_another_points_data_records_the_new_id(how):
    """A fitted model given back to fit / calibrate with the data of another point id is
    refitted for that point: the result records (and checks against) the new id, so the
    model of reflector 5 is not called the model of reflector 4 (before: the old id was
    kept, and evaluating the refit on reflector 5's own data warned of another point)."""
    import dataclasses

    import torch

    from torchcal.robots.poses import random_poses
    from torchcal.simulation.virtual_robot import VirtualRobot

    rob = torchcal.robot("ur5e")
    m = VirtualRobot(rob, ["base_frame"], seed=6).measure(random_poses(rob, 20, 6), repeats=3, seed=7)
    on = {p: dataclasses.replace(m, point=torch.full((len(m),), p, dtype=torch.int64)) for p in (4, 5)}
    run = getattr(torchcal, how)
    first = run(rob, on[4], ["base_frame"])
    again = run(first, on[5])
    assert first.model.point_ids == (4,) and again.model.point_ids == (5,)
    assert torch.allclose(again.theta, first.theta, atol=1e-9)  # the same data otherwise: the same fit
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        torchcal.evaluate(again, on[5])


def _thermal_repeats(rob, n, lo, hi, seed, repeats=3):
    """n poses of `rob`, each measured `repeats` times at one temperature drawn in
    [lo, hi] degC; hidden physics: npsim.thermal_session (plain numpy link growth)."""
    import numpy as np
    import torch

    from npsim import thermal_session
    from torchcal.measurements import Measurements
    from torchcal.robots.poses import random_poses

    q = random_poses(rob, n, seed).repeat_interleave(repeats, dim=0)
    temp = np.repeat(np.random.default_rng(seed + 100).uniform(lo, hi, n), repeats)
    xyz = thermal_session(rob, q.numpy(), temp, seed=7, noise_mm=0.005)
    return Measurements(torch.arange(n).repeat_interleave(repeats), q, torch.from_numpy(xyz),
                        temp_c=torch.from_numpy(temp))


@pytest.mark.parametrize("zoned", [False, True])
def test_an_interval_calibration_records_its_conditions_and_warns_outside(zoned, tmp_path):
    """calibrate records the temperature range its thermal effect was fitted on, as fit
    does (MODEL.json calibrated_conditions), and evaluate / compensate of the loaded model
    warn outside it (before: not recorded, so a per-zone model fitted at 18..26 degC was
    used at 45 degC in silence)."""
    import torch

    from torchcal.calibration.joint_range import ConditionRangeWarning
    from torchcal.measurements import Measurements

    rob = torchcal.robot("ur5e")
    m = _thermal_repeats(rob, 40, 18.0, 26.0, seed=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = torchcal.calibrate(rob, m, ["thermal_expansion"],
                                 partition=_in_memory_partition("ur5e") if zoned else None)
    lo, hi = float(m.temp_c.min()), float(m.temp_c.max())
    assert res.conditions == {"temp_c": [lo, hi]}
    torchcal.save(res, tmp_path / "m.json")
    assert json.loads((tmp_path / "m.json").read_text())["calibrated_conditions"] == {"temp_c": [lo, hi]}
    back = torchcal.load(tmp_path / "m.json")
    assert back.conditions == res.conditions
    hot = Measurements(m.pose, m.q, m.xyz, temp_c=m.temp_c + 20.0)
    for fn, words in ((lambda: torchcal.evaluate(back, hot), f"of {len(m)} rows outside the fitted"),
                      (lambda: torchcal.compensate(back, rob.fk(m.q[:4]).detach(), temp_c=torch.full((4,), 45.0)),
                       "temperature of 4 of 4 targets")):
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            fn()
        msgs = [str(x.message) for x in w if issubclass(x.category, ConditionRangeWarning)]
        assert len(msgs) == 1 and words in msgs[0], msgs


def test_independent_zones_with_an_empty_zone_name_the_file_and_the_counts(session, capsys, monkeypatch):
    """--zone-method independent where the partition sends no pose to a zone: one line naming
    the data file, the empty zone and the poses per zone (before: 'zone(s) [2] have no
    poses ...', no file, no counts); nothing written. The damped method keeps the global
    values there and passes."""
    from torchcal.partition.zones import Partition

    def all_in_zone_1(self, points):
        return torch.ones(len(points), dtype=torch.int64)

    monkeypatch.setattr(Partition, "assign", all_in_zone_1)
    out = session / "independent.json"
    assert cli.main(["calibrate", str(session / "kr1000titan.csv"), "--robot", "kr1000titan", "--effects",
                     "base_frame", "--partition", str(session / "part.json"), "--zone-method", "independent",
                     "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert (f"{session / 'kr1000titan.csv'}: zones 2, 3 of the partition have no poses (poses per zone: "
            f"zone 1: 30, zone 2: 0, zone 3: 0)") in err, err
    assert not out.exists()
    res = torchcal.calibrate("kr1000titan", session / "kr1000titan.csv", ["base_frame"], partition=session / "part.json")
    assert res.zone_poses == [30, 0, 0]


def test_cli_calibrate_names_an_effect_the_data_cannot_identify(tmp_path, capsys):
    """`torchcal calibrate --effects thermal_expansion` on repeats at one temperature (plain
    numpy, tests/npsim.py): its parameters were listed among the held ones only; one line
    now says the effect changes nothing and why."""
    from npsim import thermal_session
    from torchcal.cli import main
    from torchcal.io.measurement_csv import write_measurements
    from torchcal.measurements import Measurements
    from torchcal.robots.poses import random_poses

    ur = torchcal.robot("ur5e")
    q = random_poses(ur, 20, 3).repeat_interleave(2, 0)
    t = torch.full((40,), 25.0, dtype=torch.float64)
    m = Measurements(torch.arange(20).repeat_interleave(2), q,
                     torch.from_numpy(thermal_session(ur, q.numpy(), t.numpy(), 1)), temp_c=t)
    write_measurements(tmp_path / "d.csv", m, robot=ur)
    assert main(["calibrate", str(tmp_path / "d.csv"), "--robot", "ur5e", "--effects", "thermal_expansion",
                 "--out", str(tmp_path / "m.json")]) == 0
    assert ("thermal_expansion: none of its parameters is identifiable from these data (all held at nominal: "
            "temp_c is 25 degC on every row): it changes nothing") in capsys.readouterr().out.splitlines()
