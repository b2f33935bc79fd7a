"""Argument types and option groups shared by the sub-commands."""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from contextlib import contextmanager


def _number(text: str, kind, ok, expected: str):
    """The one number parser: `kind`(text) that satisfies `ok`, else an argparse error
    naming what was expected and what was given."""
    try:
        v = kind(text)
    except ValueError:
        v = None
    if v is None or not (math.isfinite(v) and ok(v)):
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
    return v


def positive_int(text: str) -> int:
    return _number(text, int, lambda v: v >= 1, "a positive integer")


def seed_int(text: str) -> int:
    """A --seed: an integer 0 .. 2**32 - 1. numpy refuses a negative seed and torch one
    beyond 64 bits; the seeds derived from it (e.g. seed * 1_000_003 + 17 in
    `torchcal.simulation.virtual_robot`) stay within 64 bits for 32-bit seeds."""
    return _number(text, int, lambda v: 0 <= v < 2 ** 32, "an integer seed 0..4294967295")


def fold_count(text: str) -> int:
    """--folds: an integer >= 2 (one fold leaves no pose to hold out)."""
    return _number(text, int, lambda v: v >= 2, "an integer >= 2 (one fold holds nothing out)")


def positive_float(text: str) -> float:
    return _number(text, float, lambda v: v > 0, "a positive number")


def nonneg_float(text: str) -> float:
    return _number(text, float, lambda v: v >= 0, "a number >= 0")


def finite_float(text: str) -> float:
    """Any finite number (a temperature, a height): 'nan' and 'inf' are refused by the option
    (a NaN temperature gave a traceback in plan, a NaN floor 'workspace filter too strict')."""
    return _number(text, float, lambda v: True, "a finite number")


def share(text: str) -> float:
    """A share of a whole in (0, 1] (plan --reach: of the arm's full stretch): 0 keeps
    nothing, and a value above 1 is no share (a length in mm, a percentage)."""
    return _number(text, float, lambda v: 0 < v <= 1, "a share in (0, 1] (1: no limit)")


FORCE_HINT = "pass --force to replace it"

#: the preset robots' names, for option help built without importing torch
#: (tests/test_cli_startup.py checks them against torchcal.robots.robot.PRESETS)
PRESET_NAMES = ("kr1000titan", "puma560", "ur5e")


def add_force(p):
    p.add_argument("--force", action="store_true", help="replace existing output files")


def add_cv(p):
    """--folds and --seed of the cross-validated commands (diagnose, discover)."""
    p.add_argument("--folds", type=fold_count, default=5, help="cross-validation folds (default 5)")
    p.add_argument("--seed", type=seed_int, default=0, help="seed of the fold assignment")


def add_effects_module(p):
    p.add_argument("--effects-module", action="append", default=[], metavar="FILE.py",
                   help="Python file defining effects of your own (torchcal.effects.Effect "
                        "subclasses, registered by their `name`); repeatable. See docs/effects.md")


def load_effects_modules(args) -> None:
    """Register the effects of every ``--effects-module`` file (InputError on a bad one)."""
    from torchcal.effects.registry import load_module

    from torchcal.errors import InputError

    for path in getattr(args, "effects_module", None) or []:
        try:
            load_module(path)
        except InputError as exc:  # the library names the file; the command line its option
            raise InputError(f"--effects-module {exc}") from None


def add_device(p, what: str = "the computation"):
    """``--device cpu|cuda|cuda:N`` (default cpu)."""
    p.add_argument("--device", default="cpu", metavar="DEVICE",
                   help=f"where {what} runs: cpu (default), cuda or cuda:N (a GPU; refused when torch sees none)")


def device_of(args):
    """The torch.device of ``--device``: one InputError line when it is not cpu / cuda[:N]
    or when CUDA is not available (before any work)."""
    import re

    import torch

    from torchcal.errors import InputError

    text = (getattr(args, "device", None) or "cpu").strip().lower()
    if not re.fullmatch(r"cpu|cuda(:\d+)?", text):
        raise InputError(f"--device: expected cpu, cuda or cuda:N, got {text!r}")
    if text.startswith("cuda"):
        if not torch.cuda.is_available():
            why = "torch was built without CUDA" if torch.version.cuda is None else "no GPU is visible"
            raise InputError(f"--device {text}: CUDA is not available here ({why}); use --device cpu")
        index = int(text.split(":")[1]) if ":" in text else 0
        if index >= torch.cuda.device_count():
            raise InputError(f"--device {text}: only {torch.cuda.device_count()} CUDA device(s) visible")
    return torch.device(text)


