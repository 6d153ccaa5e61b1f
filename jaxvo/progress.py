"""A dependency-free progress line for long CLI work (stderr, redrawn in place on a TTY)."""

from __future__ import annotations

import sys
import time


class Progress:
    """``Progress("flow", total)(done, total)`` redraws ``flow [#####    ] 120/300 41.2 it/s``.

    On a terminal the line is redrawn in place; otherwise (CI logs, pipes) a line is
    printed at every tenth of the work, so logs stay short.
    """

    def __init__(self, label: str, total: int | None = None, *, stream=None, enabled=True):
        self.label = label
        self.total = total
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.start = time.perf_counter()
        self._last_decile = -1

    def __call__(self, done: int, total: int | None = None) -> None:
        if not self.enabled:
            return
        total = total if total is not None else self.total
        rate = done / max(time.perf_counter() - self.start, 1e-9)
        if total:
            frac = min(max(done / total, 0.0), 1.0)
            bar = "#" * int(24 * frac) + " " * (24 - int(24 * frac))
            text = f"{self.label} [{bar}] {done}/{total} {rate:.1f} it/s"
            decile = int(10 * frac)
        else:
            text, decile = f"{self.label} {done} {rate:.1f} it/s", done // 100
        if self.tty:
            end = "\n" if total and done >= total else ""
            self.stream.write("\r" + text + end)
            self.stream.flush()
        elif decile != self._last_decile:
            self._last_decile = decile
            self.stream.write(text + "\n")
            self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()
