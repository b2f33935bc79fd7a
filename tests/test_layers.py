"""Dependencies point one way: parse every module's imports (ast, module level and inside
functions) and check the layer rules of docs/design.md.

- inside torchcal, only torchcal.cli imports viz;
- kinematics imports nothing else of torchcal but errors;
- robots, effects, calibration, reliability, partition, diagnosis, simulation, io never
  import workflows or cli; calibration does not import simulation; io does not import cli.
- compute modules do not write files: effects, reliability, partition, diagnosis, simulation
  and measurements import nothing of torchcal.io (io reads and writes their results);
  kinematics and calibration do not import torchcal.io.files (calibration may name the
  MODEL.json layout of torchcal.io.modelfile for `FitResult.to_dict`).
- torchcal.rotations and torchcal.statistics import nothing of torchcal;
- the library's messages name no command-line option (``--length-unit``): it names its
  keyword (`InputError.fix`) and the command line writes the option;
- the paper's experiment by concept: workflows.paper_config imports only torchcal.errors,
  workflows.paper_report never runs the experiment (no paper_experiment, simulation,
  diagnosis or reliability).
"""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "torchcal"


def imports_of(path: Path) -> set[str]:
    """Absolute module names a file imports (relative imports resolved)."""
    pkg = ["torchcal", *path.relative_to(ROOT).with_suffix("").parts]
    if pkg[-1] == "__init__":
        pkg = pkg[:-1]
    else:
        pkg = pkg[:-1]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(pkg[: len(pkg) - node.level + 1] + ([base] if base else []))
            out.add(base)
            out.update(f"{base}.{a.name}" for a in node.names)
    return out


MODULES = {".".join(("torchcal", *p.relative_to(ROOT).with_suffix("").parts)): imports_of(p)
           for p in sorted(ROOT.rglob("*.py"))}

# (package, forbidden prefixes)
RULES = [
    ("torchcal.kinematics", ["torchcal.robots", "torchcal.effects", "torchcal.calibration", "torchcal.reliability",
                             "torchcal.partition", "torchcal.diagnosis", "torchcal.simulation", "torchcal.workflows",
                             "torchcal.io", "torchcal.cli", "viz"]),
    ("torchcal.calibration", ["torchcal.simulation", "torchcal.workflows", "torchcal.cli", "viz"]),
    ("torchcal.io", ["torchcal.cli", "torchcal.workflows", "viz"]),
]
for pkg in ("robots", "effects", "reliability", "partition", "diagnosis", "simulation", "measurements"):
    RULES.append((f"torchcal.{pkg}", ["torchcal.workflows", "torchcal.cli", "viz"]))
RULES.append(("torchcal.workflows", ["torchcal.cli", "viz"]))
for pkg in ("effects", "reliability", "partition", "diagnosis", "simulation", "measurements"):
    RULES.append((f"torchcal.{pkg}", ["torchcal.io"]))
RULES.append(("torchcal.calibration", ["torchcal.io.files"]))
# the rotation convention and the generic statistics depend on nothing of torchcal
RULES.append(("torchcal.rotations", ["torchcal"]))
RULES.append(("torchcal.statistics", ["torchcal"]))
# the paper's experiment by concept: its configuration is plain data (errors only); its
# report reads results and runs nothing (no experiment, simulation or discovery)
_PACKAGES = ["torchcal." + p.name for p in sorted(ROOT.iterdir()) if p.is_dir() and (p / "__init__.py").exists()]
RULES.append(("torchcal.workflows.paper_config", [p for p in _PACKAGES if p != "torchcal.workflows"]
              + ["torchcal.workflows.paper_experiment", "torchcal.workflows.paper_report", "torchcal.api"]))
RULES.append(("torchcal.workflows.paper_report", ["torchcal.workflows.paper_experiment", "torchcal.simulation",
                                                  "torchcal.diagnosis", "torchcal.reliability", "torchcal.cli", "viz"]))


def hits(mod_imports, forbidden):
    return sorted(i for i in mod_imports for f in forbidden if i == f or i.startswith(f + "."))


@pytest.mark.parametrize("pkg,forbidden", RULES, ids=[f"{p}-not-{f[0]}" for p, f in RULES])
def test_layer(pkg, forbidden):
    bad = {m: hits(imps, forbidden) for m, imps in MODULES.items()
           if (m == pkg or m.startswith(pkg + ".")) and hits(imps, forbidden)}
    assert not bad, f"{pkg} must not import {forbidden}: {bad}"


def test_only_the_cli_imports_viz():
    bad = {m: hits(i, ["viz"]) for m, i in MODULES.items()
           if not m.startswith("torchcal.cli") and hits(i, ["viz"])}
    assert not bad


def test_the_checker_sees_imports():
    """The parser is not vacuous: known edges are found."""
    assert "torchcal.calibration.lm" in MODULES["torchcal.calibration.fit"]
    assert any(i.startswith("torchcal.") for i in MODULES["torchcal.cli.fit"])
    assert hits({"torchcal.cli._args"}, ["torchcal.cli"]) and not hits({"torchcal.client"}, ["torchcal.cli"])
    assert "torchcal.reliability.sweep" in MODULES["torchcal.io.sweep_csv"]


#: a command-line option inside a string: ``--name`` at the start or after a space, a quote or "("
FLAG = re.compile(r"(?:^|[\s(`'\"])--[a-z]")
#: strings that quote a whole command for the user to run (a command, not an option of this call)
COMMANDS_QUOTED = {("torchcal.robots.robot_file", " --base BASE_LINK --tip TIP_LINK --out ROBOT.json")}


def flag_strings(path: Path) -> list[str]:
    """Non-docstring string constants of a file that name a ``--option``."""
    tree = ast.parse(path.read_text())
    docs = {id(n.body[0].value) for n in ast.walk(tree)
            if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and n.body
            and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
    return [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)
            and id(n) not in docs and FLAG.search(n.value)]


def test_library_messages_name_no_command_line_option():
    bad = {}
    for p in sorted(ROOT.rglob("*.py")):
        mod = ".".join(("torchcal", *p.relative_to(ROOT).with_suffix("").parts))
        if mod.startswith("torchcal.cli"):
            continue
        found = [s for s in flag_strings(p) if (mod, s) not in COMMANDS_QUOTED]
        if found:
            bad[mod] = found
    assert not bad, bad
    # the checker is not vacuous: the command line's own strings are found
    assert any("--force" in s for s in flag_strings(ROOT / "cli" / "_args.py"))
