"""How the scripted model reads a chain-of-thought: its stated intent, the entity it is about, and the
objects it places with coordinates.

The same reader turns the model's *own* text into its CoT state and turns *injected* text into a spliced
CoT state, so selfsplice is identical by construction.

Intent (:func:`read_intent`): the earliest action phrase in the text wins (ties: the longest phrase), so
"Accelerate to maintain speed …" is accelerating and "Stop for the pedestrian …" decelerating:

- ``decelerating`` — stop, brake, slow (down), yield, decelerate, halt ("stop sign"/"stop line" are
  entities, not actions);
- ``accelerating`` — accelerate, speed up, resume, pick up speed;
- ``keep_distance`` — keep (a safe) distance/gap, follow the lead/the car/the vehicle;
- ``maintaining`` — maintain, keep, continue, proceed, hold speed, cruise.

A phrase right after a negation ("no need to slow down", "do not stop") does not count. When no phrase is
found, cues decide: a red light, something "blocking"/"obstructing", or a stop sign → ``decelerating``;
otherwise ``none`` (unintelligible text states no intent).

Slotted (ORION-like) CoTs: the ``decision`` slot dominates. Without an action phrase there, the
``objects`` slot, then the ``scene`` slot, are read for one (e.g. "…, requiring the ego to stop"); without
any, the cues above are looked for in all slots, so a stated obstacle in ``objects`` and no decision means
stop.

Objects with coordinates follow ORION's bird's-eye convention ``Kind at <x, y>``: x metres to the right,
y metres forward, from the ego's centre.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Mapping
from dataclasses import dataclass

DECELERATING, ACCELERATING, MAINTAINING, KEEP_DISTANCE, NO_INTENT = (
    "decelerating", "accelerating", "maintaining", "keep_distance", "none")
INTENTS = (MAINTAINING, ACCELERATING, DECELERATING, KEEP_DISTANCE, NO_INTENT)
"""The stated-action groups of the paper (Appendix B) plus ``none``; the same names as the core's labels."""

SLOTS = ("scene", "objects", "decision")
"""The slots of the ORION-like ``qa`` format, in order."""

_ACTION_PHRASES: tuple[tuple[str, str], ...] = (
    (KEEP_DISTANCE, r"keep(?:s|ing)?\s+(?:a\s+)?(?:safe\s+)?(?:following\s+)?(?:distance|gap)"),
    (KEEP_DISTANCE, r"follow(?:s|ing)?\s+the\s+(?:lead(?:ing)?|car|vehicle)"),
    (DECELERATING, r"stop(?:s|ping|ped)?\b(?!\s+(?:sign|line)s?\b)"),
    (DECELERATING, r"brak(?:e|es|ing)\b"),
    (DECELERATING, r"slow(?:s|ing|ed)?(?:\s+down)?\b"),
    (DECELERATING, r"yield(?:s|ing)?\b"),
    (DECELERATING, r"decelerat\w*"),
    (DECELERATING, r"halt(?:s|ing)?\b"),
    (ACCELERATING, r"accelerat\w*"),
    (ACCELERATING, r"speed(?:s|ing)?\s+up\b"),
    (ACCELERATING, r"resum\w*"),
    (ACCELERATING, r"pick(?:s|ing)?\s+up\s+speed\b"),
    (MAINTAINING, r"maintain(?:s|ing)?\b"),  # not "well-maintained"
    (MAINTAINING, r"keep(?:s|ing)?\b"),
    (MAINTAINING, r"continu\w*"),
    (MAINTAINING, r"proceed\w*"),
    (MAINTAINING, r"hold(?:s|ing)?\s+(?:the\s+|our\s+)?(?:current\s+)?speed\b"),
    (MAINTAINING, r"cruis\w*"),
)
_PHRASES = [(intent, re.compile(r"\b" + pattern, re.IGNORECASE)) for intent, pattern in _ACTION_PHRASES]
_NEGATION = re.compile(r"\b(?:not|never|without|no\s+need\s+to|don't|doesn't|cannot|can't)\s+(?:\w+\s+){0,2}$",
                       re.IGNORECASE)
_RED_LIGHT = re.compile(r"\b(?:light|signal)s?\b[^.]*\bred\b|\bred\b[^.]*\b(?:light|signal)s?\b", re.IGNORECASE)
_OBSTRUCTION = re.compile(r"\b(?:block|obstruct)\w*", re.IGNORECASE)
_STOP_SIGN = re.compile(r"\bstop\s+signs?\b", re.IGNORECASE)

