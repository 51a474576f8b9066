"""The scripted model: determinism, selfsplice, the coupling weight alpha and the paper's injection texts."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vdb_model_scripted.model import ScriptedModel, cot_truth
from vdb_model_scripted.testing import STRAIGHT_ROUTE, make_observation
from vladrivebench import VLAModel, step_rng
from vladrivebench.intervention import PAPER_TEXTS, gate_record

KINDS = [None, "pedestrian", "car", "traffic_light", "stop_sign"]


def curved_route(radius: float, side: float) -> tuple[tuple[float, float], ...]:
    return tuple((radius * math.sin(s / radius), side * radius * (1 - math.cos(s / radius))) for s in range(1, 51))


routes = st.sampled_from([STRAIGHT_ROUTE, (), curved_route(20.0, 1.0), curved_route(35.0, -1.0),
                          tuple((x, y + 0.4) for x, y in STRAIGHT_ROUTE)])


@st.composite
def observations(draw):
    kind = draw(st.sampled_from(KINDS))
    return make_observation(
        speed=draw(st.floats(0.0, 8.5)), step=draw(st.integers(0, 600)), kind=kind,
        distance=draw(st.floats(-3.0, 100.0)) if kind else None, blocking=draw(st.booleans()),
        light=draw(st.sampled_from(["red", "yellow", "green"])), actor_speed=draw(st.sampled_from([0.0, 1.5])),
        route=draw(routes))


@st.composite
def models(draw, alpha=None):
    rate = st.floats(0.0, 1.0)
    return ScriptedModel(alpha=draw(st.floats(0.0, 1.0)) if alpha is None else alpha,
                         miss_rate=draw(rate), hallucination_rate=draw(rate), contradiction_rate=draw(rate),
                         light_error_rate=draw(rate), cot_format=draw(st.sampled_from(["sentence", "qa"])),
                         noise=draw(st.sampled_from([0.0, 0.05, 0.3])))


def own_step(model, obs, seed):
    cot = model.generate_cot(obs, step_rng(seed, obs.step, "cot"))
    return cot, model.decode_action(obs, cot, step_rng(seed, obs.step, "action"))


def test_the_model_satisfies_the_protocol():
    model = ScriptedModel()
    assert isinstance(model, VLAModel)
    assert model.trajectory_spec.horizon_s == 3.0 and model.trajectory_spec.rate_hz == 10.0
    assert ScriptedModel(cot_format="qa").cot_format.slots == ("scene", "objects", "decision")


@given(model=models(), obs=observations(), seed=st.integers(0, 2**31))
@settings(max_examples=80, deadline=None)
def test_a_seed_and_step_reproduce_the_cot_and_trajectory(model, obs, seed):
    cot, trajectory = own_step(model, obs, seed)
    again_cot, again = own_step(model, obs, seed)
    assert (cot.text, cot.slots, cot_truth(cot)) == (again_cot.text, again_cot.slots, cot_truth(again_cot))
    assert np.array_equal(trajectory.xy, again.xy) and np.array_equal(trajectory.times, again.times)
    assert trajectory.problems() is None
    assert len(trajectory.times) == 30 and np.all(np.diff(trajectory.times) > 0)


@given(model=models(), obs=observations(), seed=st.integers(0, 2**31))
@settings(max_examples=80, deadline=None)
def test_selfsplice_is_bit_identical(model, obs, seed):
    own, own_trajectory = own_step(model, obs, seed)
    injection = own.slots if model.cot_format.is_slotted else own.text
    spliced = model.splice_cot(obs, injection, step_rng(seed, obs.step, "condition"))
    assert spliced.spliced and not own.spliced
    assert model.state_digest(spliced) == model.state_digest(own)
    spliced_trajectory = model.decode_action(obs, spliced, step_rng(seed, obs.step, "action"))
    assert np.array_equal(spliced_trajectory.xy, own_trajectory.xy)
    assert gate_record(model, own, own_trajectory, spliced, spliced_trajectory)["ok"]


@given(model=models(alpha=0.0), obs=observations(), seed=st.integers(0, 2**31),
       text=st.one_of(st.text(max_size=120), st.sampled_from([t["sentence"] for t in PAPER_TEXTS.values()
                                                              if "sentence" in t])))
@settings(max_examples=80, deadline=None)
def test_with_alpha_zero_no_text_changes_the_action(model, obs, seed, text):
    _, own_trajectory = own_step(model, obs, seed)
    spliced = model.splice_cot(obs, text, step_rng(seed, obs.step, "condition"))
    trajectory = model.decode_action(obs, spliced, step_rng(seed, obs.step, "action"))
    assert np.array_equal(trajectory.xy, own_trajectory.xy)


def displacement(model, obs, text, seed=3):
    cot = model.splice_cot(obs, text, step_rng(seed, obs.step, "condition"))
    return model.decode_action(obs, cot, step_rng(seed, obs.step, "action")).forward_displacement(2.0)


@pytest.mark.parametrize("speed", [3.0, 6.5, 8.0])
def test_with_alpha_one_the_papers_brake_texts_shorten_the_alpamayo_trajectory(speed):
    model, obs = ScriptedModel(alpha=1.0), make_observation(speed=speed)  # an empty straight road
    accel = displacement(model, obs, PAPER_TEXTS["accel"]["sentence"])
    pedestrian = displacement(model, obs, PAPER_TEXTS["pedestrian"]["sentence"])
    car = displacement(model, obs, PAPER_TEXTS["car"]["sentence"])
    assert pedestrian < accel and car < accel
    assert pedestrian < speed * 2.0 < accel or speed >= 8.0  # braking vs speeding up (8.5 m/s cap)


def test_with_alpha_one_the_papers_orion_texts_order_the_trajectories():
    model, obs = ScriptedModel(alpha=1.0, cot_format="qa"), make_observation(speed=6.5)

    def slots(name):
        return dict(zip(("scene", "objects", "decision"), PAPER_TEXTS[name]["slots"], strict=True))

    accel, car = displacement(model, obs, slots("accel")), displacement(model, obs, slots("car"))
    pedestrian, red = displacement(model, obs, slots("pedestrian")), displacement(model, obs, slots("red-light"))
    assert pedestrian < red < car < accel  # stated stop at 10 m, then at the 20 m stop line, hold, speed up


@given(alpha=st.floats(0.0, 1.0), seed=st.integers(0, 1000))
@settings(max_examples=30, deadline=None)
def test_coupling_grows_with_alpha(alpha, seed):
    obs = make_observation(speed=6.5)
    stop = PAPER_TEXTS["pedestrian"]["sentence"]
    effect = displacement(ScriptedModel(alpha=alpha, noise=0.0), obs, stop, seed)
    stronger = displacement(ScriptedModel(alpha=min(alpha + 0.2, 1.0), noise=0.0), obs, stop, seed)
    assert stronger <= effect + 1e-9


def test_a_string_given_to_a_qa_model_is_its_decision():
    model, obs = ScriptedModel(alpha=1.0, cot_format="qa"), make_observation()
    cot = model.splice_cot(obs, "You should slow down and stop.", np.random.default_rng(0))
    assert cot.slots == {"scene": "", "objects": "", "decision": "You should slow down and stop."}
    assert model.reading(cot).intent == "decelerating"


def test_a_mapping_given_to_a_sentence_model_is_joined_in_order():
    model = ScriptedModel(alpha=1.0)
    cot = model.splice_cot(make_observation(), {"a": "The road is clear.", "b": "Stop now."},
                           np.random.default_rng(0))
    assert cot.text == "The road is clear. Stop now."


@pytest.mark.parametrize("bad, message", [
    ({"scene": "x", "plan": "y"}, "unknown CoT slot 'plan'"),
    ({"decision": 3}, "a CoT must be a string or a mapping"),
    (42, "a CoT must be a string or a mapping"),
])
def test_bad_injections_are_one_line_errors(bad, message):
    from vladrivebench import ConfigError

    with pytest.raises(ConfigError, match=message) as info:
        ScriptedModel(cot_format="qa").splice_cot(make_observation(), bad, np.random.default_rng(0))
    assert "\n" not in str(info.value)


def test_a_cot_without_scripted_state_is_read_from_its_text():
    from vladrivebench import CoT

    model, obs = ScriptedModel(alpha=1.0), make_observation()
    plain = CoT("Stop for the pedestrian in the lane because it is blocking the lane.")
    spliced = model.splice_cot(obs, plain.text, np.random.default_rng(0))
    assert model.state_digest(plain) == model.state_digest(spliced)


def test_perception_stops_before_a_blocking_pedestrian_whatever_the_cot_says():
    model = ScriptedModel(alpha=0.0, noise=0.0)
    obs = make_observation(speed=6.5, kind="pedestrian", distance=12.0)
    trajectory = model.decode_action(obs, model.splice_cot(obs, PAPER_TEXTS["accel"]["sentence"],
                                                           np.random.default_rng(0)), np.random.default_rng(0))
    assert trajectory.xy[-1, 0] <= 12.0 - 4.0 + 1e-6  # the bumper keeps the 4 m gap
    assert trajectory.xy[-1, 0] - trajectory.xy[-2, 0] == pytest.approx(0.0, abs=1e-9)


def test_the_stop_sign_is_released_once_the_stop_is_made():
    model = ScriptedModel(alpha=0.0, noise=0.0)
    model.reset(0)
    rolling = make_observation(speed=0.5, kind="stop_sign", distance=1.5)
    assert model.perceive(rolling).stop_made is False
    standing = make_observation(speed=0.0, kind="stop_sign", distance=1.2, step=1)
    assert model.perceive(standing).stop_made is True
    moving_again = make_observation(speed=0.6, kind="stop_sign", distance=1.0, step=2)
    assert model.perceive(moving_again).stop_made is True
    model.reset(1)
    assert model.perceive(moving_again).stop_made is False


@given(forward=st.floats(8.0, 60.0), speed=st.floats(0.0, 8.5), right=st.floats(-1.9, 1.9))
@settings(max_examples=60, deadline=None)
def test_with_alpha_one_a_stated_obstacle_is_where_the_stop_ends(forward, speed, right):
    model = ScriptedModel(alpha=1.0, cot_format="qa", noise=0.0)
    obs = make_observation(speed=speed)
    text = {"objects": f"Pedestrian at <{right:.2f}, {forward:.2f}> standing in the lane, blocking the path.",
            "decision": "You should slow down and stop."}
    trajectory = model.decode_action(obs, model.splice_cot(obs, text, np.random.default_rng(0)),
                                     np.random.default_rng(0))
    room = round(forward, 2) - obs.ego.length / 2 - 0.3 - 4.0  # bumper to the near edge, minus the 4 m gap
    if room >= 0.05 * speed:
        assert trajectory.xy[-1, 0] <= room + 1e-6
    # beside the lane, the same pedestrian is no reason to stop there: the CoT's stop is a plain brake
    aside = {**text, "objects": text["objects"].replace(f"<{right:.2f},", "<3.50,")}
    plain = model.decode_action(obs, model.splice_cot(obs, aside, np.random.default_rng(0)), np.random.default_rng(0))
    braking = speed * speed / (2 * 3.0)  # from the current speed at the comfortable 3 m/s²
    # (a stop shorter than half a step at the current speed cannot be planned: it takes that half step)
    assert braking - speed * 0.1 - 1e-6 <= plain.xy[-1, 0] <= max(braking, 0.05 * speed) + 1e-6


def test_cot_extras_expose_the_truth_of_own_cots_only():
    import json

    model, obs = ScriptedModel(hallucination_rate=1.0), make_observation(kind="pedestrian", distance=20.0)
    own = model.generate_cot(obs, np.random.default_rng(0))
    extras = model.cot_extras(own)
    assert extras == {"scripted_truth": cot_truth(own)} and extras["scripted_truth"]["hallucinated"] is True
    assert json.loads(json.dumps(extras)) == extras  # JSON-able for the episode log
    assert model.cot_extras(model.splice_cot(obs, own.text, np.random.default_rng(0))) is None
