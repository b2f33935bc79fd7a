"""The public API: every subpackage re-exports its public names, and the names a module
declares public (its own ``__all__``) are reachable from the package; options are
keyword-only; one word for a random seed."""

import importlib
import inspect
import pkgutil

import pytest

import torchcal

# cli is the command line, not an API
SUBPACKAGES = sorted(m.name for m in pkgutil.iter_modules(torchcal.__path__) if m.ispkg and m.name != "cli")
# names a module declares public but the package leaves to the module: they share the
# module's name, or are kept qualified (see the package docstrings)
QUALIFIED = {"torchcal.calibration.compensate.compensate", "torchcal.partition.fcm.fcm", "torchcal.io.partition_file.FORMAT",
             "torchcal.io.partition_file.VERSION"}


@pytest.mark.parametrize("name", SUBPACKAGES)
def test_subpackage_reexports(name):
    pkg = importlib.import_module(f"torchcal.{name}")
    assert pkg.__all__, f"torchcal.{name} re-exports nothing"
    for attr in pkg.__all__:
        assert hasattr(pkg, attr), f"torchcal.{name}.__all__ names {attr}, which it lacks"
    for mod in pkgutil.iter_modules(pkg.__path__):
        sub = importlib.import_module(f"torchcal.{name}.{mod.name}")
        for attr in getattr(sub, "__all__", []):
            if f"{sub.__name__}.{attr}" in QUALIFIED:
                continue
            assert getattr(pkg, attr, None) is getattr(sub, attr), f"torchcal.{name} does not re-export {sub.__name__}.{attr}"


def test_the_examples_in_the_issue():
    from torchcal.reliability import r_set
    from torchcal.simulation import VirtualRobot
    from torchcal.robots import Robot, random_poses

    assert callable(r_set) and callable(random_poses) and VirtualRobot and Robot


@pytest.mark.parametrize("fn", ["fit", "evaluate", "diagnose", "discover", "calibrate", "compensate"])
def test_api_options_are_keyword_only_and_named(fn):
    params = inspect.signature(getattr(torchcal, fn)).parameters.values()
    assert not [p for p in params if p.kind is p.VAR_KEYWORD], f"torchcal.{fn} hides options in **kwargs"
    positional = [p.name for p in params if p.kind is p.POSITIONAL_OR_KEYWORD]
    assert len(positional) <= 3, f"torchcal.{fn}: options {positional[3:]} should be keyword-only"


def _public_callables():
    for info in pkgutil.walk_packages(torchcal.__path__, "torchcal."):
        if info.name.startswith("torchcal.cli") or info.name == "torchcal.__main__":
            continue
        mod = importlib.import_module(info.name)
        for name, obj in vars(mod).items():
            if name.startswith("_") or getattr(obj, "__module__", None) != mod.__name__:
                continue
            if inspect.isfunction(obj):
                yield f"{mod.__name__}.{name}", obj
            elif inspect.isclass(obj):
                for mname, meth in vars(obj).items():
                    if inspect.isfunction(meth) and (mname == "__init__" or not mname.startswith("_")):
                        yield f"{mod.__name__}.{name}.{mname}", meth


def test_one_word_for_a_random_seed():
    other = {"generator", "random_state", "rng", "random_seed"}
    bad = [f"{where}({p})" for where, fn in _public_callables()
           for p in inspect.signature(fn).parameters if p in other]
    assert not bad, f"the word for a random seed is `seed`: {bad}"


def test_register_has_one_meaning():
    """`torchcal.register` re-registers a model's measuring frame; adding an effect to the
    registry is `register_effect`, the Kabsch start `register_frame`: no second `register`."""
    import torchcal.calibration.registration as registration
    import torchcal.effects as effects

    assert callable(torchcal.register) and callable(effects.register_effect)
    assert not hasattr(effects, "register") and not hasattr(registration, "register")
