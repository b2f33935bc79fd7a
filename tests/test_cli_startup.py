"""Start-up: `torchcal --version` / `--help` load neither torch nor scikit-learn, a
sub-command imports its own module only, and the parser's static lists (one-line help
of each command, built-in effect names) agree with the modules they stand for."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from torchcal import cli

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "sklearn", "scipy", "numpy")


def _reported(code: str) -> list[str]:
    """Run `code` in a fresh interpreter (this checkout first on the path); the lines it
    printed after an '@@' marker, marker removed (asserts there is one, else shows stderr)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT)
    lines = [x[2:] for x in out.stdout.splitlines() if x.startswith("@@")]
    assert lines, out.stderr
    return lines


def _modules_after(code: str) -> set:
    """Module names loaded by `code` in a fresh interpreter (then prints them as JSON)."""
    return set(json.loads(_reported(code + "\nimport json, sys\nprint('@@' + json.dumps(sorted(sys.modules)))")[-1]))


HELP_STEPS = (["evaluate", "--help"], ["--version"], ["--help"]) + tuple([c, "--help"] for c in cli.COMMANDS
                                                                         if c != "evaluate")


@pytest.fixture(scope="module")
def help_steps() -> dict:
    """`import torchcal.cli`, then `main(argv)` of each of HELP_STEPS one after another in one
    fresh interpreter (one start instead of one per step): {step: (modules loaded before
    it, modules loaded after it)}. `evaluate --help` comes first, right after the import,
    so its set is that of a fresh interpreter; the later sets also hold what the earlier
    steps loaded, so a module that must not be loaded is looked for in more, not less."""
    code = ("import json, sys\nimport torchcal.cli\nout = []\n"
            f"for argv in {[list(a) for a in HELP_STEPS]!r}:\n"
            "    before = sorted(sys.modules)\n"
            "    try:\n        torchcal.cli.main(argv)\n    except SystemExit:\n        pass\n"
            "    out.append([before, sorted(sys.modules)])\n"
            "print('@@' + json.dumps(out))")
    steps = json.loads(_reported(code)[-1])
    return {" ".join(a): (set(b), set(c)) for a, (b, c) in zip(HELP_STEPS, steps)}


@pytest.mark.parametrize("flag", ["--version", "--help"])
def test_version_and_help_import_no_heavy_module(flag, help_steps):
    _, loaded = help_steps[flag]
    assert not {m for m in loaded if m.split(".")[0] in HEAVY}
    assert "torchcal.cli.fit" not in loaded


def test_python_m_torchcal_version_does_not_import_torch():
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-X", "importtime", "-m", "torchcal", "--version"],
                         capture_output=True, text=True, env=env, cwd=ROOT)
    assert out.returncode == 0 and out.stdout.strip().startswith("torchcal ")
    imported = {line.split("|")[-1].strip() for line in out.stderr.splitlines() if line.startswith("import time:")}
    assert "torch" not in imported and "sklearn" not in imported


def test_a_sub_command_imports_only_its_own_module(help_steps):
    _, loaded = help_steps["evaluate --help"]  # the first step: a fresh interpreter's modules
    cmds = {m.rsplit(".", 1)[-1] for m in loaded if m.startswith("torchcal.cli.") and not m.startswith("torchcal.cli._")}
    assert "evaluate" in cmds
    assert "sklearn" not in {m.split(".")[0] for m in loaded}
    assert not cmds & {"partition", "demo", "sweep", "plan"}


@pytest.mark.parametrize("command", cli.COMMANDS)
def test_sub_command_help_does_not_import_torch(command, help_steps):
    """The parser definitions import no torch (nor numpy): `torchcal COMMAND --help` starts at once."""
    before, loaded = help_steps[f"{command} --help"]
    assert f"torchcal.cli.{command}" in loaded
    assert f"torchcal.cli.{command}" not in before  # loaded by its own --help
    assert not {m for m in loaded if m.split(".")[0] in ("torch", "numpy")}


