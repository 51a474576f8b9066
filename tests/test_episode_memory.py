"""Per-episode memory in lockstep batches (EpisodeMemory): the runner names every episode on its observations
(``obs.episode``), tells such a model when each episode starts and ends instead of ``reset``, and one
instance then serves a batch with every episode seeing exactly the memory it would have alone."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import runner_fakes as fakes
from hypothesis import given, settings
from hypothesis import strategies as st
from vladrivebench import BatchedModel, EpisodeMemory
from vladrivebench._engine.runner import EpisodeFailure, LockstepEpisode, run_episode, run_lockstep
from vladrivebench.records import CoT
from vladrivebench.testing import check_batched_model


class CountingModel(fakes.EchoModel):
    """Echo whose CoT says how many distinct (scenario, step) pairs its episode has seen: memory that matters
    (seeing an observation again changes nothing)."""

    def __init__(self, **options):
        super().__init__(**options)
        self.seen: dict[str, set[tuple[str, int]]] = {}
        self.calls: list[tuple] = []

    def reset(self, seed):
        self.calls.append(("reset", seed))
        self.seen.clear()

    def start_episode(self, episode, seed):
        self.calls.append(("start", episode, seed))
        self.seen[episode] = set()

    def end_episode(self, episode):
        self.calls.append(("end", episode))
        self.seen.pop(episode, None)

    def generate_cot(self, obs, rng):
        steps = self.seen.setdefault(obs.episode, set())
        steps.add((obs.scenario_id, obs.step))
        return CoT(f"{super().generate_cot(obs, rng).text} after {len(steps)} steps")

    def decode_action(self, obs, cot, rng):
        self.seed = None
        return super().decode_action(obs, cot, rng)

    def generate_cot_batch(self, observations, rngs):
        return [self.generate_cot(o, r) for o, r in zip(observations, rngs, strict=True)]

    def decode_action_batch(self, observations, cots, rngs):
        return [self.decode_action(o, c, r) for o, c, r in zip(observations, cots, rngs, strict=True)]


class ForgetfulCountingModel(CountingModel):
    """The same memory shared by every episode: what a batch must not do."""

    def generate_cot(self, obs, rng):
        return super().generate_cot(dataclasses.replace(obs, episode=""), rng)


class Recorder:
    """An episode writer that keeps the steps' CoT texts and episode names."""

    def __init__(self):
        self.texts, self.names = [], []

    def write_step(self, obs, cot, trajectory, control, extras):
        self.texts.append(cot.text)
        self.names.append(obs.episode)


def scenarios(lengths):
    return [fakes.FakeScenario(f"r{i}", length=1000.0, max_time_s=n * fakes.DT) for i, n in enumerate(lengths)]


def lockstep_texts(model, lengths, batch):
    recorders = {}

    def opener(i):
        def open_writer():
            recorders[i] = Recorder()
            return recorders[i]
        return open_writer

    episodes = [LockstepEpisode(i, s, i % 3, opener(i)) for i, s in enumerate(scenarios(lengths))]
    run_lockstep(episodes, batch, make_lane=lambda i: (model, fakes.LineSimulator(), fakes.SpeedController()),
                 done=lambda episode, result, writer: None)
    return {i: r.texts for i, r in recorders.items()}, {i: r.names for i, r in recorders.items()}


def alone_texts(lengths):
    texts = {}
    for i, scenario in enumerate(scenarios(lengths)):
        recorder = Recorder()
        run_episode(CountingModel(), fakes.LineSimulator(), fakes.SpeedController(), scenario, i % 3, writer=recorder)
        texts[i] = recorder.texts
    return texts


def test_the_fake_declares_the_capabilities():
    assert isinstance(CountingModel(), BatchedModel) and isinstance(CountingModel(), EpisodeMemory)
    assert not isinstance(fakes.BatchedEchoModel(), EpisodeMemory)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(1, 6), min_size=1, max_size=7), st.integers(1, 4))
def test_one_instance_serves_the_batch_and_every_episode_keeps_its_own_memory(lengths, batch):
    texts, names = lockstep_texts(CountingModel(), lengths, batch)
    assert texts == alone_texts(lengths)
    for i, episode_names in names.items():
        assert set(episode_names) == {f"r{i} seed {i % 3}"}


def test_memory_shared_between_episodes_would_show():
    lengths = [4, 3, 5]
    texts, _ = lockstep_texts(ForgetfulCountingModel(), lengths, 3)
    assert texts != alone_texts(lengths)


def test_start_and_end_replace_reset_and_come_once_per_episode():
    model = CountingModel()
    lockstep_texts(model, [2, 1, 3], 2)
    assert not [c for c in model.calls if c[0] == "reset"]
    assert [c for c in model.calls if c[0] == "start"] == [("start", "r0 seed 0", 0), ("start", "r1 seed 1", 1),
                                                           ("start", "r2 seed 2", 2)]
    assert sorted(c for c in model.calls if c[0] == "end") == [("end", "r0 seed 0"), ("end", "r1 seed 1"),
                                                               ("end", "r2 seed 2")]
    assert model.seen == {}  # every episode's memory dropped


def test_a_model_without_the_capability_is_reset_as_before():
    model = fakes.BatchedEchoModel()
    calls = []
    model.reset = lambda seed: calls.append(seed)
    episodes = [LockstepEpisode(i, s, i) for i, s in enumerate(scenarios([2, 2]))]
    run_lockstep(episodes, 2, make_lane=lambda i: (model, fakes.LineSimulator(), fakes.SpeedController()),
                 done=lambda *args: None)
    assert calls == [0, 1]


