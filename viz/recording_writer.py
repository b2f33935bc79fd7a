"""The rerun file writer: an ``.rrd`` recording written without a viewer, atomically.

`RecordingWriter` opens the file, hands out its ``rerun.RecordingStream``, and on close
sends the blueprint (the one given, else its `RecordingWriter.layout`), finalises the file
(flush, then disconnect, which writes the footer) and moves it into place. On an error the
half-written file is removed and nothing appears at the target path. It knows nothing of
what is logged: the domain loggers (`viz.recording`) log into its stream through
`stream_of`, which notes the section each one fills, and `viz.recording.RecordingWriter`
lays out the default blueprint for those sections.

Recordings are deterministic in content: the recording id is derived from ``seed``
(`recording_id`), and the ``log_time``/``log_tick`` timelines and the wall-clock start
time property are not written.
"""

from __future__ import annotations

import os
import uuid
from pathlib import Path

import rerun as rr
import rerun.blueprint as rrb

from torchcal.errors import InputError
from torchcal.io.files import check_output
from viz import _common as C

APPLICATION_ID = "torchcal"


def recording_id(seed: int, application_id: str = APPLICATION_ID) -> str:
    """Deterministic recording id (a UUID string) for `application_id` and `seed`."""
    return str(uuid.uuid5(uuid.NAMESPACE_URL, f"torchcal:{application_id}:{int(seed)}"))


def stream_of(rec, section: str) -> rr.RecordingStream:
    """The stream behind `rec` (a RecordingStream or a RecordingWriter); notes `section`
    in the writer's ``sections``."""
    if isinstance(rec, RecordingWriter):
        rec.sections.add(section)
        return rec.stream
    if isinstance(rec, rr.RecordingStream):
        return rec
    raise InputError(f"rec: expected a rerun.RecordingStream or a viz.recording.RecordingWriter, "
                     f"got {type(rec).__name__}")


class RecordingWriter:
    """Open an ``.rrd`` file for logging; finalise it and move it into place on close.

    Args:
        path: target ``.rrd`` file; its folder must exist.
        seed: makes the recording id deterministic (`recording_id`).
        application_id: rerun application id (default ``"torchcal"``).
        name: recording name shown by the viewer (default: the file name).
        blueprint: a ``rerun.blueprint.Blueprint`` to open on; default: `layout`.
        force: replace an existing file at `path`.

    Attributes:
        stream: the ``rerun.RecordingStream`` (pass the writer or the stream to ``log_*``).
        sections: the sections logged through this writer (`stream_of`; for the layout).
        path: the target path.

    Use as a context manager, or call `open` and then `close` (or `abort`).
    """

    def __init__(self, path, *, seed: int = 0, application_id: str = APPLICATION_ID, name: str | None = None,
                 blueprint: rrb.Blueprint | None = None, force: bool = False):
        self.path = Path(path)
        self.seed = int(seed)
        self.application_id = application_id
        self.name = name if name is not None else self.path.stem
        self.blueprint = blueprint
        self.force = force
        self.sections: set[str] = set()
        self.stream: rr.RecordingStream | None = None
        self._tmp: Path | None = None

    def layout(self) -> rrb.Blueprint | None:
        """The blueprint sent on close when none was given (None: the viewer's own)."""
        return None

    def open(self) -> "RecordingWriter":
        """Check the target, start the stream and its file sink (a temporary file beside it)."""
        if self.stream is not None:
            raise InputError(f"{self.path}: recording is already open")
        check_output(self.path, self.force)
        self._tmp = C.temp_beside(self.path)
        stream = rr.RecordingStream(self.application_id, recording_id=recording_id(self.seed, self.application_id),
                                    send_properties=False)
        stream.set_log_time_enabled(False)  # no wall-clock timeline: deterministic content
        stream.set_log_tick_enabled(False)
        stream.save(self._tmp)
        stream.send_recording_name(self.name)
        stream.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)  # robot base frame, z up
        self.stream = stream
        return self

    def close(self) -> Path:
        """Send the blueprint, flush, disconnect (writes the footer), move into place."""
        if self.stream is None:
            raise InputError(f"{self.path}: recording is not open")
        stream, tmp = self.stream, self._tmp
        try:
            bp = self.blueprint if self.blueprint is not None else self.layout()
            if bp is not None:
                stream.send_blueprint(bp, make_active=True, make_default=True)
            stream.flush()
            stream.disconnect()  # drops the FileSink: the file gets its footer and is complete
            check_output(self.path, self.force)  # nobody created it meanwhile
            os.replace(tmp, self.path)
        except BaseException:
            self._discard()
            raise
        self.stream, self._tmp = None, None
        return self.path

    def abort(self) -> None:
        """Stop without writing the target; remove the temporary file."""
        if self.stream is not None:
            self._discard()

    def _discard(self) -> None:
        stream, tmp = self.stream, self._tmp
        self.stream, self._tmp = None, None
        try:
            if stream is not None:
                stream.disconnect()
        finally:
            if tmp is not None and tmp.exists():
                tmp.unlink()

    def __enter__(self) -> "RecordingWriter":
        return self.open()

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def __repr__(self) -> str:
        state = "open" if self.stream is not None else "closed"
        return f"{type(self).__name__}({str(self.path)!r}, seed={self.seed}, {state})"
