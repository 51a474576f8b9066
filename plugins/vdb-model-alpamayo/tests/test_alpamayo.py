"""The Alpamayo-architecture plugin on its tiny random-weight Qwen3-VL: the protocol, selfsplice and the
fidelity gate, the expert's positions, bad options, and `vdb run` / `vdb label` / `vdb intervene` end to end."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from vdb_adapter_transformers import toolkit
from vdb_model_alpamayo import model as am
from vdb_model_alpamayo.plugin import make_alpamayo
from vladrivebench import (
    ConfigError,
    EgoState,
    FidelityCheck,
    GroundTruth,
    Observation,
    TokenCounter,
    VLAModel,
)
from vladrivebench.testing import read_episode, run_cli

pytestmark = pytest.mark.filterwarnings("error::FutureWarning")
SCENARIOS = Path(__file__).resolve().parents[3] / "scenarios"


def observation(step=0, speed=5.0, seed=0, **extra):
    image = (np.random.default_rng(seed).random((80, 160, 3)) * 255).astype(np.uint8)
    truth = GroundTruth(step=step, time=step / 10, critical_id=None, critical_kind=None, distance_to_critical=None,
                        blocking=False, route_progress=0.0, route_length=50.0, collisions=(), terminal=None)
    obs = Observation(step, step / 10, image, EgoState(0.0, 0.0, 0.0, speed), "follow_lane", truth, "T")
    for name, value in extra.items():
        object.__setattr__(obs, name, value)
    return obs


def rng():
    return np.random.default_rng(7)


@pytest.fixture(scope="module")
def model():
    return make_alpamayo(frames=2, max_cot_tokens=12)


def test_protocols(model):
    assert isinstance(model, VLAModel) and isinstance(model, FidelityCheck) and isinstance(model, TokenCounter)
    assert model.trajectory_spec.horizon_s == pytest.approx(6.4) and model.trajectory_spec.rate_hz == 10.0


def test_prompt_layout(model):
    obs = observation()
    text = model.prompt_text(obs)
    assert text.startswith("<|im_start|>system\n") and text.endswith("<|im_start|>assistant\n")
    for label in ("front wide:", "front tele:", "cross left:", "cross right:"):
        assert label in text
    assert text.count("<|image_pad|>") == 4 * 2
    inputs = model.prompt_inputs(obs, model.camera_frames(obs))
    ids = inputs["input_ids"][0]
    assert int((ids == model.backbone.token_id("<|traj_history|>")).sum()) == 0  # fused with history ids
    assert inputs["image_grid_thw"].shape == (8, 3)


def test_selfsplice_is_bit_identical_and_passes_the_fidelity_gate(model):
    obs = observation()
    own = model.generate_cot(obs, rng())
    assert own.state.decoder.tokens[0] == model.start_id and own.state.decoder.tokens[-1] == model.future_id
    spliced = model.splice_cot(obs, own.text, rng())
    assert model.state_digest(spliced) == model.state_digest(own)
    a, b = model.decode_action(obs, own, rng()), model.decode_action(obs, spliced, rng())
    assert a.problems() is None and np.array_equal(a.xy, b.xy) and len(a.times) == 64
    cache_diff, trajectory_diff = model.fidelity_check(obs, spliced, rng())
    assert cache_diff <= model.fidelity_tolerance and trajectory_diff <= model.fidelity_tolerance


def test_the_greedy_cot_is_qwen3_vls_own_generate(model):
    obs = observation()
    own = model.generate_cot(obs, rng())
    _, inputs = model.prefix_state(obs)
    native = toolkit.native_generate(model.backbone.vlm, inputs, model.start_id, model.end_id,
                                     model.max_cot_tokens, banned=model.banned)
    assert model.backbone.tokenizer.decode(native) == own.text


def test_a_dropped_rope_delta_fails_fidelity_while_selfsplice_passes(model, monkeypatch):
    obs = observation(seed=3)
    real_fork = toolkit.fork

    def fork_without_delta(state):
        copy = real_fork(state)
        return dataclasses.replace(copy, rope_deltas=torch.zeros_like(copy.rope_deltas))

    model.reset(0)
    monkeypatch.setattr(am.toolkit, "fork", fork_without_delta)
    own = model.generate_cot(obs, rng())
    spliced = model.splice_cot(obs, own.text, rng())
    assert model.state_digest(spliced) == model.state_digest(own)
    cache_diff, trajectory_diff = model.fidelity_check(obs, spliced, rng())
    assert cache_diff > 100 * model.fidelity_tolerance
    monkeypatch.undo()
    model.reset(0)


def test_the_expert_reads_the_cot_and_draws_its_noise_from_the_pinned_rng(model):
    obs = observation()
    brake = model.splice_cot(obs, "Stop: a pedestrian is crossing.", rng())
    go = model.splice_cot(obs, "The road is clear, accelerate.", rng())
    assert not np.array_equal(model.decode_action(obs, brake, rng()).xy, model.decode_action(obs, go, rng()).xy)
    other = model.decode_action(obs, brake, np.random.default_rng(8)).xy
    assert not np.array_equal(model.decode_action(obs, brake, rng()).xy, other)
    length = brake.state.decoder.length
    model.decode_action(obs, brake, rng())
    assert brake.state.decoder.cache.get_seq_length() == length  # the expert leaves the cache as it found it


def test_an_empty_splice_is_valid(model):
    obs = observation()
    empty = model.splice_cot(obs, "", rng())
    assert empty.state.decoder.tokens == (model.start_id, model.end_id, model.future_id)
    assert model.decode_action(obs, empty, rng()).problems() is None


def test_rig_cameras_are_used_and_missing_ones_get_the_front_image(model):
    left = np.full((40, 80, 3), 200, np.uint8)
    obs = observation(cameras={"cross_left": [left, left]})
    frames = model.camera_frames(obs)
    assert frames["camera_cross_left_120fov"][0].mean() == pytest.approx(200)
    assert np.array_equal(frames["camera_front_tele_30fov"][0], frames["camera_front_wide_120fov"][0])
    assert frames["camera_front_wide_120fov"][0].shape == (64, 128, 3)


def test_history_poses_from_the_observation_or_extrapolated():
    poses = am.history_poses(observation(speed=5.0))
    assert poses.shape == (16, 3) and poses[-1, 0] == pytest.approx(-0.5) and poses[0, 0] == pytest.approx(-8.0)
    history = [EgoState(-float(k), 0.0, 0.0, 5.0) for k in range(3, 0, -1)]
    poses = am.history_poses(observation(ego_history=history))
    assert poses[-1, 0] == pytest.approx(-1.0) and poses[0, 0] == pytest.approx(-3.0)


def test_controls_integrate_into_waypoints():
    straight = am.controls_to_trajectory(np.zeros((64, 2)), 5.0, 0.1)
    assert straight.xy[-1, 0] == pytest.approx(32.0) and straight.xy[-1, 1] == pytest.approx(0.0)
    braking = am.controls_to_trajectory(np.tile([-8.0, 0.0], (64, 1)), 4.0, 0.1)
    assert braking.xy[-1, 0] == pytest.approx(1.0) and np.all(np.diff(braking.xy[:, 0]) >= 0)
    turning = am.controls_to_trajectory(np.tile([0.0, 0.1], (64, 1)), 5.0, 0.1)
    assert turning.xy[-1, 1] > 0


@pytest.mark.parametrize("options, fragment", [
    ({"cameras": "front_wide,rear"}, "camera 'rear' is not one the model knows"),
    ({"resolution": "16x16"}, "at least 32 pixels"),
    ({"resolution": "big"}, "expected HEIGHTxWIDTH"),
    ({"checkpoint": "/nonexistent/alpamayo"}, "no checkpoint there"),
    ({"dtype": "int8"}, "option dtype=int8"),
    ({"frames": 0}, "option frames=0"),
    ({"device": "cuda"}, "runs on cpu in float32"),
])
def test_bad_options_are_one_line_config_errors(options, fragment):
    with pytest.raises(ConfigError, match=fragment) as info:
        make_alpamayo(**options)
    assert "\n" not in str(info.value)


def test_a_checkpoint_of_another_architecture_is_refused(tmp_path):
    (tmp_path / "config.json").write_text(json.dumps({"model_type": "llama"}))
    with pytest.raises(ConfigError, match="is a 'llama' model; expected one of: alpamayo_r1"):
        make_alpamayo(checkpoint=str(tmp_path))


# -- end to end --------------------------------------------------------------------------------------------
def short_scenario(tmp_path, source, new_id, seconds=0.4):
    lines = (SCENARIOS / source).read_text().splitlines()
    first_id = next(i for i, line in enumerate(lines) if line.startswith("id = "))
    lines[first_id] = f'id = "{new_id}"'
    lines = [f"max_time_s = {seconds}" if line.startswith("max_time_s") else line for line in lines]
    path = tmp_path / source
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def vdb(capsys, *args):
    code = run_cli([str(a) for a in args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


TINY = ["--model", "alpamayo", "--model-opt", "max_cot_tokens=6", "--model-opt", "cameras=front_wide,cross_left"]


def test_vdb_run_and_label_end_to_end(capsys, tmp_path):
    scenario = short_scenario(tmp_path, "e1.toml", "E.1-run")
    code, out, err = vdb(capsys, "run", *TINY, "--scenarios", scenario, "--seeds", 1, "--executor", "sequential",
                         "--out", tmp_path / "run")
    assert code == 0, err
    episodes = list((tmp_path / "run" / "episodes").glob("*.mcap"))
    assert len(episodes) == 1
    meta = read_episode(episodes[0]).meta
    assert meta["model"]["effective_options"]["cameras"] == "front_wide,cross_left"
    assert meta["model"]["effective_options"]["splice_mode"] == "sequential"
    for package in ("torch", "transformers", "vdb-adapter-transformers", "vdb-model-alpamayo"):
        assert meta["versions"].get(package, "-") != "-", package
    code, out, err = vdb(capsys, "label", tmp_path / "run")
    assert code == 0, err
    assert (tmp_path / "run" / "labels").is_dir()


@pytest.mark.parametrize("mode, source, route_id", [
    ("open-loop", "e1.toml", "E.1-short"),
    ("closed-loop", "e1.toml", "E.1-short"),
    ("safety", "safe-kerb-ped.toml", "SAFE.kerb-ped-short"),
])
def test_vdb_intervene_end_to_end_with_the_fidelity_gate(capsys, tmp_path, mode, source, route_id):
    route = short_scenario(tmp_path, source, route_id, seconds=0.3)
    conditions = ["--conditions", "accel"] if mode != "safety" else []
    if mode == "closed-loop":  # checkpoints must fall within the 0.3 s episode
        conditions += ["--checkpoints", "0.1,0.2"]
    code, out, err = vdb(capsys, "intervene", *TINY, "--route", route, "--mode", mode, "--seeds", 1, *conditions,
                         "--quiet", "--json", "--out", tmp_path / "iv")
    assert code == 0, err
    results = json.loads(out)
    gate = results["gate"]
    assert results["valid"] and gate["steps_checked"] > 0
    assert gate["fidelity_steps_checked"] == gate["steps_checked"] and gate["fidelity_steps_failed"] == 0
    assert gate["max_fidelity_cache_diff"] < 1e-4


def test_a_bad_option_on_the_command_line_is_one_line_and_exit_2(capsys, tmp_path):
    scenario = short_scenario(tmp_path, "e1.toml", "E.1-run")
    code, out, err = vdb(capsys, "run", "--model", "alpamayo", "--model-opt", "cameras=rear", "--scenarios",
                         scenario, "--seeds", 1, "--executor", "sequential", "--out", tmp_path / "bad")
    assert code == 2 and err.count("\n") == 1 and err.startswith("vdb: error: ") and "'rear'" in err


@pytest.mark.parametrize("tamper, fragment", [
    (lambda b: setattr(b.image_processor, "merge_size", 3), "image processor's merge_size is 3, the vision tower's is 2"),
    (lambda b: setattr(b.image_processor, "patch_size", 14), "image processor's patch_size is 14"),
    (lambda b: setattr(b.vlm.config, "image_token_id", 7), "the model's image token is 7"),
])
def test_a_processor_that_does_not_match_the_model_is_refused_in_one_line(tamper, fragment):
    from vdb_model_alpamayo.backbone import check_processor, tiny_backbone

    backbone = tiny_backbone(0)
    check_processor(backbone, "(tiny model)")  # the matching one passes
    tamper(backbone)
    with pytest.raises(ConfigError, match=fragment) as info:
        check_processor(backbone, "option checkpoint=/ckpt")
    assert "\n" not in str(info.value) and "option checkpoint=/ckpt" in str(info.value)


def test_a_tokenizer_without_the_alpamayo_tokens_is_refused():
    from vdb_adapter_transformers import tiny
    from vdb_model_alpamayo.backbone import Backbone, check_processor, tiny_backbone

    good = tiny_backbone(0)
    bare = tiny.byte_tokenizer(["<|image_pad|>", "<|vision_start|>", "<|vision_end|>"])
    bad = Backbone(good.vlm, bare, good.image_processor, good.expert, good.action_in, good.action_out, "tiny")
    with pytest.raises(ConfigError, match="the tokenizer does not know <\\|cot_start\\|>"):
        check_processor(bad, "option checkpoint=/ckpt")
