"""Progress of a long command on stderr, so that nothing is silent for more than a second.

`progress(command, what)` wraps a step of a command (discover, diagnose, evaluate
--plots, plan). On a terminal, one status line ``torchcal COMMAND: WHAT ... 12 s`` is
redrawn in place every half second by a background thread and cleared when the step
ends. Off a terminal (a pipe, a log file, a test) there is no redrawing: one plain line
when the step starts and one with its time when it ends, so that a log says what ran
and for how long without a line per second. stdout (the command's results) is never
touched.
"""

from __future__ import annotations

import sys
import threading
import time
from contextlib import contextmanager

INTERVAL_S = 0.5


@contextmanager
def progress(command: str, what: str, stream=None, interval: float = INTERVAL_S):
    """Report the step `what` of ``torchcal COMMAND`` on `stream` (default stderr) while
    the block runs (module doc); yields nothing."""
    out = sys.stderr if stream is None else stream
    tty = bool(getattr(out, "isatty", lambda: False)())
    label = f"torchcal {command}: {what}"
    start = time.monotonic()
    if not tty:
        out.write(f"{label} ...\n")
        out.flush()
        yield
        out.write(f"{label}: done in {time.monotonic() - start:.1f} s\n")
        out.flush()
        return
    stop = threading.Event()

    def redraw():
        while not stop.wait(interval):
            out.write(f"\r{label} ... {time.monotonic() - start:.0f} s\033[K")
            out.flush()

    out.write(f"{label} ...")
    out.flush()
    thread = threading.Thread(target=redraw, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
        out.write("\r\033[K")  # the status line goes; the results stay on stdout
        out.flush()
