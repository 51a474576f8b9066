"""The ``pipelined`` executor: batch jobs on threads of the driver, their models in a model-server process.

What must hold: the logs are the bytes of a sequential run (kv, the fakes, batched or not, with failures);
a remote model answers protocol checks and advances the caller's RNGs as the model itself would; a model
that raises fails its episodes with the model's own error, a server that dies fails the jobs it held rather
than hanging, and bad options are one line.
"""

from __future__ import annotations

import dataclasses
import os
import signal

import numpy as np
import pytest
import runner_fakes as fakes
from hypothesis import given, settings
from hypothesis import strategies as st
from vladrivebench._engine import sweep
from vladrivebench._engine.executors import PipelinedExecutor, SequentialExecutor
from vladrivebench._engine.model_server import ModelServer, RemoteModel, StateHandle
from vladrivebench._engine.registry import Registry
from vladrivebench._engine.sweep import ComponentSpec, RegistrySpec, RunConfig, run_sweep
from vladrivebench.errors import ConfigError
from vladrivebench.protocols import BatchedModel, CoTExtras, VLAModel
from vladrivebench.records import CoT

FAKES = Registry([("fakes", fakes)], entry_points=False)


def snapshot(directory):
    return {p.name: p.read_bytes() for p in sorted(directory.glob("*.mcap"))}


def fake_config(model="echo-batched", batch=2, seeds=4, options=None) -> RunConfig:
    return RunConfig(ComponentSpec("model", model, options or {}), ComponentSpec("simulator", "line"),
                     ComponentSpec("controller", "speed"), fakes.SCENARIOS, tuple(range(seeds)), batch=batch)


def both(tmp_path, config, registry=FAKES, workers=2):
    """The sweep run sequentially and pipelined: (sequential summary, pipelined summary)."""
    first = run_sweep(config, tmp_path / "seq", executor=SequentialExecutor(), registry=registry)
    executor = PipelinedExecutor(workers=workers)
    second = run_sweep(config, tmp_path / "pipe", executor=executor, registry=registry)
    return first, second, executor


@pytest.mark.parametrize(("model", "batch"), [("echo-batched", 2), ("echo-batched", 1), ("echo", 3)])
def test_pipelined_logs_are_the_bytes_of_a_sequential_run(tmp_path, monkeypatch, model, batch):
    monkeypatch.setattr(sweep, "BATCH_JOB_FACTOR", 1)  # several batch jobs, so both threads work
    first, second, executor = both(tmp_path, fake_config(model, batch))
    assert len(first.results) == 12 and not first.failures
    assert second.results == first.results and not second.failures
    assert snapshot(tmp_path / "pipe" / "episodes") == snapshot(tmp_path / "seq" / "episodes")
    assert executor.server_stats["model_seconds"] > 0
    assert executor.server_stats["last_call"] > executor.server_stats["first_call"] > 0


def test_kv_pipelined_sweep_is_byte_identical_to_the_sequential_one(tmp_path):
    from vladrivebench._engine.registry import get_registry
    from vladrivebench._scenarios.spec import load_suite

    registry = get_registry()
    suite = load_suite(registry)
    scenarios = tuple(dataclasses.replace(suite[name], max_time_s=0.6) for name in ("P.1", "TL.1-red"))
    config = RunConfig(ComponentSpec("model", "kv"), ComponentSpec("simulator", "kinematic"),
                       ComponentSpec("controller", "mpc"), scenarios, tuple(range(4)), batch=2)
    first, second, _ = both(tmp_path, config, registry)  # 8 episodes = 1 job of 4 × 2 at each of 2 …
    assert len(first.results) == 8 and second.results == first.results
    assert snapshot(tmp_path / "pipe" / "episodes") == snapshot(tmp_path / "seq" / "episodes")


def test_a_model_that_raises_fails_its_episodes_with_its_own_error(tmp_path, monkeypatch):
    monkeypatch.setattr(sweep, "BATCH_JOB_FACTOR", 1)
    config = fake_config("echo", batch=2, seeds=2, options={"fail_at": [1, 4]})
    first, second, _ = both(tmp_path, config)
    assert second.failures.keys() == first.failures.keys() and len(second.failures) == 3
    for entry in second.failures.values():
        assert entry["step"] == 4 and entry["component"] == "model"
        assert "RuntimeError: CUDA out of memory" in entry["error"]
        assert "decode_action" in entry["traceback"]  # the server's traceback is kept
    assert snapshot(tmp_path / "pipe" / "episodes") == snapshot(tmp_path / "seq" / "episodes")


