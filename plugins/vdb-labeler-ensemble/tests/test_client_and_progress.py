"""Retry-After parsing, deterministic jittered backoff, the per-backend rate-limit gate, progress with ETA."""

from __future__ import annotations

import email.utils
import io

import httpx
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vdb_labeler_ensemble.backends import parse_backend
from vdb_labeler_ensemble.client import (
    BackendClient,
    CallFailed,
    Jitter,
    Redactor,
    RetryPolicy,
    retry_after_seconds,
)
from vdb_labeler_ensemble.progress import Progress, format_duration
from vdb_labeler_ensemble.testing import FakeClock


def response(status=429, headers=None, body=None):
    return httpx.Response(status, headers=headers or {}, json=body if body is not None else {})


def test_retry_after_in_every_form():
    assert retry_after_seconds(response(headers={"Retry-After": "12"})) == 12.0
    assert retry_after_seconds(response(headers={"retry-after-ms": "1500", "Retry-After": "9"})) == 1.5
    date = email.utils.formatdate(1_000_030, usegmt=True)
    assert retry_after_seconds(response(headers={"Retry-After": date}), now=lambda: 1_000_000) == 30.0
    gemini = {"error": {"code": 429, "details": [{"@type": "type.googleapis.com/google.rpc.RetryInfo",
                                                  "retryDelay": "41s"}]}}
    assert retry_after_seconds(response(body=gemini)) == 41.0
    assert retry_after_seconds(response(headers={"Retry-After": "soon"})) is None
    assert retry_after_seconds(response()) is None


def client_for(handler, clock, seed=0, **policy):
    http = httpx.Client(transport=httpx.MockTransport(handler))
    spec = parse_backend("openai:m")
    return BackendClient(spec, "KEY", http, RetryPolicy(**policy), sleep=clock.sleep, clock=clock,
                         jitter=Jitter(np.random.default_rng(seed)), redact=Redactor(["KEY"]))


OK = {"choices": [{"message": {"content": "{}"}, "finish_reason": "stop"}]}


@settings(deadline=None, max_examples=25)  # each example builds two HTTP clients
@given(st.integers(0, 2**32 - 1))
def test_backoff_is_reproducible_from_the_seed_and_bounded(seed):
    runs = []
    for _ in range(2):
        clock = FakeClock()
        client = client_for(lambda request: httpx.Response(503, json={}), clock, seed, max_retries=6, max_delay=20)
        with pytest.raises(CallFailed, match="gave up after 7 attempts"):
            client.call("s", "u")
        runs.append(clock.sleeps)
    assert runs[0] == runs[1]
    for attempt, delay in enumerate(runs[0]):
        assert 0.5 * min(20, 2**attempt) <= delay <= min(20, 2**attempt)


def test_a_retry_after_holds_back_every_worker_of_the_backend():
    clock = FakeClock()
    answers = iter([httpx.Response(429, headers={"Retry-After": "30"}, json={}), httpx.Response(200, json=OK),
                    httpx.Response(200, json=OK)])
    client = client_for(lambda request: next(answers), clock)
    client.call("s", "u")
    assert 30.0 <= clock.sleeps[0] <= 33.0 and len(clock.sleeps) == 1
    clock.now -= 10  # another worker arriving while the wait is still running must wait out the rest
    client.call("s", "u")
    assert 9.0 <= clock.sleeps[1] <= 13.0


def test_client_errors_are_not_retried_and_keys_are_redacted():
    clock = FakeClock()
    calls = []

    def handler(request):
        calls.append(request)
        return httpx.Response(401, json={"error": {"message": "bad key KEY"}})

    with pytest.raises(CallFailed) as raised:
        client_for(handler, clock).call("s", "u")
    assert str(raised.value) == "HTTP 401: bad key *** (check the API key in OPENAI_API_KEY)"
    assert len(calls) == 1 and not clock.sleeps
    assert "KEY" not in repr(client_for(handler, clock))


def test_connection_errors_are_retried():
    clock = FakeClock()
    attempts = []

    def handler(request):
        attempts.append(1)
        if len(attempts) < 3:
            raise httpx.ConnectError("refused")
        return httpx.Response(200, json=OK)

    assert client_for(handler, clock).call("s", "u").text == "{}"
    assert len(attempts) == 3 and len(clock.sleeps) == 2


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
