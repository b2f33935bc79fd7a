"""Dependencies point one way: parse every module's imports (ast, module level and inside
functions) and check the layer rules of docs/design.md.

- inside torchcal, only torchcal.cli imports viz;
- kinematics imports nothing else of torchcal but errors;
- robots, effects, calibration, reliability, partition, diagnosis, simulation, io never
  import workflows or cli; calibration does not import simulation; io does not import cli.
- compute modules do not write files: effects, reliability, partition, diagnosis, simulation
  and measurements import nothing of torchcal.io (io reads and writes their results);
  kinematics and calibration import nothing of torchcal.io either (`torchcal.save` writes
  a fitted model).
- the layers of docs/design.md: every import points down or to a sibling of its layer,
  and the package import graph has no cycle (so siblings never import each other both ways).
- torchcal.rotations, torchcal.statistics and torchcal.metrics import nothing of torchcal;
- a `CalibrationModel` holds no fitted state: no module but its own sets an attribute
  on one (``model.x = ...``, ``cm.x = ...``, ``fit.model.x = ...``, ``setattr``); the
  fitted facts are fields of `FitResult`.


- the library's messages name no command-line option (``--length-unit``): it names its
  keyword (`InputError.fix`) and the command line writes the option;
- the paper's experiment by concept: workflows.paper_config imports only torchcal.errors,
  workflows.paper_report never runs the experiment (no paper_experiment, simulation,
  diagnosis or reliability).
"""

import ast
import functools
import gc
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "torchcal"


@functools.lru_cache(maxsize=None)
def _tree(path: Path) -> ast.Module:
    """The parsed file, parsed once for all the checks below (they only read it)."""
    return ast.parse(path.read_text())


@functools.lru_cache(maxsize=None)
def _nodes(path: Path) -> tuple:
    """Every node of the file, in `ast.walk` order."""
    return tuple(ast.walk(_tree(path)))


@pytest.fixture(scope="module", autouse=True)
def _parsed_once():
    """The parse caches live while this module's tests run, then go: they hold about 670 000
    AST nodes, which every later full collection of the cyclic garbage collector in this test
    process scanned again. Meanwhile the collector is off: the trees hold no reference cycle
    (reference counting frees them), and its full collections while they were being built
    (about 0.15 s each) found nothing."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        for cached in (_tree, _nodes, modules):
            cached.cache_clear()
        if enabled:
            gc.enable()


def imports_of(path: Path) -> set[str]:
    """Absolute module names a file imports (relative imports resolved)."""
    pkg = ["torchcal", *path.relative_to(ROOT).with_suffix("").parts]
    if pkg[-1] == "__init__":
        pkg = pkg[:-1]
    else:
        pkg = pkg[:-1]
    out = set()
    for node in _nodes(path):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(pkg[: len(pkg) - node.level + 1] + ([base] if base else []))
            out.add(base)
            out.update(f"{base}.{a.name}" for a in node.names)
    return out


@functools.lru_cache(maxsize=None)
def modules() -> dict:
    """{module name: the modules it imports} over torchcal (parsed when a test first asks,
    not when the file is collected)."""
    return {".".join(("torchcal", *p.relative_to(ROOT).with_suffix("").parts)): imports_of(p)
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
RULES.append(("torchcal.calibration", ["torchcal.io"]))
# the rotation convention and the generic statistics depend on nothing of torchcal
RULES.append(("torchcal.rotations", ["torchcal"]))
RULES.append(("torchcal.statistics", ["torchcal"]))
RULES.append(("torchcal.metrics", ["torchcal"]))  # accuracy figures of errors: torch only
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
    bad = {m: hits(imps, forbidden) for m, imps in modules().items()
           if (m == pkg or m.startswith(pkg + ".")) and hits(imps, forbidden)}
    assert not bad, f"{pkg} must not import {forbidden}: {bad}"


def test_only_the_cli_imports_viz():
    bad = {m: hits(i, ["viz"]) for m, i in modules().items()
           if not m.startswith("torchcal.cli") and hits(i, ["viz"])}
    assert not bad


def test_the_checker_sees_imports():
    """The parser is not vacuous: known edges are found."""
    assert "torchcal.calibration.lm" in modules()["torchcal.calibration.fit"]
    assert any(i.startswith("torchcal.") for i in modules()["torchcal.cli.fit"])
    assert hits({"torchcal.cli._args"}, ["torchcal.cli"]) and not hits({"torchcal.client"}, ["torchcal.cli"])
    assert "torchcal.reliability.sweep" in modules()["torchcal.io.sweep_csv"]


# -- one kinematic structure: the kernels of torchcal.kinematics.mdh take a Chain -----------
KERNEL_NAMES = {"link_transforms", "fk_frames", "fk_pose", "positions", "fk_positions", "chain_jacobians",
                "param_jacobian", "joint_jacobian", "outer_factors", "outer_angles", "outer_positions"}
SOURCES = sorted(p for d in ("torchcal", "tests", "benchmarks", "viz", "examples")
                 for p in (ROOT.parent / d).rglob("*.py"))


def _calls(path: Path):
    for node in _nodes(path):
        if isinstance(node, ast.Call):
            f = node.func
            yield node, f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", None)


def test_no_module_passes_a_prismatic_keyword_to_a_kernel():
    bad = [f"{p.relative_to(ROOT.parent)}:{c.lineno}" for p in SOURCES for c, name in _calls(p)
           if name in KERNEL_NAMES and any(k.arg in ("prismatic", "table", "base", "tool", "tz") for k in c.keywords)]
    assert not bad, bad


def test_no_module_uses_a_private_kernel_or_the_pris_alias():
    bad = []
    for p in SOURCES:
        for node in _nodes(p):
            if isinstance(node, ast.Attribute) and (node.attr in ("pris", "_positions_kernel")):
                bad.append(f"{p.relative_to(ROOT.parent)}:{node.lineno} .{node.attr}")
    assert not bad, bad


def test_the_kernel_checker_sees_calls():
    """Not vacuous: the model's calls of the position kernel are found."""
    assert any(name == "positions" for _, name in _calls(ROOT / "calibration" / "model.py"))
    assert len(SOURCES) > 100


