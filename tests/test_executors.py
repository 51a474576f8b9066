"""Executors: every job comes back once, failures are isolated, worker processes reuse their components."""

from __future__ import annotations

import os

import pytest
import runner_fakes as fakes
from vladrivebench._engine.executors import JobFailure, ProcessExecutor, SequentialExecutor
from vladrivebench._engine.registry import Registry
from vladrivebench._engine.sweep import ComponentSpec, RegistrySpec, RunConfig, make_jobs
from vladrivebench.errors import ConfigError


def results_by_job(results):
    ok = {r[0]: r[1] for r in results if not isinstance(r, JobFailure)}
    failed = {r.job: r for r in results if isinstance(r, JobFailure)}
    return ok, failed


@pytest.mark.parametrize("executor", [SequentialExecutor(), ProcessExecutor(workers=2)], ids=["sequential", "process"])
def test_every_job_once(executor):
    ok, failed = results_by_job(list(executor.run(fakes.square, range(7))))
    assert ok == {i: i * i for i in range(7)} and not failed


@pytest.mark.parametrize("executor", [SequentialExecutor(), ProcessExecutor(workers=2)], ids=["sequential", "process"])
def test_a_raising_worker_fails_only_its_job(executor):
    ok, failed = results_by_job(list(executor.run(fakes.square_but_three_raises, range(6))))
    assert set(ok) == {0, 1, 2, 4, 5}
    assert failed[3].error == "ValueError: three is unlucky" and "Traceback" in failed[3].details


def test_a_dying_worker_process_fails_only_its_job_and_is_replaced():
    ok, failed = results_by_job(list(ProcessExecutor(workers=2).run(fakes.square_but_three_dies, range(8))))
    assert set(ok) == {0, 1, 2, 4, 5, 6, 7}
    assert failed[3].error == "worker process exited with status 7 while running this job"


def test_every_job_comes_back_once_however_many_workers_die():
    results = list(ProcessExecutor(workers=2).run(fakes.square_but_odd_die, range(16)))
    ok, failed = results_by_job(results)
    assert len(results) == 16
    assert ok == {i: i * i for i in range(0, 16, 2)} and sorted(failed) == list(range(1, 16, 2))


def test_a_worker_dying_between_jobs_loses_nothing():
    results = list(ProcessExecutor(workers=1).run(fakes.square_then_die_soon, range(8)))
    ok, failed = results_by_job(results)
    assert len(results) == 8 and ok[2] == 4
    assert set(ok) | set(failed) == set(range(8)) and set(failed) <= {3}  # job 3 may have been running


def test_no_jobs_no_processes():
    assert list(ProcessExecutor(workers=3).run(fakes.square, [])) == []


def test_workers_leave_no_processes_behind():
    import multiprocessing

    list(ProcessExecutor(workers=2).run(fakes.square, range(4)))
    assert multiprocessing.active_children() == []


def test_abandoning_the_results_stops_the_workers():
    import multiprocessing

    stream = ProcessExecutor(workers=2).run(fakes.square, range(50))
    next(stream)
    stream.close()
    assert multiprocessing.active_children() == []


@pytest.mark.parametrize("workers", [0, -1, 1.5, "2", True])
def test_bad_worker_counts_are_one_line_errors(workers):
    with pytest.raises(ConfigError, match="workers must be a whole number"):
        ProcessExecutor(workers=workers)
    with pytest.raises(ConfigError, match="workers must be a whole number"):
        SequentialExecutor(workers=workers)


def test_unknown_start_method():
    with pytest.raises(ConfigError, match="start_method 'telepathy' is not available"):
        ProcessExecutor(start_method="telepathy")


def test_each_worker_process_builds_its_model_once(tmp_path):
    registry = Registry([("fakes", fakes)], entry_points=False)
    config = RunConfig(ComponentSpec("model", "echo"), ComponentSpec("simulator", "line"),
                       ComponentSpec("controller", "speed"), (fakes.SCENARIOS[0],), tuple(range(8)))
    jobs = make_jobs(config, tmp_path, {}, RegistrySpec.of(registry))
    identities = list(ProcessExecutor(workers=2).run(fakes.component_identity, jobs))
    by_pid: dict[int, set[int]] = {}
    for pid, model_id in identities:
        by_pid.setdefault(pid, set()).add(model_id)
    assert len(identities) == 8 and os.getpid() not in by_pid
    assert all(len(models) == 1 for models in by_pid.values())


def test_registry_spec_rebuilds_local_plugins():
    registry = Registry([("fakes", fakes)], entry_points=False)
    spec = RegistrySpec.of(registry)
    assert spec == RegistrySpec(False, (), (("fakes", "runner_fakes"),))
    rebuilt = spec.build()
    assert rebuilt.names("model") == ["echo", "echo-batched"] and rebuilt.names("simulator") == ["exploding", "line"]
