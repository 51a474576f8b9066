"""The scripted model's batched forms: one instance serves a lockstep batch, its stop-sign memory kept per
episode (``obs.episode``), and every row gets exactly what it gets alone — in the conformance kit, in
``vdb run --batch`` and in ``vdb intervene --batch``."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vdb_model_scripted.model import ScriptedModel
from vdb_model_scripted.testing import make_observation
from vdb_sim_kinematic.plugin import make_simulator
from vladrivebench import BatchedModel, EpisodeMemory
from vladrivebench.episodes import build_component
from vladrivebench.testing import check_batched_model, run_cli, run_episode
from vladrivebench.world import load_suite

OPTIONS = [
    {},
    {"cot_format": "qa", "alpha": 1.0},
    {"alpha": 0.5, "miss_rate": 0.3, "hallucination_rate": 0.3, "contradiction_rate": 0.3, "light_error_rate": 0.3},
]


@pytest.fixture(scope="module")
def stop_sign_runs():
    """Observations of S.1 (a stop sign) driven by the scripted model until it has stopped and moved on,
    for three seeds, and of P.1 for one: episodes of different lengths whose memory matters."""
    suite = load_suite()
    runs = []
    for scenario_id, seed, steps in (("S.1", 0, 150), ("S.1", 1, 120), ("P.1", 2, 40), ("S.1", 3, 150)):
        observations = []
        run_episode(ScriptedModel(), make_simulator(render=False), build_component("controller", "pid"),
                    suite[scenario_id], seed, max_steps=steps,
                    on_step=lambda obs, *rest, into=observations: into.append(obs))
        runs.append(observations)
    return runs


def made_stop(run) -> bool:
    return any(obs.ego.speed < 0.1 and obs.ground_truth.critical_kind == "stop_sign"
               and 0 < (obs.ground_truth.distance_to_critical or 99) < 5 for obs in run)


def test_the_scripted_model_declares_both_capabilities():
    model = ScriptedModel()
    assert isinstance(model, BatchedModel) and isinstance(model, EpisodeMemory)
    assert callable(model.splice_cot_batch)


@pytest.mark.parametrize("options", OPTIONS)
def test_every_row_of_a_batch_gets_what_it_gets_alone(stop_sign_runs, options):
    assert sum(made_stop(run) for run in stop_sign_runs) >= 2  # the memory is exercised, not idle
    check_batched_model(ScriptedModel(**options), stop_sign_runs, name="scripted", tolerance=0.0)


class SharedMemoryModel(ScriptedModel):
    """The scripted model with one stop-sign memory for all episodes (what ``obs.episode`` prevents)."""

    def perceive(self, obs):
        return super().perceive(dataclasses.replace(obs, episode=""))


def test_the_check_catches_memory_shared_between_episodes(stop_sign_runs):
    with pytest.raises(AssertionError, match="scripted-shared.*episode"):
        check_batched_model(SharedMemoryModel(), stop_sign_runs, name="scripted-shared", tolerance=0.0)


def test_the_stop_is_remembered_per_episode():
    model = ScriptedModel()
    model.start_episode("a", 0)
    model.start_episode("b", 1)
    standing = dataclasses.replace(make_observation(speed=0.0, kind="stop_sign", distance=1.2), episode="a")
    rolling_b = dataclasses.replace(make_observation(speed=0.6, kind="stop_sign", distance=1.0, step=1), episode="b")
    assert model.perceive(standing).stop_made is True
    assert model.perceive(rolling_b).stop_made is False
    assert model.perceive(dataclasses.replace(rolling_b, episode="a")).stop_made is True
    model.end_episode("a")
    model.start_episode("a", 2)
    assert model.perceive(dataclasses.replace(rolling_b, episode="a")).stop_made is False


@settings(max_examples=30, deadline=None)
@given(rows=st.lists(st.tuples(st.integers(0, 3), st.integers(0, 149), st.integers(0, 2**32 - 1)), min_size=1,
                     max_size=8), options=st.sampled_from(OPTIONS))
def test_any_batch_equals_its_rows_one_by_one(stop_sign_runs, rows, options):
    """Rows from any episodes and steps, repeated or not: each batched call equals the per-row calls."""
    observations = [stop_sign_runs[run][min(step, len(stop_sign_runs[run]) - 1)] for run, step, _ in rows]
    seeds = [seed for *_, seed in rows]
    batched, alone = ScriptedModel(**options), ScriptedModel(**options)
    cots = batched.generate_cot_batch(observations, [np.random.default_rng(s) for s in seeds])
    own = [alone.generate_cot(o, np.random.default_rng(s)) for o, s in zip(observations, seeds, strict=True)]
    assert [c.text for c in cots] == [c.text for c in own]
    texts = [dict(c.slots) if c.slots else c.text for c in cots]
    spliced = batched.splice_cot_batch(observations, texts, [np.random.default_rng(s) for s in seeds])
    assert [batched.state_digest(c) for c in spliced] == [alone.state_digest(c) for c in own]
    trajectories = batched.decode_action_batch(observations, spliced, [np.random.default_rng(s + 1) for s in seeds])
    expected = [alone.decode_action(o, c, np.random.default_rng(s + 1)) for o, c, s in zip(observations, own, seeds,
                                                                                          strict=True)]
    assert all(np.array_equal(t.xy, e.xy) for t, e in zip(trajectories, expected, strict=True))


def step_messages(directory):
    """Every logged message of every episode (the metadata records the batch size, so it differs)."""
    from mcap.reader import make_reader

    found = {}
    for path in sorted((directory / "episodes").glob("*.mcap")):
        with path.open("rb") as handle:
            found[path.name] = [(channel.topic, message.log_time, message.data)
                                for _, channel, message in make_reader(handle).iter_messages()]
    return found


def test_vdb_run_batched_logs_the_unbatched_steps_and_every_stop_sign_is_passed(tmp_path):
    common = ["run", "--model", "scripted", "--scenarios", "S.1,P.1", "--seeds", "3",
              "--sim-opt", "render=false"]
    assert run_cli([*common, "--out", str(tmp_path / "one")]) == 0
    assert run_cli([*common, "--batch", "4", "--out", str(tmp_path / "four")]) == 0
    one, four = step_messages(tmp_path / "one"), step_messages(tmp_path / "four")
    assert len(one) == 6 and one == four
    for name, messages in four.items():
        if name.startswith("scripted__S.1"):
            truths = [json.loads(data) for topic, _, data in messages if topic == "/ground_truth"]
            assert truths[-1]["distance_to_critical"] < 0  # stopped, then went on past the line
            assert not any(t["violations"] for t in truths)


@pytest.mark.parametrize("executor", [["--executor", "process", "--workers", "2"],
                                      ["--executor", "pipelined", "--workers", "2"]])
def test_batched_runs_on_the_executors_log_the_sequential_steps(tmp_path, executor):
    """A batch per worker (process pool), or the model in a model server whose proxy forwards
    start_episode/end_episode (pipelined): the same steps as a sequential batched run."""
    common = ["run", "--model", "scripted", "--scenarios", "S.1", "--seeds", "6", "--sim-opt", "render=false",
              "--batch", "2"]
    assert run_cli([*common, "--out", str(tmp_path / "sequential")]) == 0
    assert run_cli([*common, *executor, "--out", str(tmp_path / "parallel")]) == 0
    assert step_messages(tmp_path / "sequential") == step_messages(tmp_path / "parallel")


def test_vdb_intervene_batched_runs_in_lockstep_with_the_unbatched_logs(tmp_path, capsys):
    common = ["intervene", "--model", "scripted", "--route", "S.1", "--mode", "closed-loop",
              "--conditions", "selfsplice,accel", "--seeds", "2", "--sim-opt", "render=false"]
    assert run_cli([*common, "--out", str(tmp_path / "one")]) == 0
    assert run_cli([*common, "--batch", "3", "--out", str(tmp_path / "three")]) == 0
    assert "one at a time" not in capsys.readouterr().err
    assert step_messages(tmp_path / "one") == step_messages(tmp_path / "three")
    results = [json.loads((tmp_path / d / "intervention.json").read_text()) for d in ("one", "three")]
    assert results[0]["gate"] == results[1]["gate"]
