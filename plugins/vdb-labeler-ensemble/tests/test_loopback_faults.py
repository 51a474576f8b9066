"""The labeler against a real loopback server speaking the three wire protocols, with scripted faults.

Every item must end either with the true labels or explicitly unlabelled with the reason; a successful
call is never repeated; a rerun on the same cache costs zero calls; Retry-After is honoured.
"""

from __future__ import annotations

import io
import itertools

import pytest
from vdb_labeler_ensemble.labeler import EnsembleLabeler
from vdb_labeler_ensemble.testing import (
    ENVIRON,
    KEYS,
    MODELS,
    RED_LIGHT,
    Answer,
    Hang,
    RawBody,
    Refuse,
    Script,
    Status,
    answer,
    backend_specs,
    item,
)

FIELDS = ("stated_action", "target_mentioned", "mention_slot", "light_colour", "hallucination", "contradiction")


def make_labeler(server, tmp_path, fake_clock, **options):
    options.setdefault("cache", tmp_path / "cache.sqlite")
    options.setdefault("timeout", 0.25)
    options.setdefault("max_retries", 3)
    return EnsembleLabeler(backend_specs(server), sleep=fake_clock.sleep, clock=fake_clock,
                           progress_stream=io.StringIO(), environ=ENVIRON, **options)


def labels_of(labels):
    return {name: getattr(labels, name) for name in FIELDS}


def test_all_three_protocols_agree(loopback, tmp_path, fake_clock):
    truth = {"ped": answer("decelerating", True), "light": answer("maintaining", True, colour="green"),
             "slots": answer("decelerating", True, slot="objects", hallucination=True)}
    server = loopback(Script(truth), keys=KEYS)
    items = [item("ped"), item("light", "Maintain speed, the light is green.", RED_LIGHT),
             item("slots", slots={"scene": "A quiet road.", "objects": "Pedestrian at <0, 18>. Car at <3, 9>.",
                                  "decision": "Stop for the pedestrian."})]
    with make_labeler(server, tmp_path, fake_clock) as labeler:
        results = labeler.label_batch(items)
    for result, it in zip(results, items, strict=True):
        assert result.unlabelled is None
        assert labels_of(result) == truth[it.key]
        assert set(result.details["votes"]) == {"openai:gpt-test", "anthropic:claude-test", "gemini:gemini-test"}
        assert result.details["prompt_version"] == "v1"
        assert result.labeler == "ensemble" and "prompt.v1" in result.version
    assert all(count == 1 for count in server.successes().values())
    assert len(server.seen) == 9


def test_each_wire_protocol_is_spoken_as_documented(loopback, tmp_path, fake_clock):
    server = loopback(Script({"ped": answer()}), keys=KEYS)
    with make_labeler(server, tmp_path, fake_clock) as labeler:
        labeler.label(item("ped"))
    by_protocol = {seen.protocol: seen for seen in server.seen}
    openai, anthropic, gemini = by_protocol["openai"], by_protocol["anthropic"], by_protocol["gemini"]
    assert openai.path == "/openai/v1/chat/completions"
    assert openai.headers["authorization"] == f"Bearer {KEYS['openai']}"
    assert openai.body["model"] == MODELS["openai"] and openai.body["response_format"] == {"type": "json_object"}
    assert [m["role"] for m in openai.body["messages"]] == ["system", "user"]
    assert "max_completion_tokens" in openai.body and "temperature" not in openai.body
    assert anthropic.path == "/anthropic/v1/messages"
    assert anthropic.headers["x-api-key"] == KEYS["anthropic"] and anthropic.headers["anthropic-version"]
    assert anthropic.body["max_tokens"] > 0 and anthropic.body["system"] and anthropic.body["temperature"] == 0
    assert gemini.path == f"/gemini/v1beta/models/{MODELS['gemini']}:generateContent"
    assert gemini.headers["x-goog-api-key"] == KEYS["gemini"] and "key=" not in gemini.path
    assert gemini.body["generationConfig"]["responseMimeType"] == "application/json"


