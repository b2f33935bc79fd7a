"""Robustness of the command line: every bad input gives one clear line on
stderr naming the file / row / column or the option, a non-zero exit, no traceback and no
output file (an existing output is left untouched); too few poses and rank-deficient data
are explained; the same inputs and seed give byte-identical JSON."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import torch

import torchcal
from torchcal.simulation import virtual_robot as sim
from torchcal.robots.poses import random_poses
from torchcal.cli import main
from torchcal.errors import InputError
from torchcal.measurements import Measurements
from torchcal.io.measurement_csv import write_measurements

ROBOT = "kr1000titan"


# --------------------------------------------------------------------------------------
# data, made once per module
# --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def work(tmp_path_factory):
    d = tmp_path_factory.mktemp("robust")
    robot = torchcal.robot(ROBOT)
    vr = sim.VirtualRobot(robot, [], seed=1)
    q = random_poses(robot, 30, torch.Generator().manual_seed(2))
    m = vr.measure(q, noise_mm=0.02)
    write_measurements(d / "good.csv", m)
    m3 = m.subset(slice(0, 3))
    write_measurements(d / "three.csv", Measurements(m3.pose, m3.q, m3.xyz))
    qc = q.clone()
    qc[:, 5] = 0.3  # joint 6 never moves
    write_measurements(d / "still6.csv", vr.measure(qc, noise_mm=0.02))
    assert main(["fit", str(d / "good.csv"), "--robot", ROBOT, "--out", str(d / "model.json")]) == 0
    return d


def _lines(work):
    return (work / "good.csv").read_text().splitlines()


def _write(work, name, text):
    p = work / name
    p.write_text(text)
    return p


def _cells(line):
    return line.split(",")


def _bad(capsys, argv, *must, created=(), untouched=()):
    """Run the CLI on a bad input; check one clean line on stderr; return it."""
    before = {Path(p): Path(p).read_bytes() for p in untouched}
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse errors
        rc = exc.code
    out, err = capsys.readouterr()
    assert rc not in (0, None), f"expected a failure for {argv}"
    assert "Traceback" not in err and "Traceback" not in out
    lines = [ln for ln in err.splitlines()]
    assert len(lines) == 1 and lines[0].strip(), f"expected one line on stderr, got {err!r}"
    msg = lines[0]
    for s in must:
        assert s in msg, f"{s!r} not in {msg!r}"
    for p in created:
        assert not Path(p).exists(), f"{p} was written"
    for p, data in before.items():
        assert p.read_bytes() == data, f"{p} was changed"
    return msg


def _cmd(command, data, work, out):
    """argv of `command` on `data` writing `out`."""
    if command == "fit":
        return ["fit", data, "--robot", ROBOT, "--out", out]
    if command == "evaluate":
        return ["evaluate", data, "--model", work / "model.json", "--json", out]
    if command == "diagnose":
        return ["diagnose", data, "--robot", ROBOT, "--json", out]
    return ["discover", data, "--robot", ROBOT, "--json", out]


COMMANDS = ["fit", "evaluate", "diagnose", "discover"]


# --------------------------------------------------------------------------------------
# bad measurement files (every command that reads one)
# --------------------------------------------------------------------------------------

def _missing_column(lines):
    return "\n".join(",".join(_cells(ln)[:-1]) for ln in lines), ["line 1", "missing column z"]


def _extra_column(lines):
    return "\n".join(ln + (",wobble" if i == 0 else ",1") for i, ln in enumerate(lines)), \
        ["line 1", "'wobble'", "unknown column"]


def _wrong_joint_count(lines):
    return "\n".join(",".join(_cells(ln)[:6] + _cells(ln)[7:]) for ln in lines), \
        ["line 1", "expected 6 joints", "found 5"]


def _replace_cell(lines, row, col, value):
    cells = _cells(lines[row])
    cells[col] = value
    return "\n".join(lines[:row] + [",".join(cells)] + lines[row + 1:])


def _text_in_number(lines):
    return _replace_cell(lines, 2, 3, "twelve"), ["line 3 (data row 2), column q3", "'twelve'"]


def _nan(lines):
    return _replace_cell(lines, 4, 8, "nan"), ["line 5 (data row 4), column y", "finite"]


def _inf(lines):
    return _replace_cell(lines, 5, 9, "-inf"), ["line 6 (data row 5), column z", "finite"]


def _empty(lines):
    return "", ["empty file"]


def _duplicated_header(lines):
    return "\n".join(ln + (",q2" if i == 0 else ",0") for i, ln in enumerate(lines)), \
        ["line 1", "'q2'", "duplicated"]


def _negative_payload(lines):
    return "\n".join(ln + (",payload_kg" if i == 0 else (",-5" if i == 7 else ",100"))
                     for i, ln in enumerate(lines)), ["line 8 (data row 7), column payload_kg", ">= 0"]


def _joint_out_of_range(lines):
    """q1 of data row 3 one turn on (the same position, outside the limits; a row that
    moved would be a gross outlier, refused by fit)."""
    q1 = float(_cells(lines[3])[1]) + 360.0
    return _replace_cell(lines, 3, 1, repr(q1)), ["line 4", f"q1={q1:g}", "limits"]


def _header_only(lines):
    return lines[0], ["no data rows"]


def _short_row(lines):
    return "\n".join(lines[:6] + [",".join(_cells(lines[6])[:-2])] + lines[7:]), \
        ["line 7 (data row 6)", "expected 10 fields"]


BAD_CSV = {f.__name__[1:]: f for f in (
    _missing_column, _extra_column, _wrong_joint_count, _text_in_number, _nan, _inf, _empty,
    _duplicated_header, _negative_payload, _header_only, _short_row)}


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("case", sorted(BAD_CSV))
def test_bad_measurement_file(work, capsys, case, command):
    text, must = BAD_CSV[case](_lines(work))
    data = _write(work, f"{case}.csv", text + ("\n" if text else ""))
    out = work / f"{case}-{command}.json"
    _bad(capsys, _cmd(command, data, work, out), str(data), *must, created=[out], untouched=[data])


def test_joint_out_of_limits_warns_and_goes_on(work, capsys):
    """Out-of-limit angles are one warning line naming the row, not an error: preset
    limits are data-sheet values and real sessions reach or pass them."""
    text, must = _joint_out_of_range(_lines(work))
    data = _write(work, "limits.csv", text + "\n")
    out = work / "limits.json"
    assert main([str(a) for a in ["fit", data, "--robot", ROBOT, "--out", out]]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("torchcal: warning:")
    assert all(s in err[0] for s in must) and out.exists()


@pytest.mark.parametrize("command", COMMANDS)
def test_data_file_does_not_exist(work, capsys, command):
    data, out = work / "nope.csv", work / f"nope-{command}.json"
    _bad(capsys, _cmd(command, data, work, out), str(data), "does not exist", created=[out, data])


def test_data_file_is_a_folder(work, capsys):
    out = work / "folder.json"
    _bad(capsys, ["fit", work, "--robot", ROBOT, "--out", out], str(work), created=[out])


# --------------------------------------------------------------------------------------
# bad options: robot, effects
# --------------------------------------------------------------------------------------

@pytest.mark.parametrize("command", ["fit", "diagnose", "discover"])
def test_unknown_robot(work, capsys, command):
    argv = _cmd(command, work / "good.csv", work, work / f"robot-{command}.json")
    argv[argv.index("--robot") + 1] = "marvin"
    _bad(capsys, argv, "unknown robot 'marvin'", "kr1000titan", created=[work / f"robot-{command}.json"])


@pytest.mark.parametrize("command", ["fit", "diagnose", "discover"])
def test_unknown_effect(work, capsys, command):
    out = work / f"effect-{command}.json"
    argv = _cmd(command, work / "good.csv", work, out) + ["--effects", "joint_wobble:2"]
    _bad(capsys, argv, "'joint_wobble:2'", "unknown effect", "joint_compliance", created=[out])


@pytest.mark.parametrize("spec, must", [
    ("joint_compliance:2,,3", "empty joint"),
    ("joint_compliance:x", "'joint_compliance:x'"),
    ("joint_compliance:9", "joint 9"),
    ("joint_compliance:0", "'joint_compliance:0'"),
    ("thermal_expansion:2", "'thermal_expansion:2'"),
    (":2", "':2'"),
    ("gear_periodic:", "'gear_periodic:'"),
])
def test_malformed_effect_spec(work, capsys, spec, must):
    out = work / "spec.json"
    _bad(capsys, ["fit", work / "good.csv", "--robot", ROBOT, "--effects", spec, "--out", out],
         "effect spec", must, created=[out])


def test_effect_needs_a_missing_column(work, capsys):
    out = work / "thermal.json"
    _bad(capsys, ["fit", work / "good.csv", "--robot", ROBOT, "--effects", "thermal_expansion", "--out", out],
         "temp_c", created=[out])


def test_robust_choice(work, capsys):
    out = work / "robust.json"
    _bad(capsys, ["fit", work / "good.csv", "--robot", ROBOT, "--robust", "tukey", "--out", out],
         "--robust", created=[out])


@pytest.mark.parametrize("seed", ["-1", "4294967296", "99999999999999999999", "1.5"])
@pytest.mark.parametrize("command", ["simulate", "plan", "split"])
def test_seed_out_of_range_names_the_option(work, capsys, command, seed):
    """A negative seed was refused by numpy deep inside split / plan without naming --seed
    (and accepted by simulate); a seed beyond 64 bits gave 'Overflow when unpacking long
    long'. Every --seed is one argparse line naming the option and the range."""
    out = work / f"seed-{command}.csv"
    argv = {"simulate": ["simulate", "--robot", ROBOT, "--n", "5", "--out", out],
            "plan": ["plan", "--robot", ROBOT, "--n", "10", "--out", out],
            "split": ["split", work / "good.csv", "--fraction", "0.5", "--out", out, work / "seed-val.csv"]}[command]
    _bad(capsys, [*argv, "--seed", seed], "argument --seed", "0..4294967295", repr(seed),
         created=[out, work / "seed-val.csv"])


