"""Seed-dependent variation from the pinned streams: CoT sampling (temperature, top-p) for both models and
the ``qa`` planner's learnt Gaussian — reproducible per stream, batched = unbatched, selfsplice bit-exact."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from vdb_model_neural import expert, plugin
from vdb_model_neural.common import ModelConfig, TextCodec
from vdb_model_neural.kv_model import KVModel, KVNetwork
from vdb_model_neural.qa_model import QAModel, QANetwork
from vdb_model_neural.sampling import Sampler, TokenMemo
from vladrivebench import ConfigError, EgoState, GroundTruth, Observation
from vladrivebench.testing import check_bad_options, isolated_registry

CORPUS = [s for group in expert.STOP_SENTENCES.values() for s in group] + expert.GO_CLEAR + expert.SCENES


def observation(seed: int, step: int = 0) -> Observation:
    rng = np.random.default_rng(seed)
    image = rng.integers(0, 255, (80, 160, 3), dtype=np.uint8)
    return Observation(step=step, time=step / 10, image=image, ego=EgoState(0.0, 0.0, 0.0, 1.0 + seed),
                       command="follow_lane", ground_truth=GroundTruth(step, step / 10), scenario_id=f"s{seed}")


@pytest.fixture(scope="module")
def codec():
    return TextCodec.train(CORPUS, 320)


def tiny(kind: str, codec: TextCodec, temperature: float, top_p: float = 1.0):
    """A randomly initialised model (flat logits: sampling shows in every token)."""
    torch.manual_seed(0)
    config = ModelConfig(kind=kind, vocab_size=codec.vocab_size, context=256 if kind == "kv" else 640,
                         max_cot_tokens=12)
    network = (KVNetwork if kind == "kv" else QANetwork)(config)
    cls = KVModel if kind == "kv" else QAModel
    return cls.from_network(network, codec, temperature=temperature, top_p=top_p)


def text_of(cot):
    return cot.slots if cot.slots else cot.text


# -- the sampler ------------------------------------------------------------------------------------------
@settings(max_examples=80, deadline=None)
@given(logits=st.lists(st.floats(-20, 20), min_size=2, max_size=30), temperature=st.floats(0.05, 3.0),
       top_p=st.floats(0.01, 1.0), seed=st.integers(0, 10_000), banned=st.sets(st.integers(0, 29), max_size=3))
def test_a_sampled_token_is_in_the_nucleus_never_banned_and_reproducible(logits, temperature, top_p, seed,
                                                                         banned):
    banned = sorted(b for b in banned if b < len(logits) - 1)
    sampler = Sampler(temperature, top_p)
    pick = sampler.pick(np.array(logits), banned, np.random.default_rng(seed))
    assert pick == sampler.pick(torch.tensor(logits), banned, np.random.default_rng(seed))
    assert pick not in banned
    values = np.array(logits, dtype=np.float64)
    values[banned] = -np.inf
    probs = np.exp((values - values.max()) / temperature)
    probs /= probs.sum()
    # the nucleus: every token at least as probable as the pick, together, does not exceed top_p before it
    above = probs[probs > probs[pick]].sum()
    assert above < top_p + 1e-9


@settings(max_examples=60, deadline=None)
@given(rows=st.integers(1, 6).flatmap(lambda n: st.lists(st.lists(st.floats(-20, 20), min_size=8, max_size=8),
                                                         min_size=n, max_size=n)),
       temperature=st.sampled_from([0.0, 0.1, 0.6, 1.5]), top_p=st.floats(0.01, 1.0),
       seeds=st.lists(st.integers(0, 10_000), min_size=6, max_size=6), skip=st.sets(st.integers(0, 5)))
def test_a_batch_of_rows_picks_what_each_row_picks_alone(rows, temperature, top_p, seeds, skip):
    sampler, banned = Sampler(temperature, top_p), [3]
    streams = [None if i in skip else np.random.default_rng(seeds[i]) for i in range(len(rows))]
    picks = sampler.pick_rows(torch.tensor(rows), banned, streams)
    alone = [-1 if i in skip else sampler.pick(torch.tensor(row), banned, np.random.default_rng(seeds[i]))
             for i, row in enumerate(rows)]
    assert picks == alone
    # one draw per picking row: each stream's next number is its second
    for i, stream in enumerate(streams):
        if stream is not None:
            expected = np.random.default_rng(seeds[i])
            draws = 0 if temperature == 0.0 else 1
            [expected.random() for _ in range(draws)]
            assert stream.random() == expected.random()


@settings(max_examples=40, deadline=None)
@given(logits=st.lists(st.floats(-20, 20), min_size=2, max_size=30), seed=st.integers(0, 10_000))
def test_temperature_zero_is_greedy_and_draws_nothing(logits, seed):
    rng = np.random.default_rng(seed)
    state = rng.bit_generator.state
    assert Sampler(0.0, 0.75).pick(np.array(logits), [], rng) == int(np.argmax(logits))
    assert rng.bit_generator.state == state


def test_sampling_follows_the_distribution():
    logits = np.log(np.array([0.5, 0.3, 0.2]))
    rng = np.random.default_rng(0)
    counts = np.bincount([Sampler(1.0, 1.0).pick(logits, [], rng) for _ in range(3000)], minlength=3) / 3000
    assert np.allclose(counts, [0.5, 0.3, 0.2], atol=0.04)
    rng = np.random.default_rng(0)
    assert {Sampler(1.0, 0.5).pick(logits, [], rng) for _ in range(200)} == {0}  # 0.5 alone reaches top_p
    assert {Sampler(1.0, 0.75).pick(logits, [], rng) for _ in range(300)} == {0, 1}


def test_the_memo_gives_back_sampled_tokens_only_for_non_canonical_ones():
    memo = TokenMemo(capacity=2)
    memo.remember("ab", [1, 2], canonical=[3])
    memo.remember("cd", [4], canonical=[4])
    assert memo.tokens("ab", lambda t: [3]) == [1, 2] and memo.tokens("cd", lambda t: [9]) == [9]
    memo.remember("ef", [5, 6], canonical=[7])
    memo.remember("gh", [5, 6], canonical=[7])
    assert memo.tokens("ab", lambda t: [3]) == [3]  # the oldest left the bounded memo
    memo.clear()
    assert memo.tokens("gh", lambda t: [7]) == [7]


# -- options ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["kv", "qa"])
def test_bad_sampling_options_are_one_line_errors(vdb_registry, name):
    registry = vdb_registry(("neural", plugin))
    bad = [{"temperature": -0.1}, {"temperature": "hot"}, {"temperature": float("nan")}, {"temperature": 11},
           {"temperature": True}, {"top_p": 0}, {"top_p": 1.5}, {"top_p": "all"}, {"top_p": float("inf")}]
    if name == "qa":
        bad += [{"plan_noise": -1}, {"plan_noise": "lots"}, {"plan_noise": False}]
    check_bad_options(lambda options: registry.create("model", name, options), bad, name=name)


def test_the_defaults_are_the_real_models_and_options_set_them():
    with isolated_registry(("neural", plugin)) as registry:
        kv = registry.create("model", "kv", {})
        qa = registry.create("model", "qa", {})
        assert (kv.sampler.temperature, kv.sampler.top_p) == (0.6, 0.98)  # Alpamayo's
        assert (qa.sampler.temperature, qa.sampler.top_p) == (0.1, 0.75)  # ORION's
        assert qa.plan_noise == 1.0
        greedy = registry.create("model", "qa", {"temperature": 0, "top_p": 0.5, "plan_noise": 0})
        assert greedy.sampler.greedy and greedy.sampler.top_p == 0.5 and greedy.plan_noise == 0.0
    with pytest.raises(ConfigError, match="top_p must be a number in \\(0, 1\\]"):
        Sampler.checked("kv", 0.5, 0.0)


# -- the models --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["kv", "qa"])
def test_cots_vary_with_the_stream_and_repeat_with_it(codec, kind):
    model = tiny(kind, codec, temperature=1.0)
    obs = observation(0)
    texts = [text_of(model.generate_cot(obs, np.random.default_rng([s, 1]))) for s in range(4)]
    assert len({str(t) for t in texts}) > 1
    assert text_of(model.generate_cot(obs, np.random.default_rng([2, 1]))) == texts[2]
    greedy = tiny(kind, codec, temperature=0.0)
    assert len({str(text_of(greedy.generate_cot(obs, np.random.default_rng(s)))) for s in range(3)}) == 1


@pytest.mark.parametrize("kind", ["kv", "qa"])
def test_selfsplice_of_a_sampled_cot_is_bit_identical(codec, kind):
    model = tiny(kind, codec, temperature=1.5)  # flat logits: many non-canonical token sequences
    for seed in range(4):
        obs = observation(seed)
        own = model.generate_cot(obs, np.random.default_rng(seed))
        spliced = model.splice_cot(obs, text_of(own), np.random.default_rng(99))
        assert model.state_digest(spliced) == model.state_digest(own)
        a = model.decode_action(obs, own, np.random.default_rng(7))
        b = model.decode_action(obs, spliced, np.random.default_rng(7))
        assert np.array_equal(a.xy, b.xy)


@pytest.mark.parametrize("kind", ["kv", "qa"])
def test_a_batch_samples_each_row_from_its_own_stream(codec, kind):
    model = tiny(kind, codec, temperature=1.0, top_p=0.9)
    observations = [observation(s, step=s) for s in range(3)]
    streams = lambda: [np.random.default_rng([5, i]) for i in range(3)]  # noqa: E731
    batched = model.generate_cot_batch(observations, streams())
    alone = [model.generate_cot(o, r) for o, r in zip(observations, streams(), strict=True)]
    assert [text_of(c) for c in batched] == [text_of(c) for c in alone]
    spliced = model.splice_cot_batch(observations, [text_of(c) for c in batched], streams())
    assert [model.state_digest(c) for c in spliced] == [model.state_digest(c) for c in batched]
    actions = model.decode_action_batch(observations, batched, streams())
    for obs, cot, action, rng in zip(observations, alone, actions, streams(), strict=True):
        assert np.max(np.abs(model.decode_action(obs, cot, rng).xy - action.xy)) < 1e-3


def test_the_qa_planner_samples_its_learnt_deviation_from_the_action_stream(codec):
    model = tiny("qa", codec, temperature=0.0)
    obs = observation(1)
    cot = model.generate_cot(obs, np.random.default_rng(0))
    draws = [model.decode_action(obs, cot, np.random.default_rng(s)).xy for s in range(3)]
    assert not np.array_equal(draws[0], draws[1])
    assert np.array_equal(draws[2], model.decode_action(obs, cot, np.random.default_rng(2)).xy)
    state = cot.state
    with torch.no_grad():
        mean, log_std = model.network.plan_distribution(state.decoder.last_hidden, state.vision)
        noise = model.noise(np.random.default_rng(0))
        assert torch.equal(model.network.plan(state.decoder.last_hidden, state.vision, noise, 0.5),
                           mean + 0.5 * torch.exp(log_std) * noise)
    model.plan_noise = 0.0
    means = {model.decode_action(obs, cot, np.random.default_rng(s)).xy.tobytes() for s in range(3)}
    assert len(means) == 1
