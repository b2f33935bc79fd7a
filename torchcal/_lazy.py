"""Lazy re-exports for a package's ``__init__`` (PEP 562), so that importing one module of
a package does not import all of its siblings (a sub-command imports only what it uses).

    __getattr__, __dir__, __all__ = attach(__name__, {"torchcal.io.files": ["atomic_write", ...]})

The names load from their module on first use and are then cached on the package. A
name that is also a submodule's name (``torchcal.diagnosis.diagnose``, the function, in
the module of that name) is bound at once: once the submodule is imported, Python sets
the package attribute to the module and ``__getattr__`` would never be asked.
"""

from __future__ import annotations

import importlib
import sys


def attach(package: str, exports: dict[str, list[str]]):
    """(__getattr__, __dir__, __all__) for `package` re-exporting {module: [names]}."""
    where = {name: module for module, names in exports.items() for name in names}

    def __getattr__(name):
        module = where.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        setattr(sys.modules[package], name, value)  # later look-ups skip this function
        return value

    modules = {module.rsplit(".", 1)[-1] for module in exports}
    for name in set(where) & modules:
        setattr(sys.modules[package], name, getattr(importlib.import_module(where[name]), name))

    def __dir__():
        return sorted(set(vars(sys.modules[package])) | set(where))

    return __getattr__, __dir__, list(where)