def test_a_model_that_cannot_be_built_is_one_line(tmp_path):
    config = fake_config("echo", options={"cruise": -1.0})
    with pytest.raises(ConfigError, match="cruise must be ≥ 0"):
        run_sweep(config, tmp_path / "out", executor=PipelinedExecutor(), registry=FAKES)


@pytest.fixture
def server():
    serving = ModelServer(1)
    yield serving
    serving.stop()


def kv_observation():
    from vladrivebench._engine.registry import get_registry
    from vladrivebench._scenarios.spec import load_suite

    registry = get_registry()
    simulator = registry.create("simulator", "kinematic")
    return registry, simulator.reset(load_suite(registry)["P.1"], 0)


def test_a_remote_kv_is_the_kv_model_call_for_call(server):
    registry, obs = kv_observation()
    local = registry.create("model", "kv")
    remote = server.model(0, RegistrySpec.of(registry), ComponentSpec("model", "kv"))
    assert isinstance(remote, RemoteModel) and isinstance(remote, VLAModel) and isinstance(remote, BatchedModel)
    assert isinstance(remote, CoTExtras) == isinstance(local, CoTExtras)
    assert remote.cot_format == local.cot_format and remote.trajectory_spec == local.trajectory_spec
    local.reset(0)
    remote.reset(0)
    rngs = [np.random.default_rng(7), np.random.default_rng(7)]
    cot_local, cot_remote = local.generate_cot(obs, rngs[0]), remote.generate_cot(obs, rngs[1])
    assert cot_remote.text == cot_local.text and isinstance(cot_remote.state, StateHandle)
    assert rngs[0].bit_generator.state == rngs[1].bit_generator.state  # the caller's RNG advanced alike
    assert remote.state_digest(cot_remote) == local.state_digest(cot_local)
    action = [np.random.default_rng(3), np.random.default_rng(3)]
    a, b = local.decode_action(obs, cot_local, action[0]), remote.decode_action(obs, cot_remote, action[1])
    assert np.array_equal(a.xy, b.xy) and action[0].random() == action[1].random()
    splice = remote.splice_cot(obs, cot_remote.text, np.random.default_rng(1))  # selfsplice on the server
    assert remote.state_digest(splice) == remote.state_digest(cot_remote)


def test_an_error_on_the_server_is_raised_here_with_its_traceback(server):
    registry, obs = kv_observation()
    remote = server.model(0, RegistrySpec.of(registry), ComponentSpec("model", "kv"))
    with pytest.raises(AttributeError) as raised:
        remote.decode_action(obs, "not a CoT", np.random.default_rng(0))
    assert "Traceback" in str(raised.value.__cause__)


def test_a_dead_server_fails_calls_instead_of_hanging(server):
    registry, obs = kv_observation()
    remote = server.model(0, RegistrySpec.of(registry), ComponentSpec("model", "kv"))
    os.kill(server.process.pid, signal.SIGKILL)
    server.process.join(timeout=10)
    with pytest.raises((EOFError, OSError)):
        remote.generate_cot(obs, np.random.default_rng(0))


def test_a_server_killed_mid_sweep_fails_the_episodes_it_held(tmp_path, monkeypatch):
    monkeypatch.setattr(sweep, "BATCH_JOB_FACTOR", 1)
    original = ModelServer.model

    def model_then_die(self, pipe, registry_spec, component_spec):
        proxy = original(self, pipe, registry_spec, component_spec)
        os.kill(self.process.pid, signal.SIGKILL)
        self.process.join(timeout=10)
        return proxy

    monkeypatch.setattr(ModelServer, "model", model_then_die)
    summary = run_sweep(fake_config(), tmp_path / "out", executor=PipelinedExecutor(), registry=FAKES)
    assert not summary.results and len(summary.failures) == 12
    assert not list((tmp_path / "out" / "episodes").glob("*.mcap"))  # nothing half-written is left


