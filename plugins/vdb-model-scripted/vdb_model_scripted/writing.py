"""How the scripted model writes its chain-of-thought, in two styles:

- ``sentence`` (Alpamayo-like): one sentence that leads with the decision, e.g. "Stop for the pedestrian
  in the lane because it is blocking the lane.";
- ``qa`` (ORION-like): three answers — ``scene`` ("The scene depicts …"), ``objects`` (``Pedestrian at
  <0.00, 10.00> standing in the lane, blocking the path.``, coordinates x right / y forward from the ego's
  centre) and ``decision`` ("You should slow down and stop. …").

Every random choice comes from a fixed block of uniform draws (:data:`N_DRAWS` per step, one purpose per
index), so each error event happens with exactly its configured probability, independently of the
others, and a (seed, step) reproduces the text exactly. The text never calls the ego a car or vehicle, so
an entity word always names something in (or invented for) the world.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from vladrivebench import LIGHT_COLOURS, Observation

from .policy import ROAD_USERS, Decision, World, decide, place_along_route
from .reading import ACCELERATING, DECELERATING, KEEP_DISTANCE, named_kinds

N_DRAWS = 16
(MISS, LIGHT_ERROR, WRONG_COLOUR, HALLUCINATE, PHANTOM_KIND, PHANTOM_FORWARD, PHANTOM_SIDE, CONTRADICT,
 CONTRADICTION_KIND, CONTRADICTION_PHRASE, DECISION_PHRASE, SCENE_SETTING, SCENE_MENTION, NOUN,
 PHANTOM_PHRASE, _SPARE) = range(N_DRAWS)
"""What each of the step's uniform draws decides."""
PHANTOM_KINDS = ("car", "pedestrian", "animal", "cyclist")


@dataclass(frozen=True)
class Rates:
    """The probabilities of the CoT's errors (each in [0, 1])."""

    miss: float = 0.0
    hallucination: float = 0.0
    contradiction: float = 0.0
    light_error: float = 0.0


@dataclass(frozen=True)
class Draft:
    """A composed CoT (``text`` for sentences, ``slots`` for qa) and what the model knows it did."""

    text: str = ""
    slots: dict[str, str] = field(default_factory=dict)
    truth: dict[str, Any] = field(default_factory=dict)


def pick(options: tuple[str, ...] | list[str], u: float) -> str:
    """The option a uniform draw ``u`` in [0, 1) selects."""
    return options[min(int(u * len(options)), len(options) - 1)]


def compose(obs: Observation, world: World, draws: np.ndarray, rates: Rates, cruise: float,
            cot_format: str) -> Draft:
    """The CoT for ``obs`` given the perceived ``world`` and the step's ``draws``.

    The CoT reasons about a *believed* world: the perceived one, minus the critical feature when it is
    missed (probability ``rates.miss``), with a wrong light colour (``rates.light_error``). Its decision
    is the perception policy applied to that belief. A hallucination (``rates.hallucination``) adds a
    phantom road user of a kind the ground truth does not hold; a contradiction
    (``rates.contradiction``) adds mutually inconsistent claims.
    """
    present = world.critical_kind is not None
    missed = bool(present and draws[MISS] < rates.miss)
    belief = world.without_critical() if missed else world
    light_wrong = False
    if not missed and world.light in LIGHT_COLOURS and bool(draws[LIGHT_ERROR] < rates.light_error):
        others = [c for c in LIGHT_COLOURS if c != world.light]
        belief, light_wrong = replace(belief, light=pick(others, draws[WRONG_COLOUR])), True
    speed = max(obs.ego.speed, 0.0)
    decision = decide(belief, speed, cruise)
    phantom = _phantom(obs, draws) if bool(draws[HALLUCINATE] < rates.hallucination) else None
    contradiction = bool(draws[CONTRADICT] < rates.contradiction)
    truth = {
        "mentioned": (present and not missed) if obs.ground_truth.critical_kind is not None else None,
        "in_range": present,
        "critical_kind": obs.ground_truth.critical_kind,
        "light_stated": belief.light if present and not missed else None,
        "light_wrong": light_wrong,
        "hallucinated": phantom is not None,
        "phantom": phantom.kind if phantom else None,
        "contradiction": contradiction,
        "decision": decision.action,
    }
    writer = _SentenceWriter if cot_format == "sentence" else _QAWriter
    return writer(obs, belief, decision, draws, phantom, contradiction).draft(truth)