def add_viz(p):
    p.add_argument("--rrd", help="write a rerun recording (.rrd) here")
    p.add_argument("--plots", help="write PNG figures into this folder")


def check_outputs(outputs, force: bool, inputs=()) -> None:
    """Fail before any work (and before any file is written) when an output cannot be
    written: it exists without --force, it is an input file (--force included), two
    outputs share a path, or its folder does not exist or takes no new file. `outputs`:
    (option, path or None) pairs."""
    from pathlib import Path

    from torchcal.errors import InputError, OutputExistsError
    from torchcal.io.files import check_output

    seen = {}
    from torchcal.io.files import same_file

    for opt, path in outputs:
        if path is None:
            continue
        p = Path(path)
        r = p.resolve()
        for src in inputs:
            if src is not None and same_file(p, src):
                raise InputError(f"{path}: {opt} names the input file {src}; refusing to write over it")
        if r in seen:
            raise InputError(f"{path}: {opt} and {seen[r]} name the same file")
        seen[r] = opt
        if p.is_dir():
            raise InputError(f"{path}: {opt} names a folder; expected a file")
        try:
            check_output(p, force)  # the one overwrite rule (torchcal.io.files)
        except OutputExistsError as exc:
            raise InputError(f"{exc}; {FORCE_HINT}") from None
        except InputError as exc:
            if p.parent.exists():  # a folder that takes no new file
                raise InputError(f"{exc} ({opt})") from None
            raise InputError(f"{path}: {opt}: folder {p.parent} does not exist") from None


def robot_inputs(robot) -> list:
    """Files a --robot value reads, never to be written over: the robot file, and the URDF
    it records it was imported from; [] for a preset or None."""
    import json
    from pathlib import Path

    if robot is None or not Path(robot).is_file():
        return []
    try:
        urdf = (json.loads(Path(robot).read_text()).get("urdf") or {}).get("path")
    except (ValueError, OSError, AttributeError):  # not a robot file: loading it says so
        urdf = None
    return [robot] + ([urdf] if isinstance(urdf, str) else [])


def check_folder(opt: str, path) -> None:
    """Fail before any work when an output folder option names an existing file."""
    from pathlib import Path

    from torchcal.errors import InputError

    if path is not None and Path(path).exists() and not Path(path).is_dir():
        raise InputError(f"{path}: {opt} expects a folder, but this is a file")


def make_folder(opt: str, path) -> None:
    """Create the output folder `path` of option `opt` (and its parents) when missing;
    InputError (one line naming the option) when the system refuses."""
    from pathlib import Path

    from torchcal.errors import InputError

    try:
        Path(path).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{path}: {opt}: cannot create the folder: {(exc.strerror or str(exc)).lower()}") from None


def plot_outputs(folder, names) -> list:
    """[("--plots", folder/name)...] for `check_outputs`, to check the PNGs a ``--plots``
    folder will get before any work ([] without --plots); creates the folder when missing
    (after `check_folder`)."""
    from pathlib import Path

    if folder is None:
        return []
    check_folder("--plots", folder)
    make_folder("--plots", folder)
    return [("--plots", Path(folder) / n) for n in names]


def add_units(p, what: str = "measurements"):
    """--length-unit mm|m and --angle-unit deg|rad for a command that reads `what`."""
    p.add_argument("--length-unit", choices=["mm", "m"], default="mm",
                   help=f"unit of x, y, z in the {what} (default mm)")
    p.add_argument("--angle-unit", choices=["deg", "rad"], default="deg",
                   help=f"unit of the joint angles (and rx, ry, rz) in the {what} (default deg)")


def units(args) -> dict:
    """{'length_unit', 'angle_unit'} from parsed args (defaults mm, deg)."""
    return {"length_unit": getattr(args, "length_unit", "mm") or "mm",
            "angle_unit": getattr(args, "angle_unit", "deg") or "deg"}