FAULT_TRUTH = {
    "rate": answer("decelerating"), "err500": answer("maintaining", False), "slow": answer("accelerating"),
    "garbled": answer("decelerating", hallucination=True), "refused": answer("keep_distance"),
    "partial": answer("decelerating", contradiction=True), "rawbody": answer("maintaining"),
    "dead": answer("decelerating"), "split": answer("decelerating"), "split2": answer("decelerating"),
}
MISSING_FIELD = {k: v for k, v in answer("decelerating", contradiction=True).items() if k != "hallucination"}
FAULTS = {
    ("openai", "rate"): [Status(429, {"Retry-After": "7"}), Answer(FAULT_TRUTH["rate"])],
    ("anthropic", "err500"): [Status(500), Status(503), Answer(FAULT_TRUTH["err500"])],
    ("gemini", "slow"): [Hang(1.0), Answer(FAULT_TRUTH["slow"])],
    ("openai", "garbled"): [Answer(text="The car should slow down: decelerating.")],
    ("anthropic", "refused"): [Refuse()],
    ("gemini", "partial"): [Answer(MISSING_FIELD)],
    ("anthropic", "rawbody"): [RawBody()],
    ("openai", "dead"): [Status(500)],
    ("gemini", "dead"): [Refuse()],
    ("openai", "split"): [Answer(answer("maintaining"))],
    ("anthropic", "split"): [Answer(answer("accelerating"))],
    ("openai", "split2"): [Answer(answer("maintaining"))],
    ("anthropic", "split2"): [Answer(answer("accelerating"))],
}
JUDGE = {("claude-judge", "split"): [Answer(answer("decelerating"))],
         ("claude-judge", "split2"): [Answer(answer("none"))]}


def run_faults(loopback, tmp_path, fake_clock, **options):
    server = loopback(Script(FAULT_TRUTH, FAULTS, JUDGE), keys=KEYS)
    items = [item(tag) for tag in FAULT_TRUTH]
    tie = server.spec("anthropic", "claude-judge")
    labeler = make_labeler(server, tmp_path, fake_clock, tie_breaker=tie, **options)
    return server, items, labeler, labeler.label_batch(items)


def test_every_fault_ends_correct_or_explicitly_unlabelled(loopback, tmp_path, fake_clock):
    server, items, labeler, results = run_faults(loopback, tmp_path, fake_clock)
    by_tag = {it.key: result for it, result in zip(items, results, strict=True)}
    for tag in ("rate", "err500", "slow", "garbled", "refused", "partial", "rawbody", "split"):
        assert by_tag[tag].unlabelled is None, (tag, by_tag[tag].unlabelled)
        assert labels_of(by_tag[tag]) == FAULT_TRUTH[tag], tag
    votes = {tag: result.details["votes"] for tag, result in by_tag.items()}
    assert "not valid JSON" in votes["garbled"]["openai:gpt-test"]["error"]
    assert votes["refused"]["anthropic:claude-test"]["error"].startswith("refused")
    assert "missing field hallucination" in votes["partial"]["gemini:gemini-test"]["error"]
    assert "not JSON" in votes["rawbody"]["anthropic:claude-test"]["error"]
    dead = by_tag["dead"].unlabelled
    assert dead.startswith("too few valid answers: 1 of 3 backends (need 2)")
    assert "openai:gpt-test: HTTP 500" in dead and "gave up after 4 attempts" in dead
    assert "gemini:gemini-test: refused" in dead
    assert by_tag["split"].details["decided_by"]["stated_action"] == "tie_breaker"
    assert by_tag["split"].details["tie_breaker"]["answer"]["stated_action"] == "decelerating"
    split2 = by_tag["split2"].unlabelled
    assert "no majority for stated_action" in split2 and "stated_action=\"none\"" in split2
    assert "not one of the tied values" in split2
    labeler.close()


def test_tie_breaker_is_asked_only_for_split_votes(loopback, tmp_path, fake_clock):
    server, _, labeler, _ = run_faults(loopback, tmp_path, fake_clock)
    judged = sorted(seen.tag for seen in server.seen if seen.model == "claude-judge")
    assert judged == ["split", "split2"]
    labeler.close()


def test_no_successful_call_is_repeated(loopback, tmp_path, fake_clock):
    server, _, labeler, _ = run_faults(loopback, tmp_path, fake_clock)
    assert max(server.successes().values()) == 1
    retried = {(s.protocol, s.tag) for s in server.seen if s.attempt > 0}
    assert retried == {("openai", "rate"), ("anthropic", "err500"), ("gemini", "slow"), ("openai", "dead")}
    assert len(server.requests("dead")) == 4 + 1 + 1  # openai tried 1 + 3 retries, the others once
    labeler.close()


def test_a_rerun_on_the_same_cache_spends_nothing(loopback, tmp_path, fake_clock):
    server, items, labeler, first = run_faults(loopback, tmp_path, fake_clock)
    labeler.close()
    before = len(server.seen)
    again = make_labeler(server, tmp_path, fake_clock, tie_breaker=server.spec("anthropic", "claude-judge"),
                         max_retries=0)
    second = again.label_batch(items)
    # Only the calls that never succeeded are tried again; everything answered comes from the cache.
    assert sorted((s.protocol, s.tag) for s in server.seen[before:]) == [("anthropic", "rawbody"), ("openai", "dead")]
    same = [i for i, it in enumerate(items) if it.key != "dead"]  # its reason now says max_retries=0
    assert [second[i].to_json() for i in same] == [first[i].to_json() for i in same]
    plan = again.plan(items)
    assert plan["openai:gpt-test"] == {"calls": 1, "cached": len(items) - 1}
    assert plan["anthropic:claude-test"] == {"calls": 1, "cached": len(items) - 1}
    assert plan["gemini:gemini-test"] == {"calls": 0, "cached": len(items)}
    # dead and rawbody may still split once their missing votes come in: the judge might be asked about them
    assert plan["anthropic:claude-judge"] == {"calls": 2, "cached": 2, "at_least": 0}
    again.close()


