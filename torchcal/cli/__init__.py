"""The `torchcal` command line: one entry point, one sub-command per module.

Each sub-command lives in `torchcal/cli/<name>.py` and exposes
`add_parser(subparsers)` (which sets `func=run` on its parser) and `run(args) -> int`.
This module only composes them and turns user mistakes into one line on stderr
(set TORCHCAL_DEBUG=1 to see the traceback of a ValueError that is not an InputError).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from torchcal.cli._args import FORCE_HINT
from torchcal.errors import InputError, OutputExistsError

#: the sub-commands and their one-line help (the same text as each module's
#: ``add_parser(help=...)``; tests/test_cli_startup.py checks that they agree)
SUMMARIES = {
    "demo": "the paper's whole pipeline on a simulated KR 1000 Titan",
    "simulate": "simulate a measurement session of a virtual robot (CSV)",
    "fit": "fit geometric model + effects to a measurement CSV",
    "evaluate": "errors of a fitted model on a measurement CSV",
    "diagnose": "rank the physical effects the model is missing",
    "discover": "add missing effects round by round",
    "sweep": "error envelopes and R_set over the workspace (CSV)",
    "partition": "hierarchical fuzzy c-means partition of a sweep CSV",
    "calibrate": "interval calibration (global or per zone) from repeated measurements",
    "compensate": "corrected joint commands for target positions",
    "robot": "show a robot's MD-H table; import a URDF as a robot file",
    "export": "calibrated geometry as a robot file, a URDF or an MD-H table",
    "plan": "choose optimal measurement poses (CSV)",
    "accuracy": "predicted TCP sigma of a fitted model over the workspace",
    "register": "re-estimate only the measuring frame of a model on new poses",
    "split": "train / validation split by pose, keeping the approach sequence",
    "report": "a self-contained HTML calibration report",
}
COMMANDS = tuple(SUMMARIES)

#: names of the built-in effects (torchcal.effects registers these classes; the top-level
#: --help lists them without importing torch, tests/test_cli_startup.py checks the list)
BUILTIN_EFFECTS = ("axis_tilt", "backlash", "base_compliance", "base_frame", "cross_coupling", "encoder_scale",
                   "gear_periodic", "gear_transmission", "joint_clearance", "joint_compliance", "joint_periodic",
                   "link_bending",
                   "thermal_expansion", "tool_offset")


#: argparse actions that take an option's value once: a second occurrence would silently
#: replace the first (``--frame base --frame measuring``), so it is refused (a switch given
#: twice changes nothing and passes)
_SINGLE = (argparse._StoreAction,)
_GIVEN = "_torchcal_given"  # namespace attribute: the options seen so far (removed after parsing)


def _once(cls):
    """A subclass of the action class `cls` whose second occurrence on one command line is an
    error naming the option and both values."""

    def __call__(self, parser, namespace, values, option_string=None):
        given = vars(namespace).setdefault(_GIVEN, {})
        if self.dest in given:
            def shown(v):
                return " ".join(map(str, v)) if isinstance(v, list) else str(v)
            raise argparse.ArgumentError(self, f"given twice ({shown(given[self.dest])}, then {shown(values)}); "
                                               "give it once")
        given[self.dest] = values
        cls.__call__(self, parser, namespace, values, option_string)

    return type(f"Once{cls.__name__}", (cls,), {"__call__": __call__})


class _Parser(argparse.ArgumentParser):
    command = None  # the sub-command named on the command line (set by `main`)

    def _add_action(self, action):
        if action.option_strings and isinstance(action, _SINGLE):
            action.__class__ = _once(type(action))
        return super()._add_action(action)

    def error(self, message):  # one line naming the sub-command, exit 2, as for every other user mistake
        prog = f"torchcal {self.command}" if self.prog == "torchcal" and self.command else self.prog
        sys.stderr.write(f"{prog}: error: {message}\n")
        raise SystemExit(2)


DESCRIPTION = """\
torchcal: calibrate serial robots against position measurements (laser tracker style).
Millimetres and degrees in files and on the command line. `torchcal COMMAND --help`
describes each command in full; file formats are in docs/formats.md of the repository.

