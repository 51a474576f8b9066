"""Progress with an ETA on stderr while calls are being made.

On a terminal the line is redrawn in place; otherwise (a log file, CI) a line is printed at most every
``interval`` seconds, so logs stay short. The ETA is the remaining calls divided by the rate so far.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO


class Progress:
    """Counts finished calls out of ``total`` and reports them with a rate and an ETA."""

    def __init__(self, what: str, total: int, cached: int = 0, *, stream: TextIO | None = None,
                 clock: Callable[[], float] = time.monotonic, interval: float | None = None,
                 enabled: bool = True):
        self.what, self.total, self.cached = what, total, cached
        self.done = self.failed = 0
        self._stream = stream if stream is not None else sys.stderr
        self._clock = clock
        self._tty = bool(getattr(self._stream, "isatty", lambda: False)())
        self._interval = interval if interval is not None else (0.2 if self._tty else 10.0)
        self._enabled_at_all = enabled
        self._enabled = enabled and total > 0
        self._start = clock()
        self._last_shown: float | None = None

    def announce(self) -> None:
        """Say so when every call is already cached (nothing else would be shown)."""
        if self._enabled_at_all and self.total == 0 and self.cached:
            self._stream.write(f"{self.what}: nothing to call, all {self.cached} cached\n")
            self._stream.flush()

    def advance(self, failed: bool = False) -> None:
        """One more call finished (successfully or not)."""
        self.done += 1
        self.failed += int(failed)
        now = self._clock()
        if self.done == self.total or self._last_shown is None or now - self._last_shown >= self._interval:
            self._show(now)

    def line(self, now: float | None = None) -> str:
        """The progress line as it would be shown now."""
        now = self._clock() if now is None else now
        elapsed = max(now - self._start, 0.0)
        rate = self.done / elapsed if elapsed > 0 else 0.0
        parts = [f"{self.what}: {self.done}/{self.total} calls"]
        if self.cached:
            parts.append(f"{self.cached} cached")
        if self.failed:
            parts.append(f"{self.failed} failed")
        if self.done < self.total:
            eta = (self.total - self.done) / rate if rate > 0 else None
            parts.append(f"{rate:.1f} calls/s, ETA {format_duration(eta)}")
        else:
            parts.append(f"done in {format_duration(elapsed)}")
        return ", ".join(parts)

    def _show(self, now: float) -> None:
        if not self._enabled:
            return
        self._last_shown = now
        end = "\n" if (self.done == self.total or not self._tty) else ""
        prefix = "\r\x1b[2K" if self._tty else ""
        self._stream.write(prefix + self.line(now) + end)
        self._stream.flush()


def format_duration(seconds: float | None) -> str:
    """``1h02m``, ``3m05s``, ``42s``; ``?`` when unknown."""
    if seconds is None:
        return "?"
    seconds = int(round(seconds))
    if seconds >= 3600:
        return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"
    if seconds >= 60:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds}s"
