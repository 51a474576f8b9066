"""Backend specs and the three wire formats (pure: no network)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vdb_labeler_ensemble.backends import (
    PROVIDERS,
    ProtocolError,
    Reply,
    build_request,
    parse_backend,
    parse_backends,
    read_reply,
)
from vladrivebench import ConfigError


def test_the_documented_examples_parse():
    specs = parse_backends("openai:gpt-5.4, anthropic:claude-opus-4-6,gemini:gemini-2.5-pro,"
                           "openai-compatible:llama3.1:8b@http://127.0.0.1:11434/v1?name=ollama")
    assert [s.name for s in specs] == ["openai:gpt-5.4", "anthropic:claude-opus-4-6", "gemini:gemini-2.5-pro",
                                       "ollama"]
    assert specs[0].base_url == "https://api.openai.com/v1" and specs[0].key_envs == ("OPENAI_API_KEY",)
    assert specs[2].key_envs == ("GEMINI_API_KEY", "GOOGLE_API_KEY")
    local = specs[3]
    assert (local.kind, local.model, local.base_url) == ("openai-compatible", "llama3.1:8b", "http://127.0.0.1:11434/v1")
    assert local.key_envs == () and not local.key_required


def test_options_and_mappings():
    spec = parse_backend("anthropic:claude-opus-4-7@https://proxy.example/v1/?key_env=TEAM_KEY&temperature=0.2"
                         "&max_tokens=2048&name=judge")
    assert spec.base_url == "https://proxy.example/v1" and spec.key_envs == ("TEAM_KEY",) and spec.key_required
    assert (spec.temperature, spec.max_tokens, spec.name) == (0.2, 2048, "judge")
    from_toml = parse_backend({"kind": "openai-compatible", "model": "qwen", "base_url": "http://127.0.0.1:8000/v1",
                               "json_mode": False, "temperature": "default"})
    assert from_toml.json_mode is False and from_toml.temperature is None
    with pytest.raises(ConfigError, match="unknown key 'url'"):
        parse_backend({"kind": "openai", "model": "x", "url": "http://a"})


model_names = st.from_regex(r"[A-Za-z0-9][A-Za-z0-9._:/-]{0,30}", fullmatch=True)


@settings(deadline=None)
@given(st.sampled_from(sorted(PROVIDERS)), model_names, st.sampled_from(["", "http://127.0.0.1:8080/v1"]))
def test_any_model_name_survives_parsing(kind, model, url):
    if kind == "openai-compatible" and not url:
        url = "http://localhost:9/v1"
    spec = parse_backend(f"{kind}:{model}" + (f"@{url}" if url else ""))
    assert (spec.kind, spec.model, spec.name) == (kind, model, f"{kind}:{model}")
    assert spec.base_url == (url or PROVIDERS[kind].base_url)


@settings(deadline=None)
@given(st.sampled_from(sorted(PROVIDERS)), model_names)
def test_identity_changes_with_everything_that_changes_answers(kind, model):
    url = "@http://127.0.0.1:1/v1"
    a = parse_backend(f"{kind}:{model}{url}")
    assert a.identity() == parse_backend(f"{kind}:{model}{url}?name=alias").identity()
    for option in ("temperature=0.7", "max_tokens=7", "json_mode=false"):
        changed = parse_backend(f"{kind}:{model}{url}?{option}")
        assert changed.identity() != a.identity() or option == "json_mode=false" and not a.json_mode


def test_requests_carry_the_key_only_in_headers():
    for kind, header in [("openai", "Authorization"), ("anthropic", "x-api-key"), ("gemini", "x-goog-api-key")]:
        request = build_request(parse_backend(f"{kind}:m"), "sys", "user", "SECRET")
        assert "SECRET" in request.headers[header] and "SECRET" not in request.url + str(request.body)
    local = build_request(parse_backend("openai-compatible:m@http://127.0.0.1:1/v1"), "s", "u", None)
    assert "Authorization" not in local.headers and local.body["max_tokens"] == 1024


@pytest.mark.parametrize("kind, body, expected", [
    ("openai", {"choices": [{"message": {"content": "{}"}, "finish_reason": "stop"}]}, Reply("{}", None, "stop")),
    ("openai", {"choices": [{"message": {"content": None, "refusal": "nope"}, "finish_reason": "stop"}]},
     Reply(None, "nope", "stop")),
    ("openai", {"choices": [{"message": {"content": ""}, "finish_reason": "content_filter"}]},
     Reply(None, "content filter", "content_filter")),
    ("openai-compatible", {"choices": [{"message": {"content": [{"type": "text", "text": "{}"}]}}]},
     Reply("{}", None, None)),
    ("anthropic", {"content": [{"type": "thinking", "thinking": "hm"}, {"type": "text", "text": "{}"}],
                   "stop_reason": "end_turn"}, Reply("{}", None, "end_turn")),
    ("anthropic", {"content": [], "stop_reason": "refusal"}, Reply(None, "the model refused (stop_reason=refusal)",
                                                                   "refusal")),
    ("gemini", {"candidates": [{"content": {"parts": [{"text": "x", "thought": True}, {"text": "{}"}]},
                                "finishReason": "STOP"}]}, Reply("{}", None, "STOP")),
    ("gemini", {"promptFeedback": {"blockReason": "SAFETY"}}, Reply(None, "prompt blocked (SAFETY)", None)),
    ("gemini", {"candidates": [{"finishReason": "SAFETY"}]},
     Reply(None, "the model refused (finishReason=SAFETY)", "SAFETY")),
])
def test_replies_are_read_per_protocol(kind, body, expected):
    spec = parse_backend(f"{kind}:m@http://127.0.0.1:1/v1")
    assert read_reply(spec, body) == expected


@pytest.mark.parametrize("kind, body", [("openai", {"choices": []}), ("anthropic", {"id": 1}),
                                        ("openai", ["not", "a", "dict"]), ("anthropic", {"content": "text"})])
def test_wrong_shapes_are_protocol_errors(kind, body):
    with pytest.raises(ProtocolError):
        read_reply(parse_backend(f"{kind}:m"), body)
