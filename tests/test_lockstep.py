"""Lockstep batches (`vdb run --batch B`): B episodes advance together through one model instance."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
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
from vladrivebench.errors import ConfigError

REGISTRY = Registry([("fakes", fakes)], entry_points=False)


def config(model="echo-batched", seeds=2, batch=1, scenarios=fakes.SCENARIOS) -> RunConfig:
    return RunConfig(ComponentSpec("model", model), ComponentSpec("simulator", "line"),
                     ComponentSpec("controller", "speed"), tuple(scenarios), tuple(range(seeds)), batch=batch)


def sweep_into(out, cfg, executor=None):
    return run_sweep(cfg, out, executor=executor or SequentialExecutor(), registry=REGISTRY)


def snapshot(directory: Path) -> dict[str, bytes]:
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


def steps_of(out: Path) -> dict[str, list]:
    """Every episode's logged steps (what the model said and did), without the configuration record."""
    return {p.name: [(s.step, s.cot["text"], s.trajectory["xy"], s.control) for s in read_episode(p).steps]
            for p in sorted((out / "episodes").glob("*.mcap"))}


def test_batch_one_is_the_unbatched_run_byte_for_byte(tmp_path):
    assert config(batch=1).to_json() == replace(config(), batch=1).to_json()
    assert "batch" not in config(batch=1).to_json() and config(batch=3).to_json()["batch"] == 3
    sweep_into(tmp_path / "a", config(batch=1))
    sweep_into(tmp_path / "b", RunConfig(*[getattr(config(), f) for f in ("model", "simulator", "controller",
                                                                            "scenarios", "seeds")]))
    assert snapshot(tmp_path / "a") == snapshot(tmp_path / "b")


@pytest.mark.parametrize("model", ["echo-batched", "echo"])
def test_batched_episodes_equal_the_unbatched_ones_and_repeat_byte_for_byte(tmp_path, model):
    sweep_into(tmp_path / "one", config(model, batch=1))
    first = sweep_into(tmp_path / "b3", config(model, batch=3))
    sweep_into(tmp_path / "again", config(model, batch=3))
    assert len(first.results) == 6 and not first.failures
    assert steps_of(tmp_path / "b3") == steps_of(tmp_path / "one")  # the fakes are exact: no rounding
    assert snapshot(tmp_path / "b3" / "episodes") == snapshot(tmp_path / "again" / "episodes")
    manifest = json.loads((tmp_path / "b3" / "run.json").read_text())
    assert manifest["config"]["batch"] == 3
    assert read_episode(next((tmp_path / "b3" / "episodes").glob("*.mcap"))).meta["config"]["batch"] == 3


def lockstep_schedule(lengths: list[int], batch: int) -> list[int]:
    """The batch size at every step when episodes of ``lengths`` join in order as lanes free up."""
    queue, lanes, sizes = list(lengths), [], []
    while queue or lanes:
        while len(lanes) < batch and queue:
            lanes.append(queue.pop(0))
        sizes.append(len(lanes))
        lanes = [left - 1 for left in lanes if left > 1]
    return sizes


@pytest.mark.parametrize("batch", [2, 4])
def test_episodes_that_end_leave_the_batch_and_the_next_ones_join(tmp_path, batch):
    fakes.BatchedEchoModel.BATCH_SIZES.clear()
    summary = sweep_into(tmp_path / "out", config(batch=batch))
    lengths = [summary.results[job.episode_id]["steps"] for job in summary.jobs]  # in job order
    assert len(set(lengths)) > 1  # scenarios of different lengths
    sizes = fakes.BatchedEchoModel.BATCH_SIZES
    assert sizes == lockstep_schedule(lengths, batch)
    assert max(sizes) == batch and len(sizes) < sum(lengths)
    assert min(sizes) < batch or batch == 2  # at B=2 the last two (same length) end together


def test_a_process_pool_gives_the_bytes_of_a_sequential_batched_run(tmp_path):
    sweep_into(tmp_path / "seq", config(batch=2, seeds=3))
    sweep_into(tmp_path / "pool", config(batch=2, seeds=3), executor=ProcessExecutor(workers=2))
    assert snapshot(tmp_path / "seq" / "episodes") == snapshot(tmp_path / "pool" / "episodes")


def test_resume_redoes_missing_episodes_with_the_same_batch_mates(tmp_path, monkeypatch):
    monkeypatch.setattr(sweep, "BATCH_JOB_FACTOR", 1)  # batches of exactly B episodes: many batch jobs
    reference = tmp_path / "reference"
    sweep_into(reference, config(batch=2, seeds=3))
    out = tmp_path / "out"
    sweep_into(out, config(batch=2, seeds=3))
    logs = sorted((out / "episodes").glob("*.mcap"))
    logs[1].unlink()  # a killed sweep: one episode of a batch missing, one truncated
    logs[4].write_bytes(logs[4].read_bytes()[:100])
    summary = sweep_into(out, config(batch=2, seeds=3))
    assert summary.ran == 2 and summary.total == 9
    assert snapshot(out / "episodes") == snapshot(reference / "episodes")


