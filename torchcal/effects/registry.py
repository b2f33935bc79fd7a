"""The one registry of effects: built-in ones, user modules and installed packages.

Every effect name that a spec (``NAME[:J,...]``), a model file, `simulate`, `diagnose`
or `discover` accepts is a key of `REGISTRY` (name -> `Effect` subclass). Three ways in:

- the built-in effects (registered when `torchcal.effects` is imported);
- ``load_module(path)`` / ``--effects-module FILE.py``: runs a Python file and registers
  every `Effect` subclass it defines with a non-empty ``name``;
- the ``torchcal.effects`` entry-point group of installed packages, read once on the
  first look-up (`load_entry_points`): each entry point names an `Effect` subclass
  (``joint_coupling = "mypkg.coupling:JointCoupling"``) or a module whose subclasses
  are all registered.

docs/effects.md shows how to write an effect.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import inspect
import re
import sys
import warnings
from collections.abc import Mapping
from pathlib import Path

from torchcal.effects.base import Effect
from torchcal.errors import InputError

ENTRY_POINT_GROUP = "torchcal.effects"
_NAME_RE = re.compile(r"[a-z][a-z0-9_]*", re.ASCII)

#: effect name -> Effect subclass: the one registry.
REGISTRY: dict[str, type[Effect]] = {}
_BUILTIN: set[str] = set()
_entry_points_loaded = False


def _check_class(cls, where: str) -> str:
    if not (isinstance(cls, type) and issubclass(cls, Effect)) or cls is Effect:
        raise InputError(f"{where}: {cls!r} is not a subclass of torchcal.effects.Effect")
    name = cls.name
    if not isinstance(name, str) or not _NAME_RE.fullmatch(name):
        raise InputError(f"{where}: effect class {cls.__qualname__} needs a `name` of lower-case "
                         f"letters, digits and '_' (starting with a letter), got {name!r}")
    if name == "geometric":
        raise InputError(f"{where}: 'geometric' is always part of a model; choose another name "
                         f"for {cls.__qualname__}")
    return name


def _same_class(a, b) -> bool:
    """The same class, or the same class defined again by loading its file again."""
    if a is b:
        return True
    try:
        return a.__qualname__ == b.__qualname__ and inspect.getsourcefile(a) == inspect.getsourcefile(b)
    except TypeError:
        return False


def register_effect(cls, where: str = "register_effect", builtin: bool = False):
    """Add the Effect subclass `cls` under ``cls.name``; returns cls (usable as a decorator).

    Raises InputError for a class that is not an Effect subclass, a bad name, or a name
    already taken by another class (built-in names cannot be replaced).
    """
    name = _check_class(cls, where)
    old = REGISTRY.get(name)
    if old is not None and not _same_class(old, cls):
        owner = "a built-in effect" if name in _BUILTIN else f"{old.__module__}.{old.__qualname__}"
        raise InputError(f"{where}: effect name {name!r} of {cls.__qualname__} is already taken by {owner}")
    if old is not None and name in _BUILTIN and old is not cls:
        raise InputError(f"{where}: effect name {name!r} is a built-in effect")
    REGISTRY[name] = cls
    if builtin:
        _BUILTIN.add(name)
    return cls


def unregister_effect(name: str) -> None:
    """Remove a user effect (tests, interactive sessions); built-in effects stay."""
    if name in _BUILTIN:
        raise InputError(f"unregister_effect: {name!r} is a built-in effect")
    REGISTRY.pop(name, None)


def is_builtin(name: str) -> bool:
    return name in _BUILTIN


def effect_classes(module) -> list[type[Effect]]:
    """The Effect subclasses with a name defined in `module` (not imported into it)."""
    return [c for _, c in inspect.getmembers(module, inspect.isclass)
            if issubclass(c, Effect) and c is not Effect and c.__module__ == module.__name__
            and c.__dict__.get("name")]


def load_module(path) -> list[str]:
    """Run the Python file `path` and register the Effect subclasses it defines.

    Returns their names in definition order. Raises InputError (one line naming the file)
    when the file is missing, fails to import, or defines no Effect subclass with a name.
    """
    p = Path(path)
    where = str(path)
    if not p.is_file():
        raise InputError(f"{where}: no such file")
    mod_name = "torchcal_user_effects_" + re.sub(r"\W", "_", p.stem)
    spec = importlib.util.spec_from_file_location(mod_name, p)
    if spec is None or spec.loader is None:
        raise InputError(f"{where}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    sys.modules[mod_name] = module  # dataclasses and pickling look their module up here
    try:
        spec.loader.exec_module(module)
    except Exception as exc:  # noqa: BLE001 - any failure of user code is bad input
        sys.modules.pop(mod_name, None)
        line = ""
        tb = exc.__traceback__
        while tb is not None:
            if tb.tb_frame.f_code.co_filename == str(p):
                line = f" (line {tb.tb_lineno})"
            tb = tb.tb_next
        raise InputError(f"{where}: failed to load{line}: {type(exc).__name__}: {exc}") from None
    classes = sorted(effect_classes(module), key=lambda c: inspect.getsourcelines(c)[1])
    if not classes:
        raise InputError(f"{where}: defines no subclass of torchcal.effects.Effect with a `name`")
    for c in classes:
        register_effect(c, where)
    return [c.name for c in classes]


def load_entry_points(force: bool = False) -> list[str]:
    """Register the effects of installed packages (entry-point group ``torchcal.effects``).

    Read once (again with `force`). An entry point that fails to load or names no Effect
    subclass is skipped with a warning naming it. Returns the names registered.
    """
    global _entry_points_loaded
    if _entry_points_loaded and not force:
        return []
    _entry_points_loaded = True
    names = []
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        where = f"entry point {ep.name} = {ep.value} (group {ENTRY_POINT_GROUP})"
        try:
            obj = ep.load()
            classes = effect_classes(obj) if inspect.ismodule(obj) else [obj]
            if not classes:
                raise InputError(f"{where}: module defines no Effect subclass with a `name`")
            for c in classes:
                names.append(register_effect(c, where).name)
        except Exception as exc:  # noqa: BLE001 - a broken plugin must not stop torchcal
            warnings.warn(f"torchcal: skipped {where}: {exc}", stacklevel=2)
    return names


def lookup(name: str) -> type[Effect] | None:
    """The class registered as `name` (installed packages are read first), or None."""
    load_entry_points()
    return REGISTRY.get(name)


class TakesJoints(Mapping):
    """Read-only view name -> whether the effect acts on joints, over `REGISTRY`
    (installed packages included); it follows later registrations."""

    def __getitem__(self, name):
        cls = lookup(name)
        if cls is None:
            raise KeyError(name)
        return bool(cls.takes_joints)

    def __iter__(self):
        load_entry_points()
        return iter(list(REGISTRY))

    def __len__(self):
        load_entry_points()
        return len(REGISTRY)

    def __repr__(self):
        return repr(dict(self))