def test_a_resumed_run_sends_only_what_is_missing(loopback, tmp_path, fake_clock):
    truth = {f"r{i}": answer("decelerating" if i % 2 else "maintaining") for i in range(8)}
    server = loopback(Script(truth), keys=KEYS)
    items = [item(tag) for tag in truth]
    with make_labeler(server, tmp_path, fake_clock) as first:
        assert first.plan(items)["gemini:gemini-test"] == {"calls": 8, "cached": 0}
        first.label_batch(items[:3])
    with make_labeler(server, tmp_path, fake_clock) as resumed:
        assert resumed.plan(items)["gemini:gemini-test"] == {"calls": 5, "cached": 3}
        results = resumed.label_batch(items)
    assert [labels_of(r) for r in results] == [truth[it.key] for it in items]
    assert max(server.successes().values()) == 1 and len(server.seen) == 3 * 8


def test_identical_items_in_a_batch_cost_one_call_each_backend(loopback, tmp_path, fake_clock):
    server = loopback(Script({"same": answer()}), keys=KEYS)
    with make_labeler(server, tmp_path, fake_clock) as labeler:
        results = labeler.label_batch([item("same")] * 5)
    assert len(server.seen) == 3 and len({r.unlabelled for r in results}) == 1


def test_retry_after_is_honoured_and_backoff_grows(loopback, tmp_path, fake_clock):
    server = loopback(Script({"rl": answer(), "boom": answer()},
                             {("openai", "rl"): [Status(429, {"Retry-After": "7"}), Answer(answer())],
                              ("openai", "boom"): [Status(500)]}), keys=KEYS)
    with make_labeler(server, tmp_path, fake_clock, max_retries=4, concurrency=1) as labeler:
        labeler.label(item("rl"))
        assert any(7.0 <= s <= 7.7 for s in fake_clock.sleeps), fake_clock.sleeps
        fake_clock.sleeps.clear()
        labeler.label(item("boom"))
    delays = fake_clock.sleeps
    assert len(delays) == 4
    for attempt, delay in enumerate(delays):
        assert 0.5 * 2**attempt <= delay <= 2**attempt  # base 1 s, doubled per retry, jittered in [½, 1]


def test_retry_after_too_long_fails_the_call_without_waiting(loopback, tmp_path, fake_clock):
    server = loopback(Script({"long": answer()}, {("openai", "long"): [Status(429, {"Retry-After": "3600"})]}),
                      keys=KEYS)
    with make_labeler(server, tmp_path, fake_clock) as labeler:
        result = labeler.label(item("long"))
    assert result.unlabelled is None  # two backends still agree
    error = result.details["votes"]["openai:gpt-test"]["error"]
    assert "asks to wait 3600 s" in error and not fake_clock.sleeps


def test_no_tie_breaker_leaves_a_split_unlabelled_with_the_split(loopback, tmp_path, fake_clock):
    server = loopback(Script({"s": answer()}, {("openai", "s"): [Answer(answer("maintaining"))],
                                               ("anthropic", "s"): [Answer(answer("accelerating"))]}), keys=KEYS)
    with make_labeler(server, tmp_path, fake_clock) as labeler:
        result = labeler.label(item("s"))
    assert result.unlabelled.startswith("no majority for stated_action (accelerating: anthropic:claude-test; "
                                        "decelerating: gemini:gemini-test; maintaining: openai:gpt-test)")
    assert "no tie_breaker is set" in result.unlabelled


def test_openai_compatible_local_server_without_key(loopback, tmp_path, fake_clock):
    truth = {"local": answer("maintaining", None)}
    server = loopback(Script(truth))
    specs = [server.spec("openai-compatible", name) for name in ("qwen2.5:7b", "llama3.1:8b", "mistral")]
    with EnsembleLabeler(specs, cache=None, environ={}, sleep=fake_clock.sleep, clock=fake_clock,
                         progress_stream=io.StringIO()) as labeler:
        result = labeler.label(item("local", "Keep going at this speed.", {"critical_kind": None, "actors": []}))
    assert labels_of(result) == truth["local"]
    assert result.details["decided_by"]["target_mentioned"].startswith("ground_truth")
    assert all("authorization" not in s.headers for s in server.seen)
    assert {s.body["max_tokens"] for s in server.seen} == {1024} and {s.body["temperature"] for s in server.seen} == {0}