@dataclass(frozen=True)
class Phantom:
    """An invented road user: its kind and ORION-style position (x right, y forward)."""

    kind: str
    right: float
    forward: float


def _phantom(obs: Observation, draws: np.ndarray) -> Phantom:
    held = {a.kind for a in obs.ground_truth.actors}
    kinds = [k for k in PHANTOM_KINDS if k not in held]  # never empty: the world holds no cyclists
    kind = pick(kinds, draws[PHANTOM_KIND])
    forward = round(15.0 + 25.0 * float(draws[PHANTOM_FORWARD]), 2)
    side = float(draws[PHANTOM_SIDE])
    if kind == "car" and side < 0.5:
        right = 0.0  # ORION's phantom "Car at <0.00, 30.00>" directly ahead
    else:
        right = (3.5 + 1.5 * (2.0 * side % 1.0)) * (1.0 if side >= 0.5 else -1.0)
    return Phantom(kind, round(right, 2), forward)


_NOUNS = {"pedestrian": ("pedestrian",), "car": ("stationary car", "car", "vehicle"), "animal": ("animal",),
          "cyclist": ("cyclist",)}


class _Writer:
    def __init__(self, obs: Observation, belief: World, decision: Decision, draws: np.ndarray,
                 phantom: Phantom | None, contradiction: bool):
        self.obs, self.belief, self.decision, self.draws = obs, belief, decision, draws
        self.phantom, self.contradiction = phantom, contradiction

    def noun(self, kind: str | None) -> str:
        return pick(_NOUNS.get(kind or "car", ("vehicle",)), self.draws[NOUN])

    def light_phrase(self) -> str:
        colour = self.belief.light
        return f"the traffic light ahead is {colour}" if colour else "the traffic light ahead allows it"

    def thing(self) -> str:
        """The feature a stop is for, as a noun phrase."""
        kind = self.decision.reason
        if kind == "traffic_light":
            return f"the {self.belief.light} traffic light" if self.belief.light else "the traffic light"
        if kind == "stop_sign":
            return "the stop sign"
        return f"the {self.noun(kind)} in the lane"

    def opposite_clause(self) -> str:
        u = self.draws[CONTRADICTION_PHRASE]
        if self.decision.action == DECELERATING:
            return pick(("accelerate to keep up with the traffic flow", "speed up to clear the area quickly"), u)
        return pick(("brake to a full stop right away", "slow down and stop immediately"), u)


