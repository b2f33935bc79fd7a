"""``torchcal ... | head``: standard output closed by its reader ends quietly.

Once the reader has gone, what the command still prints is dropped (standard output is
pointed at the null device), and the command finishes its work (files are still written)
and exits with its own status: no "Broken pipe" error line and no traceback.
"""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager


class _DropOnBrokenPipe:
    """A text stream proxy: writes after a broken pipe go nowhere."""

    def __init__(self, stream):
        self._stream = stream
        self.broken = False

    def _break(self) -> None:
        self.broken = True
        try:  # the interpreter's last flush of the real stream then succeeds, silently
            fd = os.open(os.devnull, os.O_WRONLY)
            os.dup2(fd, self._stream.fileno())
            os.close(fd)
        except (OSError, ValueError, AttributeError):
            pass

    def write(self, text):
        if not self.broken:
            try:
                return self._stream.write(text)
            except BrokenPipeError:
                self._break()
        return len(text)

    def flush(self):
        if not self.broken:
            try:
                self._stream.flush()
            except BrokenPipeError:
                self._break()

    def __getattr__(self, name):
        return getattr(self._stream, name)


@contextmanager
def quiet_broken_pipe():
    """Inside the block, ``sys.stdout`` drops what a closed pipe can no longer take."""
    real = sys.stdout
    proxy = _DropOnBrokenPipe(real)
    sys.stdout = proxy
    try:
        yield proxy
    finally:
        proxy.flush()
        sys.stdout = real
