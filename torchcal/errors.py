"""The one exception type for user mistakes.

`InputError` is a `ValueError`: library callers can catch either. The command line
turns it into one line on stderr and exit status 2, never a traceback. Its message must
name what is wrong and where (file, row, column, option or argument) and what was
expected.
"""


class InputError(ValueError):
    """Bad input from a user: a file, an option, an argument."""


class OutputExistsError(InputError):
    """An output file exists and replacing it was not asked for (``force=False``).

    The library's message names the file only; the command line adds its own hint
    (``pass --force``)."""