@pytest.mark.parametrize("workers", [0, -1, True, 2.5])
def test_bad_workers_are_one_line(workers):
    with pytest.raises(ConfigError, match="workers must be a whole number"):
        PipelinedExecutor(workers=workers)


def test_an_unknown_start_method_is_one_line():
    with pytest.raises(ConfigError, match="start_method 'telepathy' is not available"):
        PipelinedExecutor(start_method="telepathy")


# -- the rules of the transport, as properties -----------------------------------------------------------
def nested(leaves):
    """Nested lists, tuples and dicts (string keys) of ``leaves``."""
    return st.recursive(leaves, lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.lists(inner, max_size=4).map(tuple),
        st.dictionaries(st.text(max_size=3), inner, max_size=3)), max_leaves=12)


def flatten(value):
    if isinstance(value, (list, tuple)):
        return [leaf for item in value for leaf in flatten(item)]
    if isinstance(value, dict):
        return [leaf for item in value.values() for leaf in flatten(item)]
    return [value]


GENERATOR_OR_NOT = st.one_of(st.integers(0, 2**32 - 1).map(np.random.default_rng), st.integers(), st.none(),
                             st.text(max_size=4))


@settings(max_examples=80, deadline=None)
@given(nested(GENERATOR_OR_NOT))
def test_the_generators_sent_back_are_every_generator_in_the_call_in_order(value):
    from vladrivebench._engine.model_server import _generators

    found = _generators(value)
    assert [id(g) for g in found] == [id(x) for x in flatten(value) if isinstance(x, np.random.Generator)]


COTS = st.builds(lambda text, n: CoT(text, state=("state", n)), st.text(max_size=5), st.integers())


@settings(max_examples=80, deadline=None)
@given(nested(st.one_of(COTS, st.integers(), st.none())))
def test_cot_states_stay_on_the_server_and_come_back_as_they_were(value):
    from vladrivebench._engine.model_server import _Hosted

    host = _Hosted(model=None)
    sent = host.outgoing(value)
    for leaf in flatten(sent):
        assert not isinstance(leaf, CoT) or isinstance(leaf.state, StateHandle)
    back = host.incoming(sent)
    originals, returned = flatten(value), flatten(back)
    assert len(originals) == len(returned)
    for a, b in zip(originals, returned, strict=True):
        if isinstance(a, CoT):
            assert b.text == a.text and b.state is a.state and b.spliced == a.spliced
        elif not isinstance(a, dict):
            assert b == a


def test_the_oldest_cot_states_are_dropped_past_the_limit(monkeypatch):
    from vladrivebench._engine import model_server

    monkeypatch.setattr(model_server, "HELD_STATES", 3)
    host = model_server._Hosted(model=None)
    sent = [host.outgoing(CoT(str(i), state=i)) for i in range(5)]
    assert [host.incoming(cot).state for cot in sent[2:]] == [2, 3, 4]
    with pytest.raises(model_server.RemoteCallError, match="no longer holds this CoT's state"):
        host.incoming(sent[1])


@pytest.fixture(scope="module")
def fake_server():
    serving = ModelServer(1)
    yield serving
    serving.stop()


@settings(max_examples=12, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 4))
def test_a_remote_call_advances_the_callers_rngs_as_a_local_call_does(fake_server, seed, lanes):
    registry_spec = RegistrySpec.of(FAKES)
    remote = fake_server.model(0, registry_spec, ComponentSpec("model", "echo-batched"))
    local = FAKES.create("model", "echo-batched")
    simulator = FAKES.create("simulator", "line")
    observations = [simulator.reset(fakes.SCENARIOS[i % 3], i) for i in range(lanes)]
    mine = [np.random.default_rng(seed + i) for i in range(lanes)]
    theirs = [np.random.default_rng(seed + i) for i in range(lanes)]
    cots = remote.generate_cot_batch(observations, mine)
    assert [c.text for c in cots] == [c.text for c in local.generate_cot_batch(observations, theirs)]
    assert [g.bit_generator.state for g in mine] == [g.bit_generator.state for g in theirs]
    assert [g.random() for g in mine] == [g.random() for g in theirs]
    remote.close()