def sigma_deg(args, m) -> float | None:
    """--sigma-deg of `args` (None when not given: the library's default) for the
    measurements `m`; given for data without rx, ry, rz it weighs nothing
    (`torchcal.calibration.checks.orientation.sigma_deg_unused`), and one warning line on
    stderr, naming the option, says so at once; the library's `UnusedSigmaWarning`, which
    says the same with its keyword, is then ignored for the rest of the command (called
    inside the command's warning block, `warnings_to_stderr`, which restores the filters)."""
    from torchcal.calibration.checks.orientation import UnusedSigmaWarning, sigma_deg_unused

    given = getattr(args, "sigma_deg", None)
    if sigma_deg_unused(given, m):
        sys.stderr.write(f"torchcal: warning: --sigma-deg {given:g} is ignored: the data have no rx, ry, rz "
                         f"columns (it weighs measured orientations against positions)\n")
        warnings.filterwarnings("ignore", category=UnusedSigmaWarning)
    return given


@contextmanager
def warnings_to_stderr(*categories):
    """Warnings of `categories` raised in the block become one ``torchcal: warning: ...``
    line each (repeats once) on stderr once the block ends (none when it raises: the error
    line is what the user reads); other warnings pass on unchanged."""
    with warnings.catch_warnings(record=True) as caught:
        for c in categories:
            warnings.simplefilter("always", c)
        yield
    seen = set()
    for w in caught:
        if issubclass(w.category, categories):
            if str(w.message) not in seen:
                sys.stderr.write(f"torchcal: warning: {w.message}\n")
            seen.add(str(w.message))
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)


def read_data(path, robot, args=None, check: bool = True):
    """The measurement CSV for `robot`, in the units of `args` (--length-unit,
    --angle-unit; default mm, deg).

    Joint angles outside the preset's nominal limits are a warning (one line on
    stderr), not an error: the presets' limits are data-sheet values, and real robots
    (and other simulators' sessions) are measured at or beyond them. With `check`, the
    unit plausibility check (torchcal.calibration.checks.units.check_units) refuses
    metres read as mm and radians read as degrees with one line naming the fix.
    """
    from torchcal.calibration.checks.units import check_units
    from torchcal.io.measurement_csv import FILE_WARNINGS, read_measurements

    u = units(args)
    with warnings_to_stderr(*FILE_WARNINGS):
        m = read_measurements(path, robot=robot, **u)
        if check:
            check_units(m, robot, where=str(path), **u)
    return m


def add_robot(p, required: bool = True, default=None, what: str = "the robot") -> None:
    """``--robot ROBOT``: a preset name or the path of a robot file (the one shared option)."""
    extra = f" (default {default})" if default is not None else ""
    p.add_argument("--robot", required=required, default=default, metavar="ROBOT",
                   help=f"{what}: a preset ({', '.join(PRESET_NAMES)}) or the path of a robot "
                        f"file (.json, docs/robots.md){extra}")


def load_robot(text):
    """The `Robot` named by a ``--robot`` value (preset or robot-file path); None for None."""
    if text is None:
        return None
    from torchcal.io.robot_file import robot

    return robot(text)


def check_data_joints(data, robot, model_path) -> None:
    """Refuse (one line naming both) a measurement CSV whose q columns are not the
    model's joint count: data of another robot."""
    import csv
    import re
    from pathlib import Path

    from torchcal.errors import InputError

    p = Path(data)
    if not p.is_file():
        return  # the reader's own message
    with open(p, newline="", encoding="utf-8-sig", errors="replace") as fh:
        header = next(csv.reader(fh), [])
    qs = [h.strip() for h in header if re.fullmatch(r"q\d+", h.strip())]
    n = len(qs)
    # only a well-formed header (q1..qN once each) is another robot's; else the reader's message
    if n and sorted(qs) == sorted(f"q{k}" for k in range(1, n + 1)) and n != robot.n:
        raise InputError(f"{data}: line 1: found {n} joint columns (q1..q{n}), expected {robot.n} joints: "
                         f"{model_path} is a model of robot {robot.name!r} with {robot.n} joints; refusing to "
                         f"apply it to data of another robot")