# -- Context in its own module ---------------------------------------------------------------
CONTEXT_NAMES = {"Context", "make_context", "context_of", "approach_directions"}


def test_context_is_defined_in_its_own_module():
    """Context and its builders are defined in torchcal.effects.context only, and nothing
    imports them from torchcal.effects.base (no alias left there)."""
    defined = {}
    for p in sorted(ROOT.rglob("*.py")):
        for node in _tree(p).body:
            if isinstance(node, (ast.ClassDef, ast.FunctionDef)) and node.name in CONTEXT_NAMES:
                defined.setdefault(node.name, []).append(str(p.relative_to(ROOT.parent)))
    assert defined == {name: ["torchcal/effects/context.py"] for name in CONTEXT_NAMES}
    bad = [f"{p.relative_to(ROOT.parent)}:{node.lineno}" for p in SOURCES for node in _nodes(p)
           if isinstance(node, ast.ImportFrom) and node.module == "torchcal.effects.base"
           and CONTEXT_NAMES & {a.name for a in node.names}]
    assert not bad, bad
    import torchcal.effects as effects
    import torchcal.effects.base as base
    assert effects.Context.__module__ == "torchcal.effects.context"
    assert not CONTEXT_NAMES & set(vars(base))


MODEL_NAMES = ("model", "cm", "calibration_model")


def model_attribute_writes(source: str) -> list[str]:
    """Assignments to an attribute of something named like a CalibrationModel (`MODEL_NAMES`,
    or ``<x>.model``) and setattr calls on a name, as source lines."""
    return _attribute_writes(ast.walk(ast.parse(source)))


def _attribute_writes(nodes) -> list[str]:
    """`model_attribute_writes` of a file's nodes in `ast.walk` order (`_nodes`: parsed once)."""
    out = []
    for node in nodes:
        targets = node.targets if isinstance(node, ast.Assign) else \
            [node.target] if isinstance(node, (ast.AnnAssign, ast.AugAssign)) else []
        for t in targets:
            for x in ast.walk(t):
                if isinstance(x, ast.Attribute) and isinstance(x.ctx, ast.Store):
                    v = x.value
                    if (isinstance(v, ast.Name) and v.id in MODEL_NAMES) or \
                            (isinstance(v, ast.Attribute) and v.attr == "model"):
                        out.append(ast.unparse(t))
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "setattr" and \
                isinstance(node.args[0], (ast.Name, ast.Attribute)):  # not setattr(sys.modules[...], ...)
            out.append(ast.unparse(node))
    return out


