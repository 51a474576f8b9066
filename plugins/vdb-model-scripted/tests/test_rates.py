"""The CoT's error rates are exact: each event is one pinned uniform draw below its rate, the text shows
exactly the events the model records, and observed frequencies match the options."""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vdb_model_scripted.model import ScriptedModel, cot_truth
from vdb_model_scripted.reading import DECELERATING, named_kinds, stated_intents
from vdb_model_scripted.testing import make_observation
from vdb_model_scripted.writing import CONTRADICT, HALLUCINATE, LIGHT_ERROR, MISS, N_DRAWS
from vladrivebench import step_rng

SITUATIONS = [
    dict(),
    dict(kind="pedestrian", distance=30.0),
    dict(kind="pedestrian", distance=9.0, speed=3.0),
    dict(kind="pedestrian", distance=20.0, blocking=False),
    dict(kind="pedestrian", distance=15.0, actor_speed=1.5),
    dict(kind="car", distance=12.0),
    dict(kind="car", distance=25.0, blocking=False),
    dict(kind="traffic_light", distance=14.0, light="red"),
    dict(kind="traffic_light", distance=60.0, light="red"),
    dict(kind="traffic_light", distance=20.0, light="green"),
    dict(kind="traffic_light", distance=9.0, light="yellow", speed=8.0),
    dict(kind="stop_sign", distance=12.0),
    dict(kind="stop_sign", distance=1.0, speed=0.0),
    dict(kind="pedestrian", distance=120.0),  # beyond the perception range: nothing to mention
]
_COLOUR = re.compile(r"\b(red|yellow|green)\b", re.IGNORECASE)


def observation(i: int):
    return make_observation(step=i, **SITUATIONS[i % len(SITUATIONS)])


def lexical_contradiction(text: str) -> bool:
    """Both a slow-down/stop phrase and a keep-going/speed-up phrase, or two different light colours."""
    intents = set(stated_intents(text))
    colours = {c.lower() for c in _COLOUR.findall(text)}
    return (DECELERATING in intents and bool(intents - {DECELERATING})) or len(colours) > 1


def check_text_shows_the_truth(obs, cot, truth):
    text, gt = cot.text, obs.ground_truth
    kinds = named_kinds(text)
    if truth["mentioned"] is None:
        assert gt.critical_kind is None
    else:
        assert truth["mentioned"] == (gt.critical_kind in kinds)
        out_of_range = gt.distance_to_critical > 80.0 or (gt.distance_to_critical < 0 and not gt.blocking)
        assert truth["in_range"] == (not out_of_range)
    assert truth["hallucinated"] == (truth["phantom"] is not None)
    if truth["phantom"]:
        assert truth["phantom"] in kinds
        assert truth["phantom"] not in {a.kind for a in gt.actors}
    assert truth["contradiction"] == lexical_contradiction(text)
    if truth["light_stated"] is not None:
        stated = {c.lower() for c in _COLOUR.findall(text)}
        assert truth["light_stated"] in stated
        assert truth["light_wrong"] == (truth["light_stated"] != gt.light_state)


@pytest.mark.parametrize("cot_format", ["sentence", "qa"])
@given(seed=st.integers(0, 2**31), i=st.integers(0, 10_000),
       rates=st.tuples(*(st.floats(0.0, 1.0) for _ in range(4))))
@settings(max_examples=150, deadline=None)
def test_each_event_is_its_pinned_draw_below_its_rate(cot_format, seed, i, rates):
    miss, halluc, contra, light = rates
    model = ScriptedModel(miss_rate=miss, hallucination_rate=halluc, contradiction_rate=contra,
                          light_error_rate=light, cot_format=cot_format)
    obs = observation(i)
    cot = model.generate_cot(obs, step_rng(seed, obs.step, "cot"))
    truth = cot_truth(cot)
    u = step_rng(seed, obs.step, "cot").random(N_DRAWS)
    if truth["in_range"]:
        assert truth["mentioned"] == (not u[MISS] < miss)
    elif truth["mentioned"] is not None:
        assert truth["mentioned"] is False  # never mentioned beyond the range or behind
    assert truth["hallucinated"] == (u[HALLUCINATE] < halluc)
    assert truth["contradiction"] == (u[CONTRADICT] < contra)
    if truth["light_stated"] is not None:
        assert truth["light_wrong"] == (u[LIGHT_ERROR] < light)
    assert truth["stated_action"] == model.reading(cot).intent
    check_text_shows_the_truth(obs, cot, truth)


def within_binomial(count: int, n: int, p: float) -> bool:
    """``count`` is within 4.5 standard deviations of n·p (a false alarm has probability < 1e-5)."""
    return abs(count - n * p) <= 4.5 * np.sqrt(n * p * (1 - p)) + 1e-9


@pytest.mark.parametrize("cot_format", ["sentence", "qa"])
def test_observed_frequencies_match_the_options(cot_format):
    model = ScriptedModel(miss_rate=0.2, hallucination_rate=0.1, contradiction_rate=0.05, light_error_rate=0.3,
                          cot_format=cot_format)
    counts = dict(present=0, missed=0, hallucinated=0, contradiction=0, lights=0, wrong=0)
    n = 3000
    for i in range(n):
        obs = observation(i)
        cot = model.generate_cot(obs, step_rng(7, i, "cot"))
        truth = cot_truth(cot)
        check_text_shows_the_truth(obs, cot, truth)
        if truth["in_range"]:
            counts["present"] += 1
            counts["missed"] += not truth["mentioned"]
        if truth["light_stated"] is not None:
            counts["lights"] += 1
            counts["wrong"] += truth["light_wrong"]
        counts["hallucinated"] += truth["hallucinated"]
        counts["contradiction"] += truth["contradiction"]
    assert within_binomial(counts["missed"], counts["present"], 0.2)
    assert within_binomial(counts["hallucinated"], n, 0.1)
    assert within_binomial(counts["contradiction"], n, 0.05)
    assert within_binomial(counts["wrong"], counts["lights"], 0.3)
    assert counts["present"] > 2000 and counts["lights"] > 600


@pytest.mark.parametrize("cot_format", ["sentence", "qa"])
def test_rates_of_zero_and_one_are_never_and_always(cot_format):
    never = ScriptedModel(cot_format=cot_format)
    always = ScriptedModel(miss_rate=1.0, hallucination_rate=1.0, contradiction_rate=1.0, cot_format=cot_format)
    for i in range(len(SITUATIONS)):
        obs = observation(i)
        clean = cot_truth(never.generate_cot(obs, step_rng(1, i, "cot")))
        assert clean["mentioned"] == clean["in_range"] or clean["mentioned"] is None
        assert not (clean["hallucinated"] or clean["contradiction"] or clean["light_wrong"])
        assert clean["stated_action"] == clean["decision"]
        dirty = cot_truth(always.generate_cot(obs, step_rng(1, i, "cot")))
        assert not dirty["mentioned"] and dirty["hallucinated"] and dirty["contradiction"]


def test_a_missed_critical_feature_is_reasoned_without():
    model = ScriptedModel(miss_rate=1.0)
    obs = make_observation(kind="pedestrian", distance=10.0, speed=5.0)
    truth = cot_truth(model.generate_cot(obs, step_rng(0, 0, "cot")))
    assert truth["mentioned"] is False
    assert truth["stated_action"] in ("maintaining", "accelerating")  # the CoT saw a clear road