class _SentenceWriter(_Writer):
    def draft(self, truth: dict[str, Any]) -> Draft:
        clause = self.decision_clause()
        if self.contradiction:
            clause = self.contradicting(clause)
        kind = self.belief.critical_kind
        if kind is not None and kind not in named_kinds(clause):
            # The decision is about something else (another road user ahead): the CoT still names the
            # critical feature it sees.
            clause = f"{clause}, while the {self.noun(kind) if kind in ROAD_USERS else _title(kind).lower()} is noted ahead"
        if self.phantom is not None:
            clause = f"{clause}, and {self.phantom_clause()}"
        return Draft(text=clause + ".", truth=truth)

    def contradicting(self, clause: str) -> str:
        colour = self.belief.light
        if colour in LIGHT_COLOURS and self.draws[CONTRADICTION_KIND] < 0.5:
            other = pick([c for c in LIGHT_COLOURS if c != colour], self.draws[CONTRADICTION_PHRASE])
            return f"The light ahead is {colour}, so continue through the {other} light"
        return f"{clause}, and {self.opposite_clause()}"

    def phantom_clause(self) -> str:
        return {
            "car": "a car is parked on the right shoulder ahead",
            "pedestrian": "a pedestrian is waiting on the sidewalk to the right",
            "animal": "a dog is standing near the road edge on the left",
            "cyclist": "a cyclist is riding along the right edge of the road",
        }[self.phantom.kind]

    def decision_clause(self) -> str:
        d, u = self.decision, self.draws[DECISION_PHRASE]
        noun = self.noun(d.reason)
        if d.action == DECELERATING and d.situation == "blocking":
            return pick((f"Stop for the {noun} in the lane because it is blocking the lane",
                         f"Slow down and stop for the {noun} ahead, which is blocking our path",
                         f"Brake to yield to the {noun} in front of us",
                         f"Decelerate to a stop because the {noun} ahead is in our lane"), u)
        if d.action == DECELERATING and d.situation == "light":
            colour = self.belief.light
            return pick((f"Stop at the intersection because the traffic light ahead is {colour}",
                         f"Slow down and stop since the traffic light is {colour}",
                         f"Decelerate to stop at the stop line as the light ahead is {colour}"), u)
        if d.action == DECELERATING and d.situation == "sign":
            return pick(("Slow down to stop at the stop sign ahead",
                         "Decelerate and come to a full stop at the stop sign",
                         "Stop at the line because of the stop sign at the intersection"), u)
        if d.situation == "approach":
            if d.action == ACCELERATING:
                return pick((f"Speed up slightly while approaching {self.thing()} ahead",
                             f"Accelerate gently toward {self.thing()} ahead, which is still far away"), u)
            return pick((f"Maintain speed while approaching {self.thing()} ahead",
                         f"Keep the current speed for now as {self.thing()} ahead is still far away"), u)
        if d.situation == "resume":
            return pick(("Resume driving through the intersection now that we have waited at the stop sign",
                         "Accelerate away from the stop sign after waiting at the line"), u)
        if d.situation == "light":
            if d.action == ACCELERATING:
                return pick((f"Accelerate through the intersection because {self.light_phrase()}",
                             f"Speed up to pass the intersection since {self.light_phrase()}"), u)
            return pick((f"Continue through the intersection since {self.light_phrase()}",
                         f"Maintain speed because {self.light_phrase()}"), u)
        if d.situation == "clear_of_lane":
            if d.action == ACCELERATING:
                return pick((f"Accelerate since the {noun} ahead is clear of our lane",
                             f"Speed up because the {noun} is outside our path"), u)
            return pick((f"Maintain speed because the {noun} ahead is clear of our lane",
                         f"Keep the current speed since the {noun} is not in our path"), u)
        if d.action == KEEP_DISTANCE:
            return pick((f"Keep distance to the {noun} ahead because it is moving slower than us",
                         f"Keep a safe gap behind the {noun} moving ahead in our lane",
                         f"Follow the lead {noun} at a safe distance"), u)
        if d.action == ACCELERATING:
            return pick(("Accelerate to reach cruising speed since the road ahead is clear",
                         "Speed up gently because the lane ahead is free of obstacles",
                         "Resume speed since the road ahead is clear"), u)
        return pick(("Maintain speed to follow the lane because the road ahead is clear",
                     "Keep the current speed and stay in the lane since there are no obstacles ahead",
                     "Continue along the lane at a steady speed as the road is clear"), u)


