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

from torchcal.errors import InputError

COMMANDS = (
    "demo", "simulate", "fit", "evaluate", "diagnose", "discover",
    "sweep", "partition", "calibrate", "compensate",
)


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2, as for every other user mistake
        sys.stderr.write(f"torchcal: error: {message}\n")
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="torchcal", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for name in COMMANDS:
        importlib.import_module(f"torchcal.cli.{name}").add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    from torchcal.cli._args import load_effects_modules

    args = build_parser().parse_args(argv)
    try:
        load_effects_modules(args)  # before any effect spec or model file is read
        return int(args.func(args) or 0)
    except (InputError, ValueError, FileNotFoundError, FileExistsError, IsADirectoryError) as exc:
        if os.environ.get("TORCHCAL_DEBUG") and not isinstance(exc, InputError):
            raise  # developers: the traceback of a ValueError that is not a user mistake
        sys.stderr.write(f"torchcal {args.command}: error: {exc}\n")
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
