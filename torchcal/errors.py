"""The one exception type for user mistakes.

`InputError` is a `ValueError`: library callers can catch either. The command line
turns it into one line on stderr and exit status 2, never a traceback. Its message must
name what is wrong and where (file, row, column, option or argument) and what was
expected.
"""


class InputError(ValueError):
    """Bad input from a user: a file, an option, an argument.

    fix: optional (keyword, value) that corrects the mistake, e.g. ``("length_unit", "m")``:
    the message ends with ``; pass length_unit='m'`` for library callers, and the command
    line writes its own option instead (``; pass --length-unit m``, `command_line`). A list
    value is one option with several words (``("effects", ["base_frame", "tool_offset"])``
    -> ``--effects base_frame tool_offset``); True is a switch (``("tool", True)`` -> ``--tool``)."""

    def __init__(self, message: str = "", *, fix: tuple[str, str] | None = None):
        self.message, self.fix = message, fix
        super().__init__(message if fix is None else f"{message}; pass {fix[0]}={fix[1]!r}")

    def command_line(self) -> str:
        """The message with the fix as a command-line option (``--length-unit m``)."""
        if self.fix is None:
            return str(self)
        flag = f"--{self.fix[0].replace('_', '-')}"
        if self.fix[1] is True:  # a switch (tool=True -> --tool)
            return f"{self.message}; pass {flag}"
        value = " ".join(self.fix[1]) if isinstance(self.fix[1], (list, tuple)) else self.fix[1]
        return f"{self.message}; pass {flag} {value}"


class OutputExistsError(InputError):
    """An output file exists and replacing it was not asked for (``force=False``).

    The library's message names the file only; the command line adds its own hint
    (``pass --force``)."""


def number_argument(name: str, value, *, integer: bool = False, above=None, at_least=None):
    """`value` of the library argument `name` when it is a finite number (an integer with
    `integer`; booleans are not numbers) above `above` / at least `at_least`; else one
    InputError naming the argument, what was expected and what was given. Returns it as
    float (int with `integer`)."""
    import math
    import numbers

    kind = numbers.Integral if integer else numbers.Real
    ok = not isinstance(value, bool) and isinstance(value, kind) and math.isfinite(value)
    ok = ok and (above is None or value > above) and (at_least is None or value >= at_least)
    if not ok:
        what = "an integer" if integer else "a finite number"
        bound = f" > {above}" if above is not None else f" >= {at_least}" if at_least is not None else ""
        raise InputError(f"{name}: expected {what}{bound}, got {value!r}")
    return int(value) if integer else float(value)


class DataError(InputError):
    """An InputError about measurements as a whole (too few poses for the model) raised
    where their file is not known: the front door (`torchcal.api`) puts the file's name in
    front (`about`)."""

    def about(self, source) -> "DataError":
        """The same error naming `source` (a path) first; itself when source is None."""
        if source is None or self.message.startswith(f"{source}: "):
            return self
        return DataError(f"{source}: {self.message}", fix=self.fix)