def test_a_failing_episode_ends_its_memory_too():
    model = CountingModel(fail_at=[None, 1])
    failures = []
    episodes = [LockstepEpisode(i, s, i) for i, s in enumerate(scenarios([3, 3]))]
    run_lockstep(episodes, 2, make_lane=lambda i: (model, fakes.LineSimulator(), fakes.SpeedController()),
                 done=lambda episode, result, writer: failures.append(isinstance(result, EpisodeFailure)))
    assert failures == [True, True]  # one batched call serves both: a failing call fails the lanes it served
    assert model.seen == {} and len([c for c in model.calls if c[0] == "end"]) == 2


class EndRaises(CountingModel):
    def end_episode(self, episode):
        raise RuntimeError("cannot free the memory")


def test_a_model_that_fails_at_the_end_fails_the_episode_in_one_line():
    with pytest.raises(EpisodeFailure, match=r"^model 'model' end_episode of r0 seed 0 raised RuntimeError: "
                                             r"cannot free the memory$"):
        run_episode(EndRaises(), fakes.LineSimulator(), fakes.SpeedController(), scenarios([2])[0], 0)
    results = []
    run_lockstep([LockstepEpisode(0, scenarios([2])[0], 0)], 2,
                 make_lane=lambda i: (EndRaises(), fakes.LineSimulator(), fakes.SpeedController()),
                 done=lambda episode, result, writer: results.append(result))
    assert isinstance(results[0], EpisodeFailure) and "end_episode" in str(results[0])


def test_two_episodes_with_one_name_get_different_names_in_a_batch():
    recorders = []

    def open_writer():
        recorders.append(Recorder())
        return recorders[-1]

    scenario = scenarios([3])[0]
    episodes = [LockstepEpisode(i, scenario, 0, open_writer, name="same") for i in range(2)]
    model = CountingModel()
    run_lockstep(episodes, 2, make_lane=lambda i: (model, fakes.LineSimulator(), fakes.SpeedController()),
                 done=lambda *args: None)
    assert [set(r.names) for r in recorders] == [{"same"}, {"same (lane 1)"}]
    assert recorders[0].texts == recorders[1].texts


def test_the_episode_name_is_never_logged(tmp_path):
    from vladrivebench._engine.executors import SequentialExecutor
    from vladrivebench._engine.registry import Registry
    from vladrivebench._engine.sweep import ComponentSpec, RunConfig, run_sweep

    config = RunConfig(ComponentSpec("model", "echo-batched"), ComponentSpec("simulator", "line"),
                       ComponentSpec("controller", "speed"), tuple(fakes.SCENARIOS), (0, 1), batch=2)
    run_sweep(config, tmp_path, executor=SequentialExecutor(), registry=Registry([("fakes", fakes)], entry_points=False))
    logs = sorted((tmp_path / "episodes").glob("*.mcap"))
    assert logs and not any(b" seed 0" in p.read_bytes() or b" seed 1" in p.read_bytes() for p in logs)


def test_the_conformance_check_passes_a_memory_model_and_fails_a_forgetful_one():
    runs = [[obs for obs in _observations(scenario, seed)] for seed, scenario in enumerate(scenarios([4, 2, 5]))]
    check_batched_model(CountingModel(), runs, name="counting", tolerance=0.0)
    with pytest.raises(AssertionError, match=r"model 'forgetful' at lockstep step 0 .*differs from the CoT alone"):
        check_batched_model(ForgetfulCountingModel(), runs, name="forgetful", tolerance=0.0)


def test_the_conformance_check_refuses_a_model_without_batched_forms_and_too_few_episodes():
    runs = [_observations(s, 0) for s in scenarios([2, 2])]
    with pytest.raises(AssertionError, match="does not implement the BatchedModel protocol"):
        check_batched_model(fakes.EchoModel(), runs, name="echo")
    with pytest.raises(AssertionError, match="needs two or more episodes"):
        check_batched_model(CountingModel(), runs[:1], name="counting")


class WrongLength(CountingModel):
    def decode_action_batch(self, observations, cots, rngs):
        return super().decode_action_batch(observations, cots, rngs)[:-1]


class Drifting(CountingModel):
    def decode_action_batch(self, observations, cots, rngs):
        out = super().decode_action_batch(observations, cots, rngs)
        return [dataclasses.replace(t, xy=np.asarray(t.xy) + 0.01 * len(out)) for t in out]


def test_the_conformance_check_names_a_short_batch_and_a_drifting_row():
    runs = [_observations(s, 0) for s in scenarios([2, 2])]
    with pytest.raises(AssertionError, match="decode_action_batch must return a list of 2 Trajectorys"):
        check_batched_model(WrongLength(), runs, name="short")
    with pytest.raises(AssertionError, match=r"m from the one alone \(tolerance 0.0001 m\)"):
        check_batched_model(Drifting(), runs, name="drift")


def _observations(scenario, seed):
    sim = fakes.LineSimulator()
    frames = [sim.reset(scenario, seed)]
    from vladrivebench.records import Control

    while len(frames) < scenario.max_steps:
        frames.append(sim.step(Control(0.3, 0.0, 0.0, 3.0)))
    return frames
