"""Command-line edges a new user meets: inputs never written over, notes in robot files,
a URDF given as --robot, argparse errors naming the sub-command, a closed pipe, a quiet
URDF parser, outputs checked before the work, fresh poses of the same simulated robot,
the --robust hint."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

import torchcal
from torchcal.cli import main
from torchcal.errors import InputError
from torchcal.io.robot_file import load_robot_file, robot_to_dict

ROOT = Path(__file__).resolve().parents[1]


def _robot_file(tmp_path, **extra) -> Path:
    obj = robot_to_dict(torchcal.robot("ur5e"))
    obj.update(extra)
    p = tmp_path / "r.json"
    p.write_text(json.dumps(obj))
    return p


def test_robot_file_accepts_notes_and_x_keys(tmp_path):
    obj = robot_to_dict(torchcal.robot("ur5e"))
    obj.update(notes="measured 2026-01-02", source="data sheet rev 3", x_owner={"team": "cell 4"})
    obj["joints"][1]["x_serial"] = "A123"
    obj["joints"][2]["notes"] = "replaced gearbox"
    p = tmp_path / "r.json"
    p.write_text(json.dumps(obj))
    assert load_robot_file(p).same_geometry(torchcal.robot("ur5e"))
    obj["colour"] = "red"  # not a notes key: still a typo to refuse
    p.write_text(json.dumps(obj))
    with pytest.raises(InputError, match="unknown key.s. colour.*x_"):
        load_robot_file(p)


def test_urdf_as_robot_hints_at_robot_import(tmp_path, capsys):
    u = tmp_path / "arm.urdf"
    u.write_text('<?xml version="1.0"?><robot name="arm"><link name="a"/></robot>')
    assert main(["simulate", "--robot", str(u), "--n", "3", "--out", str(tmp_path / "d.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "torchcal robot import" in err and "Expecting value" not in err
    x = tmp_path / "arm_urdf.json"  # XML under a .json name: the same hint
    x.write_text(u.read_text())
    with pytest.raises(InputError, match="robot import"):
        load_robot_file(x)


@pytest.mark.parametrize("command, over", [("fit", "robot"), ("simulate", "robot"), ("simulate", "urdf"),
                                           ("plan", "urdf")])
def test_no_command_writes_over_its_robot_file_or_the_urdf(tmp_path, capsys, command, over):
    """--out naming the robot file (or the URDF it was imported from) is refused, even with
    --force, in one line; both files are left as they were."""
    from torchcal.io.urdf import minimal_urdf

    src = tmp_path / "arm.urdf"
    src.write_text(minimal_urdf(torchcal.robot("ur5e")))
    robot = tmp_path / "arm.json"
    assert main(["robot", "import", str(src), "--base", "base_link", "--tip", "tool0", "--out", str(robot)]) == 0
    data = tmp_path / "d.csv"
    assert main(["simulate", "--robot", str(robot), "--n", "20", "--seed", "1", "--out", str(data)]) == 0
    before = {p: p.read_bytes() for p in (src, robot)}
    out = str(robot if over == "robot" else src)
    argv = {"fit": ["fit", str(data), "--robot", str(robot)],
            "simulate": ["simulate", "--robot", str(robot), "--n", "10", "--seed", "1"],
            "plan": ["plan", "--robot", str(robot), "--n", "10", "--candidates", "50"]}[command]
    capsys.readouterr()
    assert main([*argv, "--out", out, "--force"]) == 2
    err = capsys.readouterr().err
    assert "names the input file" in err and "refusing to write over it" in err and err.count("\n") == 1
    assert all(p.read_bytes() == b for p, b in before.items())


@pytest.mark.parametrize("argv, prog", [
    (["fit", "d.csv", "--robot"], "torchcal fit: error:"),
    (["evaluate", "d.csv", "--model", "m.json", "--bogus"], "torchcal evaluate: error:"),
    (["simulate", "--n", "0", "--out", "x.csv"], "torchcal simulate: error:"),
    (["nosuch"], "torchcal: error:"),
])
def test_argparse_errors_name_the_sub_command(argv, prog, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(prog) and len(err.strip().splitlines()) == 1


def test_closed_stdout_ends_quietly(tmp_path):
    """`torchcal ... | head`: the reader has gone before the command prints; no error line,
    the command's own exit status, and its files are written."""
    out = tmp_path / "d.csv"
    env = {"PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"}
    p = subprocess.Popen([sys.executable, "-m", "torchcal", "simulate", "--robot", "ur5e", "--n", "5",
                          "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    p.stdout.close()  # as `head` does once it has its lines
    err = p.stderr.read().decode()
    assert p.wait() == 0 and err == "" and out.is_file()


def test_urdf_import_prints_nothing_of_the_parser(tmp_path, capfd):
    from torchcal.io.urdf import robot_from_urdf

    links = "".join(f'<link name="l{k}"><visual><geometry><box size="1 1 1"/></geometry></visual>'
                    f'<gazebo_thing foo="1"/></link>' for k in range(3))
    joints = "".join(f'<joint name="j{k}" type="revolute" bar="2"><parent link="l{k - 1}"/><child link="l{k}"/>'
                     f'<origin xyz="0 0 0.3" rpy="0 0 0"/><axis xyz="0 1 0"/>'
                     f'<limit lower="-1" upper="1" effort="1" velocity="1"/><dynamics damping="0.1"/></joint>'
                     for k in (1, 2))
    u = tmp_path / "a.urdf"
    u.write_text(f'<?xml version="1.0"?><robot name="a">{links}{joints}<ros2_control name="x"/></robot>')
    robot = robot_from_urdf(u, "l0", "l2")
    out, err = capfd.readouterr()
    assert robot.n == 2 and out == "" and err == ""


def test_simulate_pose_seed_fresh_poses_of_the_same_robot(tmp_path, capsys):
    def sim(name, *extra, seed="3"):
        out, truth = tmp_path / f"{name}.csv", tmp_path / f"{name}.json"
        assert main(["simulate", "--robot", "ur5e", "--effects", "joint_compliance:2", "--n", "15", "--seed", seed,
                     *extra, "--out", str(out), "--truth", str(truth)]) == 0
        return out.read_text(), json.loads(truth.read_text())
    a, ta = sim("a")
    b, tb = sim("b", "--pose-seed", "9")
    same, _ = sim("same", "--pose-seed", "3")
    c, tc = sim("c", seed="4")  # another robot
    assert same == a  # --pose-seed = --seed: the file without it, byte for byte
    assert ta["parameters"] == tb["parameters"] != tc["parameters"]  # the same hidden robot
    qa = {line.split(",")[1] for line in a.splitlines()[1:]}
    qb = {line.split(",")[1] for line in b.splitlines()[1:]}
    assert a.splitlines()[0] == b.splitlines()[0] and not qa & qb  # fresh poses


def test_plan_and_accuracy_refuse_existing_pngs_before_any_work(tmp_path, capsys, monkeypatch):
    import torchcal.planning.design as design
    import torchcal.reliability.sweep_blocks as sweep_blocks

    def boom(*a, **k):
        raise AssertionError("computed before checking the outputs")
    monkeypatch.setattr(design, "candidate_jacobian", boom)
    monkeypatch.setattr(sweep_blocks, "sample_workspace", boom)
    plots = tmp_path / "plots"
    plots.mkdir()
    (plots / "plan_criterion.png").write_bytes(b"old")
    out = tmp_path / "poses.csv"
    assert main(["plan", "--robot", "ur5e", "--n", "10", "--out", str(out), "--plots", str(plots)]) == 2
    err = capsys.readouterr().err
    assert "plan_criterion.png" in err and "--force" in err and not out.exists()
    (plots / "accuracy_hist.png").write_bytes(b"old")
    assert main(["accuracy", str(tmp_path / "model.json"), "--plots", str(plots)]) == 2
    err = capsys.readouterr().err
    assert "accuracy_hist.png" in err and "--force" in err
    new = tmp_path / "new" / "plots"  # a missing --plots folder is made, as before
    assert main(["accuracy", str(tmp_path / "model.json"), "--plots", str(new)]) == 2
    assert "model file does not exist" in capsys.readouterr().err and new.is_dir()


def test_a_few_corrupted_rows_hint_at_robust(tmp_path, capsys):
    data = tmp_path / "d.csv"
    assert main(["simulate", "--robot", "ur5e", "--n", "60", "--seed", "2", "--out", str(data)]) == 0
    lines = data.read_text().splitlines()
    bad = lines[:]
    for i in (7, 33):  # two rows with a corrupted x (a slipped digit)
        cells = bad[i].split(",")
        cells[7] = repr(float(cells[7]) + 500.0)
        bad[i] = ",".join(cells)
    (tmp_path / "bad.csv").write_text("\n".join(bad) + "\n")
    capsys.readouterr()
    assert main(["fit", str(data), "--robot", "ur5e", "--out", str(tmp_path / "m1.json")]) == 0
    assert "--robust" not in capsys.readouterr().out
    # 500 mm off: gross rows (beyond 10 mm of the nominal robot) are refused, naming them
    assert main(["fit", str(tmp_path / "bad.csv"), "--robot", "ur5e", "--out", str(tmp_path / "m2.json")]) == 2
    err = capsys.readouterr().err
    assert "2 of 60 rows (pose ids 6, 32)" in err and err.rstrip().endswith("pass --robust huber")
    assert not (tmp_path / "m2.json").exists()
    assert main(["fit", str(tmp_path / "bad.csv"), "--robot", "ur5e", "--robust", "huber",
                 "--out", str(tmp_path / "m3.json")]) == 0
    assert "try --robust" not in capsys.readouterr().out


def test_progress_bars_stay_off_when_stderr_is_not_a_terminal(tmp_path, capfd, monkeypatch):
    """A log file (stderr redirected) gets no tqdm lines: sweep's bar and demo's bar."""
    out = tmp_path / "s.csv"
    assert main(["sweep", "--robot", "kr1000titan", "--n", "30", "--samples", "20", "--out", str(out)]) == 0
    err = capfd.readouterr().err
    assert "sweep" not in err and "it/s" not in err and "pt/s" not in err and out.is_file()

    import torchcal.workflows.paper_experiment as P

    def fake(cfg, seeds=1, progress=None, **_):
        for step, done in (("seed 1/1: sweep", 0.0), ("seed 1/1: test", 0.9), ("seed 1/1: done", 1.0)):
            progress(step, done)
        raise KeyboardInterrupt  # stop here: only the bar is under test
    monkeypatch.setattr(P, "run_demo", fake)
    assert main(["demo"]) == 130
    err = capfd.readouterr().err
    assert "%" not in err and "demo" not in err


def test_a_warning_no_command_words_is_still_one_line(tmp_path, capsys):
    """report --data with rx, ry, rz in radians: evaluate's MismatchWarning, raised inside
    the report composition, came out as Python's two-line warning, twice; now one
    'torchcal: warning:' line."""
    import math

    from torchcal.cli import main

    ur10 = Path(__file__).resolve().parents[1] / "examples" / "ur10"
    lines = (ur10 / "series_c.csv").read_text().splitlines()[:121]
    cols = [lines[0].split(",").index(c) for c in ("rx", "ry", "rz")]
    rows = [line.split(",") for line in lines[1:]]
    (tmp_path / "c.csv").write_text("\n".join(lines) + "\n")
    for r in rows:
        for c in cols:
            r[c] = repr(math.radians(float(r[c])))
    (tmp_path / "rad.csv").write_text("\n".join([lines[0]] + [",".join(r) for r in rows]) + "\n")
    assert main(["fit", str(tmp_path / "c.csv"), "--robot", str(ur10 / "ur10.json"), "--effects", "base_frame",
                 "tool_offset", "--out", str(tmp_path / "m.json")]) == 0
    capsys.readouterr()
    assert main(["report", str(tmp_path / "m.json"), "--data", str(tmp_path / "rad.csv"),
                 "--out", str(tmp_path / "r.html")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(f"torchcal: warning: {tmp_path / 'rad.csv'}: rx, ry, rz disagree ")


@pytest.mark.parametrize("argv, words", [
    (["compensate", "T.csv", "--model", "M.json", "--frame", "base", "--frame", "measuring", "--out", "Q.csv"],
     "torchcal compensate: error: argument --frame: given twice (base, then measuring); give it once"),
    (["fit", "D.csv", "--robot", "ur5e", "--effects", "base_frame", "--effects", "tool_offset", "--out", "M.json"],
     "torchcal fit: error: argument --effects: given twice (base_frame, then tool_offset); give it once"),
    (["fit", "D.csv", "--robot=ur5e", "--robot", "kr1000titan", "--out", "M.json"],
     "torchcal fit: error: argument --robot: given twice (ur5e, then kr1000titan); give it once"),
    (["split", "D.csv", "--fraction", "0.6", "--seed", "0", "--seed", "1", "--out", "A.csv", "B.csv"],
     "torchcal split: error: argument --seed: given twice (0, then 1); give it once"),
])
def test_an_option_given_twice_is_refused(tmp_path, capsys, monkeypatch, argv, words):
    """argparse keeps the last of a repeated option in silence (`--frame base --frame
    measuring` compensated in the measuring frame, `--effects base_frame --effects
    tool_offset` fitted the tool offset alone): one line naming both values, exit 2,
    nothing read or written."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    assert capsys.readouterr().err == words + "\n"
    assert list(tmp_path.iterdir()) == []


def test_a_switch_given_twice_and_an_appended_option_pass(tmp_path, capsys):
    """A switch (`--force --force`) changes nothing when repeated, and `--effects-module`
    is meant to be given once per file: neither is refused."""
    from torchcal.cli import build_parser

    args = build_parser(("fit",)).parse_args(["fit", "D.csv", "--robot", "ur5e", "--out", "M.json", "--force",
                                              "--force", "--effects-module", "a.py", "--effects-module", "b.py"])
    assert args.force is True and args.effects_module == ["a.py", "b.py"]
