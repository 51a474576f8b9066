"""Sweeps into an output directory: manifest first, resume, refusal of another configuration, failure
isolation and retry, truncated logs redone, identical bytes across executors."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import pytest
import runner_fakes as fakes
from hypothesis import given, settings
from hypothesis import strategies as st
from vladrivebench._engine import sweep
from vladrivebench._engine.executors import ProcessExecutor, SequentialExecutor
from vladrivebench._engine.registry import Registry
from vladrivebench._engine.sweep import ComponentSpec, RunConfig, run_sweep
from vladrivebench._logs.episodes import read_episode
from vladrivebench.errors import ConfigError, UnknownNameError, VdbError

REGISTRY = Registry([("fakes", fakes)], entry_points=False)


def config(seeds=2, scenarios=fakes.SCENARIOS[:2], sim="line", **model_options) -> RunConfig:
    return RunConfig(ComponentSpec("model", "echo", model_options), ComponentSpec("simulator", sim),
                     ComponentSpec("controller", "speed"), tuple(scenarios), tuple(range(seeds)))


def sweep_into(out, cfg=None, executor=None, **kw):
    return run_sweep(cfg or config(), out, executor=executor or SequentialExecutor(), registry=REGISTRY, **kw)


def snapshot(directory: Path) -> dict[str, bytes]:
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


def test_new_sweep_writes_manifest_episodes_and_failures(tmp_path):
    summary = sweep_into(tmp_path / "out", executor_info={"name": "sequential", "workers": 1})
    out = tmp_path / "out"
    manifest = json.loads((out / "run.json").read_text())
    assert manifest["config"]["model"] == {"name": "echo", "options": {}}
    assert manifest["config"]["scenarios"] == ["road", "car"] and manifest["config"]["seeds"] == [0, 1]
    assert {"python", "vladrivebench", "numpy", "mcap"} <= set(manifest["versions"])
    assert manifest["executor"] == {"name": "sequential", "workers": 1}
    names = sorted(p.name for p in (out / "episodes").iterdir())
    assert names == ["echo__car__s0.mcap", "echo__car__s1.mcap", "echo__road__s0.mcap", "echo__road__s1.mcap"]
    assert json.loads((out / "failures.json").read_text()) == {"failures": []}
    assert summary.ran == 4 and summary.skipped == 0 and not summary.failures
    rows = {r["scenario"]: r for r in summary.per_scenario()}
    assert rows["road"]["episodes"] == 2 and rows["road"]["route_completion"] == 1.0
    assert rows["car"]["collisions"] == 0 and rows["car"]["route_completion"] < 1.0
    episode = read_episode(out / "episodes" / "echo__car__s1.mcap")
    assert episode.meta["config"] == manifest["config"] and episode.meta["versions"] == manifest["versions"]
    assert episode.meta["scenario"]["car_at"] == 30.0 and episode.seed == 1
    assert episode.meta["simulator"] == {"name": "line", "options": {}, "dt": 0.1,
                                         "effective_options": {"fail_reset_for": "", "height": 4, "width": 8}}
    assert episode.meta["model"]["cot_format"]["kind"] == "sentence"
    assert episode.result == summary.results["echo__car__s1"]


def test_resume_skips_complete_episodes_and_changes_nothing(tmp_path):
    sweep_into(tmp_path)
    before = snapshot(tmp_path / "episodes")
    again = sweep_into(tmp_path, executor_info={"name": "process", "workers": 2})
    assert again.ran == 0 and again.skipped == 4 and len(again.results) == 4
    assert snapshot(tmp_path / "episodes") == before


def test_different_configuration_is_refused_and_nothing_is_touched(tmp_path):
    sweep_into(tmp_path)
    before = snapshot(tmp_path)
    with pytest.raises(ConfigError) as info:
        sweep_into(tmp_path, config(cruise=4.0))
    message = str(info.value)
    assert "config.model.options.cruise: 4.0 now, absent before" in message and "\n" not in message
    with pytest.raises(ConfigError, match="config.seeds"):
        sweep_into(tmp_path, config(seeds=3))
    assert snapshot(tmp_path) == before


def test_edited_scenario_is_a_different_configuration(tmp_path):
    sweep_into(tmp_path, config(scenarios=[fakes.FakeScenario("road")]))
    with pytest.raises(ConfigError, match="config.scenario_digest"):
        sweep_into(tmp_path, config(scenarios=[fakes.FakeScenario("road", length=31.0)]))


def test_other_versions_are_refused(tmp_path, monkeypatch):
    sweep_into(tmp_path)
    real = sweep.collect_versions
    monkeypatch.setattr(sweep, "collect_versions", lambda *a: {**real(*a), "numpy": "0.0.1"})
    with pytest.raises(ConfigError, match=r"versions.numpy: \"0.0.1\" now"):
        sweep_into(tmp_path)


def test_directory_with_logs_but_no_manifest_is_refused(tmp_path):
    (tmp_path / "episodes").mkdir()
    (tmp_path / "episodes" / "x.mcap").write_bytes(b"")
    with pytest.raises(ConfigError, match="holds episode logs but no run.json"):
        sweep_into(tmp_path)


def test_unknown_components_and_options_are_refused_before_writing(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(UnknownNameError, match="unknown model 'ecco': did you mean 'echo'"):
        run_sweep(RunConfig(ComponentSpec("model", "ecco"), ComponentSpec("simulator", "line"),
                            ComponentSpec("controller", "speed"), fakes.SCENARIOS[:1], (0,)), out,
                  executor=SequentialExecutor(), registry=REGISTRY)
    with pytest.raises(ConfigError, match="model 'echo' does not take option 'temperature'"):
        sweep_into(out, config(temperature=0.3))
    assert not out.exists()


def test_truncated_and_partial_logs_are_redone(tmp_path):
    sweep_into(tmp_path)
    before = snapshot(tmp_path / "episodes")
    victim = tmp_path / "episodes" / "echo__road__s1.mcap"
    victim.write_bytes(victim.read_bytes()[:300])
    stale = tmp_path / "episodes" / "echo__car__s0.mcap.999999999.partial"
    stale.write_bytes(b"half an episode")
    again = sweep_into(tmp_path)
    assert again.ran == 1 and again.skipped == 3
    assert snapshot(tmp_path / "episodes") == before


def test_failing_episodes_are_recorded_and_the_sweep_goes_on(tmp_path):
    summary = sweep_into(tmp_path, config(fail_at=[1, 4], sim="line"))
    assert summary.ran == 4 and set(summary.failures) == {"echo__road__s1", "echo__car__s1"}
    assert len(summary.results) == 2
    failures = json.loads((tmp_path / "failures.json").read_text())["failures"]
    entry = failures[1]
    assert entry["episode_id"] == "echo__road__s1" and entry["scenario"] == "road" and entry["seed"] == 1
    assert entry["step"] == 4 and entry["component"] == "model"
    assert entry["error"] == ("model 'echo' step policy at step 4 of road seed 1 raised RuntimeError: "
                              "CUDA out of memory")
    assert "Traceback (most recent call last)" in entry["traceback"]
    assert not any(p.name.endswith(".partial") for p in (tmp_path / "episodes").iterdir())
    assert sorted(p.name for p in (tmp_path / "episodes").iterdir()) == ["echo__car__s0.mcap",
                                                                          "echo__road__s0.mcap"]
    rows = {r["scenario"]: r for r in summary.per_scenario()}
    assert rows["road"]["failed"] == 1 and rows["road"]["episodes"] == 1


def test_failed_episodes_stay_failed_on_resume_until_retried(tmp_path):
    flag = tmp_path / "flag"
    cfg = config(seeds=1, scenarios=fakes.SCENARIOS[:1], fail_once_file=str(flag))
    first = sweep_into(tmp_path / "out", cfg)
    assert set(first.failures) == {"echo__road__s0"} and "transient failure" in first.failures["echo__road__s0"]["error"]
    resumed = sweep_into(tmp_path / "out", cfg)
    assert resumed.ran == 0 and set(resumed.failures) == {"echo__road__s0"}
    retried = sweep_into(tmp_path / "out", cfg, retry_failed=True)
    assert retried.ran == 1 and not retried.failures and len(retried.results) == 1
    assert json.loads((tmp_path / "out" / "failures.json").read_text()) == {"failures": []}


def test_simulator_failure_is_isolated_too(tmp_path):
    summary = sweep_into(tmp_path, config(sim="exploding"))
    assert len(summary.failures) == 4
    assert all("simulator 'exploding' step at step 2" in f["error"] for f in summary.failures.values())


def test_configuration_mistake_found_while_building_stops_the_sweep(tmp_path):
    with pytest.raises(VdbError, match="cruise must be ≥ 0, got -1"):
        sweep_into(tmp_path, config(cruise=-1))
    assert not (tmp_path / "run.json").exists()  # checked before anything is written


def test_component_that_cannot_be_built_is_refused_before_writing(tmp_path):
    with pytest.raises(VdbError, match="cannot be built: RuntimeError: weights not found"):
        sweep_into(tmp_path, config(fail_on_build=True))
    assert not (tmp_path / "run.json").exists()


def test_process_pool_gives_the_same_bytes_as_sequential(tmp_path):
    cfg = config(seeds=3, scenarios=fakes.SCENARIOS)
    sweep_into(tmp_path / "seq", cfg)
    summary = sweep_into(tmp_path / "pool", cfg, executor=ProcessExecutor(workers=2))
    assert summary.ran == 9 and not summary.failures
    assert snapshot(tmp_path / "seq" / "episodes") == snapshot(tmp_path / "pool" / "episodes")


def test_process_pool_isolates_a_dying_worker(tmp_path):
    summary = sweep_into(tmp_path, config(seeds=3, die_at=[1, 2]), executor=ProcessExecutor(workers=2))
    assert set(summary.failures) == {"echo__road__s1", "echo__car__s1"}
    assert all("worker process exited with status 3" in f["error"] for f in summary.failures.values())
    assert len(summary.results) == 4


def test_seed_list_and_episode_ids():
    assert sweep.seed_list(3) == (0, 1, 2) and sweep.seed_list(2, 10) == (10, 11)
    for bad in (0, -2, 1.5, "3", True):
        with pytest.raises(ConfigError, match="--seeds must be a whole number from 1"):
            sweep.seed_list(bad)
    with pytest.raises(ConfigError, match="--seed-offset"):
        sweep.seed_list(2, -1)
    assert sweep.episode_id("org/model v2", "TL.1-red", 3) == "org-model-v2__TL.1-red__s3"


def test_partials_being_written_are_kept_and_abandoned_ones_removed(tmp_path):
    from vladrivebench._logs.episodes import EpisodeWriter

    (tmp_path / "episodes").mkdir(parents=True)
    abandoned = tmp_path / "episodes" / f"b.mcap.{os.getpid()}.partial"
    abandoned.write_bytes(b"x")
    with EpisodeWriter(tmp_path / "episodes" / "a.mcap", {"episode_id": "a"}) as writer:
        sweep._remove_stale_partials(tmp_path / "episodes")
        assert writer.partial_path.exists() and not abandoned.exists()


@settings(max_examples=80, deadline=None)
@given(st.text(min_size=1, max_size=20), st.text(min_size=1, max_size=20), st.integers(0, 10**6))
def test_episode_ids_are_safe_file_names(model, scenario_id, seed):
    eid = sweep.episode_id(model, scenario_id, seed)
    assert re.fullmatch(r"[A-Za-z0-9._-]+__[A-Za-z0-9._-]+__s\d+", eid) and "/" not in eid
    assert eid.endswith(f"__s{seed}")


keys = st.text("abc_", max_size=3)
json_values = st.recursive(st.none() | st.booleans() | st.integers(-5, 5) | st.text(max_size=3),
                           lambda inner: st.lists(inner, max_size=3) | st.dictionaries(keys, inner, max_size=3),
                           max_leaves=8)


@settings(max_examples=120, deadline=None)
@given(json_values, json_values)
def test_first_difference_is_none_only_for_equal_values(before, now):
    found = sweep.first_difference(before, now, "config")
    assert (found is None) == (before == now)
    if found is not None:
        path = found.split(":")[0].split(".")[1:]
        a, b = before, now
        for key in path:  # following the reported path leads to values that differ (or to a missing key)
            a = a.get(key, "<absent>") if isinstance(a, dict) else "<absent>"
            b = b.get(key, "<absent>") if isinstance(b, dict) else "<absent>"
        assert a != b


@settings(max_examples=40, deadline=None)
@given(st.lists(st.sampled_from(["ok", "failed", "missing"]), min_size=1, max_size=12),
       st.lists(st.floats(0, 1), min_size=12, max_size=12))
def test_per_scenario_counts_add_up(statuses, completions):
    jobs, results, failures = [], {}, {}
    for i, status in enumerate(statuses):
        scenario = fakes.SCENARIOS[i % 3]
        job = sweep.EpisodeJob(f"e{i}", "", scenario, i, config().model, config().simulator, config().controller, {}, {})
        jobs.append(job)
        if status == "ok":
            results[job.episode_id] = {"collisions": i % 2, "violations": 0, "route_completion": completions[i],
                                       "mean_speed": 1.0}
        elif status == "failed":
            failures[job.episode_id] = {"error": "x"}
    rows = sweep.SweepSummary(Path("."), jobs, results, failures).per_scenario()
    assert sum(r["episodes"] for r in rows) == statuses.count("ok")
    assert sum(r["failed"] for r in rows) == statuses.count("failed")
    assert sum(r["collisions"] for r in rows) == sum(i % 2 for i, s in enumerate(statuses) if s == "ok")
    for row in rows:
        assert row["route_completion"] is None or 0 <= row["route_completion"] <= 1
