"""Bad configuration: one line saying which and how to fix it, before any call is spent."""

from __future__ import annotations

import io
import socket
import subprocess
import sys

import pytest
import vdb_labeler_ensemble.plugin as plugin
from vdb_labeler_ensemble.labeler import EnsembleLabeler
from vdb_labeler_ensemble.testing import ENVIRON, KEYS, Script, answer, backend_specs, item
from vladrivebench import ConfigError, VdbError
from vladrivebench.testing import Registry


def registry() -> Registry:
    return Registry(plugins=[("ensemble", plugin)], entry_points=False)


def one_line(exc: BaseException) -> str:
    text = str(exc)
    assert "\n" not in text and text
    return text


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.mark.parametrize("missing, variable", [("OPENAI_API_KEY", "OPENAI_API_KEY"),
                                               ("ANTHROPIC_API_KEY", "ANTHROPIC_API_KEY"),
                                               ("GEMINI_API_KEY", "GEMINI_API_KEY or GOOGLE_API_KEY")])
def test_a_missing_key_names_the_variable_and_spends_nothing(loopback, missing, variable):
    server = loopback(Script({"k": answer()}), keys=KEYS)
    environ = {k: v for k, v in ENVIRON.items() if k != missing}
    labeler = EnsembleLabeler(backend_specs(server), cache=None, environ=environ, progress_stream=io.StringIO())
    with pytest.raises(ConfigError) as raised:
        labeler.check()
    assert f"needs an API key in {variable}, which is not set: export" in one_line(raised.value)
    with pytest.raises(ConfigError):
        labeler.label_batch([item("k")])
    assert server.seen == []


def test_google_api_key_is_accepted_for_gemini(loopback):
    server = loopback(Script({"k": answer()}), keys=KEYS)
    environ = dict(ENVIRON)
    environ["GOOGLE_API_KEY"] = environ.pop("GEMINI_API_KEY")
    with EnsembleLabeler(backend_specs(server), cache=None, environ=environ, progress_stream=io.StringIO()) as lab:
        assert lab.label(item("k")).unlabelled is None


def test_a_key_env_override_is_required_once_named(loopback):
    server = loopback(Script({"k": answer()}))
    spec = server.spec("openai-compatible", "local", key_env="MY_VLLM_KEY")
    labeler = EnsembleLabeler([spec], cache=None, environ={}, progress_stream=io.StringIO())
    with pytest.raises(ConfigError, match="needs an API key in MY_VLLM_KEY"):
        labeler.check()
    labeler = EnsembleLabeler([spec], cache=None, environ={"MY_VLLM_KEY": "local-secret-1"},
                              progress_stream=io.StringIO())
    assert labeler.label(item("k")).unlabelled is None
    assert server.seen[0].headers["authorization"] == "Bearer local-secret-1"


def test_an_unreachable_base_url_is_reported_before_any_call(loopback):
    server = loopback(Script({"k": answer()}), keys=KEYS)
    dead = f"openai-compatible:qwen@http://127.0.0.1:{free_port()}/v1"
    labeler = EnsembleLabeler([*backend_specs(server), dead], cache=None, environ=ENVIRON,
                              progress_stream=io.StringIO())
    with pytest.raises(ConfigError) as raised:
        labeler.label_batch([item("k")])
    message = one_line(raised.value)
    assert message.startswith("backend 'openai-compatible:qwen': cannot reach http://127.0.0.1:")
    assert "start the server, or fix the URL after '@'" in message
    assert server.seen == []


@pytest.mark.parametrize("options, expected", [
    ({"backends": "mistral:large"}, "unknown backend kind 'mistral'"),
    ({"backends": "openai-compatible:qwen"}, "needs a base URL: write openai-compatible:qwen@http://HOST:PORT/v1"),
    ({"backends": "openai"}, "cannot read backend 'openai': expected KIND:MODEL"),
    ({"backends": ""}, "give at least one backend"),
    ({"backends": "openai:a,openai:a"}, "backend name 'openai:a' is used twice"),
    ({"backends": "openai:a?colour=blue"}, "unknown option 'colour'"),
    ({"backends": "openai:a?max_tokens=lots"}, "bad option value"),
    ({"backends": "openai:a?key_env=1BAD"}, "key_env must name an environment variable"),
    ({"backends": "openai:my model"}, "cannot read backend 'openai:my model'"),
    ({"backends": "openai-compatible:m@http://127.0.0.1:99999/v1"}, "malformed port"),
    ({"backends": "openai:a", "tie_breaker": "openai:a"}, "is also a voting backend"),
    ({"backends": "openai:a,anthropic:b", "min_votes": 3}, "min_votes=3: must be between 1 and"),
    ({"backends": "openai:a", "concurrency": 0}, "concurrency must be a whole number >= 1"),
    ({"backends": "openai:a", "timeout": "soon"}, "timeout must be a number of seconds > 0"),
    ({"backends": "openai:a", "progress": "loud"}, "progress must be true or false"),
    ({"backends": "openai:a", "prompt": "/nonexistent/prompt.toml"}, "prompt file /nonexistent/prompt.toml: no such file"),
    ({"backends": "openai:a", "temperature": 0}, "does not take option 'temperature'"),
])
def test_bad_options_fail_at_creation_with_one_line(tmp_path, options, expected):
    options = {"cache": str(tmp_path / "c.sqlite"), **options}
    with pytest.raises(VdbError) as raised:
        registry().create("labeler", "ensemble", options)
    assert expected in one_line(raised.value)


def test_a_corrupt_cache_file_is_one_line(tmp_path):
    bad = tmp_path / "cache.sqlite"
    bad.write_bytes(b"this is not a database" * 100)
    with pytest.raises(ConfigError, match="not a usable SQLite cache .* delete it or choose another"):
        registry().create("labeler", "ensemble", {"backends": "openai:a", "cache": str(bad)})


def test_registration_imports_nothing_heavy():
    code = ("import sys, vdb_labeler_ensemble.plugin as p; "
            "from vladrivebench._engine.registry import Registry; "
            "r = Registry(plugins=[('ensemble', p)], entry_points=False); assert r.names('labeler') == ['ensemble']; "
            "heavy = [m for m in ('httpx', 'sqlite3', 'numpy', 'vdb_labeler_ensemble.labeler') if m in sys.modules]; "
            "print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert "httpx" not in out and "sqlite3" not in out and "vdb_labeler_ensemble.labeler" not in out
