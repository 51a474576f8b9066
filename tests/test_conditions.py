"""Conditions: the paper's texts, the derived kinds (shuffle, repeat, ablation, harvest), files and errors."""

from __future__ import annotations

import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vladrivebench import _builtins as core_plugin
from vladrivebench import hookimpl
from vladrivebench._engine.registry import Registry
from vladrivebench._intervention.conditions import (
    PAPER_TEXTS,
    ConditionError,
    ConditionLibrary,
    RepeatCondition,
    StepResolver,
    TextCondition,
    build_library,
    builtin_conditions,
    harvest_braking_cot,
    injection_problem,
    load_conditions_file,
    repeat_token,
    shuffle_words,
    text_problem,
)
from vladrivebench.errors import UnknownNameError
from vladrivebench.records import CoT, CoTFormat

QA = CoTFormat("slots", ("scene", "objects", "decision"))
SENTENCE = CoTFormat("sentence")
OWN_QA = CoT("own scene own objects own decision",
             {"scene": "own scene", "objects": "own objects", "decision": "own decision"})
OWN_SENTENCE = CoT("Keep the lane and maintain speed.")
HARVEST_QA = {"origbrake": {"scene": "The scene depicts a road with one car ahead.",
                            "objects": "Car at <0.00, 30.00> stationary.",
                            "decision": "You should keep and lanefollow."}}


def library() -> ConditionLibrary:
    return ConditionLibrary(builtin_conditions())


def resolver(fmt=QA, own=OWN_QA, harvested=None, count_tokens=None) -> StepResolver:
    kwargs = {"count_tokens": count_tokens} if count_tokens else {}
    return StepResolver(library(), fmt, own, harvested if harvested is not None else HARVEST_QA,
                        model_name="fake", **kwargs)


def test_paper_sentences_are_verbatim():
    r = resolver(SENTENCE, OWN_SENTENCE, {"origbrake": "Slow down."})
    assert r("accel") == "Accelerate to maintain speed since the road ahead is clear and no obstacles are present."
    assert r("pedestrian") == "Stop for the pedestrian in the lane because it is blocking the lane."
    assert r("car") == "Stop for the stationary car in the lane because it is blocking the lane."


def test_paper_slot_texts_map_to_the_models_slots_in_order():
    r = resolver()
    ped = r("pedestrian")
    assert list(ped) == ["scene", "objects", "decision"]
    assert ped["objects"] == "Pedestrian at <0.00, 10.00> standing in the lane, blocking the path."
    assert "showing green" in ped["scene"] and "showing red" in r("red-light")["scene"]
    assert r("red-light")["scene"] == ped["scene"].replace("showing green", "showing red")


def test_selfsplice_is_the_models_own_cot():
    assert resolver()("selfsplice") == OWN_QA.slots
    assert resolver(SENTENCE, OWN_SENTENCE)("selfsplice") == OWN_SENTENCE.text


def test_origbrake_shuffle_uses_seeds_42_43_44_per_slot():
    shuffled = resolver()("origbrake-shuffle")
    for seed, slot in zip((42, 43, 44), ("scene", "objects", "decision"), strict=True):
        assert shuffled[slot] == shuffle_words(HARVEST_QA["origbrake"][slot], seed)


def test_depicts_all_matches_the_token_count_of_each_origbrake_slot():
    out = resolver()("depicts-all")
    for slot, text in HARVEST_QA["origbrake"].items():
        assert len(out[slot].split()) == len(text.split())
        assert set(out[slot].split()) == {"depicts"}


