"""Training is reproducible from the seed and writes bundles the models load (on a tiny synthetic dataset)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from vdb_model_neural import expert, train
from vdb_model_neural.common import bundle_paths, save_bundle
from vdb_model_neural.data import Dataset
from vdb_model_neural.kv_model import KVModel
from vdb_model_neural.qa_model import QAModel
from vladrivebench import EgoState, GroundTruth, Observation


def tiny_dataset(n: int = 24) -> Dataset:
    rng = np.random.default_rng(0)
    obs = Observation(0, 0.0, np.zeros((80, 160, 3), np.uint8), EgoState(0, 0, 0, 5.0), "follow_lane",
                      GroundTruth(0, 0.0))
    decisions = [expert.Decision("go", "clear"), expert.Decision("stop", "blocking", "car", 10.0)]
    rows = [decisions[i % 2] for i in range(n)]
    controls = np.stack([expert.rollout_controls(5.0, obs.ground_truth, d.stop_distance, 8.0) for d in rows])
    return Dataset(
        images=rng.integers(0, 255, (n, 80, 160, 3), dtype=np.uint8), speeds=np.full(n, 5.0),
        commands=["follow_lane"] * n, sentences=[expert.sentence_cot(d, 5.0, rng) for d in rows],
        slots=[expert.slot_cot(obs, d, rng) for d in rows], controls=controls, sentence_controls=controls,
        waypoints=np.cumsum(np.ones((n, 30, 2)), axis=1), cf_sentences=[expert.pick(rng, expert.GO_CLEAR)] * n,
        cf_controls=controls[::-1].copy(), cf_vetoed=np.arange(n) % 4 == 1, decisions=[d.action for d in rows], scenario_ids=["x"] * n,
        perception=np.array([[d.action == "stop", 2 * (d.action == "stop"), 0, 0.5, 0] for d in rows], np.float32),
    )


@pytest.mark.parametrize("name, trainer, model", [("kv", train.train_kv, KVModel), ("qa", train.train_qa, QAModel)])
def test_training_is_reproducible_and_its_bundle_loads(tmp_path, name, trainer, model):
    dataset = tiny_dataset()
    first, codec, config = trainer(dataset, seed=3, steps=3, threads=1, log=lambda m: None, batch=4)
    second, _, _ = trainer(dataset, seed=3, steps=3, threads=1, log=lambda m: None, batch=4)
    for (key, a), (_, b) in zip(first.state_dict().items(), second.state_dict().items(), strict=True):
        assert torch.equal(a, b), key
    other, _, _ = trainer(dataset, seed=4, steps=3, threads=1, log=lambda m: None, batch=4)
    assert any(not torch.equal(a, b)
               for a, b in zip(first.state_dict().values(), other.state_dict().values(), strict=True))
    paths = save_bundle(name, first, config, codec, tmp_path)
    assert paths == bundle_paths(name, tmp_path) and all(p.is_file() for p in paths.values())
    loaded = model(weights_dir=str(tmp_path))
    for key, value in first.state_dict().items():
        assert torch.equal(loaded.network.state_dict()[key], value), key
    assert config.training["seed"] == 3


def test_expert_data_is_the_same_whatever_the_number_of_workers():
    from vdb_model_neural.data import generate

    one, two = generate(5, 2, workers=1), generate(5, 2, workers=2)
    assert len(one) == len(two) > 0
    assert np.array_equal(one.images, two.images) and np.array_equal(one.controls, two.controls)
    assert one.sentences == two.sentences and one.cf_sentences == two.cf_sentences


@settings(max_examples=30, deadline=None)
@given(decisions=st.lists(st.sampled_from(["go", "stop"]), min_size=1, max_size=12))
def test_qa_learns_the_committed_profile_for_a_stop_and_the_experts_plan_otherwise(decisions):
    from types import SimpleNamespace

    n = len(decisions)
    plans = np.arange(n * 60, dtype=float).reshape(n, 30, 2)
    dataset = SimpleNamespace(decisions=decisions, controls=plans, sentence_controls=-plans)
    targets = train.qa_targets(dataset)
    for row, decision in enumerate(decisions):
        assert np.array_equal(targets[row], -plans[row] if decision == "stop" else plans[row])
