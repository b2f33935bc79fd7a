"""`torchcal split`: a split by pose whose files carry the approach each row had in the
whole session (prev_q columns), so a split file reads exactly as its rows did in memory;
bad input is refused with one line, nothing written."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

import torchcal
from torchcal.calibration.fit import fit
from torchcal.calibration.model import CalibrationModel
from torchcal.cli import main
from torchcal.effects import context_of
from torchcal.errors import InputError
from torchcal.io.measurement_csv import read_measurements, write_measurements
from torchcal.measurements import previous_angles, split_by_pose
from torchcal.robots.poses import random_poses
from torchcal.simulation.virtual_robot import VirtualRobot


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """A kr1000titan session with backlash on joints 2 and 3 (in the model) and geometric
    errors, 70 poses measured twice in random order, as one CSV."""
    robot = torchcal.robot("kr1000titan")
    vr = VirtualRobot(robot, ["backlash:2,3"], seed=3)
    m = vr.measure(random_poses(robot, 70, torch.Generator().manual_seed(5)), repeats=2, noise_mm=0.01, seed=7)
    path = tmp_path_factory.mktemp("split") / "session.csv"
    write_measurements(path, m)
    return robot, path


def _fit_and_errors(robot, train, val):
    """Backlash model fitted on `train`; (N_val, 3) mm residuals on `val`."""
    model = CalibrationModel(robot, ["base_frame", "backlash:2,3"])
    res = fit(model, context_of(robot, train), train.xyz)
    with torch.no_grad():
        return val.xyz - model.predict(res.theta, context_of(robot, val))


def test_split_files_read_as_the_rows_did_in_memory(session, tmp_path, capsys):
    robot, path = session
    tr, va = tmp_path / "tr.csv", tmp_path / "va.csv"
    assert main(["split", str(path), "--fraction", "0.6", "--seed", "2", "--out", str(tr), str(va)]) == 0
    assert f"wrote {tr}" in capsys.readouterr().out
    whole = read_measurements(path)
    keep = split_by_pose(whole.pose, 0.6, 2)
    mem_tr, mem_va = whole.subset(keep), whole.subset(~keep)
    f_tr, f_va = read_measurements(tr), read_measurements(va)
    assert torch.equal(f_tr.pose, mem_tr.pose) and torch.equal(f_va.pose, mem_va.pose)
    assert not set(f_tr.pose.tolist()) & set(f_va.pose.tolist())  # whole poses on one side
    torch.testing.assert_close(f_va.q_prev, mem_va.q_prev, rtol=1e-14, atol=1e-14)
    e_mem = _fit_and_errors(robot, mem_tr, mem_va)
    e_file = _fit_and_errors(robot, f_tr, f_va)
    assert float((e_file - e_mem).norm(dim=-1).max()) < 1e-9  # mm
    # the check can fail: the same rows without the approach columns (a plain row split)
    plain = tmp_path / "plain.csv"
    write_measurements(plain, f_va)  # no prev_q columns: q_prev from the file's own order
    e_plain = _fit_and_errors(robot, f_tr, read_measurements(plain))
    assert float((e_plain - e_mem).norm(dim=-1).max()) > 1e-3


def test_prev_columns_round_trip_and_are_checked(session, tmp_path):
    robot, path = session
    m = read_measurements(path)
    torch.testing.assert_close(m.q_prev, previous_angles(m.q))  # no columns: the file's order
    sub = m.subset(slice(1, None, 3))
    write_measurements(tmp_path / "s.csv", sub, approach=True)
    back = read_measurements(tmp_path / "s.csv")
    torch.testing.assert_close(back.q_prev, sub.q_prev, rtol=1e-14, atol=1e-14)
    text = (tmp_path / "s.csv").read_text().splitlines()
    cut = [",".join(r.split(",")[:-1]) for r in text]  # drop prev_q6
    (tmp_path / "cut.csv").write_text("\n".join(cut) + "\n")
    with pytest.raises(InputError, match="missing column prev_q6"):
        read_measurements(tmp_path / "cut.csv")


def test_split_by_pose_is_the_seeded_permutation_of_pose_ids():
    pose = torch.tensor([4, 4, 1, 9, 1, 7, 2, 9, 3, 3])
    keep = split_by_pose(pose, 0.4, 11)
    ids = np.random.default_rng(11).permutation(np.unique(pose.numpy()))[:2]  # round(0.4 * 6) = 2
    assert set(pose[keep].tolist()) == set(ids.tolist())
    with pytest.raises(InputError, match="no validation pose"):
        split_by_pose(pose, 0.95, 0)


@pytest.mark.parametrize("args, message", [
    (["--fraction", "1"], "--fraction 1.0: expected a share"),
    (["--fraction", "0"], "--fraction 0.0: expected a share"),
    (["--fraction", "-0.2"], "--fraction -0.2: expected a share"),
])
def test_split_refuses_a_fraction_outside_0_1(session, tmp_path, capsys, args, message):
    _, path = session
    assert main(["split", str(path), *args, "--out", str(tmp_path / "a.csv"), str(tmp_path / "b.csv")]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())


def test_split_refuses_bad_outputs_and_columns(session, tmp_path, capsys):
    _, path = session
    before = Path(path).read_bytes()
    assert main(["split", str(path), "--out", str(tmp_path / "a.csv"), str(path)]) == 2
    assert "names the input file" in capsys.readouterr().err
    assert Path(path).read_bytes() == before
    assert main(["split", str(path), "--out", str(tmp_path / "a.csv"), str(tmp_path / "a.csv")]) == 2
    assert "name the same file" in capsys.readouterr().err
    bad = tmp_path / "bad.csv"
    bad.write_text("pose,q1,q2,x,y\n1,2,3,4,5\n")
    assert main(["split", str(bad), "--out", str(tmp_path / "a.csv"), str(tmp_path / "b.csv")]) == 2
    err = capsys.readouterr().err
    assert "missing column z" in err and len(err.strip().splitlines()) == 1
    (tmp_path / "b.csv").write_text("keep\n")
    assert main(["split", str(path), "--out", str(tmp_path / "a.csv"), str(tmp_path / "b.csv")]) == 2
    assert "--force" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.csv", "bad.csv"]
    assert (tmp_path / "b.csv").read_text() == "keep\n"


def test_an_interrupted_split_leaves_neither_file(session, tmp_path, capsys, monkeypatch):
    """Ctrl-C (or a full disk) while the second file is written: the first used to stay
    behind, and the rerun then needed --force; now neither is left, and the rerun works."""
    import torchcal.io.measurement_csv as mc

    _, path = session
    real, calls = mc.write_measurements, []

    def interrupted(p, *a, **kw):
        calls.append(p)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(p, *a, **kw)

    monkeypatch.setattr(mc, "write_measurements", interrupted)
    outs = [str(tmp_path / "a.csv"), str(tmp_path / "b.csv")]
    assert main(["split", str(path), "--fraction", "0.5", "--out", *outs]) == 130
    assert len(calls) == 2 and not any(Path(p).exists() for p in outs)
    assert capsys.readouterr().err == "torchcal: interrupted\n"
    monkeypatch.setattr(mc, "write_measurements", real)
    assert main(["split", str(path), "--fraction", "0.5", "--out", *outs]) == 0
    assert all(Path(p).is_file() for p in outs)


def test_a_side_of_few_poses_is_named(session, tmp_path, capsys):
    """70 poses at --fraction 0.95: 4 validation poses, named in one warning (and the counts
    spelt as counts); at 0.6 (28 validation poses) no warning."""
    _, path = session
    outs = [str(tmp_path / "a.csv"), str(tmp_path / "b.csv")]
    assert main(["split", str(path), "--fraction", "0.95", "--out", *outs]) == 0
    cap = capsys.readouterr()
    assert "(4 poses, 8 rows)" in cap.out
    assert cap.err.count("warning") == 1 and f"the validation file {outs[1]} holds 4 poses" in cap.err
    assert main(["split", str(path), "--fraction", "0.6", "--out", *outs, "--force"]) == 0
    assert "warning" not in capsys.readouterr().err
