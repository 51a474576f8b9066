"""Test kit: a real HTTP server on 127.0.0.1 that speaks the three wire protocols and injects faults.

Use it to test the labeler, a prompt file you edited, or your own code around it, without spending a call.

Paths: ``/openai/v1/chat/completions`` (OpenAI chat completions, also used for openai-compatible),
``/anthropic/v1/messages`` (Anthropic Messages) and ``/gemini/v1beta/models/MODEL:generateContent``
(Gemini). The server finds the item being labelled by its tag (``CASE-name``) in the part of the prompt
after "Now label this CoT", asks a responder what to do for (protocol, model, tag, attempt) and records
every request (never sends anything off the machine; it stops with the test).
"""

from __future__ import annotations

import json
import re
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from vladrivebench import LabelInput

# -- what the server can be told to do -------------------------------------------------------------------


@dataclass(frozen=True)
class Answer:
    """A well-formed reply whose text is ``json.dumps(value)`` (or ``text`` when given)."""

    value: dict[str, Any] | None = None
    text: str | None = None


@dataclass(frozen=True)
class Refuse:
    """The protocol's own way of refusing."""


@dataclass(frozen=True)
class Status:
    """An error status with optional headers and JSON body."""

    code: int
    headers: dict[str, str] = field(default_factory=dict)
    body: dict[str, Any] | None = None


@dataclass(frozen=True)
class Hang:
    """Wait ``seconds`` before answering (longer than the client's timeout: a timeout)."""

    seconds: float


@dataclass(frozen=True)
class RawBody:
    """HTTP 200 with a body that is not JSON."""

    body: bytes = b"<html>gateway hiccup</html>"


Action = Answer | Refuse | Status | Hang | RawBody
Responder = Callable[[str, str, str, int], Action]


@dataclass
class Seen:
    """One request as the server saw it."""

    protocol: str
    model: str
    tag: str
    attempt: int
    status: int
    headers: dict[str, str]
    body: dict[str, Any]
    path: str


_TAG = re.compile(r"CASE-([A-Za-z0-9_]+)")
_PATH = re.compile(r"^/(openai|anthropic|gemini)/(?:v1|v1beta)/(chat/completions|messages|models/(.+):generateContent)$")


class _Server(ThreadingHTTPServer):
    request_queue_size = 128  # the default backlog of 5 drops connections when many calls start at once


