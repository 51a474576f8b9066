"""The Ray executor on a local Ray instance (started once for the module): every job once, failures and
dead actors isolated, one model per actor, and sweeps byte-identical to the sequential executor."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest
from vdb_executor_ray import plugin
from vdb_executor_ray.executor import RayExecutor
from vladrivebench import ConfigError
from vladrivebench.executors import JobFailure, SequentialExecutor
from vladrivebench.testing import (
    ComponentSpec,
    Registry,
    RegistrySpec,
    RunConfig,
    core_plugin,
    make_jobs,
    run_sweep,
)

CORE_TESTS = Path(__file__).resolve().parents[3] / "tests"  # the core's fake components (runner_fakes.py)


def load_fakes():
    if str(CORE_TESTS) not in sys.path:
        sys.path.insert(0, str(CORE_TESTS))
    return importlib.import_module("runner_fakes")


fakes = load_fakes()


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray instance for the module (starting Ray takes seconds); executors reuse it."""
    import ray

    started = RayExecutor(workers=2)._connect(ray)
    yield ray
    if started:
        ray.shutdown()


def split(results):
    ok = {r[0]: r[1] for r in results if not isinstance(r, JobFailure)}
    return ok, {r.job: r for r in results if isinstance(r, JobFailure)}


def test_every_job_once_and_raising_jobs_isolated(local_ray):
    ok, failed = split(list(RayExecutor(workers=2).run(fakes.square_but_three_raises, range(7))))
    assert ok == {i: i * i for i in range(7) if i != 3}
    assert failed[3].error == "ValueError: three is unlucky"


def test_a_dying_actor_fails_only_its_job_and_is_replaced(local_ray):
    ok, failed = split(list(RayExecutor(workers=2).run(fakes.square_but_three_dies, range(6))))
    assert set(ok) == {0, 1, 2, 4, 5}
    assert failed[3].error.startswith("ray worker died while running this job")


def test_each_actor_builds_its_model_once(local_ray, tmp_path):
    registry = Registry([("fakes", fakes)], entry_points=False)
    config = RunConfig(ComponentSpec("model", "echo"), ComponentSpec("simulator", "line"),
                       ComponentSpec("controller", "speed"), fakes.SCENARIOS[:1], tuple(range(6)))
    identities = list(RayExecutor(workers=2).run(fakes.component_identity,
                                                 make_jobs(config, tmp_path, {}, RegistrySpec.of(registry))))
    models: dict[int, set[int]] = {}
    for pid, model_id in identities:
        models.setdefault(pid, set()).add(model_id)
    assert len(identities) == 6 and 1 <= len(models) <= 2
    assert all(len(ids) == 1 for ids in models.values())


def test_sweep_on_ray_gives_the_same_bytes_as_sequential(local_ray, tmp_path):
    registry = Registry([core_plugin(), ("fakes", fakes), ("ray", plugin)], entry_points=False)
    config = RunConfig(ComponentSpec("model", "echo"), ComponentSpec("simulator", "line"),
                       ComponentSpec("controller", "speed"), fakes.SCENARIOS, (0, 1))
    run_sweep(config, tmp_path / "seq", executor=SequentialExecutor(), registry=registry)
    executor = registry.create("executor", "ray", {"workers": 2})
    summary = run_sweep(config, tmp_path / "ray", executor=executor, registry=registry)
    assert summary.ran == 6 and not summary.failures

    def files(directory):
        return {p.name: p.read_bytes() for p in sorted((directory / "episodes").iterdir())}

    assert files(tmp_path / "seq") == files(tmp_path / "ray")


def test_no_jobs_needs_no_ray():
    assert list(RayExecutor(workers=2).run(fakes.square, [])) == []


@pytest.mark.parametrize(("options", "message"), [
    ({"workers": 0}, "workers must be a whole number ≥ 1"),
    ({"address": ""}, "address must be a non-empty string"),
    ({"num_cpus_per_worker": 0}, "num_cpus_per_worker must be a number > 0"),
])
def test_bad_options_are_one_line_errors(options, message):
    with pytest.raises(ConfigError, match=message):
        plugin.make_executor(**options)


def test_registration_does_not_import_ray():
    code = ("import sys; from vladrivebench._engine.registry import Registry; from vdb_executor_ray import plugin; "
            "r = Registry([('ray', plugin)], entry_points=False); print(r.names('executor'), 'ray' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "['ray'] False"


@pytest.mark.parametrize("model", ["echo-batched", "echo"])
def test_batched_sweep_on_ray_gives_the_same_bytes_as_sequential(local_ray, tmp_path, model):
    registry = Registry([core_plugin(), ("fakes", fakes), ("ray", plugin)], entry_points=False)
    config = RunConfig(ComponentSpec("model", model), ComponentSpec("simulator", "line"),
                       ComponentSpec("controller", "speed"), fakes.SCENARIOS, (0, 1), batch=2)
    run_sweep(config, tmp_path / "seq", executor=SequentialExecutor(), registry=registry)
    executor = registry.create("executor", "ray", {"workers": 2})
    summary = run_sweep(config, tmp_path / "ray", executor=executor, registry=registry)
    assert summary.ran == 6 and not summary.failures

    def files(directory):
        return {p.name: p.read_bytes() for p in sorted((directory / "episodes").iterdir())}

    assert files(tmp_path / "seq") == files(tmp_path / "ray")
