"""Hypothesis over every file format the CLI reads: truncations, byte flips, wrong encodings and wrong shapes
of configuration TOML, scenario TOML/JSON, condition files, label JSONL, run manifests and episode logs.

Whatever the bytes, the command either accepts the file (exit 0) or refuses it in one ``vdb: error:`` line
with exit 2; never a traceback, and no file that existed before is changed.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import pytest
from harness import Case, classify, explain, run_in_process, snapshot  # noqa: E402
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_fuzz_cli import complete_run  # noqa: E402

FUZZ = settings(max_examples=25, derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz-files")


def mutated(valid: bytes, *, text: bool = True):
    """Strategies that damage ``valid``: truncate it, flip bytes, re-encode it (text files), or replace it."""
    truncate = st.integers(0, max(len(valid) - 1, 0)).map(lambda n: valid[:n])
    flips = st.lists(st.tuples(st.integers(0, max(len(valid) - 1, 0)), st.integers(1, 255)), min_size=1, max_size=4)
    flipped = flips.map(lambda changes: _flip(valid, changes))
    encodings = st.sampled_from(["utf-16", "latin-1", "cp1252", "utf-32"]).map(
        lambda enc: valid.decode("utf-8").replace("a", "ä").encode(enc, errors="replace"))
    junk = st.binary(max_size=200)
    return st.one_of(truncate, flipped, encodings, junk) if text else st.one_of(truncate, flipped, junk)


def _flip(data: bytes, changes) -> bytes:
    out = bytearray(data)
    for index, mask in changes:
        out[index] ^= mask
    return bytes(out)


def shapes():
    """JSON values of the wrong shape for a file that expects an object of objects."""
    leaf = st.one_of(st.none(), st.booleans(), st.integers(-10**12, 10**12), st.floats(allow_nan=True),
                     st.text(max_size=8))
    return st.recursive(leaf, lambda inner: st.one_of(st.lists(inner, max_size=3),
                                                     st.dictionaries(st.text(max_size=6), inner, max_size=3)),
                        max_leaves=8)


def accepted_or_one_line(case: Case, root: Path) -> None:
    before = snapshot(root)
    ended = run_in_process(case)
    after = snapshot(root)
    if ended.status == 0 and ended.escaped is None:
        changed = [p for p, digest in before.items() if after.get(p) != digest]
        assert not changed or case.status == 0, explain(case, ended, before, after)
        return
    refused = dataclasses.replace(case, status=2)
    assert classify(refused, ended, before, after) == "one line", explain(refused, ended, before, after)


def fresh(base: Path, name: str) -> Path:
    root = base / name
    if root.exists():
        shutil.rmtree(root)
    root.mkdir()
    return root


VALID_CONFIG = b'model = "scripted"\nscenarios = ["P.1"]\nseeds = 1\n[model_options]\nalpha = 0.5\n'


@FUZZ
@given(body=mutated(VALID_CONFIG))
def test_configuration_toml(body, base):
    root = fresh(base, "config")
    (root / "c.toml").write_bytes(body)
    # --seeds 0 is refused after the configuration is read, so a configuration that survives never runs
    accepted_or_one_line(Case("config", ["run", "--config", str(root / "c.toml"), "--seeds", "0",
                                         "--out", str(root / "o")]), root)


def _scenario_bytes(suffix: str) -> bytes:
    from vladrivebench._scenarios.spec import resolve_scenarios

    data = resolve_scenarios("P.1")[0].to_json()
    data["id"] = "X.fuzz"
    if suffix == ".json":
        return json.dumps(data).encode()
    return _toml(data).encode()


def _toml(data: dict, prefix: str = "") -> str:
    scalars, tables, arrays = [], [], []
    for key, value in data.items():
        if isinstance(value, dict):
            tables.append((key, value))
        elif isinstance(value, list) and value and isinstance(value[0], dict):
            arrays.append((key, value))
        elif value is not None:
            scalars.append(f"{key} = {json.dumps(value)}")
    text = "\n".join(scalars) + "\n"
    for key, value in tables:
        text += f"[{prefix}{key}]\n" + _toml(value, f"{prefix}{key}.")
    for key, items in arrays:
        for item in items:
            text += f"[[{prefix}{key}]]\n" + _toml(item, f"{prefix}{key}.")
    return text


@pytest.mark.parametrize("suffix", [".toml", ".json"])
def test_scenario_template_is_valid(suffix, base):
    root = fresh(base, f"scenario-valid{suffix}")
    (root / f"s{suffix}").write_bytes(_scenario_bytes(suffix))
    ended = run_in_process(Case("scenario", ["scenarios", str(root / f"s{suffix}")]))
    assert ended.status == 0, ended.stderr


@FUZZ
@given(data=st.data(), suffix=st.sampled_from([".toml", ".json"]))
def test_scenario_files(data, suffix, base):
    body = data.draw(mutated(_scenario_bytes(suffix)))
    root = fresh(base, "scenario")
    (root / f"s{suffix}").write_bytes(body)
    accepted_or_one_line(Case("scenario", ["scenarios", str(root / f"s{suffix}")]), root)


@FUZZ
@given(value=shapes())
def test_scenario_json_shapes(value, base):
    root = fresh(base, "scenario-shape")
    (root / "s.json").write_text(json.dumps(value))
    accepted_or_one_line(Case("scenario", ["scenarios", str(root / "s.json")]), root)


VALID_CONDITIONS = (b'[conditions.cyclist]\nintent = "brake"\n'
                    b'sentence = "Stop for the cyclist in the lane because it is blocking the lane."\n')


@FUZZ
@given(body=mutated(VALID_CONDITIONS), suffix=st.sampled_from([".toml", ".json"]))
def test_condition_files(body, suffix, base):
    root = fresh(base, "conditions")
    (root / f"k{suffix}").write_bytes(body)
    accepted_or_one_line(Case("conditions", ["conditions", "--condition-file", str(root / f"k{suffix}")]), root)


VALID_JSONL = (b'{"id": "a", "text": "Stop for the pedestrian in the lane."}\n'
               b'{"id": "b", "slots": {"scene": "Clear road.", "decision": "Keep going."}}\n')


@FUZZ
@given(body=mutated(VALID_JSONL))
def test_label_jsonl(body, base):
    root = fresh(base, "jsonl")
    (root / "t.jsonl").write_bytes(body)
    accepted_or_one_line(Case("labels", ["label", "--texts", str(root / "t.jsonl"), "--out", str(root / "o.jsonl"),
                                         "--quiet"], status=0), root)


@FUZZ
@given(value=shapes())
def test_label_jsonl_shapes(value, base):
    root = fresh(base, "jsonl-shape")
    (root / "t.jsonl").write_text(json.dumps(value) + "\n")
    accepted_or_one_line(Case("labels", ["label", "--texts", str(root / "t.jsonl"), "--out", str(root / "o.jsonl"),
                                         "--quiet"], status=0), root)


def _run_copy(base: Path, name: str) -> tuple[Path, Path]:
    root = fresh(base, name)
    run = root / "run"
    shutil.copytree(complete_run(base), run)
    return root, run


RUN_ARGS = ["run", "--model", "scripted", "--scenarios", "P.1", "--seeds", "1", "--quiet",
            "--sim-opt", "render=false"]


@settings(FUZZ, max_examples=10)
@given(data=st.data())
def test_run_manifest(data, base):
    root, run = _run_copy(base, "manifest")
    manifest = run / "run.json"
    kind = data.draw(st.sampled_from(["bytes", "shape"]))
    if kind == "bytes":
        manifest.write_bytes(data.draw(mutated(manifest.read_bytes())))
    else:
        manifest.write_text(json.dumps(data.draw(shapes())))
    accepted_or_one_line(Case("manifest", [*RUN_ARGS, "--out", str(run)]), root)


@settings(FUZZ, max_examples=15)
@given(data=st.data())
def test_episode_logs_strict(data, base):
    root, run = _run_copy(base, "logs")
    log = sorted((run / "episodes").glob("*.mcap"))[0]
    log.write_bytes(data.draw(mutated(log.read_bytes(), text=False)))
    accepted_or_one_line(Case("logs", ["metrics", str(run), "--strict", "--json"]), root)


@settings(FUZZ, max_examples=3)
@given(data=st.data())
def test_resumed_sweep_redoes_a_damaged_log(data, base):
    """A log damaged anywhere (its result record included) is never counted complete: the resumed sweep
    runs the episode again and, being deterministic, writes the original bytes."""
    root, run = _run_copy(base, "resume")
    log = sorted((run / "episodes").glob("*.mcap"))[0]
    original = log.read_bytes()
    damaged = data.draw(mutated(original, text=False).filter(lambda b: b != original))
    log.write_bytes(damaged)
    ended = run_in_process(Case("resume", [*RUN_ARGS, "--out", str(run)], status=0))
    assert ended.status == 0 and ended.escaped is None, ended.stderr
    assert log.read_bytes() == original
