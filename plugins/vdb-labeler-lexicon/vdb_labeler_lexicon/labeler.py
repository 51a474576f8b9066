"""The lexicon labeler: the reader's claims judged against the step's ground truth.

Labels (the rules are spelled out in this distribution's README, which the gold file follows):

- ``stated_action``: the first current command of the decision slot (slotted CoTs), else the first
  current command of the text; ``none`` when there is none.
- ``target_mentioned``: the critical feature is named (type word or synonym) in an asserted — not
  negated, not hedged — phrase, at a compatible position when one is given; ``None`` without a target.
  ``mention_slot`` is the first slot that names it.
- ``light_colour``: the first colour stated for a traffic light as it is now (not "until it turns green").
- ``hallucination``: an asserted entity the ground truth does not hold (kind absent, or no actor of the
  kind near the stated coordinates), or a motion the actor does not have (a stopped car "overtaking").
- ``contradiction``: current stop and go commands together (a red light or a blocking entity demands
  stopping), two colours for the light, an entity both asserted and (without qualification) denied, or
  one entity both moving and stationary.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from vladrivebench import LabelInput, Labels

from . import rules

VERSION = "1.1"
DECISION_SLOTS = ("decision", "action", "a3", "answer3", "q3")
FORWARD_TOLERANCE_M = 4.0
FORWARD_TOLERANCE_FRACTION = 0.2
LATERAL_TOLERANCE_M = 2.5
MOVING_SPEED = 0.2
PHANTOM_CAR = (30.0, 0.0)
"""ORION's known artifact: ``Car at <0.00, 30.00>`` written whatever the scene (the paper filters it)."""


class LexiconLabeler:
    """Deterministic, offline labeler (labeler name ``lexicon``)."""

    name = "lexicon"

    def __init__(self, filter_phantom_car: bool = False):
        if not isinstance(filter_phantom_car, bool):
            from vladrivebench import ConfigError

            raise ConfigError(f"labeler 'lexicon': filter_phantom_car must be true or false, got {filter_phantom_car!r}")
        self.filter_phantom_car = filter_phantom_car
        self.version = VERSION + ("+phantom-filtered" if filter_phantom_car else "")

    def label_batch(self, items: Sequence[LabelInput]) -> list[Labels]:
        return [self.label(item) for item in items]

    def label(self, item: LabelInput) -> Labels:
        reading = rules.read(item.text, item.slots or None)
        context = item.context or {}
        actors = [a for a in context.get("actors") or () if isinstance(a, Mapping)]
        details: dict[str, Any] = {}
        mentioned, slot = self._target(reading, context, actors)
        hallucinated, phantom = self._hallucinations(reading, actors, context)
        contradictions = self._contradictions(reading)
        if hallucinated:
            details["hallucinated"] = hallucinated
        if phantom:
            details["phantom_car"] = True
        if contradictions:
            details["contradictions"] = contradictions
        colours = [m.colour for m in reading.mentions if m.colour]
        return Labels(
            stated_action=self._stated_action(reading),
            target_mentioned=mentioned,
            mention_slot=slot,
            light_colour=colours[0] if colours else None,
            hallucination=bool(hallucinated),
            contradiction=bool(contradictions),
            details=details,
            labeler=self.name,
            version=self.version,
        )

    # -- stated action -------------------------------------------------------------------------------
    @staticmethod
    def _stated_action(reading: rules.Reading) -> str:
        current = [c for c in reading.claims if c.current]
        decision = _decision_slot(reading.slots)
        preferred = [c for c in current if c.slot == decision] if decision else []
        chosen = preferred or current
        return chosen[0].action if chosen else "none"

    # -- target ---------------------------------------------------------------------------------------
    @staticmethod
    def _target(reading: rules.Reading, context: Mapping, actors: list) -> tuple[bool | None, str | None]:
        kind = context.get("critical_kind")
        if not kind:
            return None, None
        critical = context.get("critical_position")
        for mention in reading.mentions:
            if not mention.named or mention.kind != kind:
                continue
            if mention.position is not None and critical is not None and kind in rules.ROAD_USERS:
                if not _near(mention.position, critical):
                    continue
            return True, mention.slot
        return False, None

    # -- hallucination ---------------------------------------------------------------------------------
    def _hallucinations(self, reading: rules.Reading, actors: list,
                        context: Mapping) -> tuple[list[str], bool]:
        found, phantom = [], False
        for mention in reading.mentions:
            if not mention.asserted or mention.kind == "traffic":
                continue
            problem = _fabricated(mention, actors, context)
            if problem is None:
                continue
            if self.filter_phantom_car and _is_phantom_car(mention) and problem.startswith("no car"):
                phantom = True
                continue
            found.append(problem)
        return found, phantom

    # -- contradiction ------------------------------------------------------------------------------------
    @staticmethod
    def _contradictions(reading: rules.Reading) -> list[str]:
        found = []
        current = [c for c in reading.claims if c.current and not c.purpose]
        stops = [c.phrase for c in current if rules.go_or_stop(c.action) == "stop" and not c.anticipatory]
        goes = [c for c in current if rules.go_or_stop(c.action) == "go"]
        demands = [f"{m.colour} light" for m in reading.mentions if m.colour == "red"]
        demands += [f"{m.word} blocking" for m in reading.mentions if m.blocking]
        firm_goes = [c.phrase for c in goes if not c.anticipatory]
        if stops and goes:
            found.append(f"stop ({stops[0]}) and go ({goes[0].phrase})")
        elif demands and firm_goes:
            found.append(f"stop ({demands[0]}) and go ({firm_goes[0]})")
        halts = [c.phrase for c in current if c.halt and not c.anticipatory]
        follows = [c.phrase for c in current if c.action == "keep_distance"]
        if halts and follows:
            found.append(f"halt ({halts[0]}) and follow ({follows[0]})")
        colours = sorted({m.colour for m in reading.mentions if m.colour})
        if len(colours) > 1:
            found.append(f"light stated {' and '.join(colours)}")
        for kind in sorted({_presence_kind(m.kind) for m in reading.mentions}):
            same = [m for m in reading.mentions if _presence_kind(m.kind) == kind]
            if any(m.asserted for m in same) and any(m.status == "negated" and not m.qualified for m in same):
                found.append(f"{kind} both present and absent")
            if _motion_conflict([m for m in same if m.asserted]):
                found.append(f"{kind} both moving and stationary")
        return found