class _QAWriter(_Writer):
    def draft(self, truth: dict[str, Any]) -> Draft:
        scene, objects, decision = self.scene(), self.objects(), self.decision_answer()
        if self.contradiction:
            demands_stop = self.decision.stop_at is not None
            if demands_stop and self.draws[CONTRADICTION_KIND] < 0.5:
                # The decision ignores what the objects demand, and the objects say so explicitly.
                decision = "You should accelerate and lane follow. The road ahead appears clear."
                objects = f"{objects} This requires the ego to stop."
            else:
                opposite = "accelerate" if self.decision.action == DECELERATING else "slow down and stop"
                scene = f"{scene} The ego should {opposite} now."
        return Draft(slots={"scene": scene, "objects": objects, "decision": decision}, truth=truth)

    def scene(self) -> str:
        setting = pick(("an urban street during daytime with clear weather",
                        "a residential street lined with trees on a clear day",
                        "a straight two-lane road under a clear sky"), self.draws[SCENE_SETTING])
        parts = [f"The scene depicts {setting}.", "The road is dry and well-maintained."]
        kind = self.belief.critical_kind
        if kind == "traffic_light":
            colour = self.belief.light
            parts.append(f"The traffic light ahead is showing {colour}." if colour else "There is a traffic light ahead.")
        elif kind == "stop_sign":
            parts.append("A stop sign stands at the intersection ahead.")
        elif kind in ROAD_USERS and self.draws[SCENE_MENTION] < 0.5:
            where = "in the lane" if self.belief.blocking else "at the side of the road"
            parts.append(f"A {self.noun(kind)} is {where} ahead.")
        return " ".join(parts)

    def objects(self) -> str:
        lines = []
        kind, belief = self.belief.critical_kind, self.belief
        if kind in ROAD_USERS:
            lines.append(f"{_title(kind)} at {self._position_of_critical()} {self._road_user_description()}.")
        elif kind == "traffic_light":
            colour = belief.light or "an unknown colour"
            need = ", requiring the ego to stop" if self.decision.action == DECELERATING else ""
            lines.append(f"Traffic light at {self._position_of_line()} showing {colour}{need}.")
        elif kind == "stop_sign":
            lines.append(f"Stop sign at {self._position_of_line()} at the intersection ahead.")
        if self.phantom is not None:
            p = self.phantom
            lines.append(f"{_title(p.kind)} at {_coords(p.right, p.forward)} {_phantom_description(p)}.")
        return " ".join(lines) if lines else "There are no critical objects near the ego."

    def _road_user_description(self) -> str:
        belief, kind = self.belief, self.belief.critical_kind
        if self.decision.action == KEEP_DISTANCE:
            return f"ahead in the lane, moving at {max(belief.lead_speed or 0.0, 0.0):.1f} m/s, may influence following distance"
        if belief.blocking:
            if kind == "car":
                return "directly in front of the ego, stationary, blocking the lane"
            return f"{'crossing the road' if self._critical_moving() else 'standing in the lane'}, blocking the path"
        if kind == "car":
            return "in the adjacent lane, stationary, not affecting the ego"
        return "at the side of the road, clear of the ego's path"

    def _critical_moving(self) -> bool:
        actor = self.obs.ground_truth.critical()
        return actor is not None and actor.speed > 0.3

    def _position_of_critical(self) -> str:
        actor = self.obs.ground_truth.critical()
        if actor is None:
            return self._position_of_line()
        ex, ey = self.obs.ego.to_ego_frame(actor.x, actor.y)
        return _coords(-ey, ex)

    def _position_of_line(self) -> str:
        along = (self.belief.distance or 0.0) + self.obs.ego.length / 2.0
        ex, ey = place_along_route(self.obs.ground_truth.route_ahead, np.array([along]))[0]
        return _coords(-ey, ex)

    def decision_answer(self) -> str:
        d, u = self.decision, self.draws[DECISION_PHRASE]
        noun = self.noun(d.reason)
        if d.action == DECELERATING:
            opener = pick(("You should slow down and stop.", "You should brake and stop.",
                           "You should decelerate and stop."), u)
            if d.situation == "light":
                return f"{opener} The traffic light ahead is {self.belief.light}, requiring us to stop."
            if d.situation == "sign":
                return f"{opener} The stop sign ahead requires a full stop at the line."
            return f"{opener} The {noun} ahead is blocking the lane, requiring us to yield."
        if d.situation == "approach":
            verb = "accelerate gently and lane follow" if d.action == ACCELERATING else "keep and lanefollow"
            return f"You should {verb}. {_capital(self.thing())} ahead is still far away."
        if d.situation == "resume":
            return "You should accelerate and go straight. We have waited at the stop sign."
        if d.situation == "light":
            verb = "accelerate" if d.action == ACCELERATING else "maintain your current speed"
            return f"You should {verb} and go straight. {_capital(self.light_phrase())}."
        if d.situation == "clear_of_lane":
            verb = "accelerate and lane follow" if d.action == ACCELERATING else (
                "maintain your current speed and follow the lane")
            return f"You should {verb}. The {noun} ahead is not in the ego's path."
        if d.action == KEEP_DISTANCE:
            return f"You should keep a safe distance and follow the lane. The {noun} ahead is moving slowly in our lane."
        if d.action == ACCELERATING:
            return pick(("You should accelerate and lane follow. The road ahead appears clear.",
                         "You should speed up and follow the lane. There are no obstacles ahead."), u)
        return pick(("You should maintain your current speed and follow the lane. The road ahead is clear of obstacles.",
                     "You should keep and lanefollow. The lane ahead is clear."), u)


def _phantom_description(p: Phantom) -> str:
    if p.kind == "car":
        return ("directly in front of the ego, moving at a similar speed, may influence following distance"
                if p.right == 0.0 else "in the adjacent lane, moving at a similar speed")
    return {"pedestrian": "on the sidewalk, walking along the road", "animal": "near the road edge",
            "cyclist": "riding along the edge of the road"}[p.kind]


def _coords(right: float, forward: float) -> str:
    return f"<{right + 0.0:.2f}, {forward + 0.0:.2f}>"


def _title(kind: str) -> str:
    return {"traffic_light": "Traffic light", "stop_sign": "Stop sign"}.get(kind, kind.capitalize())


def _capital(text: str) -> str:
    return text[:1].upper() + text[1:]
