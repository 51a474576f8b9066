"""The one progress line (``vladrivebench.cli.Progress``) every command and plugin uses."""

from __future__ import annotations

import io

import pytest
from vladrivebench.cli import Progress, format_duration


class FakeClock:
    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_progress_reports_rate_and_eta():
    clock = FakeClock()
    stream = io.StringIO()
    progress = Progress("ensemble", 10, cached=5, stream=stream, clock=clock, interval=0.0)
    clock.now += 4.0
    progress.advance()
    progress.advance(failed=True)
    assert stream.getvalue().splitlines()[-1] == "ensemble: 2/10 calls, 5 cached, 1 failed, 0.5 calls/s, ETA 16s"
    for _ in range(8):
        progress.advance()
    assert stream.getvalue().splitlines()[-1] == "ensemble: 10/10 calls, 5 cached, 1 failed, done in 4s"


def test_progress_is_throttled_off_a_terminal_and_silent_for_short_batches():
    clock = FakeClock()
    stream = io.StringIO()
    progress = Progress("x", 100, stream=stream, clock=clock)
    for _ in range(99):
        progress.advance()
    progress.advance()
    assert stream.getvalue() == ""  # done within 10 s: nothing to say, the caller reports the result
    long = Progress("x", 100, stream=stream, clock=clock)
    for _ in range(100):
        clock.now += 1.0
        long.advance()
    lines = stream.getvalue().splitlines()
    assert len(lines) == 10 and lines[0] == "x: 10/100 calls, 1.0 calls/s, ETA 1m30s"
    assert lines[-1] == "x: 100/100 calls, done in 1m40s"
    quiet = io.StringIO()
    Progress("x", 3, stream=quiet, clock=clock, interval=0.0, enabled=False).advance()
    assert quiet.getvalue() == ""


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_on_a_terminal_the_line_is_redrawn_then_cleared():
    clock = FakeClock()
    stream = Terminal()
    progress = Progress("x", 3, stream=stream, clock=clock)
    for _ in range(3):
        clock.now += 1.0
        progress.advance()
    assert stream.getvalue() == ("\r\x1b[2Kx: 1/3 calls, 1.0 calls/s, ETA 2s\r\x1b[2Kx: 2/3 calls, 1.0 calls/s, ETA 1s"
                                 "\r\x1b[2K")


@pytest.mark.parametrize("seconds, text", [(None, "?"), (0.4, "0s"), (42, "42s"), (185, "3m05s"), (3720, "1h02m")])
def test_durations(seconds, text):
    assert format_duration(seconds) == text


def test_a_closing_line_is_printed_when_asked_even_for_short_work():
    clock = FakeClock()
    stream = io.StringIO()
    progress = Progress("vdb run", 2, stream=stream, clock=clock, unit="episodes", close=True)
    clock.now += 3.0
    progress.advance(note="P.1 seed 0")
    progress.advance(failed=True, note="P.1 seed 1")
    assert stream.getvalue() == "vdb run: 2/2 episodes, 1 failed, done in 3s\n"


def test_the_note_says_what_finished_last():
    clock = FakeClock()
    stream = io.StringIO()
    progress = Progress("vdb intervene", 4, stream=stream, clock=clock, interval=0.0, unit="episodes")
    clock.now += 2.0
    progress.advance(note="E.1 seed 0 baseline")
    assert stream.getvalue() == "vdb intervene: 1/4 episodes, 0.5 episodes/s, ETA 6s, E.1 seed 0 baseline\n"