@pytest.fixture(scope="module")
def fit_process(tmp_path_factory) -> tuple[Path, set, int, bool]:
    """`torchcal fit` (UR10 series D, base_frame and tool_offset) in a fresh interpreter: the
    model file, the modules loaded, and the collector's state after the command (the freeze
    count, whether it is on). One process for the two tests below."""
    data, robot = ROOT / "examples/ur10/series_d.csv", ROOT / "examples/ur10/ur10.json"
    out = tmp_path_factory.mktemp("fit") / "m.json"
    code = (f"import gc\nimport torchcal.cli\nrc = torchcal.cli.main(['fit', {str(data)!r}, '--robot', {str(robot)!r}, "
            f"'--effects', 'base_frame', 'tool_offset', '--out', {str(out)!r}])\nassert rc == 0\n"
            "print('@@gc', gc.get_freeze_count(), gc.isenabled())")
    lines = _reported(code + "\nimport json, sys\nprint('@@' + json.dumps(sorted(sys.modules)))")
    gc_line = [x for x in lines if x.startswith("gc ")]
    mods = [x for x in lines if not x.startswith("gc ")]
    assert gc_line and mods, lines
    _, frozen, enabled = gc_line[-1].split()
    return out, set(json.loads(mods[-1])), int(frozen), enabled == "True"


def test_a_fit_imports_no_sympy_scipy_or_plotting(fit_process):
    """The way to a fit (read, fit, covariance, MODEL.json) leaves out sympy (pulled in by
    torch.broadcast_shapes), scipy (its Student t quantile is `torchcal.statistics`') and
    the plotting packages."""
    out, loaded, _, _ = fit_process
    assert out.is_file() and "torch" in loaded
    tops = {m.split(".")[0] for m in loaded}
    assert not tops & {"sympy", "matplotlib", "rerun", "sklearn", "scipy"}


def test_preset_names_match_the_presets():
    from torchcal.cli._args import PRESET_NAMES
    from torchcal.robots.robot import PRESETS

    assert list(PRESET_NAMES) == sorted(PRESETS)


def test_import_torchcal_is_lazy_and_sets_the_wait_policy():
    loaded = _modules_after("import os\nos.environ.pop('OMP_WAIT_POLICY', None)\nimport torchcal\n"
                            "assert os.environ['OMP_WAIT_POLICY'] == 'PASSIVE'")
    assert "torch" not in loaded


def test_static_summaries_match_the_modules():
    parser = cli.build_parser()  # every module's own add_parser
    sub = next(a for a in parser._actions if a.dest == "command")
    helps = {a.dest: a.help for a in sub._choices_actions}
    assert helps == cli.SUMMARIES


def test_builtin_effect_names_match_the_registry():
    from torchcal.effects import registry

    assert set(cli.BUILTIN_EFFECTS) == set(registry._BUILTIN)



@pytest.mark.parametrize("torch_first", [False, True])
def test_the_command_line_freezes_what_importing_torch_made(torch_first, request):
    """A command that imports torch does so with the cyclic collector off and then freezes
    the objects it made (gc.freeze: no later full collection, nor the ones at exit, scans
    them again), and leaves the collector on (the fresh process of `fit_process`). In a
    process that imported torch before (the test suite, a program calling `main`), main
    leaves the collector as it is."""
    if not torch_first:
        _, loaded, frozen, enabled = request.getfixturevalue("fit_process")
        assert "torch" in loaded and enabled and frozen > 50_000
        return
    code = ("import gc\nimport torch\n"
            "import torchcal.cli\nassert torchcal.cli.main(['robot', 'show', 'ur5e']) == 0\n"
            "print('@@', gc.get_freeze_count(), gc.isenabled())")
    frozen, enabled = _reported(code)[-1].split()
    assert enabled == "True" and int(frozen) == 0
