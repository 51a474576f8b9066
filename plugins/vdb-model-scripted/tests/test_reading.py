"""The keyword reader behind the CoT state: intents, entities, placed objects, digests."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st
from vdb_model_scripted.reading import (
    ACCELERATING,
    DECELERATING,
    INTENTS,
    KEEP_DISTANCE,
    MAINTAINING,
    NO_INTENT,
    CoTReading,
    StatedObject,
    read_intent,
    read_sentence,
    read_slots,
    stated_intents,
)
from vladrivebench.intervention import PAPER_TEXTS

ALPAMAYO_EXPECTED = {"accel": ACCELERATING, "pedestrian": DECELERATING, "car": DECELERATING}
ORION_EXPECTED = {"accel": ACCELERATING, "pedestrian": DECELERATING, "animal": DECELERATING,
                  "red-light": DECELERATING, "car": MAINTAINING, "origbrake-paper": MAINTAINING}


@pytest.mark.parametrize("name", sorted(ALPAMAYO_EXPECTED))
def test_the_papers_alpamayo_texts(name):
    reading = read_sentence(PAPER_TEXTS[name]["sentence"])
    assert reading.intent == ALPAMAYO_EXPECTED[name]
    if name != "accel":
        assert reading.referent == name


@pytest.mark.parametrize("name", sorted(ORION_EXPECTED))
def test_the_papers_orion_texts(name):
    scene, objects, decision = PAPER_TEXTS[name]["slots"]
    reading = read_slots({"scene": scene, "objects": objects, "decision": decision})
    assert reading.intent == ORION_EXPECTED[name]


def test_orion_coordinates_are_read_right_then_forward():
    reading = read_slots({"objects": "Pedestrian at <0.00, 10.00> standing in the lane, blocking the path."})
    assert reading.objects == (StatedObject("pedestrian", 0.0, 10.0),)
    assert read_slots({"objects": "Car at <-0.00, 30.00> directly in front"}).objects[0].kind == "car"


@pytest.mark.parametrize("text, intent", [
    ("Stop for the pedestrian in the lane because it is blocking the lane.", DECELERATING),
    ("Accelerate to maintain speed since the road ahead is clear.", ACCELERATING),
    ("Keep distance to the lead vehicle because it is slowing down.", KEEP_DISTANCE),
    ("Follow the lead car at a safe distance.", KEEP_DISTANCE),
    ("Keep the current speed and stay in the lane.", MAINTAINING),
    ("There is no need to slow down, so maintain speed.", MAINTAINING),
    ("Do not stop here; continue through the intersection.", MAINTAINING),
    ("Continue past the stop sign.", MAINTAINING),
    ("The stop sign ahead.", DECELERATING),  # no action phrase: the stop sign is a cue
    ("The light ahead is red.", DECELERATING),
    ("A car is blocking the lane.", DECELERATING),
    ("Resume speed after the intersection.", ACCELERATING),
    ("depicts depicts depicts", NO_INTENT),
    ("The road is dry and well-maintained.", NO_INTENT),
    ("", NO_INTENT),
])
def test_sentence_intents(text, intent):
    assert read_sentence(text).intent == intent


def test_the_decision_slot_dominates_then_objects_then_scene():
    assert read_slots({"scene": "The ego should accelerate now.", "objects": "",
                       "decision": "You should slow down and stop."}).intent == DECELERATING
    assert read_slots({"scene": "The ego should accelerate now.", "objects": "requiring the ego to stop",
                       "decision": "depicts depicts"}).intent == DECELERATING
    assert read_slots({"scene": "The ego should accelerate now.", "decision": ""}).intent == ACCELERATING
    # a stated obstacle and no decision: stop
    assert read_slots({"objects": "Animal at <0.00, 10.00> placed in the lane, obstructing the path."}
                      ).intent == DECELERATING
    assert read_slots({"scene": "The scene depicts a street.", "objects": "", "decision": ""}).intent == NO_INTENT


ACTION_PHRASES = [("Stop", DECELERATING), ("Brake", DECELERATING), ("Slow down", DECELERATING),
                  ("Yield", DECELERATING), ("Accelerate", ACCELERATING), ("Speed up", ACCELERATING),
                  ("Resume", ACCELERATING), ("Maintain speed", MAINTAINING), ("Keep", MAINTAINING),
                  ("Continue", MAINTAINING), ("Keep distance", KEEP_DISTANCE)]


@given(phrase=st.sampled_from(ACTION_PHRASES), rest=st.text(max_size=80))
def test_the_leading_phrase_decides(phrase, rest):
    words, intent = phrase
    assert read_sentence(f"{words}. {rest}").intent == intent
    assert read_slots({"decision": f"{words}. {rest}", "scene": rest, "objects": rest}).intent == intent


@given(text=st.text(max_size=200))
def test_any_text_has_a_known_intent_and_a_stable_digest(text):
    reading = read_sentence(text)
    assert reading.intent in INTENTS
    assert read_sentence(text).digest() == reading.digest()
    assert read_intent(text) == (stated_intents(text)[0] if stated_intents(text) else None)


@given(a=st.sampled_from(INTENTS), b=st.sampled_from(INTENTS), ref=st.sampled_from([None, "car", "pedestrian"]),
       x=st.floats(-50, 50, allow_nan=False), y=st.floats(-50, 50, allow_nan=False))
def test_digests_differ_exactly_when_readings_differ(a, b, ref, x, y):
    one = CoTReading(a, ref, (StatedObject("car", x, y),))
    other = CoTReading(b, ref, (StatedObject("car", x, y),))
    assert (one.digest() == other.digest()) == (one == other)
    moved = CoTReading(a, ref, (StatedObject("car", x, y + 1.0),))
    assert moved.digest() != one.digest()
