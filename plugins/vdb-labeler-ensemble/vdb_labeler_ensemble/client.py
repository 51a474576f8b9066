"""One backend's HTTP calls: retries with exponential backoff and jitter, honouring Retry-After.

Retried: HTTP 408, 409, 429 and 5xx, timeouts and dropped connections. Not retried: other 4xx (a bad key,
an unknown model, a malformed request: retrying would only spend money), and a 200 whose body is not the
protocol's JSON. A Retry-After (``retry-after-ms``, ``retry-after`` in seconds or as a date, or Gemini's
``RetryInfo``) holds back *every* worker of that backend until it has passed. ``sleep``, ``clock`` and the
jitter RNG are injected so that tests run in no time and every run is reproducible.
"""

from __future__ import annotations

import email.utils
import logging
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import httpx
import numpy as np

from .backends import BackendSpec, ProtocolError, Reply, build_request, read_reply

logger = logging.getLogger("vdb_labeler_ensemble")

RETRYABLE_STATUS = frozenset({408, 409, 429, *range(500, 600)})


@dataclass(frozen=True)
class RetryPolicy:
    """How failed calls are retried: ``max_retries`` after the first attempt, delays in seconds."""

    max_retries: int = 5
    base_delay: float = 1.0
    max_delay: float = 60.0
    max_retry_after: float = 300.0


class CallFailed(Exception):
    """A call that gave no reply; the message (one line, secrets redacted) says why."""


class Redactor:
    """Replaces every known secret in a text with ``***`` (errors may echo what was sent)."""

    def __init__(self, secrets: list[str] | None = None):
        self._secrets = sorted({s for s in (secrets or []) if s}, key=len, reverse=True)

    def add(self, secret: str) -> None:
        if secret and secret not in self._secrets:
            self._secrets = sorted([*self._secrets, secret], key=len, reverse=True)

    def __call__(self, text: str) -> str:
        for secret in self._secrets:
            text = text.replace(secret, "***")
        return text


class Jitter:
    """Thread-safe uniform draws in [0, 1) from a generator passed in."""

    def __init__(self, rng: np.random.Generator):
        self._rng, self._lock = rng, threading.Lock()

    def __call__(self) -> float:
        with self._lock:
            return float(self._rng.random())


