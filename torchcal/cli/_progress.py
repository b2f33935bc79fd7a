"""Progress of a long command on stderr, so that nothing is silent for more than a second.

`progress(command, what)` wraps a step of a command (discover, diagnose, evaluate
--plots, plan). A step that ends within DELAY_S = 1 s shows nothing (a refusal stays one
line). On a terminal, one status line ``torchcal COMMAND: WHAT ... 12 s`` is then redrawn
in place every half second by a background thread and cleared when the step ends, so a
refusal that comes late still stays one line. Off a terminal (a pipe, a log file, a test)
there is no redrawing: one plain line with the step's time when it ends well, so that a
log says what ran and for how long, and a refusal is still its one error line. stdout
(the command's results) is never touched.
"""

from __future__ import annotations

import sys
import threading
import time
from contextlib import contextmanager

DELAY_S = 1.0  # a step shorter than this shows nothing
INTERVAL_S = 0.5  # redraw period on a terminal


@contextmanager
def progress(command: str, what: str, stream=None, delay: float | None = None, interval: float = INTERVAL_S):
    """Report the step `what` of ``torchcal COMMAND`` on `stream` (default stderr) while
    the block runs (module doc); delay: seconds before anything shows (default DELAY_S,
    0: at once); yields nothing."""
    out = sys.stderr if stream is None else stream
    tty = bool(getattr(out, "isatty", lambda: False)())
    label = f"torchcal {command}: {what}"
    wait = DELAY_S if delay is None else delay
    start = time.monotonic()
    stop, shown, lock = threading.Event(), threading.Event(), threading.Lock()

    def show():  # on a terminal only
        with lock:
            if stop.is_set():
                return
            out.write(f"\r{label} ... {time.monotonic() - start:.0f} s\033[K")
            out.flush()
            shown.set()

    def run():
        if wait > 0 and stop.wait(wait):
            return
        show()
        while not stop.wait(interval):
            show()

    thread = threading.Thread(target=run, daemon=True)
    if tty:
        thread.start()
    ok = False
    try:
        yield
        ok = True
    finally:
        with lock:
            stop.set()
        if tty:
            thread.join()
            if shown.is_set():
                out.write("\r\033[K")
                out.flush()
        elif ok and time.monotonic() - start >= wait:
            out.write(f"{label}: done in {time.monotonic() - start:.1f} s\n")
            out.flush()
