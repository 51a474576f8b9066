"""The shipped ``kv`` and ``qa`` models: selfsplice, prefill, batching, pinned RNG, weights errors."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch
from vdb_adapter_transformers import toolkit
from vdb_model_neural import plugin
from vdb_model_neural.common import WeightsError, bundle_paths
from vdb_model_neural.kv_model import KVModel
from vdb_model_neural.qa_model import QAModel
from vladrivebench import ConfigError, EgoState, GroundTruth, Observation, VdbError
from vladrivebench.testing import isolated_registry


def observation(seed: int, speed: float = 6.0, step: int = 0) -> Observation:
    """A camera-like image: sky, grey road, and a random box (the model must not care that it is fake)."""
    rng = np.random.default_rng(seed)
    image = np.zeros((80, 160, 3), np.uint8)
    image[:38] = (150, 190, 230)
    image[38:] = (80, 110, 70)
    image[38:, 50:110] = (72, 72, 76)
    top, left = int(rng.integers(30, 60)), int(rng.integers(40, 110))
    image[top : top + int(rng.integers(3, 20)), left : left + int(rng.integers(2, 30))] = rng.integers(0, 255, 3)
    return Observation(step=step, time=step / 10, image=image, ego=EgoState(0.0, 0.0, 0.0, speed),
                       command="follow_lane", ground_truth=GroundTruth(step, step / 10), scenario_id="test")


@pytest.fixture(scope="module")
def kv():
    return KVModel()


@pytest.fixture(scope="module")
def qa():
    return QAModel()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kv_selfsplice_is_bit_identical(kv, seed):
    obs = observation(seed, speed=2.0 * seed)
    own = kv.generate_cot(obs, np.random.default_rng(0))
    assert own.text
    spliced = kv.splice_cot(obs, own.text, np.random.default_rng(0))
    assert kv.state_digest(spliced) == kv.state_digest(own)
    a = kv.decode_action(obs, own, np.random.default_rng(7))
    b = kv.decode_action(obs, spliced, np.random.default_rng(7))
    assert np.array_equal(a.xy, b.xy) and a.problems() is None


@pytest.mark.parametrize("seed", [0, 1])
def test_qa_selfsplice_is_bit_identical(qa, seed):
    obs = observation(seed)
    own = qa.generate_cot(obs, np.random.default_rng(0))
    assert set(own.slots) == {"scene", "objects", "decision"} and all(own.slots.values())
    spliced = qa.splice_cot(obs, own.slots, np.random.default_rng(0))
    assert qa.state_digest(spliced) == qa.state_digest(own)
    a = qa.decode_action(obs, own, np.random.default_rng(7))
    assert np.array_equal(a.xy, qa.decode_action(obs, spliced, np.random.default_rng(7)).xy)


def test_prefill_splice_differs_only_by_rounding_and_the_gate_sees_it(kv):
    prefill = KVModel(splice_mode="prefill")
    obs = observation(3)
    own = kv.generate_cot(obs, np.random.default_rng(0))
    spliced = prefill.splice_cot(obs, own.text, np.random.default_rng(0))
    difference = toolkit.cache_difference(own.state.decoder, spliced.state.decoder)
    assert difference < 1e-4
    assert (prefill.state_digest(spliced) == kv.state_digest(own)) == (difference == 0.0)
    a = kv.decode_action(obs, own, np.random.default_rng(7)).xy
    b = prefill.decode_action(obs, spliced, np.random.default_rng(7)).xy
    assert np.abs(a - b).max() < 1e-2


def test_the_digest_changes_with_the_text(kv):
    obs = observation(4)
    a = kv.splice_cot(obs, "Stop for the pedestrian in the lane because it is blocking the lane.", None)
    b = kv.splice_cot(obs, "Stop for the stationary car in the lane because it is blocking the lane.", None)
    assert kv.state_digest(a) != kv.state_digest(b)


def test_pinned_rng_reproduces_the_sampled_action(kv):
    obs = observation(5)
    cot = kv.generate_cot(obs, np.random.default_rng(0))
    same = [kv.decode_action(obs, cot, np.random.default_rng(11)).xy for _ in range(2)]
    other = kv.decode_action(obs, cot, np.random.default_rng(12)).xy
    assert np.array_equal(same[0], same[1])
    assert not np.array_equal(same[0], other)


def test_batched_conditions_equal_one_by_one(kv):
    prefill = KVModel(splice_mode="prefill")
    obs = observation(6)
    texts = ["Accelerate to maintain speed since the road ahead is clear and no obstacles are present.",
             "Stop for the pedestrian in the lane because it is blocking the lane.",
             "Brake.",
             "Keep the current speed because no obstacles are present in the lane."]
    batched = kv.decode_batch(obs, texts, np.random.default_rng(3))
    for text, trajectory in zip(texts, batched, strict=True):
        single = prefill.decode_action(obs, prefill.splice_cot(obs, text, None), np.random.default_rng(3))
        assert np.abs(trajectory.xy - single.xy).max() < 1e-3


def test_a_too_long_splice_names_the_limit(kv, qa):
    obs = observation(7)
    with pytest.raises(toolkit.SpliceTooLongError, match=r"at most 256 positions"):
        kv.splice_cot(obs, "depicts " * 400, None)
    slots = {"scene": "depicts " * 700, "objects": "x", "decision": "y"}
    with pytest.raises(VdbError, match=r"slot 'scene'.*640 positions.*at most \d+ tokens"):
        qa.splice_cot(obs, slots, None)


def test_wrong_injection_shapes_are_config_errors(kv, qa):
    obs = observation(8)
    with pytest.raises(ConfigError, match="one sentence"):
        kv.splice_cot(obs, {"scene": "a"}, None)
    with pytest.raises(ConfigError, match="takes slots scene, objects, decision"):
        qa.splice_cot(obs, "one text", None)


def _copy_bundle(name, tmp_path):
    for path in bundle_paths(name).values():
        shutil.copy(path, tmp_path / path.name)
    return bundle_paths(name, tmp_path)


@pytest.mark.parametrize("name, factory", [("kv", plugin.make_kv), ("qa", plugin.make_qa)])
def test_missing_weights_name_the_file_and_the_rebuild_command(tmp_path, name, factory):
    paths = _copy_bundle(name, tmp_path)
    paths["weights"].unlink()
    with pytest.raises(WeightsError) as info:
        factory(weights_dir=str(tmp_path))
    message = str(info.value)
    assert str(paths["weights"]) in message and "missing" in message
    assert f"python -m vdb_model_neural.train --model {name} --seed 0" in message
    assert "\n" not in message


@pytest.mark.parametrize("damage", ["garbage", "truncated", "pickle"])
def test_corrupt_weights_are_one_line_errors(tmp_path, damage):
    paths = _copy_bundle("kv", tmp_path)
    data = paths["weights"].read_bytes()
    if damage == "garbage":
        paths["weights"].write_bytes(b"\x00\x01not a safetensors file" * 10)
    elif damage == "truncated":
        paths["weights"].write_bytes(data[: len(data) // 2])
    else:  # a pickled checkpoint under the safetensors name is refused, never unpickled
        torch.save({"x": torch.zeros(2)}, paths["weights"])
    with pytest.raises(WeightsError, match=r"weights file .*kv\.safetensors is corrupt .*--model kv --seed 0"):
        KVModel(weights_dir=str(tmp_path))


def test_weights_of_another_shape_are_refused(tmp_path):
    paths = _copy_bundle("kv", tmp_path)
    config = json.loads(paths["config"].read_text())
    config["hidden"] = config["hidden"] * 2
    paths["config"].write_text(json.dumps(config))
    with pytest.raises(WeightsError, match="does not fit model 'kv'"):
        KVModel(weights_dir=str(tmp_path))


def test_corrupt_config_and_tokenizer(tmp_path):
    paths = _copy_bundle("qa", tmp_path)
    paths["tokenizer"].write_text("{not json")
    with pytest.raises(WeightsError, match=r"tokenizer file .*qa\.tokenizer\.json is corrupt"):
        QAModel(weights_dir=str(tmp_path))
    paths = _copy_bundle("qa", tmp_path)
    paths["config"].write_text("[]")
    with pytest.raises(WeightsError, match=r"config file .*qa\.config\.json is corrupt"):
        QAModel(weights_dir=str(tmp_path))


def test_loading_never_unpickles(monkeypatch):
    import pickle

    def refuse(*args, **kwargs):
        raise AssertionError("pickle must not be used to load weights")

    monkeypatch.setattr(pickle, "load", refuse)
    monkeypatch.setattr(pickle, "loads", refuse)
    monkeypatch.setattr(torch, "load", refuse)
    assert KVModel().cot_format.kind == "sentence"


def test_registration_is_light_and_options_are_checked():
    code = ("import sys, vdb_model_neural.plugin as p; from vladrivebench._engine.registry import Registry; "
            "r = Registry([('neural', p)], entry_points=False); print(r.names('model')); "
            "print(any(m in sys.modules for m in ('torch', 'transformers', 'tokenizers')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split("\n")[:2] == ["['kv', 'qa']", "False"]
    with isolated_registry(("neural", plugin)) as registry:
        with pytest.raises(ConfigError, match="splice_mode='fast' is not known"):
            registry.create("model", "kv", {"splice_mode": "fast"})
        with pytest.raises(ConfigError, match="does not take option 'beam_width'"):
            registry.create("model", "qa", {"beam_width": 4})