class LoopbackLLM:
    """The server. ``keys`` maps protocol → expected API key (a wrong key gets a 401 that echoes it);
    ``latency`` is how long every answer takes."""

    def __init__(self, responder: Responder, keys: dict[str, str] | None = None, latency: float = 0.0):
        self.responder = responder
        self.keys = keys or {}
        self.latency = latency  # seconds every answer takes, as a real model's would
        self.seen: list[Seen] = []
        self._lock = threading.Lock()
        self._attempts: Counter[tuple[str, str, str]] = Counter()
        owner = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:  # noqa: N802 - http.server's naming
                owner._handle(self)

            def log_message(self, *args: Any) -> None:
                pass

        self._server = _Server(("127.0.0.1", 0), Handler)
        self._server.daemon_threads = True
        self._thread = threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": 0.05},
                                        daemon=True)

    @property
    def port(self) -> int:
        return self._server.server_address[1]

    def base_url(self, protocol: str) -> str:
        version = "v1beta" if protocol == "gemini" else "v1"
        return f"http://127.0.0.1:{self.port}/{protocol}/{version}"

    def spec(self, kind: str, model: str, **options: str) -> str:
        """A backend spec string pointing at this server."""
        protocol = "openai" if kind == "openai-compatible" else kind
        query = "&".join(f"{k}={v}" for k, v in options.items())
        return f"{kind}:{model}@{self.base_url(protocol)}" + (f"?{query}" if query else "")

    def successes(self) -> Counter[tuple[str, str, str]]:
        """Completed (HTTP 200) requests per (protocol, model, tag)."""
        return Counter((s.protocol, s.model, s.tag) for s in self.seen if s.status == 200)

    def requests(self, tag: str | None = None) -> list[Seen]:
        return [s for s in self.seen if tag is None or s.tag == tag]

    def start(self) -> LoopbackLLM:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._server.shutdown()
        self._server.server_close()

    # -- handling ------------------------------------------------------------------------------------
    def _handle(self, handler: BaseHTTPRequestHandler) -> None:
        length = int(handler.headers.get("Content-Length", "0"))
        raw = handler.rfile.read(length)
        match = _PATH.match(handler.path)
        if not match:
            return self._send(handler, 404, {"error": {"message": f"no route {handler.path}"}})
        protocol = match.group(1)
        body = json.loads(raw)
        model = match.group(3) or body.get("model", "")
        prompt = _user_text(protocol, body)
        tail = prompt.split("Now label this CoT", 1)[-1]
        tag_match = _TAG.search(tail)
        tag = tag_match.group(1) if tag_match else "?"
        headers = {k.lower(): v for k, v in handler.headers.items()}
        with self._lock:
            attempt = self._attempts[(protocol, model, tag)]
            self._attempts[(protocol, model, tag)] += 1
        seen = Seen(protocol, model, tag, attempt, 0, headers, body, handler.path)
        with self._lock:
            self.seen.append(seen)
        received = _received_key(protocol, headers)
        expected = self.keys.get(protocol)
        if expected is not None and received != expected:
            seen.status = 401
            self._send(handler, 401, {"error": {"message": f"Incorrect API key provided: {received}"}})
            return
        action = self.responder(protocol, model, tag, attempt)
        if self.latency:
            time.sleep(self.latency)
        if isinstance(action, Hang):
            seen.status = -1  # the client gives up before the answer comes
            time.sleep(action.seconds)
            self._send(handler, 200, _success(protocol, "{}"), quiet=True)
            return
        self._act(handler, protocol, action, seen)

    def _act(self, handler: BaseHTTPRequestHandler, protocol: str, action: Action, seen: Seen) -> None:
        # The status is recorded before the response is written, so a test never sees a reply unrecorded.
        if isinstance(action, Status):
            seen.status = action.code
            body = action.body if action.body is not None else {"error": {"message": "scripted failure"}}
            self._send(handler, action.code, body, action.headers)
            return
        seen.status = 200
        if isinstance(action, RawBody):
            self._send_bytes(handler, 200, action.body, "text/html")
        elif isinstance(action, Refuse):
            self._send(handler, 200, _refusal(protocol))
        else:
            text = action.text if action.text is not None else json.dumps(action.value)
            self._send(handler, 200, _success(protocol, text))

    def _send(self, handler: BaseHTTPRequestHandler, status: int, payload: Any,
              headers: dict[str, str] | None = None, quiet: bool = False) -> None:
        self._send_bytes(handler, status, json.dumps(payload).encode(), "application/json", headers, quiet)

    @staticmethod
    def _send_bytes(handler: BaseHTTPRequestHandler, status: int, data: bytes, content_type: str,
                    headers: dict[str, str] | None = None, quiet: bool = False) -> None:
        try:
            handler.send_response(status)
            handler.send_header("Content-Type", content_type)
            handler.send_header("Content-Length", str(len(data)))
            for name, value in (headers or {}).items():
                handler.send_header(name, value)
            handler.end_headers()
            handler.wfile.write(data)
        except (BrokenPipeError, ConnectionResetError):
            if not quiet:
                raise


def _user_text(protocol: str, body: dict[str, Any]) -> str:
    if protocol == "gemini":
        return body["contents"][-1]["parts"][0]["text"]
    return body["messages"][-1]["content"]


def _received_key(protocol: str, headers: dict[str, str]) -> str | None:
    if protocol == "openai":
        auth = headers.get("authorization", "")
        return auth.removeprefix("Bearer ") if auth else None
    return headers.get("x-api-key" if protocol == "anthropic" else "x-goog-api-key")


def _success(protocol: str, text: str) -> dict[str, Any]:
    if protocol == "openai":
        return {"id": "chatcmpl-1", "object": "chat.completion", "choices": [
            {"index": 0, "message": {"role": "assistant", "content": text, "refusal": None},
             "finish_reason": "stop"}]}
    if protocol == "anthropic":
        return {"id": "msg_1", "type": "message", "role": "assistant",
                "content": [{"type": "text", "text": text}], "stop_reason": "end_turn"}
    return {"candidates": [{"content": {"role": "model", "parts": [{"text": text}]}, "finishReason": "STOP"}]}