def test_progress_with_eta_goes_to_the_given_stream(loopback, tmp_path):
    truth = {f"p{i}": answer() for i in range(4)}
    server = loopback(Script(truth), keys=KEYS)
    ticks = itertools.count(0, 3)  # every look at the clock is 3 s later: the calls seem slow (thread-safe)

    stream = io.StringIO()
    labeler = EnsembleLabeler(backend_specs(server), cache=tmp_path / "c.sqlite", environ=ENVIRON,
                              clock=lambda: float(next(ticks)), progress_stream=stream, concurrency=1)
    labeler.label_batch([item(tag) for tag in truth])
    labeler.close()
    lines = stream.getvalue().splitlines()
    assert lines and all(line.startswith("ensemble: ") for line in lines)
    assert any(" calls/s, ETA " in line for line in lines[:-1])
    assert lines[-1].startswith("ensemble: 12/12 calls, done in ")


@pytest.mark.parametrize("protocol", ["openai", "anthropic", "gemini"])
def test_a_wrong_key_fails_that_backend_only_and_names_the_variable(loopback, tmp_path, fake_clock, protocol):
    server = loopback(Script({"k": answer()}), keys=KEYS)
    env_var = {"openai": "OPENAI_API_KEY", "anthropic": "ANTHROPIC_API_KEY", "gemini": "GEMINI_API_KEY"}[protocol]
    wrong = dict(ENVIRON, **{env_var: "sk-WRONG-but-still-secret-0042"})
    labeler = EnsembleLabeler(backend_specs(server), cache=tmp_path / "c.sqlite", environ=wrong,
                              sleep=fake_clock.sleep, clock=fake_clock, progress_stream=io.StringIO())
    result = labeler.label(item("k"))
    labeler.close()
    error = result.details["votes"][f"{protocol}:{MODELS[protocol]}"]["error"]
    assert error.startswith("HTTP 401") and env_var in error
    assert "sk-WRONG-but-still-secret-0042" not in error and "***" in error
    assert len(server.requests()) == 3  # a 401 is not retried


def test_an_interrupt_stops_waiting_workers_and_keeps_what_arrived(loopback, tmp_path):
    import os
    import signal
    import threading
    import time

    server = loopback(Script({"wait": answer()}, {("openai", "wait"): [Status(429, {"Retry-After": "120"})]}),
                      keys=KEYS)
    cache = tmp_path / "cache.sqlite"
    labeler = EnsembleLabeler(backend_specs(server), cache=cache, environ=ENVIRON, max_retry_after=600,
                              progress_stream=io.StringIO())  # real sleeps: the Retry-After would take 2 min
    timer = threading.Timer(0.5, os.kill, (os.getpid(), signal.SIGINT))  # as Ctrl-C does
    # Python's own handler, re-registered with the OS: a library loaded by an earlier test (Ray's core
    # worker) can take SIGINT over below Python, and the interrupt then never reached this test (it hung).
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    started = time.monotonic()
    try:
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            labeler.label_batch([item("wait")])
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)
    assert time.monotonic() - started < 10
    assert len(labeler.cache) == 2  # anthropic's and gemini's replies were kept
    labeler.close()


def test_the_dry_run_bounds_the_tie_breaker_calls(loopback, tmp_path, fake_clock):
    truth = {t: answer() for t in ("u1", "u2", "s1")}
    server = loopback(Script(truth, {("openai", "s1"): [Answer(answer("none"))],
                                     ("anthropic", "s1"): [Answer(answer("maintaining"))]}), keys=KEYS)
    items = [item(t) for t in truth]
    judge = server.spec("anthropic", "claude-judge")
    with make_labeler(server, tmp_path, fake_clock, tie_breaker=judge) as labeler:
        assert labeler.plan(items)["anthropic:claude-judge"] == {"calls": 3, "cached": 0, "at_least": 0}
    with make_labeler(server, tmp_path, fake_clock) as voters_only:
        assert voters_only.label(items[2]).unlabelled.startswith("no majority for stated_action")
        voters_only.label_batch(items)
    with make_labeler(server, tmp_path, fake_clock, tie_breaker=judge) as labeler:
        assert labeler.plan(items)["anthropic:claude-judge"] == {"calls": 1, "cached": 0, "at_least": 1}
        labeler.label_batch(items)
        assert labeler.plan(items)["anthropic:claude-judge"] == {"calls": 0, "cached": 1, "at_least": 0}
    assert [s.tag for s in server.seen if s.model == "claude-judge"] == ["s1"]