def _presence_kind(kind: str) -> str:
    return "car" if kind == "traffic" else kind  # "no traffic" denies vehicles


def _decision_slot(slots: tuple[str | None, ...]) -> str | None:
    named = [s for s in slots if s and s.lower() in DECISION_SLOTS]
    if named:
        return named[0]
    return slots[-1] if len(slots) > 1 else None


def _near(stated: tuple[float, float], actual: Sequence[float]) -> bool:
    """Stated ``(forward, lateral)`` against an actor's ego-frame ``[x forward, y left]``."""
    forward, lateral = stated
    ax, ay = float(actual[0]), float(actual[1])
    forward_ok = abs(forward - ax) <= max(FORWARD_TOLERANCE_M, FORWARD_TOLERANCE_FRACTION * abs(ax))
    lateral_ok = min(abs(lateral - ay), abs(-lateral - ay)) <= LATERAL_TOLERANCE_M
    return forward_ok and lateral_ok


def _is_phantom_car(mention: rules.Mention) -> bool:
    if mention.kind != "car" or mention.position is None:
        return False
    forward, lateral = mention.position
    return abs(forward - PHANTOM_CAR[0]) < 1.0 and abs(lateral) < 0.5


def _fabricated(mention: rules.Mention, actors: list, context: Mapping) -> str | None:
    """Why an asserted mention is not in the ground truth, or ``None`` when it is."""
    kind = mention.kind
    if kind == "obstacle":
        present = [a for a in actors if a.get("kind") not in rules.INFRASTRUCTURE]
        return None if present else f"obstacle ({mention.word}) on an empty road"
    if kind == "traffic_light":
        present = [a for a in actors if a.get("kind") == kind] or context.get("light_state")
        return None if present else f"no traffic light ({mention.word})"
    same = [a for a in actors if a.get("kind") == kind]
    if not same:
        return f"no {kind.replace('_', ' ')} ({mention.word})"
    if mention.position is not None and kind in rules.ROAD_USERS:  # signs: kerb vs stop-line positions differ
        same = [a for a in same if _near(mention.position, a.get("position") or (0.0, 0.0))]
        if not same:
            forward, lateral = mention.position
            return f"no {kind} near <{lateral:.2f}, {forward:.2f}> ({mention.word})"
    if kind in rules.ROAD_USERS and mention.motion and len(mention.motion) == 1:
        claimed = next(iter(mention.motion))
        if all(_actual_motion(a) != claimed for a in same):
            return f"{mention.word} described as {claimed}, but it is not"
    return None


def _actual_motion(actor: Mapping) -> str:
    return "moving" if float(actor.get("speed") or 0.0) > MOVING_SPEED else "stationary"


_SPECIFIC_TYPES = ("truck", "bus", "van", "sedan", "suv", "pickup", "taxi", "lorr", "motorcycle", "car")


def _vehicle_type(word: str) -> str | None:
    """The vehicle type a word names ("trucks" → "truck"), or None for a generic word ("vehicle")."""
    return next((t for t in _SPECIFIC_TYPES if word.startswith(t)), None)


def _same_entity(a: rules.Mention, b: rules.Mention) -> bool:
    """Two mentions can be one entity: no clearly different places, not one plural and one singular, nor two
    different vehicle types ("the truck and bus are parked, while the car is driving" speaks of three)."""
    if a.position is not None and b.position is not None and not _near(a.position, b.position):
        return False
    if _plural(a.word) != _plural(b.word):
        return False  # "the parked vehicles" are several; "the car is driving" is one
    type_a, type_b = _vehicle_type(a.word), _vehicle_type(b.word)
    return type_a is None or type_b is None or type_a == type_b


def _plural(word: str) -> bool:
    return word in ("people", "men", "women", "children") or (
        word.endswith("s") and not word.endswith(("bus", "ss")))


def _motion_conflict(mentions: list[rules.Mention]) -> bool:
    """One entity said to be both moving and stationary."""
    moving = [m for m in mentions if m.motion == {"moving"}]
    still = [m for m in mentions if m.motion == {"stationary"}]
    return any(_same_entity(a, b) for a in moving for b in still)