class BackendClient:
    """Sends labelling calls to one backend through a shared :class:`httpx.Client`."""

    def __init__(self, spec: BackendSpec, key: str | None, http: httpx.Client, policy: RetryPolicy, *,
                 sleep: Callable[[float], None] = time.sleep, clock: Callable[[], float] = time.monotonic,
                 jitter: Callable[[], float], redact: Callable[[str], str], stop: threading.Event | None = None):
        self.spec, self.policy = spec, policy
        self._stop = stop or threading.Event()
        self._key, self._http = key, http
        self._sleep, self._clock, self._jitter, self._redact = sleep, clock, jitter, redact
        self._gate_lock = threading.Lock()
        self._not_before = 0.0

    def __repr__(self) -> str:  # never show the key
        return f"BackendClient({self.spec.name!r})"

    def call(self, system: str, user: str) -> Reply:
        """One completed reply, after as many retries as the policy allows; :class:`CallFailed` otherwise."""
        request = build_request(self.spec, system, user, self._key)
        attempt = 0
        while True:
            self._wait_for_gate()
            if self._stop.is_set():
                raise CallFailed("interrupted before an answer came")
            problem, retry_after = self._attempt(request)
            if isinstance(problem, Reply):
                return problem
            if attempt >= self.policy.max_retries:
                raise CallFailed(f"{problem}; gave up after {attempt + 1} attempts (max_retries={self.policy.max_retries})")
            if retry_after is not None and retry_after > self.policy.max_retry_after:
                raise CallFailed(f"{problem}; the server asks to wait {retry_after:.0f} s, longer than "
                                 f"max_retry_after={self.policy.max_retry_after:g}")
            delay = self._delay(attempt, retry_after)
            if retry_after is not None:
                self._hold_gate(delay)
            logger.warning("%s: %s; retry %d/%d in %.1f s", self.spec.name, problem, attempt + 1,
                           self.policy.max_retries, delay)
            self._sleep(delay)
            attempt += 1

    def _attempt(self, request: Any) -> tuple[Reply | str, float | None]:
        """A reply, or a retryable problem and the server's requested wait; raises if not retryable."""
        try:
            response = self._http.post(request.url, headers=request.headers, json=request.body)
        except httpx.TimeoutException:
            return f"timed out after {self._timeout_text()}", None
        except httpx.TransportError as exc:
            return self._redact(f"connection failed ({type(exc).__name__}: {exc})"), None
        if response.status_code == 200:
            return self._reply(response), None
        problem = self._redact(f"HTTP {response.status_code}{_provider_message(response)}")
        if response.status_code in RETRYABLE_STATUS:
            return problem, retry_after_seconds(response)
        raise CallFailed(problem + _hint(response.status_code, self.spec))

    def _reply(self, response: httpx.Response) -> Reply:
        try:
            body = response.json()
        except ValueError:
            raise CallFailed(self._redact(f"HTTP 200 with a body that is not JSON: {_snippet(response.text)!r}")) from None
        try:
            return read_reply(self.spec, body)
        except ProtocolError as exc:
            raise CallFailed(self._redact(f"HTTP 200 but not a {self.spec.kind} response: {exc}")) from None

    def _delay(self, attempt: int, retry_after: float | None) -> float:
        if retry_after is not None:
            # Honour the server's wait, plus up to 10% so that the waiting workers do not all return at once.
            return retry_after * (1.0 + 0.1 * self._jitter())
        backoff = min(self.policy.max_delay, self.policy.base_delay * 2.0**attempt)
        return backoff * (0.5 + 0.5 * self._jitter())

    def _hold_gate(self, delay: float) -> None:
        with self._gate_lock:
            self._not_before = max(self._not_before, self._clock() + delay)

    def _wait_for_gate(self) -> None:
        with self._gate_lock:
            wait = self._not_before - self._clock()
        if wait > 0:
            self._sleep(wait)

    def _timeout_text(self) -> str:
        timeout = self._http.timeout.read
        return f"{timeout:g} s" if timeout is not None else "the timeout"


def retry_after_seconds(response: httpx.Response, now: Callable[[], float] = time.time) -> float | None:
    """The wait a response asks for, from ``retry-after-ms``, ``retry-after`` or a Gemini ``RetryInfo``."""
    headers = response.headers
    if "retry-after-ms" in headers:
        try:
            return max(0.0, float(headers["retry-after-ms"]) / 1000.0)
        except ValueError:
            pass
    if "retry-after" in headers:
        value = headers["retry-after"].strip()
        try:
            return max(0.0, float(value))
        except ValueError:
            try:
                when = email.utils.parsedate_to_datetime(value)
            except (TypeError, ValueError):
                when = None
            if when is not None:
                return max(0.0, when.timestamp() - now())
    return _gemini_retry_delay(response)


def _gemini_retry_delay(response: httpx.Response) -> float | None:
    try:
        details = response.json()["error"]["details"]
    except (ValueError, KeyError, TypeError):
        return None
    for detail in details if isinstance(details, list) else []:
        delay = detail.get("retryDelay") if isinstance(detail, dict) else None
        match = re.fullmatch(r"\s*(\d+(?:\.\d+)?)s\s*", delay) if isinstance(delay, str) else None
        if match:
            return float(match.group(1))
    return None


def _provider_message(response: httpx.Response) -> str:
    try:
        error = response.json().get("error")
        message = error.get("message") if isinstance(error, dict) else error
    except (ValueError, AttributeError):
        message = response.text
    message = _snippet(message) if isinstance(message, str) else ""
    return f": {message}" if message else ""


def _hint(status: int, spec: BackendSpec) -> str:
    if status in (401, 403):
        where = " or ".join(spec.key_envs) if spec.key_envs else "the key (set one with ?key_env=VAR)"
        return f" (check the API key in {where})"
    if status == 404:
        return f" (check the model name {spec.model!r} and the base URL {spec.base_url})"
    return ""


def _snippet(text: str, limit: int = 200) -> str:
    flat = " ".join(str(text).split())
    return flat if len(flat) <= limit else flat[: limit - 1] + "…"

