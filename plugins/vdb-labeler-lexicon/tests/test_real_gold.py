"""The lexicon labeler on real CoTs: the hand-labelled gold set of real outputs (tests/data/real_gold), the
1,181 public Alpamayo-R1 traces, the phrasings real models use, and the clause rules as properties."""

from __future__ import annotations

import ast
import csv
import hashlib
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vdb_labeler_lexicon.labeler import LexiconLabeler
from vladrivebench import LabelInput
from vladrivebench.labels import PROPERTIES, agreement, read_jsonl

REAL = Path(__file__).resolve().parents[3] / "tests" / "data" / "real_gold"
SEED = "vdb-real-gold-1"
STYLES = ("alpamayo", "orion", "narration", "qa")
REPORTED_STYLES = ("alpamayo", "orion", "narration")  # "qa" (9 long model answers) is reported, not held to 0.9
LABELER = LexiconLabeler()


def split_of(ident: str) -> str:
    """The documented split (SOURCES.md): dev when sha256(seed:id) is even."""
    return "dev" if int(hashlib.sha256(f"{SEED}:{ident}".encode()).hexdigest(), 16) % 2 == 0 else "test"


@pytest.fixture(scope="module")
def real_items():
    return read_jsonl(REAL / "real_cots.jsonl", need_labels=True)


def half_agreement(items, half, style=None):
    chosen = [e for e in items if e.extra["split"] == half and (style is None or e.extra["style"] == style)]
    return agreement({e.id: e.labels for e in chosen}, {e.id: LABELER.label(e.item) for e in chosen})


def test_real_gold_set_is_large_sourced_and_split_by_the_seed(real_items):
    assert len(real_items) >= 150
    assert {e.extra["style"] for e in real_items} == set(STYLES)
    for entry in real_items:
        assert entry.extra["split"] == split_of(entry.id), entry.id
        assert entry.extra["source"].startswith("github:"), entry.id
        assert set(entry.stated) == set(PROPERTIES), entry.id  # every property labelled by hand
    halves = {e.extra["split"] for e in real_items}
    assert halves == {"dev", "test"}


def test_kappa_on_the_test_half_is_at_least_0_9_on_every_property(real_items):
    report = half_agreement(real_items, "test")
    assert report.compared >= 60
    for prop in report.properties:
        if prop.prop == "mention_slot":
            assert prop.agreement == 1.0 or prop.n == 0, prop
            continue
        assert prop.kappa is not None and prop.kappa >= 0.9, (prop.prop, prop.kappa, prop.confusion)


@pytest.mark.parametrize("style", REPORTED_STYLES)
def test_each_style_of_the_test_half_agrees(real_items, style):
    report = half_agreement(real_items, "test", style)
    for prop in report.properties:
        if prop.n:
            assert prop.agreement >= 0.9, (style, prop.prop, prop.confusion)
            assert prop.kappa is None or prop.kappa >= 0.9, (style, prop.prop, prop.kappa)


def alpamayo_traces():
    with (REAL / "alpamayo_r1_traces.csv").open(encoding="utf-8") as fh:
        return [ast.literal_eval(row["reasoning_trace"])[0][0] for row in csv.DictReader(fh)]


def test_false_contradiction_rate_on_real_alpamayo_traces_is_at_most_1_percent():
    traces = alpamayo_traces()
    assert len(traces) == 1181
    flagged = [t for t in traces if LABELER.label(LabelInput(text=t)).contradiction]
    assert len(flagged) / len(traces) <= 0.01, flagged[:5]  # none of them contradicts itself (SOURCES.md)


# -- real phrasing ------------------------------------------------------------------------------------------
GREEN = {"critical_kind": "traffic_light", "light_state": "green",
         "actors": [{"kind": "traffic_light", "position": [30.0, 4.0], "speed": 0.0, "state": "green"}]}