def test_depicts_all_uses_the_models_tokenizer():
    # a tokenizer that counts characters / 4, and "depicts" as 2 tokens
    def chars(text: str) -> int:
        return max(1, len(text) // 4)

    out = resolver(count_tokens=chars)("depicts-all")
    for slot, text in HARVEST_QA["origbrake"].items():
        assert len(out[slot].split()) == max(1, round(chars(text) / chars("depicts")))


@given(st.integers(min_value=1, max_value=400))
@settings(deadline=None)
def test_depicts_n_repeats_n_times_in_every_slot(n):
    out = resolver()(f"depicts-{n}")
    assert all(text.split() == ["depicts"] * n for text in out.values())


def test_ablation_swaps_one_slot_and_keeps_the_others():
    out = resolver()("origbrake-swap-objects")
    assert out == {**HARVEST_QA["origbrake"], "objects": OWN_QA.slots["objects"]}


def test_ablation_needs_a_slotted_model():
    with pytest.raises(ConditionError, match="one sentence"):
        resolver(SENTENCE, OWN_SENTENCE, {"origbrake": "x"})("origbrake-swap-scene")


def test_ablation_of_an_unknown_slot_names_the_slots():
    lib = library()
    lib.add(TextCondition("weird-swap", slots=("a", "b", "c")))
    with pytest.raises(ConditionError, match="takes slots scene, objects, decision"):
        StepResolver(lib, QA, OWN_QA, HARVEST_QA)("pedestrian-swap-lights")


def test_unknown_condition_suggests_close_names():
    with pytest.raises(UnknownNameError, match="did you mean 'pedestrian'"):
        library().get("pedestrain")


def test_origbrake_paper_has_no_sentence_form():
    with pytest.raises(ConditionError, match="no one-sentence text"):
        resolver(SENTENCE, OWN_SENTENCE)("origbrake-paper")


def test_unharvested_origbrake_is_an_error():
    with pytest.raises(ConditionError, match="not been harvested"):
        resolver(harvested={})("origbrake")


def test_per_step_follows_dependencies():
    lib = library()
    assert lib.is_per_step("selfsplice")
    assert not lib.is_per_step("origbrake-shuffle")
    assert lib.is_per_step("origbrake-swap-scene")
    assert lib.harvest_names(["depicts-all", "pedestrian"]) == ["origbrake"]


def test_cycles_are_reported():
    lib = ConditionLibrary([RepeatCondition("a", "x", match="b"), RepeatCondition("b", "x", match="a")])
    with pytest.raises(ConditionError, match="cycle: a -> b -> a"):
        lib.closure(["a"])


@given(st.lists(st.text(alphabet="abcdefgh ", min_size=1, max_size=8), min_size=1, max_size=30),
       st.integers(min_value=0, max_value=2**32 - 1))
@settings(deadline=None)
def test_shuffle_is_a_fixed_permutation_of_the_words(words, seed):
    text = " ".join(words)
    once, again = shuffle_words(text, seed), shuffle_words(text, seed)
    assert once == again
    assert sorted(once.split()) == sorted(text.split())


@given(st.text(min_size=1, max_size=12).filter(lambda t: t.split() == [t]), st.integers(1, 200))
@settings(deadline=None)
def test_repeat_token_has_count_words(token, count):
    assert repeat_token(token, count).split() == [token] * count


def test_text_problem_rejects_empty_and_control_characters():
    assert text_problem("fine text") is None
    assert text_problem("  ") == "is empty"
    assert "U+0000" in text_problem("bad\x00text")
    assert "string" in text_problem(3)


def test_injection_problem_checks_shape_and_token_limit():
    limited = CoTFormat("sentence", max_tokens=5)
    assert injection_problem("one two three", limited, lambda t: len(t.split())) is None
    assert "6 tokens" in injection_problem("a b c d e f", limited, lambda t: len(t.split()))
    assert "one text per slot" in injection_problem("text", QA, len)
    assert "expected scene, objects, decision" in injection_problem({"scene": "x"}, QA, len)
    assert "slot 'objects' is empty" in injection_problem({"scene": "x", "objects": "", "decision": "y"}, QA, len)


def test_harvest_takes_the_hardest_brake_earliest_on_ties():
    steps = [(0, {"text": "a"}, {"brake": 0.0}), (1, {"text": "b"}, {"brake": 0.4}),
             (2, {"text": "c"}, {"brake": 0.9}), (3, {"text": "d"}, {"brake": 0.9})]
    got = harvest_braking_cot(steps, SENTENCE, "ep")
    assert (got.injection, got.step, got.brake) == ("c", 2, 0.9)
    assert harvest_braking_cot(steps[:1], SENTENCE, "ep") is None
    slotted = harvest_braking_cot([(5, {"text": "x", "slots": {"scene": "s", "objects": "o", "decision": "d"}},
                                    {"brake": 1.0})], QA, "ep")
    assert slotted.injection == {"scene": "s", "objects": "o", "decision": "d"}


def test_builtins_register_through_the_hook():
    registry = Registry([("core", core_plugin)], entry_points=False)
    names = registry.names("condition")
    assert {"selfsplice", "accel", "pedestrian", "car", "animal", "red-light", "origbrake",
            "origbrake-shuffle", "depicts-all", "depicts-150"} <= set(names)
    assert build_library(registry).names() == names


def test_a_plugin_adds_a_condition_through_the_hook():
    class Plugin:
        @hookimpl
        def register_conditions(self, register):
            register("cyclist", lambda: TextCondition("cyclist", "Stop for the cyclist.", intent="brake"))

    registry = Registry([("core", core_plugin), ("mine", Plugin())], entry_points=False)
    lib = build_library(registry)
    assert lib.sources["cyclist"] == "plugin mine"
    assert StepResolver(lib, SENTENCE, OWN_SENTENCE)("cyclist") == "Stop for the cyclist."


def test_a_plugin_condition_with_the_wrong_name_is_refused():
    class Plugin:
        @hookimpl
        def register_conditions(self, register):
            register("cyclist", lambda: TextCondition("bicycle", "Stop."))

    with pytest.raises(ConditionError, match="calls itself 'bicycle'"):
        build_library(Registry([("mine", Plugin())], entry_points=False))


# -- files ----------------------------------------------------------------------------------------------
FILE_TOML = """
[conditions.cyclist]
intent = "brake"
sentence = "Stop for the cyclist in the lane because it is blocking the lane."
slots = ["The scene depicts a street.", "Cyclist at <0.00, 10.00> in the lane.", "You should slow down and stop."]

[conditions.stop-40]
kind = "repeat"
token = "stop"
count = 40

[conditions.car-shuffle]
kind = "shuffle"
base = "car"
seed = 7

[conditions.car-own-decision]
kind = "ablation"
base = "car"
slot = "decision"

[conditions.pedestrian]
replace = true
intent = "brake"
sentence = "Brake for the person."
"""


def test_conditions_file_toml(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text(FILE_TOML)
    registry = Registry([("core", core_plugin)], entry_points=False)
    lib = build_library(registry, [path])
    r = StepResolver(lib, QA, OWN_QA, HARVEST_QA)
    assert r("cyclist")["objects"] == "Cyclist at <0.00, 10.00> in the lane."
    assert r("stop-40")["scene"].split() == ["stop"] * 40
    assert r("car-own-decision") == {**r("car"), "decision": "own decision"}
    assert r("car-shuffle")["scene"] == shuffle_words(PAPER_TEXTS["car"]["slots"][0], 7)
    assert r("car-shuffle")["objects"] == shuffle_words(PAPER_TEXTS["car"]["slots"][1], 8)
    with pytest.raises(ConditionError, match="'pedestrian' has no per-slot texts"):
        r("pedestrian")  # replaced by a sentence-only text
    assert StepResolver(lib, SENTENCE, OWN_SENTENCE)("pedestrian") == "Brake for the person."
    assert lib.sources["cyclist"] == f"file {path}"


def test_conditions_file_json(tmp_path):
    path = tmp_path / "mine.json"
    path.write_text(json.dumps({"conditions": {"go": {"intent": "accelerate", "sentence": "Speed up now."}}}))
    (cond, replace), = load_conditions_file(path)
    assert (cond.name, cond.intent, cond.sentence, replace) == ("go", "accelerate", "Speed up now.", False)


def test_a_file_condition_may_not_silently_replace_a_builtin(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text('[conditions.pedestrian]\nsentence = "x y"\n')
    with pytest.raises(ConditionError, match="already defined by plugin core .*replace = true"):
        build_library(Registry([("core", core_plugin)], entry_points=False), [path])


@pytest.mark.parametrize("body, message", [
    ('[conditions.a]\nkind = "repeat"\ntoken = "x"\ncount = "ten"\n',
     "condition 'a': field 'count' must be an integer between 1 and 100000, got 'ten'"),
    ('[conditions.a]\nkind = "repeat"\ntoken = "x"\n', "exactly one of 'count'"),
    ('[conditions.a]\nkind = "repeat"\ntoken = "two words"\ncount = 3\n', "one word"),
    ('[conditions.a]\nkind = "teleport"\n', "field 'kind' must be one of text, harvest"),
    ('[conditions.a]\nsentence = "x"\ncolour = "red"\n', "unknown field 'colour' for kind 'text'"),
    ('[conditions.a]\nintent = "swerve"\nsentence = "x"\n', "field 'intent' must be one of brake"),
    ('[conditions.a]\nintent = "brake"\n', "needs 'sentence'"),
    ('[conditions.a]\nsentence = ""\n', "field 'sentence' is empty"),
    ('[conditions.a]\nslots = ["x", ""]\n', "field 'slots[1]' is empty"),
    ('[conditions.a]\nslots = 3\n', "field 'slots' must be a table"),
    ('[conditions.a]\nkind = "shuffle"\n', "missing field 'base'"),
    ('[conditions.a]\nkind = "shuffle"\nbase = "car"\nseeds = [-1]\n', "field 'seeds' must be an integer"),
    ('[conditions."a b"]\nsentence = "x"\n', "names may hold"),
    ("[other]\nx = 1\n", "unknown top-level key 'other'"),
    ("[conditions]\n", "non-empty 'conditions' table"),
    ("[conditions.a\n", "not valid TOML"),
])
def test_bad_condition_files_give_one_line_naming_file_condition_and_field(tmp_path, body, message):
    path = tmp_path / "bad.toml"
    path.write_text(body)
    with pytest.raises(ConditionError) as info:
        load_conditions_file(path)
    text = str(info.value)
    assert "\n" not in text and str(path) in text
    assert message in text


def test_missing_conditions_file(tmp_path):
    with pytest.raises(ConditionError, match="no such file"):
        load_conditions_file(tmp_path / "nope.toml")
