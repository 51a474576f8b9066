"""`vdb intervene --workers N`: an intervention's shares (lockstep chunks, or single episodes) run on the
process executor's workers and log the same bytes as one process; on the real plugins (spawned workers
discover them from their entry points), with routes cut to a couple of seconds."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from vladrivebench._engine.executors import PipelinedExecutor, ProcessExecutor, SequentialExecutor
from vladrivebench._engine.registry import get_registry
from vladrivebench._engine.sweep import ComponentSpec
from vladrivebench._intervention.runs import InterventionConfig, InterventionRun
from vladrivebench._scenarios.spec import resolve_scenarios


def config(model: str, controller: str, batch: int, seeds: int) -> InterventionConfig:
    registry = get_registry()
    route = dataclasses.replace(resolve_scenarios(["E.1"], registry)[0], max_time_s=1.5)
    return InterventionConfig(mode="closed-loop", model=ComponentSpec("model", model, {}),
                              simulator=ComponentSpec("simulator", "kinematic", {}),
                              controller=ComponentSpec("controller", controller, {}), routes=(route,),
                              conditions=("selfsplice", "accel"), seeds=tuple(range(seeds)), checkpoints=(0.5, 1.0),
                              batch=batch)


def logs(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((out / "episodes").glob("*.mcap"))}


@pytest.mark.parametrize("model, controller, batch, executor",
                         [("scripted", "pid", 1, ProcessExecutor), ("kv", "mpc", 2, ProcessExecutor),
                          ("scripted", "pid", 1, PipelinedExecutor), ("kv", "mpc", 2, PipelinedExecutor)],
                         ids=["scripted-episodes", "kv-lockstep-chunks", "scripted-pipelined", "kv-pipelined"])
def test_workers_log_the_same_bytes_as_one_process(tmp_path, model, controller, batch, executor):
    # kv at --batch 2: 3 seeds × (baseline, selfsplice, accel) = 9 episodes in chunks of 8 → two jobs; the
    # pipelined executor runs them on two threads here, the model (its splices and gate) on its server
    run = config(model, controller, batch, seeds=3)
    one = InterventionRun(run, tmp_path / "one", registry=get_registry(), executor=SequentialExecutor()).run()
    many = InterventionRun(run, tmp_path / "many", registry=get_registry(), executor=executor(workers=2)).run()
    assert len(logs(tmp_path / "one")) == 9
    assert logs(tmp_path / "one") == logs(tmp_path / "many")
    assert (tmp_path / "one" / "intervention.json").read_bytes() == (tmp_path / "many" / "intervention.json").read_bytes()
    assert one["gate"] == many["gate"]


def test_a_resumed_run_on_workers_runs_only_what_is_missing(tmp_path):
    run = config("scripted", "pid", 1, seeds=2)
    InterventionRun(run, tmp_path / "out", registry=get_registry(), executor=ProcessExecutor(workers=2)).run()
    before = logs(tmp_path / "out")
    victim = sorted(before)[1]
    (tmp_path / "out" / "episodes" / victim).unlink()
    stamps = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "out" / "episodes").glob("*.mcap")}
    InterventionRun(run, tmp_path / "out", registry=get_registry(), executor=ProcessExecutor(workers=2)).run()
    assert logs(tmp_path / "out") == before
    assert all((tmp_path / "out" / "episodes" / name).stat().st_mtime_ns == ns for name, ns in stamps.items())
