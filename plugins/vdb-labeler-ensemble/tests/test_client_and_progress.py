"""Retry-After parsing, deterministic jittered backoff, the per-backend rate-limit gate, progress with ETA."""

from __future__ import annotations

import email.utils

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