def _refusal(protocol: str) -> dict[str, Any]:
    if protocol == "openai":
        return {"choices": [{"index": 0, "message": {"role": "assistant", "content": None,
                                                     "refusal": "I can't help with that."},
                             "finish_reason": "stop"}]}
    if protocol == "anthropic":
        return {"type": "message", "content": [], "stop_reason": "refusal"}
    return {"candidates": [{"content": {"parts": []}, "finishReason": "SAFETY"}]}


class FakeClock:
    """A monotonic clock that only moves when slept on: backoff is measured, never waited for."""

    def __init__(self) -> None:
        self.now = 1000.0
        self.sleeps: list[float] = []
        self._lock = threading.Lock()

    def __call__(self) -> float:
        with self._lock:
            return self.now

    def sleep(self, seconds: float) -> None:
        with self._lock:
            self.sleeps.append(seconds)
            self.now += max(seconds, 0.0)


# -- test data: items tagged for the server, their answers, scripted responders -------------------------

KEYS = {
    "openai": "sk-test-OPENAI-7f3a9c1e5b",
    "anthropic": "sk-ant-test-ANTHROPIC-42d8e0aa",
    "gemini": "AIza-test-GEMINI-91bc77f0",
}
ENVIRON = {"OPENAI_API_KEY": KEYS["openai"], "ANTHROPIC_API_KEY": KEYS["anthropic"],
           "GEMINI_API_KEY": KEYS["gemini"]}
MODELS = {"openai": "gpt-test", "anthropic": "claude-test", "gemini": "gemini-test"}

PEDESTRIAN = {"critical_kind": "pedestrian", "critical_position": [18.0, 0.4], "distance_to_critical": 18.0,
              "light_state": None, "actors": [{"kind": "pedestrian", "position": [18.0, 0.4]}], "ego_speed": 5.5}
RED_LIGHT = {"critical_kind": "traffic_light", "critical_position": [42.0, 2.5], "distance_to_critical": 40.0,
             "light_state": "red", "actors": [{"kind": "traffic_light", "position": [42.0, 2.5]}], "ego_speed": 7.0}
EMPTY = {"critical_kind": None, "critical_position": None, "distance_to_critical": None, "light_state": None,
         "actors": [], "ego_speed": 8.0}


def answer(action: str = "decelerating", mentioned: bool | None = True, slot: str | None = None,
           colour: str | None = None, hallucination: bool = False, contradiction: bool = False) -> dict[str, Any]:
    return {"stated_action": action, "target_mentioned": mentioned, "mention_slot": slot,
            "light_colour": colour, "hallucination": hallucination, "contradiction": contradiction}


def item(tag: str, text: str = "Slow down for the pedestrian ahead.", context: Mapping[str, Any] = PEDESTRIAN,
         slots: Mapping[str, str] | None = None) -> LabelInput:
    if slots:
        slots = {name: (f"CASE-{tag} " + value if i == 0 else value) for i, (name, value) in enumerate(slots.items())}
        return LabelInput(text=" ".join(slots.values()), slots=dict(slots), context=dict(context), key=tag)
    return LabelInput(text=f"CASE-{tag} {text}", context=dict(context), key=tag)


def backend_specs(server: Any) -> list[str]:
    return [server.spec(kind, MODELS[kind]) for kind in ("openai", "anthropic", "gemini")]


class Script:
    """Answers ``truth[tag]`` unless ``actions[(protocol, tag)]`` says otherwise (last action repeats)."""

    def __init__(self, truth: Mapping[str, dict[str, Any]],
                 actions: Mapping[tuple[str, str], Sequence[Action]] | None = None,
                 by_model: Mapping[tuple[str, str], Sequence[Action]] | None = None):
        self.truth, self.actions, self.by_model = dict(truth), dict(actions or {}), dict(by_model or {})

    def __call__(self, protocol: str, model: str, tag: str, attempt: int) -> Action:
        script = self.by_model.get((model, tag)) or self.actions.get((protocol, tag))
        if script:
            return script[min(attempt, len(script) - 1)]
        return Answer(self.truth[tag])
