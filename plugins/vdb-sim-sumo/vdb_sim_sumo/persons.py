"""Pedestrians walked by SUMO (``pedestrians="sumo"``): SUMO persons on sidewalks, walking areas and crossings.

A moving scenario pedestrian (or animal) becomes a SUMO person whose plan is: wait (until the ego
reaches its trigger), walk, wait. The walk is SUMO's own route for it — for ``cross`` from the sidewalk
where it starts, through the walking area, over the crossing netconvert built at its crossing line (a
mid-block zebra or the junction's crossing) to the sidewalk on the other side; for ``along`` along the
sidewalk it stands on, 200 m in its direction — at the scenario's speed, moved by SUMO's striping model
(no dawdling, so the speed is the scenario's). While a person waits, SUMO would draw it beside the road,
so it is held where it stands (its scenario position before the walk, where the walk ended after it).

SUMO persons walk only on pedestrian lanes: a moving pedestrian whose path lies in a traffic lane (walking
along the ego's lane, crossing from or to the middle of the road) cannot be represented and is refused
with a one-line error; ``pedestrians="scripted"`` poses those. Static pedestrians stand where the
scenario puts them, as in the scripted mode.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

from vladrivebench.errors import ScenarioError
from vladrivebench.scenarios import Scenario

from .scripted import ScriptedUser

PERSON_KINDS = ("pedestrian", "animal")
ALONG_DISTANCE = 200.0
"""How far (m) an ``along`` walker's SUMO route reaches (scenario walkers walk on for the whole episode)."""
SIDEWALK_TOLERANCE = 0.3
"""How far (m) outside a sidewalk a walker may start or end and still count as on it (the kerb)."""
HOLD = "hold"
WALK = "walk"


def walkers(scenario: Scenario) -> list[Any]:
    """The scenario's road users that SUMO walks in this mode: moving pedestrians and animals."""
    return [a for a in scenario.actors if a.kind in PERSON_KINDS and a.motion != "static"]


def check_walkable(scenario: Scenario, world: Any) -> None:
    """Raise a one-line :class:`ScenarioError` naming the first moving pedestrian SUMO cannot walk."""
    road = world.road
    where = scenario.source or scenario.id
    for spec in walkers(scenario):
        ends = [("starts", spec.offset)]
        if spec.motion == "cross":
            ends.append(("ends", spec.end_offset))
            if spec.id not in world.crossing_nodes:
                raise ScenarioError(
                    f"scenario {where}: simulator 'sumo' with pedestrians='sumo' cannot walk actor {spec.id!r} "
                    f"(feature 'motion:cross' at s = {spec.s:g}: no SUMO crossing there, too close to the end of "
                    "the network); use --sim-opt pedestrians=scripted"
                )
        for verb, offset in ends:
            x, y = (float(v) for v in road.route.to_world(spec.s, offset))
            m = float(road.road_offset(x, y))
            if not -SIDEWALK_TOLERANCE <= m <= road.sidewalk_width + SIDEWALK_TOLERANCE:
                place = "in a traffic lane" if m < 0 else "off the sidewalk"
                raise ScenarioError(
                    f"scenario {where}: simulator 'sumo' with pedestrians='sumo' cannot walk actor {spec.id!r} "
                    f"(feature 'motion:{spec.motion}': it {verb} at offset {offset:g} m, {place}; SUMO persons "
                    "walk on sidewalks and crossings); use --sim-opt pedestrians=scripted"
                )


