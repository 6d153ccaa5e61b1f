"""The CLI progress line: the rate, the time left, a line per tenth off a terminal."""

import io

from jaxvo import progress as progress_mod
from jaxvo.progress import Progress


def test_time_left_follows_the_average_rate(monkeypatch):
    clock = iter([100.0, 110.0, 130.0, 140.0])  # start, then one reading per call
    monkeypatch.setattr(progress_mod.time, "perf_counter", lambda: next(clock))
    out = io.StringIO()
    p = Progress("study", 400, stream=out, unit="config-frames")
    p(100)  # 100 in 10 s: 300 left at 10 a second
    p(250)  # 250 in 30 s: 150 left at 8.33 a second
    p(400)
    lines = out.getvalue().splitlines()
    assert lines[0].endswith("100/400 10.0 config-frames/s, 30 s left")
    assert lines[1].endswith("250/400 8.3 config-frames/s, 18 s left")
    assert lines[2].endswith("400/400 10.0 config-frames/s")  # done: no time left shown


def test_durations_read_as_minutes_and_hours():
    assert progress_mod._duration(59.4) == "59 s"
    assert progress_mod._duration(185) == "3 min 05 s"
    assert progress_mod._duration(7620) == "2 h 07 min"


def test_a_note_is_a_line_of_its_own():
    out = io.StringIO()
    p = Progress("study", 10, stream=out)
    p(5)
    p.note("seq: flow from the cache")
    assert out.getvalue().splitlines()[-1] == "seq: flow from the cache"
    Progress("study", 10, stream=out, enabled=False).note("hidden")
    assert "hidden" not in out.getvalue()
