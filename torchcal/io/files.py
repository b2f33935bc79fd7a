"""Files: atomic writes and deterministic JSON.

Every write goes through `atomic_write`: a temporary file in the target's folder, then
`os.replace`, so a failure never leaves a half-written output. An existing output is
only replaced with ``force=True``; an input file is never written over (``force``
included; `same_file`). A folder that takes no new file is found before the work, and
every message names the user's path, never the temporary one or a bare errno.
"""

from __future__ import annotations

import csv
import io
import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

from torchcal.errors import InputError, OutputExistsError


def csv_rows(path, what: str, expected: str) -> list[tuple[int, list[str]]]:
    """Every row of the CSV text file `path` as (file line number, fields), blank rows
    included: UTF-8, a byte order mark (spreadsheets write one) dropped, any newline
    convention. `what` names the file in messages ("measurement file"), `expected` says
    what its CSV holds. One InputError naming `path` when the file is missing, not a
    regular file, not UTF-8, unreadable or not valid CSV (with the line)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: {what} does not exist")
    if not path.is_file():
        raise InputError(f"{path}: {what} is not a regular file")
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a UTF-8 text file (byte {exc.start}); expected a CSV {expected}") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read the {what}: {exc.strerror or exc}") from None
    reader = csv.reader(io.StringIO(text, newline=None), strict=True)
    rows = []
    try:
        for fields in reader:
            rows.append((reader.line_num, fields))
    except csv.Error as exc:
        raise InputError(f"{path}: line {reader.line_num}: not valid CSV: {exc}") from None
    return rows


def same_file(a, b) -> bool:
    """Whether paths a and b name one file: the same resolved path, or (both existing) the
    same file on disk (a hard link, another mount of it)."""
    a, b = Path(a), Path(b)
    if a.resolve() == b.resolve():
        return True
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def check_output(path, force: bool = False, inputs=()) -> Path:
    """The overwrite rule (library and command line alike): `path` must not be one of
    `inputs` (`same_file`; `force` does not change that), must not exist unless `force`
    (OutputExistsError), must not be a folder nor another non-regular file (a device such as
    /dev/null, a pipe: the rename would replace it, `force` or not), its folder must exist and take a new file
    (tried: a temporary file is created and removed there), all before any work.
    Returns `path` as a Path."""
    path = Path(path)
    for src in inputs:
        if src is not None and same_file(path, src):
            raise InputError(f"{path}: refusing to write over the input file {src}")
    if path.is_dir():  # before "output exists": --force would not help
        raise InputError(f"{path}: is a folder, expected a file name")
    if path.exists() and not force:
        raise OutputExistsError(f"{path}: output exists")
    if path.exists() and not path.is_file():  # the rename would replace a device node or a pipe
        raise InputError(f"{path}: not a regular file (a device, pipe or socket), expected a file name")
    if not path.parent.exists():
        raise InputError(f"{path}: folder {path.parent} does not exist")
    try:
        with tempfile.TemporaryFile(dir=path.parent):
            pass
    except OSError as exc:
        raise InputError(f"{path}: cannot write in folder {path.parent}: {(exc.strerror or str(exc)).lower()}") \
            from None
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
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:  # the user's path in the message, not the temporary name
        raise InputError(f"{path}: cannot write: {(exc.strerror or str(exc)).lower()}") from None
    try:
        umask = os.umask(0o022)  # read the umask (there is no getter), then put it back
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)  # normal file permissions, not mkstemp's 0600
        with os.fdopen(fd, mode) as fh:
            yield fh
        os.replace(tmp, path)
    except BaseException as exc:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(exc, OSError) and not isinstance(exc, InputError):
            raise InputError(f"{path}: cannot write: {(exc.strerror or str(exc)).lower()}") from None
        raise


@contextmanager
def all_or_none(paths):
    """Outputs written together (split's two files, export's robot file, URDF and table):
    when the block raises (an error, a full disk, Ctrl-C), those of `paths` (None skipped)
    that did not exist before it are removed again, so no half set is left behind; one it
    replaced (force) keeps what was written."""
    new = [Path(p) for p in paths if p is not None and not os.path.lexists(p)]
    try:
        yield
    except BaseException:
        for p in new:
            if p.is_file():
                p.unlink()
        raise


def dumps_json(obj) -> str:
    """Deterministic JSON text (sorted keys, fixed float repr) for reports and models."""
    return json.dumps(obj, indent=2, sort_keys=True, allow_nan=False) + "\n"


def write_json(path, obj, force: bool = False, inputs=()) -> Path:
    """Atomically write `obj` as deterministic JSON."""
    return atomic_write(path, dumps_json(obj), force=force, inputs=inputs)


class _DuplicateKey(Exception):
    """A key given twice in one JSON object (the parser would keep the last in silence)."""


def _no_duplicates(pairs: list) -> dict:
    """object_pairs_hook of `read_json`: the dict of `pairs`, _DuplicateKey(key) for a key
    given twice in one object."""
    seen = set()
    for k, _ in pairs:
        if k in seen:
            raise _DuplicateKey(k)
        seen.add(k)
    return dict(pairs)


def read_json(path, what: str = "JSON file") -> dict:
    """Read a JSON object; one clear InputError for a missing file, bad JSON or a key given
    twice in one object (e.g. two "tool" matrices in a robot file: JSON keeps the last in
    silence), naming the key and the lines it appears on."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: {what} does not exist")
    try:
        text = path.read_text(encoding="utf-8-sig")  # a byte order mark (Windows editors) is no content
        obj = json.loads(text, object_pairs_hook=_no_duplicates)
    except _DuplicateKey as exc:
        import re

        key = exc.args[0]
        lines = [text.count("\n", 0, m.start()) + 1 for m in re.finditer(re.escape(json.dumps(key)) + r"\s*:", text)]
        raise InputError(f"{path}: not a valid {what}: key {key!r} given twice in one object"
                         + (f" (the key is on lines {', '.join(map(str, lines))})" if lines else "")
                         + "; JSON would keep the last in silence: remove one") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        first = text.split("\n", 1)[0].strip() if isinstance(exc, json.JSONDecodeError) else ""
        if isinstance(exc, json.JSONDecodeError) and not text.strip():
            raise InputError(f"{path}: not a valid {what}: the file is empty") from None
        if "," in first and first[:1] not in "{[":  # a measurement or targets table given as the JSON
            raise InputError(f"{path}: not a valid {what}: a CSV table (first line {first[:60]!r}), "
                             f"not JSON") from None
        raise InputError(f"{path}: not a valid {what}: {exc}") from None
    if not isinstance(obj, dict):
        raise InputError(f"{path}: expected a JSON object in the {what}")
    return obj