class NativePersons:
    """The SUMO-walked pedestrians of one episode (see the module docstring)."""

    def __init__(self, sumo: Any, scenario: Scenario, world: Any, users: list[ScriptedUser]):
        import sumolib

        self.sumo, self.world = sumo, world
        self.ids = {spec.id for spec in walkers(scenario)}
        self.phase: dict[str, str] = {}
        self.hold_at: dict[str, tuple[float, float, float]] = {}
        self.net = None
        if self.ids:
            with warnings.catch_warnings():  # sumolib's note that the optional rtree index is missing
                warnings.simplefilter("ignore")
                self.net = sumolib.net.readNet(str(world.net))

    def handles(self, actor_id: str) -> bool:
        return actor_id in self.ids

    def add(self, user: ScriptedUser, type_id: str, sumo_id: str) -> None:
        """Add the person with its plan: wait, walk (SUMO's route), wait."""
        sumo, spec, route = self.sumo, user.spec, self.world.road.route
        start = user.actor(route)
        if spec.motion == "cross":
            target = route.to_world(user.s, spec.end_offset)
        else:
            ahead = ALONG_DISTANCE if spec.direction == "same" else -ALONG_DISTANCE
            target = route.to_world(user.s + ahead, user.offset)
        from_edge, from_pos = self._sidewalk(start.x, start.y)
        to_edge, to_pos = self._sidewalk(float(target[0]), float(target[1]))
        vtype = sumo.vehicletype
        vtype.setSpeedFactor(type_id, 1.0)
        vtype.setSpeedDeviation(type_id, 0.0)
        vtype.setMaxSpeed(type_id, spec.speed)
        sumo.person.add(sumo_id, from_edge, from_pos, typeID=type_id)
        sumo.person.appendWaitingStage(sumo_id, 1e7)
        stages = sumo.simulation.findIntermodalRoute(from_edge, to_edge, departPos=from_pos, arrivalPos=to_pos)
        edges = [e for stage in stages for e in stage.edges] or [from_edge]
        sumo.person.appendWalkingStage(sumo_id, _dedupe(edges), to_pos, speed=spec.speed)
        sumo.person.appendWaitingStage(sumo_id, 1e7)
        self.phase[spec.id] = HOLD
        self.hold_at[spec.id] = (start.x, start.y, start.yaw)
        if user.started:
            self.start(user, sumo_id)

    def start(self, user: ScriptedUser, sumo_id: str) -> None:
        """The ego reached the trigger: SUMO walks the person from now on.

        Holding a person with ``moveToXY`` puts a stage of its own in front of the plan; every stage before
        the planned walk (that one, the first wait, the departure) is ended, leaving walk + final wait."""
        person = self.sumo.person
        while person.getRemainingStages(sumo_id) > 2:
            person.removeStage(sumo_id, 0)
        self.phase[user.spec.id] = WALK

    def place(self, actor_id: str, sumo_id: str) -> None:
        """Hold a waiting person where it stands; leave a walking one to SUMO (and note where it is)."""
        sumo = self.sumo
        if self.phase[actor_id] == WALK:
            if sumo.person.getRemainingStages(sumo_id) <= 1 and sumo.person.getStage(sumo_id).type == 1:
                self.phase[actor_id] = HOLD
            else:
                return
        x, y, yaw = self.hold_at[actor_id]
        sumo.person.moveToXY(sumo_id, "", x, y, (90.0 - math.degrees(yaw)) % 360.0, 2)

    def observed(self, actor_id: str, x: float, y: float, yaw: float) -> None:
        """Remember a walking person's last pose, where it will stand once its walk ends."""
        if self.phase.get(actor_id) == WALK:
            self.hold_at[actor_id] = (x, y, yaw)

    def _sidewalk(self, x: float, y: float) -> tuple[str, float]:
        """The nearest pedestrian lane of a normal (non-junction) edge: (edge id, position along it)."""
        best = None
        for lane, dist in self.net.getNeighboringLanes(x, y, 8.0):
            if lane.allows("pedestrian") and (best is None or dist < best[1]):
                best = (lane, dist)
        if best is None:
            raise ScenarioError(f"simulator 'sumo': no sidewalk within 8 m of ({x:.1f}, {y:.1f})")
        lane = best[0]
        pos, _ = lane.getClosestLanePosAndDist((x, y))
        pos = min(max(pos, 0.1), lane.getLength() - 0.1)
        return lane.getEdge().getID(), float(pos)


def _dedupe(edges: list[str]) -> list[str]:
    out: list[str] = []
    for edge in edges:
        if not out or out[-1] != edge:
            out.append(edge)
    return out
