"""Pedestrians walked by SUMO (``pedestrians="sumo"``): SUMO persons on sidewalks, walking areas and crossings.

A moving scenario pedestrian (or animal) is a SUMO person while it walks: when the ego reaches its trigger
it becomes a person whose walk is SUMO's own route for it — for ``cross`` from the sidewalk where it
stands, through the walking area, over the crossing netconvert built at its crossing line (a mid-block
zebra or the junction's crossing) to the sidewalk on the other side; for ``along`` along the sidewalk it
stands on, 200 m in its direction — at the scenario's speed, moved by SUMO's striping model (no dawdling,
so the speed is the scenario's), yielding to vehicles as SUMO's pedestrians do. Before its walk and after
it, it stands: a placed stand-in like every scripted road user (SUMO draws a waiting person beside the road,
and moving a person onto a walking area crashes the striping model), where the scenario puts it and where
its walk ended.

SUMO persons walk only on pedestrian lanes: a moving pedestrian whose path lies in a traffic lane (walking
along the ego's lane, crossing from or to the middle of the road) cannot be represented and is refused
with a one-line error; ``pedestrians="scripted"`` poses those. Static pedestrians stand where the
scenario puts them, as in the scripted mode.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace
from typing import Any

from vladrivebench import Actor, Scenario, ScenarioError
from vladrivebench.world import ScriptedUser

PERSON_KINDS = ("pedestrian", "animal")
PERSON_PREFIX = "vdb.person."
ALONG_DISTANCE = 200.0
"""How far (m) an ``along`` walker's SUMO route reaches (scenario walkers walk on for the whole episode)."""
SIDEWALK_TOLERANCE = 0.3
"""How far (m) outside a sidewalk a walker may start or end and still count as on it (the kerb)."""
WAITING, WALKING, STOPPED = "waiting", "walking", "stopped"
_STAGE_WAITING, _STAGE_WALKING = 1, 2


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
                    f"(feature 'motion:cross' at s = {spec.s:g}: the network has no crossing built there); use "
                    "--sim-opt pedestrians=scripted"
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


@dataclass
class _Walker:
    """One SUMO-walked road user: its phase, its walk and the pose it stands at when not walking."""

    user: ScriptedUser
    edges: list[str]
    depart_pos: float
    arrival_pos: float
    phase: str = WAITING
    pose: Actor | None = None


class NativePersons:
    """The SUMO-walked pedestrians of one episode (see the module docstring)."""

    def __init__(self, sumo: Any, scenario: Scenario, world: Any):
        self.sumo, self.world = sumo, world
        self.ids = {spec.id for spec in walkers(scenario)}
        self.walkers: dict[str, _Walker] = {}
        self.net = None
        if self.ids:
            import sumolib

            with warnings.catch_warnings():  # sumolib's note that the optional rtree index is missing
                warnings.simplefilter("ignore")
                self.net = sumolib.net.readNet(str(world.net))

    def handles(self, actor_id: str) -> bool:
        return actor_id in self.ids

    def walking(self, actor_id: str) -> bool:
        return actor_id in self.walkers and self.walkers[actor_id].phase == WALKING

    def prepare(self, user: ScriptedUser) -> None:
        """Plan the walk (SUMO's pedestrian route) and the person's type; it stands where it starts."""
        sumo, spec, route = self.sumo, user.spec, self.world.road.route
        start = user.actor(route)
        if spec.motion == "cross":
            target = route.to_world(user.s, spec.end_offset)
        else:
            ahead = ALONG_DISTANCE if spec.direction == "same" else -ALONG_DISTANCE
            target = route.to_world(user.s + ahead, user.offset)
        from_edge, from_pos = self._sidewalk(start.x, start.y)
        to_edge, to_pos = self._sidewalk(float(target[0]), float(target[1]))
        stages = sumo.simulation.findIntermodalRoute(from_edge, to_edge, departPos=from_pos, arrivalPos=to_pos)
        edges = _dedupe([e for stage in stages for e in stage.edges]) or [from_edge]
        type_id = PERSON_PREFIX + spec.id
        vtype = sumo.vehicletype
        vtype.copy("DEFAULT_PEDTYPE", type_id)
        for setter, value in ((vtype.setLength, spec.length), (vtype.setWidth, spec.width),
                              (vtype.setHeight, spec.height), (vtype.setMaxSpeed, spec.speed),
                              (vtype.setSpeedFactor, 1.0), (vtype.setSpeedDeviation, 0.0)):
            setter(type_id, value)
        self.walkers[spec.id] = _Walker(user, edges, from_pos, to_pos, pose=start)

    def start(self, actor_id: str) -> None:
        """The ego reached the trigger: the person departs on its walk (its stand-in is removed by the
        caller)."""
        walker = self.walkers[actor_id]
        person, person_id = self.sumo.person, PERSON_PREFIX + actor_id
        person.add(person_id, walker.edges[0], walker.depart_pos, typeID=person_id)
        person.appendWalkingStage(person_id, walker.edges, walker.arrival_pos, speed=walker.user.spec.speed)
        person.appendWaitingStage(person_id, 1e7)
        walker.phase = WALKING

    def update(self, actor_id: str) -> bool:
        """After a step: the walker's pose from SUMO while it walks; True when its walk just ended (the
        person is removed; the caller puts its stand-in where it stopped)."""
        walker = self.walkers[actor_id]
        if walker.phase != WALKING:
            return False
        person, person_id = self.sumo.person, PERSON_PREFIX + actor_id
        stage = person.getStage(person_id).type
        if stage == _STAGE_WALKING:
            spec = walker.user.spec
            x, y = person.getPosition(person_id)
            yaw = math.remainder(math.radians(90.0 - person.getAngle(person_id)), 2 * math.pi)
            walker.pose = Actor(spec.id, spec.kind, x, y, yaw, spec.length, spec.width, spec.height,
                                max(person.getSpeed(person_id), 0.0))
            return False
        if stage == _STAGE_WAITING:
            person.remove(person_id)
            walker.phase = STOPPED
            walker.pose = replace(walker.pose, speed=0.0)
            return True
        return False

    def pose(self, actor_id: str) -> Actor:
        """Where the walker is (standing: where it waits or stopped; walking: where SUMO has it)."""
        return self.walkers[actor_id].pose

    def _sidewalk(self, x: float, y: float) -> tuple[str, float]:
        """The nearest pedestrian lane of a normal (non-junction) edge: (edge id, position along it)."""
        best = None
        with warnings.catch_warnings():  # sumolib's note that the optional rtree index is missing
            warnings.simplefilter("ignore")
            near = self.net.getNeighboringLanes(x, y, 8.0)
        for lane, dist in near:
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
