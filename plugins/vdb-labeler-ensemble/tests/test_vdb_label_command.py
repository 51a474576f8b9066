"""The plugin through ``vdb label`` (the core's command): dry-run, labelling, one-line errors before any call."""

from __future__ import annotations

import json
import socket

import pytest
import vdb_labeler_ensemble.plugin as plugin
from vdb_labeler_ensemble.testing import ENVIRON, KEYS, PEDESTRIAN, Script, Status, answer, backend_specs
from vladrivebench.testing import isolated_registry
from vladrivebench.testing import run_cli as main


@pytest.fixture
def cots(tmp_path):
    path = tmp_path / "cots.jsonl"
    lines = [{"id": tag, "text": f"CASE-{tag} Brake, a pedestrian is ahead.", "context": PEDESTRIAN}
             for tag in ("a", "b", "c", "d")]
    path.write_text("\n".join(json.dumps(line) for line in lines) + "\n")
    return path


@pytest.fixture
def env(monkeypatch):
    for name, value in ENVIRON.items():
        monkeypatch.setenv(name, value)
    return monkeypatch


def vdb(*argv):
    with isolated_registry(("ensemble", plugin)):
        return main(list(argv))


def test_vdb_label_dry_run_then_label_then_nothing_to_spend(loopback, tmp_path, cots, env, capsys):
    server = loopback(Script({t: answer() for t in "abcd"}, {("anthropic", "d"): [Status(500)]}), keys=KEYS)
    common = ["--labeler", "ensemble", "--backends", ",".join(backend_specs(server)),
              "--labeler-opt", f"cache={tmp_path / 'cache.sqlite'}", "--labeler-opt", "max_retries=1"]
    assert vdb("label", "--texts", str(cots), "--dry-run", *common) == 0
    out = capsys.readouterr().out
    assert "4 CoTs to label with ensemble ensemble-0.1.0+prompt.v1." in out
    assert "  anthropic:claude-test: 4 calls, 0 cached" in out
    assert server.seen == []

    out_file = tmp_path / "labelled.jsonl"
    assert vdb("label", "--texts", str(cots), "--out", str(out_file), *common) == 0
    labelled = [json.loads(line)["labels"] for line in out_file.read_text().splitlines()]
    assert [lab["stated_action"] for lab in labelled] == ["decelerating"] * 4
    assert labelled[3]["details"]["votes"]["anthropic:claude-test"]["error"].startswith("HTTP 500")
    assert all(lab["details"]["prompt_version"] == "v1" for lab in labelled)

    capsys.readouterr()
    assert vdb("label", "--texts", str(cots), "--dry-run", *common) == 0
    out = capsys.readouterr().out
    assert "  gemini:gemini-test: 0 calls, 4 cached" in out and "  anthropic:claude-test: 1 calls, 3 cached" in out


@pytest.mark.parametrize("problem, expected", [
    ("missing key", "backend 'anthropic:claude-test' needs an API key in ANTHROPIC_API_KEY, which is not set"),
    ("unknown kind", "unknown backend kind 'mistral' in 'mistral:large'"),
    ("unreachable", "backend 'openai-compatible:qwen': cannot reach http://127.0.0.1:"),
])
def test_bad_input_is_one_line_exit_2_and_spends_nothing(loopback, tmp_path, cots, env, capsys, problem, expected):
    server = loopback(Script({t: answer() for t in "abcd"}), keys=KEYS)
    backends = backend_specs(server)
    if problem == "missing key":
        env.delenv("ANTHROPIC_API_KEY")
    elif problem == "unknown kind":
        backends.append("mistral:large")
    else:
        with socket.socket() as sock:  # a port that was free a moment ago: nothing listens there
            sock.bind(("127.0.0.1", 0))
            port = sock.getsockname()[1]
        backends.append(f"openai-compatible:qwen@http://127.0.0.1:{port}/v1")
    code = vdb("label", "--texts", str(cots), "--out", str(tmp_path / "o.jsonl"), "--labeler", "ensemble",
               "--backends", ",".join(backends), "--labeler-opt", f"cache={tmp_path / 'c.sqlite'}")
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and err.startswith("vdb: error: ") and expected in err
    assert "Traceback" not in err and server.seen == [] and not (tmp_path / "o.jsonl").exists()
