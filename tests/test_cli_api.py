"""The command line only parses, calls one library function and formats: the same inputs
through the CLI and through the API give the same outputs, field by field (files byte for
byte, every printed figure, the refusal lines).

References: the API's own results (`torchcal.api.compensate_targets`, `export`, `accuracy`,
`torchcal.planning.plan.plan`) and `torchcal.compensate` on the same targets; the printed
figures are parsed back from stdout and compared with the result's ``to_dict()`` at the
printed precision.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import torch
from torch.testing import assert_close

import torchcal
from torchcal.api import accuracy, compensate_targets, export
from torchcal.io.targets_csv import compensation_csv
from torchcal.io.truth_file import truth_to_dict
from torchcal.cli import main
from torchcal.io.measurement_csv import write_measurements
from torchcal.io.modelfile import file_units
from torchcal.measurements import Measurements
from torchcal.planning.plan import plan
from torchcal.robots.poses import random_poses
from torchcal.simulation.virtual_robot import VirtualRobot

EFFECTS = ["base_frame", "tool_offset", "joint_compliance:2,3"]
NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?")


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """(robot, model path, data path, folder): a ur5e model with joint compliance fitted by the CLI."""
    d = tmp_path_factory.mktemp("lib")
    rob = torchcal.robot("ur5e")
    vr = VirtualRobot(rob, EFFECTS, seed=5, effect_mm={"joint_compliance": 1.0})
    write_measurements(d / "m.csv", vr.measure(random_poses(rob, 60, 11), seed=12))
    assert main(["fit", str(d / "m.csv"), "--robot", "ur5e", "--effects", *EFFECTS, "--out", str(d / "model.json")]) == 0
    return rob, d / "model.json", d / "m.csv", d


def _targets(path, xyz, extra=""):
    path.write_text("x,y,z\n" + "".join(",".join(repr(float(v)) for v in r) + "\n" for r in xyz.tolist()) + extra)
    return path


def _numbers(text: str) -> list[float]:
    return [float(v) for v in NUMBER.findall(text)]


@pytest.fixture(scope="module")
def interval(tmp_path_factory):
    """(robot, model path, data path): a ur5e interval model written by `torchcal calibrate`."""
    d = tmp_path_factory.mktemp("interval")
    rob = torchcal.robot("ur5e")
    vr = VirtualRobot(rob, ["base_frame"], seed=6)
    write_measurements(d / "m.csv", vr.measure(random_poses(rob, 30, 6), repeats=3, seed=7))
    assert main(["calibrate", str(d / "m.csv"), "--robot", "ur5e", "--effects", "base_frame",
                 "--out", str(d / "model.json")]) == 0
    return rob, d / "model.json", d / "m.csv"


@pytest.mark.parametrize("kind, far", [("fit", False), ("fit", True), ("calibrate", False)],
                         ids=["fit", "fit-unreachable", "interval"])
@pytest.mark.filterwarnings("ignore:targets.*beyond the reach")
def test_compensate_cli_and_api_agree_field_by_field(request, kind, far, tmp_path, capsys):
    """The same file, printed figures and exit status from the CLI and the API, for a fitted
    model and an interval model; with a target beyond reach (no seeds) the others still solve."""
    rob, model = request.getfixturevalue("fitted" if kind == "fit" else "interval")[:2]
    t = rob.fk(random_poses(rob, 25, 40))
    if far:
        t = torch.cat([t, torch.tensor([[3000.0, 0.0, 500.0]], dtype=t.dtype)])  # beyond the ur5e's reach
    targets = _targets(tmp_path / "t.csv", t)
    out = tmp_path / "q.csv"
    capsys.readouterr()
    code = main(["compensate", str(targets), "--model", str(model), "--out", str(out)])
    printed = capsys.readouterr()
    res = compensate_targets(str(model), targets)
    assert out.read_text() == compensation_csv(res)  # every command, zone, residual and flag
    d = res.to_dict()
    assert code == (1 if res.failed else 0)
    assert f"compensated {len(d['targets'])} targets (x,y,z in the {d['frame']} frame) with {d['n_zones']} " \
           f"parameter set(s) ({d['method']})" in printed.out
    assert f"{len(d['targets']) - len(res.failed)} converged within the joint limits" in printed.out
    assert f"max predicted residual {d['max_residual_mm']:.3g} mm" in printed.out
    assert [r["q"] for r in d["targets"]] == res.q_user.tolist()
    if kind == "calibrate":
        assert d["method"] == "global" and d["n_zones"] == 1
        return
    # the one library answer: the same commands as torchcal.compensate from the same nominal seeds
    comp = torchcal.compensate(str(model), t)
    assert_close(res.q_user, rob.q_to_user(comp.q), rtol=0, atol=1e-9)
    assert res.compensation.converged.tolist() == comp.converged.tolist()
    if far:
        assert comp.converged.tolist() == [True] * 25 + [False] and code == 1 and d["beyond_reach"] == [26]
        assert "not converged: target(s) 26" in printed.err


def test_compensate_failure_line_lists_the_apis_rows(fitted, tmp_path, capsys):
    rob, model, _, _ = fitted
    q = random_poses(rob, 6, 41)
    t = rob.fk(q)
    t[2] = torch.tensor([3000.0, 0.0, 500.0], dtype=torch.float64)  # beyond the ur5e's reach
    targets = tmp_path / "t.csv"  # with seeds: the nominal inverse of the far target is not needed; a payload
    targets.write_text("x,y,z," + ",".join(f"q{k}" for k in range(1, 7)) + ",payload_kg\n" + "".join(
        ",".join(repr(float(v)) for v in [*t[i].tolist(), *rob.q_to_user(q[i:i + 1])[0].tolist(), 2.0]) + "\n"
        for i in range(6)))
    capsys.readouterr()
    assert main(["compensate", str(targets), "--model", str(model), "--out", str(tmp_path / "q.csv")]) == 1
    err = capsys.readouterr().err
    res = compensate_targets(model, targets)
    assert (tmp_path / "q.csv").read_text() == compensation_csv(res)
    d = res.to_dict()
    assert 3 in d["not_converged"] and d["beyond_reach"] == [3]
    failed = sorted(set(d["not_converged"]) | set(d["outside_limits"]))
    assert err.startswith(f"torchcal compensate: error: {len(failed)} target(s) failed (")
    assert f"not converged: target(s) {', '.join(map(str, d['not_converged']))}" in err
    assert "beyond the reach of ur5e: target(s) 3" in err and err.count("\n") == 1


@pytest.mark.parametrize("command", ["fit", "compensate"])
def test_metres_in_an_mm_file_are_the_same_finding(fitted, tmp_path, capsys, command):
    """Positions in metres in an mm file: the library names its keyword, the CLI its option,
    nothing is written; read in metres, both accept the file and agree."""
    rob, model, _, _ = fitted
    q = random_poses(rob, 30, 42)
    out = tmp_path / ("model.json" if command == "fit" else "q.csv")
    if command == "fit":
        path = tmp_path / "m.csv"
        write_measurements(path, Measurements(torch.arange(30), q, rob.fk(q) / 1000))
        argv = ["fit", str(path), "--robot", "ur5e", "--out", str(out)]

        def library(**kw):
            return torchcal.fit("ur5e", path, **kw)
        with pytest.raises(torchcal.InputError, match="look like metres read as mm"):
            library(max_length_mm=None, max_angle_deg=None)  # refused without the plausibility limits too
    else:
        path = _targets(tmp_path / "t.csv", rob.fk(q) / 1000)
        argv = ["compensate", str(path), "--model", str(model), "--out", str(out)]

        def library(**kw):
            return compensate_targets(model, path, **kw)
    with pytest.raises(torchcal.InputError) as exc:
        library()
    assert exc.value.fix == ("length_unit", "m") and str(exc.value).endswith("; pass length_unit='m'")
    assert "--" not in str(exc.value)
    capsys.readouterr()
    assert main(argv) == 2
    assert capsys.readouterr().err == f"torchcal {command}: error: {exc.value.message}; pass --length-unit m\n"
    assert not out.exists()
    assert main(argv + ["--length-unit", "m"]) == 0
    res = library(length_unit="m")
    if command == "fit":
        _, k = file_units(res.model)  # the file's units (deg, mm) per parameter
        values = [p["value"] for p in json.loads(out.read_text())["parameters"]]
        assert values == pytest.approx((res.theta * k).tolist(), abs=1e-10)
    else:
        assert out.read_text() == compensation_csv(res)


def test_compensate_needs_the_conditions_of_the_models_effects(tmp_path, capsys):
    rob = torchcal.robot("ur5e")
    vr = VirtualRobot(rob, ["thermal_expansion"], seed=3)
    m = vr.measure(random_poses(rob, 40, 3), seed=4)  # a session with temperatures
    write_measurements(tmp_path / "m.csv", m)
    model = tmp_path / "model.json"
    assert main(["fit", str(tmp_path / "m.csv"), "--robot", "ur5e", "--effects", "thermal_expansion",
                 "--out", str(model)]) == 0
    targets = _targets(tmp_path / "t.csv", rob.fk(random_poses(rob, 4, 5)))
    with pytest.raises(torchcal.InputError) as exc:
        compensate_targets(model, targets)
    assert "column temp_c" in str(exc.value)
    capsys.readouterr()
    assert main(["compensate", str(targets), "--model", str(model), "--out", str(tmp_path / "q.csv")]) == 2
    assert capsys.readouterr().err == f"torchcal compensate: error: {exc.value}\n"


@pytest.mark.parametrize("with_data", [False, True])
def test_export_cli_and_api_write_the_same_files(fitted, tmp_path, capsys, with_data):
    rob, model, data, _ = fitted
    names = {"robot_file": tmp_path / "r.json", "urdf": tmp_path / "r.urdf", "table": tmp_path / "r.csv"}
    argv = ["export", str(model), "--robot-file", str(names["robot_file"]), "--urdf", str(names["urdf"]),
            "--table", str(names["table"])] + (["--data", str(data)] if with_data else [])
    capsys.readouterr()
    assert main(argv) == 0
    printed = capsys.readouterr()
    cli = {k: p.read_text() for k, p in names.items()}
    res = export(str(model), **names, data=data if with_data else None, force=True)
    assert {k: p.read_text() for k, p in names.items()} == cli
    d = res.to_dict()
    assert d["written"] == {k: str(p) for k, p in names.items()}
    assert json.loads(cli["robot_file"]).get("effects", []) == res.effects_not_held
    if with_data:
        r = d["refit"]
        assert r["rows"] == 60 and r["dropped"] == ["joint_compliance:2,3"] and d["effects_not_held"] == []
        line = next(s for s in printed.out.splitlines() if s.startswith("geometry alone refitted"))
        assert _numbers(line)[-3:] == pytest.approx(
            [round(r[k], 4) for k in ("refit_rms_mm", "full_rms_mm", "naive_rms_mm")], abs=1e-12)
        assert f"(solver {r['status']})" in line
    else:
        assert d["refit"] is None and d["effects_not_held"] == ["joint_compliance:2,3"]
        assert "joint_compliance:2,3" in printed.err and "pass --data DATA.csv" in printed.err
    assert f"exported {d['robot']} ({d['joints']} joints)" in printed.out


def test_export_without_outputs_or_over_a_file_refuses_alike(fitted, tmp_path, capsys):
    _, model, _, _ = fitted
    with pytest.raises(torchcal.InputError):
        export(model)
    (tmp_path / "r.csv").write_text("x")
    with pytest.raises(torchcal.InputError) as exc:
        export(model, table=tmp_path / "r.csv")
    assert "--" not in str(exc.value)
    capsys.readouterr()
    assert main(["export", str(model), "--table", str(tmp_path / "r.csv")]) == 2
    assert capsys.readouterr().err == f"torchcal export: error: {exc.value}; pass --force to replace it\n"
    assert (tmp_path / "r.csv").read_text() == "x"


def test_accuracy_cli_prints_the_apis_figures(fitted, capsys):
    _, model, _, _ = fitted
    capsys.readouterr()
    assert main(["accuracy", str(model), "--n", "200", "--seed", "3", "--payload", "2", "--temp", "25"]) == 0
    lines = capsys.readouterr().out.splitlines()
    d = accuracy(str(model), n=200, seed=3, payload_kg=2.0, temp_c=25.0).to_dict()
    s = d["sigma_mm"]
    # "... (1-sigma, 3-D, mm) min X, median Y, 95th percentile Z, max W"
    assert _numbers(lines[0].split("mm)")[-1]) == pytest.approx(
        [round(s["min"], 4), round(s["median"], 4), 95, round(s["p95"], 4), round(s["max"], 4)], abs=1e-12)
    assert f"at {d['poses']} workspace poses" in lines[0]
    assert f"({d['robot']} + [{', '.join(d['effects'])}])" in lines[0]
    for line, r in zip(lines[2:5], d["regions"][:3]):
        assert line.split()[:-3] == r["region"].split() and _numbers(line)[-3:] == pytest.approx(
            [round(r["mean_mm"], 4), round(r["max_mm"], 4), r["points"]], abs=1e-12)


def test_accuracy_of_a_fit_in_memory_is_that_of_its_file(fitted):
    rob, model, data, _ = fitted
    res = torchcal.fit(rob, str(data), EFFECTS)
    a, b = accuracy(res, n=100, seed=1), accuracy(str(model), n=100, seed=1)
    assert_close(a.sigma, b.sigma, rtol=1e-6, atol=1e-9)


def test_plan_cli_and_api_agree(tmp_path, capsys):
    out = tmp_path / "plan.csv"
    capsys.readouterr()
    assert main(["plan", "--robot", "puma560", "--effects", "joint_compliance:2", "--n", "10", "--candidates", "400",
                 "--seed", "2", "--criterion", "O1", "--random-plans", "6", "--out", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    res = plan("puma560", ["joint_compliance:2"], n=10, candidates=400, seed=2, criterion="O1", random_plans=6)
    from torchcal.io.plan_csv import plan_csv

    assert out.read_text() == plan_csv(res.q, torchcal.robot("puma560"))
    d = res.to_dict()
    assert f"{d['n']} of {d['candidates']} candidate poses, {d['identifiable']} identifiable parameters" in lines[0]
    assert lines[1] == (f"criterion O1: plan {d['value']:.6g}; random plans of 10 (n=6) mean {d['random']['mean']:.6g}, "
                        f"best {d['random']['best']:.6g}")
    for line, k in zip(lines[3:8], ("O1", "O2", "O3", "O4", "O5")):
        o = d["observability"][k]
        assert _numbers(line.replace(k, "", 1))[:2] == pytest.approx(
            [float(f"{o['plan']:.4g}"), float(f"{o['random_mean']:.4g}")], rel=1e-12)
    travel = next(s for s in lines if s.startswith("joint travel"))
    assert _numbers(travel) == [round(d["travel_deg"]["ordered"]), round(d["travel_deg"]["selection"])]


def test_plan_refusals_name_the_keyword_in_the_library_and_the_option_in_the_cli(tmp_path, capsys):
    with pytest.raises(torchcal.InputError) as exc:
        plan("puma560", n=2, candidates=300)
    assert exc.value.fix[0] == "n" and "--" not in str(exc.value)
    need = exc.value.fix[1]
    capsys.readouterr()
    assert main(["plan", "--robot", "puma560", "--n", "2", "--candidates", "300", "--out", str(tmp_path / "p.csv")]) == 2
    assert capsys.readouterr().err == f"torchcal plan: error: {exc.value.message}; pass --n {need}\n"
    with pytest.raises(torchcal.InputError, match="criterion: unknown 'X'"):
        plan("puma560", n=20, candidates=300, criterion="X")


def test_simulate_cli_and_api_write_the_same_session(tmp_path, capsys):
    from torchcal.api import simulate
    from torchcal.io.measurement_csv import format_measurements

    out, truth = tmp_path / "m.csv", tmp_path / "truth.json"
    capsys.readouterr()
    assert main(["simulate", "--robot", "ur5e", "--effects", "joint_compliance:2", "thermal_expansion", "--n", "7",
                 "--repeats", "2", "--noise", "0.05", "--seed", "4", "--pose-seed", "9", "--out", str(out),
                 "--truth", str(truth)]) == 0
    printed = capsys.readouterr().out
    sim = simulate("ur5e", ["joint_compliance:2", "thermal_expansion"], n=7, repeats=2, noise_mm=0.05, seed=4,
                   pose_seed=9)
    assert out.read_text() == format_measurements(sim.measurements, robot=sim.robot)
    assert json.loads(truth.read_text()) == json.loads(json.dumps(truth_to_dict(sim)))
    d = sim.to_dict()
    assert (d["rows"], d["poses"], d["pose_seed"]) == (14, 7, 9) and "temp_c" in d["columns"]
    assert f"7 poses x 2 repeats = 14 rows (+ {', '.join(d['columns'])}), noise 0.05 mm, seed 4, pose seed 9" in printed


def test_plan_of_a_prismatic_robot_writes_the_slide_in_mm(tmp_path, capsys):
    scara = str(Path(__file__).resolve().parents[1] / "examples" / "scara.json")
    out = tmp_path / "plan.csv"
    assert main(["plan", "--robot", scara, "--n", "12", "--candidates", "300", "--floor=-1e9",
                 "--column-radius", "0", "--out", str(out)]) == 0
    rows = [r.split(",") for r in out.read_text().splitlines()[1:]]
    robot = torchcal.robot(scara)
    lo, hi = robot.limits[2].tolist()  # the slide's limits, mm
    slide = [float(r[3]) for r in rows]
    assert all(lo <= v <= hi for v in slide) and max(slide) - min(slide) > 0.2 * (hi - lo)
    res = plan(robot, n=12, candidates=300, workspace=_workspace(floor=-1e9, column_radius=0.0))
    assert_close(torch.tensor(slide, dtype=torch.float64), res.q[:, 2], rtol=0, atol=1e-9)


def _workspace(**kw):
    from torchcal.robots.workspace import Workspace

    w = Workspace()
    return Workspace(kw.get("floor", w.floor_z_mm), kw.get("column_radius", w.column_radius_mm),
                     w.column_height_mm, w.reach_fraction)


def test_unknown_effect_names_the_registry_in_the_library_and_the_option_in_the_cli(tmp_path, capsys):
    from torchcal.effects.spec import UnknownEffectError

    with pytest.raises(UnknownEffectError) as exc:
        plan("puma560", ["joint_coupling:2"], n=20, candidates=300)
    assert "torchcal.effects.register_effect" in str(exc.value) and "--" not in str(exc.value)
    capsys.readouterr()
    assert main(["plan", "--robot", "puma560", "--effects", "joint_coupling:2", "--n", "20", "--candidates", "300",
                 "--out", str(tmp_path / "p.csv")]) == 2
    expected = str(exc.value).replace(UnknownEffectError.HINT, "(an effect of your own: load its file with "
                                                               "--effects-module FILE.py)")
    assert capsys.readouterr().err == f"torchcal plan: error: {expected}\n" and expected != str(exc.value)


@pytest.mark.parametrize("command", ["fit", "calibrate"])
def test_the_cli_writes_the_apis_model(interval, command):
    """MODEL.json of `torchcal fit` / `calibrate` = the API's fit / interval model written by
    the library, key by key (the fit's settings recorded)."""
    from torchcal.io.modelfile import to_dict

    _, _, data = interval
    out = data.parent / f"{command}-model.json"
    settings = ["--robust", "huber", "--sigma-mm", "0.02", "--sigma-deg", "0.03"] if command == "fit" else []
    assert main([command, str(data), "--robot", "ur5e", "--effects", "base_frame", *settings, "--out", str(out)]) == 0
    cli = json.loads(out.read_text())
    if command == "fit":
        res = torchcal.fit("ur5e", data, ["base_frame"], robust="huber", sigma_mm=0.02, sigma_deg=0.03)
        assert (res.robust, res.sigma_mm, res.sigma_deg) == ("huber", 0.02, 0.03)
        api = json.loads(json.dumps(to_dict(res, source=data)))
        assert api["fit"]["robust"] == "huber" and api["fit"]["sigma_mm"] == 0.02
    else:
        api = json.loads(json.dumps(to_dict(torchcal.calibrate("ur5e", data, ["base_frame"]), source=data)))
    assert cli.keys() == api.keys()
    for key in cli:
        assert cli[key] == api[key], key
    assert cli["provenance"]["input"] == str(data) and len(cli["provenance"]["input_sha256"]) == 64


def test_sigma_deg_on_data_without_orientations_is_named(fitted, capsys):
    """--sigma-deg weighs rx, ry, rz against positions: on data without those columns it
    changes nothing, and fit says so in one warning line (none when the option is not given);
    the model is the one fitted without it."""
    _, _, data, d = fitted
    outs = {}
    for name, extra in (("plain", []), ("given", ["--sigma-deg", "0.5"])):
        outs[name] = d / f"sigma-{name}.json"
        assert main(["fit", str(data), "--robot", "ur5e", "--effects", *EFFECTS, *extra,
                     "--out", str(outs[name]), "--force"]) == 0
        err = capsys.readouterr().err
        lines = [ln for ln in err.splitlines() if "--sigma-deg" in ln]
        assert len(lines) == (1 if extra else 0), err
    assert lines[0].startswith("torchcal: warning: --sigma-deg 0.5 is ignored") and "rx, ry, rz" in lines[0]
    theta = [json.loads(outs[k].read_text())["parameters"] for k in ("plain", "given")]
    assert theta[0] == theta[1]
