"""The one progress line of every ``vdb`` command and plugin: done/total, rate and ETA on stderr.

On a terminal the line is redrawn in place and cleared when the work is done (or, with ``close=True``,
left as a closing line); otherwise (a log file, CI) a line is printed every ``interval`` seconds and a
closing line if any was (always, with ``close=True``), so short batches stay silent unless the command wants
its total reported. The ETA is the remaining work divided by the rate so far.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO


class Progress:
    """Counts finished ``unit``s (calls, episodes, CoTs) out of ``total`` and reports them with a rate and an
    ETA. ``note`` (set by :meth:`advance`) says what finished last (e.g. the episode)."""

    def __init__(self, what: str, total: int, cached: int = 0, *, stream: TextIO | None = None,
                 clock: Callable[[], float] = time.monotonic, interval: float | None = None,
                 enabled: bool = True, unit: str = "calls", close: bool = False):
        self.what, self.total, self.cached = what, total, cached
        self.unit, self.close, self.note = unit, close, ""
        self.done = self.failed = 0
        self._stream = stream if stream is not None else sys.stderr
        self._clock = clock
        self._tty = bool(getattr(self._stream, "isatty", lambda: False)())
        self._interval = interval if interval is not None else (0.2 if self._tty else 10.0)
        self._enabled = enabled and total > 0
        self._start = self._last_shown = clock()
        self._shown = False

    def advance(self, failed: bool = False, *, count: int = 1, note: str = "") -> None:
        """``count`` more units finished (``failed``: one of them failed)."""
        self.done += count
        self.failed += int(failed)
        self.note = note
        now = self._clock()
        if self.done >= self.total:
            self._finish(now)
        elif now - self._last_shown >= self._interval:
            self._show(now)

    def line(self, now: float | None = None) -> str:
        """The progress line as it would be shown now."""
        now = self._clock() if now is None else now
        elapsed = max(now - self._start, 0.0)
        rate = self.done / elapsed if elapsed > 0 else 0.0
        parts = [f"{self.what}: {self.done}/{self.total} {self.unit}"]
        if self.cached:
            parts.append(f"{self.cached} cached")
        if self.failed:
            parts.append(f"{self.failed} failed")
        if self.done < self.total:
            eta = (self.total - self.done) / rate if rate > 0 else None
            parts.append(f"{rate:.1f} {self.unit}/s, ETA {format_duration(eta)}")
            if self.note:
                parts.append(self.note)
        else:
            parts.append(f"done in {format_duration(elapsed)}")
        return ", ".join(parts)

    def _show(self, now: float) -> None:
        if not self._enabled:
            return
        self._last_shown, self._shown = now, True
        if self._tty:
            self._stream.write("\r\x1b[2K" + self.line(now))
        else:
            self._stream.write(self.line(now) + "\n")
        self._stream.flush()

    def _finish(self, now: float) -> None:
        if not self._enabled or not (self._shown or self.close):
            return
        if self._tty:
            self._stream.write("\r\x1b[2K" + (self.line(now) + "\n" if self.close else ""))
        else:
            self._stream.write(self.line(now) + "\n")
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
