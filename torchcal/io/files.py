"""Files: atomic writes and deterministic JSON.

Every write goes through `atomic_write`: a temporary file in the target's folder, then
`os.replace`, so a failure never leaves a half-written output. An existing output is
only replaced with ``force=True``; an input file is never written over.
"""

from __future__ import annotations

import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

from torchcal.errors import InputError, OutputExistsError


def check_output(path, force: bool = False, inputs=()) -> Path:
    """The overwrite rule (library and command line alike): `path` must not be one of
    `inputs`, must not exist unless `force` (OutputExistsError), must not be a folder, and its
    folder must exist.
    Returns `path` as a Path."""
    path = Path(path)
    for src in inputs:
        if src is not None and Path(src).exists() and path.exists() and path.resolve() == Path(src).resolve():
            raise InputError(f"{path}: refusing to write over the input file")
    if path.exists() and not force:
        raise OutputExistsError(f"{path}: output exists")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a file name")
    if not path.parent.exists():
        raise InputError(f"{path}: folder {path.parent} does not exist")
    return path


def atomic_write(path, data: str | bytes, force: bool = False, inputs=()) -> Path:
    """Write `data` to `path` atomically, after `check_output(path, force, inputs)`.

    Raises OutputExistsError if `path` exists and not `force`, InputError if `path` is
    one of `inputs` or its folder does not exist.
    """
    with atomic_open(path, "wb" if isinstance(data, bytes) else "w", force=force, inputs=inputs) as fh:
        fh.write(data)
    return Path(path)


@contextmanager
def atomic_open(path, mode: str = "w", force: bool = False, inputs=()):
    """A file object for writing `path` piece by piece: a temporary file in its folder that
    replaces `path` when the block ends (removed, `path` untouched, on an error)."""
    path = check_output(path, force, inputs)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        umask = os.umask(0o022)  # read the umask (there is no getter), then put it back
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)  # normal file permissions, not mkstemp's 0600
        with os.fdopen(fd, mode) as fh:
            yield fh
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def dumps_json(obj) -> str:
    """Deterministic JSON text (sorted keys, fixed float repr) for reports and models."""
    return json.dumps(obj, indent=2, sort_keys=True, allow_nan=False) + "\n"


def write_json(path, obj, force: bool = False, inputs=()) -> Path:
    """Atomically write `obj` as deterministic JSON."""
    return atomic_write(path, dumps_json(obj), force=force, inputs=inputs)


def read_json(path, what: str = "JSON file") -> dict:
    """Read a JSON object; one clear InputError for a missing file or bad JSON."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: {what} does not exist")
    try:
        obj = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a valid {what}: {exc}") from None
    if not isinstance(obj, dict):
        raise InputError(f"{path}: expected a JSON object in the {what}")
    return obj
