"""The tests mirror the package: every tests/test_<name>.py is named after what it tests,
a module, package or command of torchcal or viz (`test_fit_robust.py`: the module `fit`,
aspect `robust`), or is one of the few files that check the whole code base (CROSS_CUTTING).
The rule is written in docs/design.md ("Tests")."""

from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: files that check the whole code base rather than one unit: the layer rules, this file,
#: every command's --device, every Jacobian against autodiff, the public names, the Makefile.
CROSS_CUTTING = {"layers", "layout", "device", "jacobians", "public_api", "makefile"}


def unit_names(root: Path = REPO) -> set[str]:
    """Names a test file may be named after: every module (leading '_' dropped) and package
    of torchcal and viz; the commands are the modules of torchcal.cli."""
    names = set()
    for top in ("torchcal", "viz"):
        names.add(top)
        for p in (root / top).rglob("*.py"):
            names.update(d.name for d in p.relative_to(root).parents if d.name)
            if p.stem not in ("__init__", "__main__"):
                names.add(p.stem.lstrip("_"))
    return names


def unnamed(files, names) -> list[str]:
    """The test files among `files` (names 'test_*.py') whose name, after 'test_', is not a
    unit of `names` nor starts with one followed by '_' (an aspect), nor is cross-cutting."""
    out = []
    for f in files:
        stem = f[len("test_"):-len(".py")]
        parts = stem.split("_")
        prefixes = {"_".join(parts[:k]) for k in range(1, len(parts) + 1)}
        if stem not in CROSS_CUTTING and not prefixes & names:
            out.append(f)
    return sorted(out)


def test_every_test_file_is_named_after_what_it_tests():
    files = [p.name for p in (REPO / "tests").glob("test_*.py")]
    assert len(files) > 40
    assert unnamed(files, unit_names()) == []


def test_the_name_checker_finds_a_file_named_after_past_work():
    names = unit_names()
    assert {"fit", "modelfile", "gcv", "discover", "sweep", "viz", "progress", "calibration"} <= names
    files = ["test_one_answer.py", "test_trust_rules.py", "test_fit.py", "test_fit_robust.py",
             "test_measurement_csv_units.py", "test_cli_api.py", "test_layers.py", "test_fitted_model.py"]
    assert unnamed(files, names) == ["test_fitted_model.py", "test_one_answer.py", "test_trust_rules.py"]
