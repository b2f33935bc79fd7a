"""viz.recording_writer: the .rrd file writer knows nothing of what is logged; it notes the
sections its loggers fill and asks its `layout` for the blueprint only when none was given."""

from __future__ import annotations

import pytest
import rerun as rr
import rerun.blueprint as rrb
from rerun.chunk import RrdReader

from torchcal.errors import InputError
from viz.recording_writer import RecordingWriter, recording_id, stream_of


def _entities(path) -> set[str]:
    return {ch.entity_path for ch in RrdReader(path).stream()}


def test_stream_of_notes_the_section_and_refuses_other_objects(tmp_path):
    with RecordingWriter(tmp_path / "a.rrd", seed=2) as rec:
        assert stream_of(rec, "summary") is rec.stream
        assert stream_of(rec.stream, "ignored") is rec.stream  # a plain stream: nothing to note
        rec.stream.log("summary", rr.TextDocument("# hello"), static=True)
        assert rec.sections == {"summary"}
        with pytest.raises(InputError, match="expected a rerun.RecordingStream"):
            stream_of(object(), "summary")
    assert "/summary" in _entities(tmp_path / "a.rrd")
    assert recording_id(2) != recording_id(3)


def test_layout_is_asked_only_without_a_given_blueprint(tmp_path):
    calls = []

    class Laid(RecordingWriter):
        def layout(self):
            calls.append(set(self.sections))
            return rrb.Blueprint(rrb.TextDocumentView(origin="/summary"))

    with Laid(tmp_path / "b.rrd") as rec:
        stream_of(rec, "summary").log("summary", rr.TextDocument("# b"), static=True)
    assert calls == [{"summary"}]
    given = rrb.Blueprint(rrb.TextDocumentView(origin="/summary"))
    with Laid(tmp_path / "c.rrd", blueprint=given):
        pass
    assert calls == [{"summary"}]  # not asked again
    with RecordingWriter(tmp_path / "d.rrd") as rec:  # the plain writer lays nothing out
        assert rec.layout() is None
    assert (tmp_path / "d.rrd").stat().st_size > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.rrd", "c.rrd", "d.rrd"]  # no temporary file left
