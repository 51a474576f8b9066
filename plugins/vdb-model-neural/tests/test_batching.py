"""Lockstep batches of the reference models: batched = unbatched up to rounding, selfsplice bit-exact."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from vdb_adapter_transformers import toolkit
from vdb_model_neural.kv_model import KVModel
from vdb_model_neural.qa_model import QAModel
from vladrivebench import BatchedModel, ConfigError, EgoState, GroundTruth, Observation

TOLERANCE_M = 1e-3
"""Largest waypoint difference (metres) allowed between a batched and an unbatched step: the batch only
changes floating-point summation order (measured differences are ~1e-6 m; see benchmarks/bench_batching.py)."""


def observation(seed: int, speed: float = 6.0, step: int = 0) -> Observation:
    rng = np.random.default_rng(seed)
    image = np.zeros((80, 160, 3), np.uint8)
    image[:38] = (150, 190, 230)
    image[38:] = (80, 110, 70)
    image[38:, 50:110] = (72, 72, 76)
    top, left = int(rng.integers(30, 60)), int(rng.integers(40, 110))
    image[top : top + int(rng.integers(3, 20)), left : left + int(rng.integers(2, 30))] = rng.integers(0, 255, 3)
    return Observation(step=step, time=step / 10, image=image, ego=EgoState(0.0, 0.0, 0.0, speed),
                       command="follow_lane", ground_truth=GroundTruth(step, step / 10), scenario_id=f"t{seed}")


@pytest.fixture(scope="module", params=["kv", "qa"])
def model(request):
    return KVModel() if request.param == "kv" else QAModel()


OBSERVATIONS = [observation(s, speed=1.5 * s, step=s) for s in range(3)]


def rngs(seed: int) -> list[np.random.Generator]:
    return [np.random.default_rng([seed, i]) for i in range(len(OBSERVATIONS))]


def test_reference_models_are_batched_models(model):
    assert isinstance(model, BatchedModel)


def test_batched_cots_and_trajectories_match_the_unbatched_ones(model):
    batched = model.generate_cot_batch(OBSERVATIONS, rngs(0))
    trajectories = model.decode_action_batch(OBSERVATIONS, batched, rngs(1))
    for i, obs in enumerate(OBSERVATIONS):
        alone = model.generate_cot(obs, rngs(0)[i])
        assert batched[i].text == alone.text and batched[i].slots == alone.slots
        assert toolkit.cache_difference(batched[i].state.decoder, alone.state.decoder) < 1e-4
        reference = model.decode_action(obs, alone, rngs(1)[i])
        assert np.max(np.abs(trajectories[i].xy - reference.xy)) < TOLERANCE_M
        assert trajectories[i].problems() is None


def test_selfsplice_within_a_batch_is_bit_identical(model):
    own = model.generate_cot_batch(OBSERVATIONS, rngs(0))
    texts = [cot.slots if cot.slots else cot.text for cot in own]
    spliced = model.splice_cot_batch(OBSERVATIONS, texts, rngs(0))
    assert [model.state_digest(c) for c in spliced] == [model.state_digest(c) for c in own]
    a = model.decode_action_batch(OBSERVATIONS, own, rngs(5))
    b = model.decode_action_batch(OBSERVATIONS, spliced, rngs(5))
    assert all(np.array_equal(x.xy, y.xy) for x, y in zip(a, b, strict=True))


def test_same_batch_gives_the_same_bits_twice(model):
    first = model.decode_action_batch(OBSERVATIONS, model.generate_cot_batch(OBSERVATIONS, rngs(0)), rngs(2))
    second = model.decode_action_batch(OBSERVATIONS, model.generate_cot_batch(OBSERVATIONS, rngs(0)), rngs(2))
    assert all(np.array_equal(x.xy, y.xy) for x, y in zip(first, second, strict=True))


def test_each_row_keeps_its_own_noise():
    kv = KVModel()
    own = kv.generate_cot_batch(OBSERVATIONS[:1] * 2, rngs(0)[:2])
    a, b = kv.decode_action_batch(OBSERVATIONS[:1] * 2, own, [np.random.default_rng(1), np.random.default_rng(2)])
    alone = kv.decode_action(OBSERVATIONS[0], own[1], np.random.default_rng(2))
    assert not np.array_equal(a.xy, b.xy) and np.max(np.abs(b.xy - alone.xy)) < TOLERANCE_M


@pytest.mark.parametrize("device", ["gpu0", "cuda:x", 3])
def test_a_bad_device_is_a_one_line_error(device):
    with pytest.raises(ConfigError, match="device"):
        KVModel(device=device)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_device_runs_batched():
    kv = KVModel(device="cuda")
    cots = kv.generate_cot_batch(OBSERVATIONS, rngs(0))
    assert all(t.problems() is None for t in kv.decode_action_batch(OBSERVATIONS, cots, rngs(1)))


def test_the_reference_models_pass_the_batched_conformance_check(model):
    """Three episodes of rendered frames of different lengths in lockstep through the public check."""
    from vladrivebench.testing import check_batched_model, observations

    episodes = [observations(n, height=80, width=160, seed=seed) for seed, n in ((0, 3), (1, 1), (2, 2))]
    check_batched_model(model, episodes, name=type(model).__name__, tolerance=TOLERANCE_M)