def test_a_failing_episode_leaves_the_batch_and_the_others_finish(tmp_path):
    cfg = RunConfig(ComponentSpec("model", "echo", {"fail_at": [1, 4]}), ComponentSpec("simulator", "line"),
                    ComponentSpec("controller", "speed"), fakes.SCENARIOS[:2], (0, 1), batch=2)
    summary = sweep_into(tmp_path / "out", cfg)
    assert len(summary.failures) == 2 and len(summary.results) == 2  # seed 1 fails in both scenarios
    assert all(f["step"] == 4 and "CUDA out of memory" in f["error"] for f in summary.failures.values())


@pytest.mark.parametrize("value", [0, -1, "x", "", True, 2.5])
def test_bad_batch_sizes_are_one_line_config_errors(value):
    with pytest.raises(ConfigError, match="--batch must be a whole number"):
        sweep.batch_size(value)


def fake_vdb(*args: object) -> list[str]:
    return [sys.executable, str(Path(fakes.__file__)), *[str(a) for a in args]]


BASE = ("run", "--model", "echo-batched", "--sim", "line", "--controller", "speed", "--scenarios", "road,car,long",
        "--seeds", 2, "--quiet")


@pytest.mark.parametrize("value", ["0", "-1", "x"])
def test_bad_batch_on_the_command_line_is_one_line_and_exit_2(tmp_path, value):
    done = subprocess.run(fake_vdb(*BASE, "--batch", value, "--out", tmp_path / "out"), capture_output=True,
                          text=True)
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("vdb: error: --batch must be a whole number")
    assert not (tmp_path / "out").exists()


def test_a_model_without_batched_forms_is_said_once_on_stderr_and_runs_as_before(tmp_path):
    command = ("run", "--sim", "line", "--controller", "speed", "--scenarios", "road,car,long", "--seeds", 2, "--quiet",
               "--json", "--batch", 2)
    plain = subprocess.run(fake_vdb(*command, "--model", "echo", "--out", tmp_path / "plain"), capture_output=True,
                           text=True)
    assert plain.returncode == 0, plain.stderr
    assert plain.stderr == "note: model 'echo' has no batched forms; its episodes run one at a time\n"
    summary = json.loads(plain.stdout)  # stdout is the summary alone
    assert summary["complete"] == 6 and summary["ran"] == 6
    sweep_into(tmp_path / "direct", config("echo", batch=2))
    assert snapshot(tmp_path / "plain" / "episodes") == snapshot(tmp_path / "direct" / "episodes")

    batched = subprocess.run(fake_vdb(*command, "--model", "echo-batched", "--out", tmp_path / "batched"),
                             capture_output=True, text=True)
    assert batched.returncode == 0 and batched.stderr == ""  # a batched model: nothing to say


def test_killed_batched_run_resumes_to_the_same_bytes(tmp_path):
    slow = ("--batch", 2, "--model-opt", "sleep=0.003")
    reference = tmp_path / "reference"
    subprocess.run(fake_vdb(*BASE, *slow, "--out", reference), check=True, capture_output=True)
    expected = snapshot(reference / "episodes")
    out = tmp_path / "killed"
    command = fake_vdb(*BASE, *slow, "--out", out)
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 30
    while len(list(out.glob("episodes/*.mcap"))) < 2 and time.monotonic() < deadline:
        time.sleep(0.005)
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    killed_with = len(list(out.glob("episodes/*.mcap")))
    resumed = subprocess.run(command, capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr
    assert snapshot(out / "episodes") == expected
    assert killed_with < len(expected)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(1, 6), min_size=1, max_size=7), st.integers(1, 4))
def test_lockstep_runs_every_episode_once_as_it_would_run_alone(lengths, batch):
    from vladrivebench._engine.runner import LockstepEpisode, run_episode, run_lockstep

    scenarios = [fakes.FakeScenario(f"r{i}", length=1000.0, max_time_s=n * fakes.DT) for i, n in enumerate(lengths)]
    model = fakes.BatchedEchoModel()
    fakes.BatchedEchoModel.BATCH_SIZES.clear()
    finished = []
    episodes = [LockstepEpisode(i, s, i % 2) for i, s in enumerate(scenarios)]
    run_lockstep(episodes, batch, make_lane=lambda i: (model, fakes.LineSimulator(), fakes.SpeedController()),
                 done=lambda episode, result, writer: finished.append((episode.key, result)))
    assert sorted(key for key, _ in finished) == list(range(len(lengths)))
    alone = {i: run_episode(fakes.EchoModel(), fakes.LineSimulator(), fakes.SpeedController(), s, i % 2)
             for i, s in enumerate(scenarios)}
    assert all(result == alone[key] for key, result in finished)
    steps = [alone[i].steps for i in range(len(lengths))]
    assert fakes.BatchedEchoModel.BATCH_SIZES == lockstep_schedule(steps, batch)