LEAD_STOPPED = {"critical_kind": "car", "critical_position": [10.0, 0.0],
                "actors": [{"kind": "car", "position": [10.0, 0.0], "speed": 0.0}]}
LEAD_MOVING = {"critical_kind": "car", "critical_position": [15.0, 0.0],
               "actors": [{"kind": "car", "position": [15.0, 0.0], "speed": 6.0}]}
CYCLIST = {"actors": [{"kind": "cyclist", "position": [10.0, 0.0], "speed": 3.0}]}

PHRASES = [  # text, context, stated action, light colour, hallucination, contradiction
    ("We slow down for the pedestrian ahead.", {}, "decelerating", None, None, False),
    ("I will keep my speed since the road is clear.", {}, "maintaining", None, None, False),
    ("The ego vehicle moves off as the signal changes to green.", GREEN, "accelerating", "green", False, False),
    ("The car moves off as the light turns green.", GREEN, "accelerating", "green", False, False),
    ("Ease off for the cyclist ahead.", CYCLIST, "decelerating", None, False, False),
    ("Gradually slowing as the lead car brakes.", LEAD_MOVING, "decelerating", None, False, False),
    ("Stay put until the crossing is clear.", {}, "decelerating", None, False, False),
    ("Creep forward to get a better view of the junction.", {}, "accelerating", None, False, False),
    ("Adapt speed for the right curve ahead.", {}, "decelerating", None, False, False),
    ("Adapt speed to maintain a safe distance from the lead vehicle", LEAD_MOVING, "keep_distance", None, False, False),
    ("The green protected-left light allows us to proceed.", GREEN, "maintaining", "green", False, False),
    ("The signal is green, so proceed through the intersection.", GREEN, "maintaining", "green", False, False),
    ("The lamp shows green; keep going.", GREEN, "maintaining", "green", False, False),
    ("Accelerate through the intersection due to the green straight traffic light", GREEN, "accelerating", "green",
     False, False),
    ("Keep speed because the truck ahead is coming to a stop.", LEAD_STOPPED, "maintaining", None, False, False),
    ("Proceed only if the crossing is clear.", {}, "none", None, False, False),
    ("Keep the current speed and prepare to stop.", {}, "maintaining", None, False, False),
    ("Nothing here requires a stop, so keep going.", {}, "maintaining", None, False, False),
    ("Pull away from a standstill stop as the light turns green.", GREEN, "accelerating", "green", False, False),
    ("Stop to keep distance to the lead vehicle.", LEAD_STOPPED, "decelerating", None, False, False),
    ("Resume speed from stop since the crossing vehicle has cleared the intersection.",
     {"actors": [{"kind": "car", "position": [12.0, -14.0], "speed": 6.0}]}, "accelerating", None, False, False),
    ("Slow down due to the lead car ahead braking and approaching a stop, requiring a safe following gap.",
     LEAD_MOVING, "decelerating", None, False, False),
    ("Keep speed due to the lead car ahead maintaining a steady pace with a stable gap.", LEAD_STOPPED,
     "maintaining", None, True, False),
    ("Keep distance to the lead vehicle because it is stopped ahead.", LEAD_MOVING, "keep_distance", None, True,
     False),
    ("The ego vehicle is going straight. The ego vehicle is not moving.", {}, "decelerating", None, False, False),
    ("The ego vehicle proceeds along the current road, coming to a halt at the traffic light intersection.",
     GREEN, "maintaining", None, False, False),
    ("Nudge left to pass the construction vehicle on the right", LEAD_STOPPED, "none", None, False, False),
    ("Keep lane to continue driving since the railroad crossing signals are inactive", {}, "maintaining", None,
     False, False),
]


@pytest.mark.parametrize(("text", "context", "action", "colour", "hallucination", "contradiction"), PHRASES)
def test_real_phrasing(text, context, action, colour, hallucination, contradiction):
    labels = LABELER.label(LabelInput(text=text, context=context))
    assert labels.stated_action == action, labels.details
    assert labels.light_colour == colour
    if hallucination is not None:
        assert labels.hallucination == hallucination, labels.details
    assert labels.contradiction == contradiction, labels.details