def test_no_module_sets_fitted_state_on_a_calibration_model():
    bad = {str(p.relative_to(ROOT)): w for p in sorted(ROOT.rglob("*.py"))
           if p != ROOT / "calibration" / "model.py" and (w := _attribute_writes(_nodes(p)))}
    assert not bad, f"attributes set on a CalibrationModel outside its class (make them FitResult fields): {bad}"


def test_the_model_attribute_checker_sees_writes():
    assert model_attribute_writes("res.model.residual_model = None") == ["res.model.residual_model"]
    assert model_attribute_writes("model.tool_rotation = r\nsetattr(new, a, 1)") == \
        ["model.tool_rotation", "setattr(new, a, 1)"]
    assert model_attribute_writes("x = model.theta\nres.theta = 1\nsetattr(sys.modules[p], n, v)") == []


#: a command-line option inside a string: ``--name`` at the start or after a space, a quote or "("
FLAG = re.compile(r"(?:^|[\s(`'\"])--[a-z]")
#: strings that quote a whole command for the user to run (a command, not an option of this call)
COMMANDS_QUOTED = {("torchcal.io.robot_file", " --base BASE_LINK --tip TIP_LINK --out ROBOT.json")}


def flag_strings(path: Path) -> list[str]:
    """Non-docstring string constants of a file that name a ``--option``."""
    docs = {id(n.body[0].value) for n in _nodes(path)
            if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and n.body
            and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
    return [n.value for n in _nodes(path) if isinstance(n, ast.Constant) and isinstance(n.value, str)
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


# the layers of docs/design.md ("Layers"): a unit is a subpackage or a top-level module
LAYERS = {
    1: ["errors", "rotations", "statistics", "metrics", "threads", "defaults", "_lazy", "folds", "kernel_ridge",
        "native", "kinematics"],
    2: ["robots", "measurements"],
    3: ["effects", "reliability", "partition"],
    4: ["calibration"],
    5: ["diagnosis", "planning", "simulation"],
    6: ["io"],
    7: ["api", "workflows"],
    8: ["cli", "__init__", "__main__"],
}
LAYER_OF = {u: k for k, units in LAYERS.items() for u in units}


def _unit(module: str) -> str:
    parts = module.split(".")
    return "__init__" if len(parts) == 1 else parts[1]


def _unit_edges() -> dict:
    """{(importer unit, imported unit): [(module, import)]} over every torchcal import."""
    edges = {}
    for mod, imps in modules().items():
        for imp in imps:
            if imp.startswith("torchcal.") and _unit(imp) != _unit(mod) and not mod.endswith(".__init__"):
                edges.setdefault((_unit(mod), _unit(imp)), []).append((mod, imp))
    return edges


def test_every_unit_has_a_layer():
    units = {_unit(m) for m in modules()}
    assert units <= set(LAYER_OF), f"place these in docs/design.md's layers and LAYERS: {sorted(units - set(LAYER_OF))}"


def test_imports_point_down_the_layers():
    bad = [f"{a} (layer {LAYER_OF[a]}) -> {b} (layer {LAYER_OF[b]}): {v[0][0]} imports {v[0][1]}"
           for (a, b), v in _unit_edges().items()
           if LAYER_OF[b] > LAYER_OF[a]]
    assert not bad, "\n".join(bad)


def _cycle(edges) -> list | None:
    graph = {}
    for a, b in edges:
        graph.setdefault(a, set()).add(b)
    state, stack = {}, []

    def visit(u):
        state[u] = 1
        stack.append(u)
        for v in sorted(graph.get(u, ())):
            if state.get(v) == 1:
                return stack[stack.index(v):] + [v]
            if v not in state:
                found = visit(v)
                if found:
                    return found
        state[u] = 2
        stack.pop()
        return None

    for u in sorted(graph):
        if u not in state:
            found = visit(u)
            if found:
                return found
    return None


def test_the_package_import_graph_is_acyclic():
    assert _cycle(_unit_edges()) is None, " -> ".join(_cycle(_unit_edges()))


def test_the_cycle_finder_finds_a_cycle():
    assert _cycle({("a", "b"): [], ("b", "c"): [], ("c", "a"): []}) == ["a", "b", "c", "a"]
    assert _cycle({("a", "b"): [], ("b", "c"): []}) is None
