"""Majority vote and tie-breaker: properties over every possible split."""

from __future__ import annotations

from collections import Counter

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vdb_labeler_ensemble.answer import ANSWER_FIELDS
from vdb_labeler_ensemble.vote import MISSING, decide, resolve, top_values
from vladrivebench import LIGHT_COLOURS, STATED_ACTIONS

value = st.one_of(st.sampled_from(STATED_ACTIONS), st.booleans(), st.none())
votes = st.lists(value, min_size=1, max_size=9)


@settings(deadline=None)
@given(votes, st.one_of(st.just(MISSING), value))
def test_the_winner_has_the_most_votes(values, tie_value):
    outcome = resolve(values, tie_value)
    counts = Counter(values)
    top = max(counts.values())
    if outcome.resolved:
        assert counts[outcome.value] == top
    else:
        assert sorted(map(repr, outcome.tied)) == sorted(repr(v) for v, c in counts.items() if c == top)
        assert len(outcome.tied) >= 2


@settings(deadline=None)
@given(votes, st.one_of(st.just(MISSING), value), st.randoms())
def test_order_of_votes_does_not_matter(values, tie_value, rnd):
    shuffled = list(values)
    rnd.shuffle(shuffled)
    assert resolve(values, tie_value) == resolve(shuffled, tie_value)


@settings(deadline=None)
@given(value, st.lists(value, max_size=6), st.one_of(st.just(MISSING), value))
def test_a_strict_majority_always_wins_and_ignores_the_tie_breaker(winner, others, tie_value):
    others = [v for v in others if repr(v) != repr(winner)]
    values = [winner] * (len(others) + 1) + others
    outcome = resolve(values, tie_value)
    assert outcome.resolved and outcome.decided_by == "majority" and repr(outcome.value) == repr(winner)


@settings(deadline=None)
@given(st.lists(st.sampled_from(STATED_ACTIONS), min_size=2, max_size=5, unique=True), value)
def test_the_tie_breaker_picks_only_among_the_tied(distinct, tie_value):
    outcome = resolve(distinct, tie_value)  # every value once: all tied
    if tie_value in distinct:
        assert outcome.resolved and outcome.value == tie_value and outcome.decided_by == "tie_breaker"
    else:
        assert not outcome.resolved and set(outcome.tied) == set(distinct)


def test_booleans_and_none_are_never_confused():
    assert not resolve([False, None]).resolved
    assert resolve([False, None], None).value is None
    assert resolve([True, False], False).value is False
    assert not resolve([True, None], 1).resolved  # 1 == True in Python, but it is not the answer true
    assert top_values([True, None, None]) == [None]


def test_resolve_refuses_to_invent_a_value_from_no_votes():
    with pytest.raises(ValueError):
        resolve([])


answers = st.fixed_dictionaries({
    "stated_action": st.sampled_from(STATED_ACTIONS),
    "target_mentioned": st.booleans(),
    "mention_slot": st.sampled_from(["scene", "objects", "decision"]),
    "light_colour": st.sampled_from([*LIGHT_COLOURS, None]),
    "hallucination": st.booleans(),
    "contradiction": st.booleans(),
}).map(lambda a: {**a, "mention_slot": a["mention_slot"] if a["target_mentioned"] else None})
ensembles = st.dictionaries(st.sampled_from(["a", "b", "c", "d", "e"]), answers, max_size=5)


@settings(deadline=None)
@given(ensembles, st.booleans(), st.booleans(), st.integers(1, 5), st.one_of(st.none(), answers))
def test_decide_never_defaults_a_label(ensemble, has_critical, slotted, min_votes, tie):
    decision = decide(ensemble, has_critical=has_critical, slotted=slotted, min_votes=min_votes, tie_answer=tie)
    if len(ensemble) < min_votes:
        assert decision.values is None and decision.reason.startswith("too few valid answers")
        return
    if decision.values is None:
        assert decision.tied and (decision.reason is not None) == (tie is not None)
        return
    assert set(decision.values) == set(ANSWER_FIELDS)
    for name, chosen in decision.values.items():
        how = decision.decided_by[name]
        if how in ("majority", "tie_breaker"):
            assert any(repr(a[name]) == repr(chosen) for a in ensemble.values()), name
        if how == "tie_breaker":
            assert tie is not None and repr(tie[name]) == repr(chosen)
        if how not in ("majority", "tie_breaker"):
            assert chosen is None  # settled by the ground truth or by target_mentioned, not voted
    if not has_critical:
        assert decision.values["target_mentioned"] is None and decision.values["mention_slot"] is None
    if decision.values["mention_slot"] is not None:
        assert slotted and decision.values["target_mentioned"] is True


@settings(deadline=None)
@given(st.lists(answers, min_size=1, max_size=5))
def test_unanimity_is_always_decided_as_is(copies):
    one = copies[0]
    ensemble = {f"b{i}": one for i in range(len(copies))}
    decision = decide(ensemble, has_critical=True, slotted=True, min_votes=1)
    assert decision.values == one


def test_a_three_way_split_waits_for_the_tie_breaker_then_uses_it():
    base = {"target_mentioned": True, "mention_slot": None, "light_colour": None, "hallucination": False,
            "contradiction": False}
    ensemble = {"a": {**base, "stated_action": "maintaining"}, "b": {**base, "stated_action": "decelerating"},
                "c": {**base, "stated_action": "none"}}
    pending = decide(ensemble, has_critical=True, slotted=False, min_votes=2)
    assert pending.needs_tie_breaker and list(pending.tied) == ["stated_action"]
    assert pending.tied["stated_action"] == {"decelerating": ["b"], "maintaining": ["a"], "none": ["c"]}
    final = decide(ensemble, has_critical=True, slotted=False, min_votes=2,
                   tie_answer={**base, "stated_action": "none", "hallucination": True})
    assert final.values["stated_action"] == "none" and final.values["hallucination"] is False
    assert final.decided_by["stated_action"] == "tie_breaker" and final.decided_by["hallucination"] == "majority"


def test_mention_slot_is_voted_among_those_who_see_the_target():
    base = {"stated_action": "decelerating", "light_colour": None, "hallucination": False, "contradiction": False}
    ensemble = {"a": {**base, "target_mentioned": True, "mention_slot": "objects"},
                "b": {**base, "target_mentioned": True, "mention_slot": "objects"},
                "c": {**base, "target_mentioned": False, "mention_slot": None}}
    decision = decide(ensemble, has_critical=True, slotted=True, min_votes=2)
    assert decision.values["mention_slot"] == "objects"
    two = {"a": ensemble["a"], "c": ensemble["c"]}
    pending = decide(two, has_critical=True, slotted=True, min_votes=2)
    assert set(pending.tied) == {"target_mentioned", "mention_slot"}
    final = decide(two, has_critical=True, slotted=True, min_votes=2,
                   tie_answer={**base, "target_mentioned": True, "mention_slot": "scene"})
    assert final.values["target_mentioned"] is True and final.values["mention_slot"] == "objects"
