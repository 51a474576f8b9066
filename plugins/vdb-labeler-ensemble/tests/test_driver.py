"""``python -m vdb_labeler_ensemble``: label a JSONL file end to end, dry-run, one-line errors."""

from __future__ import annotations

import json

import pytest
from vdb_labeler_ensemble.__main__ import main
from vdb_labeler_ensemble.testing import ENVIRON, KEYS, PEDESTRIAN, Script, Status, answer, backend_specs


@pytest.fixture
def cots(tmp_path):
    path = tmp_path / "cots.jsonl"
    lines = [{"id": "a", "text": "CASE-a Slow down, pedestrian ahead.", "context": PEDESTRIAN},
             {"id": "b", "slots": {"scene": "CASE-b A road.", "objects": "A pedestrian at <0, 18>.",
                                   "decision": "Stop."}, "context": PEDESTRIAN},
             {"id": "c", "text": "CASE-c Keep going.", "context": PEDESTRIAN}]
    path.write_text("\n".join(json.dumps(line) for line in lines) + "\n")
    return path


@pytest.fixture
def keys(monkeypatch):
    for name, value in ENVIRON.items():
        monkeypatch.setenv(name, value)


def test_label_a_jsonl_file_then_rerun_from_cache(loopback, tmp_path, cots, keys, capsys):
    truth = {"a": answer(), "b": answer(slot="objects"), "c": answer("maintaining", False)}
    server = loopback(Script(truth, {("gemini", "c"): [Status(400)]}), keys=KEYS)
    args = ["label", str(cots), "-o", str(tmp_path / "out.jsonl"), "--backends", ",".join(backend_specs(server)),
            "--cache", str(tmp_path / "cache.sqlite"), "--timeout", "2"]
    assert main(["label", str(cots), "--dry-run", *args[4:]]) == 0
    plan = capsys.readouterr().out
    assert "3 CoTs" in plan and "gemini:gemini-test" in plan and "calls      3  cached      0" in plan
    assert main(args) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["labelled"] == 3
    written = [json.loads(line) for line in (tmp_path / "out.jsonl").read_text().splitlines()]
    assert [w["labels"]["stated_action"] for w in written] == ["decelerating", "decelerating", "maintaining"]
    assert written[1]["labels"]["mention_slot"] == "objects"
    assert written[2]["labels"]["details"]["votes"]["gemini:gemini-test"]["error"].startswith("HTTP 400")
    requests = len(server.seen)
    assert main(["label", str(cots), "--dry-run", *args[4:]]) == 0
    assert "calls      0  cached      3" in capsys.readouterr().out
    assert main([*args, "--no-progress"]) == 0
    assert len(server.seen) == requests + 1  # only the call that failed with HTTP 400 is tried again


def test_render_shows_the_messages(cots, capsys):
    assert main(["render", str(cots), "--id", "b"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("--- system ---") and "[objects] A pedestrian at <0, 18>." in out


def test_prompt_prints_the_shipped_file(capsys):
    assert main(["prompt"]) == 0
    assert 'version = "v1"' in capsys.readouterr().out


@pytest.mark.parametrize("argv, expected", [
    (["label", "{cots}", "--backends", "openai:gpt"], "give --output FILE"),
    (["label", "{cots}", "-o", "x", "--backends", "claude:opus"], "unknown backend kind 'claude'"),
    (["label", "missing.jsonl", "-o", "x", "--backends", "openai:gpt"], "missing.jsonl: no such file"),
    (["label", "{cots}", "-o", "x", "--backends", "openai:gpt", "--cache", "off"], "needs an API key in OPENAI_API_KEY"),
    (["render", "{cots}", "--id", "zz"], "no CoT with id 'zz'"),
])
def test_mistakes_are_one_line_and_exit_2(cots, capsys, monkeypatch, argv, expected):
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    argv = [a.replace("{cots}", str(cots)) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and expected in err and err.startswith("python -m vdb_labeler_ensemble: error: ")