Effects (for --effects): NAME or NAME:J[,J...] with 1-based joints, e.g. joint_compliance:2,3.
"""


def _effect_names() -> list[str]:
    """Every registered effect name: the registry when it is loaded, else the built-in
    names and those of installed packages' entry points (no torch import)."""
    registry = sys.modules.get("torchcal.effects.registry")
    if registry is not None:
        return sorted(registry.REGISTRY)
    import importlib.metadata

    plugins = [ep.name for ep in importlib.metadata.entry_points(group="torchcal.effects")]
    return sorted(set(BUILTIN_EFFECTS) | set(plugins))


def build_parser(commands=COMMANDS) -> argparse.ArgumentParser:
    """The parser; only the sub-commands in `commands` import their module and get their
    options (the others are listed with their one-line help), so ``--help``,
    ``--version`` and each sub-command import only what they use."""
    from torchcal import __version__

    desc = DESCRIPTION + "Known effects: " + ", ".join(_effect_names()) + "."
    parser = _Parser(prog="torchcal", description=desc, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"torchcal {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser, metavar="COMMAND")
    for name in COMMANDS:
        if name not in commands:
            sub.add_parser(name, help=SUMMARIES[name])
            continue
        module = importlib.import_module(f"torchcal.cli.{name}")
        module.add_parser(sub)
        p = sub.choices[name]  # the whole module docstring is the command's description
        p.description = module.__doc__
        p.formatter_class = argparse.RawDescriptionHelpFormatter
    return parser


def main(argv: list[str] | None = None) -> int:
    from torchcal.cli._pipe import quiet_broken_pipe

    argv = sys.argv[1:] if argv is None else list(argv)
    first = next((a for a in argv if not a.startswith("-")), None)  # the sub-command, named in argparse errors
    _Parser.command = first if first in COMMANDS else None
    args = build_parser((first,) if first in COMMANDS else ()).parse_args(argv)
    vars(args).pop(_GIVEN, None)
    from torchcal import threads

    threads.apply_importing()  # torch imported with its import's objects frozen
    with quiet_broken_pipe():  # `torchcal ... | head` ends quietly
        return _run(args)


def _caused_by(exc: BaseException, kind) -> bool:
    """exc or an exception it was raised while handling (``raise ... from None`` keeps it) is a `kind`."""
    while exc is not None:
        if isinstance(exc, kind):
            return True
        exc = exc.__context__
    return False


def command_line_message(exc: Exception) -> str:
    """The one error line of a library exception: the library names no flag; its fix
    (`InputError.fix`) becomes the option, and a missing output or effect gets the flag hint."""
    spec = sys.modules.get("torchcal.effects.spec")  # not loaded: no effect spec was read (no torch import here)
    text = exc.command_line() if isinstance(exc, InputError) else str(exc)
    if isinstance(exc, OutputExistsError):
        text += f"; {FORCE_HINT}"
    elif spec is not None and _caused_by(exc, spec.UnknownEffectError):
        text = text.replace(spec.UnknownEffectError.HINT, "(an effect of your own: load its file with "
                                                          "--effects-module FILE.py)")
    return text


def _run(args) -> int:
    from torchcal.cli._args import load_effects_modules, warnings_to_stderr

    try:
        # a warning no command turned into its line (a library's, one raised inside a
        # composition such as report) is still one "torchcal: warning:" line, once
        with warnings_to_stderr(UserWarning):
            load_effects_modules(args)  # before any effect spec or model file is read
            return int(args.func(args) or 0)
    except (InputError, ValueError, FileNotFoundError, FileExistsError, IsADirectoryError) as exc:
        if os.environ.get("TORCHCAL_DEBUG") and not isinstance(exc, InputError):
            raise  # developers: the traceback of a ValueError that is not a user mistake
        sys.stderr.write(f"torchcal {args.command}: error: {command_line_message(exc)}\n")
        return 2
    except OSError as exc:  # permission denied, disk full, ...: one line, not a traceback
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        sys.stderr.write(f"torchcal {args.command}: error: {where}{exc.strerror or exc}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("torchcal: interrupted\n")
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