@pytest.mark.parametrize("option, value", [("--temp", "nan"), ("--floor", "nan"), ("--column-height", "inf")])
def test_plan_numbers_must_be_finite(work, capsys, option, value):
    """plan --temp nan gave a traceback ('cannot reshape tensor of 0 elements'), --floor nan
    'workspace filter too strict': every such option is one argparse line naming it."""
    out = work / "finite-plan.csv"
    _bad(capsys, ["plan", "--robot", ROBOT, "--effects", "thermal_expansion", "--n", "10", "--out", out,
                  option, value], f"argument {option}", "a finite number", repr(value), created=[out])


def test_joined_files_warn_in_one_line(work, capsys):
    """Two sessions joined with restarting pose ids: the reader's PoseIdWarning is one
    'torchcal: warning:' line on stderr (not Python's two-line warning), and split goes on."""
    lines = _lines(work)
    again = _cells(lines[1])
    again[1] = repr(float(again[1]) + 5.0)  # the first pose's id, q1 5 degrees away
    p = _write(work, "joined.csv", "\n".join(lines + [",".join(again)]) + "\n")
    outs = [work / "joined-a.csv", work / "joined-b.csv"]
    assert main(["split", str(p), "--fraction", "0.5", "--out", *map(str, outs)]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(f"torchcal: warning: {p}: 1 row(s) repeat a pose id at other joint "
                                               f"values (first: line {len(lines) + 1}, pose id "), err


@pytest.mark.parametrize("command", ["diagnose", "discover"])
def test_one_fold_is_refused_by_the_option(work, capsys, command):
    """--folds 1 holds no pose out: it was 'error: Singular matrix' from deep inside the
    cross-validation; now the option's own line, before any work."""
    out = work / f"folds-{command}.json"
    _bad(capsys, _cmd(command, work / "good.csv", work, out) + ["--folds", "1"], "argument --folds",
         "integer >= 2", "'1'", created=[out])


# --------------------------------------------------------------------------------------
# model files
# --------------------------------------------------------------------------------------

def test_model_from_another_robot_diagnose(work, capsys):
    out = work / "other-diag.json"
    _bad(capsys, ["diagnose", work / "good.csv", "--robot", "puma560", "--model", work / "model.json",
                  "--json", out], str(work / "model.json"), "kr1000titan", "puma560", created=[out])


def test_model_from_another_robot_evaluate(work, capsys):
    out = work / "other-eval.json"
    _bad(capsys, ["evaluate", work / "good.csv", "--model", work / "model.json", "--robot", "puma560",
                  "--json", out], str(work / "model.json"), "kr1000titan", "puma560", created=[out])


def test_model_on_data_of_another_joint_count(work, capsys):
    text, _ = _wrong_joint_count(_lines(work))
    data = _write(work, "five.csv", text + "\n")
    out = work / "five-eval.json"
    _bad(capsys, ["evaluate", data, "--model", work / "model.json", "--json", out],
         str(data), "expected 6 joints", created=[out])


@pytest.mark.parametrize("text, must", [
    ("{not json", "not a valid model file"),
    ("", "not a valid model file"),
    ("[1, 2, 3]", "JSON object"),
    ('{"format": "something/else"}', "not a torchcal model file"),
    ('{"format": "torchcal-model/1", "robot": "kr1000titan"}', "bad field"),
    (b"\xff\xfe\x00garbage", "not a valid model file"),
])
def test_model_file_not_a_model(work, capsys, text, must):
    model = work / "bad-model.json"
    if isinstance(text, bytes):
        model.write_bytes(text)
    else:
        model.write_text(text)
    out = work / "badmodel.json"
    _bad(capsys, ["evaluate", work / "good.csv", "--model", model, "--json", out],
         str(model), must, created=[out], untouched=[model])
    _bad(capsys, ["diagnose", work / "good.csv", "--robot", ROBOT, "--model", model, "--json", out],
         str(model), must, created=[out], untouched=[model])


def test_model_file_does_not_exist(work, capsys):
    model, out = work / "no-model.json", work / "nomodel.json"
    _bad(capsys, ["evaluate", work / "good.csv", "--model", model, "--json", out],
         str(model), "does not exist", created=[out, model])


def test_model_with_tampered_parameters(work, capsys):
    obj = json.loads((work / "model.json").read_text())
    obj["parameters"] = obj["parameters"][:-1]
    model = _write(work, "short-model.json", json.dumps(obj))
    _bad(capsys, ["evaluate", work / "good.csv", "--model", model], str(model), "parameters")


# --------------------------------------------------------------------------------------
# outputs: --force, inputs never overwritten
# --------------------------------------------------------------------------------------

@pytest.mark.parametrize("command", COMMANDS)
def test_output_exists_without_force(work, capsys, command):
    out = _write(work, f"exists-{command}.json", '{"keep": "me"}\n')
    _bad(capsys, _cmd(command, work / "good.csv", work, out), str(out), "--force", untouched=[out])


# an output option naming an input file: (argv of the work folder w, the file named, files left untouched)
INPUT_AS_OUTPUT = {
    "fit --out DATA": (lambda w: ["fit", w / "good.csv", "--robot", ROBOT, "--out", w / "good.csv", "--force"],
                       "good.csv", ["good.csv"]),
    "evaluate --json MODEL": (lambda w: ["evaluate", w / "good.csv", "--model", w / "model.json", "--json",
                                         w / "model.json", "--force"], "model.json", ["model.json", "good.csv"]),
    "evaluate --json DATA": (lambda w: ["evaluate", w / "good.csv", "--model", w / "model.json", "--json",
                                        w / "good.csv", "--force"], "good.csv", ["good.csv"]),
    "diagnose --json DATA": (lambda w: ["diagnose", w / "good.csv", "--robot", ROBOT, "--json", w / "good.csv",
                                        "--force"], "good.csv", ["good.csv"]),
}


@pytest.mark.parametrize("case", sorted(INPUT_AS_OUTPUT))
def test_an_output_naming_an_input_is_refused(work, capsys, case):
    argv, named, untouched = INPUT_AS_OUTPUT[case]
    _bad(capsys, argv(work), str(work / named), "input", untouched=[work / u for u in untouched])


def test_discover_two_outputs_one_file(work, capsys):
    out = work / "same.json"
    _bad(capsys, ["discover", work / "good.csv", "--robot", ROBOT, "--json", out, "--out", out],
         str(out), "same file", created=[out])


def test_discover_second_output_exists_nothing_written(work, capsys):
    first = work / "disc-history.json"
    second = _write(work, "disc-model.json", "keep\n")
    _bad(capsys, ["discover", work / "good.csv", "--robot", ROBOT, "--json", first, "--out", second],
         str(second), "--force", created=[first], untouched=[second])


@pytest.mark.parametrize("command", ["diagnose", "discover"])
def test_plots_names_a_file(work, capsys, command):
    out = work / f"plots-{command}.json"
    argv = _cmd(command, work / "good.csv", work, out) + ["--plots", work / "good.csv"]
    _bad(capsys, argv, "--plots", "folder", created=[out], untouched=[work / "good.csv"])


@pytest.mark.parametrize("command", ["evaluate", "plan"])
def test_plots_folder_that_cannot_be_made(work, capsys, command):
    """A --plots folder the system will not create (here below a file) was an
    '[Errno 20] Not a directory' line without the option; now it names --plots, before any work."""
    plots = work / "good.csv" / "plots"
    out = work / f"plots-made-{command}.json"
    argv = (["plan", "--robot", ROBOT, "--n", "10", "--out", out] if command == "plan"
            else _cmd(command, work / "good.csv", work, out))
    _bad(capsys, argv + ["--plots", plots], str(plots), "--plots: cannot create the folder", created=[out],
         untouched=[work / "good.csv"])


def test_diagnose_model_and_effects_both(work, capsys):
    out = work / "both.json"
    _bad(capsys, ["diagnose", work / "good.csv", "--robot", ROBOT, "--model", work / "model.json",
                  "--effects", "joint_compliance:2", "--json", out], "--model", "--effects", created=[out])


def test_output_folder_missing(work, capsys):
    out = work / "no-such-folder" / "model.json"
    _bad(capsys, ["fit", work / "good.csv", "--robot", ROBOT, "--out", out], "does not exist", created=[out])


# --------------------------------------------------------------------------------------
# too few poses, rank deficiency
# --------------------------------------------------------------------------------------

def test_too_few_poses_says_how_many(work, capsys):
    out = work / "three-model.json"
    msg = _bad(capsys, ["fit", work / "three.csv", "--robot", ROBOT, "--out", out],
               "too few poses", "3 poses", created=[out])
    assert f"error: {work / 'three.csv'}: too few poses: 3 poses" in msg  # the file named (it was not)
    k = int(re.search(r"(\d+) identifiable parameters", msg).group(1))
    need = int(re.search(r"need at least (\d+) poses", msg).group(1))
    assert k > 9  # the model's count, not the 9 equations of 3 poses
    assert need == k // 3 + 1


def test_constant_joint_names_unidentifiable(work, capsys):
    out = work / "still6-model.json"
    assert main(["fit", str(work / "still6.csv"), "--robot", ROBOT, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    held_line = next(ln for ln in text.splitlines() if ln.startswith("held at nominal"))
    held = set(held_line.split(": ", 1)[1].split(", "))
    ref = set(json.loads((work / "model.json").read_text())["identifiability"]["held_at_nominal"])
    extra = held - ref
    assert extra and all(name.endswith("6") for name in extra), (held, ref)
    assert "q6 (constant" in text
    obj = json.loads(out.read_text())
    assert set(obj["identifiability"]["held_at_nominal"]) == held
    for p in obj["parameters"]:
        if p["name"] in held:
            assert p["value"] == 0.0 and p["std"] == 0.0 and not p["identified"]


# --------------------------------------------------------------------------------------
# reproducibility: same inputs and seed -> byte-identical JSON
# --------------------------------------------------------------------------------------

# the argv of each command writing its JSON to `out`, in the work folder w
REPRODUCIBLE = {
    "fit": lambda w, out: ["fit", w / "good.csv", "--robot", ROBOT, "--robust", "huber", "--seed", "3", "--out", out],
    "evaluate": lambda w, out: ["evaluate", w / "good.csv", "--model", w / "model.json", "--json", out],
    "diagnose": lambda w, out: ["diagnose", w / "good.csv", "--robot", ROBOT, "--folds", "3", "--seed", "5",
                                "--json", out],
    "discover": lambda w, out: ["discover", w / "good.csv", "--robot", ROBOT, "--folds", "3", "--seed", "5",
                                "--json", out],
}


@pytest.mark.parametrize("command", sorted(REPRODUCIBLE))
def test_the_same_inputs_and_seed_give_byte_identical_json(work, capsys, command):
    outs = []
    for k in (1, 2):
        out = work / f"repro-{command}-{k}.json"
        assert main([str(a) for a in REPRODUCIBLE[command](work, out)]) == 0
        outs.append(out.read_bytes())
    capsys.readouterr()
    assert outs[0] == outs[1]
    json.loads(outs[0])


@pytest.mark.parametrize("value", ["2", "0", "95", "-0.5"])
def test_plan_reach_must_be_a_share_of_the_stretch(work, capsys, value):
    """plan --reach 2 (or 95, a percentage) was taken as 'no limit' in silence, --reach 0
    ended in 'workspace filter too strict': the option is one line naming the range."""
    out = work / "reach-plan.csv"
    _bad(capsys, ["plan", "--robot", ROBOT, "--n", "10", "--out", out, "--reach", value],
         "argument --reach", "a share in (0, 1] (1: no limit)", repr(value), created=[out])


def test_workspace_reach_fraction_outside_a_share_is_refused():
    from torchcal.robots.workspace import Workspace

    with pytest.raises(InputError, match=r"Workspace: reach_fraction: expected a share of the arm's full stretch in "
                                         r"\(0, 1\] \(1: no limit\), got 1300"):
        Workspace(reach_fraction=1300)
    with pytest.raises(InputError, match=r"Workspace: floor_z_mm: expected a finite number, got nan"):
        Workspace(floor_z_mm=float("nan"))
    assert Workspace(reach_fraction=1).reach_fraction == 1
