"""Backend specifications and the three wire protocols (OpenAI chat completions, Anthropic Messages, Gemini).

A backend is written as one string::

    KIND:MODEL[@BASE_URL][?option=value&option=value]

``KIND`` is ``openai``, ``openai-compatible``, ``anthropic`` or ``gemini``; ``MODEL`` may itself contain
``:`` (``llama3.1:8b``); ``@BASE_URL`` (``http://`` or ``https://``) overrides the provider's endpoint and
is required for ``openai-compatible``. Options: ``key_env`` (environment variable holding the API key),
``name`` (how the backend is called in votes and reports), ``temperature``, ``max_tokens``, ``json_mode``.
This module is pure: it builds request bodies and reads response bodies, it never talks to the network.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any
from urllib.parse import parse_qsl, urlsplit

from vladrivebench import ConfigError

SPEC_SYNTAX = "KIND:MODEL[@BASE_URL][?key_env=VAR&name=ALIAS&temperature=T&max_tokens=N&json_mode=true|false]"
SPEC_OPTIONS = ("key_env", "name", "temperature", "max_tokens", "json_mode")


@dataclass(frozen=True)
class Provider:
    """What differs between kinds: the default endpoint, where the key lives, the request defaults."""

    kind: str
    base_url: str | None
    key_envs: tuple[str, ...]
    key_required: bool
    temperature: float | None
    max_tokens: int
    json_mode: bool
    key_help: str


PROVIDERS: dict[str, Provider] = {
    "openai": Provider(
        "openai", "https://api.openai.com/v1", ("OPENAI_API_KEY",), True,
        # GPT-5-family models only accept their default temperature, so none is sent unless asked for.
        temperature=None, max_tokens=4096, json_mode=True,
        key_help="export OPENAI_API_KEY=… (or name another variable with ?key_env=VAR)",
    ),
    "openai-compatible": Provider(
        "openai-compatible", None, (), False, temperature=0.0, max_tokens=1024, json_mode=True,
        key_help="export the variable named by ?key_env=VAR (local servers usually need no key)",
    ),
    "anthropic": Provider(
        "anthropic", "https://api.anthropic.com/v1", ("ANTHROPIC_API_KEY",), True,
        temperature=0.0, max_tokens=1024, json_mode=False,
        key_help="export ANTHROPIC_API_KEY=… (or name another variable with ?key_env=VAR)",
    ),
    "gemini": Provider(
        "gemini", "https://generativelanguage.googleapis.com/v1beta", ("GEMINI_API_KEY", "GOOGLE_API_KEY"), True,
        # Gemini 2.5 counts its thinking tokens against the output budget.
        temperature=0.0, max_tokens=8192, json_mode=True,
        key_help="export GEMINI_API_KEY=… (or GOOGLE_API_KEY, or name another variable with ?key_env=VAR)",
    ),
}

_SPEC = re.compile(
    r"^(?P<kind>[A-Za-z][A-Za-z0-9_-]*):(?P<model>[^\s?]+?)(?:@(?P<url>https?://[^?\s]+))?(?:\?(?P<opts>[^\s]*))?$"
)


@dataclass(frozen=True)
class BackendSpec:
    """One configured LLM backend. ``key_envs`` are tried in order; the key itself is never stored here."""

    kind: str
    model: str
    base_url: str
    name: str
    key_envs: tuple[str, ...]
    key_required: bool
    temperature: float | None
    max_tokens: int
    json_mode: bool
    text: str = field(default="", compare=False)

    @property
    def provider(self) -> Provider:
        return PROVIDERS[self.kind]

    def identity(self) -> dict[str, Any]:
        """Everything about this backend that can change its answers (part of every cache key)."""
        return {
            "kind": self.kind, "model": self.model, "base_url": self.base_url,
            "temperature": self.temperature, "max_tokens": self.max_tokens, "json_mode": self.json_mode,
        }

    def same_model(self, other: BackendSpec) -> bool:
        return (self.kind, self.model, self.base_url) == (other.kind, other.model, other.base_url)

    def find_key(self, environ: Mapping[str, str] | None = None) -> str | None:
        """The API key from the first non-empty variable of ``key_envs``, or ``None``."""
        environ = os.environ if environ is None else environ
        for var in self.key_envs:
            value = environ.get(var, "").strip()
            if value:
                return value
        return None

    def missing_key_message(self) -> str:
        names = " or ".join(self.key_envs)
        return f"backend {self.name!r} needs an API key in {names}, which is not set: {self.provider.key_help}"


def parse_backend(entry: str | Mapping[str, Any], where: str = "backends") -> BackendSpec:
    """Parse one backend written as a spec string or as a mapping (``{kind, model, base_url, …}``)."""
    if isinstance(entry, Mapping):
        return _from_mapping(entry, where)
    if not isinstance(entry, str) or not entry.strip():
        raise ConfigError(f"{where}: each backend must be a string {SPEC_SYNTAX}, got {entry!r}")
    text = entry.strip()
    match = _SPEC.match(text)
    if not match:
        raise ConfigError(f"{where}: cannot read backend {text!r}: expected {SPEC_SYNTAX}, "
                          f"e.g. openai-compatible:qwen2.5@http://127.0.0.1:8000/v1")
    options = _parse_options(match["opts"] or "", text, where)
    return _build(match["kind"], match["model"], match["url"], options, text, where)


def parse_backends(value: Any, where: str = "backends") -> list[BackendSpec]:
    """Parse the ``backends`` option: a comma-separated string, or a list of strings / mappings."""
    if isinstance(value, str):
        entries: list[Any] = [part for part in (p.strip() for p in value.split(",")) if part]
    elif isinstance(value, (list, tuple)):
        entries = list(value)
    else:
        entries = []
    if not entries:
        raise ConfigError(f"{where}: give at least one backend, e.g. "
                          f"backends=openai:gpt-5.4,anthropic:claude-opus-4-6,gemini:gemini-2.5-pro")
    specs = [parse_backend(entry, where) for entry in entries]
    seen: dict[str, BackendSpec] = {}
    for spec in specs:
        if spec.name in seen:
            raise ConfigError(f"{where}: backend name {spec.name!r} is used twice: "
                              f"give one a distinct name with ?name=ALIAS")
        seen[spec.name] = spec
    return specs


def _parse_options(text: str, spec: str, where: str) -> dict[str, str]:
    options: dict[str, str] = {}
    for key, value in parse_qsl(text, keep_blank_values=True):
        if key not in SPEC_OPTIONS:
            raise ConfigError(f"{where}: backend {spec!r} has unknown option {key!r} "
                              f"(options: {', '.join(SPEC_OPTIONS)})")
        options[key] = value
    return options


def _from_mapping(entry: Mapping[str, Any], where: str) -> BackendSpec:
    allowed = {"kind", "model", "base_url", *SPEC_OPTIONS}
    unknown = sorted(set(entry) - allowed)
    if unknown:
        raise ConfigError(f"{where}: backend {dict(entry)!r} has unknown key {unknown[0]!r} "
                          f"(keys: {', '.join(sorted(allowed))})")
    if not entry.get("kind") or not entry.get("model"):
        raise ConfigError(f"{where}: backend {dict(entry)!r} needs 'kind' and 'model'")
    options = {k: str(v).lower() if isinstance(v, bool) else str(v)
               for k, v in entry.items() if k in SPEC_OPTIONS}
    text = f"{entry['kind']}:{entry['model']}" + (f"@{entry['base_url']}" if entry.get("base_url") else "")
    return _build(str(entry["kind"]), str(entry["model"]), entry.get("base_url"), options, text, where)


def _build(kind: str, model: str, url: str | None, options: dict[str, str], text: str, where: str) -> BackendSpec:
    kind = kind.lower()
    provider = PROVIDERS.get(kind)
    if provider is None:
        raise ConfigError(f"{where}: unknown backend kind {kind!r} in {text!r} "
                          f"(kinds: {', '.join(PROVIDERS)}; for a local server use openai-compatible:MODEL@URL)")
    base_url = (url or provider.base_url or "").rstrip("/")
    if not base_url:
        raise ConfigError(f"{where}: backend {text!r} needs a base URL: write {kind}:{model}@http://HOST:PORT/v1")
    _check_url(base_url, text, where)
    key_envs = provider.key_envs
    key_required = provider.key_required
    if "key_env" in options:
        var = options["key_env"].strip()
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", var):
            raise ConfigError(f"{where}: backend {text!r}: key_env must name an environment variable, got {var!r}")
        key_envs, key_required = (var,), True
    spec = BackendSpec(
        kind=kind, model=model.strip(), base_url=base_url, name=options.get("name") or f"{kind}:{model.strip()}",
        key_envs=key_envs, key_required=key_required, temperature=provider.temperature,
        max_tokens=provider.max_tokens, json_mode=provider.json_mode, text=text,
    )
    return replace(spec, **_typed_options(options, text, where))


def _typed_options(options: dict[str, str], text: str, where: str) -> dict[str, Any]:
    typed: dict[str, Any] = {}
    try:
        if "temperature" in options:
            raw = options["temperature"].strip().lower()
            typed["temperature"] = None if raw in {"", "none", "default"} else float(raw)
        if "max_tokens" in options:
            typed["max_tokens"] = int(options["max_tokens"])
            if typed["max_tokens"] < 1:
                raise ValueError("must be at least 1")
        if "json_mode" in options:
            raw = options["json_mode"].strip().lower()
            if raw not in {"true", "false", "1", "0", "yes", "no"}:
                raise ValueError("must be true or false")
            typed["json_mode"] = raw in {"true", "1", "yes"}
    except ValueError as exc:
        raise ConfigError(f"{where}: backend {text!r} has a bad option value ({exc})") from None
    return typed


def _check_url(url: str, text: str, where: str) -> None:
    parts = urlsplit(url)
    if parts.scheme not in {"http", "https"} or not parts.hostname:
        raise ConfigError(f"{where}: backend {text!r}: base URL {url!r} must look like http://HOST:PORT/v1")
    try:
        parts.port  # noqa: B018 - raises on a malformed port
    except ValueError:
        raise ConfigError(f"{where}: backend {text!r}: base URL {url!r} has a malformed port") from None


# -- wire protocols ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Reply:
    """What a backend answered in a completed (HTTP 200) call: the text, or why there is none."""

    text: str | None
    refusal: str | None = None
    finish: str | None = None

    def to_json(self) -> dict[str, Any]:
        return {"text": self.text, "refusal": self.refusal, "finish": self.finish}

    @staticmethod
    def from_json(data: Mapping[str, Any]) -> Reply:
        return Reply(data.get("text"), data.get("refusal"), data.get("finish"))


class ProtocolError(Exception):
    """A response body that does not have the shape of its wire protocol."""


@dataclass(frozen=True)
class Request:
    url: str
    headers: dict[str, str]
    body: dict[str, Any]


def build_request(spec: BackendSpec, system: str, user: str, key: str | None) -> Request:
    """The HTTP request for one labelling call to ``spec``."""
    return _BUILDERS[spec.kind](spec, system, user, key)


def read_reply(spec: BackendSpec, body: Any) -> Reply:
    """The :class:`Reply` in a decoded response body; :class:`ProtocolError` if the shape is wrong."""
    if not isinstance(body, dict):
        raise ProtocolError(f"expected a JSON object, got {type(body).__name__}")
    try:
        return _READERS[spec.kind](body)
    except (KeyError, IndexError, TypeError, AttributeError) as exc:
        raise ProtocolError(f"unexpected response shape ({type(exc).__name__}: {exc})") from None


def _openai_request(spec: BackendSpec, system: str, user: str, key: str | None) -> Request:
    body: dict[str, Any] = {
        "model": spec.model,
        "messages": [{"role": "system", "content": system}, {"role": "user", "content": user}],
    }
    # api.openai.com deprecated max_tokens for max_completion_tokens; local servers still read max_tokens.
    body["max_completion_tokens" if spec.kind == "openai" else "max_tokens"] = spec.max_tokens
    if spec.temperature is not None:
        body["temperature"] = spec.temperature
    if spec.json_mode:
        body["response_format"] = {"type": "json_object"}
    headers = {"Content-Type": "application/json"}
    if key:
        headers["Authorization"] = f"Bearer {key}"
    return Request(f"{spec.base_url}/chat/completions", headers, body)


def _openai_reply(body: dict[str, Any]) -> Reply:
    choice = body["choices"][0]
    message = choice["message"]
    finish = choice.get("finish_reason")
    refusal = message.get("refusal") or ("content filter" if finish == "content_filter" else None)
    return Reply(_text_or_none(message.get("content")), refusal, finish)


def _anthropic_request(spec: BackendSpec, system: str, user: str, key: str | None) -> Request:
    body: dict[str, Any] = {
        "model": spec.model,
        "max_tokens": spec.max_tokens,
        "system": system,
        "messages": [{"role": "user", "content": user}],
    }
    if spec.temperature is not None:
        body["temperature"] = spec.temperature
    headers = {"Content-Type": "application/json", "anthropic-version": "2023-06-01"}
    if key:
        headers["x-api-key"] = key
    return Request(f"{spec.base_url}/messages", headers, body)


def _anthropic_reply(body: dict[str, Any]) -> Reply:
    stop = body.get("stop_reason")
    texts = [block["text"] for block in body["content"] if block.get("type") == "text"]
    refusal = "the model refused (stop_reason=refusal)" if stop == "refusal" else None
    return Reply(_text_or_none("".join(texts)), refusal, stop)


def _gemini_request(spec: BackendSpec, system: str, user: str, key: str | None) -> Request:
    config: dict[str, Any] = {"maxOutputTokens": spec.max_tokens}
    if spec.temperature is not None:
        config["temperature"] = spec.temperature
    if spec.json_mode:
        config["responseMimeType"] = "application/json"
    body = {
        "systemInstruction": {"parts": [{"text": system}]},
        "contents": [{"role": "user", "parts": [{"text": user}]}],
        "generationConfig": config,
    }
    # The key goes in a header, never in the URL, so that it cannot leak through logged URLs.
    headers = {"Content-Type": "application/json"}
    if key:
        headers["x-goog-api-key"] = key
    model = spec.model.removeprefix("models/")  # both "gemini-2.5-pro" and "models/gemini-2.5-pro" work
    return Request(f"{spec.base_url}/models/{model}:generateContent", headers, body)


_GEMINI_REFUSALS = {"SAFETY", "RECITATION", "BLOCKLIST", "PROHIBITED_CONTENT", "SPII", "LANGUAGE", "OTHER"}


def _gemini_reply(body: dict[str, Any]) -> Reply:
    blocked = (body.get("promptFeedback") or {}).get("blockReason")
    candidates = body.get("candidates") or []
    if not candidates:
        reason = f"prompt blocked ({blocked})" if blocked else "no candidates in the response"
        return Reply(None, reason, None)
    candidate = candidates[0]
    finish = candidate.get("finishReason")
    parts = (candidate.get("content") or {}).get("parts") or []
    text = "".join(part.get("text", "") for part in parts if not part.get("thought"))
    refusal = f"the model refused (finishReason={finish})" if finish in _GEMINI_REFUSALS else None
    return Reply(_text_or_none(text), refusal, finish)


def _text_or_none(text: Any) -> str | None:
    if isinstance(text, list):  # some OpenAI-compatible servers return content parts
        text = "".join(part.get("text", "") for part in text if isinstance(part, dict))
    return text if isinstance(text, str) and text.strip() else None


_BUILDERS: dict[str, Callable[[BackendSpec, str, str, str | None], Request]] = {
    "openai": _openai_request,
    "openai-compatible": _openai_request,
    "anthropic": _anthropic_request,
    "gemini": _gemini_request,
}
_READERS: dict[str, Callable[[dict[str, Any]], Reply]] = {
    "openai": _openai_reply,
    "openai-compatible": _openai_reply,
    "anthropic": _anthropic_reply,
    "gemini": _gemini_reply,
}

CUT_OFF_FINISHES = {"length", "max_tokens", "MAX_TOKENS"}
"""Finish reasons that mean the answer was cut off by the output-token limit."""