# -- the clause rules as properties ----------------------------------------------------------------------------
COMMANDS = {"slow down": "decelerating", "brake": "decelerating", "stop": "decelerating", "yield": "decelerating",
            "accelerate": "accelerating", "speed up": "accelerating", "maintain speed": "maintaining",
            "keep the current speed": "maintaining", "proceed": "maintaining", "continue": "maintaining",
            "keep a safe distance": "keep_distance", "adapt speed": "decelerating", "ease off": "decelerating"}
commands = st.sampled_from(sorted(COMMANDS))
reasons = st.sampled_from(["", " for the pedestrian", " because the light is red", " due to the lead vehicle ahead",
                           " at the intersection", " since the road ahead is clear"])
conditions = st.sampled_from(["if the light turns red", "if a pedestrian steps out", "if the lead car brakes",
                              "unless the crossing is clear", "in case the truck pulls out"])
egos = st.sampled_from(["The ego vehicle", "We", "I", "The car", "The ego car"])
narrated = st.sampled_from(["slows down", "stops", "accelerates", "keeps going", "moves off", "continues",
                            "brakes", "yields", "eases off"])


@settings(max_examples=200, deadline=None)
@given(command=commands, reason=reasons, negation=st.sampled_from(["Do not {c}", "There is no need to {c}",
                                                                     "Never {c}", "We should not {c}"]))
def test_negating_a_command_never_yields_that_command(command, reason, negation):
    labels = LABELER.label(LabelInput(text=negation.format(c=command) + reason + "."))
    assert labels.stated_action != COMMANDS[command], labels.details


@settings(max_examples=200, deadline=None)
@given(command=commands, reason=reasons, condition=conditions)
def test_a_leading_condition_never_yields_a_current_command(command, reason, condition):
    labels = LABELER.label(LabelInput(text=f"{condition.capitalize()}, {command}{reason}."))
    assert labels.stated_action == "none", labels.details
    assert not labels.contradiction


@settings(max_examples=200, deadline=None)
@given(ego=egos, verb=narrated, reason=reasons)
def test_narrating_the_ego_never_yields_a_hallucinated_car(ego, verb, reason):
    verb = {"I": verb.replace("es ", "e ").removesuffix("s"), "We": verb.replace("es ", "e ").removesuffix("s")}.get(
        ego, verb)
    labels = LABELER.label(LabelInput(text=f"{ego} {verb}{reason.replace('the lead vehicle', 'the light')}.",
                                      context={"actors": []}))
    assert not any("car" in h for h in labels.details.get("hallucinated", [])), labels.details


@settings(max_examples=200, deadline=None)
@given(first=commands, second=commands)
def test_a_purpose_clause_is_one_decision_not_a_contradiction(first, second):
    labels = LABELER.label(LabelInput(text=f"{first.capitalize()} to {second}."))
    # "adapt speed" takes its sense from its purpose: adapting speed to keep a distance is following
    expected = "keep_distance" if first == "adapt speed" and COMMANDS[second] == "keep_distance" else COMMANDS[first]
    assert labels.stated_action == expected, labels.details
    assert not labels.contradiction, labels.details


@settings(max_examples=200, deadline=None)
@given(command=commands, actor=st.sampled_from(["the truck ahead", "the lead car", "the bus in front"]),
       motion=st.sampled_from(["is coming to a stop", "is braking", "is stopping", "is slowing down"]))
def test_another_actors_stopping_is_no_command_of_the_ego(command, actor, motion):
    labels = LABELER.label(LabelInput(text=f"{command.capitalize()} because {actor} {motion}."))
    assert labels.stated_action == COMMANDS[command], labels.details
    assert not any(c.startswith("stop (") for c in labels.details.get("contradictions", [])), labels.details