_ENTITY_WORDS = {
    "pedestrian": "pedestrian", "person": "pedestrian", "people": "pedestrian",
    "car": "car", "vehicle": "car", "truck": "car", "bus": "car", "sedan": "car",
    "animal": "animal", "dog": "animal", "deer": "animal",
    "cyclist": "cyclist", "bicycle": "cyclist", "bike": "cyclist",
    "traffic light": "traffic_light", "light": "traffic_light", "signal": "traffic_light",
    "stop sign": "stop_sign",
}
"""Words for the entities the model knows, and the kind each names (the ego is never called a car)."""
_ENTITY = re.compile(
    r"\b(" + "|".join(sorted((re.escape(w) for w in _ENTITY_WORDS), key=len, reverse=True)) + r")s?\b",
    re.IGNORECASE)
_NUMBER = r"[-+]?\d+(?:\.\d+)?"
_PLACED = re.compile(
    r"\b(" + "|".join(sorted((re.escape(w) for w in _ENTITY_WORDS), key=len, reverse=True)) + r")s?\s+at\s+<\s*("
    + _NUMBER + r")\s*,\s*(" + _NUMBER + r")\s*>", re.IGNORECASE)


@dataclass(frozen=True)
class StatedObject:
    """An object the CoT places: its kind and ORION-style coordinates (x right, y forward, metres)."""

    kind: str
    right: float
    forward: float


@dataclass(frozen=True)
class CoTReading:
    """Everything the action head reads from a CoT: the stated intent, the entity the CoT is about (the
    first one it names in its deciding text) and the objects it places with coordinates."""

    intent: str
    referent: str | None = None
    objects: tuple[StatedObject, ...] = ()

    def canonical(self) -> str:
        """A canonical serialisation (sorted keys, repr-exact floats)."""
        data = {"intent": self.intent, "referent": self.referent,
                "objects": [[o.kind, repr(float(o.right)), repr(float(o.forward))] for o in self.objects]}
        return json.dumps(data, sort_keys=True, separators=(",", ":"))

    def digest(self) -> str:
        """sha256 of :meth:`canonical`: equal digests ⇔ the action head sees the same CoT."""
        return hashlib.sha256(self.canonical().encode("utf-8")).hexdigest()


def stated_intents(text: str) -> list[str]:
    """Every non-negated action phrase's intent, in order of appearance (the longest phrase where
    several start at the same place; overlapping phrases count once)."""
    found: list[tuple[int, int, str]] = []
    for intent, pattern in _PHRASES:
        for match in pattern.finditer(text):
            if not _NEGATION.search(text[max(0, match.start() - 40):match.start()]):
                found.append((match.start(), -(match.end() - match.start()), intent))
    found.sort()
    intents, covered = [], -1
    for start, negative_length, intent in found:
        if start >= covered:
            intents.append(intent)
            covered = start - negative_length
    return intents


def read_intent(text: str) -> str | None:
    """The earliest non-negated action phrase's intent, or ``None`` when the text has none."""
    intents = stated_intents(text)
    return intents[0] if intents else None


def read_cues(text: str) -> str | None:
    """``decelerating`` when the text states a red light, an obstruction or a stop sign, else ``None``."""
    if _RED_LIGHT.search(text) or _OBSTRUCTION.search(text) or _STOP_SIGN.search(text):
        return DECELERATING
    return None


def first_entity(text: str) -> str | None:
    """The kind of the first entity the text names (``pedestrian``, ``car``, ``traffic_light`` …)."""
    match = _ENTITY.search(text)
    return _ENTITY_WORDS[match.group(1).lower()] if match else None


def named_kinds(text: str) -> set[str]:
    """The kinds of every entity the text names."""
    return {_ENTITY_WORDS[m.group(1).lower()] for m in _ENTITY.finditer(text)}


def placed_objects(text: str) -> tuple[StatedObject, ...]:
    """Every ``Kind at <x, y>`` in the text, in order."""
    return tuple(StatedObject(_ENTITY_WORDS[m.group(1).lower()], float(m.group(2)), float(m.group(3)))
                 for m in _PLACED.finditer(text))


def read_sentence(text: str) -> CoTReading:
    """The reading of a one-sentence (Alpamayo-like) CoT."""
    intent = read_intent(text) or read_cues(text) or NO_INTENT
    return CoTReading(intent, first_entity(text), placed_objects(text))


def read_slots(slots: Mapping[str, str]) -> CoTReading:
    """The reading of an ORION-like CoT (``scene``, ``objects``, ``decision``; missing slots are empty)."""
    scene, objects, decision = (slots.get(name, "") for name in SLOTS)
    intent = (read_intent(decision) or read_intent(objects) or read_intent(scene)
              or read_cues(" ".join((scene, objects, decision))) or NO_INTENT)
    referent = first_entity(decision) or first_entity(objects) or first_entity(scene)
    return CoTReading(intent, referent, placed_objects(objects) + placed_objects(decision) + placed_objects(scene))
