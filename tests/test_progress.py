"""Nothing silent: progress lines on stderr for the long commands, a "wrote PATH" line for
every file written, help texts that point at the right docs."""

from __future__ import annotations

import io
import time

import pytest

from torchcal.cli import main
from torchcal.cli._progress import progress


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_off_a_terminal_one_plain_line_at_the_end():
    out = io.StringIO()
    with progress("discover", "searching effects", stream=out, delay=0):
        pass
    lines = out.getvalue().splitlines()
    assert len(lines) == 1 and lines[0].startswith("torchcal discover: searching effects: done in ")


def test_on_a_terminal_the_status_line_is_redrawn_then_cleared():
    out = _Terminal()
    with progress("plan", "choosing poses", stream=out, delay=0, interval=0.02):
        time.sleep(0.3)  # the block's work; the redraws come from the other thread
    text = out.getvalue()
    assert text.count("\rtorchcal plan: choosing poses ... ") >= 2 and text.endswith("\r\033[K")
    assert "\n" not in text  # one line, redrawn in place


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    d = tmp_path_factory.mktemp("progress")
    assert main(["simulate", "--robot", "ur5e", "--effects", "base_frame", "--n", "40", "--seed", "2",
                 "--out", str(d / "s.csv")]) == 0
    assert main(["fit", str(d / "s.csv"), "--robot", "ur5e", "--effects", "base_frame",
                 "--out", str(d / "m.json")]) == 0
    return d


def test_a_short_step_or_a_refusal_shows_nothing():
    out = _Terminal()
    with progress("plan", "choosing poses", stream=out):  # shorter than a second
        pass
    assert out.getvalue() == ""
    for out in (io.StringIO(), _Terminal()):  # a refusal after the delay: nothing left but its error line
        with pytest.raises(ValueError):
            with progress("plan", "choosing poses", stream=out, delay=0, interval=0.02):
                time.sleep(0.1)
                raise ValueError("bad input")
        assert out.getvalue().replace("\033[K", "").split("\r")[-1] == ""


def test_every_file_written_has_a_wrote_line(session, capsys, monkeypatch):
    monkeypatch.setattr("torchcal.cli._progress.DELAY_S", 0.0)  # the lines at once, however fast the step
    d = session
    runs = [(["simulate", "--robot", "ur5e", "--n", "5", "--seed", "1", "--out", str(d / "s2.csv"),
              "--truth", str(d / "t2.json")], [d / "s2.csv", d / "t2.json"], None),
            (["evaluate", str(d / "s.csv"), "--model", str(d / "m.json"), "--json", str(d / "e.json")],
             [d / "e.json"], None),
            (["diagnose", str(d / "s.csv"), "--robot", "ur5e", "--effects", "base_frame", "--folds", "2",
              "--json", str(d / "g.json")], [d / "g.json"], "torchcal diagnose: screening candidate effects on 40 rows"),
            (["discover", str(d / "s.csv"), "--robot", "ur5e", "--effects", "base_frame", "--folds", "2",
              "--json", str(d / "h.json"), "--out", str(d / "m2.json")], [d / "h.json", d / "m2.json"],
             "torchcal discover: searching effects on 40 rows"),
            (["plan", "--robot", "ur5e", "--n", "12", "--candidates", "60", "--random-plans", "2",
              "--out", str(d / "p.csv")], [d / "p.csv"], "torchcal plan: choosing 12 of 60 candidate poses")]
    for argv, files, stage in runs:
        capsys.readouterr()
        assert main(argv) == 0
        cap = capsys.readouterr()
        for f in files:
            assert f.exists() and (f"wrote {f}" in cap.out or f"wrote {files[0]}, {f} (truth)" in cap.out), (argv, f)
        if stage is not None:  # off a terminal: one line with the time, at the end, on stderr
            assert f"{stage} ..." not in cap.err and f"{stage}: done in " in cap.err


def test_fit_help_points_at_the_formats_page(capsys):
    with pytest.raises(SystemExit):
        main(["fit", "--help"])
    out = capsys.readouterr().out
    assert "docs/formats.md" in out and "docs/design.md" not in out
