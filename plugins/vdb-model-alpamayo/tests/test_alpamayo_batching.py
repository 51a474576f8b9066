"""Lockstep batches of the Alpamayo-architecture model: batched = unbatched up to rounding (rows with prompts
of different lengths, repeated observations), selfsplice and its trajectory bit-exact within a batch, the
fidelity gate on batched rows, per-row multimodal-RoPE positions, conditions over one shared prompt cache,
and ``vdb run`` / ``vdb intervene --batch`` end to end."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_alpamayo import TINY, observation, short_scenario, vdb
from vdb_adapter_transformers import lockstep, toolkit
from vdb_model_alpamayo import model as am
from vdb_model_alpamayo.plugin import make_alpamayo
from vladrivebench import BatchedModel, ConditionBatch, ConfigError
from vladrivebench.testing import read_episode

pytestmark = pytest.mark.filterwarnings("error::FutureWarning")

CACHE_TOLERANCE = 1e-5
"""Largest cache difference between a batched row and the same row alone: float32 summation order only
(measured ~6e-7)."""
TRAJECTORY_TOLERANCE_M = 1e-4  # measured ~3e-7 m


@pytest.fixture(scope="module")
def model():
    return make_alpamayo(frames=2, max_cot_tokens=12, cameras="front_wide,cross_left")


def mixed_observations():
    """Four observations with prompts of different lengths (routes), one of them twice."""
    routes = ["follow the lane", "turn left at the second junction, then keep right", "stop", "go"]
    observations = [observation(step=i, speed=2.0 + i, seed=i, route=route) for i, route in enumerate(routes)]
    return [*observations, observations[1]]


def rngs(seed, count):
    return [np.random.default_rng([seed, i]) for i in range(count)]


def test_the_model_declares_the_batched_capabilities(model):
    assert isinstance(model, BatchedModel) and isinstance(model, ConditionBatch)
    assert callable(model.splice_cot_batch)


def test_rows_have_prompts_of_different_lengths(model):
    lengths = {int(state.length) for state, _ in model.prefix_rows(mixed_observations())}
    assert len(lengths) >= 3


def test_batched_cots_and_trajectories_match_each_row_alone(model):
    observations = mixed_observations()
    cots = model.generate_cot_batch(observations, rngs(0, 5))
    trajectories = model.decode_action_batch(observations, cots, rngs(1, 5))
    for i, obs in enumerate(observations):
        model.reset(0)
        alone = model.generate_cot(obs, rngs(0, 5)[i])
        assert cots[i].text == alone.text
        assert cots[i].state.decoder.tokens == alone.state.decoder.tokens
        assert toolkit.cache_difference(cots[i].state.decoder, alone.state.decoder) < CACHE_TOLERANCE
        assert torch.equal(cots[i].state.decoder.rope_deltas, alone.state.decoder.rope_deltas)
        reference = model.decode_action(obs, alone, rngs(1, 5)[i])
        assert np.max(np.abs(trajectories[i].xy - reference.xy)) < TRAJECTORY_TOLERANCE_M
        assert trajectories[i].problems() is None


@pytest.mark.parametrize("splice_mode", ["sequential", "prefill"])
def test_selfsplice_within_a_batch_is_bit_identical_and_passes_the_fidelity_gate(splice_mode):
    model = make_alpamayo(frames=1, max_cot_tokens=10, cameras="front_wide,cross_left", splice_mode=splice_mode)
    observations = mixed_observations()
    own = model.generate_cot_batch(observations, rngs(0, 5))
    spliced = model.splice_cot_batch(observations, [c.text for c in own], rngs(2, 5))
    own_paths = model.decode_action_batch(observations, own, rngs(1, 5))
    spliced_paths = model.decode_action_batch(observations, spliced, rngs(1, 5))
    for a, b, pa, pb, obs in zip(own, spliced, own_paths, spliced_paths, observations, strict=True):
        assert b.spliced and model.state_digest(a) == model.state_digest(b)
        assert np.array_equal(pa.xy, pb.xy)
        cache_diff, trajectory_diff = model.fidelity_check(obs, b, np.random.default_rng(3))
        assert cache_diff <= model.fidelity_tolerance and trajectory_diff <= model.fidelity_tolerance


def test_a_batched_row_one_position_off_fails_the_fidelity_gate(model):
    observations = mixed_observations()[:2]
    cots = model.generate_cot_batch(observations, rngs(0, 2))
    real = cots[0].state.decoder
    shifted = dataclasses.replace(real, rope_deltas=real.rope_deltas + 1)
    wrong = dataclasses.replace(cots[0], state=am.AlpamayoState(shifted, cots[0].state.inputs))
    _, good = model.fidelity_check(observations[0], cots[0], np.random.default_rng(3))
    _, bad = model.fidelity_check(observations[0], wrong, np.random.default_rng(3))
    assert good <= model.fidelity_tolerance < bad


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(texts=st.lists(st.text(alphabet="abcdefghij .,:", max_size=14), min_size=1, max_size=4),
       order=st.randoms(use_true_random=False))
def test_any_splice_batch_equals_its_rows_alone_and_repeats_bit_for_bit(model, texts, order):
    pool = mixed_observations()
    observations = [pool[order.randrange(len(pool))] for _ in texts]
    batched = model.splice_cot_batch(observations, texts, rngs(0, len(texts)))
    again = model.splice_cot_batch(observations, texts, rngs(0, len(texts)))
    for i, (obs, text) in enumerate(zip(observations, texts, strict=True)):
        model.reset(0)
        alone = model.splice_cot(obs, text, np.random.default_rng(0))
        assert batched[i].state.decoder.tokens == alone.state.decoder.tokens
        assert toolkit.cache_difference(batched[i].state.decoder, alone.state.decoder) < CACHE_TOLERANCE
        assert model.state_digest(batched[i]) == model.state_digest(again[i])


def test_a_call_depends_on_its_observations_only_never_on_earlier_calls(model):
    observations = mixed_observations()
    first = [model.state_digest(c) for c in model.generate_cot_batch(observations, rngs(0, 5))]
    model.generate_cot_batch(observations[2:], rngs(0, 3))  # another batch in between
    fresh = make_alpamayo(frames=2, max_cot_tokens=12, cameras="front_wide,cross_left")
    assert [fresh.state_digest(c) for c in fresh.generate_cot_batch(observations, rngs(0, 5))] == first
    assert [model.state_digest(c) for c in model.generate_cot_batch(observations, rngs(0, 5))] == first


def test_conditions_over_one_shared_prompt_cache_match_one_by_one_splices(model):
    obs = mixed_observations()[1]
    texts = ["Stop: a pedestrian is crossing.", "", "The road is clear, accelerate now please."]
    decoded = model.decode_batch(obs, texts, np.random.default_rng(5))
    for text, trajectory in zip(texts, decoded, strict=True):
        alone = model.decode_action(obs, model.splice_cot(obs, text, np.random.default_rng(0)),
                                    np.random.default_rng(5))
        assert np.max(np.abs(alone.xy - trajectory.xy)) < TRAJECTORY_TOLERANCE_M


def test_the_expert_masks_padding_so_a_row_ignores_its_batch(model):
    obs = mixed_observations()[0]
    short = model.splice_cot_batch([obs], ["go"], rngs(0, 1))
    with_long = model.splice_cot_batch([obs, obs], ["go", "x" * 40], rngs(0, 2))
    alone = model.decode_action_batch([obs], short, rngs(1, 1))[0]
    beside = model.decode_action_batch([obs, obs], with_long, rngs(1, 2))[0]
    assert np.max(np.abs(alone.xy - beside.xy)) < TRAJECTORY_TOLERANCE_M


def test_bad_splices_in_a_batch_are_one_line_errors(model):
    obs = mixed_observations()[0]
    with pytest.raises(ConfigError, match="a splice needs one text, got slots"):
        model.splice_cot_batch([obs, obs], ["go", {"plan": "stop"}], rngs(0, 2))
    limit = toolkit.context_limit(model.backbone.vlm)
    with pytest.raises(toolkit.SpliceTooLongError, match="model 'alpamayo' splice text is .* tokens") as info:
        model.splice_cot_batch([obs, obs], ["go", "x" * limit], rngs(0, 2))
    assert "\n" not in str(info.value)


def test_lockstep_rows_cannot_mix_plain_and_multimodal_positions(model):
    state, _ = model.prefix_rows([mixed_observations()[0]])[0]
    plain = dataclasses.replace(state, rope_deltas=None)
    with pytest.raises(ValueError, match="cannot mix"):
        lockstep.LockstepDecoder.from_states(model.backbone.vlm, [state, plain], 0)


# -- end to end --------------------------------------------------------------------------------------------
def episode_cots(folder):
    out = {}
    for path in sorted(folder.glob("*.mcap")):
        episode = read_episode(path)
        out[path.name] = ([s.cot.text for s in episode.steps], [s.trajectory.xy for s in episode.steps])
    return out


def test_vdb_run_batched_gives_the_unbatched_cots_and_repeats_its_bytes(capsys, tmp_path):
    scenario = short_scenario(tmp_path, "e1.toml", "E.1-batch", seconds=0.5)
    runs = {}
    for name, batch in (("b1", 1), ("b3", 3), ("b3-again", 3)):
        code, _, err = vdb(capsys, "run", *TINY, "--scenarios", scenario, "--seeds", 4, "--batch", batch,
                           "--executor", "sequential", "--out", tmp_path / name)
        assert code == 0, err
        runs[name] = tmp_path / name / "episodes"
    for path in runs["b3"].glob("*.mcap"):
        assert path.read_bytes() == (runs["b3-again"] / path.name).read_bytes()
    unbatched, batched = episode_cots(runs["b1"]), episode_cots(runs["b3"])
    assert unbatched.keys() == batched.keys() and len(batched) == 4
    for name, (texts, paths) in batched.items():
        assert texts == unbatched[name][0]
        for a, b in zip(paths, unbatched[name][1], strict=True):
            assert np.max(np.abs(a - b)) < 1e-3


@pytest.mark.parametrize("mode", ["open-loop", "closed-loop"])
def test_vdb_intervene_batched_keeps_the_gate_exact(capsys, tmp_path, mode):
    route = short_scenario(tmp_path, "e1.toml", "E.1-short", seconds=0.3)
    extra = ["--checkpoints", "0.1,0.2"] if mode == "closed-loop" else []
    code, out, err = vdb(capsys, "intervene", *TINY, "--route", route, "--mode", mode, "--seeds", 3,
                         "--conditions", "accel,pedestrian", *extra, "--batch", 3, "--quiet", "--json",
                         "--out", tmp_path / "iv")
    assert code == 0, err
    results = json.loads(out)
    gate = results["gate"]
    assert results["valid"] and gate["steps_checked"] > 0 and gate["steps_failed"] == 0
    assert gate["max_trajectory_diff"] == 0.0
    assert gate["fidelity_steps_checked"] == gate["steps_checked"] and gate["fidelity_steps_failed"] == 0


def test_the_model_passes_the_batched_conformance_check(model):
    """Episodes of different lengths and prompts in lockstep through the public check (rows alone = in the
    batch up to rounding, selfsplice of the batch's own CoTs bit-identical)."""
    from vladrivebench.testing import check_batched_model

    episodes = [[observation(step=s, speed=2.0 + s, seed=10 * e + s, route=route) for s in range(length)]
                for e, (length, route) in enumerate(((2, "follow the lane"), (1, "turn left at the junction, then "
                                                                               "keep right"), (2, "stop")))]
    check_batched_model(model, episodes, name="alpamayo", tolerance=TRAJECTORY_TOLERANCE_M)
