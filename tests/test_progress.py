"""The CLI progress line: the rate, the time left, a line per tenth off a terminal."""

import io

from jaxvo.host.services import progress as progress_mod
from jaxvo.host.services.progress import Progress


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


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_a_terminal_line_is_redrawn_at_most_every_interval_and_when_done(monkeypatch):
    """``jaxvo run`` calls it every frame: 300 calls 1 ms apart draw 4 times, not 300."""
    clock = iter(0.001 * k for k in range(400))
    monkeypatch.setattr(progress_mod.time, "perf_counter", lambda: next(clock))
    out = _Terminal()
    p = Progress("jaxvo run", 300, stream=out, interval=0.1)
    for done in range(1, 301):
        p(done)
    draws = out.getvalue().split("\r")[1:]
    assert len(draws) == 4  # at 1, 101 and 201 ms, and the last
    assert draws[-1].rstrip().endswith("300/300 1000.0 it/s")
