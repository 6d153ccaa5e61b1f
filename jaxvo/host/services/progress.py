"""A dependency-free progress line for long CLI work (stderr, redrawn in place on a TTY)."""

from __future__ import annotations

import sys
import time


class Progress:
    """``Progress("flow", total)(done, total)`` redraws
    ``flow [#####    ] 120/300 41.2 it/s, 4 s left``.

    On a terminal the line is redrawn in place, at most every ``interval`` seconds and when
    the work is done (a call costs a clock reading otherwise: ``jaxvo run`` calls it every
    frame, a few milliseconds apart); elsewhere (CI logs, pipes) a line is printed at every
    tenth of the work, so logs stay short. The time left assumes the rest goes at the
    average rate so far (a first call that compiles makes it high at first); ``unit`` names
    what is counted.
    """

    def __init__(self, label: str, total: int | None = None, *, stream=None, enabled=True,
                 unit: str = "it", interval: float = 0.1):
        self.label = label
        self.total = total
        self.unit = unit
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.start = time.perf_counter()
        self.interval = interval
        self._drawn = -float("inf")  # when the terminal line was last drawn
        self._last_decile = -1
        self._width = 0  # the longest line drawn: a shorter one is padded over it

    def __call__(self, done: int, total: int | None = None) -> None:
        if not self.enabled:
            return
        total = total if total is not None else self.total
        now = time.perf_counter()
        finished = bool(total) and done >= total
        if self.tty and not finished and now - self._drawn < self.interval:
            return
        rate = done / max(now - self.start, 1e-9)
        if total:
            frac = min(max(done / total, 0.0), 1.0)
            bar = "#" * int(24 * frac) + " " * (24 - int(24 * frac))
            text = f"{self.label} [{bar}] {done}/{total} {rate:.1f} {self.unit}/s"
            if 0 < done < total:
                text += f", {_duration((total - done) / rate)} left"
            decile = int(10 * frac)
        else:
            text, decile = f"{self.label} {done} {rate:.1f} {self.unit}/s", done // 100
        if self.tty:
            self._drawn = now
            end = "\n" if finished else ""
            self._width = max(self._width, len(text))
            self.stream.write("\r" + text.ljust(self._width) + end)
            self.stream.flush()
        elif decile != self._last_decile:
            self._last_decile = decile
            self.stream.write(text + "\n")
            self.stream.flush()

    def note(self, line: str) -> None:
        """A line of its own (e.g. what a step found), above the progress line."""
        if not self.enabled:
            return
        if self.tty:  # over the progress line; the next call draws it again below
            line = "\r" + line.ljust(self._width)
        self.stream.write(line + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _duration(seconds: float) -> str:
    """``42 s``, ``3 min 05 s`` or ``2 h 07 min``."""
    s = round(seconds)
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"
