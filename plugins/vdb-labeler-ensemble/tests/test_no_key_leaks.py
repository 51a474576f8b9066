"""API keys never appear in logs, progress output, label files, reports or the cache (grepped)."""

from __future__ import annotations

import io
import json
import logging

from vdb_labeler_ensemble.labeler import EnsembleLabeler
from vdb_labeler_ensemble.testing import (
    ENVIRON,
    KEYS,
    Answer,
    Hang,
    Refuse,
    Script,
    Status,
    answer,
    backend_specs,
    item,
)
from vladrivebench.labels import JsonlItem, LabelStore, write_jsonl

WRONG_KEY = "sk-wrong-LEAKCHECK-5e5e5e5e"


def test_keys_never_leak(loopback, tmp_path, fake_clock, caplog, capsys):
    caplog.set_level(logging.DEBUG)  # everything, httpx and httpcore included
    truth = {tag: answer() for tag in ("ok", "rate", "boom", "slow", "deny", "split")}
    faults = {("openai", "rate"): [Status(429, {"Retry-After": "2"}), Answer(truth["rate"])],
              ("anthropic", "boom"): [Status(500, body={"error": {"message": f"echo {KEYS['anthropic']}"}})],
              ("gemini", "slow"): [Hang(0.6), Answer(truth["slow"])],
              ("anthropic", "deny"): [Refuse()],
              ("openai", "split"): [Answer(answer("maintaining"))],
              ("anthropic", "split"): [Answer(answer("accelerating"))]}
    server = loopback(Script(truth, faults), keys={**KEYS, "openai": KEYS["openai"]})
    # The tie-breaker is sent a wrong key: the server's 401 echoes it back, as real providers half do.
    tie = server.spec("openai", "judge", key_env="JUDGE_KEY")
    environ = {**ENVIRON, "JUDGE_KEY": WRONG_KEY}
    progress = io.StringIO()
    items = [item(tag) for tag in truth]
    cache = tmp_path / "cache.sqlite"
    labeler = EnsembleLabeler(backend_specs(server), tie_breaker=tie, cache=cache, timeout=0.25, max_retries=2,
                              environ=environ, sleep=fake_clock.sleep, clock=fake_clock, progress_stream=progress)
    results = labeler.label_batch(items)
    plan = labeler.plan(items)
    text_of_repr = repr(labeler) + repr(labeler._clients)
    labeler.close()

    assert results[-1].details["tie_breaker"]["error"].startswith("HTTP 401")
    entries = [JsonlItem(it.key, it) for it in items]
    write_jsonl(tmp_path / "labels.jsonl", entries, results)
    store = LabelStore(tmp_path / "run", "ensemble")
    store.add([(it, it.key, label) for it, label in zip(items, results, strict=True)], labeler.version)
    (tmp_path / "report.json").write_text(json.dumps({"plan": plan, "labels": [r.to_json() for r in results]}))

    captured = capsys.readouterr()
    outputs = {
        "log": "\n".join(f"{r.name} {r.getMessage()} {r.args}" for r in caplog.records),
        "stdout+stderr": captured.out + captured.err,
        "progress": progress.getvalue(),
        "repr": text_of_repr,
        "labels.jsonl": (tmp_path / "labels.jsonl").read_text(),
        "label store": store.path.read_text(),
        "report.json": (tmp_path / "report.json").read_text(),
        "cache": cache.read_bytes().decode("latin-1"),
    }
    assert any("retry" in r.getMessage() for r in caplog.records)  # the logs did record the faults
    assert "***" in outputs["labels.jsonl"]  # the echoed keys were redacted, not dropped silently
    for secret in [*KEYS.values(), WRONG_KEY]:
        for where, text in outputs.items():
            assert secret not in text, f"key leaked into {where}"
