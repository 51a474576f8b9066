"""Answers are checked against the schema: valid ones round-trip, anything else is invalid with a reason."""

from __future__ import annotations

import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vdb_labeler_ensemble.answer import ANSWER_FIELDS, InvalidAnswer, parse_answer_text, parse_reply
from vdb_labeler_ensemble.backends import Reply
from vladrivebench import LIGHT_COLOURS, STATED_ACTIONS

SLOTS = ["scene", "objects", "decision"]
valid_answers = st.fixed_dictionaries({
    "stated_action": st.sampled_from(STATED_ACTIONS),
    "target_mentioned": st.one_of(st.booleans(), st.none()),
    "mention_slot": st.sampled_from([*SLOTS, None]),
    "light_colour": st.sampled_from([*LIGHT_COLOURS, None]),
    "hallucination": st.booleans(),
    "contradiction": st.booleans(),
}).map(lambda a: {**a, "mention_slot": a["mention_slot"] if a["target_mentioned"] is True else None})


@settings(deadline=None)
@given(valid_answers, st.sampled_from(["{}", "```json\n{}\n```", "```\n{}\n```", "  {}  "]))
def test_valid_answers_round_trip(answer, wrapper):
    text = wrapper.replace("{}", json.dumps(answer))
    assert parse_answer_text(text, SLOTS) == answer


@settings(deadline=None)
@given(valid_answers, st.sampled_from(ANSWER_FIELDS))
def test_a_missing_field_is_never_filled_in(answer, missing):
    partial = {k: v for k, v in answer.items() if k != missing}
    with pytest.raises(InvalidAnswer, match=f"missing field {missing}"):
        parse_answer_text(json.dumps(partial), SLOTS)


bad_values = {
    "stated_action": st.one_of(st.text().filter(lambda t: t.strip().lower().replace(" ", "_") not in STATED_ACTIONS),
                               st.none(), st.integers()),
    "target_mentioned": st.one_of(st.text(), st.integers()),
    "light_colour": st.one_of(st.sampled_from(["amber", "blue", "off", ""]), st.integers(), st.booleans()),
    "hallucination": st.one_of(st.none(), st.text(), st.integers()),
    "contradiction": st.one_of(st.none(), st.sampled_from(["true", "false"]), st.floats(allow_nan=False)),
}


@settings(deadline=None)
@given(valid_answers, st.sampled_from(sorted(bad_values)), st.data())
def test_a_value_outside_its_domain_makes_the_answer_invalid(answer, name, data):
    bad = data.draw(bad_values[name])
    with pytest.raises(InvalidAnswer, match=name):
        parse_answer_text(json.dumps({**answer, name: bad}), SLOTS)


def test_spelling_variants_of_enums_are_normalised_not_guessed():
    base = {"target_mentioned": True, "mention_slot": None, "light_colour": "Green", "hallucination": False,
            "contradiction": False}
    parsed = parse_answer_text(json.dumps({**base, "stated_action": "Keep distance"}))
    assert parsed["stated_action"] == "keep_distance" and parsed["light_colour"] == "green"
    with pytest.raises(InvalidAnswer, match="stated_action is \"slowing\""):
        parse_answer_text(json.dumps({**base, "stated_action": "slowing"}))


def test_slots_and_consistency():
    base = {"stated_action": "none", "light_colour": None, "hallucination": False, "contradiction": False}
    with pytest.raises(InvalidAnswer, match="mention_slot is \"route\", expected one of scene, objects, decision"):
        parse_answer_text(json.dumps({**base, "target_mentioned": True, "mention_slot": "route"}), SLOTS)
    with pytest.raises(InvalidAnswer, match="mention_slot is 'objects' but target_mentioned is false"):
        parse_answer_text(json.dumps({**base, "target_mentioned": False, "mention_slot": "objects"}), SLOTS)
    one_sentence = parse_answer_text(json.dumps({**base, "target_mentioned": True, "mention_slot": "objects"}))
    assert one_sentence["mention_slot"] is None  # a one-sentence CoT has no slot; nothing is voted on


@pytest.mark.parametrize("text, reason", [
    ("decelerating", "not valid JSON"),
    ('{"stated_action": "none",', "not valid JSON"),
    ("[1, 2]", "must be a JSON object, got list"),
    ("I'm sorry, I can't comply with that.", "not valid JSON"),
])
def test_malformed_text_is_invalid_with_a_reason(text, reason):
    with pytest.raises(InvalidAnswer, match=reason):
        parse_answer_text(text)


def test_refusals_and_cut_off_answers():
    with pytest.raises(InvalidAnswer, match="^refused: no"):
        parse_reply(Reply(None, refusal="no"))
    with pytest.raises(InvalidAnswer, match="empty answer .*raise \\?max_tokens=N"):
        parse_reply(Reply(None, finish="length"))
    with pytest.raises(InvalidAnswer, match="not valid JSON.*cut off by the output-token limit"):
        parse_reply(Reply('{"stated_action": "dec', finish="MAX_TOKENS"))
